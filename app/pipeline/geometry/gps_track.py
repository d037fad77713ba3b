"""Frame positions from GPS fixes by a smoothing spline in time, instead of straight lines between
fixes.

A window's GPS alignment fixes its scale from the spread of its frames' GPS positions; the frames
lie between fixes (1-10 Hz against 5-30 frames/s), so how they are interpolated sets that scale.
Straight lines pass through every fix's noise and cut the corners of a curve: on the corpus's
rendered journeys, the scale of a 70-frame window fitted to linearly interpolated OXTS-like fixes
was off by 0.2-1.9 % rms against the true trajectory (chords alone: 2.8 % at 1 Hz, 17 m/s, 14 m
radius), and by 0.3-1.6 % through a smoothing spline whose smoothing generalised cross-validation
chooses per journey (SciPy's ``make_smoothing_spline``). Frames are in the caller's metric frame
(``xyz`` (N, 3), metres).

``camera_positions`` moves GPS positions from the antenna to the camera. Convention (the
contract's section 1b): the offset is the antenna's position minus the camera's, in the vehicle's
axes: forward = the horizontal direction of travel, up = the local frame's up (z), left = up x
forward; so camera = antenna - (forward_m * forward + left_m * left + up_m * up). The vehicle's
pitch and roll are neglected (a 1 m offset moves by 2 cm at 1 degree).
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import make_smoothing_spline

from app.pipeline.types import AntennaOffset

MIN_FIXES = 5  # what a cubic smoothing spline needs
# Cross-validation costs ~1 s per 1000 fixes per axis and grows faster beyond (122 s for 100 000):
# a long track is smoothed in pieces of this many fixes, each overlapping its neighbours by
# PIECE_OVERLAP fixes so that no frame is near the end of the piece it takes its position from.
PIECE_FIXES = 500
PIECE_OVERLAP = 50
# Cross-validation can take an undersampled curve for noise (fixes 1 s apart on a tight roundabout)
# and flatten it: a spline further from its fixes than this many times their white noise (rms)
# is not believed, and that axis keeps the straight lines. A right smoothing leaves less than one.
MAX_RESIDUAL_NOISE = 2.0
MIN_RESIDUAL_M = 0.05  # ... or than this, for a near-perfect receiver
# Fewer than 10 fixes (a short journey at 1 Hz) tell no noise (``geometry.gps_noise``), yet are where
# lines cut curves the most; cross-validation then mostly interpolates them. Without a noise
# figure, a spline further than this from the fixes (rms) is not believed.
UNKNOWN_NOISE_MAX_RESIDUAL_M = 1.0


def smoothed_positions(t_frame_s: np.ndarray, xyz_linear: np.ndarray, t_fix_s: np.ndarray,
                       xyz_fix: np.ndarray, noise_m: float | None) -> np.ndarray:
    """(N, 3) frame positions: inside the fixes' time span, a smoothing spline through the fixes
    ``xyz_fix`` (M, 3) at ``t_fix_s`` (M,), per axis; outside it, ``xyz_linear`` (N, 3) (the
    linear interpolation and end extrapolation the bundle reader gave) shifted to meet the spline
    at the end fix. ``noise_m``: the fixes' white noise per axis (``geometry.gps_noise``; None:
    unknown). An axis with a non-finite fix (altitude missing) or whose spline strays from the
    fixes (MAX_RESIDUAL_NOISE, UNKNOWN_NOISE_MAX_RESIDUAL_M) keeps ``xyz_linear``; fewer than
    MIN_FIXES fixes keep it all."""
    out = np.array(xyz_linear, dtype=float, copy=True)
    if len(t_fix_s) < MIN_FIXES:
        return out
    before, after = t_frame_s < t_fix_s[0], t_frame_s > t_fix_s[-1]
    # East and north are believed together or not at all: a path is not half a spline. GPS
    # altitude scatters about twice as much as the horizontal position.
    for axes, noise_factor in (((0, 1), 1.0), ((2,), 2.0)):
        values = xyz_fix[:, axes]
        if not np.all(np.isfinite(values)):
            continue
        splines = [(make_smoothing_spline(t_fix_s[a:b], values[a:b, k]), k, (a, b), span)
                   for k in range(len(axes)) for (a, b), span in _pieces(t_fix_s)]
        max_residual_m = (UNKNOWN_NOISE_MAX_RESIDUAL_M if noise_m is None else
                          max(MAX_RESIDUAL_NOISE * noise_factor * noise_m, MIN_RESIDUAL_M))
        if any(np.sqrt(np.mean((spline(t_fix_s[a:b]) - values[a:b, k]) ** 2)) > max_residual_m
               for spline, k, (a, b), _ in splines):
            continue
        for spline, k, (a, b), (t_from, t_to) in splines:
            axis = axes[k]
            mine = (t_frame_s >= t_from) & (t_frame_s <= t_to)
            out[mine, axis] = spline(t_frame_s[mine])
            if a == 0:
                out[before, axis] += spline(t_fix_s[0]) - values[0, k]
            if b == len(t_fix_s):
                out[after, axis] += spline(t_fix_s[-1]) - values[-1, k]
    return out


def _pieces(t_fix_s: np.ndarray) -> list[tuple[tuple[int, int], tuple[float, float]]]:
    """((first, stop) fix indices of a piece, (from, to) the time span whose frames it places),
    covering the fixes' span once."""
    m = len(t_fix_s)
    if m <= PIECE_FIXES + 2 * PIECE_OVERLAP:
        return [((0, m), (t_fix_s[0], t_fix_s[-1]))]
    out = []
    for core in range(0, m - 1, PIECE_FIXES):
        stop = min(m - 1, core + PIECE_FIXES)
        a, b = max(0, core - PIECE_OVERLAP), min(m, stop + 1 + PIECE_OVERLAP)
        if b - a < MIN_FIXES:  # a last sliver of a core: widen it back
            a = max(0, b - PIECE_FIXES)
        out.append(((a, b), (t_fix_s[core], t_fix_s[stop])))
    return out


