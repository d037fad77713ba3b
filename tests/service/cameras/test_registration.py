"""PUT /api/v1/cameras/{camera_id}/calibration: what is refused (422 naming the field, 403 for
other roles), a registered calibration used as given in an epoch of its own (SQLite and
PostgreSQL), and migration 0008 on a database made at 0007."""

from __future__ import annotations

import secrets

import pytest
from sqlalchemy import func, select, text, update

from app.pipeline.types import CameraModel
from app.service.db.models import CalibrationRow, JourneyRow, utc_now
from app.service.db.session import get_engine, session_scope, temporary_database, upgrade
from app.service.jobs import state
from tests.service.cameras.conftest import BODY, new_camera, self_calibrated
from tests.utils.backends import PG_URL
from tests.utils.stack import ADMIN_KEY, auth

PARAMS = ("fx", "fy", "cx", "cy", "k1", "k2")


def _put(client, camera_id: str, body, key: str = ADMIN_KEY):
    return client.put(f"/api/v1/cameras/{camera_id}/calibration", json=body, headers=auth(key))


def _registered(stack, camera_id: str) -> int:
    with session_scope(stack.url) as session:
        return session.scalar(select(func.count()).select_from(CalibrationRow).where(
            CalibrationRow.camera_id == camera_id, CalibrationRow.source == "registered"))


@pytest.mark.parametrize("change, field", [
    ({"width": 0}, "width"), ({"height": -48}, "height"), ({"width": 64.5}, "width"),
    ({"fx": 0}, "fx"), ({"fy": -55.0}, "fy"), ({"fx": "55"}, "fx"), ({"fx": None}, "fx"),
    ({"fy": 1e7}, "fy"),  # 160 000 image widths: no camera
    ({"cx": 64.0}, "cx"), ({"cy": -3.0}, "cy"),  # the principal point outside the image
    ({"k1": 150.0}, "k1"),
    ({"k1": -3.0}, "k2"),  # folds the image back inside it: reported with k2, naming both
    ({"sigma": {"fx": -1.0}}, "sigma.fx"), ({"sigma": {"f": 1.0}}, "sigma.f"),
    ({"k3": 0.1}, "k3"),
])
def test_a_calibration_that_is_no_camera_is_refused_naming_the_field(sqlite, change, field):
    camera_id = new_camera()
    with sqlite.client() as client:
        answer = _put(client, camera_id, {**BODY, **change})
    assert answer.status_code == 422, answer.text
    locs = [e["loc"] for e in answer.json()["detail"]]
    assert locs == [["body", *field.split(".")]], answer.json()
    if field == "k2":
        assert "k1 = -3 and k2 = 0.01 fold the image back" in answer.json()["detail"][0]["msg"]
    assert _registered(sqlite, camera_id) == 0


def test_missing_and_non_finite_values_are_refused(sqlite):
    camera_id = new_camera()
    url = f"/api/v1/cameras/{camera_id}/calibration"
    with sqlite.client() as client:
        missing = _put(client, camera_id, {k: v for k, v in BODY.items() if k != "cx"})
        assert missing.status_code == 422
        assert [(e["loc"], e["type"]) for e in missing.json()["detail"]] == [
            (["body", "cx"], "missing")]
        for token in ("NaN", "Infinity", "-Infinity"):
            raw = ('{"width": 64, "height": 48, "fx": %s, "fy": 55, "cx": 31.5, "cy": 23.5}'
                   % token)
            answer = client.put(url, content=raw, headers={
                **auth(ADMIN_KEY), "Content-Type": "application/json"})
            assert answer.status_code == 422, (token, answer.text)
            assert [e["loc"] for e in answer.json()["detail"]] == [["body", "fx"]]
        bad_id = client.put("/api/v1/cameras/bad%01id/calibration", json=BODY,
                            headers=auth(ADMIN_KEY))
        assert bad_id.status_code == 422
        assert bad_id.json()["detail"][0]["loc"] == ["path", "camera_id"]
        assert "control characters" in bad_id.json()["detail"][0]["msg"]
    assert _registered(sqlite, camera_id) == 0


