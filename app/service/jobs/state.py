"""The journey row's life cycle in the database: claim, heartbeat, progress, result, failure, recovery.

Every run first *claims* the journey, which increments ``attempts``; afterwards it only writes while
the row still carries that attempt number. A run that was given up for dead (stale heartbeat) and
then wakes up can therefore never overwrite the run that replaced it.
"""

from __future__ import annotations

import io
import logging
import math
from dataclasses import dataclass
from datetime import datetime, timedelta

import numpy as np
from sqlalchemy import and_, delete, func, or_, select, update
from sqlalchemy.orm import Session

from app.pipeline.cameras.check_on_turn import SHARE_OF, deviation as calibration_deviation
from app.pipeline.colmap.joint import MAX_POINTS_PER_WINDOW, thinned
from app.pipeline.types import (INTRINSICS_STD, AntennaEstimate, CameraModel,
                                Journey as JourneyData, JourneyResult, StageReport,
                                WindowObservations)
from app.service.db.models import (WAITING_FOR_CAMERA, CalibrationRow, CameraFitRow, JourneyRow,
                                   JourneySignRow, utc_now)

log = logging.getLogger(__name__)


def _stale(cutoff: datetime):
    return and_(JourneyRow.status == "running",
                or_(JourneyRow.heartbeat_at.is_(None), JourneyRow.heartbeat_at < cutoff))


def not_waiting():
    """A queued journey that may be claimed: not one waiting for its camera (stage NULL counts)."""
    return or_(JourneyRow.stage.is_(None), JourneyRow.stage != WAITING_FOR_CAMERA)


def _mine(journey_id: str, attempt: int):
    return and_(JourneyRow.id == journey_id, JourneyRow.attempts == attempt, JourneyRow.status == "running")


def claim(session: Session, journey_id: str, stale_after_s: float, max_attempts: int) -> int | None:
    """Mark the journey running if it is queued (and not waiting for its camera: woken first,
    ``jobs.cameras``), or running with a stale heartbeat and attempts left; return the new
    attempt number, or None when another run owns it, it waits or it is finished."""
    now = utc_now()
    cutoff = now - timedelta(seconds=stale_after_s)
    give_up_exhausted(session, cutoff, max_attempts)
    return session.scalars(
        update(JourneyRow)
        .where(JourneyRow.id == journey_id,
               or_(and_(JourneyRow.status == "queued", not_waiting()),
                   and_(_stale(cutoff), JourneyRow.attempts < max_attempts)))
        .values(status="running", attempts=JourneyRow.attempts + 1, stage="start", progress=0.0,
                error=None, started_at=now, heartbeat_at=now, finished_at=None)
        .returning(JourneyRow.attempts)
    ).first()


def give_up_exhausted(session: Session, cutoff: datetime, max_attempts: int) -> None:
    session.execute(
        update(JourneyRow)
        .where(_stale(cutoff), JourneyRow.attempts >= max_attempts)
        .values(status="failed", finished_at=utc_now(),
                error=f"gave up after {max_attempts} attempts: the worker died or stalled each time")
    )


def requeue_stale(session: Session, stale_after_s: float, max_attempts: int) -> list[str]:
    """Put running journeys whose heartbeat is older than ``stale_after_s`` back to queued (or fail
    them when their attempts are used up); return the ids that need to be submitted again."""
    cutoff = utc_now() - timedelta(seconds=stale_after_s)
    give_up_exhausted(session, cutoff, max_attempts)
    return list(session.scalars(
        update(JourneyRow).where(_stale(cutoff)).values(status="queued", stage="requeued")
        .returning(JourneyRow.id)
    ))


def abandon(session: Session, journey_id: str) -> None:
    """The process running this journey is known to be dead: make it stale at once."""
    session.execute(update(JourneyRow).where(JourneyRow.id == journey_id, JourneyRow.status == "running")
                    .values(heartbeat_at=None))


def queued_ids(session: Session) -> list[str]:
    """Queued journeys to submit, oldest first; not those waiting for their camera."""
    return list(session.scalars(select(JourneyRow.id).where(JourneyRow.status == "queued",
                                                            not_waiting())
                                .order_by(JourneyRow.created_at)))


