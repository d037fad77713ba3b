"""Cameras the operator knows, and journeys that wait for their camera (issue 66, items 4 and 6).

* **A registered calibration** (``register``): an admin gives a camera's calibration (PUT
  /api/v1/cameras/{id}/calibration, the dashboard's cameras page, ``signmap cameras set``). It
  starts a new epoch of the camera and is what the camera's later journeys are given, as given
  (``state.stored_calibration``); the older epochs' self-calibrations are never averaged into it.
* **A journey that waits** (``wait_for_camera``): a journey without a turn whose camera has no
  calibration does not fail. It goes back to ``queued`` with stage ``waiting_for_camera`` and a
  ``message``; ``state.claim`` leaves it alone and no sweep submits it.
* **Waking** (``wake_waiting``): once its camera has a calibration (a registration, or another
  journey's self-calibration stored), the camera's waiting journeys are put back to plain queued
  and submitted to the normal queue. ``wake_calibrated`` does the same from the workers' sweeps,
  for a wake that was lost (a process died between the calibration's commit and the wake, or the
  broker was down).

Races. Whether a journey waits is decided, and a camera's journeys are woken, each in a
transaction holding the camera's lock (PostgreSQL: an advisory transaction lock on the camera id;
SQLite: ``BEGIN IMMEDIATE``, the database's one write lock), and the calibration is committed
before the wake begins. So a journey that decides to wait either sees the new calibration (and
goes back to the queue itself) or is seen waiting by the wake. Only the wake's own transaction
takes a journey out of waiting, so two triggers wake it once; and a journey submitted twice is
run once at a time, as every run claims it first (``state.claim``). A woken journey is submitted
after the commit (``_submit`` says why); one whose submit failed waits again, and a process that
dies in between leaves it queued, as an upload that died before its submit (the embedded
worker's sweep submits every queued journey; Celery has no such sweep).

* **Re-processing** (``reprocess_superseded``): a registered calibration supersedes the one the
  camera's done journeys were given. Those journeys (calibration source "supplied" or "checked",
  frames of the registration's size, a calibration other than the registered one) go back to
  ``queued`` with stage ``reprocessing``, a ``message`` naming the epoch and ``reprocess_epoch``
  set, and are submitted to the normal queue; each run claims them as any other (``state.claim``).
  Until the new run stores its result they keep serving their earlier signs
  (``models.serves_result``); a re-processing run that fails leaves the earlier result done
  (``state.fail``). Selected and marked in the camera's lock, so two triggers queue a journey once;
  a registration of the same values finds nothing left to re-process. A run that stores a result
  with a calibration registered meanwhile superseded checks itself the same way (``jobs.run``).
  Self-calibrated journeys keep their own result (a journey whose turn confirmed the stored
  calibration, "checked", used the stored one and is re-processed as "supplied" ones are), and a
  moving consensus of self-calibrations triggers nothing. A lens change (``state.lens_change``)
  supersedes the old lens's calibration for the journeys uploaded after the new epoch's first
  journey (docs/decisions/registered-calibration.md, "Lens changes"); a joint calibration
  (``jobs.camera_fit``) that moved by more than its sigma from what a journey was given supersedes
  it (docs/decisions/camera-joint-calibration.md).
"""

from __future__ import annotations

import logging
import zlib
from contextlib import contextmanager
from typing import Callable, Iterator

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator
from sqlalchemy import select, text, update
from sqlalchemy.orm import Session

from app.pipeline.bundle.csv_table import CONTROL_CHARS, MAX_TEXT_CHARS
from app.pipeline.types import STORED_SOURCES, CameraModel, StageReport
from app.service.db.models import (CALIBRATION_PARAMS, REPROCESSING, WAITING_FOR_CAMERA,
                                   CalibrationRow, CameraFitRow, JourneyRow)
from app.service.db.session import session_scope
from app.service.jobs import state
from app.settings import Settings

log = logging.getLogger(__name__)

Submit = Callable[[str], None]
REQUEUED = "requeued"  # the stage of a journey woken, until a run claims it
# pg_advisory_xact_lock(key1, key2): key1 names the kind of lock ("SGCM"), key2 the camera.
CAMERA_LOCK_KEY = 0x5347434D
# Bounds of a registered calibration (pixels; OpenCV's radial coefficients): beyond them it is no
# camera. A focal length of 100 image sides is a field of view of 0.6 degrees, one of 1/100 of
# 178 degrees (beyond any lens the two-coefficient model describes).
MAX_SIDE_PX = 100_000
MAX_FOCAL_PER_SIDE = 100.0
MIN_FOCAL_PER_SIDE = 0.01
MAX_K = 100.0
MAX_SIGMA_PX = 1e6


