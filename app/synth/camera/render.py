"""Exact ray-cast rendering of a packed scene through a distorted camera.

Every output pixel's ray is the camera model's own inverse (``cv2.undistortPoints`` with tight
criteria, once per camera), so projecting a world point with ``cv2.projectPoints(K, dist)`` lands
where the renderer drew it. Surfaces are tested only inside the pixel window their outline can
cover (tiles of undistorted ray bounds), nearest positive hit wins, textures are sampled bilinearly
from a mip level matched to the pixel's footprint (mild anti-aliasing).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from app.pipeline.types import CameraModel
from app.synth.camera.lens import undistort_normalized
from app.synth.camera.scene import MIP_LEVELS, Atlas, Scene

SKY_ID = -1
GROUND_ID = -2
TILE_PX = 16
NEAR_M = 0.05
_SKY_HORIZON_BGR = np.array([238, 222, 205], np.float32)
_SKY_ZENITH_BGR = np.array([215, 160, 105], np.float32)


@dataclass(frozen=True)
class CameraRays:
    """Per-pixel undistorted rays of one camera: pixel (r, c) sees direction (xn, yn, 1) in the
    camera frame. ``log2_footprint`` is log2 of the pixel's angular size (radians)."""

    camera: CameraModel
    xn: np.ndarray  # (H, W) float32
    yn: np.ndarray  # (H, W) float32
    log2_footprint: np.ndarray  # (H, W) float32
    ray_norm: np.ndarray  # (H, W) float32, |(xn, yn, 1)|
    tile_lo: np.ndarray  # (TH, TW, 2) min (xn, yn) over each TILE_PX tile
    tile_hi: np.ndarray  # (TH, TW, 2) max (xn, yn)


@dataclass(frozen=True)
class Rendered:
    image_bgr: np.ndarray  # (H, W, 3) uint8
    surface_id: np.ndarray  # (H, W) int32: index into the scene's surfaces, SKY_ID or GROUND_ID
    depth_m: np.ndarray  # (H, W) float32: camera-frame z of the hit, inf for sky


