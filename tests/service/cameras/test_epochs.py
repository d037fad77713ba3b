"""Lens changes (issue 66, item 2): one disagreeing self-calibration starts no epoch; two that
agree with each other and differ from the epoch's calibration do, and the camera's calibration
becomes theirs while the old epoch keeps its own; frames of another size start an epoch at once;
a straight journey of the new size waits for its camera and resumes once the epoch exists; the
done journeys given the old lens's calibration after the change are re-processed, not those
before it."""

from __future__ import annotations

import dataclasses
import secrets

from sqlalchemy import select

from app.pipeline.types import CameraModel
from app.service.db.models import CalibrationRow
from app.service.db.session import session_scope
from app.service.jobs import cameras, fusion, state
from app.service.jobs.run import run_journey
from tests.service.cameras.conftest import journey, new_camera, self_calibrated
from tests.utils import bundle_factory as bf
from tests.utils.results.service_support import bf_zip, made_result
from tests.utils.stack import ADMIN_KEY, auth, upload


def _epochs(stack, camera_id: str) -> dict[str, int]:
    with session_scope(stack.url) as session:
        return dict(session.execute(select(CalibrationRow.journey_id, CalibrationRow.epoch).where(
            CalibrationRow.camera_id == camera_id, CalibrationRow.source == "self")).all())


def _stored(stack, camera_id: str, size=None) -> state.StoredCalibration | None:
    with session_scope(stack.url) as session:
        return state.stored_calibration(session, camera_id, "", agree_rel=0.03, newest=7,
                                        size=size)


def _camera(client, camera_id: str) -> dict:
    return client.get(f"/api/v1/cameras/{camera_id}", headers=auth(ADMIN_KEY)).json()


def test_one_disagreeing_journey_starts_no_epoch(sqlite):
    camera_id, fleet = new_camera(), sqlite.key("fleet")
    with sqlite.client() as client:
        old = [self_calibrated(sqlite, client, fleet, camera_id, fx=50.0, n_frames=n)
               for n in (5, 6)]
        lone = self_calibrated(sqlite, client, fleet, camera_id, fx=55.0, n_frames=7)
        assert set(_epochs(sqlite, camera_id).values()) == {1}
        body = _camera(client, camera_id)
        assert [e["epoch"] for e in body["epochs"]] == [1]
        assert [o["journey_id"] for o in body["left_out"]] == [lone]
        assert body["calibration"]["fx"] == 50.0 and body["journeys"] == 2
        assert client.get(f"/api/v1/journeys/{lone}",
                          headers=auth(fleet)).json()["calibration_flag"] is not None
        # One that agrees with the epoch after it: still one epoch.
        self_calibrated(sqlite, client, fleet, camera_id, fx=50.3, n_frames=8)
        assert set(_epochs(sqlite, camera_id).values()) == {1}
    assert old


def test_two_agreeing_disagreeing_journeys_start_an_epoch_and_move_the_camera(sqlite):
    camera_id, fleet = new_camera(), sqlite.key("fleet")
    with sqlite.client() as client:
        old = [self_calibrated(sqlite, client, fleet, camera_id, fx=fx, n_frames=n)
               for fx, n in ((50.0, 5), (50.4, 6))]
        before = self_calibrated(sqlite, client, fleet, camera_id, fx=50.2, n_frames=7,
                                 source="supplied")  # old lens, no turn: keeps its calibration
        first = self_calibrated(sqlite, client, fleet, camera_id, fx=52.5, n_frames=8)
        between = self_calibrated(sqlite, client, fleet, camera_id, fx=50.2, n_frames=9,
                                  source="supplied")  # new lens given the old lens's calibration
        assert set(_epochs(sqlite, camera_id).values()) == {1}  # one alone: no epoch
        second = self_calibrated(sqlite, client, fleet, camera_id, fx=52.7, n_frames=10)

        assert _epochs(sqlite, camera_id) == {old[0]: 1, old[1]: 1, first: 2, second: 2}
        stored = _stored(sqlite, camera_id)
        assert (stored.source, stored.epoch) == ("consensus", 2)
        assert abs(stored.camera.fx - 52.6) < 1e-9  # their consensus, never the old epoch's
        body = _camera(client, camera_id)
        assert (body["epoch"], body["journeys"], body["left_out"]) == (2, 2, [])
        one, two = body["epochs"]
        assert (one["epoch"], one["journeys"], one["self_calibrations"]) == (1, 2, 2)
        assert abs(one["calibration"]["fx"] - 50.2) < 1e-9  # the old epoch is unchanged
        assert (two["source"], two["first_journey_id"], two["journeys"]) == ("self", first, 2)
        assert two["reason"] == ("2 journeys agree with each other and differ from epoch 1 by "
                                 "fx +4.8 %")
        assert client.post("/admin/login", data={"key": ADMIN_KEY}).status_code == 200
        section = client.get("/admin/cameras").text.split(f"<h2>{camera_id}</h2>")[1]
        assert "differ from epoch 1 by fx +4.8 % (first journey" in section
        assert f'<a href="/admin/journeys/{first}">' in section

        # Re-processing: the journey given the old lens's calibration after the change, not the
        # one before it; a second trigger finds nothing left.
        submitted: list[str] = []
        assert cameras.reprocess_superseded(sqlite.url, camera_id, submitted.append,
                                            settings=sqlite.settings) == [between]
        assert submitted == [between]
        assert cameras.reprocess_superseded(sqlite.url, camera_id, None,
                                            settings=sqlite.settings) == []
        row = journey(sqlite, between)
        assert (row.status, row.stage, row.reprocess_epoch) == ("queued", "reprocessing", 2)
        assert journey(sqlite, before).status == "done"

        # A later agreeing journey joins the new epoch; a re-run of a moved one stays in it.
        third = self_calibrated(sqlite, client, fleet, camera_id, fx=52.4, n_frames=11)
        assert _epochs(sqlite, camera_id)[third] == 2