class CalibrationSigma(BaseModel):
    """1-sigma of each parameter, in its own units (pixels; k1, k2 unitless); 0 when left out."""

    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)

    fx: float = Field(0.0, ge=0, le=MAX_SIGMA_PX)
    fy: float = Field(0.0, ge=0, le=MAX_SIGMA_PX)
    cx: float = Field(0.0, ge=0, le=MAX_SIGMA_PX)
    cy: float = Field(0.0, ge=0, le=MAX_SIGMA_PX)
    k1: float = Field(0.0, ge=0, le=MAX_K)
    k2: float = Field(0.0, ge=0, le=MAX_K)


class Registration(BaseModel):
    """A camera's calibration as an operator knows it: the body of PUT
    /api/v1/cameras/{camera_id}/calibration and of ``signmap cameras set``'s file. Pixels of the
    original image (OpenCV convention: the top-left pixel's centre is (0, 0)); k1, k2 OpenCV's
    radial coefficients (0 when left out)."""

    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False,
                              json_schema_extra={"examples": [{
                                  "width": 1242, "height": 375, "fx": 721.5, "fy": 721.5,
                                  "cx": 609.6, "cy": 172.9, "k1": -0.3, "k2": 0.1,
                                  "sigma": {"fx": 2.0, "fy": 2.0, "cx": 1.5, "cy": 1.5,
                                            "k1": 0.005, "k2": 0.01}}]})

    width: int = Field(gt=0, le=MAX_SIDE_PX, description="image width, pixels")
    height: int = Field(gt=0, le=MAX_SIDE_PX, description="image height, pixels")
    fx: float = Field(gt=0, description="focal length, pixels")
    fy: float = Field(gt=0, description="focal length, pixels")
    cx: float = Field(description="principal point, pixels; inside the image")
    cy: float = Field(description="principal point, pixels; inside the image")
    k1: float = Field(0.0, ge=-MAX_K, le=MAX_K)
    k2: float = Field(0.0, ge=-MAX_K, le=MAX_K)
    sigma: CalibrationSigma | None = Field(
        None, description="1-sigma of each parameter, same units; left out: taken as exact (0)")

    @field_validator("fx", "fy")
    @classmethod
    def _focal_in_reach(cls, value: float, info: ValidationInfo) -> float:
        side = max(info.data.get("width", 0), info.data.get("height", 0))
        if side and value > MAX_FOCAL_PER_SIDE * side:
            raise ValueError(f"{value:g} px is over {MAX_FOCAL_PER_SIDE:g} times the image's "
                             f"longer side ({side} px): no camera's field of view is that narrow")
        if side and value < MIN_FOCAL_PER_SIDE * side:
            raise ValueError(f"{value:g} px is under {MIN_FOCAL_PER_SIDE:g} times the image's "
                             f"longer side ({side} px): no camera's field of view is that wide")
        return value

    @field_validator("cx", "cy")
    @classmethod
    def _inside_the_image(cls, value: float, info: ValidationInfo) -> float:
        side = info.data.get("width" if info.field_name == "cx" else "height")
        if side is not None and not -0.5 <= value <= side - 0.5:
            raise ValueError(f"the principal point must be inside the image: {info.field_name} "
                             f"between -0.5 and {side - 0.5:g} (the image is {side} px "
                             f"{'wide' if info.field_name == 'cx' else 'high'}), not {value:g}")
        return value

    @field_validator("k2")
    @classmethod
    def _distortion_does_not_fold(cls, k2: float, info: ValidationInfo) -> float:
        d = info.data
        if not all(k in d for k in ("width", "height", "fx", "fy", "cx", "cy", "k1")):
            return k2  # an error on one of them is reported already
        fold = distortion_fold(d["width"], d["height"], d["fx"], d["fy"], d["cx"], d["cy"],
                               d["k1"], k2)
        if fold is not None:
            raise ValueError(f"k1 = {d['k1']:g} and k2 = {k2:g} fold the image back on itself "
                             f"{fold:.0f} px from the principal point (the distorted radius stops "
                             f"growing there, inside the image): no lens does that; check their "
                             f"signs, and that they are OpenCV's (normalized coordinates)")
        return k2


