"""Where things stand in a synthetic world: signs, building fronts with side walls, distant
buildings seen through gaps, and isolated props (poles, cabinets, kiosks). Geometry only; the
textures are made in ``app.synth.street.world``. All in local ENU metres, z up."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from shapely import LineString, MultiPoint, Polygon
from shapely.ops import unary_union

from app.synth.street.road import Road

SIGN_CLASSES = ("stop", "yield", "speed_limit_50", "speed_limit_30", "no_entry", "priority",
                "parking")
ROAD_CLEARANCE_M = 4.5  # half a two-lane road plus room for journeys driven off the centreline


@dataclass(frozen=True)
class Wall:
    """A vertical rectangle over the ground segment a->b, from ``z0_m`` up to ``z1_m``."""

    a_xy: np.ndarray
    b_xy: np.ndarray
    z0_m: float
    z1_m: float
    kind: str  # "front", "side", "back", "far", "prop", "pole"


@dataclass(frozen=True)
class Roof:
    """A horizontal rectangle: ``corner_xy`` plus edges ``u_xy`` and ``v_xy`` at height ``z_m``."""

    corner_xy: np.ndarray
    u_xy: np.ndarray
    v_xy: np.ndarray
    z_m: float


@dataclass(frozen=True)
class SignPlacement:
    sign_id: str
    cls: str
    s_m: float  # road arc length of the sign's foot
    lateral_m: float  # metres to the right of the driving direction (negative: left)
    centre_enu: np.ndarray  # (3,) plate centre
    normal_enu: np.ndarray  # (3,) unit, horizontal, towards the traffic the sign faces
    size_m: float


@dataclass(frozen=True)
class Layout:
    signs: list[SignPlacement]
    walls: list[Wall]
    roofs: list[Roof]


def place_signs(rng: np.random.Generator, road: Road, travel_m: float,
                n_signs: int) -> list[SignPlacement]:
    """``n_signs`` signs on the straights of the travelled part, at least two per straight."""
    spans = [(max(a, 6.0), min(b, travel_m - 4.0)) for a, b in road.straights_m]
    spans = [(a, b) for a, b in spans if b - a > 4.0]
    lengths = np.array([b - a for a, b in spans])
    counts = np.maximum(2, np.floor(n_signs * lengths / lengths.sum())).astype(int)
    while counts.sum() < n_signs:
        counts[int(np.argmax(lengths / counts))] += 1
    signs = []
    for (a, b), k in zip(spans, counts):
        slot = (b - a) / k
        for j in range(k):
            s = a + (j + float(rng.uniform(0.2, 0.8))) * slot
            side = 1.0 if rng.random() < 0.75 else -1.0
            lateral = side * float(rng.uniform(3.0, 7.0))
            xy = road.offset([s], [lateral])[0]
            _, heading = road.at([s])
            # Face the approaching traffic, turned a little towards the road.
            yaw = float(heading[0]) + math.pi - side * math.radians(float(rng.uniform(0.0, 15.0)))
            signs.append(SignPlacement(
                sign_id=f"s{len(signs):02d}", cls=str(rng.choice(SIGN_CLASSES)), s_m=float(s),
                lateral_m=lateral,
                centre_enu=np.array([xy[0], xy[1], float(rng.uniform(1.8, 3.0))]),
                normal_enu=np.array([math.cos(yaw), math.sin(yaw), 0.0]),
                size_m=float(rng.uniform(0.6, 0.9))))
    return signs


def _sight_keepout(road: Road, signs: list[SignPlacement]):
    """Where nothing may stand: the wedges between the lanes and each sign, over 3..40 m."""
    wedges = []
    for sg in signs:
        s = np.linspace(sg.s_m - 40.0, sg.s_m - 2.0, 12)
        lane = np.vstack([road.offset(s, np.full(s.shape, off)) for off in (-2.5, 2.5)])
        hull = MultiPoint(np.vstack([lane, sg.centre_enu[None, :2]])).convex_hull
        wedges.append(hull.buffer(0.4))
    return unary_union(wedges)


def density_factors(density: float) -> tuple[float, float]:
    """(scale, gap probability) of a scene ``density`` in 0..1. ``scale`` multiplies building
    heights and divides setbacks and spacings: 0.5 at a sparse suburb, 2 in a dense city. Both are
    exactly today's values (1.0, 0.25) at the default 0.5, so default worlds do not change."""
    scale = 2.0 ** (2.0 * (density - 0.5))
    if density <= 0.5:
        return scale, 0.25 * 2.4 ** (2.0 * (0.5 - density))  # up to 0.6: many gaps
    return scale, 0.25 * 0.2 ** (2.0 * (density - 0.5))  # down to 0.05: a closed street wall