def test_the_size_must_be_that_of_the_cameras_journeys(sqlite):
    camera_id = new_camera()
    fleet = sqlite.key("fleet")
    with sqlite.client() as client:
        self_calibrated(sqlite, client, fleet, camera_id, fx=50.0)  # 64x48 frames
        answer = _put(client, camera_id, {**BODY, "width": 640, "height": 480, "cx": 320.0,
                                          "cy": 240.0})
        assert answer.status_code == 422
        detail = answer.json()["detail"]
        assert [e["loc"] for e in detail] == [["body", "width"], ["body", "height"]]
        assert "journeys have 64x48 frames, not 640x480" in detail[0]["msg"]
        assert _put(client, camera_id, BODY).status_code == 200


@pytest.mark.parametrize("role", ["fleet", "reader"])
def test_only_an_admin_may_register(sqlite, role):
    camera_id = new_camera()
    with sqlite.client() as client:
        answer = _put(client, camera_id, BODY, key=sqlite.key(role))
        assert answer.status_code == 403 and "admin key" in answer.json()["detail"]
        assert _put(client, camera_id, {**BODY, "fx": -1}, sqlite.key(role)).status_code == 403
        assert client.put(f"/api/v1/cameras/{camera_id}/calibration",
                          json=BODY).status_code == 401
    assert _registered(sqlite, camera_id) == 0


def _stored(stack, camera_id: str) -> state.StoredCalibration:
    settings = stack.settings
    with session_scope(stack.url) as session:
        return state.stored_calibration(session, camera_id, "", newest=7,
                                        agree_rel=settings.calibration_flag_rel)


def test_a_registered_calibration_starts_an_epoch_and_is_used_as_given(stack):
    """Epoch 1: a self-calibration. The registration is epoch 2, the camera's from then on as
    given: a later self-calibration that disagrees is flagged and left out, one that agrees is
    counted in it, and neither moves it."""
    camera_id = new_camera()
    fleet = stack.key("fleet")
    sigma = {"fx": 0.5, "fy": 0.5, "cx": 0.4, "cy": 0.4, "k1": 0.002, "k2": 0.004}
    given = CameraModel(64, 48, **{k: BODY[k] for k in PARAMS})
    with stack.client() as client:
        first = self_calibrated(stack, client, fleet, camera_id, fx=50.0)
        assert _stored(stack, camera_id).camera.fx == 50.0
        answer = _put(client, camera_id, {**BODY, "sigma": sigma})
        assert answer.status_code == 200, answer.text
        body = answer.json()
        assert (body["registered_epoch"], body["new_epoch"], body["resumed"]) == (2, True, [])
        assert (body["source"], body["epoch"], body["calibration"]) == (
            "registered", 2, {k: BODY[k] for k in PARAMS})
        assert body["sigma"] == sigma and body["sigma_basis"] == "as registered"
        assert [(e["epoch"], e["source"], e["journeys"], e["self_calibrations"])
                for e in body["epochs"]] == [(1, "self", 1, 1), (2, "registered", 0, 0)]
        assert body["epochs"][0]["calibration"]["fx"] == 50.0  # the older epoch keeps its own
        assert body["epochs"][1]["registered_by"] == "SIGNMAP_ADMIN_KEY"
        assert _stored(stack, camera_id) == state.StoredCalibration(given, "registered", 2)

        wrong = self_calibrated(stack, client, fleet, camera_id, fx=60.0, n_frames=6)
        right = self_calibrated(stack, client, fleet, camera_id, fx=55.2, n_frames=7)
        flag = client.get(f"/api/v1/journeys/{wrong}", headers=auth(fleet)).json()[
            "calibration_flag"]
        assert flag["reason"] == "self-calibration differs from the registered one in fx, fy"
        assert flag["stored_source"] == "registered" and flag["stored"]["fx"] == 55.0
        assert client.get(f"/api/v1/journeys/{right}",
                          headers=auth(fleet)).json()["calibration_flag"] is None
        assert _stored(stack, camera_id) == state.StoredCalibration(given, "registered", 2)
        body = client.get(f"/api/v1/cameras/{camera_id}", headers=auth(ADMIN_KEY)).json()
        assert body["calibration"] == {k: BODY[k] for k in PARAMS}  # as given: no mean
        assert body["journeys"] == 1
        assert [o["journey_id"] for o in body["left_out"]] == [wrong]
        assert body["left_out"][0]["reason"].startswith(
            "fx 9.1 %, fy 9.9 % off the registered calibration")
        assert [(e["epoch"], e["journeys"], e["self_calibrations"]) for e in body["epochs"]] == [
            (1, 1, 1), (2, 1, 2)]

        # The same values again change nothing; others start epoch 3, and epoch 2's
        # self-calibrations stay in epoch 2.
        again = _put(client, camera_id, {**BODY, "sigma": sigma}).json()
        assert (again["registered_epoch"], again["new_epoch"]) == (2, False)
        third = _put(client, camera_id, {**BODY, "fx": 56.0}).json()
        assert (third["registered_epoch"], third["new_epoch"], third["epoch"]) == (3, True, 3)
        assert third["sigma"] == dict.fromkeys(PARAMS, 0.0)
        assert third["sigma_basis"] == "registered without sigmas: taken as exact (0)"
        assert [e["self_calibrations"] for e in third["epochs"]] == [1, 2, 0]
    with session_scope(stack.url) as session:
        epochs = dict(session.execute(select(CalibrationRow.journey_id, CalibrationRow.epoch)
                                      .where(CalibrationRow.camera_id == camera_id,
                                             CalibrationRow.source == "self")).all())
    assert epochs == {first: 1, wrong: 2, right: 2}


