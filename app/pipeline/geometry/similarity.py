"""Align a monocular reconstruction (arbitrary frame and scale) to GPS: a similarity (Umeyama).

Frames: ``model`` is the reconstruction's frame, ``world`` the journey's ENU frame (metres).
A ``Sim3`` maps model -> world: ``p_world = scale * R @ p_model + t``.

A straight stretch of road leaves the rotation about the road's line unobserved by positions; GPS
noise then picks it at random and the whole reconstruction rolls about the road.
``align_trajectory`` detects that and fixes the roll from a longer alignment or from gravity
(cameras mounted level).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pycolmap
from scipy.spatial.transform import Rotation


@dataclass(frozen=True)
class Sim3:
    scale: float
    R: np.ndarray  # (3,3) rotation model -> world
    t: np.ndarray  # (3,)

    def apply(self, p: np.ndarray) -> np.ndarray:
        """(N,3) or (3,) model points -> world points of the same shape: s R p + t."""
        p = np.asarray(p, dtype=float)
        return self.scale * p @ self.R.T + self.t

    def apply_poses(self, T_model_cam: np.ndarray) -> np.ndarray:
        """(N,4,4) camera poses cam -> model -> (N,4,4) T_world_cam, rotation part a pure rotation
        (the scale moves camera centres, it does not belong in a pose)."""
        T_model_cam = np.asarray(T_model_cam, dtype=float)
        T_world_cam = np.zeros_like(T_model_cam)
        T_world_cam[:, :3, :3] = self.R @ T_model_cam[:, :3, :3]
        T_world_cam[:, :3, 3] = self.apply(T_model_cam[:, :3, 3])
        T_world_cam[:, 3, 3] = 1.0
        return T_world_cam

    def inverse(self) -> "Sim3":
        R_inv = self.R.T
        return Sim3(1.0 / self.scale, R_inv, -(R_inv @ self.t) / self.scale)

    def partial(self, weight: float, pivot: np.ndarray) -> "Sim3":
        """This similarity taken ``weight`` of the way from the identity (0: identity, 1: itself):
        its rotation angle and log scale times ``weight``, and ``pivot`` (3,) moved ``weight`` of
        the way to where this similarity takes it."""
        R = Rotation.from_rotvec(weight * Rotation.from_matrix(self.R).as_rotvec()).as_matrix()
        scale = self.scale**weight
        pivot = np.asarray(pivot, dtype=float)
        target = pivot + weight * (self.apply(pivot) - pivot)
        return Sim3(scale, R, target - scale * R @ pivot)


def umeyama(src: np.ndarray, dst: np.ndarray, *, with_scale: bool = True,
            robust_max_error_m: float | None = None) -> Sim3:
    """Least-squares similarity ``dst ~ s R src + t`` (Umeyama 1991); src, dst (N,3), N >= 3.

    ``with_scale=False`` fixes s = 1 (rigid). ``robust_max_error_m`` switches to COLMAP's LO-RANSAC
    with that inlier threshold in dst units (for GPS outliers; needs ``with_scale``).
    Raises ValueError for fewer than 3 points or a point set that fixes no rotation (e.g. src
    exactly collinear).
    """
    src, dst = _check_pair(src, dst)
    if not with_scale:
        if robust_max_error_m is not None:
            raise ValueError("robust alignment is only available with scale")
        src_c, dst_c = src - src.mean(0), dst - dst.mean(0)
        R = Rotation.align_vectors(dst_c, src_c)[0].as_matrix()
        return Sim3(1.0, R, dst.mean(0) - R @ src.mean(0))
    if robust_max_error_m is None:
        sim = pycolmap.estimate_sim3d(src, dst)
    else:
        # Seeded: the same journey mends the same way on every run.
        found = pycolmap.estimate_sim3d_robust(
            src, dst, pycolmap.RANSACOptions(max_error=float(robust_max_error_m), random_seed=0))
        sim = None if found is None else found["tgt_from_src"]
    if sim is None:
        raise ValueError("degenerate point set: the similarity is not determined")
    return Sim3(float(sim.scale), np.array(sim.rotation.matrix()), np.array(sim.translation))


def align_trajectory(centres_model: np.ndarray, xyz_gps: np.ndarray, R_model_cam: np.ndarray, *,
                     up: np.ndarray = np.array([0.0, 0.0, 1.0]),
                     R_fallback: np.ndarray | None = None, collinear_ratio: float = 0.05,
                     min_lateral_spread_m: float = 1.5,
                     robust_max_error_m: float | None = None) -> tuple[Sim3, dict]:
    """Similarity model -> world mapping camera centres onto their GPS positions.

    centres_model (N,3): camera centres of the reconstruction; xyz_gps (N,3): their GPS positions,
    ENU metres; R_model_cam (N,3,3): camera orientations cam -> model.

    When the GPS points are nearly collinear (second singular value of the centred points below
    ``collinear_ratio`` times the first, or their rms distance from the best-fit line below
    ``min_lateral_spread_m``: GPS noise alone then decides the roll) positions fix everything but
    the roll about the line.
    The roll is then taken from ``R_fallback`` (a model -> world rotation of a longer,
    non-degenerate alignment) if given, else from gravity: the cameras' mean x axis (right) is made
    horizontal and their mean y axis (down) to point down.

    Returns (sim, info) with info ``{"degenerate", "rms_m", "n", "scale", "roll_from"}``,
    ``roll_from`` one of ``"positions"``, ``"fallback"``, ``"gravity"``.
    """
    centres_model, xyz_gps = _check_pair(centres_model, xyz_gps)
    sv = np.linalg.svd(xyz_gps - xyz_gps.mean(0), compute_uv=False)
    if sv[0] <= 1e-9 * max(1.0, float(np.abs(xyz_gps).max())):
        raise ValueError("GPS positions do not move: no alignment possible")
    lateral_rms_m = sv[1] / np.sqrt(len(xyz_gps))
    degenerate = bool(sv[1] < collinear_ratio * sv[0] or lateral_rms_m < min_lateral_spread_m)
    if not degenerate:
        sim, roll_from = umeyama(centres_model, xyz_gps,
                                 robust_max_error_m=robust_max_error_m), "positions"
    else:
        u_model, u_world = _line_directions(centres_model, xyz_gps)
        if R_fallback is not None:
            R, roll_from = _roll_from_fallback(u_model, u_world, np.asarray(R_fallback)), "fallback"
        else:
            R_model_cam = np.asarray(R_model_cam, dtype=float).reshape(-1, 3, 3)
            R, roll_from = _roll_from_gravity(u_model, u_world, R_model_cam,
                                              np.asarray(up, float)), "gravity"
        sim = _similarity_with_rotation(centres_model, xyz_gps, R)
    residual = sim.apply(centres_model) - xyz_gps
    rms_m = float(np.sqrt(np.mean(np.sum(residual**2, axis=1))))
    info = {"degenerate": degenerate, "rms_m": rms_m, "n": len(xyz_gps), "scale": sim.scale,
            "roll_from": roll_from}
    return sim, info


def _check_pair(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    src = np.asarray(src, dtype=float)
    dst = np.asarray(dst, dtype=float)
    if src.ndim != 2 or src.shape[1] != 3 or src.shape != dst.shape:
        raise ValueError(f"expected two (N,3) arrays, got {src.shape} and {dst.shape}")
    if len(src) < 3:
        raise ValueError(f"need at least 3 point pairs, got {len(src)}")
    return src, dst


def _line_directions(centres_model: np.ndarray, xyz_gps: np.ndarray) -> tuple[np.ndarray, ...]:
    """Unit directions (3,) of the best-fit lines of both point sets, signed so that they point the
    same way along the journey."""
    dirs = []
    proj = []
    for p in (centres_model, xyz_gps):
        p_c = p - p.mean(0)
        u = np.linalg.svd(p_c, full_matrices=False)[2][0]
        dirs.append(u)
        proj.append(p_c @ u)
    if np.dot(proj[0], proj[1]) < 0:
        dirs[0] = -dirs[0]
    return dirs[0], dirs[1]


def _roll_from_fallback(u_model: np.ndarray, u_world: np.ndarray,
                        R_fallback: np.ndarray) -> np.ndarray:
    """The rotation taking u_model exactly onto u_world that is closest to R_fallback."""
    e_model = np.linalg.svd(u_model[None, :])[2][1:]  # (2,3) orthonormal, perpendicular to line
    a = np.vstack([u_world, e_model @ R_fallback.T])
    b = np.vstack([u_model, e_model])
    return Rotation.align_vectors(a, b, weights=[np.inf, 1.0, 1.0])[0].as_matrix()


def _roll_from_gravity(u_model: np.ndarray, u_world: np.ndarray, R_model_cam: np.ndarray,
                       up: np.ndarray) -> np.ndarray:
    """The rotation taking u_model onto u_world under which the mean camera x axis is horizontal
    and the mean y axis points down."""
    up = up / np.linalg.norm(up)
    x_model = R_model_cam[:, :, 0].mean(0)
    y_model = R_model_cam[:, :, 1].mean(0)
    R_base = Rotation.align_vectors(u_world[None, :], u_model[None, :])[0]
    x_world = R_base.apply(x_model)
    # Rolling by phi about u: up . x(phi) = c + a cos(phi) + b sin(phi); solve for zero.
    x_along = np.dot(x_world, u_world) * u_world
    c = np.dot(up, x_along)
    a = np.dot(up, x_world - x_along)
    b = np.dot(up, np.cross(u_world, x_world))
    phi0 = np.arctan2(b, a)
    rho = np.hypot(a, b)
    # When no roll makes x exactly horizontal (x nearly along the line) the clip takes the closest.
    delta = np.arccos(np.clip(-c / rho, -1.0, 1.0)) if rho > 0 else 0.0
    candidates = [Rotation.from_rotvec(phi * u_world) * R_base
                  for phi in (phi0 + delta, phi0 - delta)]
    return min(candidates, key=lambda r: np.dot(up, r.apply(y_model))).as_matrix()


def _similarity_with_rotation(src: np.ndarray, dst: np.ndarray, R: np.ndarray) -> Sim3:
    """Least-squares scale and translation of dst ~ s R src + t for a fixed rotation R."""
    src_c, dst_c = src - src.mean(0), dst - dst.mean(0)
    scale = float(np.sum(dst_c * (src_c @ R.T)) / np.sum(src_c**2))
    return Sim3(scale, R, dst.mean(0) - scale * R @ src.mean(0))


# Does a reconstruction keep one scale along its cameras' path? Compared with GPS. Where the
# mapper collapsed part of a window's translation (the cameras of its first half almost still, the
# rest moving), no single scale fits, and the intrinsics stage 2 then pins fit that structure, not
# the lens: tuning c0838, fx +1.9 %, first-third chords 0.4x and last-third 17x the middle's
# against the true centres (docs/decisions/calib-path-scale.md).
def scale_spread(c_model: np.ndarray, xyz_gps_m: np.ndarray, *, n_segments: int = 3,
                 min_chord_m: float = 4.0) -> float:
    """The largest over the smallest of the model's chord / the GPS's chord over ``n_segments``
    consecutive stretches of equal GPS road length (1: one scale fits). ``c_model`` (K, 3):
    camera centres in the model frame, ``xyz_gps_m`` (K, 3): the same frames' GPS positions
    (metres), both in travel order. NaN when a stretch's GPS chord is under ``min_chord_m``
    (the car stood, or the window is too short for the GPS to say)."""
    c_model = np.asarray(c_model, dtype=float)
    xyz_gps_m = np.asarray(xyz_gps_m, dtype=float)
    if len(c_model) < n_segments + 1:
        return float("nan")
    s_m = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xyz_gps_m, axis=0), axis=1))])
    bounds = np.searchsorted(s_m, np.linspace(0.0, s_m[-1], n_segments + 1))
    bounds[-1] = len(s_m) - 1
    ratios = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        gps_m = float(np.linalg.norm(xyz_gps_m[b] - xyz_gps_m[a]))
        if b <= a or gps_m < min_chord_m:
            return float("nan")
        ratios.append(float(np.linalg.norm(c_model[b] - c_model[a])) / gps_m)
    return max(ratios) / max(min(ratios), 1e-12)