def distortion_fold(width: int, height: int, fx: float, fy: float, cx: float, cy: float,
                    k1: float, k2: float) -> float | None:
    """Where, in pixels from the principal point, the radial distortion r (1 + k1 r^2 + k2 r^4)
    stops growing (or flips sign) inside the image; None when it grows all the way to the
    farthest corner."""
    corners_x = np.array([-0.5, width - 0.5])
    corners_y = np.array([-0.5, height - 0.5])
    r2_max = float(np.max(((corners_x[:, None] - cx) / fx) ** 2
                          + ((corners_y[None, :] - cy) / fy) ** 2))
    s = np.linspace(0.0, r2_max, 512)  # r^2
    bad = (1 + k1 * s + k2 * s**2 <= 0) | (1 + 3 * k1 * s + 5 * k2 * s**2 <= 0)
    if not bad.any():
        return None
    return float(np.sqrt(s[np.argmax(bad)]) * min(fx, fy))


class InvalidCalibration(ValueError):
    """A registration that cannot be this camera's; ``errors`` as FastAPI's 422 lists them
    (``loc``, ``msg``, ``type``)."""

    def __init__(self, errors: list[dict]):
        super().__init__("; ".join(f"{'.'.join(str(p) for p in e['loc'])}: {e['msg']}"
                                   for e in errors))
        self.errors = errors


def check_camera_id(camera_id: str) -> None:
    """InvalidCalibration unless ``camera_id`` could be a manifest's (``bundle.manifest``)."""
    bad = CONTROL_CHARS.search(camera_id)
    msg = ("must be a non-empty string" if not camera_id.strip() else
           f"at most {MAX_TEXT_CHARS} characters" if len(camera_id) > MAX_TEXT_CHARS else
           f"must not contain control characters ({bad.group()!r} at character {bad.start() + 1})"
           if bad else None)
    if msg:
        raise InvalidCalibration([{"loc": ["path", "camera_id"], "msg": msg,
                                   "type": "value_error", "input": camera_id[:64]}])


def _lock_key(camera_id: str) -> int:
    return zlib.crc32(camera_id.encode()) - 2**31  # PostgreSQL's int4 range


@contextmanager
def camera_session(url: str, camera_id: str) -> Iterator[Session]:
    """A transaction holding ``camera_id``'s lock from its first statement (module docstring)."""
    with session_scope(url) as session:
        if url.startswith("sqlite"):
            session.connection().exec_driver_sql("BEGIN IMMEDIATE")
        else:
            session.execute(text("SELECT pg_advisory_xact_lock(:kind, :camera)"),
                            {"kind": CAMERA_LOCK_KEY, "camera": _lock_key(camera_id)})
        yield session


def image_sizes(session: Session, camera_id: str) -> set[tuple[int, int]]:
    """The frame sizes the camera's journeys are known to have (read by a run, or self-calibrated
    on)."""
    sizes = set(session.execute(
        select(JourneyRow.image_width, JourneyRow.image_height).distinct()
        .where(JourneyRow.camera_id == camera_id, JourneyRow.image_width.is_not(None))).all())
    sizes |= set(session.execute(
        select(CalibrationRow.width, CalibrationRow.height).distinct()
        .where(CalibrationRow.camera_id == camera_id, CalibrationRow.source == "self")).all())
    return {(int(w), int(h)) for w, h in sizes}


def _check_size(session: Session, camera_id: str, reg: Registration) -> None:
    sizes = image_sizes(session, camera_id)
    if not sizes or (reg.width, reg.height) in sizes:
        return
    known = " or ".join(f"{w}x{h}" for w, h in sorted(sizes))
    msg = (f"camera {camera_id}'s journeys have {known} frames, not {reg.width}x{reg.height}: "
           f"a calibration is for the size of the frames it is used on")
    fields = [key for key, i in (("width", 0), ("height", 1))
              if all(getattr(reg, key) != size[i] for size in sizes)] or ["width"]
    raise InvalidCalibration([{"loc": ["body", key], "msg": msg, "type": "value_error",
                               "input": getattr(reg, key)} for key in fields])


def _same(row: CalibrationRow, reg: Registration, sigma: dict[str, float]) -> bool:
    return ((row.width, row.height) == (reg.width, reg.height)
            and all(getattr(row, k) == getattr(reg, k) for k in CALIBRATION_PARAMS)
            and all(getattr(row, f"sigma_{k}") == sigma[k] for k in CALIBRATION_PARAMS))


