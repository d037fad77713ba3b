"""The one journey job, run alike by the Celery task and by the embedded worker.

A journey without a turn whose camera has no calibration of its frames' size does not fail: it
waits for its camera (``jobs.cameras``). A journey that self-calibrated wakes the journeys waiting for its camera; one
given a calibration that a registration superseded while it ran is queued again with the new one."""

from __future__ import annotations

import dataclasses
import logging
import shutil
import threading
import time
from typing import Callable

from sqlalchemy import select

from app.pipeline.bundle import read_bundle
from app.pipeline.detect import apply_detector, bundle_has_detections
from app.pipeline.run import process_journey
from app.pipeline.types import AntennaOffset, Journey, NoTurnError, PipelineError, StageReport
from app.service import storage
from app.service.jobs import camera_fit, cameras, fusion, state
from app.service.db.session import session_scope
from app.service.db.models import CalibrationRow, JourneyRow, VehicleRow
from app.settings import Settings

log = logging.getLogger(__name__)


class Superseded(Exception):
    """This run was given up for dead and the journey now belongs to a newer run."""


class _Heartbeat(threading.Thread):
    """Stamps the heartbeat every ``interval_s`` while the pipeline runs; a stage can take minutes
    and a silent run would otherwise look dead."""

    def __init__(self, url: str, journey_id: str, attempt: int, interval_s: float):
        super().__init__(name=f"heartbeat-{journey_id}", daemon=True)
        self.url, self.journey_id, self.attempt, self.interval_s = url, journey_id, attempt, interval_s
        self.stopped = threading.Event()
        self.lost = threading.Event()

    def run(self) -> None:
        while not self.stopped.wait(self.interval_s):
            try:
                with session_scope(self.url) as session:
                    if not state.beat(session, self.journey_id, self.attempt):
                        self.lost.set()
                        return
            except Exception:  # a database hiccup must not end the job; the next beat retries
                log.warning("journey %s: heartbeat failed", self.journey_id, exc_info=True)


def run_journey(journey_id: str, settings: Settings,
                submit: Callable[[str], None] | None = None) -> None:
    """Process one uploaded journey and store its signs; every outcome ends in the journey's row
    (done, failed with a reason, or queued waiting for its camera). Safe to call again for the
    same journey: it claims the row first and replaces, never adds, the journey's signs.
    ``submit`` queues a journey this run puts back to the queue (one that waited for this
    camera, or this one); None: the caller's sweep finds them (the embedded worker's)."""
    url = settings.effective_database_url
    with session_scope(url) as session:
        attempt = state.claim(session, journey_id, settings.stale_after_s, settings.max_attempts)
        row = session.get(JourneyRow, journey_id) if attempt is not None else None
        sha256, camera_id = (row.bundle_sha256, row.camera_id) if row else (None, None)
        stored_calibration = (state.stored_calibration(
            session, camera_id, journey_id, agree_rel=settings.calibration_flag_rel,
            newest=settings.calibration_consensus_newest) if row else None)
    known_camera = stored_calibration.camera if stored_calibration else None
    if attempt is None:
        log.info("journey %s: not claimed (finished, unknown or owned by a live run)", journey_id)
        return
    log.info("journey %s: attempt %d started (camera %s, stored calibration: %s)", journey_id,
             attempt, camera_id, "yes" if known_camera else "no")
    t0 = time.perf_counter()
    workdir = storage.work_dir(settings.data_dir, journey_id, attempt)
    heartbeat = _Heartbeat(url, journey_id, attempt, settings.heartbeat_s)
    heartbeat.start()

    def progress(stage: str, fraction: float, message: str = "") -> None:
        if heartbeat.lost.is_set():
            raise Superseded(journey_id)
        log.info("journey %s: %s %.0f%% %s", journey_id, stage, 100 * fraction, message)
        with session_scope(url) as session:
            if not state.beat(session, journey_id, attempt, stage, fraction):
                raise Superseded(journey_id)

    stage = "extract"
    size = (0, 0)
    try:
        try:
            # Into this worker's own scratch (an object store) or read in place (data_dir/bundles).
            bundle = storage.make_store(settings).fetch(sha256, workdir)
        except storage.StorageError as exc:
            raise PipelineError(stage, str(exc)) from exc
        journey = read_bundle(bundle, workdir / "bundle", limits=settings.bundle,
                              decode_images=True, progress=lambda fraction: progress(
                                  "extract", 0.0, f"video {100 * fraction:.0f} % decoded"))
        progress("extract", 0.0, f"{len(journey.frames)} frames")
        journey = _with_vehicle_antenna(url, journey_id, journey)
        size = (journey.image_width, journey.image_height)
        if known_camera is not None and (known_camera.width, known_camera.height) != size:
            # The camera's newest epoch is of other frames: its newest epoch of this journey's
            # size, if any (a lens change, docs/decisions/registered-calibration.md); none: it
            # calibrates itself (starting an epoch of its size), or waits for its camera.
            with session_scope(url) as session:
                stored_calibration = state.stored_calibration(
                    session, camera_id, journey_id, agree_rel=settings.calibration_flag_rel,
                    newest=settings.calibration_consensus_newest, size=size)
            log.info("journey %s: camera %s's newest calibration is for %dx%d frames, this "
                     "journey's are %dx%d: %s", journey_id, camera_id, known_camera.width,
                     known_camera.height, *size,
                     f"epoch {stored_calibration.epoch} is of its size" if stored_calibration
                     else "no epoch of its size")
            known_camera = stored_calibration.camera if stored_calibration else None
        stage = "detect"
        journey = apply_detector(journey, settings.detector, bundle_has_detections(bundle),
                                 progress=progress)
        stage = "pipeline"
        result = process_journey(journey, settings.pipeline, workdir / "pipeline",
                                 known_camera=known_camera, progress=progress)
        timings_s = {**result.timings_s, "total_s": round(time.perf_counter() - t0, 3)}
        stored = fusion.store_and_fuse(
            url, journey_id, attempt, journey, result, timings_s, known_camera, settings,
            stored_source=stored_calibration.source if stored_calibration else None)
        if not stored:
            raise Superseded(journey_id)
        log.info("journey %s: done in %.1f s, %d signs (calibration: %s), stages %s", journey_id,
                 timings_s["total_s"], len(result.signs), result.calibration.source,
                 result.timings_s)
        if result.calibration.turn_estimate is not None:  # self-calibrated, or checked
            _refit(url, journey_id, camera_id, settings)
            _wake(url, camera_id, size, submit)
            _reprocess_if_superseded(url, camera_id, None, submit, settings)
        else:
            _reprocess_if_superseded(url, camera_id, journey_id, submit, settings)
    except Superseded:
        log.warning("journey %s: attempt %d was superseded by a newer run; its result is dropped",
                    journey_id, attempt)
    except NoTurnError as exc:
        outcome = cameras.wait_for_camera(url, journey_id, attempt, camera_id, size,
                                          exc.finding, exc.report, settings, submit)
        log.info("journey %s: no turn and no calibration of camera %s for %dx%d frames: %s",
                 journey_id, camera_id, *size,
                 {"waiting": "waits for the camera",
                  "requeued": "the camera was calibrated meanwhile; queued again",
                  None: "superseded meanwhile"}[outcome])
    except PipelineError as exc:
        log.info("journey %s: failed at %s: %s", journey_id, exc.stage, exc.reason)
        _fail(url, journey_id, attempt, exc.stage, exc.reason, exc.report)
    except Exception as exc:
        log.exception("journey %s: internal error during %s", journey_id, stage)
        _fail(url, journey_id, attempt, None,
              f"internal error during {stage}: {type(exc).__name__}: {exc}")
    finally:
        heartbeat.stopped.set()
        shutil.rmtree(workdir, ignore_errors=True)


