"""One bundle adjustment over many calibrated windows that share a camera (issue 66's joint
calibration; the choice of windows is ``cameras.calibrate_jointly``'s). Runs in a COLMAP child
process (``fit_jointly``), as ``colmap.sfm`` does.

Each window is a separate part of one reconstruction, in its own model frame and scale: its poses
and points stay its own, the camera is one. The windows were calibrated each with its own camera,
so each is first adjusted alone with the camera held at the start (its poses and points move to
fit it), then all together with every intrinsic free (stage 2's two passes, ``refine``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.pipeline.colmap.refine import Gauge, _held_fit, errors_by_image, refine_all_intrinsics
from app.pipeline.colmap.sfm import COLMAP_PIXEL_OFFSET, _colmap_camera, camera_model, colmap_pool
from app.pipeline.types import CameraModel, WindowObservations

# Points per window in the joint adjustment, a cap (the fleet corpus's windows have 1,200-9,300):
# thinned to 3,000 the tuning half's cameras were 0.05-0.17 % off in fx, with all their points
# 0.01-0.10 %, and the distortion 0.46 px off on one camera against 0.09 px, at twice the time
# (7-20 s for 2-7 windows; docs/decisions/camera-joint-calibration.md).
MAX_POINTS_PER_WINDOW = 20000


@dataclass(frozen=True)
class JointFit:
    """The shared camera; ``intrinsics_std`` (6,) sigma of ``types.INTRINSICS_STD`` from the
    joint covariance (nan: not estimable); ``rms_px`` (W,) each window's RMS reprojection error
    under it (observations in front of the camera, clipped at 4 px)."""

    camera: CameraModel
    intrinsics_std: np.ndarray
    rms_px: np.ndarray


def fit_jointly(windows: list[WindowObservations], start: CameraModel, *,
                max_iterations: int = 1000, function_tolerance: float = 1e-6,
                aspect_sigma: float = 0.0, threads: int = -1,
                max_points: int = MAX_POINTS_PER_WINDOW) -> JointFit:
    """The camera that every window of ``windows`` fits best, from ``start``, in a child
    process (COLMAP can abort the process it runs in); each window thinned to ``max_points``."""
    with colmap_pool(1) as pool:
        return pool.submit(_fit, windows, start, max_iterations, function_tolerance,
                           aspect_sigma, threads, max_points).result()


def _fit(windows, start, max_iterations, function_tolerance, aspect_sigma, threads,
         max_points) -> JointFit:
    import pycolmap

    # As the mapping children do (``sfm._pycolmap``). Each window's scale is free (``Gauge``), so
    # Ceres warns of steps it could not take in that direction and damps them: not an error.
    pycolmap.logging.minloglevel = 3
    pycolmap.logging.logtostderr = True

    params = np.asarray(_colmap_camera(pycolmap, start).params, dtype=float)
    parts = []
    for window in windows:
        alone = _reconstruction(pycolmap, [thinned(window, max_points)], start)[0]
        parts.append(_held_fit(pycolmap, alone, params, 200, threads, function_tolerance))
    rec, gauge, image_part = _merged(pycolmap, parts)
    std = refine_all_intrinsics(pycolmap, rec, function_tolerance=function_tolerance,
                                max_iterations=max_iterations, aspect_sigma=aspect_sigma,
                                threads=threads, gauge=gauge)
    camera = camera_model(next(iter(rec.cameras.values())))
    return JointFit(camera, np.asarray(std, float), _rms_per_part(rec, image_part, len(parts)))


def thinned(window: WindowObservations, max_points: int) -> WindowObservations:
    """At most ``max_points`` of the window's points (evenly over their order, which follows
    the images), with their observations."""
    n = len(window.xyz_model)
    if n <= max_points:
        return window
    keep = np.unique(np.linspace(0, n - 1, max_points).round().astype(int))
    new_index = np.full(n, -1)
    new_index[keep] = np.arange(len(keep))
    obs = new_index[window.obs_point] >= 0
    return WindowObservations(window.label, window.T_cam_model, window.xyz_model[keep],
                              window.xy_px[obs], window.obs_image[obs],
                              new_index[window.obs_point[obs]])


def _reconstruction(pycolmap, windows: list[WindowObservations], camera: CameraModel):
    """One reconstruction of ``windows`` as separate parts seen by one OPENCV ``camera``; the
    gauge that holds each part (its first image's pose; its scale is left to the solver's
    damping: a point held as well pinned a test window's fx 0.8 % from where its images put it,
    the valley being that shallow); and the part of each image id."""
    rec = pycolmap.Reconstruction()
    cam = _colmap_camera(pycolmap, camera)
    cam.camera_id = 1
    rec.add_camera_with_trivial_rig(cam)
    frames, image_part = [], {}
    next_id = 1
    for part, window in enumerate(windows):
        ids = []
        for k, T_cam_model in enumerate(window.T_cam_model):
            xy = window.xy_px[window.obs_image == k] + COLMAP_PIXEL_OFFSET
            points2D = pycolmap.Point2DList([pycolmap.Point2D(p) for p in xy])
            pose = pycolmap.Rigid3d(pycolmap.Rotation3d(T_cam_model[:3, :3]), T_cam_model[:3, 3])
            rec.add_image_with_trivial_frame(
                pycolmap.Image(name=f"{part}/{k}", points2D=points2D, camera_id=1,
                               image_id=next_id), pose)
            ids.append(next_id)
            image_part[next_id] = part
            next_id += 1
        # Each observation's index among its image's points2D, in the order added above.
        idx_in_image = np.zeros(len(window.obs_image), dtype=int)
        for k in range(len(window.T_cam_model)):
            rows = np.flatnonzero(window.obs_image == k)
            idx_in_image[rows] = np.arange(len(rows))
        order = np.argsort(window.obs_point, kind="stable")
        bounds = np.searchsorted(window.obs_point[order], np.arange(len(window.xyz_model) + 1))
        for p, xyz in enumerate(window.xyz_model):
            rows = order[bounds[p]:bounds[p + 1]]
            if len(rows) < 2:
                continue
            track = pycolmap.Track()
            for r in rows:
                track.add_element(ids[window.obs_image[r]], int(idx_in_image[r]))
            rec.add_point3D(xyz, track, np.zeros(3, dtype=np.uint8))
        frames.append(rec.image(ids[0]).frame_id)
    return rec, Gauge(tuple(frames)), image_part


def _merged(pycolmap, parts: list):
    """``_reconstruction`` of the adjusted single-part reconstructions ``parts``."""
    windows = [_observations(rec) for rec in parts]
    camera = camera_model(next(iter(parts[0].cameras.values())))
    return _reconstruction(pycolmap, windows, camera)


def _observations(rec) -> WindowObservations:
    from app.pipeline.colmap.sfm import window_observations

    names = sorted((im.name for im in rec.images.values() if im.has_pose),
                   key=lambda n: int(n.split("/")[1]))
    return window_observations(rec, names)


def _rms_per_part(rec, image_part: dict[int, int], n_parts: int) -> np.ndarray:
    """(n_parts,) rms reprojection error (px) of each part's images (``image_part``: image id ->
    part), an error capped at 4 px and a point behind the camera counted as 4 px."""
    errors: list[list[np.ndarray]] = [[] for _ in range(n_parts)]
    for image_id, e in errors_by_image(rec).items():
        errors[image_part[image_id]].append(e)
    out = np.full(n_parts, np.nan)
    for part, chunks in enumerate(errors):
        if chunks:
            e = np.minimum(np.nan_to_num(np.concatenate(chunks), nan=4.0), 4.0)
            out[part] = float(np.sqrt(np.mean(e ** 2)))
    return out
