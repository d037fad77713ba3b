"""COLMAP (pycolmap) structure-from-motion on windows of a journey's frames.

Used by self-calibration (intrinsics free) and by ego-motion (intrinsics fixed). Features are
extracted and matched once per journey into one database; each window is then mapped separately
(``IncrementalPipelineOptions.image_names``) so cost grows with the number of windows, not with the
square of the journey's length.

All COLMAP work runs in a spawned child process: fatal COLMAP errors abort the process (glog
``CHECK``), and that must fail the journey with a reason, never kill a worker. This is also the only
module that knows COLMAP's pixel convention (pixel centres at +0.5) and converts at the boundary.
"""

from __future__ import annotations

import concurrent.futures as cf
import logging
import multiprocessing
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from app.pipeline.types import CameraModel, PipelineError

log = logging.getLogger(__name__)

COLMAP_PIXEL_OFFSET = 0.5


@dataclass(frozen=True)
class FeatureOptions:
    """How COLMAP extracts, matches and maps (``PipelineConfig`` documents each knob)."""

    max_features: int = 2048
    max_image_size: int = 1600
    first_octave: int = 0
    overlap: int = 6
    threads: int = 2
    ba_max_refinements: int = 1


@dataclass(frozen=True)
class WindowRequest:
    """One window to map. ``camera`` None means unknown intrinsics (self-calibration)."""

    image_names: list[str]
    camera: CameraModel | None
    calibrate: bool = False
    use_position_priors: bool = False
    # Two of ``image_names`` to start the reconstruction from (None: COLMAP's choice, which favours
    # the most matched pair: neighbouring frames whose short forward baseline can fix a wrong
    # relative pose that bundle adjustment never leaves). Falls back to COLMAP's choice on failure.
    init_pair: tuple[str, str] | None = None


@dataclass
class WindowResult:
    """A window's reconstruction in its own (arbitrary) model frame and scale.

    ``T_model_cam``: (M, 4, 4) poses of the registered images listed in ``image_names``.
    """

    image_names: list[str]
    T_model_cam: np.ndarray
    camera: CameraModel
    stage1_camera: CameraModel | None = None
    reprojection_error_px: float = float("nan")
    n_points: int = 0
    n_input: int = 0
    error: str | None = None
    mapping_s: float = 0.0  # wall time COLMAP spent mapping (and refining) this window


@dataclass(frozen=True)
class SfmJob:
    image_dir: Path
    workdir: Path
    width: int
    height: int
    extract_names: list[str]  # empty: reuse the features already in workdir
    windows: list[WindowRequest]
    features: FeatureOptions = field(default_factory=FeatureOptions)
    verbose: bool = False
    # GPS positions (ENU metres) of the extracted images, by image name, and their 1-sigma noise
    # (horizontal, vertical): pose priors that keep long windows free of monocular scale drift.
    prior_enu: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    prior_std_m: tuple[float, float] = (0.5, 1.0)


def run_sfm(job: SfmJob) -> list[WindowResult]:
    """Extract, match and map every window of ``job`` in a child process; one result per window."""
    ctx = multiprocessing.get_context("spawn")
    with cf.ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        try:
            results, timings_s = pool.submit(_run_in_child, job).result()
        except cf.process.BrokenProcessPool as exc:
            raise PipelineError("colmap", "COLMAP aborted the process (see the worker log); "
                                          "the images may be too few or too poor to match") from exc
    if job.extract_names:
        log.info("COLMAP: features of %d images extracted in %.1f s, matched in %.1f s",
                 len(job.extract_names), timings_s["extract"], timings_s["match"])
    return results


# --- everything below runs in the child process --------------------------------------------------

def _run_in_child(job: SfmJob) -> tuple[list[WindowResult], dict[str, float]]:
    import pycolmap

    pycolmap.logging.minloglevel = 0 if job.verbose else 2
    pycolmap.logging.logtostderr = True
    job.workdir.mkdir(parents=True, exist_ok=True)
    database = job.workdir / "features.db"
    if job.extract_names:
        if database.exists():
            database.unlink()
        timings_s = _extract_and_match(pycolmap, job, database)
    else:
        timings_s = {}
    if not database.exists():
        raise RuntimeError("no feature database to map from")
    results = []
    for i, window in enumerate(job.windows):
        t0 = time.perf_counter()
        result = _map_window(pycolmap, job, database, i, window)
        result.mapping_s = round(time.perf_counter() - t0, 3)
        results.append(result)
    return results, timings_s