def test_a_registered_epoch_is_left_by_two_agreeing_journeys(sqlite):
    camera_id, fleet = new_camera(), sqlite.key("fleet")
    with sqlite.client() as client:
        self_calibrated(sqlite, client, fleet, camera_id, fx=50.0)
        cameras.register(sqlite.url, camera_id, cameras.Registration(
            width=64, height=48, fx=50.0, fy=51.0, cx=31.5, cy=23.5, k1=-0.1, k2=0.01), "test")
        a = self_calibrated(sqlite, client, fleet, camera_id, fx=47.0, n_frames=6)
        b = self_calibrated(sqlite, client, fleet, camera_id, fx=47.2, n_frames=7)
        assert _epochs(sqlite, camera_id)[a] == _epochs(sqlite, camera_id)[b] == 3
        reasons = [(e["source"], e["reason"]) for e in _camera(client, camera_id)["epochs"]]
        assert reasons[1] == ("registered", "calibration registered")
        assert reasons[2] == ("self", "2 journeys agree with each other and differ from epoch "
                                      "2's registered calibration by fx -5.8 %")


def _files(camera_id: str, n_frames: int, width: int, height: int) -> dict[str, bytes]:
    """``camera_files`` with frames of ``width`` x ``height``."""
    return {**bf.valid_files(n_frames=n_frames, width=width, height=height),
            "manifest.json": bf.manifest_bytes(camera_id=camera_id)}


def _self_calibrated_at(stack, client, key, camera_id, width, height, fx, n_frames) -> str:
    """``self_calibrated`` for frames of ``width`` x ``height``."""
    from app.pipeline.bundle import read_bundle

    files = _files(camera_id, n_frames, width, height)
    journey_id = upload(client, key, bf_zip(files))
    work = stack.settings.data_dir / "test-extract" / secrets.token_hex(4)
    work.mkdir(parents=True)
    (work / "b.zip").write_bytes(bf_zip(files))
    data = read_bundle(work / "b.zip", work / "x", decode_images=False)
    result = made_result([("0", "stop", 49.0112, 8.4185, 114.0)], "self", fx=fx)
    camera = CameraModel(width, height, fx, fx + 1.0, width / 2 - 0.5, height / 2 - 0.5, -0.1, 0.01)
    result.calibration = dataclasses.replace(result.calibration, camera=camera)
    with session_scope(stack.url) as session:
        attempt = state.claim(session, journey_id, 60, 3)
    with session_scope(stack.url) as session:
        assert fusion.store_journey(session, journey_id, attempt, data, result, {"total_s": 1.0},
                                    None, stack.settings)
    return journey_id


def test_another_frame_size_starts_an_epoch_at_once_and_its_straight_journey_waits(sqlite):
    camera_id, fleet = new_camera(), sqlite.key("fleet")
    with sqlite.client() as client:
        old = self_calibrated(sqlite, client, fleet, camera_id, fx=50.0)
        # A straight journey of 80x60 frames: the camera's calibration is for 64x48, and it has
        # no epoch of 80x60: it waits (it no longer fails).
        straight = upload(client, fleet, bf_zip(_files(camera_id, 6, 80, 60)))
        run_journey(straight, sqlite.settings)
        row = journey(sqlite, straight)
        assert (row.status, row.stage) == ("queued", "waiting_for_camera"), row.error
        assert (row.image_width, row.image_height) == (80, 60)

        new = _self_calibrated_at(sqlite, client, fleet, camera_id, 80, 60, fx=62.0, n_frames=7)
        assert _epochs(sqlite, camera_id) == {old: 1, new: 2}  # at once, one journey
        two = _camera(client, camera_id)["epochs"][1]
        assert (two["source"], two["first_journey_id"], two["reason"]) == (
            "self", new, "frames 80x60, epoch 1 was 64x48")
        assert _stored(sqlite, camera_id, (80, 60)).epoch == 2
        assert _stored(sqlite, camera_id, (64, 48)).epoch == 1  # the old size keeps its epoch

        # The wake (the run of ``new`` does it; the sweeps repair a lost one) and the resumed run:
        # given epoch 2's calibration (the only one of 80x60 frames) it gets past calibrate; the
        # factory bundle's random pixels then give COLMAP nothing to reconstruct (a rendered
        # journey finishes, tests/service/cameras/test_resume_registered.py).
        assert cameras.wake_calibrated(sqlite.url, sqlite.settings, None) == [straight]
        run_journey(straight, sqlite.settings)
        row = journey(sqlite, straight)
        calibrate = next(r for r in row.report if r["stage"] == "calibrate")
        assert calibrate["summary"].startswith(f"stored calibration of camera {camera_id} used")
        assert row.stage == "ego_motion", row.error
        # Back to 64x48 frames: another change of size, another epoch (never epoch 1 averaged).
        again = self_calibrated(sqlite, client, fleet, camera_id, fx=50.1, n_frames=8)
        assert _epochs(sqlite, camera_id)[again] == 3  # 64x48 after 80x60: another change