def in_dropout(t_frame_s: np.ndarray, t_fix_s: np.ndarray, max_gap_factor: float) -> np.ndarray:
    """(N,) bool: frames whose position no fix near them pins, i.e. that lie between two fixes
    more than ``max_gap_factor`` times the median fix interval apart, or further than one median
    interval outside the fixes' span. Across a dropout in a curve, straight lines and the spline
    alike cut the corner by metres: on the corpus's tuning half (c0054: 2 Hz, a 2.3 s dropout in
    an 85 deg turn) a window right to 3 cm against the truth lay 2.35 m rms from its frames' GPS
    positions, over the limit that marks a broken reconstruction, and its 8 signs were rejected."""
    t_frame_s, t_fix_s = np.asarray(t_frame_s, float), np.asarray(t_fix_s, float)
    out = np.zeros(len(t_frame_s), bool)
    if len(t_fix_s) < 2 or max_gap_factor <= 0:
        return out
    interval_s = np.diff(t_fix_s)
    typical_s = float(np.median(interval_s))
    after = np.searchsorted(t_fix_s, t_frame_s, side="right")  # index of the next fix
    inside = (after > 0) & (after < len(t_fix_s))
    out[inside] = interval_s[after[inside] - 1] > max_gap_factor * typical_s
    out |= (t_frame_s < t_fix_s[0] - typical_s) | (t_frame_s > t_fix_s[-1] + typical_s)
    return out


# The direction of travel at a sample is the slope, at that sample, of a parabola fitted to the
# positions within this many seconds either side (least squares, per horizontal axis): against
# 0.3 m of white noise at 10 Hz its heading scatters by 0.5 degree rms at 8 m/s inside a journey.
# Where the window is symmetric the parabola's slope is a straight line's, which on a circle driven
# at constant speed lies on the tangent; at a journey's ends, where the window is one-sided, the
# parabola keeps the slope from lagging behind a turn as a straight line's would.
HEADING_HALF_WINDOW_S = 1.5
# Slower than this (the fitted speed), the heading is noise: such a sample holds the heading of the
# nearest (in time) sample that moves.
MIN_HEADING_SPEED_MPS = 1.0
# ... or than this many times its own standard error (from the fit's residuals): a one-sided window
# at a journey's end fits a parabola to few noisy fixes, and a parked car's would point anywhere.
MIN_SPEED_SIGMAS = 4.0
MIN_WINDOW_SAMPLES = 5  # a parabola and its residuals' spread
HEADING_ITERATIONS = 2  # camera_positions: 8.5 cm of error -> 0.05 mm for KITTI's 1.1 m, 14 m turn
_CHUNK = 4096  # samples fitted at once (memory: chunk x samples per window)