def register(url: str, camera_id: str, reg: Registration, by: str) -> tuple[int, bool]:
    """Store ``reg`` as ``camera_id``'s calibration, registered by ``by`` (a key's name): a new
    epoch, unless it is already the newest epoch's registered calibration, same values and
    sigmas (then nothing changes: PUT is idempotent). Returns (its epoch, whether it is new).
    Raises InvalidCalibration for a camera id no manifest can have, or when the camera's
    journeys have frames of another size. The caller wakes the camera's waiting journeys after
    this commit (``wake_waiting``)."""
    check_camera_id(camera_id)
    sigma = (reg.sigma or CalibrationSigma()).model_dump()
    with camera_session(url, camera_id) as session:
        _check_size(session, camera_id, reg)
        epoch = state.current_epoch(session, camera_id) or 0
        current = state.registered_row(session, camera_id, epoch) if epoch else None
        if current is not None and _same(current, reg, sigma):
            return epoch, False
        session.add(CalibrationRow(
            camera_id=camera_id, journey_id=None, source="registered", epoch=epoch + 1,
            width=reg.width, height=reg.height, **{k: getattr(reg, k) for k in CALIBRATION_PARAMS},
            **{f"sigma_{k}": v for k, v in sigma.items()}, registered_by=by[:200]))
    log.info("camera %s: calibration registered by %s as epoch %d (fx %.2f, fy %.2f, cx %.2f, "
             "cy %.2f, k1 %.5f, k2 %.5f, %dx%d)", camera_id, by, epoch + 1, reg.fx, reg.fy,
             reg.cx, reg.cy, reg.k1, reg.k2, reg.width, reg.height)
    return epoch + 1, True


def waiting_message(camera_id: str, finding: str) -> str:
    return (f"waiting for a calibration of camera {camera_id}: {finding}, so it cannot "
            f"calibrate the camera itself, and the camera has none yet. It resumes by itself "
            f"once the camera has one: when a journey of this camera with a turn has "
            f"self-calibrated, or when an admin registers the camera's calibration "
            f"(PUT /api/v1/cameras/{{camera_id}}/calibration, the dashboard's Cameras page, or "
            f"`signmap cameras set CAMERA_ID cam.json`)")


def wait_for_camera(url: str, journey_id: str, attempt: int, camera_id: str,
                    size: tuple[int, int], finding: str, report: list[StageReport] | None,
                    settings: Settings, submit: Submit | None) -> str | None:
    """This run's journey has no turn and was given no calibration of its camera: put it back to
    queued, waiting for one (``message`` says so). When the camera got a calibration of the
    journey's image size meanwhile, it goes back to the queue instead (``_submit``'s). Returns
    "waiting", "requeued", or None when this run no longer owns the journey."""
    with camera_session(url, camera_id) as session:
        stored = state.stored_calibration(session, camera_id, journey_id,
                                          agree_rel=settings.calibration_flag_rel,
                                          newest=settings.calibration_consensus_newest, size=size)
        usable = stored is not None
        if usable:
            mine = state.back_to_queue(session, journey_id, attempt, stage=REQUEUED,
                                       image_size=size)
            outcome = "requeued" if mine else None
        else:
            mine = state.back_to_queue(
                session, journey_id, attempt, stage=WAITING_FOR_CAMERA,
                message=waiting_message(camera_id, finding), image_size=size,
                report=None if report is None else [r.to_json() for r in report])
            outcome = "waiting" if mine else None
    if outcome == "requeued":
        _submit_woken(url, camera_id, [journey_id], submit)
    return outcome


def wake_waiting(url: str, camera_id: str, size: tuple[int, int] | None,
                 submit: Submit | None) -> list[str]:
    """Put the journeys waiting for ``camera_id`` back to the queue, those of image ``size`` (and
    those whose size is not known; None: all), and submit them (``_submit``). Returns their
    ids."""
    with camera_session(url, camera_id) as session:
        where = [JourneyRow.camera_id == camera_id, JourneyRow.status == "queued",
                 JourneyRow.stage == WAITING_FOR_CAMERA]
        if size is not None:
            where.append((JourneyRow.image_width.is_(None))
                         | ((JourneyRow.image_width == size[0])
                            & (JourneyRow.image_height == size[1])))
        ids = list(session.scalars(
            update(JourneyRow).where(*where)
            .values(stage=REQUEUED, message=None, progress=0.0, report=None)
            .returning(JourneyRow.id)))
    if ids:
        log.info("camera %s is calibrated: %d waiting journeys queued again: %s", camera_id,
                 len(ids), ", ".join(sorted(ids)))
        _submit_woken(url, camera_id, ids, submit)
    return ids


