"""Windows that pose the same frames, aligned together (``align_group``)."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from app.pipeline.geometry.similarity import Sim3
from app.pipeline.steps.align.window import (AlignedWindow, centre_rms_m, shared_rows,
                                             fit_rows)

log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class JointSigmas:
    """1-sigma errors of the joint alignment's residuals. ``gps_m``: a GPS fix (per axis);
    ``centre_m`` / ``rotation_deg``: how closely two windows' world poses of one frame agree (both
    are reconstructions of the same images); ``roll_deg``: the prior that keeps a straight-road
    window's roll about the road at its independent (gravity or fallback) value."""

    gps_m: float = 0.5
    centre_m: float = 0.03
    rotation_deg: float = 0.2
    roll_deg: float = 1.0


# The robust loss (soft L1) is quadratic up to this many sigmas: a window whose reconstruction
# bends cannot drag its neighbours far.
ROBUST_SCALE_SIGMAS = 2.0


class _JointProblem:
    """The joint alignment of linked windows as a least-squares problem.

    Unknowns: per window a similarity correction (rotation vector 3, translation 3, log scale 1)
    applied in the world frame after the window's independent alignment, rotating about the
    window's world centroid (a rotation about the distant ENU origin would be tangled with the
    translation). Residuals, each divided by its sigma: (a) camera centres vs GPS, a frame's fix
    weighted 1/sqrt(number of windows posing it) so a shared frame counts once; (b) per frame
    posed by two windows, their world camera centres and rotations agree; (c) a window whose
    roll about its road line is unobserved keeps its independent roll.
    """

    def __init__(self, windows: list[AlignedWindow], xyz_gps: np.ndarray, sigmas: JointSigmas,
                 trusted: np.ndarray | None = None):
        self.windows = windows
        self.sigmas = sigmas
        self.centres_model = [w.poses.T_model_cam[:, :3, 3] for w in windows]  # (K,3) each
        self.R_model_cam = [w.poses.T_model_cam[:, :3, :3] for w in windows]  # (K,3,3) each
        self.xyz_gps = [xyz_gps[w.poses.frame_idx] for w in windows]  # (K,3) each
        counts = np.bincount(np.concatenate([w.poses.frame_idx for w in windows]))
        # A frame whose GPS position is not trusted (``fit_rows``) weighs nothing.
        self.gps_weight = [fit_rows(w.poses.frame_idx, trusted)
                           / (sigmas.gps_m * np.sqrt(counts[w.poses.frame_idx]))
                           for w in windows]  # (K,) each
        self.pivot_enu = [w.T_world_cam[:, :3, 3].mean(0) for w in windows]
        self.pairs = [(i, j, *shared_rows(windows[i].poses, windows[j].poses))
                      for i in range(len(windows)) for j in range(i + 1, len(windows))]
        self.pairs = [p for p in self.pairs if len(p[2])]
        self.roll_axes = [(k, _line_direction(w.T_world_cam[:, :3, 3]))
                          for k, w in enumerate(windows) if w.info.get("degenerate")]

    def sims(self, x: np.ndarray) -> list[Sim3]:
        """Model -> world similarity of every window for the corrections x (7 * n_windows,)."""
        out = []
        for w, pivot, dx in zip(self.windows, self.pivot_enu, x.reshape(-1, 7)):
            R_delta = Rotation.from_rotvec(dx[:3]).as_matrix()
            k = np.exp(dx[6])
            out.append(Sim3(k * w.sim.scale, R_delta @ w.sim.R,
                            pivot + k * R_delta @ (w.sim.t - pivot) + dx[3:6]))
        return out

    def residuals(self, x: np.ndarray) -> np.ndarray:
        sims = self.sims(x)
        xyz_world = [sim.apply(c) for sim, c in zip(sims, self.centres_model)]
        R_world_cam = [sim.R @ R for sim, R in zip(sims, self.R_model_cam)]
        parts = [((xyz - gps) * wt[:, None]).ravel()
                 for xyz, gps, wt in zip(xyz_world, self.xyz_gps, self.gps_weight)]
        for i, j, rows_i, rows_j in self.pairs:
            parts.append((xyz_world[i][rows_i] - xyz_world[j][rows_j]).ravel()
                         / self.sigmas.centre_m)
            R_i_j = R_world_cam[i][rows_i] @ np.transpose(R_world_cam[j][rows_j], (0, 2, 1))
            parts.append(Rotation.from_matrix(R_i_j).as_rotvec().ravel()
                         / np.radians(self.sigmas.rotation_deg))
        dx = x.reshape(-1, 7)
        parts.append(np.array([dx[k, :3] @ u for k, u in self.roll_axes])
                     / np.radians(self.sigmas.roll_deg))
        return np.concatenate(parts)

    def jac_sparsity(self) -> sparse.lil_matrix:
        """Which unknowns each residual depends on, in ``residuals``' order: a window's GPS rows
        on its own 7, a shared frame's rows on its two windows' 14. Finite differences then cost
        a few evaluations per Jacobian instead of 7 per window (a 1000-frame journey chains ~50
        windows)."""
        blocks = [(3 * len(c), (k,)) for k, c in enumerate(self.centres_model)]
        blocks += [(6 * len(rows_i), (i, j)) for i, j, rows_i, _ in self.pairs]
        blocks += [(1, (k,)) for k, _ in self.roll_axes]
        out = sparse.lil_matrix((sum(n for n, _ in blocks), 7 * len(self.windows)), dtype=int)
        row = 0
        for n, ks in blocks:
            for k in ks:
                out[row:row + n, 7 * k:7 * k + 7] = 1
            row += n
        return out

    def pair_disagreement_m(self, sims: list[Sim3]) -> float:
        """Rms distance (m) between two windows' world centres of the frames they share."""
        d = [sims[i].apply(self.centres_model[i][ri]) - sims[j].apply(self.centres_model[j][rj])
             for i, j, ri, rj in self.pairs]
        return float(np.sqrt(np.mean(np.sum(np.concatenate(d) ** 2, axis=1))))


