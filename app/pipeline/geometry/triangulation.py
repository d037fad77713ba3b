"""Triangulate one sign from its detections in several posed frames (the paper's Sec. III-D).

Frames: ``world`` is the journey's ENU frame (metres); ``cam`` is x right, y down, z forward;
poses ``T_world_cam`` (M,4,4) map cam -> world. Pixels are OpenCV pixels of the rectified camera
``K`` (no distortion) unless said otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares

from app.pipeline.types import CameraModel


@dataclass(frozen=True)
class TriangulatedPoint:
    xyz_world: np.ndarray  # (3,)
    cov_world: np.ndarray  # (3,3) m^2
    std_m: float  # sqrt of the largest eigenvalue of cov_world
    rms_px: float  # reprojection rms in undistorted pixels
    p_cam: np.ndarray  # (M,3) the point in each observing camera (x right, y down, z fwd)


class TriangulationError(ValueError):
    """The sign cannot be placed; ``reason`` says why in words a user can act on."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


class ReprojectionError(TriangulationError):
    """The refined point reprojects too far from the detections: ``residuals_px`` (M,) is each
    observation's pixel distance from it."""

    def __init__(self, reason: str, residuals_px: np.ndarray):
        super().__init__(reason)
        self.residuals_px = residuals_px


# The iterative undistortion stops on a residual in normalised coordinates; 1e-12 there is far
# below 1e-6 px, and strong barrel lenses need more than OpenCV's default 5 iterations at corners.
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


def undistort_pixels(camera: CameraModel, px: np.ndarray) -> np.ndarray:
    """(M,2) distorted OpenCV pixels of ``camera`` -> (M,2) pixels of its rectified camera K."""
    px = np.asarray(px, dtype=np.float64).reshape(-1, 1, 2)
    if len(px) == 0:
        return np.zeros((0, 2))
    K = camera.K
    # OpenCV 5 folded undistortPointsIter into undistortPoints' criteria argument.
    out = cv2.undistortPoints(px, K, camera.dist, R=None, P=K, criteria=_UNDISTORT_CRITERIA)
    return out.reshape(-1, 2)


def midpoint(centres_world: np.ndarray, dirs_world: np.ndarray) -> np.ndarray:
    """(M,3) ray origins and (M,3) directions -> (3,) point minimising the summed squared
    distances to the rays (linear least squares)."""
    d = dirs_world / np.linalg.norm(dirs_world, axis=1, keepdims=True)
    # Each ray contributes the projector onto the plane perpendicular to it.
    P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    A = P.sum(0)
    b = np.einsum("mij,mj->i", P, centres_world)
    return np.linalg.lstsq(A, b, rcond=None)[0]


def _to_cam(T_world_cam: np.ndarray, xyz_world: np.ndarray) -> np.ndarray:
    R = T_world_cam[:, :3, :3]
    return np.einsum("mji,mj->mi", R, xyz_world[None, :] - T_world_cam[:, :3, 3])


def _residual(xyz_world, T_world_cam, px, K):
    uvw = _to_cam(T_world_cam, xyz_world) @ K.T
    return (uvw[:, :2] / uvw[:, 2:3] - px).ravel()


def _jacobian(xyz_world, T_world_cam, px, K):
    p_cam = _to_cam(T_world_cam, xyz_world)
    uvw = p_cam @ K.T
    uv = uvw[:, :2] / uvw[:, 2:3]
    # d(u,v)/d(p_cam) = (K[:2] - uv K[2]) / w, then through p_cam = R^T (x - c).
    d_cam = (K[None, :2, :] - uv[:, :, None] * K[None, 2:3, :]) / uvw[:, 2, None, None]
    R_cam_world = np.transpose(T_world_cam[:, :3, :3], (0, 2, 1))
    return (d_cam @ R_cam_world).reshape(-1, 3)


def _check_in_front(T_world_cam: np.ndarray, xyz_world: np.ndarray) -> np.ndarray:
    p_cam = _to_cam(T_world_cam, xyz_world)
    behind = np.flatnonzero(p_cam[:, 2] <= 0)
    if len(behind):
        raise TriangulationError(f"behind camera in frame {int(behind[0])}")
    return p_cam


