"""A deterministic synthetic street from a seed: road, textured buildings and props, a textured
ground, and traffic signs with their ground truth. Local ENU metres, z up."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from shapely import LineString

from app.synth.street import textures
from app.synth.street.layout import Layout, layout_world
from app.synth.street.road import Road, TurnSpecs, build_road

REPEATED_FACADES = 3  # distinct textures when facades repeat
FACADE_TEXEL_M = 0.03
GROUND_TEXEL_M = 0.05
SIGN_TEXEL_M = 0.008
GROUND_MARGIN_M = 45.0
_SUN = np.array([0.45, -0.6, 0.66]) / np.linalg.norm([0.45, -0.6, 0.66])


@dataclass(frozen=True)
class WorldSpec:
    """Everything a world depends on: equal specs give identical worlds."""

    world_seed: int = 0
    turns: int = 1
    loop: bool = False
    travel_m: float = 96.0  # length of road the journeys are meant to drive, from arc length 0
    n_signs: int | None = None  # default: one per ~10 m of travel, at least 8
    low_texture: bool = False
    turn_specs: TurnSpecs | None = None  # explicit (angle_deg, radius_m) turns, see build_road
    turn_gaps_m: tuple[float, ...] | None = None
    density: float = 0.5  # 0 sparse suburb .. 1 dense city (layout.layout_world)
    repeated_facades: bool = False  # a few facade textures shared by every building wall


@dataclass(frozen=True)
class Surface:
    """A textured planar rectangle: points ``origin + u * axis_u + v * axis_v``, 0<=u<=w, 0<=v<=h.

    ``texture`` indexes ``World.textures`` (grey) or, for a sign plate, ``World.sign_faces``.
    """

    origin_enu: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    size_m: tuple[float, float]
    texel_m: float
    texture: int
    tint_bgr: tuple[float, float, float]
    sign: int = -1  # index into World.signs for a sign's plate
    shape: str = "rect"
    pole_of: int = -1  # index into World.signs for the faces of a sign's pole


@dataclass(frozen=True)
class SignTruth:
    sign_id: str
    cls: str
    shape: str  # "square", "round", "octagon", "triangle", "diamond"
    size_m: float
    centre_enu: np.ndarray  # (3,) plate centre: the ground-truth position
    normal_enu: np.ndarray  # (3,) the direction the face looks at
    axis_u_enu: np.ndarray  # (3,) right on the face, as seen by its viewer
    s_m: float
    lateral_m: float

    def outline_enu(self) -> np.ndarray:
        """Points on the plate's rim, (K, 3) ENU metres."""
        uv = textures.sign_outline(self.shape, self.size_m)
        return self.centre_enu + uv[:, :1] * self.axis_u_enu + uv[:, 1:] * np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class Ground:
    origin_xy: np.ndarray  # ENU of texel (0, 0)'s corner; texture rows go north, columns east
    texel_m: float
    texture: int


@dataclass
class World:
    spec: WorldSpec
    road: Road
    surfaces: list[Surface]
    textures: list[np.ndarray]  # grey uint8 images
    sign_faces: list[np.ndarray]  # BGR uint8 images
    signs: list[SignTruth]
    ground: Ground


def _rngs(spec: WorldSpec) -> list[np.random.Generator]:
    return [np.random.default_rng(s) for s in np.random.SeedSequence(spec.world_seed).spawn(6)]


def _road(spec: WorldSpec, rng: np.random.Generator) -> Road:
    return build_road(rng, spec.turns, spec.loop, spec.travel_m, turn_specs=spec.turn_specs,
                      turn_gaps_m=spec.turn_gaps_m)


def road_for(spec: WorldSpec) -> Road:
    """The road ``build_world(spec)`` builds, without the (slow) rest of the world."""
    return _road(spec, _rngs(spec)[0])