def beat(session: Session, journey_id: str, attempt: int, stage: str | None = None,
         progress: float | None = None) -> bool:
    """Stamp the heartbeat (and the stage/progress when given); False if this run lost the job."""
    values: dict = {"heartbeat_at": utc_now()}
    if stage is not None:
        values["stage"] = stage[:64]
    if progress is not None:
        values["progress"] = min(1.0, max(0.0, float(progress)))
    return session.execute(update(JourneyRow).where(_mine(journey_id, attempt)).values(**values)
                           ).rowcount == 1


def fail(session: Session, journey_id: str, attempt: int, stage: str | None, reason: str,
         report: list[StageReport] | None = None) -> bool:
    """Mark this run's journey failed at ``stage`` (None: not a pipeline stage) with ``reason`` and
    the reports of the stages that ran (None: the pipeline gave none, e.g. an internal error);
    a journey being re-processed is done again with its earlier result instead, ``message``
    saying why. False if this run lost the job."""
    values: dict = {"status": "failed", "error": reason, "finished_at": utc_now(),
                    "report": None if report is None else [r.to_json() for r in report]}
    if stage is not None:
        values["stage"] = stage[:64]
    epoch = session.scalar(select(JourneyRow.reprocess_epoch).where(_mine(journey_id, attempt)))
    if epoch is not None:
        # A re-processing that failed: the earlier result stays, done, and says why.
        at = f" at {stage}" if stage else ""
        values = {"status": "done", "stage": "done", "progress": 1.0, "error": None,
                  "finished_at": values["finished_at"], "reprocess_epoch": None,
                  "message": f"re-processing with calibration epoch {epoch} failed{at}: "
                             f"{reason}; the earlier result is kept"[:2000]}
    return session.execute(update(JourneyRow).where(_mine(journey_id, attempt)).values(**values)
                           ).rowcount == 1


def back_to_queue(session: Session, journey_id: str, attempt: int, *, stage: str,
                  message: str | None = None, report: list | None = None,
                  image_size: tuple[int, int] | None = None) -> bool:
    """End this run without a result and put its journey back to queued at ``stage`` (e.g.
    waiting for its camera, ``jobs.cameras``), with ``message`` and the stage reports as JSON;
    False if this run lost the job."""
    values: dict = {"status": "queued", "stage": stage[:64], "progress": 0.0, "error": None,
                    "message": message, "report": report, "finished_at": None,
                    "heartbeat_at": utc_now()}
    if image_size is not None:
        values["image_width"], values["image_height"] = image_size
    return session.execute(update(JourneyRow).where(_mine(journey_id, attempt)).values(**values)
                           ).rowcount == 1


@dataclass(frozen=True)
class StoredCalibration:
    """What a camera's later journeys are given: its newest epoch's registered calibration
    (``source`` 'registered', as given), or its joint calibration ('joint', ``jobs.camera_fit``),
    or else the ``consensus`` of that epoch's self-calibrations ('consensus')."""

    camera: CameraModel
    source: str
    epoch: int


def window_bytes(observations: WindowObservations) -> bytes:
    """What ``calibrations.window`` keeps: the window thinned to the points a joint fit uses."""
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **thinned(observations, MAX_POINTS_PER_WINDOW).arrays())
    return buffer.getvalue()


def window_of(data: bytes) -> WindowObservations:
    with np.load(io.BytesIO(data)) as arrays:
        return WindowObservations.from_arrays(arrays)


def latest_fit(session: Session, camera_id: str, epoch: int) -> CameraFitRow | None:
    return session.scalars(select(CameraFitRow)
                           .where(CameraFitRow.camera_id == camera_id, CameraFitRow.epoch == epoch)
                           .order_by(CameraFitRow.created_at.desc(), CameraFitRow.id.desc())
                           .limit(1)).first()


def fit_camera(row: CameraFitRow) -> CameraModel:
    return CameraModel(row.width, row.height, row.fx, row.fy, row.cx, row.cy, row.k1, row.k2)


def current_epoch(session: Session, camera_id: str) -> int | None:
    """The camera's newest calibration epoch; None before its first calibration."""
    return session.scalar(select(func.max(CalibrationRow.epoch))
                          .where(CalibrationRow.camera_id == camera_id))


def epoch_self_rows(session: Session, camera_id: str, epoch: int,
                    exclude_journey_id: str | None = None, limit: int | None = None
                    ) -> list[CalibrationRow]:
    """The epoch's self-calibrations, newest first."""
    query = (select(CalibrationRow)
             .where(CalibrationRow.camera_id == camera_id, CalibrationRow.epoch == epoch,
                    CalibrationRow.source == "self")
             .order_by(CalibrationRow.created_at.desc(), CalibrationRow.id.desc()))
    if exclude_journey_id is not None:
        query = query.where(CalibrationRow.journey_id != exclude_journey_id)
    return list(session.scalars(query.limit(limit)))