def _submit(url: str, ids: list[str], submit: Submit | None, stage: str,
            undo: dict) -> None:
    """Submit journeys just put back to the queue at ``stage``, after that commit: a run claims
    only a journey its snapshot shows claimable, so one sent before would find it still waiting
    and drop it. None: nobody to submit to (the embedded worker's sweep submits every queued
    journey). When a submit fails, the journeys not submitted get the column values ``undo``
    (what they were before, with a message saying why), and the error is raised."""
    for i, journey_id in enumerate(ids if submit is not None else []):
        try:
            submit(journey_id)
        except Exception:
            with session_scope(url) as session:
                session.execute(
                    update(JourneyRow).where(JourneyRow.id.in_(ids[i:]),
                                             JourneyRow.status == "queued",
                                             JourneyRow.stage == stage)
                    .values(**undo))
            raise


def _submit_woken(url: str, camera_id: str, ids: list[str], submit: Submit | None) -> None:
    """``_submit`` journeys woken for their camera; those not submitted wait again, for the
    sweeps' ``wake_calibrated``."""
    _submit(url, ids, submit, REQUEUED, dict(stage=WAITING_FOR_CAMERA, message=(
        f"waiting to be queued again: camera {camera_id} has a calibration now, but the job "
        f"queue could not be reached; the workers' sweeps queue it again")))


def wake_calibrated(url: str, settings: Settings, submit: Submit | None) -> list[str]:
    """The sweeps' repair: wake the waiting journeys of every camera that has a calibration
    of their image size. One query when nothing waits."""
    with session_scope(url) as session:
        waiting = session.execute(
            select(JourneyRow.camera_id, JourneyRow.image_width, JourneyRow.image_height)
            .distinct().where(JourneyRow.status == "queued",
                              JourneyRow.stage == WAITING_FOR_CAMERA)).all()
        sizes: dict[str, set] = {}
        for camera_id, width, height in waiting:
            sizes.setdefault(camera_id, set()).add((width, height) if width else None)
        # Per waiting size, the camera's newest epoch of that size (None: its newest epoch).
        stored = {(camera_id, size): state.stored_calibration(
            session, camera_id, "", agree_rel=settings.calibration_flag_rel,
            newest=settings.calibration_consensus_newest, size=size)
            for camera_id in sizes for size in sizes[camera_id]}
    woken: list[str] = []
    for (camera_id, _size), calibration in stored.items():
        if calibration is None:
            continue
        woken += wake_waiting(url, camera_id, (calibration.camera.width,
                                               calibration.camera.height), submit)
    return woken


def reprocess_message(camera_id: str, epoch: int) -> str:
    return f"reprocessing: camera {camera_id} calibration epoch {epoch}"


def _used(calibration: dict | None, row: CalibrationRow) -> bool:
    """Whether a journey's stored calibration (``JourneyRow.calibration``) is ``row``'s."""
    return calibration is not None and all(
        k in calibration and abs(float(calibration[k]) - getattr(row, k))
        <= 1e-9 * max(1.0, abs(getattr(row, k))) for k in CALIBRATION_PARAMS)


def _disagrees(calibration: dict | None, camera: CameraModel, agree_rel: float) -> bool:
    """Whether a journey's stored calibration disagrees with ``camera`` beyond ``agree_rel``."""
    if calibration is None or not all(k in calibration for k in CALIBRATION_PARAMS):
        return False
    given = CameraModel.from_params(camera.width, camera.height,
                                    {k: float(calibration[k]) for k in CALIBRATION_PARAMS})
    return state.calibration_agreement(given, camera) > agree_rel


def _moved(calibration: dict | None, fit: CameraFitRow) -> bool:
    """Whether a journey's stored calibration differs from the joint ``fit`` by more than the
    fit's sigma in fx, cx or cy, or in fy where the fit resolves it (an unresolved fy's sigma
    is wide, and its error matters to heights only)."""
    if calibration is None or not all(k in calibration for k in CALIBRATION_PARAMS):
        return False
    keys = ("fx", "fy", "cx", "cy") if fit.fy_resolved else ("fx", "cx", "cy")
    sigma = fit.sigma()
    return any(sigma[k] is not None and abs(float(calibration[k]) - getattr(fit, k)) > sigma[k]
               for k in keys)


