"""A world packed for rendering: surfaces as stacked arrays and all textures (with their mip
chains) in two flat atlases, so one gather samples every pixel of a frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.synth.street.textures import mip_chain, sign_polygon
from app.synth.street.world import World

MIP_LEVELS = 7
MAX_HALF_PLANES = 8


@dataclass(frozen=True)
class Atlas:
    """Textures in one flat array (n_texels, channels); per texture and mip level its offset,
    width and height, shapes (T, MIP_LEVELS). Levels past a chain's end repeat its last one."""

    texels: np.ndarray
    offset: np.ndarray
    width: np.ndarray
    height: np.ndarray


@dataclass(frozen=True)
class Scene:
    origin_enu: np.ndarray  # (P, 3)
    axis_u: np.ndarray  # (P, 3)
    axis_v: np.ndarray  # (P, 3)
    normal: np.ndarray  # (P, 3) axis_u x axis_v
    size_m: np.ndarray  # (P, 2)
    texel_m: np.ndarray  # (P,)
    texture: np.ndarray  # (P,) index into grey_atlas, or into sign_atlas where is_sign
    tint_bgr: np.ndarray  # (P, 3) float32
    is_sign: np.ndarray  # (P,) bool
    sign_index: np.ndarray  # (P,) index into World.signs, -1 for other surfaces
    # Plate outlines in surface (u, v) metres: inside iff a*u + b*v + c >= 0 for every half-plane
    # and (u-cu)^2 + (v-cv)^2 <= radius^2; both are trivially true for plain rectangles.
    half_planes: np.ndarray  # (P, MAX_HALF_PLANES, 3)
    radius_m: np.ndarray  # (P,) inf for non-round surfaces
    grey_atlas: Atlas
    sign_atlas: Atlas
    ground_origin_xy: np.ndarray  # (2,)
    ground_texel_m: float
    ground_texture: int  # index into grey_atlas

    @property
    def n_surfaces(self) -> int:
        return len(self.texel_m)


def _atlas(images: list[np.ndarray]) -> Atlas:
    n = len(images)
    offset = np.zeros((n, MIP_LEVELS), np.int64)
    width = np.zeros((n, MIP_LEVELS), np.int64)
    height = np.zeros((n, MIP_LEVELS), np.int64)
    chunks, pos = [], 0
    channels = images[0].shape[2] if images and images[0].ndim == 3 else 1
    for i, img in enumerate(images):
        chain = mip_chain(img, MIP_LEVELS)
        for level in range(MIP_LEVELS):
            lv = chain[min(level, len(chain) - 1)]
            if level < len(chain):
                chunks.append(lv.reshape(-1, channels))
                offset[i, level] = pos
                pos += lv.shape[0] * lv.shape[1]
            else:
                offset[i, level] = offset[i, len(chain) - 1]
            height[i, level], width[i, level] = lv.shape[:2]
    texels = np.concatenate(chunks) if chunks else np.zeros((1, channels), np.uint8)
    return Atlas(texels=texels, offset=offset, width=width, height=height)


def build_scene(world: World, removed_sign_ids: tuple[str, ...] | list[str] = ()) -> Scene:
    """Pack ``world``, leaving out the plates and poles of the signs in ``removed_sign_ids``."""
    removed = set(removed_sign_ids)
    unknown = removed - {s.sign_id for s in world.signs}
    if unknown:
        raise ValueError(f"unknown sign ids: {sorted(unknown)}")
    removed_idx = {i for i, s in enumerate(world.signs) if s.sign_id in removed}
    keep = [i for i, s in enumerate(world.surfaces)
            if s.sign not in removed_idx and s.pole_of not in removed_idx]
    surfs = [world.surfaces[i] for i in keep]
    p = len(surfs)
    half_planes = np.zeros((p, MAX_HALF_PLANES, 3))
    half_planes[:, :, 2] = 1.0
    radius = np.full(p, np.inf)
    for i, s in enumerate(surfs):
        if s.sign < 0 or s.shape == "square":
            continue
        w, h = s.size_m
        if s.shape == "round":
            radius[i] = w / 2.0
            continue
        poly = sign_polygon(s.shape, w) + np.array([w / 2.0, h / 2.0])
        for k, (a, b) in enumerate(zip(poly, np.roll(poly, -1, axis=0))):
            e = b - a  # counter-clockwise: inside is on the left of every edge
            half_planes[i, k] = (-e[1], e[0], e[1] * a[0] - e[0] * a[1])
    axis_u = np.array([s.axis_u for s in surfs])
    axis_v = np.array([s.axis_v for s in surfs])
    return Scene(
        origin_enu=np.array([s.origin_enu for s in surfs]), axis_u=axis_u, axis_v=axis_v,
        normal=np.cross(axis_u, axis_v), size_m=np.array([s.size_m for s in surfs]),
        texel_m=np.array([s.texel_m for s in surfs]), texture=np.array([s.texture for s in surfs]),
        tint_bgr=np.array([s.tint_bgr for s in surfs], np.float32),
        is_sign=np.array([s.sign >= 0 for s in surfs]),
        sign_index=np.array([s.sign for s in surfs]), half_planes=half_planes, radius_m=radius,
        grey_atlas=_atlas(world.textures), sign_atlas=_atlas(world.sign_faces),
        ground_origin_xy=np.asarray(world.ground.origin_xy, float),
        ground_texel_m=float(world.ground.texel_m), ground_texture=int(world.ground.texture))
