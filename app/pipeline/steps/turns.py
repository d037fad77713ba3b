"""Find the turns of a journey on its metric GPS track (the paper's Ramer-Douglas-Peucker step).

Self-calibration is ill-posed under pure forward translation, so calibration uses the stretches of
track where the car turns. The track is simplified with shapely's Douglas-Peucker
(``simplify(preserve_topology=False)``); the corners of the simplified polyline are the turns.

Input everywhere: ``xy_m``, shape (N, 2), one metric position per frame (ENU east, north, metres),
in frame order. Heading changes are signed, left (counter-clockwise seen from above) positive.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from scipy.ndimage import gaussian_filter1d
from shapely.geometry import LineString


@dataclass(frozen=True)
class TurnWindow:
    start: int  # first frame index (inclusive)
    end: int  # last frame index (exclusive)
    vertex: int  # frame index of the RDP vertex (the turn)
    angle_deg: float  # heading change at that vertex (signed, left positive)
    # Sum of |heading changes| of the turns in the window: differs from |angle_deg| when merged
    # turns of opposite directions (an S-bend) cancel in angle_deg but still rotate the camera.
    rotation_deg: float = 0.0
    # Track length between the first and the last corner of the turn (0 for a single corner): a
    # wide curve turns over this much road, and a window of fixed length sees only part of it.
    curve_m: float = 0.0


# GPS jitter of a standing car that exceeds the tolerance survives simplification as a knot of
# corners joined by segments a few metres long; real streets have longer straight pieces.
_MIN_SEGMENT_TOLERANCES = 4.0


@dataclass(frozen=True)
class _Track:
    """The simplified track: ``vertex_idx`` (K,) frame indices of its vertices, ``turn_deg`` (K,)
    signed heading change at each vertex (0 at both ends), ``s_m`` (N,) track length of each
    frame."""

    vertex_idx: np.ndarray
    turn_deg: np.ndarray
    s_m: np.ndarray


def _simplify(xy_m: np.ndarray, tolerance_m: float) -> _Track:
    xy_m = np.asarray(xy_m, dtype=float).reshape(-1, 2)
    n = len(xy_m)
    if n < 2:
        return _Track(np.arange(n), np.zeros(n), np.zeros(n))
    # Thinning to one point per quarter tolerance drops the repeated positions of a stopped car
    # (zero-length segments) but keeps corner points in place, which thinning by the full
    # tolerance would cut.
    thinned = shapely.remove_repeated_points(LineString(xy_m), tolerance=0.25 * tolerance_m)
    simple = thinned.simplify(tolerance_m, preserve_topology=False)
    vertex_idx = _collapse_jitter(xy_m, _match_indices(xy_m, np.asarray(simple.coords)),
                                  _MIN_SEGMENT_TOLERANCES * tolerance_m)
    if len(vertex_idx) < 2:
        return _Track(vertex_idx, np.zeros(len(vertex_idx)), np.zeros(n))

    seg = np.diff(xy_m[vertex_idx], axis=0)
    heading = np.arctan2(seg[:, 1], seg[:, 0])
    turn = np.angle(np.exp(1j * np.diff(heading)))  # wrapped to (-pi, pi]
    turn_deg = np.concatenate([[0.0], np.degrees(turn), [0.0]])
    return _Track(vertex_idx, turn_deg, _track_length(xy_m, vertex_idx))


def _collapse_jitter(xy_m: np.ndarray, vertex_idx: np.ndarray, min_segment_m: float) -> np.ndarray:
    """Replace each chain of interior vertices joined by segments shorter than ``min_segment_m``
    with its middle vertex (the headings in and out of the knot then carry its net turn); a
    chain attached to either end of the track is dropped."""
    k_last = len(vertex_idx) - 1
    if k_last < 2:
        return vertex_idx
    seg_len = np.linalg.norm(np.diff(xy_m[vertex_idx], axis=0), axis=1)
    keep = [0]
    k = 1
    while k < k_last:
        j = k
        while j + 1 < k_last and seg_len[j] < min_segment_m:
            j += 1
        at_start = k == 1 and seg_len[0] < min_segment_m
        at_end = j == k_last - 1 and seg_len[k_last - 1] < min_segment_m
        if not (at_start or at_end):
            keep.append((k + j) // 2)
        k = j + 1
    keep.append(k_last)
    return vertex_idx[keep]


def _match_indices(xy_m: np.ndarray, coords: np.ndarray) -> np.ndarray:
    """Frame index of each simplified vertex. Douglas-Peucker keeps a subset of the input points in
    order, so an in-order exact match is unambiguous even when the track revisits a place."""
    out: list[int] = []
    i = 0
    for c in coords:
        while i < len(xy_m) and not (xy_m[i, 0] == c[0] and xy_m[i, 1] == c[1]):
            i += 1
        if i == len(xy_m):
            break
        out.append(i)
        i += 1
    return np.asarray(out, dtype=int)


def _track_length(xy_m: np.ndarray, vertex_idx: np.ndarray) -> np.ndarray:
    """Track length (N,) of every frame, measured along the simplified polyline.

    Each frame is projected onto the simplified segment it belongs to, so GPS noise and standstill
    jitter add no length; the running maximum keeps the result monotone."""
    n = len(xy_m)
    a, b = xy_m[vertex_idx[:-1]], xy_m[vertex_idx[1:]]
    seg_len = np.linalg.norm(b - a, axis=1)
    seg_start_m = np.concatenate([[0.0], np.cumsum(seg_len)])
    # Frames before the first / after the last vertex belong to the first / last segment.
    k = np.clip(np.searchsorted(vertex_idx, np.arange(n), side="right") - 1, 0, len(seg_len) - 1)
    d = (b - a)[k]
    safe_len = np.where(seg_len[k] > 0, seg_len[k], 1.0)
    along = np.einsum("ij,ij->i", xy_m - a[k], d) / safe_len
    s = seg_start_m[k] + np.clip(along, 0.0, seg_len[k])
    return np.maximum.accumulate(s)


def _bends(track: _Track, window_m: float) -> list[list[int]]:
    """Group consecutive interior vertices of one turning direction closer than window_m in track
    length: a smooth curve simplifies into several small corners that together make one turn."""
    groups: list[list[int]] = []
    s_v = track.s_m[track.vertex_idx]
    for k in range(1, len(track.vertex_idx) - 1):
        t = track.turn_deg[k]
        if t == 0.0:
            continue
        if groups:
            last = groups[-1][-1]
            if np.sign(track.turn_deg[last]) == np.sign(t) and s_v[k] - s_v[last] <= window_m:
                groups[-1].append(k)
                continue
        groups.append([k])
    return groups


def find_turns(xy_m: np.ndarray, *, tolerance_m: float = 2.0, min_angle_deg: float = 30.0,
               window_m: float = 40.0) -> list[TurnWindow]:
    """Turn windows of a track ``xy_m`` (N, 2) ENU metres per frame, sorted by |angle| descending.

    A corner of the simplified track (or a run of same-direction corners within ``window_m`` of
    each other, i.e. a smooth curve, whose vertex is then its middle frame) is a turn when its
    heading change reaches ``min_angle_deg``.
    Its window holds the frames within ``window_m`` of track length before its first and after its
    last corner; overlapping windows are merged (angles summed, vertex and curve length of the
    larger turn kept).
    """
    track = _simplify(xy_m, tolerance_m)
    n = len(track.s_m)
    s_v = track.s_m[track.vertex_idx]
    windows: list[TurnWindow] = []
    for group in _bends(track, window_m):
        angle = float(np.sum(track.turn_deg[group]))
        if abs(angle) < min_angle_deg:
            continue
        lo_m, hi_m = s_v[group[0]] - window_m, s_v[group[-1]] + window_m
        start = int(np.searchsorted(track.s_m, lo_m, side="left"))
        end = int(np.searchsorted(track.s_m, hi_m, side="right"))
        if len(group) == 1:
            vertex = int(track.vertex_idx[group[0]])
        else:  # a curve: its middle, by track length
            mid_m = 0.5 * (s_v[group[0]] + s_v[group[-1]])
            vertex = int(np.searchsorted(track.s_m, mid_m, side="left"))
        rotation = float(np.sum(np.abs(track.turn_deg[group])))
        windows.append(TurnWindow(start, min(end, n), vertex, angle, rotation,
                                  float(s_v[group[-1]] - s_v[group[0]])))

    merged: list[TurnWindow] = []
    for w in windows:  # already in track order
        if merged and w.start < merged[-1].end:
            prev = merged[-1]
            larger = prev if abs(prev.angle_deg) >= abs(w.angle_deg) else w
            merged[-1] = TurnWindow(prev.start, max(prev.end, w.end), larger.vertex,
                                    prev.angle_deg + w.angle_deg,
                                    prev.rotation_deg + w.rotation_deg, larger.curve_m)
        else:
            merged.append(w)
    return sorted(merged, key=lambda w: -abs(w.angle_deg))


def smooth_track(xy_m: np.ndarray, timestamp_s: np.ndarray, sigma_s: float,
                 max_sigma_m: float | None = None, *, extend_ends: bool = False) -> np.ndarray:
    """``xy_m`` (N, 2) smoothed by a Gaussian of ``sigma_s`` seconds, or of ``max_sigma_m`` metres
    of the journey's mean speed when that is shorter (frames may be unevenly timed: the kernel
    width is taken at their median interval).

    A phone-grade receiver (1-3 m of white noise) zigzags by more than the RDP tolerance: on a
    corpus of 42 journeys the raw tracks showed up to 857 deg of "turning" on straight roads and
    none on a real 89 deg turn; smoothed over 1 s, the found rotation followed the true one
    (docs/decisions/turn-finding.md). A turn keeps its heading change, spread over a few more
    metres. At speed, one second is many metres: a 51 deg turn at 18 m/s on an 80 m journey
    (corpus c0058) flattened to 28 deg; ``max_sigma_m`` (None or 0: no cap) caps the width in
    metres, at the price of less smoothing of phone-grade noise at speed
    (``config.turn_smoothing_max_m``: at 6 m that noise made turns on straight roads, at 12 m it
    did not).

    The kernel is padded with copies of the end points, which pulls the first and last 4 sigma
    of track towards them; ``extend_ends`` pads with the track continued along its heading
    instead (``_extend_linearly``), which keeps a turn in the journey's last second."""
    xy_m = np.asarray(xy_m, dtype=float).reshape(-1, 2)
    timestamp_s = np.asarray(timestamp_s, dtype=float)
    if sigma_s <= 0 or len(xy_m) < 3:
        return xy_m
    dt_s = float(np.median(np.diff(timestamp_s)))
    if dt_s <= 0:
        return xy_m
    duration_s = float(timestamp_s[-1] - timestamp_s[0])
    if max_sigma_m and duration_s > 0:
        mean_speed_mps = float(track_length_m(xy_m)[-1]) / duration_s
        if mean_speed_mps > 0:
            sigma_s = min(sigma_s, max_sigma_m / mean_speed_mps)
    sigma_frames = sigma_s / dt_s
    if not extend_ends:
        return gaussian_filter1d(xy_m, sigma_frames, axis=0, mode="nearest")
    pad = int(np.ceil(4.0 * sigma_frames))  # gaussian_filter1d's reach (truncate=4)
    padded = _extend_linearly(xy_m, pad)
    return gaussian_filter1d(padded, sigma_frames, axis=0)[pad:pad + len(xy_m)]