def triangulate(T_world_cam: np.ndarray, px_undist: np.ndarray, K: np.ndarray, *,
                pixel_sigma: float = 1.0, min_ray_angle_deg: float = 1.0,
                max_rms_px: float = 4.0, loss: str = "huber", f_scale_px: float = 2.0,
                max_shift_sigma: float = 10.0) -> TriangulatedPoint:
    """The world point seen at ``px_undist`` (M,2) rectified pixels by cameras ``T_world_cam``
    (M,4,4) with intrinsics ``K`` (3,3).

    The midpoint of the rays starts a robust (``loss``, ``f_scale_px``) least-squares refinement of
    the reprojection error. The covariance comes from the Jacobian at the solution, scaled by the
    squared per-coordinate pixel error: the larger of ``pixel_sigma`` and the residuals' estimate.

    Raises TriangulationError when the rays are nearly parallel, the point is behind an observing
    camera ("frame k": k indexes the M observations), the refinement diverged (failed, non-finite, or moved more than ``max_shift_sigma``
    standard deviations from the midpoint) or the reprojection rms exceeds ``max_rms_px``.
    """
    T_world_cam = np.asarray(T_world_cam, dtype=float).reshape(-1, 4, 4)
    px = np.asarray(px_undist, dtype=float).reshape(-1, 2)
    K = np.asarray(K, dtype=float)
    m = len(px)
    if m < 2 or len(T_world_cam) != m:
        raise TriangulationError(f"need at least 2 posed observations, got {m}")

    rays_cam = np.column_stack([px, np.ones(m)]) @ np.linalg.inv(K).T
    dirs_world = np.einsum("mij,mj->mi", T_world_cam[:, :3, :3], rays_cam)
    dirs_world /= np.linalg.norm(dirs_world, axis=1, keepdims=True)
    cos = np.clip(dirs_world @ dirs_world.T, -1.0, 1.0)
    max_angle_deg = float(np.degrees(np.arccos(cos.min())))
    if max_angle_deg < min_ray_angle_deg:
        raise TriangulationError(f"rays nearly parallel ({max_angle_deg:.1f} deg)")

    xyz0 = midpoint(T_world_cam[:, :3, 3], dirs_world)
    _check_in_front(T_world_cam, xyz0)
    try:
        sol = least_squares(_residual, xyz0, jac=_jacobian, args=(T_world_cam, px, K),
                            loss=loss, f_scale=f_scale_px, method="trf", x_scale="jac")
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise TriangulationError(f"refinement diverged ({exc})") from exc
    xyz = sol.x
    if sol.status <= 0 or not np.all(np.isfinite(xyz)) or not np.all(np.isfinite(sol.fun)):
        raise TriangulationError("refinement diverged")
    p_cam = _check_in_front(T_world_cam, xyz)

    r = _residual(xyz, T_world_cam, px, K)
    rms_px = float(np.sqrt(np.sum(r**2) / m))  # of the per-observation pixel distances
    # Per-coordinate sigma: residual sum over the 2M - 3 degrees of freedom left by the point.
    sigma_px = max(pixel_sigma, float(np.sqrt(np.sum(r**2) / max(2 * m - 3, 1))))
    # The plain Jacobian, not sol.jac: scipy's loss-modified Jacobian vanishes for residuals in
    # Huber's linear zone, which would make a point with a few large residuals look exact.
    J = _jacobian(xyz, T_world_cam, px, K)
    JtJ = J.T @ J
    if np.linalg.cond(JtJ) > 1e12:
        raise TriangulationError("refinement diverged (point not constrained)")
    cov = sigma_px**2 * np.linalg.inv(JtJ)
    cov = 0.5 * (cov + cov.T)
    std_m = largest_std_m(cov)

    shift_m = float(np.linalg.norm(xyz - xyz0))
    if shift_m > max_shift_sigma * std_m:
        raise TriangulationError(
            f"refinement diverged (moved {shift_m:.2f} m from the ray midpoint, std {std_m:.2f} m)")
    if rms_px > max_rms_px:
        raise ReprojectionError(f"reprojection rms {rms_px:.1f} px > {max_rms_px:.1f}",
                                np.hypot(*r.reshape(-1, 2).T))
    return TriangulatedPoint(xyz, cov, std_m, rms_px, p_cam)


def triangulate_inliers(T_world_cam: np.ndarray, px_undist: np.ndarray, K: np.ndarray, *,
                        min_inlier_share: float, min_inliers: int, max_rms_px: float = 4.0,
                        **options) -> tuple[TriangulatedPoint, np.ndarray]:
    """``triangulate``, and while the point reprojects too far from the detections (a box on
    the wrong object, a frame whose pose slipped), again without the worst one, as long as at
    least ``min_inlier_share`` of the track and ``min_inliers`` observations are left. One at a
    time because a few far boxes pull even the robust fit, so that its residuals alone do not
    tell which boxes are wrong. Returns the point and the (M,) bool mask of the observations it
    used; raises the first TriangulationError when no such subset fits."""
    T_world_cam = np.asarray(T_world_cam, dtype=float).reshape(-1, 4, 4)
    px = np.asarray(px_undist, dtype=float).reshape(-1, 2)
    keep = np.ones(len(px), bool)
    first: TriangulationError | None = None
    while True:
        try:
            return triangulate(T_world_cam[keep], px[keep], K, max_rms_px=max_rms_px,
                               **options), keep
        except ReprojectionError as exc:
            first = first or exc
            if keep.sum() - 1 < max(min_inliers, min_inlier_share * len(px)):
                raise first from None
            keep[np.flatnonzero(keep)[np.argmax(exc.residuals_px)]] = False
        except TriangulationError as exc:
            raise (first or exc) from None


def largest_std_m(cov_world: np.ndarray) -> float:
    """Standard deviation (m) along the worst direction of a (3, 3) position covariance."""
    return float(np.sqrt(max(np.linalg.eigvalsh(cov_world)[-1], 0.0)))
