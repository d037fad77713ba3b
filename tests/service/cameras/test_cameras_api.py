"""GET /api/v1/cameras and /api/v1/cameras/{camera_id}: who sees which camera (an admin all, a
fleet key the cameras of its own journeys, a reader none), and what a camera's record says: the
consensus and its sigma, the journeys left out and why, the journeys waiting for it."""

from __future__ import annotations

import numpy as np
import pytest

from tests.service.cameras.conftest import (BODY, camera_files, new_camera, self_calibrated,
                                            waiting)
from tests.utils.results.service_support import bf_zip
from tests.utils.stack import ADMIN_KEY, auth, upload


def _get(client, path: str, key: str):
    return client.get(f"/api/v1/cameras{path}", headers=auth(key))


def test_who_sees_which_camera(stack):
    fleet_a, fleet_b, reader = stack.key("fleet"), stack.key("fleet"), stack.key("reader")
    cam_a, cam_b, cam_r = new_camera(), new_camera(), new_camera()
    with stack.client() as client:
        own = self_calibrated(stack, client, fleet_a, cam_a, fx=50.0)
        upload(client, fleet_b, bf_zip(camera_files(cam_b)))  # queued, not run
        assert client.put(f"/api/v1/cameras/{cam_r}/calibration", json=BODY,
                          headers=auth(ADMIN_KEY)).status_code == 200  # no journey yet

        listed = {c["camera_id"] for c in _get(client, "", ADMIN_KEY).json()}
        assert {cam_a, cam_b, cam_r} <= listed
        assert [c["camera_id"] for c in _get(client, "", fleet_a).json()] == [cam_a]
        assert [c["camera_id"] for c in _get(client, "", fleet_b).json()] == [cam_b]
        for path in ("", f"/{cam_a}"):
            assert _get(client, path, reader).status_code == 403
        assert _get(client, "", "not-a-key").status_code == 401

        a = _get(client, f"/{cam_a}", fleet_a).json()
        assert (a["camera_id"], a["source"], a["epoch"], a["journeys"]) == (
            cam_a, "consensus", 1, 1)
        assert a["calibration"] == {"fx": 50.0, "fy": 51.0, "cx": 31.5, "cy": 23.5, "k1": -0.1,
                                    "k2": 0.01}
        assert (a["width"], a["height"], a["waiting"], a["left_out"]) == (64, 48, 0, [])
        assert a["sigma"] == dict.fromkeys(("fx", "fy", "cx", "cy", "k1", "k2"))
        assert a["sigma_basis"] == "one self-calibration: its spread is not known"
        assert a == _get(client, f"/{cam_a}", ADMIN_KEY).json()
        # Another fleet's camera, or one of no journey of the caller's, is not found.
        for path in (f"/{cam_b}", f"/{cam_r}", "/no-such-camera"):
            assert _get(client, path, fleet_a).status_code == 404
        assert _get(client, "/no-such-camera", ADMIN_KEY).status_code == 404

        b = _get(client, f"/{cam_b}", fleet_b).json()
        assert (b["calibration"], b["source"], b["epoch"], b["sigma"], b["journeys"]) == (
            None, None, None, None, 0)
        assert b["epochs"] == [] and b["width"] is None  # its frames were never read
        r = _get(client, f"/{cam_r}", ADMIN_KEY).json()
        assert (r["source"], r["epoch"], r["width"], r["height"]) == ("registered", 1, 64, 48)

        # Fleet B drives camera A too, and its calibration disagrees with fleet A's two: fleet
        # A sees it left out, but not which journey it is; an admin sees that too.
        self_calibrated(stack, client, fleet_a, cam_a, fx=50.3, n_frames=7)
        other = self_calibrated(stack, client, fleet_b, cam_a, fx=57.0, n_frames=6)
        a = _get(client, f"/{cam_a}", fleet_a).json()
        assert a["journeys"] == 2 and [o["journey_id"] for o in a["left_out"]] == [None]
        assert a["left_out"][0]["reason"] == (
            "fx 13.7 %, fy 13.4 % off the consensus of 2 others, over the 3 % the journeys must "
            "agree within")
        admin = _get(client, f"/{cam_a}", ADMIN_KEY).json()
        assert [o["journey_id"] for o in admin["left_out"]] == [other]
        assert _get(client, f"/{cam_a}", fleet_b).json()["left_out"][0]["journey_id"] == other
        assert own not in str(_get(client, f"/{cam_a}", fleet_b).json())


def test_the_sigma_of_a_consensus_is_the_standard_error_of_its_mean(sqlite):
    camera_id = new_camera()
    fleet = sqlite.key("fleet")
    with sqlite.client() as client:
        for i, fx in enumerate((50.0, 50.5, 49.8, 57.0)):  # three agree, one 14 % off
            self_calibrated(sqlite, client, fleet, camera_id, fx=fx, n_frames=5 + i)
        body = _get(client, f"/{camera_id}", fleet).json()
    members = np.array([50.0, 50.5, 49.8])
    assert body["journeys"] == 3 and len(body["left_out"]) == 1
    assert body["calibration"]["fx"] == pytest.approx(members.mean())
    assert body["sigma"]["fx"] == pytest.approx(members.std(ddof=1) / np.sqrt(3))
    assert body["sigma"]["fy"] == pytest.approx(members.std(ddof=1) / np.sqrt(3))
    assert body["sigma"]["cx"] == 0.0  # every member has the same principal point
    assert body["sigma_basis"].startswith("standard error of the mean of 3 self-calibrations")


def test_a_camera_id_may_hold_slashes(sqlite):
    camera_id = f"fleet/{new_camera()}/front"
    with sqlite.client() as client:
        assert client.put(f"/api/v1/cameras/{camera_id}/calibration", json=BODY,
                          headers=auth(ADMIN_KEY)).status_code == 200
        escaped = camera_id.replace("/", "%2F")
        for path in (camera_id, escaped):
            body = _get(client, f"/{path}", ADMIN_KEY).json()
            assert (body["camera_id"], body["source"]) == (camera_id, "registered")


def test_the_journeys_waiting_for_a_camera_are_counted(sqlite):
    camera_id = new_camera()
    fleet = sqlite.key("fleet")
    with sqlite.client() as client:
        journey_id = waiting(sqlite, client, fleet, camera_id)
        body = _get(client, f"/{camera_id}", fleet).json()
        assert (body["waiting"], body["calibration"], body["width"], body["height"]) == (
            1, None, 64, 48)
        journey = client.get(f"/api/v1/journeys/{journey_id}", headers=auth(fleet)).json()
    assert (journey["status"], journey["stage"], journey["error"]) == (
        "queued", "waiting_for_camera", None)
    assert journey["message"].startswith(f"waiting for a calibration of camera {camera_id}: "
                                         "the journey has no turn")
    assert "PUT /api/v1/cameras/{camera_id}/calibration" in journey["message"]
    assert [r["stage"] for r in journey["report"]] == ["turns", "calibrate"]