def _extend_linearly(xy_m: np.ndarray, pad: int) -> np.ndarray:
    """``xy_m`` (N, 2) with ``pad`` points added before and after, on the straight line fitted
    to its first / last ``pad`` points and spaced as they are.

    Padding a smoothing window with copies of the end point (``mode="nearest"``) pulls the last
    second of track towards it: a turn in that second (a journey ending just past its corner,
    c0304 of corpus seed 256, +125 deg at 18 m/s) left a stub shorter than the RDP tolerance and
    the turn was not found. Continuing the track's heading keeps its length. The line is fitted
    over the kernel's whole reach so that the end point's GPS noise does not steer it: fitted
    over one sigma, straight phone-grade tracks (2.5 m at 1 Hz) showed 5 false turns in 180,
    over four none."""
    fit_n = min(pad, len(xy_m))
    if pad <= 0 or fit_n < 2:
        return xy_m

    def beyond(end_part: np.ndarray) -> np.ndarray:
        """``pad`` points continuing ``end_part`` (fit_n, 2) past its last point, nearest first."""
        coef = np.polynomial.polynomial.polyfit(np.arange(fit_n), end_part, 1)  # (2, 2)
        return coef[0] + np.outer(fit_n - 1 + np.arange(1, pad + 1), coef[1])

    return np.concatenate([beyond(xy_m[:fit_n][::-1])[::-1], xy_m, beyond(xy_m[-fit_n:])])