def _extract_and_match(pycolmap, job: SfmJob, database: Path) -> dict[str, float]:
    """Features and sequential matches of ``job.extract_names``; returns wall seconds per step."""
    opts = job.features
    t0 = time.perf_counter()
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "SIMPLE_RADIAL"
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = opts.threads
    extraction.max_image_size = opts.max_image_size
    extraction.sift.max_num_features = opts.max_features
    extraction.sift.first_octave = opts.first_octave
    pycolmap.extract_features(database, job.image_dir, image_names=job.extract_names,
                              camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                              extraction_options=extraction, device=pycolmap.Device.cpu)
    t1 = time.perf_counter()
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = opts.threads
    pairing = pycolmap.SequentialPairingOptions()
    pairing.overlap = opts.overlap
    pairing.quadratic_overlap = False
    pairing.loop_detection = False  # needs a vocabulary file it would try to download
    pycolmap.match_sequential(database, matching_options=matching, pairing_options=pairing,
                              device=pycolmap.Device.cpu)
    timings_s = {"extract": t1 - t0, "match": time.perf_counter() - t1}
    if job.prior_enu:
        h, v = job.prior_std_m
        cov = np.diag([h * h, h * h, v * v])
        with pycolmap.Database.open(database) as db:
            for image in db.read_all_images():
                if image.name in job.prior_enu:
                    db.write_pose_prior(pycolmap.PosePrior(
                        corr_data_id=image.data_id, position=np.asarray(job.prior_enu[image.name]),
                        position_covariance=cov,
                        coordinate_system=pycolmap.PosePriorCoordinateSystem.CARTESIAN))
    return timings_s


def _colmap_camera(pycolmap, camera: CameraModel):
    params = [camera.fx, camera.fy, camera.cx + COLMAP_PIXEL_OFFSET,
              camera.cy + COLMAP_PIXEL_OFFSET, camera.k1, camera.k2, 0.0, 0.0]
    return pycolmap.Camera(model="OPENCV", width=camera.width, height=camera.height, params=params)


def _camera_model(cam) -> CameraModel:
    """A COLMAP SIMPLE_RADIAL / RADIAL / OPENCV camera -> CameraModel (OpenCV pixels)."""
    p = np.asarray(cam.params, dtype=float)
    name = cam.model_name
    if name == "SIMPLE_RADIAL":
        fx = fy = p[0]; cx, cy = p[1], p[2]; k1, k2 = p[3], 0.0
    elif name == "RADIAL":
        fx = fy = p[0]; cx, cy = p[1], p[2]; k1, k2 = p[3], p[4]
    elif name == "OPENCV":
        fx, fy, cx, cy, k1, k2 = p[:6]
    else:
        raise ValueError(f"unexpected COLMAP camera model {name}")
    return CameraModel(int(cam.width), int(cam.height), float(fx), float(fy),
                       float(cx - COLMAP_PIXEL_OFFSET), float(cy - COLMAP_PIXEL_OFFSET),
                       float(k1), float(k2))


