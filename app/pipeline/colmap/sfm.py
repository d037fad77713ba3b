"""COLMAP (pycolmap) structure-from-motion on windows of a journey's frames.

Used by self-calibration (intrinsics free) and by ego-motion (intrinsics fixed). Features are
extracted and matched once per stage into one database (``stage``); each window is then mapped
separately (``IncrementalPipelineOptions.image_names``) so cost grows with the number of windows,
not with the square of the journey's length.

All COLMAP work runs in a spawned child process: fatal COLMAP errors abort the process (glog
``CHECK``), and that must fail the journey with a reason, never kill a worker. Every COLMAP option
comes from ``presets``. This module converts between OpenCV's pixels and COLMAP's (pixel centres
at +0.5) at the boundary; only ``cv_sift``, which writes keypoints into COLMAP's database, knows
that convention too.
"""

from __future__ import annotations

import concurrent.futures as cf
import logging
import multiprocessing
import os
import shutil
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from app.pipeline.colmap import cv_sift, presets, sift_cache
from app.pipeline.colmap.lifeline import die_with_parent
from app.pipeline.colmap.presets import MappingOptions, ProcessOptions, SiftOptions
from app.pipeline.types import CameraModel, PipelineError, WindowObservations

log = logging.getLogger(__name__)

COLMAP_PIXEL_OFFSET = 0.5


@dataclass(frozen=True, kw_only=True)
class WindowRequest:
    """One window to map. ``camera``: the intrinsics to hold fixed, or with ``calibrate`` the
    starting point of self-calibration (its focal length and image size). With ``check``, the
    window is mapped with ``camera`` held and stage 2 then frees all six intrinsics from it: a
    stored calibration checked on a turn (``cameras.check_on_turn``)."""

    image_names: list[str]
    camera: CameraModel
    calibrate: bool = False
    check: bool = False
    # Two of ``image_names`` to start the reconstruction from (None: COLMAP's choice, which favours
    # the most matched pair: neighbouring frames whose short forward baseline can fix a wrong
    # relative pose that bundle adjustment never leaves). ``more_init_pairs`` are tried next, in
    # order; COLMAP's choice comes last.
    init_pair: tuple[str, str] | None = None
    more_init_pairs: tuple[tuple[str, str], ...] = ()
    # With ``calibrate``: when the model from ``camera`` registers fewer than ``retry_below``
    # images, map again from each of these focal lengths (px) in turn until one does; the model
    # that registered most is kept.
    retry_focals_px: tuple[float, ...] = ()
    retry_below: int = 0


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
    refine_s: float = 0.0  # of which self-calibration's stage 2 (and its focal probe)
    # Stage 2's sigma(fx) / fx from its covariance (nan: not a calibration, or not estimable),
    # and its sigma of each of ``types.INTRINSICS_STD`` (px for fx, fy, cx, cy).
    focal_std_rel: float = float("nan")
    intrinsics_std: tuple[float, ...] = ()
    # The focal length (px) stage 1 started from when this is the mapping of a retry
    # (``WindowRequest.retry_focals_px``); nan: the request's own camera.
    retry_focal_px: float = float("nan")
    # The focal scales stage 2 was started again from (``MappingOptions.stage2_probe``).
    probe_moves: tuple[float, ...] = ()
    unprobed_camera: CameraModel | None = None  # stage 2's camera before those
    observations: WindowObservations | None = None  # a calibration's reconstruction, kept


@dataclass(frozen=True)
class SfmRun:
    """A stage's COLMAP work: one result per requested window, in order, and where its wall time
    went (``timings_s``): ``extract`` and ``match`` (SIFT), or ``import`` and ``verify`` (KLT
    tracks); ``map``, all windows side by side; ``map_idle_core_s``, the core-seconds the mapping
    processes sat without a window (the last window mapping alone)."""

    windows: list[WindowResult]
    timings_s: dict[str, float]


@dataclass(frozen=True, kw_only=True)
class SfmJob:
    """COLMAP's work for one stage: correspondences into a new database under ``workdir`` (SIFT
    of ``extract_names``, or ``imported`` tracks), then every window mapped from it."""

    image_dir: Path
    workdir: Path
    extract_names: list[str]  # SIFT from these images; empty when ``imported`` is given
    windows: list[WindowRequest]
    sift: SiftOptions = field(default_factory=SiftOptions)
    mapping: MappingOptions = field(default_factory=MappingOptions)
    process: ProcessOptions = field(default_factory=ProcessOptions)
    verbose: bool = False
    # Correspondences made elsewhere (KLT tracks) to import instead of extracting SIFT; then
    # ``extract_names`` must be empty and ``workdir`` gets a database of its own.
    imported: "ImportedFeatures | None" = None
    # A database of SIFT features other stages of the journey extracted (``sift_cache``): images
    # found there are not extracted again. None: extract every image into the stage's own.
    feature_cache: Path | None = None
    # The intrinsics when they are known (ego-motion): SIFT pairs are then verified with them, an
    # essential matrix instead of a fundamental one, in two thirds of the time (c5006).
    camera: CameraModel | None = None


