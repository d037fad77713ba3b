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
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import make_smoothing_spline

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
