"""The admin dashboard, server side (TestClient on the SQLite stack): sign-in, refusals, pages, actions."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from sqlalchemy import func, select

from app.service.admin.session import COOKIE
from app.service.db.session import session_scope
from app.service.db.models import (AdminSessionRow, ApiKeyRow, CalibrationRow, JourneyRow, CoverageRow,
                                JourneySignRow)
from tests.utils.results.dashboard_seed import add_journey
from app.service.db.map_tiles import decode
from tests.utils.stack import ADMIN_KEY, auth, sqlite_stack

PAGES = ["/admin", "/admin/journeys", "/admin/map", "/admin/cameras",
         "/admin/journeys/progress.json?ids=x", "/admin/api/signs?bbox=0,0,1,1"]


@pytest.fixture
def stack(tmp_path):
    return sqlite_stack(tmp_path / "data")


@pytest.fixture
def client(stack):
    with stack.client() as client:
        yield client


def sign_in(client, key: str = ADMIN_KEY):
    return client.post("/admin/login", data={"key": key}, follow_redirects=False)


@pytest.mark.parametrize("path", PAGES)
def test_every_page_redirects_to_sign_in_without_a_session(client, path):
    answer = client.get(path, follow_redirects=False)
    assert answer.status_code == 303
    assert answer.headers["location"] == "/admin/login"


def test_actions_need_a_session(client, stack):
    journey_id = add_journey(stack.settings, "failed")
    for action in ("retry", "delete"):
        answer = client.post(f"/admin/journeys/{journey_id}/{action}", follow_redirects=False)
        assert answer.status_code == 303 and answer.headers["location"] == "/admin/login"
    with session_scope(stack.url) as session:
        assert session.get(JourneyRow, journey_id).status == "failed"


@pytest.mark.parametrize("role", ["fleet", "reader", None])
def test_non_admin_keys_are_refused(client, stack, role):
    key = stack.key(role) if role else "not-a-key"
    answer = sign_in(client, key)
    assert answer.status_code == 403
    assert "not an admin key" in answer.text
    assert COOKIE not in answer.cookies
    assert client.get("/admin/journeys", follow_redirects=False).status_code == 303


def test_sign_in_sets_a_strict_http_only_cookie_and_sign_out_ends_it(client, stack):
    answer = sign_in(client)
    assert answer.status_code == 303 and answer.headers["location"] == "/admin/journeys"
    cookie = answer.headers["set-cookie"]
    assert "HttpOnly" in cookie and "SameSite=strict" in cookie and "Path=/admin" in cookie
    assert "Secure" not in cookie  # plain http here; https sets it
    value = answer.cookies[COOKIE]
    assert client.get("/admin/journeys").status_code == 200
    with session_scope(stack.url) as session:
        assert session.scalar(select(func.count()).select_from(ApiKeyRow)) == 0  # no key was made
        assert session.scalar(select(func.count()).select_from(AdminSessionRow)) == 1

    assert client.post("/admin/logout", follow_redirects=False).status_code == 303
    with session_scope(stack.url) as session:
        assert session.scalar(select(func.count()).select_from(AdminSessionRow)) == 0
    client.cookies.set(COOKIE, value, path="/admin")  # a replayed cookie is dead after sign-out
    assert client.get("/admin/journeys", follow_redirects=False).status_code == 303


def test_a_tampered_cookie_and_a_stored_admin_key(client, stack):
    sign_in(client)
    value = client.cookies.get(COOKIE)
    client.cookies.clear()
    client.cookies.set(COOKIE, value[:-2] + ("AA" if value[-2:] != "AA" else "BB"), path="/admin")
    assert client.get("/admin/journeys", follow_redirects=False).status_code == 303
    client.cookies.clear()
    assert sign_in(client, stack.key("admin")).status_code == 303
    assert client.get("/admin/cameras").status_code == 200


def test_cross_origin_posts_are_refused(client, stack):
    sign_in(client)
    journey_id = add_journey(stack.settings, "failed")
    answer = client.post(f"/admin/journeys/{journey_id}/retry",
                         headers={"Origin": "https://evil.example"}, follow_redirects=False)
    assert answer.status_code == 403


def test_journeys_page_lists_filters_and_paginates(client, stack):
    done = add_journey(stack.settings, "done")
    failed = add_journey(stack.settings, "failed", camera_id="cam-b", error="no turn found")
    running = add_journey(stack.settings, "running", progress=0.4, stage="ego-motion")
    sign_in(client)
    page = client.get("/admin/journeys").text
    for journey_id in (done, failed, running):
        assert f'data-id="{journey_id}"' in page
    assert "no turn found" in page and "width: 40.0%" in page and "ego-motion" in page
    only_failed = client.get("/admin/journeys?status=failed").text
    assert f'data-id="{failed}"' in only_failed and f'data-id="{done}"' not in only_failed
    cam_b = client.get("/admin/journeys?camera=cam-b").text
    assert cam_b.count("<tr data-id=") == 1
    for _ in range(50):
        add_journey(stack.settings)
    assert client.get("/admin/journeys").text.count("<tr data-id=") == 50
    assert client.get("/admin/journeys?page=2").text.count("<tr data-id=") == 3
    progress = client.get(f"/admin/journeys/progress.json?ids={running},{done}").json()
    assert progress[running]["progress"] == pytest.approx(0.4)
    assert progress[done] == {"status": "done", "stage": "done", "progress": 1.0, "error": None,
                              "message": None, "n_signs": 2}


def test_journey_page_shows_track_signs_calibration_and_crops(client, stack):
    journey_id = add_journey(stack.settings, "done")
    sign_in(client)
    page = client.get(f"/admin/journeys/{journey_id}")
    assert page.status_code == 200
    text = page.text
    assert "GPS track (5 frames)" in text and "signs (2)" in text
    assert "stop" in text and "yield" in text and "calibrate" in text and "1.50 s" in text
    assert "fx = 50" in text
    # Each sign's 95 % radius and facing (tests/utils/results/service_support.py: 0.5 + 0.1 i m,
    # 90 i deg).
    assert "95 % within 0.50 m · faces 0°" in text and "95 % within 0.60 m · faces 90°" in text
    crop_url = f"/admin/journeys/{journey_id}/crop.png?track=0&frame=000001"
    assert crop_url in text
    crop = client.get(crop_url)
    assert crop.status_code == 200 and crop.headers["content-type"] == "image/png"
    image = cv2.imdecode(np.frombuffer(crop.content, np.uint8), cv2.IMREAD_COLOR)
    # Box [13, 10, 21, 18] in a 64x48 frame: the 96 px minimum crop is clipped to the frame.
    assert image.shape == (48, 64, 3)
    assert tuple(image[10, 17]) == (0, 0, 255)  # the box's top edge, drawn in red
    cached = list((stack.settings.data_dir / "cache" / "admin").rglob("000001_*.png"))
    assert len(cached) == 1
    assert client.get(f"/admin/journeys/{journey_id}/crop.png?track=0&frame=999").status_code == 404
    assert client.get("/admin/journeys/nope").status_code == 404


def test_journey_page_shows_the_estimated_trajectory_when_stored(client, stack):
    journey_id = add_journey(stack.settings, "done")
    with session_scope(stack.url) as session:
        session.merge(CoverageRow(
            journey_id=journey_id, journey_key="k", captured_at_s=0.0, origin_lat_deg=49.0,
            origin_lon_deg=8.4, origin_alt_m=100.0, camera={}, frame_ids=["000000", "000001"],
            poses=[[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0], [1, 0, 0, 100, 0, 1, 0, 0, 0, 0, 1, 0]]))
    sign_in(client)
    text = client.get(f"/admin/journeys/{journey_id}").text
    assert "estimated, aligned to GPS (2 frames)" in text
    data = json.loads(text.split('id="journey-data" type="application/json">')[1]
                      .split("</script>")[0])
    (lat0, lon0), (lat1, lon1) = data["estimated"]
    assert (lat0, lon0) == pytest.approx((49.0, 8.4), abs=1e-9)
    # 100 m east at 49 deg N: 100 / (111320 cos 49deg) deg of longitude.
    assert lon1 - 8.4 == pytest.approx(100 / (111_320 * np.cos(np.radians(49.0))), rel=5e-3)
    assert lat1 == pytest.approx(49.0, abs=2e-6)


def test_map_page_serves_leaflet_locally_and_passes_the_public_map_through(client, stack):
    add_journey(stack.settings, "done")
    sign_in(client)
    page = client.get("/admin/map").text
    assert 'src="/admin/static/leaflet/leaflet.js"' in page and "openstreetmap" in page
    assert "http" not in page.split("data-tile-url")[0].replace("https://tile", "")  # no CDN
    assert client.get("/admin/static/leaflet/leaflet.js").status_code == 200
    assert client.get("/admin/static/app/map.js").status_code == 200
    bbox = "8.41,49.0,8.43,49.02"
    passed = client.get(f"/admin/api/signs?bbox={bbox}")
    direct = client.get(f"/api/v1/signs?bbox={bbox}", headers=auth(ADMIN_KEY))
    assert passed.status_code == 200 and passed.json() == direct.json()
    assert passed.json()["features"], "the seeded journey's signs are on the map"
    sign_id = passed.json()["features"][0]["id"]
    one = client.get(f"/admin/api/signs/{sign_id}")
    assert one.status_code == 200
    assert one.json() == client.get(f"/api/v1/signs/{sign_id}", headers=auth(ADMIN_KEY)).json()
    assert client.get("/admin/api/signs?bbox=nonsense").status_code == 400
    # The map draws the vector tiles: served through the same pass-through, byte for byte.
    assert 'src="/admin/static/app/vendor/Leaflet.VectorGrid.bundled.min.js"' in page
    assert client.get("/admin/static/app/vendor/Leaflet.VectorGrid.bundled.min.js").status_code == 200
    # this tile holds the seeded signs (tests/utils/results/dashboard_seed.py)
    tile = "/tiles/17/68600/45006.mvt"
    passed = client.get(f"/admin/api{tile}")
    direct = client.get(f"/api/v1{tile}", headers=auth(ADMIN_KEY))
    assert passed.status_code == 200 and passed.content == direct.content
    assert passed.headers["content-type"] == "application/vnd.mapbox-vector-tile"
    assert len(decode(passed.content)["signs"]["features"]) == len(direct_ids := [
        f["id"] for f in client.get(f"/admin/api/signs?bbox={bbox}").json()["features"]])
    assert direct_ids
    assert client.get("/admin/api/tiles/30/0/0.mvt").status_code == 400


def test_cameras_page_shows_each_cameras_calibrations(client, stack):
    add_journey(stack.settings, "done", fx=50.0)
    add_journey(stack.settings, "done", fx=52.5)
    sign_in(client)
    page = client.get("/admin/cameras").text
    assert "<h2>test-cam</h2>" in page and "50.0" in page and "52.5" in page
    assert 'points="0.0,56.0 240.0,4.0 "' in page  # fx rises from the first to the second


def test_retry_requeues_a_failed_journey(client, stack):
    failed = add_journey(stack.settings, "failed")
    done = add_journey(stack.settings, "done")
    sign_in(client)
    answer = client.post(f"/admin/journeys/{failed}/retry", follow_redirects=False,
                         headers={"Referer": "http://testserver/admin/journeys?status=failed"})
    assert answer.status_code == 303
    assert answer.headers["location"] == "/admin/journeys?status=failed"  # back to the same list
    with session_scope(stack.url) as session:
        row = session.get(JourneyRow, failed)
        assert (row.status, row.error, row.attempts, row.progress) == ("queued", None, 0, 0.0)
    assert client.post(f"/admin/journeys/{done}/retry").status_code == 409


def test_delete_removes_the_journey_its_signs_and_calibration(client, stack):
    doomed = add_journey(stack.settings, "done")
    kept = add_journey(stack.settings, "done")
    sign_in(client)
    assert client.post(f"/admin/journeys/{doomed}/delete", follow_redirects=False).status_code == 303
    with session_scope(stack.url) as session:
        assert session.get(JourneyRow, doomed) is None
        assert session.scalar(select(func.count()).select_from(JourneySignRow)
                              .where(JourneySignRow.journey_id == doomed)) == 0
        assert session.scalar(select(func.count()).select_from(CalibrationRow)
                              .where(CalibrationRow.journey_id == doomed)) == 0
        assert session.scalar(select(func.count()).select_from(JourneySignRow)
                              .where(JourneySignRow.journey_id == kept)) == 2
    assert client.post(f"/admin/journeys/{doomed}/delete").status_code == 404


def test_cameras_page_shows_the_stored_calibration_and_the_outvoted_one(client, stack):
    for fx in (50.0, 50.5, 49.8, 57.0):  # three that agree, then one 14 % off
        add_journey(stack.settings, "done", fx=fx)
    sign_in(client)
    section = client.get("/admin/cameras").text.split("<h2>test-cam</h2>")[1]
    assert "fx 50.1," in section and "the mean of 3 of the newest" in section
    assert "4 self-calibrations" in section and "1 outvoted" in section
    outvoted = section.split('class="outvoted"')
    assert len(outvoted) == 2 and "57.0" in outvoted[1].split("</tr>")[0]
    assert section.count('fill="#b71c1c"') == 1  # its point on the fx chart, in red