def track_length_m(xy_m: np.ndarray, *, tolerance_m: float = 2.0) -> np.ndarray:
    """(N,) metres travelled at each frame of ``xy_m`` (N, 2), along the simplified track: monotone,
    flat while the car stands, free of the length GPS jitter would add."""
    return _simplify(xy_m, tolerance_m).s_m


def _grid_heading_rad(xy_m: np.ndarray, s_m: np.ndarray, step_m: float, smooth_m: float
                     ) -> tuple[np.ndarray, np.ndarray] | None:
    """(grid_m, heading_rad): the track ``xy_m`` (N, 2) resampled every ``step_m`` of its length
    ``s_m`` (N,), smoothed over ``smooth_m``, and its unwrapped heading there; None for a track
    shorter than two steps."""
    xy_m = np.asarray(xy_m, dtype=float).reshape(-1, 2)
    s_m = np.asarray(s_m, dtype=float)
    if len(xy_m) < 2 or s_m[-1] - s_m[0] < 2 * step_m:
        return None
    first = np.r_[True, np.diff(s_m) > 0]  # one position per track length
    grid_m = np.arange(s_m[0], s_m[-1] + step_m, step_m)
    xy_grid = np.column_stack([np.interp(grid_m, s_m[first], xy_m[first, k]) for k in (0, 1)])
    xy_grid = gaussian_filter1d(xy_grid, smooth_m / step_m, axis=0, mode="nearest")
    return grid_m, np.unwrap(np.arctan2(*np.gradient(xy_grid, axis=0).T[::-1]))


