"""Stage 2 of self-calibration: refine fx, fy, cx, cy, k1, k2 together by bundle adjustment.

The stage-1 reconstruction (one focal length, centred principal point, k1) is converted to COLMAP's
OPENCV model (fx, fy, cx, cy, k1, k2, p1, p2) and bundle-adjusted with every intrinsic free except
the tangential terms p1 = p2 = 0, which the paper's radial model does not have. COLMAP's BA flags
switch whole parameter groups, so p1, p2 are held by a Ceres subset manifold on the camera's
parameter block. Runs inside the COLMAP child process (``colmap.sfm``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from app.pipeline.colmap import presets
from app.pipeline.types import INTRINSICS_STD

OPENCV_TANGENTIAL = [6, 7]


def _to_opencv(pycolmap, cam) -> None:
    p = np.asarray(cam.params, dtype=float)
    if cam.model_name == "SIMPLE_RADIAL":
        params = [p[0], p[0], p[1], p[2], p[3], 0.0, 0.0, 0.0]
    elif cam.model_name == "RADIAL":
        params = [p[0], p[0], p[1], p[2], p[3], p[4], 0.0, 0.0]
    else:
        params = list(p[:6]) + [0.0, 0.0]
    cam.model = pycolmap.CameraModelId.OPENCV
    cam.params = np.array(params, dtype=float)


def _aspect_prior(pyceres, params: np.ndarray, sigma: float):
    """A Gaussian prior on an OPENCV parameter block that only says fx = fy to within ``sigma``
    (relative): it is flat (variance ``_FLAT``) in every other direction. Car footage rotates about
    one axis, which leaves fy (and cy) in a shallow valley that the data alone does not pin down.
    A C++ cost (not a Python one): COLMAP's solve holds the GIL, and a Python callback from a
    Ceres worker thread deadlocked."""
    f = 0.5 * (params[0] + params[1])
    mean = np.array(params, dtype=float)
    mean[:2] = f
    along = np.array([1.0, 1.0]) / np.sqrt(2.0)
    across = np.array([1.0, -1.0]) / np.sqrt(2.0)
    cov = np.eye(len(params)) * _FLAT * f * f
    cov[:2, :2] = (_FLAT * f * f * np.outer(along, along)
                   + 0.5 * (sigma * f) ** 2 * np.outer(across, across))
    return pyceres.factors.NormalPrior(mean, cov)


# Relative variance of the directions the aspect prior leaves free: 1e8 makes its pull on them
# ~1e-8 of one pixel's residual.
_FLAT = 1e8


def _bundle_adjust(pycolmap, rec, *, principal_point: bool, loss_scale_px: float,
                   function_tolerance: float, max_iterations: int,
                   aspect_sigma: float = 0.0, threads: int = -1,
                   covariance: bool = False, gauge: "Gauge | None" = None) -> np.ndarray:
    """One bundle adjustment of ``rec`` in place; with ``covariance``, returns the standard
    deviations (6,) of fx, fy, cx, cy (px), k1, k2 that the solution's covariance gives (unit
    pixel noise scaled by the mean reprojection error; nan when they cannot be estimated), else
    nan. ``gauge``: what holds the gauge of each separate part of ``rec`` (None: ``rec`` is one
    part, COLMAP's own choice of two cameras holds it)."""
    import pyceres

    options = presets.options(pycolmap, "BundleAdjustmentOptions",
                              presets.INTRINSICS_BUNDLE_ADJUSTMENT,
                              refine_principal_point=principal_point,
                              **{"ceres.loss_function_scale": loss_scale_px,
                                 "ceres.solver_options.function_tolerance": function_tolerance,
                                 "ceres.solver_options.max_num_iterations": max_iterations,
                                 "ceres.solver_options.num_threads": threads})
    config = pycolmap.BundleAdjustmentConfig()
    for image_id in rec.reg_image_ids():
        config.add_image(image_id)
    if gauge is None:
        config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
    else:
        for frame_id in gauge.frames:
            config.set_constant_rig_from_world_pose(frame_id)
    adjuster = pycolmap.create_default_ceres_bundle_adjuster(options, config, rec)
    problem = adjuster.problem
    # Keep the manifold and the parameter arrays alive in variables until solve() returns: a
    # temporary manifold was seen to segfault inside solve().
    manifolds = []
    params_blocks = []
    for cam in rec.cameras.values():
        params = cam.params
        if problem.has_parameter_block(params) and not problem.is_parameter_block_constant(params):
            manifold = pyceres.SubsetManifold(len(params), OPENCV_TANGENTIAL)
            problem.set_manifold(params, manifold)
            manifolds.append(manifold)
            params_blocks.append(params)
            if aspect_sigma > 0:
                # The prior weighs like one observation against thousands: it only decides
                # where the reprojection error is flat.
                prior = _aspect_prior(pyceres, params, aspect_sigma)
                problem.add_residual_block(prior, None, [params])
                manifolds.append(prior)
    adjuster.solve()
    rec.update_point_3d_errors()
    std = np.full(len(INTRINSICS_STD), np.nan)
    if covariance and params_blocks:
        std = _intrinsics_std(pycolmap, rec, adjuster, params_blocks[0])
    del manifolds, params_blocks
    return std


def _intrinsics_std(pycolmap, rec, adjuster, params: np.ndarray) -> np.ndarray:
    """sigma of each of ``INTRINSICS_STD`` from COLMAP's covariance of the camera block: the
    OPENCV parameters its tangent space keeps, in that order (p1, p2 are held)."""
    std = np.full(len(INTRINSICS_STD), np.nan)
    cov = pycolmap.estimate_ba_covariance(pycolmap.BACovarianceOptions(), rec, adjuster)
    if cov is None:
        return std
    block = cov.get_other_params_cov(params)
    if block is None or block.shape[0] < len(std):
        return std
    rms_px = float(rec.compute_mean_reprojection_error())
    diag = np.diag(block)[: len(std)]
    return np.where(np.isfinite(diag), np.sqrt(np.clip(diag, 0.0, None)) * rms_px, np.nan)


@dataclass(frozen=True)
class Gauge:
    """The frames whose poses a bundle adjustment holds: in a reconstruction of separate parts
    (``colmap.joint``), one per part (COLMAP's gauge holds one connected part only)."""

    frames: tuple[int, ...] = ()


def refine_all_intrinsics(pycolmap, rec, *, filter_max_error_px: float = 4.0,
                          function_tolerance: float = 1e-6, max_iterations: int = 1000,
                          aspect_sigma: float = 0.0, threads: int = -1,
                          gauge: Gauge | None = None) -> np.ndarray:
    """Stage 2 in place on ``rec``: OPENCV model, all intrinsics but p1, p2 refined. Returns
    the standard deviations (6,) of ``INTRINSICS_STD`` from COLMAP's covariance of its solution
    (nan where there is none).

    Two passes: first focal lengths and distortion with the principal point held (it is the
    weakest-determined group and must not absorb the large stage-1 focal error), then everything;
    observations with large errors are dropped in between and after: the robust loss leaves a few
    points far off (errors of 1e100 px were seen) that would swamp the mean reprojection error by
    which candidate windows are judged, and so reject a right calibration.

    ``function_tolerance``: Ceres stops when an iteration lowers the cost by less than this
    fraction. COLMAP's 0 ran both passes to 100 iterations: 7.7 s on turn-70's 22 images, 2.4 s
    at 1e-6 with every intrinsic within 0.1 % of the same. ``gauge``: see ``_bundle_adjust``.
    ``max_iterations``: the
    limit of each adjustment; a stage 1 far off can need more than 100 iterations down stage 2's
    shallow valley (tuning c0800 stopped at fx -8.3 % after 100, reached -0.05 % within 1000).

    ``aspect_sigma`` > 0 adds a prior fx = fy with that relative standard deviation.
    ``threads``: Ceres threads (-1: every core; 1 gives the same result on every run).
    """
    for cam in rec.cameras.values():
        _to_opencv(pycolmap, cam)
    _bundle_adjust(pycolmap, rec, principal_point=False, loss_scale_px=2.0,
                   function_tolerance=function_tolerance, max_iterations=max_iterations,
                   threads=threads, gauge=gauge)
    _filter_observations(pycolmap, rec, filter_max_error_px)
    std = _bundle_adjust(pycolmap, rec, principal_point=True, loss_scale_px=1.0,
                         function_tolerance=function_tolerance, max_iterations=max_iterations,
                         aspect_sigma=aspect_sigma, threads=threads, covariance=True,
                         gauge=gauge)
    _filter_observations(pycolmap, rec, filter_max_error_px)
    return std


def _filter_observations(pycolmap, rec, max_error_px: float) -> None:
    pycolmap.ObservationManager(rec).filter_all_points3D(max_error_px, 1.5)


def _held_fit(pycolmap, rec, params: np.ndarray, max_iterations: int, threads: int,
              function_tolerance: float):
    """A copy of ``rec`` bundle-adjusted with the camera held at the OPENCV ``params``
    (``function_tolerance`` 0: every iteration up to ``max_iterations``)."""
    held = pycolmap.Reconstruction(rec)
    for cam in held.cameras.values():
        cam.model = pycolmap.CameraModelId.OPENCV
        cam.params = np.asarray(params, dtype=float)
    options = presets.options(pycolmap, "BundleAdjustmentOptions",
                              presets.INTRINSICS_BUNDLE_ADJUSTMENT,
                              refine_focal_length=False, refine_principal_point=False,
                              refine_extra_params=False,
                              **{"ceres.loss_function_scale": 1.0,
                                 "ceres.solver_options.max_num_iterations": max_iterations,
                                 "ceres.solver_options.function_tolerance": function_tolerance,
                                 "ceres.solver_options.num_threads": threads})
    _global_bundle_adjustment(pycolmap, held, options)
    return held


def _global_bundle_adjustment(pycolmap, rec, options) -> None:
    """What ``pycolmap.bundle_adjustment`` does (COLMAP's BundleAdjustmentController; the same
    result to the bit), without its OptionManager: that resets glog to log everything to stderr,
    which printed COLMAP's log without ``--verbose`` (``sfm._pycolmap`` sets it)."""
    pycolmap.ObservationManager(rec).filter_observations_with_negative_depth()
    config = pycolmap.BundleAdjustmentConfig()
    for image_id in rec.reg_image_ids():
        config.add_image(image_id)
    config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
    pycolmap.create_default_bundle_adjuster(options, config, rec).solve()
    rec.update_point_3d_errors()


def errors_by_image(rec) -> dict[int, np.ndarray]:
    """Per posed image id with observations, each observation's reprojection error (px; nan
    where the point is behind the camera), projected image by image in one call (a call per
    observation took 1 s on turn-70's window)."""
    xyz = {point_id: point.xyz for point_id, point in rec.points3D.items()}
    out = {}
    for image_id, image in rec.images.items():
        observed = image.get_observation_points2D() if image.has_pose else []
        if not observed:
            continue
        xy_observed = np.array([p.xy for p in observed])  # (M, 2)
        p_model = np.array([xyz[p.point3D_id] for p in observed])  # (M, 3)
        T_cam_model = np.asarray(image.cam_from_world().matrix())  # (3, 4)
        p_cam = p_model @ T_cam_model[:, :3].T + T_cam_model[:, 3]
        xy = rec.camera(image.camera_id).img_from_cam(p_cam)  # nan rows behind the camera
        out[image_id] = np.linalg.norm(xy - xy_observed, axis=1)
    return out


def _errors_px(rec) -> np.ndarray:
    """Every observation's reprojection error (px; ``errors_by_image``), in one array."""
    return np.concatenate([np.zeros(0), *errors_by_image(rec).values()])


def _thinned(pycolmap, rec, max_points: int):
    """A copy of ``rec`` with at most ``max_points`` of its points, evenly spread over their
    ids (COLMAP numbers points as it triangulates them, so every part of the window keeps some)."""
    out = pycolmap.Reconstruction(rec)
    ids = sorted(out.point3D_ids())
    if len(ids) > max_points:
        keep = {ids[i] for i in np.linspace(0, len(ids) - 1, max_points).round().astype(int)}
        for point_id in ids:
            if point_id not in keep:
                out.delete_point3D(point_id)
    return out


def _cauchy_cost(rec) -> float:
    """Stage 2's robust cost (Cauchy, 1 px) of ``rec``'s observations in front of their camera.
    Counting the few behind it as far off (27.6 each) hid the way out of tuning c0888's stuck
    structure on 1500 points: 5 such points at fx x 0.97 against 1 at its own camera
    (docs/decisions/stage2-probe.md)."""
    errors = _errors_px(rec)
    return float(np.sum(np.log1p(errors[np.isfinite(errors)] ** 2)))


def probe_focal(pycolmap, rec, *, step: float, max_moves: int,
                refine: Callable[[object], np.ndarray], max_points: int = 1500,
                max_iterations: int = 200, function_tolerance: float = 1e-6,
                threads: int = -1) -> tuple[object, list[float], np.ndarray | None]:
    """Stage 2 ends at the minimum of the structure stage 1 built; from a stage 1 13 % off that
    was 28 % short on a tuning window whose images fit the truth far better
    (docs/decisions/stage2-probe.md). So: hold the camera at its fx, fy times
    1 - ``step`` and 1 + ``step`` and at itself, each in a bundle adjustment of poses and points
    (Cauchy, 1 px; stopping as stage 2's do at ``function_tolerance``: COLMAP's default 0 ran
    each fit to 200 iterations, 6 s on tuning c0846); when a probe costs less than the camera
    itself, ``refine`` (stage 2) runs again from the whole window adjusted to that camera. At
    most ``max_moves`` times.

    The three fits that decide see ``max_points`` of the window's points (``_thinned``): on
    turn-70's 7849 they cost 10 s, on 1500 under 2 s, and the ordering held (the held camera's
    extra cost is a sum over points, so it shrinks with them but keeps its sign). Returns the
    reconstruction, the scales moved by, and the last ``refine``'s result (None if it never
    ran)."""
    moves: list[float] = []
    std = None
    for _ in range(max_moves):
        own = np.asarray(next(iter(rec.cameras.values())).params, dtype=float)
        sample = _thinned(pycolmap, rec, max_points)
        fits = []
        for scale in (1.0, 1.0 - step, 1.0 + step):
            params = own.copy()
            params[:2] *= scale
            held = _held_fit(pycolmap, sample, params, max_iterations, threads,
                             function_tolerance)
            fits.append((_cauchy_cost(held), scale, params))
        _, scale, params = min(fits, key=lambda f: f[0])
        if scale == 1.0:
            break
        rec = _held_fit(pycolmap, rec, params, max_iterations, threads, function_tolerance)
        std = refine(rec)
        moves.append(scale)
    return rec, moves, std