def registered_row(session: Session, camera_id: str, epoch: int) -> CalibrationRow | None:
    return session.scalars(select(CalibrationRow).where(
        CalibrationRow.camera_id == camera_id, CalibrationRow.epoch == epoch,
        CalibrationRow.source == "registered")).first()


def epoch_size(session: Session, camera_id: str, epoch: int) -> tuple[int, int] | None:
    """The frame size of an epoch's calibrations (all of an epoch's are of one size)."""
    row = session.execute(select(CalibrationRow.width, CalibrationRow.height).where(
        CalibrationRow.camera_id == camera_id, CalibrationRow.epoch == epoch).limit(1)).first()
    return (int(row[0]), int(row[1])) if row else None


def stored_calibration(session: Session, camera_id: str, exclude_journey_id: str, *,
                       agree_rel: float, newest: int, size: tuple[int, int] | None = None
                       ) -> StoredCalibration | None:
    """The camera's stored calibration, not counting this journey's own (so that a re-run of a
    journey calibrates itself again, exactly as the first run did). Only the camera's newest
    epoch counts (with ``size``: its newest epoch of frames that size; None when it has none):
    its registered calibration as given, or else the ``consensus`` of its ``newest`` newest
    self-calibrations (``Settings.calibration_consensus_newest``) or, once two of them kept
    their turn windows, their newest joint calibration (which may count this journey's own
    window: a journey that calibrates itself does not use it)."""
    epoch = current_epoch(session, camera_id)
    if epoch is None:
        return None
    if size is not None:
        while epoch > 0 and epoch_size(session, camera_id, epoch) != tuple(size):
            epoch -= 1
        if epoch == 0:
            return None
    registered = registered_row(session, camera_id, epoch)
    if registered is not None:
        return StoredCalibration(stored_camera(registered), "registered", epoch)
    fit = latest_fit(session, camera_id, epoch)
    if fit is not None:
        return StoredCalibration(fit_camera(fit), "joint", epoch)
    rows = epoch_self_rows(session, camera_id, epoch, exclude_journey_id, newest)
    camera = consensus([stored_camera(r) for r in rows], agree_rel)[0]
    return StoredCalibration(camera, "consensus", epoch) if camera is not None else None


def camera_calibration(session: Session, camera_id: str, exclude_journey_id: str, *,
                       agree_rel: float, newest: int) -> CameraModel | None:
    """``stored_calibration``'s camera, or None."""
    stored = stored_calibration(session, camera_id, exclude_journey_id, agree_rel=agree_rel,
                                newest=newest)
    return stored.camera if stored is not None else None


def stored_camera(row: CalibrationRow) -> CameraModel:
    return CameraModel(width=row.width, height=row.height, fx=row.fx, fy=row.fy, cx=row.cx,
                       cy=row.cy, k1=row.k1, k2=row.k2)


def consensus(cameras: list[CameraModel], agree_rel: float
              ) -> tuple[CameraModel | None, list[int]]:
    """The mean of the largest group of ``cameras`` (newest first) that agree with one of them
    within ``agree_rel`` (``calibration_agreement``; on a tie, the group of the newest), and the
    indices of its members; (None, []) for none.

    A single self-calibration can be accepted wrong (13 % off in fx on a corpus check journey,
    docs/decisions/camera-calibration-consensus.md). Reused as "the camera", it would misplace every later
    journey that cannot calibrate itself and flag every right one as disagreeing; a majority of
    the camera's journeys outvotes it. The mean, not a median per parameter: the distortion
    1 + k1 r^2 + k2 r^4 is linear in (k1, k2), so the mean camera has the mean curve."""
    groups = [[i for i, c in enumerate(cameras) if calibration_agreement(c, centre) <= agree_rel]
              for centre in cameras]
    members = max(groups, key=len, default=[])  # max keeps the first (newest) of equal groups
    if not members:
        return None, []
    params = [cameras[i].params() for i in members]
    mean = {k: float(np.mean([p[k] for p in params])) for k in params[0]}
    first = cameras[members[0]]
    return CameraModel.from_params(first.width, first.height, mean), members