def build_world(spec: WorldSpec) -> World:
    rngs = _rngs(spec)
    road = _road(spec, rngs[0])
    n_signs = spec.n_signs if spec.n_signs is not None else max(8, int(round(spec.travel_m / 10)))
    layout = layout_world(rngs[1], rngs[2], rngs[3], road, spec.travel_m, n_signs, spec.density)
    world = World(spec=spec, road=road, surfaces=[], textures=[], sign_faces=[], signs=[],
                  ground=Ground(np.zeros(2), GROUND_TEXEL_M, -1))
    _add_walls(world, layout, rngs[4])
    _add_signs(world, layout, rngs[4])
    world.ground = _ground(world, rngs[5])
    return world


def _tint(rng, normal: np.ndarray, kind: str) -> tuple[float, float, float]:
    # Lambert shading keeps walls of different orientation apart; the hue varies per building.
    light = 0.55 + 0.45 * abs(float(normal @ _SUN))
    hue = rng.uniform(0.8, 1.15, 3) if kind != "pole" else np.full(3, rng.uniform(0.6, 0.9))
    return tuple(float(x) for x in light * hue)


def _shared_facades(world: World, layout: Layout, rng) -> list[int]:
    """Texture indices of a few facades big enough for every near wall. A wall shows its
    texture's top-left part, so walls of one building line look alike: repeated structure."""
    near = [w for w in layout.walls if w.kind in ("front", "side", "back")]
    if not near:
        return []
    width = max(float(np.linalg.norm(w.b_xy - w.a_xy)) for w in near)
    height = max(w.z1_m - w.z0_m for w in near)
    for _ in range(REPEATED_FACADES):
        world.textures.append(textures.facade_texture(rng, width, height, FACADE_TEXEL_M,
                                                      world.spec.low_texture))
    return list(range(len(world.textures) - REPEATED_FACADES, len(world.textures)))


def _add_walls(world: World, layout: Layout, rng) -> None:
    low = world.spec.low_texture
    shared = _shared_facades(world, layout, rng) if world.spec.repeated_facades else []
    for k, wall in enumerate(layout.walls):
        ab = wall.b_xy - wall.a_xy
        width = float(np.linalg.norm(ab))
        if width < 1e-3:
            continue
        axis_u = np.array([ab[0] / width, ab[1] / width, 0.0])
        axis_v = np.array([0.0, 0.0, 1.0])
        height = wall.z1_m - wall.z0_m
        texel = FACADE_TEXEL_M if wall.kind != "far" else 2 * FACADE_TEXEL_M
        if shared and wall.kind in ("front", "side", "back"):
            texture = shared[k % len(shared)]
        else:
            world.textures.append(textures.facade_texture(rng, width, height, texel, low)
                                  if wall.kind in ("front", "side", "back", "far")
                                  else textures.surface_texture(rng, width, height, texel, low))
            texture = len(world.textures) - 1
        world.surfaces.append(Surface(
            origin_enu=np.array([wall.a_xy[0], wall.a_xy[1], wall.z0_m]), axis_u=axis_u,
            axis_v=axis_v, size_m=(width, height), texel_m=texel, texture=texture,
            tint_bgr=_tint(rng, np.cross(axis_u, axis_v), wall.kind)))
    for roof in layout.roofs:
        w, d = float(np.linalg.norm(roof.u_xy)), float(np.linalg.norm(roof.v_xy))
        world.textures.append(textures.surface_texture(rng, w, d, FACADE_TEXEL_M, low))
        world.surfaces.append(Surface(
            origin_enu=np.array([roof.corner_xy[0], roof.corner_xy[1], roof.z_m]),
            axis_u=np.array([*roof.u_xy / w, 0.0]), axis_v=np.array([*roof.v_xy / d, 0.0]),
            size_m=(w, d), texel_m=FACADE_TEXEL_M, texture=len(world.textures) - 1,
            tint_bgr=_tint(rng, np.array([0.0, 0.0, 1.0]), "prop")))


