"""What is known of a camera, as GET /api/v1/cameras/{camera_id}, the dashboard's Cameras page and
``signmap cameras show`` give it: its calibration now (what its later journeys are given,
``state.stored_calibration``) with sigmas, the journeys in it and those left out with the reason,
the journeys waiting for it, those being re-processed with a newer registered calibration, and its
epochs (docs/decisions/registered-calibration.md).

Per epoch: a registered calibration is the epoch's as given; its sigma is the one given (0 where
none was). Otherwise the epoch's calibration is the consensus of its newest self-calibrations
(``state.consensus``), and its sigma the standard error of that mean: the members' standard
deviation over sqrt(n), unknown (null) for a single one. The journeys "in" an epoch's calibration
are the consensus's members, or, for a registered one, the epoch's self-calibrations that agree
with it; the others of the epoch (the newest ``calibration_consensus_newest`` for a consensus)
are left out, each with the reason.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime
from typing import Any, Callable

import numpy as np
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.pipeline.types import CameraModel
from app.service.db.models import (CALIBRATION_PARAMS, WAITING_FOR_CAMERA, CalibrationRow,
                                   CameraFitRow, JourneyRow)
from app.service.jobs import state
from app.settings import Settings

Visible = Callable[[int | None], bool]  # may the caller see a journey of this owner key id?


@dataclass
class EpochView:
    epoch: int
    source: str  # "registered" or "self"
    started_at: datetime
    rows: list[CalibrationRow]  # oldest first, the registered one (if any) among them
    camera: CameraModel | None = None
    sigma: dict[str, float | None] | None = None
    sigma_basis: str | None = None
    registered: CalibrationRow | None = None
    members: list[CalibrationRow] = field(default_factory=list)
    considered: list[CalibrationRow] = field(default_factory=list)
    left_out: list[tuple[CalibrationRow, str]] = field(default_factory=list)
    reason: str | None = None  # why it started (a lens change's ``epoch_reason``)
    first_journey_id: str | None = None  # a lens change's first journey
    fit: CameraFitRow | None = None  # its newest joint calibration, when that is its calibration

    @property
    def kind(self) -> str:
        """'registered', 'joint' or 'consensus': where the epoch's calibration comes from."""
        return "registered" if self.registered else "joint" if self.fit else "consensus"


@dataclass
class CameraView:
    camera_id: str
    epochs: list[EpochView]
    waiting: int
    sizes: list[tuple[int, int]]  # of its journeys' frames, newest first
    owners: dict[str, int | None]  # journey id -> owner key id, of the calibrations' journeys
    reprocessing: int = 0  # journeys queued or running again with a newer registered calibration

    @property
    def current(self) -> EpochView | None:
        return self.epochs[-1] if self.epochs else None

    @property
    def rows(self) -> list[CalibrationRow]:
        return [r for e in self.epochs for r in e.rows]


def camera_ids(session: Session, owner_key_id: int | None = None, everyone: bool = True
               ) -> list[str]:
    """Every camera known to the service (of a journey, or with a registered calibration), or
    with ``everyone`` False those of the journeys ``owner_key_id`` uploaded."""
    if not everyone:
        return list(session.scalars(select(JourneyRow.camera_id).distinct()
                                    .where(JourneyRow.owner_key_id == owner_key_id)
                                    .order_by(JourneyRow.camera_id)))
    ids = set(session.scalars(select(JourneyRow.camera_id).distinct()))
    ids |= set(session.scalars(select(CalibrationRow.camera_id).distinct()))
    return sorted(ids)


def owns_journey_of(session: Session, camera_id: str, owner_key_id: int | None) -> bool:
    return session.scalar(select(JourneyRow.id).where(
        JourneyRow.camera_id == camera_id, JourneyRow.owner_key_id == owner_key_id).limit(1)
    ) is not None