def travel_direction(t_s: np.ndarray, xyz: np.ndarray,
                     half_window_s: float = HEADING_HALF_WINDOW_S,
                     min_speed_mps: float = MIN_HEADING_SPEED_MPS) -> np.ndarray | None:
    """(N, 2) unit horizontal directions of travel at ``t_s`` (N,) (non-decreasing) of positions
    ``xyz`` (N, 3) (see HEADING_HALF_WINDOW_S; wider when the samples are sparser than
    MIN_WINDOW_SAMPLES in it); a sample slower than ``min_speed_mps`` or than
    MIN_SPEED_SIGMAS standard errors, or whose window holds too few samples, takes the direction
    of the nearest sample that is not. None when no sample moves."""
    t = np.asarray(t_s, float) - float(t_s[0])
    xy = np.asarray(xyz, float)[:, :2] - np.asarray(xyz, float)[0, :2]
    tol_s = 1e-6  # timestamps such as 0.1 * k are not exact: keep the windows symmetric
    if len(t) > 1:  # sparse samples (photos a second apart): wide enough for a parabola
        half_window_s = max(half_window_s, 0.5 * MIN_WINDOW_SAMPLES * float(np.median(np.diff(t))))
    lo = np.searchsorted(t, t - half_window_s - tol_s, side="left")
    hi = np.searchsorted(t, t + half_window_s + tol_s, side="right")
    velocity = np.full((len(t), 2), np.nan)
    speed_sigma = np.full(len(t), np.inf)  # the slope's standard error per axis, m/s
    for a in range(0, len(t), _CHUNK):
        rows = np.arange(a, min(len(t), a + _CHUNK))
        idx = lo[rows, None] + np.arange(int((hi - lo)[rows].max()))[None, :]
        valid = idx < hi[rows, None]
        idx = np.minimum(idx, len(t) - 1)
        tau = np.where(valid, t[idx] - t[rows, None], 0.0)
        design = np.stack([np.ones_like(tau), tau, tau * tau], axis=-1) * valid[..., None]
        normal = np.einsum("ckj,ckl->cjl", design, design)
        rhs = np.einsum("ckj,ckd->cjd", design, xy[idx] * valid[..., None])
        # Enough samples to tell the fit's noise, spread over a fifth of the window at least.
        n = valid.sum(axis=1)
        spread = np.where(valid, tau, np.inf).min(axis=1), np.where(valid, tau, -np.inf).max(axis=1)
        fit = (n >= MIN_WINDOW_SAMPLES) & (spread[1] - spread[0] >= 0.4 * half_window_s)
        fit &= np.abs(np.linalg.det(np.where(fit[:, None, None], normal, np.eye(3)))) > 1e-12
        if not fit.any():
            continue
        inverse = np.linalg.inv(normal[fit])
        coef = inverse @ rhs[fit]  # (F, 3, 2)
        residual = (xy[idx[fit]] - design[fit] @ coef) * valid[fit][..., None]
        noise_var = (residual ** 2).sum(axis=(1, 2)) / (2.0 * (n[fit] - 3))
        velocity[rows[fit]] = coef[:, 1, :]
        speed_sigma[rows[fit]] = np.sqrt(inverse[:, 1, 1] * noise_var)
    speed = np.linalg.norm(velocity, axis=1)
    moving = (np.isfinite(speed) & (speed >= min_speed_mps)
              & (speed >= MIN_SPEED_SIGMAS * speed_sigma))
    if not moving.any():
        return None
    idx = np.flatnonzero(moving)
    # The nearest moving sample in time, for each sample (itself when it moves).
    after = np.clip(np.searchsorted(t[idx], t), 0, len(idx) - 1)
    before = np.clip(after - 1, 0, len(idx) - 1)
    nearest = np.where(np.abs(t[idx[before]] - t) <= np.abs(t[idx[after]] - t),
                       idx[before], idx[after])
    nearest[moving] = idx
    return velocity[nearest] / speed[nearest][:, None]


def camera_positions(t_s: np.ndarray, xyz_antenna: np.ndarray,
                     offset: AntennaOffset) -> tuple[np.ndarray, bool]:
    """(N, 3) camera positions from the antenna's ``xyz_antenna`` (N, 3) at ``t_s`` (N,), and
    whether the direction of travel was known (``camera_travel_direction``, ``antenna_to_camera``).
    """
    forward = camera_travel_direction(t_s, xyz_antenna, offset)
    return antenna_to_camera(xyz_antenna, offset, forward), forward is not None


def camera_travel_direction(t_s: np.ndarray, xyz_antenna: np.ndarray,
                            offset: AntennaOffset) -> np.ndarray | None:
    """(N, 2) the camera's horizontal direction of travel (``travel_direction``) from the
    antenna's positions ``xyz_antenna`` (N, 3) at ``t_s`` (N,): the antenna's own direction of
    travel turns by atan(forward_m / radius) more than the camera's in a turn (4.5 degrees for
    1.09 m on a 14 m radius), so the camera's path is taken from it, its direction found again,
    and so on HEADING_ITERATIONS times (each leaves ~forward_m / radius of the error before).
    None when the vehicle never moved (no sample at ``MIN_HEADING_SPEED_MPS``): forward and left
    then point nowhere in particular."""
    xyz = np.asarray(xyz_antenna, float)
    forward = travel_direction(t_s, xyz) if len(xyz) else None
    if forward is None:
        return None
    for _ in range(HEADING_ITERATIONS):
        again = travel_direction(t_s, antenna_to_camera(xyz, offset, forward))
        forward = forward if again is None else again
    return forward


def antenna_to_camera(xyz: np.ndarray, offset: AntennaOffset,
                      forward: np.ndarray | None) -> np.ndarray:
    """``xyz`` (N, 3) minus ``offset`` in the vehicle axes of the horizontal unit directions of
    travel ``forward`` (N, 2); only its up part when None."""
    out = np.array(xyz, dtype=float, copy=True)
    out[:, 2] -= offset.up_m
    if forward is not None:
        left = np.column_stack([-forward[:, 1], forward[:, 0]])  # up x forward
        out[:, :2] -= offset.forward_m * forward + offset.left_m * left
    return out
