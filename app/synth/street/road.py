"""The road centreline of a synthetic world: straights joined by circular arcs, in the ground plane.

Coordinates are local ENU metres (x east, y north); headings are radians counter-clockwise from
east, unwrapped (a loop ends at start + 2 pi). Arc length ``s_m = 0`` is the ENU origin; an open
road also extends ``lead_m`` before it so the scenery behind the first camera position exists.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SAMPLE_STEP_M = 0.1
MIN_STRAIGHT_M = 12.0  # before the first and after the last turn (and between, unless given)
TurnSpecs = tuple[tuple[float, float], ...]  # (signed angle_deg, radius_m); positive turns left


@dataclass(frozen=True)
class Road:
    xy_enu: np.ndarray  # (M, 2) centreline samples every SAMPLE_STEP_M, metres
    heading_rad: np.ndarray  # (M,) unwrapped tangent direction
    s_m: np.ndarray  # (M,) arc length of each sample (starts at -lead_m for an open road)
    closed: bool  # a loop: arc length wraps modulo length_m
    straights_m: tuple[tuple[float, float], ...]  # (s_start, s_end) of every straight
    turns_m: tuple[tuple[float, float], ...]  # (s_start, s_end) of every arc

    @property
    def length_m(self) -> float:
        return float(self.s_m[-1] - self.s_m[0])

    def wrap(self, s_m) -> np.ndarray:
        s = np.asarray(s_m, dtype=float)
        return np.mod(s - self.s_m[0], self.length_m) + self.s_m[0] if self.closed else s

    def at(self, s_m) -> tuple[np.ndarray, np.ndarray]:
        """Centreline points (K, 2) and headings (K,) at arc lengths ``s_m`` (K,)."""
        s_raw = np.atleast_1d(np.asarray(s_m, dtype=float))
        s = self.wrap(s_raw)
        s_all = self.s_m
        xy = np.column_stack([np.interp(s, s_all, self.xy_enu[:, 0]),
                              np.interp(s, s_all, self.xy_enu[:, 1])])
        heading = np.interp(s, s_all, self.heading_rad)
        if self.closed:  # keep the heading continuous from one lap to the next
            laps = np.floor((s_raw - s_all[0]) / self.length_m)
            heading = heading + laps * (self.heading_rad[-1] - self.heading_rad[0])
        return xy, heading

    def offset(self, s_m, right_m) -> np.ndarray:
        """Points ``right_m`` metres to the right of the driving direction at ``s_m``, (K, 2)."""
        xy, heading = self.at(s_m)
        right = np.column_stack([np.sin(heading), -np.cos(heading)])
        return xy + np.asarray(right_m, dtype=float).reshape(-1, 1) * right


def min_travel_m(turns: int, loop: bool, turn_specs: TurnSpecs | None = None,
                 turn_gaps_m: tuple[float, ...] | None = None) -> float:
    """The shortest ``travel_m`` that ``build_road`` accepts for any seed."""
    if loop:
        return 4 * 20.0 * math.pi / 2 + 4 * 15.0
    if turn_specs is not None:
        arcs_m = sum(abs(math.radians(a)) * r for a, r in turn_specs)
        if turn_gaps_m is None:
            return arcs_m + MIN_STRAIGHT_M * (len(turn_specs) + 1)
        return arcs_m + sum(turn_gaps_m) + 2 * MIN_STRAIGHT_M
    return turns * 20.0 * math.radians(100.0) + 12.0 * (turns + 1)


def _integrate(segments: list[tuple[float, float]], heading0: float, start_xy: np.ndarray,
               s0: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample a chain of (length_m, curvature_per_m) pieces; returns xy, heading, s."""
    xys, hs, ss = [start_xy[None, :]], [np.array([heading0])], [np.array([s0])]
    xy, h, s = start_xy.astype(float), heading0, s0
    for length, kappa in segments:
        n = max(1, int(math.ceil(length / SAMPLE_STEP_M)))
        ds = np.linspace(0.0, length, n + 1)[1:]
        hh = h + kappa * ds
        if kappa == 0.0:
            pts = xy + ds[:, None] * np.array([math.cos(h), math.sin(h)])
        else:
            pts = xy + np.column_stack([np.sin(hh) - math.sin(h), math.cos(h) - np.cos(hh)]) / kappa
        xys.append(pts)
        hs.append(hh)
        ss.append(s + ds)
        xy, h, s = pts[-1], float(hh[-1]), float(s + length)
    return np.vstack(xys), np.concatenate(hs), np.concatenate(ss)