def _reason(row: CalibrationRow, against: CameraModel, what: str, agree_rel: float) -> str | None:
    """Why ``row`` is left out of ``against`` (None: it agrees)."""
    camera = state.stored_camera(row)
    if (camera.width, camera.height) != (against.width, against.height):
        return (f"calibrated on {camera.width}x{camera.height} frames; {what} is for "
                f"{against.width}x{against.height}")
    deviation = state.calibration_deviation(camera, against)
    over = [k for k in ("fx", "fy", "cx", "cy") if deviation[k] > agree_rel]
    if not over:
        return None
    unit = {"fx": "", "fy": "", "cx": " of the width", "cy": " of the height"}
    parts = ", ".join(f"{k} {100 * deviation[k]:.1f} %{unit[k]}" for k in over)
    return f"{parts} off {what}, over the {100 * agree_rel:g} % the journeys must agree within"


def _consensus_sigma(members: list[CalibrationRow]) -> tuple[dict[str, float | None], str]:
    if len(members) < 2:
        return ({k: None for k in CALIBRATION_PARAMS},
                "one self-calibration: its spread is not known")
    values = np.array([[getattr(r, k) for k in CALIBRATION_PARAMS] for r in members])
    sem = values.std(axis=0, ddof=1) / np.sqrt(len(members))
    return ({k: float(v) for k, v in zip(CALIBRATION_PARAMS, sem)},
            f"standard error of the mean of {len(members)} self-calibrations (their standard "
            f"deviation over sqrt({len(members)}))")


def _joint(view: EpochView, selfs: list[CalibrationRow], fit: CameraFitRow, newest: int) -> None:
    view.fit, view.camera = fit, state.fit_camera(fit)
    view.sigma = fit.sigma()
    view.sigma_basis = (f"joint bundle adjustment of {len(fit.used)} journeys' turn windows: the "
                        f"larger of its covariance's sigma and the spread of their own "
                        f"calibrations over sqrt({len(fit.used)})")
    view.considered = selfs[::-1][:newest]
    used, inputs = set(fit.used), set(fit.inputs)
    for row in view.considered:
        if row.id in used:
            view.members.append(row)
        elif str(row.id) in fit.left_out:
            view.left_out.append((row, fit.left_out[str(row.id)]))
        elif row.id not in inputs:
            view.left_out.append((row, "calibrated after the newest joint calibration"
                                  if row.id > max(inputs) else "its turn window was not kept"))


def _epoch(epoch: int, rows: list[CalibrationRow], agree_rel: float, newest: int,
           fit: CameraFitRow | None = None) -> EpochView:
    registered = next((r for r in rows if r.source == "registered"), None)
    selfs = [r for r in rows if r.source == "self"]
    view = EpochView(epoch=epoch, source="registered" if registered else "self",
                     started_at=min(r.created_at for r in rows), rows=rows, registered=registered)
    started = next((r for r in rows if r.epoch_reason), None)
    if registered is not None:
        view.reason = "calibration registered"
    elif started is not None:
        view.reason, view.first_journey_id = started.epoch_reason, started.journey_id
        view.started_at = started.created_at
    elif epoch == 1:
        view.reason = "the camera's first calibration"
    if view.first_journey_id is None and selfs:
        view.first_journey_id = selfs[0].journey_id
    if registered is not None:
        view.camera = state.stored_camera(registered)
        given = registered.sigma()
        view.sigma = {k: 0.0 if v is None else float(v) for k, v in given.items()}
        view.sigma_basis = ("as registered" if any(given.values()) else
                            "registered without sigmas: taken as exact (0)")
        view.considered = selfs[::-1]
        for row in view.considered:
            reason = _reason(row, view.camera, "the registered calibration", agree_rel)
            if reason is None:
                view.members.append(row)
            else:
                view.left_out.append((row, reason))
        return view
    if fit is not None:
        _joint(view, selfs, fit, newest)
        return view
    voters = selfs[::-1][:newest]
    camera, members = state.consensus([state.stored_camera(r) for r in voters], agree_rel)
    view.camera, view.considered = camera, voters
    view.members = [voters[i] for i in members]
    view.sigma, view.sigma_basis = _consensus_sigma(view.members)
    kept = {r.id for r in view.members}
    for row in voters:
        if row.id not in kept:
            what = f"the consensus of {len(view.members)} others"
            view.left_out.append((row, _reason(row, camera, what, agree_rel)
                                  or f"not in the largest group agreeing within "
                                     f"{100 * agree_rel:g} %"))
    return view