def heading_deg(xy_m: np.ndarray, s_m: np.ndarray, *, step_m: float = 1.0,
                smooth_m: float = 3.0) -> np.ndarray:
    """(N,) signed heading (degrees, counterclockwise from x, unwrapped) at each frame of
    ``xy_m`` (N, 2), taken as ``cumulative_rotation_deg`` takes it; zeros for a too short track."""
    grid = _grid_heading_rad(xy_m, s_m, step_m, smooth_m)
    if grid is None:
        return np.zeros(len(np.asarray(xy_m).reshape(-1, 2)))
    return np.degrees(np.interp(np.asarray(s_m, dtype=float), *grid))


def cumulative_rotation_deg(xy_m: np.ndarray, s_m: np.ndarray, *, step_m: float = 1.0,
                            smooth_m: float = 3.0) -> np.ndarray:
    """(N,) degrees of heading change, whatever the direction, accumulated along ``xy_m`` (N, 2)
    up to each frame; ``s_m`` (N,) is its ``track_length_m``. The heading is taken on the track
    resampled every ``step_m`` of length and smoothed over ``smooth_m``, so a standing car turns
    nothing and a sharp corner turns over the metres it takes, not at one frame."""
    grid = _grid_heading_rad(xy_m, s_m, step_m, smooth_m)
    if grid is None:
        return np.zeros(len(np.asarray(xy_m).reshape(-1, 2)))
    grid_m, heading = grid
    turned = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(heading)))])
    return np.degrees(np.interp(np.asarray(s_m, dtype=float), grid_m, turned))


def total_rotation_deg(xy_m: np.ndarray, *, tolerance_m: float = 2.0) -> float:
    """Sum of |heading changes| (degrees) along the simplified track ``xy_m`` (N, 2): how much
    rotation the journey contains, whatever its direction."""
    return float(np.sum(np.abs(_simplify(xy_m, tolerance_m).turn_deg)))


def chord_heading_deg(xy_m: np.ndarray, s_m: np.ndarray, at_m: np.ndarray,
                      chord_m: float) -> np.ndarray:
    """Heading (degrees, counterclockwise from x, in (-180, 180]) of the chord of ``xy_m``
    (N, 2) from ``at_m - chord_m / 2`` to ``at_m + chord_m / 2`` metres along it, for each of
    ``at_m`` (K,); ``s_m`` (N,) is its ``track_length_m``. On a circular arc the chord's
    direction is the tangent at its middle whatever the curvature, and unlike a smoothed heading
    it does not spread a sharp turn over the smoothing's width."""
    xy_m = np.asarray(xy_m, dtype=float).reshape(-1, 2)
    s_m = np.asarray(s_m, dtype=float)
    at_m = np.atleast_1d(np.asarray(at_m, dtype=float))
    first = np.r_[True, np.diff(s_m) > 0]  # one position per track length
    ends = [np.column_stack([np.interp(at_m + d, s_m[first], xy_m[first, k]) for k in (0, 1)])
            for d in (-chord_m / 2, chord_m / 2)]
    d_xy = ends[1] - ends[0]
    return np.degrees(np.arctan2(d_xy[:, 1], d_xy[:, 0]))


def chord_rotation_deg(xy_m: np.ndarray, s_m: np.ndarray, frame_idx: np.ndarray,
                       chord_m: float) -> float:
    """Largest heading change (degrees, either way) from the chord centred on the first of
    ``frame_idx`` to the chord centred on any other: the GPS's measure of what a reconstruction of
    those frames should turn (``calibrate.rotation_covered_deg`` takes the same largest change)."""
    heading = chord_heading_deg(xy_m, s_m, np.asarray(s_m, dtype=float)[frame_idx], chord_m)
    change = (heading - heading[0] + 180.0) % 360.0 - 180.0
    return float(np.max(np.abs(change)))