def calibration_agreement(a: CameraModel, b: CameraModel) -> float:
    """The largest of ``calibration_deviation``; inf for calibrations of other image sizes."""
    if (a.width, a.height) != (b.width, b.height):
        return math.inf
    return max(calibration_deviation(a, b).values())


def _finite_or_none(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def store_result(session: Session, journey_id: str, attempt: int, journey: JourneyData,
                 result: JourneyResult, timings_s: dict[str, float],
                 lens: "LensRule | None" = None) -> bool:
    """Replace the journey's signs and calibration with ``result`` and mark it done, all in the
    caller's one transaction. False (nothing written) when this run no longer owns the journey.
    With ``lens``, a new self-calibration may start a new epoch (``lens_change``)."""
    row = session.scalars(select(JourneyRow).where(_mine(journey_id, attempt)).with_for_update()
                          ).first()
    if row is None:
        return False
    session.execute(delete(JourneySignRow).where(JourneySignRow.journey_id == journey_id))
    # A re-run keeps its calibration in the epoch it was made in; a new one joins the newest.
    epoch = session.scalar(select(CalibrationRow.epoch).where(
        CalibrationRow.journey_id == journey_id).order_by(CalibrationRow.id.desc()).limit(1))
    session.execute(delete(CalibrationRow).where(CalibrationRow.journey_id == journey_id))
    boxes = {(d.frame_id, d.track_id): [d.x1, d.y1, d.x2, d.y2] for d in journey.detections}
    session.add_all(
        JourneySignRow(
            id=f"{journey_id}:{s.track_id}", journey_id=journey_id, track_id=s.track_id, cls=s.cls,
            lat_deg=float(s.lat_deg), lon_deg=float(s.lon_deg), alt_m=_finite_or_none(s.alt_m),
            x_enu_m=float(s.xyz_enu[0]), y_enu_m=float(s.xyz_enu[1]), z_enu_m=float(s.xyz_enu[2]),
            std_m=float(s.std_m), reprojection_rms_px=float(s.reprojection_rms_px),
            r95_h_m=_finite_or_none(s.r95_h_m), facing_deg=_finite_or_none(s.facing_deg),
            observations=[{"frame": o.frame_id, "x": float(o.p_cam[0]), "y": float(o.p_cam[1]),
                           "z": float(o.p_cam[2]), "box": boxes.get((o.frame_id, s.track_id))}
                          for o in s.observations],
        )
        for s in result.signs
    )
    calib = result.calibration
    if (cam := calib.turn_estimate) is not None:
        # What the journey's own turn measured, whether it used it (self-calibrated) or the
        # stored calibration it confirmed (checked): the camera's consensus and joint fit take it.
        reason = None
        if epoch is None:
            epoch = current_epoch(session, journey.camera_id) or 1
            size = epoch_size(session, journey.camera_id, epoch)
            if lens is not None and size is not None and size != (cam.width, cam.height):
                reason = (f"frames {cam.width}x{cam.height}, epoch {epoch} was "
                          f"{size[0]}x{size[1]}")
                epoch += 1
        session.add(CalibrationRow(
            camera_id=journey.camera_id, journey_id=journey_id, source="self", epoch=epoch,
            width=cam.width, height=cam.height, **cam.params(), **_sigma_columns(calib),
            n_images=calib.n_images, n_registered=calib.n_registered,
            reprojection_error_px=_finite_or_none(calib.reprojection_error_px),
            rotation_deg=float(calib.rotation_deg), epoch_reason=reason,
            window=(window_bytes(calib.observations) if calib.observations is not None
                    else None)))
        if reason is not None:
            log.warning("camera %s: lens change, calibration epoch %d starts with journey %s: %s",
                        journey.camera_id, epoch, journey_id, reason)
        elif lens is not None and epoch == current_epoch(session, journey.camera_id):
            session.flush()
            lens_change(session, journey.camera_id, epoch, lens)
    now = utc_now()
    row.status, row.stage, row.progress, row.error = "done", "done", 1.0, None
    row.n_signs = len(result.signs)
    row.calibration = calib.camera.params()
    row.calibration_source = calib.source
    row.timings_s = {k: _finite_or_none(v) for k, v in timings_s.items()}
    row.report = [r.to_json() for r in result.report]
    row.message = None
    row.reprocess_epoch = None
    row.image_width, row.image_height = journey.image_width, journey.image_height
    row.finished_at = row.heartbeat_at = now
    return True


@dataclass(frozen=True)
class LensRule:
    """When a camera's self-calibrations start a new epoch (``lens_change``); from the settings
    ``calibration_flag_rel``, ``calibration_epoch_confirm``, ``calibration_consensus_newest``."""

    agree_rel: float
    confirm: int
    newest: int

    @classmethod
    def of(cls, settings) -> "LensRule":
        return cls(settings.calibration_flag_rel, settings.calibration_epoch_confirm,
                   settings.calibration_consensus_newest)


def lens_change(session: Session, camera_id: str, epoch: int, rule: LensRule) -> int | None:
    """Start a new epoch when the camera's newest ``rule.confirm`` self-calibrations of ``epoch``
    agree with each other (``calibration_agreement`` within ``rule.agree_rel``) and each
    disagrees beyond it with the epoch's calibration: its registered one, or the consensus of
    its older self-calibrations, when that consensus has at least ``rule.confirm`` members (a
    smaller one the camera's consensus outvotes already). They move to the new epoch (their
    ``epoch``; the oldest of them gets ``epoch_reason``), so the old epoch never averages them.
    Returns the new epoch, or None."""
    newest = epoch_self_rows(session, camera_id, epoch, limit=rule.confirm)
    if len(newest) < rule.confirm:
        return None
    cams = [stored_camera(r) for r in newest]
    if any(calibration_agreement(a, b) > rule.agree_rel for a in cams for b in cams):
        return None
    registered = registered_row(session, camera_id, epoch)
    if registered is not None:
        reference, what = stored_camera(registered), f"epoch {epoch}'s registered calibration"
    else:
        moved = {r.id for r in newest}
        older = [stored_camera(r) for r in epoch_self_rows(session, camera_id, epoch,
                                                           limit=rule.newest + rule.confirm)
                 if r.id not in moved][:rule.newest]
        reference, members = consensus(older, rule.agree_rel)
        if reference is None or len(members) < rule.confirm:
            return None
        what = f"epoch {epoch}"
    if any(calibration_agreement(c, reference) <= rule.agree_rel for c in cams):
        return None
    mean = consensus(cams, rule.agree_rel)[0]
    deviation = {k: getattr(mean, k) / getattr(reference, k) - 1 for k in ("fx", "fy")}
    deviation |= {"cx": (mean.cx - reference.cx) / reference.width,
                  "cy": (mean.cy - reference.cy) / reference.height}
    key = max(deviation, key=lambda k: abs(deviation[k]))
    of = SHARE_OF.get(key, "")
    reason = (f"{len(newest)} journeys agree with each other and differ from {what} by "
              f"{key} {100 * deviation[key]:+.1f} %{of}")
    new_epoch = (current_epoch(session, camera_id) or epoch) + 1
    session.execute(update(CalibrationRow).where(CalibrationRow.id.in_([r.id for r in newest]))
                    .values(epoch=new_epoch))
    session.execute(update(CalibrationRow).where(CalibrationRow.id == newest[-1].id)
                    .values(epoch_reason=reason[:500]))
    log.warning("camera %s: lens change, calibration epoch %d starts with journey %s (then %s): "
                "%s", camera_id, new_epoch, newest[-1].journey_id,
                ", ".join(r.journey_id for r in newest[-2::-1]), reason)
    return new_epoch


def _sigma_columns(calib) -> dict[str, float | None]:
    """Stage 2's sigma of each parameter it gave one for (``Calibration.intrinsics_std``)."""
    std = tuple(calib.intrinsics_std or ())
    if len(std) != len(INTRINSICS_STD):
        return {}
    return {f"sigma_{k}": _finite_or_none(v) for k, v in zip(INTRINSICS_STD, std)}


def vehicle_estimate(session: Session, vehicle_id: str, but: str | None = None
                     ) -> AntennaEstimate | None:
    """What the vehicle's done journeys (but journey ``but``) estimated of its undeclared GPS
    antenna offset, combined (``AntennaEstimate.combined``); None when none did."""
    rows = session.execute(select(JourneyRow.id, JourneyRow.antenna_estimate)
                           .where(JourneyRow.vehicle_id == vehicle_id,
                                  JourneyRow.status == "done")).all()
    return AntennaEstimate.combined([AntennaEstimate.from_json(estimate)
                                     for journey_id, estimate in rows
                                     if isinstance(estimate, dict) and journey_id != but])
