"""Where the GPS antenna sits, estimated from reconstructed windows that turn, when nobody said.

Conventions are ``geometry.gps_track``'s (the contract's section 1b): the offset is the antenna's
position minus the camera's in the vehicle's axes, forward = the camera's horizontal direction of
travel, left = up x forward. At each GPS fix inside a window, the window's camera centre ``c``
(its own model frame, interpolated from its dense frames to the fix's time) and the fix ``g``
(ENU metres, the antenna's) obey ``g = s R c + t + forward * forward_m + left * left_m``, forward
being the camera path's own direction rotated by ``R``. On a straight road both offset terms are
constant and the translation ``t`` absorbs them; on a circular arc a forward offset is a rotation
about the arc's centre and a left one a scale about it, which the similarity absorbs too. What
tells the offset is a window whose heading changes *and* whose path is not one circle: a straight
run into a turn. So a window is fitted only if it turns MIN_TURN_DEG or more, and its sigma says
how well its shape pinned the offset. With fixes free of noise and the true camera path, the
model gives back the rendered offsets within 0.02 m (docs/decisions/antenna-offset.md).

The fixes' errors are correlated in time (a receiver's bias wanders over seconds): a
least-squares sigma that took every fix as independent would be several times too small. It is
inflated by the residuals' integrated autocorrelation time. The vertical part is not estimated: a
constant height offset is the translation's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from app.pipeline.geometry import gps_track
from app.pipeline.types import AntennaEstimate

MIN_TURN_DEG = 30.0
MIN_FIXES = 8
# A window's offset that misfits its GPS worse than this (rms, m) comes from a reconstruction the
# alignment would not trust either: it is not used.
MAX_RESIDUAL_M = 1.5
# The camera's direction of travel at a fix: its reconstructed path's chord over this many seconds
# either side (frames are dense; the path is smooth where the GPS is not).
VELOCITY_HALF_S = 0.25
MIN_SPEED_MPS = 1.0  # slower (at the start's scale), a fix is left out
# A window sharing more than this share of its fixes with a better window is not counted again.
MAX_SHARED_FIXES = 0.2
# The fit's sigma, even inflated by the correlation time, is optimistic: its error over its sigma
# was 1.34 at the median on the corpus's tuning half and 1.5-2 on the rendered test journeys,
# whose antenna at the camera got +0.28 ± 0.14 m and, applied, moved its signs 0.27 m further off
# (docs/decisions/antenna-offset.md). Reported sigmas are this many times the fit's.
SIGMA_SCALE = 2.0


@dataclass(frozen=True)
class OffsetEstimate:
    """The horizontal antenna offset (m, vehicle axes) and its 1-sigma (m), from ``n_windows``
    windows holding ``n_fixes`` GPS fixes that turned by up to ``turn_deg``."""

    forward_m: float
    left_m: float
    sigma_forward_m: float
    sigma_left_m: float
    n_windows: int
    n_fixes: int
    turn_deg: float

    @property
    def sigma_m(self) -> float:
        return max(self.sigma_forward_m, self.sigma_left_m)

    def estimate(self) -> AntennaEstimate:
        """The offset and sigmas alone, as one journey's (what a vehicle's journeys combine)."""
        return AntennaEstimate(self.forward_m, self.left_m, self.sigma_forward_m,
                               self.sigma_left_m)


@dataclass(frozen=True)
class _WindowFit:
    offset_m: np.ndarray  # (2,) forward, left
    cov: np.ndarray  # (2, 2)
    fixes: np.ndarray  # (M,) indices of the fixes it used
    turn_deg: float


def estimate_offset(windows: list[tuple[np.ndarray, np.ndarray]], t_fix_s: np.ndarray,
                    xyz_fix: np.ndarray) -> OffsetEstimate | None:
    """The offset from ``windows``, each (t_s (K,) its registered frames' times, increasing;
    camera centres (K, 3) in its own model frame), against the antenna's GPS fixes ``xyz_fix``
    (M, 3, ENU m) at ``t_fix_s`` (M,). The fit is at the fixes' own times, the dense camera path
    interpolated to them: fixes interpolated to the frames would cut a turn's corners by
    decimetres (the sagitta of a 1-10 Hz chord), which the offset would absorb. Of windows
    sharing fixes (which share their errors) only the best pinned counts; the rest are combined
    by inverse covariance. None when no window turns enough."""
    forward = gps_track.travel_direction(t_fix_s, xyz_fix)
    if forward is None:
        return None
    heading = np.unwrap(np.arctan2(forward[:, 1], forward[:, 0]))
    fits = []
    for t_s, centres in windows:
        inside = np.flatnonzero((t_fix_s >= t_s[0]) & (t_fix_s <= t_s[-1]))
        if len(inside) < MIN_FIXES:
            continue
        turn_deg = float(np.degrees(np.ptp(heading[inside])))
        if turn_deg < MIN_TURN_DEG:
            continue
        fit = _fit_window(np.asarray(t_s, float), np.asarray(centres, float), t_fix_s[inside],
                          xyz_fix[inside])
        if fit is not None:
            fits.append(_WindowFit(fit[0], fit[1], inside, turn_deg))
    chosen: list[_WindowFit] = []
    for fit in sorted(fits, key=lambda f: np.trace(f.cov)):
        shared = sum(np.intersect1d(fit.fixes, c.fixes).size for c in chosen)
        if shared <= MAX_SHARED_FIXES * len(fit.fixes):
            chosen.append(fit)
    if not chosen:
        return None
    info = sum(np.linalg.inv(f.cov) for f in chosen)
    cov = np.linalg.inv(info)
    mean = cov @ sum(np.linalg.inv(f.cov) @ f.offset_m for f in chosen)
    return OffsetEstimate(float(mean[0]), float(mean[1]), float(np.sqrt(cov[0, 0])),
                          float(np.sqrt(cov[1, 1])), len(chosen),
                          int(sum(len(f.fixes) for f in chosen)),
                          float(max(f.turn_deg for f in chosen)))


def _fit_window(t_s: np.ndarray, centres: np.ndarray, t_fix_s: np.ndarray, xyz_fix: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray] | None:
    """(offset (2,), its covariance (2, 2)) of one window, or None when it does not fit."""
    def at(t):
        return np.column_stack([np.interp(t, t_s, centres[:, i]) for i in range(3)])

    c_fix = at(t_fix_s)
    v_fix = (at(np.minimum(t_fix_s + VELOCITY_HALF_S, t_s[-1]))
             - at(np.maximum(t_fix_s - VELOCITY_HALF_S, t_s[0])))
    # Kabsch for the start (COLMAP's Umeyama refuses a flat road's planar centres).
    src_c, dst_c = c_fix - c_fix.mean(0), xyz_fix - xyz_fix.mean(0)
    spread = float(np.linalg.norm(src_c))
    if spread == 0.0:
        return None
    R = Rotation.align_vectors(dst_c, src_c)[0]
    scale = float(np.linalg.norm(dst_c)) / spread
    # Standing, the path has no direction for the offset to follow (and a stop's fixes wander).
    moving = scale * np.linalg.norm(v_fix, axis=1) >= MIN_SPEED_MPS * 2.0 * VELOCITY_HALF_S
    if moving.sum() < MIN_FIXES:
        return None
    c_fix, v_fix, xyz_fix = c_fix[moving], v_fix[moving], xyz_fix[moving]
    x0 = np.concatenate([R.as_rotvec(), [np.log(scale)],
                         xyz_fix.mean(0) - scale * R.apply(c_fix.mean(0)), [0.0, 0.0]])
    fit = least_squares(_residuals, x0, args=(c_fix, v_fix, xyz_fix), method="lm")
    residual = fit.fun.reshape(-1, 3)
    rms_m = float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1))))
    if not fit.success or rms_m > MAX_RESIDUAL_M:
        return None
    jtj = fit.jac.T @ fit.jac
    if np.linalg.cond(jtj) > 1e12:
        return None
    dof = max(fit.fun.size - len(fit.x), 1)
    cov = np.linalg.inv(jtj) * float(fit.fun @ fit.fun) / dof
    return (fit.x[7:9].copy(),
            cov[7:9, 7:9] * correlation_time(residual[:, :2]) * SIGMA_SCALE ** 2)


def _residuals(x: np.ndarray, c_fix: np.ndarray, v_fix: np.ndarray,
               xyz_fix: np.ndarray) -> np.ndarray:
    """GPS minus (the similarity's camera centre + the offset in the vehicle's axes), per fix;
    forward is the camera path's own direction, rotated into the world and made horizontal."""
    R = Rotation.from_rotvec(x[:3]).as_matrix()
    v_world = v_fix @ R.T
    forward = v_world[:, :2] / np.linalg.norm(v_world[:, :2], axis=1, keepdims=True)
    left = np.column_stack([-forward[:, 1], forward[:, 0]])
    offset_xy = x[7] * forward + x[8] * left
    predicted = np.exp(x[3]) * c_fix @ R.T + x[4:7]
    predicted[:, :2] += offset_xy
    return (xyz_fix - predicted).ravel()


def correlation_time(residual: np.ndarray) -> float:
    """The integrated autocorrelation time (in samples, >= 1) of ``residual`` (K, D) in time
    order, averaged over its columns: 1 + 2 * the sum of the lag correlations up to the first
    that is not positive, at most K / 4 lags (Geyer's initial positive sequence, simplified)."""
    r = residual - residual.mean(axis=0)
    k = len(r)
    denom = float(np.sum(r * r))
    if k < 4 or denom <= 0.0:
        return 1.0
    tau = 1.0
    for lag in range(1, k // 4 + 1):
        rho = float(np.sum(r[lag:] * r[:-lag])) / denom
        if rho <= 0.0:
            break
        tau += 2.0 * rho
    return tau