# Migration 0008 on a database made at 0007, with a journey and its self-calibration in it.

@pytest.fixture(params=["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def url_at_0007(request, tmp_path):
    if request.param == "sqlite":
        url = f"sqlite:///{tmp_path / 'old.db'}"
        upgrade(url, "0007")
        yield url
        return
    request.getfixturevalue("pg_url")  # skips (or fails under CI) without PostgreSQL
    with temporary_database(PG_URL, f"signmap_test_0008_{secrets.token_hex(3)}") as url:
        upgrade(url, "0007")
        yield url


def test_migration_0008_keeps_the_calibrations_as_epoch_1(url_at_0007):
    with get_engine(url_at_0007).begin() as conn:
        conn.execute(text(
            "INSERT INTO journeys (id, camera_id, bundle_sha256, bundle_bytes, status, progress, "
            "n_frames, attempts, created_at) VALUES ('j-old', 'cam-old', 'x', 1, 'done', 1.0, 5, "
            "1, :t)"), {"t": utc_now()})
        conn.execute(text(
            "INSERT INTO calibrations (camera_id, journey_id, width, height, fx, fy, cx, cy, k1, "
            "k2, n_images, n_registered, rotation_deg, created_at) VALUES ('cam-old', 'j-old', "
            "64, 48, 50, 51, 31.5, 23.5, -0.1, 0.01, 5, 5, 35, :t)"), {"t": utc_now()})
    upgrade(url_at_0007)
    with session_scope(url_at_0007) as session:
        row = session.scalars(select(CalibrationRow)).one()
        assert (row.source, row.epoch, row.journey_id, row.sigma()) == (
            "self", 1, "j-old", dict.fromkeys(PARAMS))
        old = session.get(JourneyRow, "j-old")
        assert (old.image_width, old.image_height, old.message) == (64, 48, None)
        stored = state.stored_calibration(session, "cam-old", "", agree_rel=0.03, newest=7)
        assert (stored.source, stored.epoch, stored.camera.fx) == ("consensus", 1, 50.0)
        # A registered calibration has no journey; a self-calibration must have one.
        session.add(CalibrationRow(camera_id="cam-old", source="registered", epoch=2, width=64,
                                   height=48, fx=1, fy=1, cx=1, cy=1, k1=0, k2=0))
    with pytest.raises(Exception, match="ck_calibrations_source|CHECK constraint"):
        with session_scope(url_at_0007) as session:
            session.execute(update(CalibrationRow).where(CalibrationRow.source == "registered")
                            .values(journey_id="j-old"))