def _line_direction(xyz: np.ndarray) -> np.ndarray:
    """Unit direction (3,) of the best-fit line of the points (K,3)."""
    return np.linalg.svd(xyz - xyz.mean(0), full_matrices=False)[2][0]


def align_group(windows: list[AlignedWindow], xyz_gps: np.ndarray,
                 sigmas: JointSigmas, trusted: np.ndarray | None = None) -> list[AlignedWindow]:
    """Joint alignment of linked windows (see ``_JointProblem``), started from their independent
    alignments. Each window's ``info`` keeps its independent values, with ``rms_m`` and ``scale``
    of the joint alignment and ``rms_independent_m``, ``joint_windows`` added."""
    problem = _JointProblem(windows, xyz_gps, sigmas, trusted)
    # lsmr, not the dense SVD solver: same solution (to 1e-6 m on the tests), but the SVD's
    # threaded LAPACK spun 10x the CPU time while COLMAP busied the other core.
    fit = least_squares(problem.residuals, np.zeros(7 * len(windows)), loss="soft_l1",
                        f_scale=ROBUST_SCALE_SIGMAS, x_scale="jac", tr_solver="lsmr",
                        jac_sparsity=problem.jac_sparsity())
    sims = problem.sims(fit.x)
    out = []
    for w, sim, gps in zip(windows, sims, problem.xyz_gps):
        T_world_cam = sim.apply_poses(w.poses.T_model_cam)
        use = fit_rows(w.poses.frame_idx, trusted)
        info = {**w.info, "rms_m": centre_rms_m(T_world_cam[use], gps[use]), "scale": sim.scale,
                "rms_independent_m": w.info["rms_m"], "joint_windows": len(windows)}
        out.append(AlignedWindow(w.poses, sim, info, T_world_cam))
    log.info("joint alignment of windows %s: GPS rms %.3f -> %.3f m, shared frames disagree "
             "%.3f -> %.3f m rms (%d evaluations)", [w.poses.window for w in windows],
             _pooled_rms([w.info["rms_m"] for w in windows], windows),
             _pooled_rms([w.info["rms_m"] for w in out], windows),
             problem.pair_disagreement_m([w.sim for w in windows]),
             problem.pair_disagreement_m(sims), fit.nfev)
    return out


def _pooled_rms(rms_m: list[float], windows: list[AlignedWindow]) -> float:
    n = np.array([len(w.poses.frame_idx) for w in windows])
    return float(np.sqrt(np.sum(n * np.square(rms_m)) / n.sum()))
