"""Robust information-form mean of one map sign's member positions.

The fused position minimises sum_i rho(r_i), with r_i = sqrt((x_i - m)^T C_i^-1 (x_i - m)) the
Mahalanobis residual of member i under its own covariance, by iteratively reweighted least squares:
first Huber (convex, so the start does not matter), then Cauchy from the Huber solution (redescending,
so one bad member ends with a weight near 0 instead of pulling by k / r). Member i's information
C_i^-1 is scaled by ``scale_i`` (relative to the largest), which is how a journey flagged as biased
keeps a near-zero say. The fused covariance is (sum_i w_i scale_i C_i^-1)^-1; Cauchy weights of
inliers are somewhat below 1, so it is slightly conservative.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FusedPoint:
    xyz_enu: np.ndarray  # (3,)
    cov_enu: np.ndarray  # (3, 3) m^2
    weights: np.ndarray  # (n,) robust weights in [0, 1], before ``scale``
    residuals: np.ndarray  # (n,) Mahalanobis residuals at the solution


def _solve(info: np.ndarray, xyz: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    weighted = info * w[:, None, None]
    A = weighted.sum(axis=0)
    b = np.einsum("nij,nj->i", weighted, xyz)
    return np.linalg.solve(A, b), A


def _mahalanobis(info: np.ndarray, xyz: np.ndarray, m: np.ndarray) -> np.ndarray:
    d = xyz - m
    return np.sqrt(np.maximum(np.einsum("ni,nij,nj->n", d, info, d), 0.0))


def robust_fuse(xyz_enu: np.ndarray, cov_enu: np.ndarray, scale: np.ndarray | None = None, *,
                huber_k: float = 3.0, cauchy_c: float = 3.0, max_iter: int = 50) -> FusedPoint:
    """Fuse n >= 1 points ``xyz_enu`` (n, 3) with covariances ``cov_enu`` (n, 3, 3)."""
    xyz = np.asarray(xyz_enu, dtype=float)
    info = np.linalg.inv(np.asarray(cov_enu, dtype=float))
    s = np.ones(len(xyz)) if scale is None else np.asarray(scale, dtype=float)
    s = s / s.max()
    losses = (lambda r: np.where(r <= huber_k, 1.0, huber_k / np.maximum(r, huber_k)),
              lambda r: 1.0 / (1.0 + (r / cauchy_c) ** 2))
    w = np.ones(len(xyz))
    for loss in losses:
        for _ in range(max_iter):
            m, _ = _solve(info, xyz, s * w)
            w_new = loss(_mahalanobis(info, xyz, m))
            converged = np.max(np.abs(w_new - w)) < 1e-10
            w = w_new
            if converged:
                break
    m, A = _solve(info, xyz, s * w)
    return FusedPoint(m, np.linalg.inv(A), w, _mahalanobis(info, xyz, m))