def build_road(rng: np.random.Generator, turns: int, loop: bool, travel_m: float,
               margin_m: float = 60.0, lead_m: float = 20.0, turn_specs: TurnSpecs | None = None,
               turn_gaps_m: tuple[float, ...] | None = None) -> Road:
    """A road whose first ``travel_m`` metres hold ``turns`` turns spread between straights.

    The open road continues ``margin_m`` past ``travel_m`` (the camera must see scenery ahead at the
    end of its journey). A loop is a rounded rectangle of four same-direction 90 degree turns whose
    perimeter is ``travel_m``: a journey of that length comes back to its start.

    ``turn_specs`` replaces the random ~90 degree turns by the given arcs; ``turn_gaps_m`` (one per
    pair of consecutive turns, 0 = arcs back to back as in a roundabout) fixes the straights between
    them, else all straights share what the arcs leave of ``travel_m``.
    """
    heading0 = float(rng.uniform(0.0, 2.0 * math.pi))
    if turn_specs is not None:
        if loop:
            raise ValueError("turn_specs and loop cannot be combined")
        return _road_from_specs(rng, heading0, turn_specs, turn_gaps_m, travel_m, margin_m, lead_m)
    if loop:
        radius = float(rng.uniform(12.0, 20.0))
        arc = radius * math.pi / 2.0
        sides = travel_m - 4.0 * arc
        if sides < 4 * 15.0:
            raise ValueError(f"a loop needs >= {4 * arc + 60:.0f} m of travel, "
                             f"got {travel_m:.0f} m")
        sgn = 1.0 if rng.random() < 0.5 else -1.0
        a = sides / 2.0 * float(rng.uniform(0.4, 0.6))
        b = sides / 2.0 - a
        # Start in the middle of a side so the turns are not at the journey's ends.
        pieces = [(a / 2, 0.0), (arc, sgn / radius), (b, 0.0), (arc, sgn / radius), (a, 0.0),
                  (arc, sgn / radius), (b, 0.0), (arc, sgn / radius), (a / 2, 0.0)]
        xy, heading, s = _integrate(pieces, heading0, np.zeros(2), 0.0)
        return _with_spans(xy, heading, s, pieces, 0.0, closed=True)
    if turns < 0:
        raise ValueError("turns must be >= 0")
    radii = rng.uniform(12.0, 20.0, size=turns)
    angles = np.radians(rng.uniform(80.0, 100.0, size=turns))
    signs = np.where(rng.random(turns) < 0.5, 1.0, -1.0)
    arcs = radii * angles
    straight_total = travel_m - float(arcs.sum())
    if straight_total < 12.0 * (turns + 1):
        raise ValueError(f"{travel_m:.0f} m of travel is too short for {turns} turns")
    weights = rng.uniform(0.8, 1.2, size=turns + 1)
    straights = straight_total * weights / weights.sum()
    straights[0] += lead_m
    straights[-1] += margin_m
    pieces: list[tuple[float, float]] = []
    for i in range(turns):
        pieces += [(float(straights[i]), 0.0), (float(arcs[i]), float(signs[i] / radii[i]))]
    pieces.append((float(straights[-1]), 0.0))
    back = -lead_m * np.array([math.cos(heading0), math.sin(heading0)])
    xy, heading, s = _integrate(pieces, heading0, back, -lead_m)
    return _with_spans(xy, heading, s, pieces, -lead_m, closed=False)


def _road_from_specs(rng, heading0, turn_specs, turn_gaps_m, travel_m, margin_m, lead_m) -> Road:
    n = len(turn_specs)
    angles = np.radians([a for a, _ in turn_specs])
    radii = np.array([r for _, r in turn_specs], float)
    if np.any(radii <= 0) or np.any(angles == 0):
        raise ValueError("every turn needs a radius > 0 and a non-zero angle")
    arcs = radii * np.abs(angles)
    if travel_m < min_travel_m(n, False, turn_specs, turn_gaps_m) - 1e-9:
        raise ValueError(f"{travel_m:.0f} m of travel is too short for turns {turn_specs}")
    if turn_gaps_m is None:
        weights = rng.uniform(0.8, 1.2, size=n + 1)
        straights = (travel_m - float(arcs.sum())) * weights / weights.sum()
    else:
        if len(turn_gaps_m) != max(n - 1, 0):
            raise ValueError("turn_gaps_m needs one gap per pair of consecutive turns")
        ends = (travel_m - float(arcs.sum()) - sum(turn_gaps_m)) * rng.uniform(0.4, 0.6)
        rest = travel_m - float(arcs.sum()) - sum(turn_gaps_m) - ends
        straights = np.array([ends, *turn_gaps_m, rest], float)
    straights[0] += lead_m
    straights[-1] += margin_m
    pieces: list[tuple[float, float]] = []
    for i in range(n):
        if straights[i] > 0:  # a zero gap joins two arcs directly
            pieces.append((float(straights[i]), 0.0))
        pieces.append((float(arcs[i]), float(np.sign(angles[i]) / radii[i])))
    pieces.append((float(straights[-1]), 0.0))
    back = -lead_m * np.array([math.cos(heading0), math.sin(heading0)])
    xy, heading, s = _integrate(pieces, heading0, back, -lead_m)
    return _with_spans(xy, heading, s, pieces, -lead_m, closed=False)


def _with_spans(xy, heading, s, pieces, s0, closed) -> Road:
    straights, turns = [], []
    for length, kappa in pieces:
        (turns if kappa else straights).append((s0, s0 + length))
        s0 += length
    return Road(xy_enu=xy, heading_rad=heading, s_m=s, closed=closed,
                straights_m=tuple(straights), turns_m=tuple(turns))