def _add_signs(world: World, layout: Layout, rng) -> None:
    up = np.array([0.0, 0.0, 1.0])
    for placement in layout.signs:
        shape = textures.SIGN_STYLES[placement.cls][0]
        axis_u = np.cross(-placement.normal_enu, up)
        sign = SignTruth(sign_id=placement.sign_id, cls=placement.cls, shape=shape,
                         size_m=placement.size_m, centre_enu=placement.centre_enu,
                         normal_enu=placement.normal_enu, axis_u_enu=axis_u, s_m=placement.s_m,
                         lateral_m=placement.lateral_m)
        world.signs.append(sign)
        world.sign_faces.append(
            textures.sign_texture(placement.cls, placement.size_m, SIGN_TEXEL_M))
        half = placement.size_m / 2.0
        world.surfaces.append(Surface(
            origin_enu=placement.centre_enu - half * axis_u - half * up, axis_u=axis_u, axis_v=up,
            size_m=(placement.size_m, placement.size_m), texel_m=SIGN_TEXEL_M,
            texture=len(world.sign_faces) - 1, tint_bgr=(1.0, 1.0, 1.0),
            sign=len(world.signs) - 1, shape=shape))
        # The pole: a thin square post just behind the plate, up to the plate's centre.
        foot = placement.centre_enu[:2] - 0.06 * placement.normal_enu[:2]
        a_u, a_n = 0.035 * axis_u[:2], 0.035 * placement.normal_enu[:2]
        corners = [foot - a_u - a_n, foot + a_u - a_n, foot + a_u + a_n, foot - a_u + a_n]
        world.textures.append(textures.surface_texture(rng, 0.07, placement.centre_enu[2],
                                                       FACADE_TEXEL_M, world.spec.low_texture))
        for i in range(4):
            a, b = corners[i], corners[(i + 1) % 4]
            world.surfaces.append(Surface(
                origin_enu=np.array([a[0], a[1], 0.0]), axis_u=np.array([*(b - a) / 0.07, 0.0]),
                axis_v=up, size_m=(0.07, float(placement.centre_enu[2])), texel_m=FACADE_TEXEL_M,
                texture=len(world.textures) - 1, tint_bgr=(0.75, 0.75, 0.75),
                pole_of=len(world.signs) - 1))


def _ground(world: World, rng) -> Ground:
    xy = world.road.xy_enu
    lo = xy.min(axis=0) - GROUND_MARGIN_M
    hi = xy.max(axis=0) + GROUND_MARGIN_M
    w, h = (np.ceil((hi - lo) / GROUND_TEXEL_M)).astype(int)
    centre = LineString(xy[::5])
    mask = np.zeros((h, w), np.uint8)
    road_area = centre.buffer(3.6)
    for poly in getattr(road_area, "geoms", [road_area]):
        cv2.fillPoly(mask, [_to_texels(np.asarray(poly.exterior.coords), lo)], 1)
        for hole in poly.interiors:
            cv2.fillPoly(mask, [_to_texels(np.asarray(hole.coords), lo)], 0)
    img = textures.ground_texture(rng, h, w, mask, GROUND_TEXEL_M, world.spec.low_texture)
    # Solid edge lines: continuous, so they add no repeating pattern along the road.
    edges = centre.buffer(3.3)
    for poly in getattr(edges, "geoms", [edges]):
        rings = [poly.exterior, *poly.interiors]
        cv2.polylines(img, [_to_texels(np.asarray(r.coords), lo) for r in rings], True, 215,
                      max(1, int(round(0.12 / GROUND_TEXEL_M))), cv2.LINE_AA)
    world.textures.append(img)
    return Ground(origin_xy=lo, texel_m=GROUND_TEXEL_M, texture=len(world.textures) - 1)


def _to_texels(xy: np.ndarray, lo: np.ndarray) -> np.ndarray:
    return np.round((xy - lo) / GROUND_TEXEL_M).astype(np.int32)