def _map_window(pycolmap, job: SfmJob, database: Path, index: int,
                window: WindowRequest) -> WindowResult:
    out = job.workdir / f"window_{index:03d}"
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    fixed = window.camera is not None and not window.calibrate
    db_path = database
    if window.camera is not None:
        # The database holds one camera; give this window its own copy with the known intrinsics
        # (fixed) or the stage-1 starting point (one focal, centred principal point, k1 = 0).
        db_path = out / "window.db"
        shutil.copyfile(database, db_path)
        with pycolmap.Database.open(db_path) as db:
            for cam in db.read_all_cameras():
                if window.calibrate:
                    c = window.camera
                    new = pycolmap.Camera(model="SIMPLE_RADIAL", width=c.width, height=c.height,
                                          params=[c.fx, c.cx + COLMAP_PIXEL_OFFSET,
                                                  c.cy + COLMAP_PIXEL_OFFSET, 0.0])
                else:
                    new = _colmap_camera(pycolmap, window.camera)
                new.camera_id = cam.camera_id
                new.has_prior_focal_length = True
                db.update_camera(new)
    options = pycolmap.IncrementalPipelineOptions()
    options.image_names = list(window.image_names)
    options.num_threads = job.features.threads
    options.multiple_models = False
    options.extract_colors = False
    # Global BA less often than COLMAP's default (every 10 % growth): windows are short and
    # local BA keeps them consistent; measured ~20 % faster with the same result.
    options.ba_global_frames_ratio = 1.5
    options.ba_global_points_ratio = 1.5
    # COLMAP re-runs every bundle adjustment after filtering outliers up to 5 (global) / 2 (local)
    # times; on our short windows the re-runs doubled the mapping time (turn-70, 2026-11-23), and
    # calibration and sign errors stayed within the tests' and the quick bench's bars without them.
    options.ba_global_max_refinements = job.features.ba_max_refinements
    options.ba_local_max_refinements = job.features.ba_max_refinements
    options.random_seed = 0
    options.use_prior_position = window.use_position_priors
    options.use_robust_loss_on_prior_position = True
    options.mapper.random_seed = 0
    options.ba_refine_focal_length = not fixed
    options.ba_refine_extra_params = not fixed
    options.ba_refine_principal_point = False
    options.mapper.abs_pose_refine_focal_length = not fixed
    options.mapper.abs_pose_refine_extra_params = not fixed
    if fixed:
        # With known intrinsics an essential matrix fixes forward motion well, and a car on a
        # straight road moves only forwards: COLMAP's defaults (<= 0.95 forward, >= 16 deg) would
        # refuse every initial pair there.
        options.mapper.init_max_forward_motion = 1.0
        options.mapper.init_min_tri_angle = 4.0
    empty = WindowResult([], np.zeros((0, 4, 4)),
                         window.camera or CameraModel(job.width, job.height, 1, 1, 0, 0),
                         n_input=len(window.image_names))
    models = None
    if window.init_pair is not None:
        with pycolmap.Database.open(db_path) as db:
            ids = {im.name: im.image_id for im in db.read_all_images()}
        if all(name in ids for name in window.init_pair):
            options.init_image_id1, options.init_image_id2 = (ids[n] for n in window.init_pair)
            try:
                models = pycolmap.incremental_mapping(db_path, job.image_dir, out, options=options)
            except Exception:
                models = None
            if not models or max(r.num_reg_images() for r in models.values()) < 3:
                log.warning("window %d: no reconstruction from the chosen initial pair %s; "
                            "letting COLMAP choose", index, window.init_pair)
                shutil.rmtree(out / "0", ignore_errors=True)
                options.init_image_id1 = options.init_image_id2 = -1
                models = None
    try:
        if models is None:
            models = pycolmap.incremental_mapping(db_path, job.image_dir, out, options=options)
    except Exception as exc:  # COLMAP raises for windows it cannot initialise
        empty.error = f"mapping failed: {exc}"
        return empty
    if not models:
        empty.error = "COLMAP found no initial image pair (too little parallax or texture)"
        return empty
    rec = max(models.values(), key=lambda r: r.num_reg_images())
    stage1 = _camera_model(next(iter(rec.cameras.values())))
    if window.calibrate:
        from app.pipeline.colmap_refine import refine_all_intrinsics
        refine_all_intrinsics(pycolmap, rec)
    return _window_result(rec, window, stage1 if window.calibrate else None)


def _window_result(rec, window: WindowRequest, stage1: CameraModel | None) -> WindowResult:
    order = {name: i for i, name in enumerate(window.image_names)}
    images = sorted((im for im in rec.images.values() if im.has_pose and im.name in order),
                    key=lambda im: order[im.name])
    T = np.zeros((len(images), 4, 4))
    for k, im in enumerate(images):
        T_cam_model = np.eye(4)
        T_cam_model[:3, :] = im.cam_from_world().matrix()
        T[k] = np.linalg.inv(T_cam_model)
    camera = _camera_model(next(iter(rec.cameras.values())))
    return WindowResult([im.name for im in images], T, camera, stage1,
                        float(rec.compute_mean_reprojection_error()), rec.num_points3D(),
                        len(window.image_names))