@dataclass(frozen=True)
class ImportedFeatures:
    """Keypoints and tentative matches to verify and map; ``camera`` None: not known yet.

    ``keypoints_px[k]`` (K_k, 2): keypoints of image ``image_names[k]`` in OpenCV pixels;
    ``matches[(k1, k2)]`` (M, 2) uint32: keypoint indices into images k1 and k2.
    """

    image_names: list[str]
    keypoints_px: list[np.ndarray]
    matches: dict[tuple[int, int], np.ndarray]
    camera: CameraModel | None


def run_sfm(job: SfmJob, *, on_mapped: Callable[[int, int], None] | None = None,
            on_prepared: Callable[[], None] | None = None) -> SfmRun:
    """Extract (or import) and match features, then map every window of ``job``, in child
    processes; one result per window.

    Windows are independent (each maps its own copy of the database), and COLMAP's incremental
    mapper keeps about one core busy (CPU time ~1.1x wall on turn-70): ``map_workers`` processes
    map windows side by side. ``on_prepared()`` is called when the features are matched,
    ``on_mapped(k, total)`` as the k-th window finishes."""
    workers = max(1, min(job.process.map_workers, len(job.windows)))
    # The mapping tasks need no features: do not pickle the imported ones again for each.
    light = replace(job, extract_names=[], imported=None, process=replace(
        job.process, threads=max(1, job.process.threads // workers)))
    try:
        with colmap_pool(workers) as pool:
            timings_s = pool.submit(_prepare_in_child, job).result()
            if on_prepared is not None:
                on_prepared()
            t0 = time.perf_counter()
            futures = [pool.submit(_map_in_child, light, i) for i in range(len(job.windows))]
            for k, _ in enumerate(cf.as_completed(futures), start=1):
                if on_mapped is not None:
                    on_mapped(k, len(futures))
            results = [f.result() for f in futures]
            timings_s["map"] = time.perf_counter() - t0
    except cf.process.BrokenProcessPool as exc:
        raise PipelineError("colmap", "COLMAP aborted the process (see the worker log); "
                                      "the images may be too few or too poor to match") from exc
    timings_s["map_idle_core_s"] = max(
        0.0, workers * timings_s["map"] - sum(r.mapping_s for r in results))
    if timings_s.keys() & {"extract", "import"}:
        log.info("COLMAP: features of %d images %s in %.1f s, %s in %.1f s",
                 len(job.imported.image_names) if job.imported else len(job.extract_names),
                 *(("imported", timings_s["import"], "verified", timings_s["verify"])
                   if job.imported else
                   ("extracted", timings_s["extract"], "matched", timings_s["match"])))
    log.info("COLMAP: %d windows mapped in %.1f s by %d processes (per window %s s)",
             len(results), timings_s["map"], workers, [r.mapping_s for r in results])
    return SfmRun(results, {k: round(v, 3) for k, v in timings_s.items()})


def colmap_pool(workers: int) -> cf.ProcessPoolExecutor:
    """The pool COLMAP runs in: spawned (not forked) processes that die with this one."""
    return cf.ProcessPoolExecutor(max_workers=workers,
                                  mp_context=multiprocessing.get_context("spawn"),
                                  initializer=die_with_parent, initargs=(os.getpid(),))


# --- everything below runs in the child processes ------------------------------------------------

def _pycolmap(job: SfmJob):
    import pycolmap

    pycolmap.logging.minloglevel = 0 if job.verbose else 3  # glog's ERROR lines are ours to say
    pycolmap.logging.logtostderr = True
    return pycolmap


def _prepare_in_child(job: SfmJob) -> dict[str, float]:
    """The stage's feature database, new when ``job`` brings features; wall seconds per step."""
    pycolmap = _pycolmap(job)
    job.workdir.mkdir(parents=True, exist_ok=True)
    database = job.workdir / "features.db"
    timings_s = {}
    if job.imported is not None or job.extract_names:
        database.unlink(missing_ok=True)
        timings_s = (_import_and_verify(pycolmap, job, database) if job.imported is not None
                     else _extract_and_match(pycolmap, job, database))
    if not database.exists():
        raise RuntimeError("no feature database to map from")
    return timings_s


def _map_in_child(job: SfmJob, index: int) -> WindowResult:
    pycolmap = _pycolmap(job)
    t0 = time.perf_counter()
    window = job.windows[index]
    result = _map_window(pycolmap, job, job.workdir / "features.db", index, window)
    if window.calibrate:
        result = _retry_from_other_focals(pycolmap, job, index, window, result)
    result.mapping_s = round(time.perf_counter() - t0, 3)
    return result


def _retry_from_other_focals(pycolmap, job: SfmJob, index: int, window: WindowRequest,
                             result: WindowResult) -> WindowResult:
    """``result``, or the mapping from another starting focal length that registered more.

    Free-intrinsics mapping from a focal length far from the lens's (0.8 of the width for a
    99 deg lens whose focal is 0.37 of it) let the two-view bundle adjustment of the initial
    pair run off (k1 = 263) and nothing else registered; from 0.5 of the width the same window
    registered 22 of 22 (corpus c0032)."""
    for focal_px in window.retry_focals_px:
        if len(result.image_names) >= window.retry_below:
            break
        start = window.camera.replace(fx=focal_px, fy=focal_px)
        again = _map_window(pycolmap, job, job.workdir / "features.db", index,
                            replace(window, camera=start), suffix=f"_f{focal_px:.0f}")
        again.retry_focal_px = focal_px
        log.info("window %d: %d/%d images registered from fx %.0f, %d before", index,
                 len(again.image_names), again.n_input, focal_px, len(result.image_names))
        if len(again.image_names) > len(result.image_names):
            result = again
    return result


def _extract_and_match(pycolmap, job: SfmJob, database: Path) -> dict[str, float]:
    """Features (COLMAP's SIFT, or OpenCV's with ``job.sift.extractor``) and sequential matches
    of ``job.extract_names``; returns wall seconds per step."""
    t0 = time.perf_counter()
    reader = presets.options(pycolmap, "ImageReaderOptions", presets.IMAGE_READER)
    extraction = presets.options(pycolmap, "FeatureExtractionOptions", {},
                                 **presets.sift_extraction(job.sift, job.process))

    def extract(into: Path, names: list[str]) -> None:
        if job.sift.extractor == "opencv":
            if not into.exists():
                pycolmap.Database.open(into).close()  # COLMAP's schema, empty
            cv_sift.extract_into(pycolmap, into, job.image_dir, names, reader,
                                 max_features=job.sift.max_features, threads=job.process.threads)
            return
        pycolmap.extract_features(into, job.image_dir, image_names=names,
                                  camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                                  extraction_options=extraction, device=pycolmap.Device.cpu)

    if job.feature_cache is None:
        extract(database, job.extract_names)
    else:
        missing = sift_cache.extract_into(job.feature_cache, job.extract_names, extract)
        pycolmap.Database.open(database).close()  # COLMAP's schema, empty
        sift_cache.write_database(job.feature_cache, database, job.extract_names)
        log.info("SIFT: %d of %d images extracted, the others taken from the journey's cache",
                 len(missing), len(job.extract_names))
    if job.camera is not None:
        with pycolmap.Database.open(database) as db:
            _write_known_camera(pycolmap, db, job.camera)
    t1 = time.perf_counter()
    matching = presets.options(pycolmap, "FeatureMatchingOptions", {},
                               num_threads=job.process.threads)
    pairing = presets.options(pycolmap, "SequentialPairingOptions", presets.SEQUENTIAL_PAIRING,
                              overlap=job.sift.overlap)
    pycolmap.match_sequential(database, matching_options=matching, pairing_options=pairing,
                              device=pycolmap.Device.cpu)
    return {"extract": t1 - t0, "match": time.perf_counter() - t1}


def _import_and_verify(pycolmap, job: SfmJob, database: Path) -> dict[str, float]:
    """Write ``job.imported`` into a new database and let COLMAP verify every pair (RANSAC on the
    essential matrix of the known camera); returns wall seconds per step."""
    feats = job.imported
    t0 = time.perf_counter()
    # As SIFT extraction; replaced when the camera is known.
    reader = presets.options(pycolmap, "ImageReaderOptions", presets.IMAGE_READER)
    pycolmap.Database.open(database).close()  # import_images wants the file to exist
    pycolmap.import_images(database, job.image_dir, pycolmap.CameraMode.SINGLE,
                           image_names=feats.image_names, options=reader)
    with pycolmap.Database.open(database) as db:
        ids = {im.name: im.image_id for im in db.read_all_images()}
        if feats.camera is not None:
            _write_known_camera(pycolmap, db, feats.camera)
        image_ids = [ids[name] for name in feats.image_names]
        for image_id, kp in zip(image_ids, feats.keypoints_px):
            db.write_keypoints(image_id, np.asarray(kp, np.float32) + COLMAP_PIXEL_OFFSET)
        for (k1, k2), m in feats.matches.items():
            db.write_matches(image_ids[k1], image_ids[k2], np.asarray(m, np.uint32))
    t1 = time.perf_counter()
    verify = presets.options(pycolmap, "TwoViewGeometryOptions",
                             presets.VERIFY_KNOWN_CAMERA if feats.camera is not None
                             else presets.VERIFY_UNKNOWN_CAMERA)
    # As many threads as matching gets: with one, results are bit-reproducible (the order in
    # which pairs are verified and written feeds the mapper).
    verifier = presets.options(pycolmap, "GeometricVerifierOptions", {},
                               num_threads=job.process.threads)
    pycolmap.geometric_verification(database, verifier_options=verifier,
                                    two_view_geometry_options=verify)
    return {"import": t1 - t0, "verify": time.perf_counter() - t1}


def _write_known_camera(pycolmap, db, camera: CameraModel) -> None:
    """Give the open database's camera(s) ``camera``'s intrinsics, marked as known."""
    for cam in db.read_all_cameras():
        new = _colmap_camera(pycolmap, camera)
        new.camera_id = cam.camera_id
        new.has_prior_focal_length = True
        db.update_camera(new)


def _colmap_camera(pycolmap, camera: CameraModel):
    params = [camera.fx, camera.fy, camera.cx + COLMAP_PIXEL_OFFSET,
              camera.cy + COLMAP_PIXEL_OFFSET, camera.k1, camera.k2, 0.0, 0.0]
    return pycolmap.Camera(model="OPENCV", width=camera.width, height=camera.height, params=params)


def camera_model(cam) -> CameraModel:
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
                window: WindowRequest, suffix: str = "") -> WindowResult:
    out = job.workdir / f"window_{index:03d}{suffix}"
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    # The database holds one camera; give this window its own copy with the known intrinsics
    # (fixed) or the stage-1 starting point (one focal, centred principal point, k1).
    db_path = out / "window.db"
    shutil.copyfile(database, db_path)
    with pycolmap.Database.open(db_path) as db:
        for cam in db.read_all_cameras():
            if window.calibrate:
                c = window.camera
                params = [c.fx, c.cx + COLMAP_PIXEL_OFFSET, c.cy + COLMAP_PIXEL_OFFSET, c.k1]
                new = pycolmap.Camera(
                    model="RADIAL" if job.mapping.stage1_k2 else "SIMPLE_RADIAL",
                    width=c.width, height=c.height,
                    params=params + ([c.k2] if job.mapping.stage1_k2 else []))
            else:
                new = _colmap_camera(pycolmap, window.camera)
            new.camera_id = cam.camera_id
            new.has_prior_focal_length = True
            db.update_camera(new)
    options = presets.options(
        pycolmap, "IncrementalPipelineOptions",
        presets.CALIBRATION_MAPPER if window.calibrate else presets.EGO_MOTION_MAPPER,
        **presets.mapper_knobs(job.mapping), image_names=list(window.image_names),
        num_threads=job.process.threads)
    empty = WindowResult([], np.zeros((0, 4, 4)), window.camera, n_input=len(window.image_names))
    # The chosen initial pairs first, then COLMAP's own choice (-1) if they lead nowhere.
    pairs = [(-1, -1)]
    if window.init_pair is not None:
        with pycolmap.Database.open(db_path) as db:
            ids = {im.name: im.image_id for im in db.read_all_images()}
        chosen = [p for p in (window.init_pair, *window.more_init_pairs)
                  if all(name in ids for name in p)]
        pairs = [tuple(ids[n] for n in p) for p in chosen] + pairs
    models = None
    own_choice_trials = options.init_num_trials
    for id1, id2 in pairs:
        options.init_image_id1, options.init_image_id2 = id1, id2
        options.init_num_trials = (own_choice_trials if id1 == -1
                                   else presets.CHOSEN_INIT_PAIR_TRIALS)
        error = "COLMAP found no initial image pair (too little parallax or texture)"
        shutil.rmtree(out / "0", ignore_errors=True)
        try:
            models = pycolmap.incremental_mapping(db_path, job.image_dir, out, options=options)
        except Exception as exc:  # COLMAP raises for windows it cannot initialise
            models, error = None, f"mapping failed: {exc}"
        if models and max(r.num_reg_images() for r in models.values()) >= 3:
            break
        if id1 != -1:
            log.warning("window %d: no reconstruction from the initial pair of images %d and %d; "
                        "trying the next", index, id1, id2)
    if not models:
        empty.error = error
        return empty
    rec = max(models.values(), key=lambda r: r.num_reg_images())
    stage1 = camera_model(next(iter(rec.cameras.values())))
    std, moves, unprobed = None, [], None
    t_refine = time.perf_counter()
    stage2_after = window.calibrate or window.check
    if stage2_after:
        from app.pipeline.colmap.refine import probe_focal, refine_all_intrinsics

        def stage2(rec) -> np.ndarray:
            return refine_all_intrinsics(
                pycolmap, rec, function_tolerance=job.mapping.ba_function_tolerance,
                max_iterations=job.mapping.stage2_max_iterations,
                aspect_sigma=job.mapping.aspect_prior_sigma, threads=job.process.threads)

        std = stage2(rec)
        # The probe escapes a wrong minimum a free-intrinsics start fell into; a check starts at
        # the camera's own.
        if job.mapping.stage2_probe > 0 and window.calibrate:
            unprobed = camera_model(next(iter(rec.cameras.values())))
            rec, moves, probed_std = probe_focal(
                pycolmap, rec, step=job.mapping.stage2_probe, max_moves=3, refine=stage2,
                max_points=job.mapping.stage2_probe_points, threads=job.process.threads)
            std = std if probed_std is None else probed_std
    result = _window_result(rec, window.image_names, stage1 if window.calibrate else None)
    result.refine_s = round(time.perf_counter() - t_refine, 3) if stage2_after else 0.0
    result.probe_moves = tuple(moves)
    result.unprobed_camera = unprobed if moves else None
    if stage2_after:
        result.observations = window_observations(rec, result.image_names)
    if std is not None:
        result.intrinsics_std = tuple(float(v) for v in std)
        result.focal_std_rel = float(std[0]) / result.camera.fx
    return result


def _window_result(rec, image_names: list[str], stage1: CameraModel | None) -> WindowResult:
    names, T = registered_poses(rec, image_names)
    camera = camera_model(next(iter(rec.cameras.values())))
    return WindowResult(names, T, camera, stage1,
                        float(rec.compute_mean_reprojection_error()), rec.num_points3D(),
                        len(image_names))


def window_observations(rec, names: list[str]) -> WindowObservations:
    """``rec``'s registered images of ``names`` (in that order), their points and observations,
    in OpenCV pixels."""
    names, T_model_cam = registered_poses(rec, names)
    by_name = {im.name: im for im in rec.images.values()}
    point_index: dict[int, int] = {}
    xyz, xy, obs_image, obs_point = [], [], [], []
    for k, name in enumerate(names):
        for p in by_name[name].get_observation_points2D():
            if p.point3D_id not in point_index:
                point_index[p.point3D_id] = len(xyz)
                xyz.append(rec.points3D[p.point3D_id].xyz)
            xy.append(np.asarray(p.xy) - COLMAP_PIXEL_OFFSET)
            obs_image.append(k)
            obs_point.append(point_index[p.point3D_id])
    return WindowObservations(
        f"frames {names[0]}-{names[-1]}" if names else "", np.linalg.inv(T_model_cam),
        np.array(xyz, float).reshape(-1, 3), np.array(xy, float).reshape(-1, 2),
        np.array(obs_image, np.int64), np.array(obs_point, np.int64))


def registered_poses(rec, names: list[str]) -> tuple[list[str], np.ndarray]:
    """The images of ``names`` that ``rec`` (a pycolmap Reconstruction) registered, in the order
    of ``names``, and their (K, 4, 4) T_model_cam."""
    order = {name: i for i, name in enumerate(names)}
    images = sorted((im for im in rec.images.values() if im.has_pose and im.name in order),
                    key=lambda im: order[im.name])
    T = np.zeros((len(images), 4, 4))
    for k, im in enumerate(images):
        T_cam_model = np.eye(4)
        T_cam_model[:3, :] = im.cam_from_world().matrix()
        T[k] = np.linalg.inv(T_cam_model)
    return [im.name for im in images], T