def _with_vehicle_antenna(url: str, journey_id: str, journey: Journey) -> Journey:
    """``journey`` with its vehicle's GPS antenna offset (``PUT /api/v1/vehicles/{id}``) when
    its manifest gives none (a manifest's wins); with neither, with what the vehicle's other done
    journeys estimated, combined (``state.vehicle_estimate``), for the pipeline to add its own to."""
    if journey.gps_antenna_offset is not None or not journey.vehicle_id:
        return journey
    with session_scope(url) as session:
        row = session.get(VehicleRow, journey.vehicle_id)
        given = row.gps_antenna_offset_m if row is not None else None
        if not given:
            return dataclasses.replace(
                journey, antenna_prior=state.vehicle_estimate(session, journey.vehicle_id,
                                                              but=journey_id),
                antenna_prior_source=f"vehicle {journey.vehicle_id}")
    offset = AntennaOffset(float(given["forward"]), float(given["left"]), float(given["up"]),
                           source=f"vehicle {journey.vehicle_id}")
    return dataclasses.replace(journey, gps_antenna_offset=offset)


def _refit(url: str, journey_id: str, camera_id: str, settings: Settings) -> None:
    """The camera's joint calibration, with this journey's turn window in it (before the wake,
    so that the journeys waiting for the camera are given it). The journey is done whatever
    happens here; the next self-calibration of the camera fits again."""
    try:
        with session_scope(url) as session:
            epoch = session.scalar(select(CalibrationRow.epoch)
                                   .where(CalibrationRow.journey_id == journey_id))
        if epoch is not None:
            camera_fit.refit(url, camera_id, epoch, settings)
    except Exception:
        log.exception("camera %s: the joint calibration with journey %s failed; its consensus "
                      "or earlier joint calibration stays", camera_id, journey_id)


def _wake(url: str, camera_id: str, size: tuple[int, int],
          submit: Callable[[str], None] | None) -> None:
    """The camera has a self-calibration now: the journeys waiting for it go back to the queue.
    The journey is done whatever happens here; a wake that fails is the sweeps' to repeat."""
    try:
        cameras.wake_waiting(url, camera_id, size, submit)
    except Exception:
        log.exception("camera %s: its waiting journeys could not be woken now; a sweep will",
                      camera_id)


def _reprocess_if_superseded(url: str, camera_id: str, journey_id: str | None,
                             submit: Callable[[str], None] | None, settings: Settings) -> None:
    """A calibration registered (or a lens change detected) while this run used the camera's
    earlier one: the journey is queued again with it; ``journey_id`` None: after this run's
    self-calibration, the camera's journeys a lens change it confirmed supersedes
    (``cameras.reprocess_superseded``). The journey is done whatever happens here."""
    try:
        cameras.reprocess_superseded(url, camera_id, submit, journey_id=journey_id,
                                     settings=settings)
    except Exception:
        log.exception("journey %s: not queued again for camera %s's newer calibration",
                      journey_id or "(the camera's)", camera_id)


def _fail(url: str, journey_id: str, attempt: int, stage: str | None, reason: str,
          report: list[StageReport] | None = None) -> None:
    with session_scope(url) as session:
        state.fail(session, journey_id, attempt, stage, reason, report)