def camera_rays(camera: CameraModel) -> CameraRays:
    h, w = camera.height, camera.width
    cols, rows = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    pix = np.stack([cols, rows], axis=-1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    und = cv2.undistortPoints(pix, camera.K, camera.dist, criteria=criteria).reshape(h, w, 2)
    und = _fix_diverged(camera, und, pix.reshape(h, w, 2))
    xn, yn = und[..., 0], und[..., 1]
    norm = np.sqrt(1.0 + xn * xn + yn * yn)
    # Solid angle of a pixel from the Jacobian of the undistortion, projected onto the unit sphere.
    area = np.abs(np.gradient(xn, axis=1) * np.gradient(yn, axis=0)
                  - np.gradient(xn, axis=0) * np.gradient(yn, axis=1))
    log2_fp = 0.5 * np.log2(area) - 1.5 * np.log2(norm)
    th, tw = -(-h // TILE_PX), -(-w // TILE_PX)
    pad = ((0, th * TILE_PX - h), (0, tw * TILE_PX - w), (0, 0))
    tiles = np.pad(und, pad, mode="edge").reshape(th, TILE_PX, tw, TILE_PX, 2)
    return CameraRays(camera=camera, xn=xn.astype(np.float32), yn=yn.astype(np.float32),
                      log2_footprint=log2_fp.astype(np.float32), ray_norm=norm.astype(np.float32),
                      tile_lo=tiles.min(axis=(1, 3)), tile_hi=tiles.max(axis=(1, 3)))


def _fix_diverged(camera: CameraModel, und: np.ndarray, pix: np.ndarray) -> np.ndarray:
    """OpenCV's iteration stops short near the rim of some strong wide-angle lenses (see
    ``app.synth.camera.lens``): where its ray does not project back onto its pixel, take the
    robust one."""
    r2 = np.sum(und * und, axis=-1)
    radial = 1.0 + camera.k1 * r2 + camera.k2 * r2 * r2
    back = np.stack([und[..., 0] * radial * camera.fx + camera.cx,
                     und[..., 1] * radial * camera.fy + camera.cy], axis=-1)
    bad = ~np.all(np.abs(back - pix) < 1e-6, axis=-1)
    if bad.any():
        und = und.copy()
        und[bad] = undistort_normalized(camera, pix[bad])
    return und


def _windows(scene: Scene, rays: CameraRays, T_world_cam: np.ndarray):
    """(surface index, row slice, col slice) for every surface that may cover some pixel."""
    R_cam_world = T_world_cam[:3, :3].T
    c_world = T_world_cam[:3, 3]
    w, h = scene.size_m[:, 0:1], scene.size_m[:, 1:2]
    o, au, av = scene.origin_enu, scene.axis_u, scene.axis_v
    corners_world = np.stack([o, o + w * au, o + w * au + h * av, o + h * av], axis=1)
    corners_cam = (corners_world - c_world) @ R_cam_world.T  # (P, 4, 3)
    z = corners_cam[..., 2]
    out = []
    for i in np.nonzero(z.max(axis=1) > NEAR_M)[0]:
        poly = corners_cam[i]
        if z[i].min() <= NEAR_M:
            poly = _clip_near(poly)
        xy = poly[:, :2] / poly[:, 2:3]
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        hit = np.all(rays.tile_hi >= lo, axis=2) & np.all(rays.tile_lo <= hi, axis=2)
        r_any, c_any = np.nonzero(hit.any(axis=1))[0], np.nonzero(hit.any(axis=0))[0]
        if len(r_any) == 0:
            continue
        out.append((int(i), slice(r_any[0] * TILE_PX, (r_any[-1] + 1) * TILE_PX),
                    slice(c_any[0] * TILE_PX, (c_any[-1] + 1) * TILE_PX)))
    return out


def _clip_near(poly: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman clip of a convex polygon (K, 3) to z >= NEAR_M."""
    kept = []
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):
        if a[2] >= NEAR_M:
            kept.append(a)
        if (a[2] >= NEAR_M) != (b[2] >= NEAR_M):
            kept.append(a + (NEAR_M - a[2]) / (b[2] - a[2]) * (b - a))
    return np.array(kept)


def _inside_outline(scene: Scene, i: int, u, v):
    ok = np.ones(np.shape(u), bool)
    if np.isfinite(scene.radius_m[i]):
        r = scene.radius_m[i]
        cu, cv = scene.size_m[i] / 2.0
        ok &= (u - cu) ** 2 + (v - cv) ** 2 <= r * r
    for a, b, c in scene.half_planes[i]:
        if a != 0.0 or b != 0.0:
            ok &= a * u + b * v + c >= 0.0
    return ok


def render_frame(scene: Scene, rays: CameraRays, T_world_cam: np.ndarray) -> Rendered:
    """Render the view of a camera at pose ``T_world_cam`` (camera -> ENU world, 4x4)."""
    R = T_world_cam[:3, :3].astype(np.float32)
    c = T_world_cam[:3, 3].astype(np.float64)
    d = [R[k, 0] * rays.xn + R[k, 1] * rays.yn + R[k, 2] for k in range(3)]  # world ray dirs
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ground = np.where(d[2] < 0, np.float32(-c[2]) / d[2], np.float32(np.inf))
    depth = t_ground.astype(np.float32)
    sid = np.where(np.isfinite(depth), GROUND_ID, SKY_ID).astype(np.int32)
    with np.errstate(invalid="ignore"):
        tex_u = (c[0] + depth * d[0]).astype(np.float32)
        tex_v = (c[1] + depth * d[1]).astype(np.float32)
    cos_in = np.abs(d[2]) / rays.ray_norm
    for i, rs, cs in _windows(scene, rays, T_world_cam):
        dx, dy, dz = d[0][rs, cs], d[1][rs, cs], d[2][rs, cs]
        rel = c - scene.origin_enu[i]
        # Python floats keep the per-pixel arithmetic in float32 (NumPy 2 promotion rules).
        n, au, av = scene.normal[i].tolist(), scene.axis_u[i].tolist(), scene.axis_v[i].tolist()
        size_u, size_v = scene.size_m[i].tolist()
        nd = n[0] * dx + n[1] * dy + n[2] * dz
        with np.errstate(divide="ignore", invalid="ignore"):
            t = float(-(scene.normal[i] @ rel)) / nd
        depth_w = depth[rs, cs]
        ok = (t > NEAR_M) & (t < depth_w)
        if not ok.any():
            continue
        u = float(scene.axis_u[i] @ rel) + t * (au[0] * dx + au[1] * dy + au[2] * dz)
        v = float(scene.axis_v[i] @ rel) + t * (av[0] * dx + av[1] * dy + av[2] * dz)
        ok &= (u >= 0) & (u <= size_u) & (v >= 0) & (v <= size_v)
        if scene.is_sign[i]:
            ok &= _inside_outline(scene, i, u, v)
        np.copyto(depth_w, t, where=ok)
        sid[rs, cs][ok] = i
        np.copyto(tex_u[rs, cs], u, where=ok)
        np.copyto(tex_v[rs, cs], v, where=ok)
        np.copyto(cos_in[rs, cs], np.abs(nd) / rays.ray_norm[rs, cs], where=ok)
    image = _shade(scene, rays, sid, depth, tex_u, tex_v, cos_in, d)
    return Rendered(image_bgr=image, surface_id=sid, depth_m=depth)


def _shade(scene, rays, sid, depth, tex_u, tex_v, cos_in, d) -> np.ndarray:
    h, w = sid.shape
    out = np.empty((h * w, 3), np.float32)
    flat_sid = sid.ravel()
    elev = np.clip((d[2] / (rays.ray_norm)).ravel(), 0.0, 1.0)[:, None] ** 0.6
    sky = flat_sid == SKY_ID
    out[sky] = (1 - elev[sky]) * _SKY_HORIZON_BGR + elev[sky] * _SKY_ZENITH_BGR
    # log2 of the texel footprint at each hit, before dividing by the texel size.
    with np.errstate(divide="ignore"):
        log2_fp = (rays.log2_footprint + np.log2(depth * rays.ray_norm)
                   - 0.5 * np.log2(np.maximum(cos_in, 1e-3))).ravel()
    u, v = tex_u.ravel(), tex_v.ravel()
    ground = np.nonzero(flat_sid == GROUND_ID)[0]
    if len(ground):
        texel = scene.ground_texel_m
        x0, y0 = scene.ground_origin_xy.tolist()
        col = (u[ground] - x0) * (1.0 / texel)
        row = (v[ground] - y0) * (1.0 / texel)
        tex = np.full(len(ground), scene.ground_texture)
        out[ground] = _sample(scene.grey_atlas, tex, col, row, _level(log2_fp[ground], texel))
    surf = np.nonzero(flat_sid >= 0)[0]
    s = flat_sid[surf]
    texel = scene.texel_m[s].astype(np.float32)
    col, row = u[surf] / texel, (scene.size_m[s, 1].astype(np.float32) - v[surf]) / texel
    level = _level(log2_fp[surf], texel)
    signs = scene.is_sign[s]
    grey = ~signs
    out[surf[grey]] = _sample(scene.grey_atlas, scene.texture[s[grey]], col[grey], row[grey],
                              level[grey]) * scene.tint_bgr[s[grey]]
    out[surf[signs]] = _sample(scene.sign_atlas, scene.texture[s[signs]], col[signs], row[signs],
                               level[signs])
    return np.clip(out, 0, 255).astype(np.uint8).reshape(h, w, 3)


def _level(log2_footprint_m: np.ndarray, texel_m) -> np.ndarray:
    level = np.round(log2_footprint_m - np.log2(texel_m))
    return np.clip(level, 0, MIP_LEVELS - 1).astype(np.int64)


def _sample(atlas: Atlas, tex: np.ndarray, col: np.ndarray, row: np.ndarray,
            level: np.ndarray) -> np.ndarray:
    """Bilinear lookups (M, channels) float32; ``col``/``row`` in level-0 texel units (texel j
    covers [j, j + 1)). ``cv2.pyrDown`` centres texel j of a level on texel 2j of the level
    below, so texel j of level k sits at level-0 position 2^k j + 0.5, not 2^k (j + 0.5): the
    latter slid every texture by (2^k - 1) / 2 level-0 texels, about 0.25-0.45 px in the image,
    and by a different amount each time the level changed (generator 1's renders)."""
    scale = np.ldexp(np.float32(1.0), -level.astype(np.int32)).astype(np.float32)
    x, y = (col - 0.5) * scale, (row - 0.5) * scale
    w, h, off = atlas.width[tex, level], atlas.height[tex, level], atlas.offset[tex, level]
    x0f, y0f = np.floor(x), np.floor(y)
    fx, fy = (x - x0f).astype(np.float32)[:, None], (y - y0f).astype(np.float32)[:, None]
    x0 = np.clip(x0f.astype(np.int64), 0, w - 1)
    y0 = np.clip(y0f.astype(np.int64), 0, h - 1)
    dx = (x0 < w - 1).astype(np.int64)  # the right/lower neighbour, clamped at the edge
    dy = np.where(y0 < h - 1, w, 0)
    t = atlas.texels
    i00 = off + y0 * w + x0
    top = t[i00] * (1 - fx) + t[i00 + dx] * fx
    bottom = t[i00 + dy] * (1 - fx) + t[i00 + dy + dx] * fx
    return top * (1 - fy) + bottom * fy


def first_hits(scene: Scene, origin_enu: np.ndarray, dirs_enu: np.ndarray,
               ignore_ground: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit of rays ``origin + t * dir`` (dirs (K, 3)): t (K,) in units of |dir| (inf for
    none) and surface ids (K,) (SKY_ID when nothing is hit, GROUND_ID for the ground)."""
    dirs = np.atleast_2d(np.asarray(dirs_enu, float))
    rel = np.asarray(origin_enu, float) - scene.origin_enu  # (P, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        nd = dirs @ scene.normal.T  # (K, P)
        t = -np.einsum("pk,pk->p", scene.normal, rel)[None, :] / nd
        u = np.einsum("pk,pk->p", scene.axis_u, rel)[None, :] + t * (dirs @ scene.axis_u.T)
        v = np.einsum("pk,pk->p", scene.axis_v, rel)[None, :] + t * (dirs @ scene.axis_v.T)
    ok = (t > 1e-9) & (u >= 0) & (u <= scene.size_m[:, 0]) & (v >= 0) & (v <= scene.size_m[:, 1])
    for i in np.nonzero(scene.is_sign)[0]:
        ok[:, i] &= _inside_outline(scene, i, u[:, i], v[:, i])
    t = np.where(ok, t, np.inf)
    best = np.argmin(t, axis=1) if t.shape[1] else np.zeros(len(dirs), int)
    t_best = t[np.arange(len(dirs)), best] if t.shape[1] else np.full(len(dirs), np.inf)
    ids = np.where(np.isfinite(t_best), best, SKY_ID)
    if not ignore_ground:
        with np.errstate(divide="ignore", invalid="ignore"):
            tg = np.where(dirs[:, 2] < 0, -origin_enu[2] / dirs[:, 2], np.inf)
        ids = np.where(tg < t_best, GROUND_ID, ids)
        t_best = np.minimum(tg, t_best)
    return t_best, ids