def _lens_change_row(session: Session, camera_id: str, epoch: int) -> CalibrationRow | None:
    """The first self-calibration of ``epoch`` when a lens change started it
    (``state.lens_change``, or frames of another size); None otherwise."""
    return session.scalars(select(CalibrationRow).where(
        CalibrationRow.camera_id == camera_id, CalibrationRow.epoch == epoch,
        CalibrationRow.epoch_reason.is_not(None))).first()


def reprocess_superseded(url: str, camera_id: str, submit: Submit | None,
                         journey_id: str | None = None,
                         settings: Settings | None = None) -> list[str]:
    """Queue again the camera's done journeys that were given a calibration its newest epoch
    supersedes, or only ``journey_id`` among them; submit them after the commit (None: the
    embedded worker's sweep does). Returns their ids.

    * A registered epoch: those given a calibration (source "supplied" or "checked") of its
      frame size
      other than the registered one.
    * An epoch a lens change started (``state.lens_change``): those given a calibration of its
      frame size that disagrees with the epoch's (beyond ``calibration_flag_rel``: the old
      lens's) and uploaded after the epoch's first journey; the ones uploaded before were
      taken with the old lens and keep its calibration. A consensus that moves within the
      tolerance re-processes nothing.
    * An epoch whose calibration is a joint fit (``jobs.camera_fit``): those given a calibration
      of its frame size that differs from the fit by more than its sigma (``_moved``).
    * Otherwise nothing: a consensus of self-calibrations that moves triggers nothing."""
    settings = settings or Settings()
    with camera_session(url, camera_id) as session:
        epoch = state.current_epoch(session, camera_id)
        registered = state.registered_row(session, camera_id, epoch) if epoch else None
        lens = _lens_change_row(session, camera_id, epoch) if epoch and not registered else None
        fit = state.latest_fit(session, camera_id, epoch) if epoch and not registered else None
        if registered is None and lens is None and fit is None:
            return []
        reference = registered or lens or fit
        where = [JourneyRow.camera_id == camera_id, JourneyRow.status == "done",
                 JourneyRow.calibration_source.in_(STORED_SOURCES),
                 JourneyRow.image_width == reference.width,
                 JourneyRow.image_height == reference.height]
        if journey_id is not None:
            where.append(JourneyRow.id == journey_id)
        if registered is not None:
            candidates = session.execute(select(JourneyRow.id, JourneyRow.calibration)
                                         .where(*where)).all()
            ids = sorted(i for i, calibration in candidates
                         if not _used(calibration, registered))
        elif lens is None:
            candidates = session.execute(select(JourneyRow.id, JourneyRow.calibration)
                                         .where(*where)).all()
            ids = sorted(i for i, calibration in candidates if _moved(calibration, fit))
        else:
            first = session.get(JourneyRow, lens.journey_id)
            stored = state.stored_calibration(
                session, camera_id, "", agree_rel=settings.calibration_flag_rel,
                newest=settings.calibration_consensus_newest)
            where.append(JourneyRow.created_at > first.created_at)
            candidates = session.execute(select(JourneyRow.id, JourneyRow.calibration)
                                         .where(*where)).all()
            ids = sorted(i for i, calibration in candidates
                         if stored is not None and _disagrees(calibration, stored.camera,
                                                              settings.calibration_flag_rel))
        if ids:
            ids = sorted(session.scalars(
                update(JourneyRow).where(JourneyRow.id.in_(ids), JourneyRow.status == "done")
                .values(status="queued", stage=REPROCESSING, progress=0.0,
                        message=reprocess_message(camera_id, epoch), reprocess_epoch=epoch)
                .returning(JourneyRow.id)))
    if not ids:
        return []
    log.info("camera %s epoch %d: %d journeys queued for re-processing: %s", camera_id, epoch,
             len(ids), ", ".join(ids))
    # A journey the queue did not take is done again with its earlier result; the same
    # registration again (or the journey's Retry of the camera) queues it.
    _submit(url, ids, submit, REPROCESSING, dict(
        status="done", stage="done", progress=1.0, reprocess_epoch=None,
        message=(f"not re-processed with camera {camera_id}'s calibration epoch {epoch}: the "
                 f"job queue could not be reached; register the calibration again to queue it")))
    return ids
