"""Check the focal length the journey ran with against its GPS, on the ego-motion's turning windows.

A focal length short by a factor 1/kappa makes every rotation the reconstruction sees about kappa
times too large (an image offset x is read as the angle atan(x / f)): with fx 3 % short, tuning
journey c0054's 85.5 deg turn came out as 87.9 deg (bench/results/2026-11-27-focal-error.md). The
trajectory then bends too far and its positions fit the GPS worse, which no choice of similarity
hides. So each turning window is unbent by candidate factors kappa (its rotations relative to its
first camera divided by kappa, its steps between cameras re-chained along them), aligned to the GPS
by a similarity, and the kappa that fits best over all turning windows estimates the focal error:
fx_true ~ kappa * fx. Straight windows carry no such evidence and are left out.

Frames: ``model`` is each window's own reconstruction frame (``ego_motion.WindowPoses``),
``xyz_gps`` the journey's metric GPS frame (ENU metres).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from app.pipeline.geometry.similarity import umeyama
from app.pipeline.steps.align import fit_rows
from app.pipeline.steps.calibrate import rotation_covered_deg
from app.pipeline.steps.ego_motion import WindowPoses

# Candidate rotation scales: +-8 % covers what the calibration gates let through (3 %) twice over.
KAPPAS = np.round(np.arange(0.92, 1.0801, 0.0025), 4)


@dataclass(frozen=True)
class FocalEvidence:
    """What the GPS says of the focal length: ``kappa`` the rotation scale that fits best (the focal
    length used times ``kappa`` fits the GPS best), ``kappa_std`` its standard error from the fit's
    curvature and residual (an underestimate where GPS errors are correlated); ``rms_m`` the
    turning windows' pooled alignment residual as run (kappa 1) and unbent by ``kappa``;
    ``n_windows`` and ``turn_deg`` (their summed rotation) how much evidence there is."""

    kappa: float
    kappa_std: float
    n_windows: int
    turn_deg: float
    rms_m: float
    rms_best_m: float


def unbent_centres(T_model_cam: np.ndarray, kappa: float) -> np.ndarray:
    """(K, 3) camera centres of the poses ``T_model_cam`` (K, 4, 4) with every rotation relative to
    the first camera divided by ``kappa``, each step between consecutive centres kept as it was in
    the camera it starts from (forward motion stays forward motion)."""
    R_model_cam = T_model_cam[:, :3, :3]
    c_model = T_model_cam[:, :3, 3]
    R0 = R_model_cam[0]
    rotvec_rel = Rotation.from_matrix(np.einsum("ji,njk->nik", R0, R_model_cam)).as_rotvec()
    R_unbent = R0 @ Rotation.from_rotvec(rotvec_rel / kappa).as_matrix()
    step_cam = np.einsum("nji,nj->ni", R_model_cam[:-1], np.diff(c_model, axis=0))
    step_unbent = np.einsum("nij,nj->ni", R_unbent[:-1], step_cam)
    return np.vstack([c_model[:1], c_model[:1] + np.cumsum(step_unbent, axis=0)])


def _sse_m2(c_model: np.ndarray, xyz: np.ndarray) -> float:
    sim = umeyama(c_model, xyz)
    return float(np.sum((sim.apply(c_model) - xyz) ** 2))


def focal_evidence(poses: list[WindowPoses], xyz_gps: np.ndarray,
                   trusted: np.ndarray | None = None, *, min_turn_deg: float = 30.0,
                   kappas: np.ndarray = KAPPAS) -> FocalEvidence | None:
    """The rotation scale that best fits the windows of ``poses`` turning at least
    ``min_turn_deg`` to ``xyz_gps`` (N, 3), using the frames ``trusted`` (N,) bool marks (None:
    all); None when no window turns that far."""
    sse = np.zeros(len(kappas))
    n_windows, n_rows, turn_deg = 0, 0, 0.0
    for p in poses:
        turn = rotation_covered_deg(p.T_model_cam)
        use = fit_rows(p.frame_idx, trusted)
        if turn < min_turn_deg or use.sum() < 6:
            continue
        xyz = xyz_gps[p.frame_idx]
        curve = []
        for kappa in kappas:
            # Unbend over all frames (the chain needs every step), fit on the trusted ones.
            curve.append(_sse_m2(unbent_centres(p.T_model_cam, kappa)[use], xyz[use]))
        sse += np.array(curve)
        n_windows, n_rows, turn_deg = n_windows + 1, n_rows + int(use.sum()), turn_deg + turn
    if not n_windows:
        return None
    k = int(np.argmin(sse))
    kappa, curvature = float(kappas[k]), np.inf
    if 0 < k < len(kappas) - 1:
        # A parabola through the minimum and its neighbours: its vertex and curvature.
        a, b, _ = np.polyfit(kappas[k - 1:k + 2], sse[k - 1:k + 2], 2)
        if a > 0:
            kappa, curvature = float(-b / (2 * a)), float(a)
    # Each window's similarity takes 7 of its 3 * n rows' degrees of freedom, kappa one more.
    dof = max(3 * n_rows - 7 * n_windows - 1, 1)
    kappa_std = float(np.sqrt(sse[k] / dof / curvature)) if np.isfinite(curvature) else np.inf
    at_one = int(np.argmin(np.abs(kappas - 1.0)))
    return FocalEvidence(kappa=kappa, kappa_std=kappa_std, n_windows=n_windows,
                         turn_deg=turn_deg, rms_m=float(np.sqrt(sse[at_one] / n_rows)),
                         rms_best_m=float(np.sqrt(sse[k] / n_rows)))
