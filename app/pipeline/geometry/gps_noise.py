"""How noisy a journey's GPS is, from its own fixes: the white-noise sigma per horizontal axis (m).

A car's path is smooth over a few seconds, GPS white noise is not. Over every run of ``WINDOW``
consecutive fixes a quadratic in time (constant acceleration) is fitted per axis; the residual
of the middle fix is noise (plus what a turn adds beyond a quadratic). For white noise of sigma
``s`` that residual has sigma ``s * sqrt(1 - h)``, ``h`` the middle fix's leverage in the fit;
the median absolute residual, scaled for a Gaussian, is robust to the turns. A slowly drifting
bias moves all fixes of a window together and is not seen: this measures what the fixes scatter
by, which is what a window alignment's residual is compared with (``steps.place_signs``).
"""

from __future__ import annotations

import numpy as np

from app.pipeline.geometry.geodesy import frame_at

WINDOW = 5
MIN_FIXES = 2 * WINDOW
# Enough to judge a window by (``steps.place_signs.judging_noise_m``): three windows. A short
# journey (24 frames at 5 Hz, a fix every 0.5 s: 9 fixes) had no estimate, so nothing judged its
# window, which lay 15 m rms off the GPS and placed 3 false signs. Few windows err, mostly upwards
# where a turn fills them, and the check allows 5 times the estimate; the journey's other uses
# of its noise (turn finding, the GPS spline) keep MIN_FIXES: given these estimates they placed
# a sign of another short journey 3.4 m off (docs/decisions/gps-noise-few-fixes.md).
MIN_FIXES_TO_JUDGE = WINDOW + 2
MAX_WINDOWS = 5000  # evenly spread over a long journey: the estimate needs no more
MEDIAN_ABS_PER_SIGMA = 0.6745  # median |z| of a standard normal


def white_noise_m(timestamp_s: np.ndarray, lat_deg: np.ndarray, lon_deg: np.ndarray,
                  min_fixes: int = MIN_FIXES) -> float | None:
    """Horizontal white-noise sigma (m, per axis) of fixes at ``timestamp_s`` (M,), increasing;
    None with fewer than ``min_fixes``."""
    t = np.asarray(timestamp_s, float)
    if len(t) < max(min_fixes, MIN_FIXES_TO_JUDGE):
        return None
    origin = frame_at(float(lat_deg[0]), float(lon_deg[0]), 0.0)
    xy = origin.to_local(lat_deg, lon_deg, np.zeros(len(t)))[:, :2]
    starts = np.unique(np.linspace(0, len(t) - WINDOW, min(MAX_WINDOWS, len(t) - WINDOW + 1))
                       .astype(int))
    rows = starts[:, None] + np.arange(WINDOW)[None, :]              # (W, 5) fix indices
    dt = t[rows] - t[rows[:, WINDOW // 2]][:, None]                  # times about the middle fix
    A = np.stack([np.ones_like(dt), dt, dt**2], axis=2)              # (W, 5, 3)
    # Hat matrix row of the middle fix: leverage and fitted value, per window.
    pinv = np.linalg.pinv(A)                                         # (W, 3, 5)
    hat_mid = np.einsum("wk,wkj->wj", A[:, WINDOW // 2, :], pinv)    # (W, 5)
    leverage = hat_mid[:, WINDOW // 2]
    ok = leverage < 0.999  # a degenerate window (repeated times) fits its middle exactly
    if not np.any(ok):
        return None
    resid = xy[rows[:, WINDOW // 2]] - np.einsum("wj,wjd->wd", hat_mid, xy[rows])  # (W, 2)
    scaled = np.abs(resid[ok]) / np.sqrt(1.0 - leverage[ok])[:, None]
    return float(np.median(scaled) / MEDIAN_ABS_PER_SIGMA)