def layout_world(rng_signs, rng_build, rng_props, road: Road, travel_m: float,
                 n_signs: int, density: float = 0.5) -> Layout:
    scale, gap_p = density_factors(density)
    signs = place_signs(rng_signs, road, travel_m, n_signs)
    centre = LineString(road.xy_enu[::10])
    keepout = _sight_keepout(road, signs)
    s_lo, s_hi = road.s_m[0], road.s_m[-1]
    walls, roofs, footprints = [], [], []

    def free(poly, clearance):
        return poly.distance(centre) >= clearance and not poly.intersects(keepout)

    for side in (1.0, -1.0):
        s, prev_d = s_lo - 10.0 * (not road.closed), 8.0
        while s < s_hi:
            if rng_build.random() < gap_p:  # a gap, with a building further back behind it
                gap = float(rng_build.uniform(4.0, 12.0)) / scale
                _back_wall(rng_build, road, s + gap / 2, side, prev_d, free, walls, scale)
                s += gap
                continue
            length = float(rng_build.uniform(10.0, 30.0))
            d = float(rng_build.uniform(5.0, 14.0)) / scale
            height = float(rng_build.uniform(6.0, 15.0)) * scale
            depth = float(rng_build.uniform(6.0, 14.0))
            # A block in the way of a sign or too close to the road steps back, then shrinks.
            for length, d, depth in ((length, d, depth), (length, d + 5.0, depth),
                                     (length / 2, d + 5.0, depth / 2), (length / 4, d, depth / 2)):
                a, b = road.offset([s, s + length], [side * d, side * d])
                out = side * np.array([b[1] - a[1], a[0] - b[0]]) / max(np.linalg.norm(b - a), 1e-9)
                foot = Polygon([a, b, b + depth * out, a + depth * out])
                if free(foot, max(ROAD_CLEARANCE_M, d - 2.0)):
                    walls += [Wall(a, b, 0.0, height, "front"),
                              Wall(a, a + depth * out, 0.0, height, "side"),
                              Wall(b, b + depth * out, 0.0, height, "side")]
                    footprints.append(foot)
                    prev_d = d
                    break
            s += length
        s = s_lo + float(rng_build.uniform(0, 20))
        while s < s_hi:  # a row of tall distant buildings, seen above and between the fronts
            _far_wall(rng_build, road, s, side, free, walls, scale)
            s += float(rng_build.uniform(25.0, 45.0)) / scale
    buildings = unary_union(footprints + [LineString([w.a_xy, w.b_xy]) for w in walls]).buffer(0.3)
    _props(rng_props, road, signs, free, buildings, walls, roofs)
    return Layout(signs=signs, walls=walls, roofs=roofs)


def _back_wall(rng, road, s_mid, side, prev_d, free, walls, scale) -> None:
    d = prev_d + float(rng.uniform(6.0, 20.0)) / scale
    half = float(rng.uniform(5.0, 12.0))
    a, b = road.offset([s_mid - half, s_mid + half], [side * d, side * d])
    if free(LineString([a, b]), 8.0):
        walls.append(Wall(a, b, 0.0, float(rng.uniform(8.0, 20.0)) * scale, "back"))


def _far_wall(rng, road, s, side, free, walls, scale) -> None:
    d = float(rng.uniform(25.0, 45.0))
    half = float(rng.uniform(8.0, 18.0))
    a, b = road.offset([s - half, s + half], [side * d, side * d])
    if free(LineString([a, b]), 15.0):
        walls.append(Wall(a, b, 0.0, float(rng.uniform(10.0, 25.0)) * scale, "far"))


def _props(rng, road, signs, free, buildings, walls, roofs) -> None:
    """Poles, cabinets and kiosks between the road and the buildings, at varied depths."""
    sign_spots = unary_union([MultiPoint([sg.centre_enu[:2]]).buffer(1.2) for sg in signs]) \
        if signs else Polygon()
    for side in (1.0, -1.0):
        s = road.s_m[0] + float(rng.uniform(0.0, 10.0))
        while s < road.s_m[-1]:
            kind = rng.choice(["pole", "pole", "cabinet", "kiosk"])
            if kind == "pole":
                w, dp, h = (float(rng.uniform(0.12, 0.25)),) * 2 + (float(rng.uniform(3.0, 7.0)),)
            elif kind == "cabinet":
                w, dp, h = (float(rng.uniform(0.5, 1.2)), float(rng.uniform(0.3, 0.8)),
                            float(rng.uniform(1.0, 1.8)))
            else:
                w, dp, h = (float(rng.uniform(1.5, 3.0)), float(rng.uniform(1.5, 3.0)),
                            float(rng.uniform(2.3, 3.0)))
            lateral = side * float(rng.uniform(ROAD_CLEARANCE_M + dp / 2, 9.0))
            c = road.offset([s], [lateral])[0]
            _, heading = road.at([s])
            u = np.array([math.cos(heading[0]), math.sin(heading[0])])
            v = np.array([-u[1], u[0]])
            corners = [c - u * w / 2 - v * dp / 2, c + u * w / 2 - v * dp / 2,
                       c + u * w / 2 + v * dp / 2, c - u * w / 2 + v * dp / 2]
            foot = Polygon(corners)
            if free(foot, ROAD_CLEARANCE_M) and not foot.intersects(buildings) \
                    and not foot.intersects(sign_spots):
                for i in range(4):
                    walls.append(Wall(corners[i], corners[(i + 1) % 4], 0.0, h,
                                      "pole" if kind == "pole" else "prop"))
                if kind != "pole":
                    roofs.append(Roof(corners[0], u * w, v * dp, h))
            s += float(rng.uniform(5.0, 14.0))