def camera_view(session: Session, camera_id: str, settings: Settings) -> CameraView | None:
    """Everything known of ``camera_id``; None for a camera the service never heard of."""
    rows = list(session.scalars(select(CalibrationRow).where(CalibrationRow.camera_id == camera_id)
                                .order_by(CalibrationRow.created_at, CalibrationRow.id)))
    sizes = [(int(w), int(h)) for w, h in session.execute(
        select(JourneyRow.image_width, JourneyRow.image_height)
        .where(JourneyRow.camera_id == camera_id, JourneyRow.image_width.is_not(None))
        .order_by(JourneyRow.created_at.desc()).limit(50))]
    n_journeys = session.scalar(select(func.count()).select_from(JourneyRow)
                                .where(JourneyRow.camera_id == camera_id))
    if not rows and not n_journeys:
        return None
    waiting = session.scalar(select(func.count()).select_from(JourneyRow).where(
        JourneyRow.camera_id == camera_id, JourneyRow.status == "queued",
        JourneyRow.stage == WAITING_FOR_CAMERA))
    reprocessing = session.scalar(select(func.count()).select_from(JourneyRow).where(
        JourneyRow.camera_id == camera_id, JourneyRow.reprocess_epoch.is_not(None),
        JourneyRow.status.in_(("queued", "running"))))
    journey_ids = [r.journey_id for r in rows if r.journey_id]
    owners = dict(session.execute(select(JourneyRow.id, JourneyRow.owner_key_id)
                                  .where(JourneyRow.id.in_(journey_ids))).all()) if journey_ids else {}
    by_epoch: dict[int, list[CalibrationRow]] = {}
    for row in rows:
        by_epoch.setdefault(row.epoch, []).append(row)
    epochs = [_epoch(e, by_epoch[e], settings.calibration_flag_rel,
                     settings.calibration_consensus_newest,
                     state.latest_fit(session, camera_id, e)) for e in sorted(by_epoch)]
    return CameraView(camera_id, epochs, waiting, list(dict.fromkeys(sizes)), owners,
                      reprocessing)


def _sigma_json(sigma: dict[str, float | None] | None) -> dict[str, float | None] | None:
    return None if sigma is None else {k: sigma[k] for k in CALIBRATION_PARAMS}


def to_json(view: CameraView, visible: Visible = lambda _owner: True, admin: bool = True
            ) -> dict[str, Any]:
    """The API's answer (``api.schemas.CameraOut``). Journeys of other owners than ``visible``
    admits are counted but not named (their ids are not disclosed across fleets); who registered
    a calibration is said to ``admin`` callers only."""
    current = view.current
    camera = current.camera if current else None
    size = ((camera.width, camera.height) if camera is not None
            else view.sizes[0] if view.sizes else (None, None))

    def journey(row: CalibrationRow) -> str | None:
        return row.journey_id if visible(view.owners.get(row.journey_id)) else None

    return {
        "camera_id": view.camera_id,
        "width": size[0], "height": size[1],
        "calibration": camera.params() if camera is not None else None,
        "source": current.kind if camera is not None else None,
        "fy_resolved": (bool(current.fit.fy_resolved) if camera is not None and current.fit
                        else None),
        "epoch": current.epoch if current else None,
        "sigma": _sigma_json(current.sigma) if camera is not None else None,
        "sigma_basis": current.sigma_basis if camera is not None else None,
        "journeys": len(current.members) if current else 0,
        "left_out": [{"journey_id": journey(row), "reason": reason}
                     for row, reason in (current.left_out if current else [])],
        "waiting": view.waiting,
        "reprocessing": view.reprocessing,
        "epochs": [{
            "epoch": e.epoch, "source": e.source, "started_at": e.started_at,
            "calibration_source": e.kind if e.camera is not None else None,
            "calibration": e.camera.params() if e.camera is not None else None,
            "sigma": _sigma_json(e.sigma), "journeys": len(e.members),
            "self_calibrations": sum(r.source == "self" for r in e.rows),
            "registered_by": e.registered.registered_by if e.registered and admin else None,
            "reason": e.reason,
            "first_journey_id": (e.first_journey_id
                                 if e.first_journey_id and visible(view.owners.get(
                                     e.first_journey_id)) else None),
        } for e in view.epochs],
    }
