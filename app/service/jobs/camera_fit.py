"""A camera's joint calibration, kept up to date as its journeys self-calibrate (issue 66,
item 1; docs/decisions/camera-joint-calibration.md).

Each self-calibration stores its accepted turn window with it (``calibrations.window``). After a
journey's self-calibration is stored, ``refit`` adjusts the newest windows of its epoch
(``calibration_consensus_newest`` of them) together with one shared camera
(``cameras.calibrate_jointly``) and stores the result as a ``camera_fits`` row, which
``state.stored_calibration`` gives the camera's later journeys in place of the consensus of
their calibrations. An epoch with a registered calibration keeps it as given; an epoch with one
window has nothing to fit (its calibration is that one).

The fit runs in the worker after the journey is stored (seconds to a minute, in a COLMAP child
process), outside any transaction. Two journeys of a camera finishing together may both fit:
each stores its own row, the newest wins, and the same inputs are never fitted twice.
"""

from __future__ import annotations

import logging

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session, undefer

from app.pipeline.cameras.calibrate_jointly import CameraWindow, calibrate_jointly
from app.pipeline.types import INTRINSICS_STD
from app.service.db.models import CalibrationRow, CameraFitRow
from app.service.db.session import session_scope
from app.service.jobs import state
from app.settings import Settings

log = logging.getLogger(__name__)


def _windows(session: Session, camera_id: str, epoch: int, newest: int
             ) -> list[CalibrationRow]:
    """The epoch's newest self-calibrations that kept their window, oldest first."""
    rows = session.scalars(
        select(CalibrationRow).options(undefer(CalibrationRow.window))
        .where(CalibrationRow.camera_id == camera_id, CalibrationRow.epoch == epoch,
               CalibrationRow.source == "self", CalibrationRow.window.is_not(None))
        .order_by(CalibrationRow.created_at.desc(), CalibrationRow.id.desc()).limit(newest))
    return list(rows)[::-1]


def refit(url: str, camera_id: str, epoch: int, settings: Settings) -> CameraFitRow | None:
    """Fit ``camera_id``'s ``epoch`` jointly from its newest windows and store the result;
    None when there is nothing to fit (a registered epoch, fewer than two windows) or these
    windows were fitted already."""
    with session_scope(url) as session:
        if state.registered_row(session, camera_id, epoch) is not None:
            return None
        rows = _windows(session, camera_id, epoch, settings.calibration_consensus_newest)
        inputs = sorted(r.id for r in rows)
        last = state.latest_fit(session, camera_id, epoch)
        if len(rows) < 2 or (last is not None and sorted(last.inputs) == inputs):
            return None
        windows = [CameraWindow(str(r.id), state.stored_camera(r), state.window_of(r.window),
                                tuple(np.nan if v is None else v for v in r.sigma().values()))
                   for r in rows]
        journeys = {str(r.id): r.journey_id for r in rows}
    joint = calibrate_jointly(windows, agree_rel=settings.calibration_flag_rel)
    cam = joint.camera
    fit = CameraFitRow(
        camera_id=camera_id, epoch=epoch, width=cam.width, height=cam.height, **cam.params(),
        **{f"sigma_{k}": (float(joint.sigma[k]) if np.isfinite(joint.sigma[k]) else None)
           for k in INTRINSICS_STD},
        fy_resolved=joint.fy_resolved, inputs=inputs, used=sorted(int(i) for i in joint.used),
        left_out=dict(joint.left_out), rms_px=dict(joint.rms_px))
    with session_scope(url) as session:
        session.add(fit)
    log.info("camera %s: epoch %d calibrated jointly from %d journeys' turn windows (%s left "
             "out): fx %.1f fy %.1f cx %.1f cy %.1f k1 %+.4f k2 %+.4f, sigma fx %.2f px%s",
             camera_id, epoch, len(joint.used), len(joint.left_out) or "none", cam.fx, cam.fy,
             cam.cx, cam.cy, cam.k1, cam.k2, joint.sigma["fx"],
             "" if joint.fy_resolved else "; fy not resolved by these turns")
    for calibration_id, reason in joint.left_out.items():
        log.warning("camera %s: journey %s's turn window left out of the joint calibration: %s",
                    camera_id, journeys[calibration_id], reason)
    return fit
