"""The fused map over HTTP, on SQLite and PostgreSQL: GET /signs filters and pagination,
GET /signs/{id} with its evidence, GET /signs/changes with tombstones, DELETE /journeys/{id},
GET /journeys/{id}'s calibration flag, and the roles of every map route."""

from __future__ import annotations

import secrets

import numpy as np
import pytest
from sqlalchemy import text
from sqlalchemy.dialects import postgresql

from app.pipeline.bundle import read_bundle
from app.service.db.session import session_scope
from app.service.db.map_read import page_query
from app.service.db.models import utc_now
from app.service.db.queries import BBox
from tests.utils.results import map_support as ms
from tests.utils.results.service_support import bf_zip
from tests.utils.stack import ADMIN_KEY, auth


@pytest.fixture(scope="module")
def journey_data(tmp_path_factory):
    work = tmp_path_factory.mktemp("bundle")
    (work / "b.zip").write_bytes(bf_zip())
    return read_bundle(work / "b.zip", work / "x", decode_images=False)


def bbox_of(world: ms.World, margin_deg: float = 0.01) -> str:
    return (f"{world.lon0 - margin_deg},{world.lat0 - margin_deg},"
            f"{world.lon0 + margin_deg},{world.lat0 + margin_deg}")


def test_map_routes(stack, journey_data):
    world = ms.make_world(6)
    world.signs["9"] = ("stop", 70.0, 12.0, 2.5)  # seen by journey E only
    rng = np.random.default_rng(21)
    tag = secrets.token_hex(4)
    ids = {name: f"j-{tag}-{name}" for name in "ABCDE"}
    for day, name in enumerate("ABC"):
        ms.insert_done_journey(stack.settings, journey_data, ids[name], day,
                               ms.journey_result(world, rng, skip=("9",)))
    t_mid = utc_now()
    # D saw signs 0-2 only and its camera never had 3-5 in view: only 0-2 change.
    ms.insert_done_journey(stack.settings, journey_data, ids["D"], 3,
                           ms.journey_result(world, rng, only=("0", "1", "2"), road_end_m=40.0))
    reader, fleet = stack.key("reader"), stack.key("fleet")
    box = bbox_of(world)
    with stack.client() as client:
        def get(path: str, key: str = reader, **params):
            response = client.get(f"/api/v1{path}", headers=auth(key), params=params)
            assert response.status_code == 200, response.text
            return response.json()

        signs = get("/signs", bbox=box)
        assert signs["type"] == "FeatureCollection" and signs["next"] is None
        features = signs["features"]
        # Ordered by position: latitude, longitude, then id.
        assert len(features) == 6 and features == sorted(
            features, key=lambda f: (f["geometry"]["coordinates"][1],
                                     f["geometry"]["coordinates"][0], f["id"]))
        by_track = {ms_track(world, f): f for f in features}
        props = by_track["0"]["properties"]
        assert set(props) == {"id", "class", "state", "std_m", "n_journeys", "n_observations",
                              "first_seen_at", "last_seen_at", "facing_deg"}
        # Four journeys' facings (270 +- 10 deg each) fused by their circular mean.
        assert abs(props["facing_deg"] - 270.0) < 12.0
        assert (props["class"], props["state"], props["n_journeys"], props["n_observations"]) == (
            "stop", "confirmed", 4, 4)
        assert props["first_seen_at"].startswith("2026-11-01T08:00:00")
        assert props["last_seen_at"].startswith("2026-11-04T08:00:00")
        assert 0.0 < props["std_m"] < 1.0
        assert len(by_track["0"]["geometry"]["coordinates"]) == 3

        assert {ms_track(world, f) for f in get("/signs", bbox=box, **{"class": "stop"})[
            "features"]} == {"0", "3"}
        assert len(get("/signs", bbox=box, state="confirmed")["features"]) == 6
        assert get("/signs", bbox=box, state="new")["features"] == []
        assert {ms_track(world, f) for f in get("/signs", bbox=box, since=t_mid.isoformat())[
            "features"]} == {"0", "1", "2"}
        assert get("/signs", bbox=f"{world.lon0 - 1e-3},{world.lat0 - 1e-3},{world.lon0 + 1e-4},"
                   f"{world.lat0 + 1e-3}")["features"] == []  # west of the first sign
        page1 = get("/signs", bbox=box, limit=4)
        page2 = get("/signs", bbox=box, limit=4, cursor=page1["next"])
        assert len(page1["features"]) == 4 and page1["next"].endswith(page1["features"][-1]["id"])
        assert page2["next"] is None
        assert [f["id"] for f in page1["features"] + page2["features"]] == [f["id"] for f in features]

        one = get(f"/signs/{by_track['0']['id']}")
        members = one["properties"]["members"]
        assert [m["journey_id"] for m in members] == sorted(ids[n] for n in "ABCD")
        assert all(m["track_id"] == "0" and m["journey_sign_id"] == f"{m['journey_id']}:0"
                   for m in members)
        # Frames, camera-frame positions and the bundle's detection boxes.
        assert members[0]["observations"] == [
            {"frame": "000000", "x": 1.0, "y": -0.5, "z": 12.0, "box": [10.0, 10.0, 18.0, 18.0]}]
        assert set(one["properties"]["evidence"]["weights"]) == {m["journey_sign_id"]
                                                                 for m in members}
        assert one["properties"]["evidence"]["change"]["rule"] == "confirmed"
        assert client.get("/api/v1/signs/ms-nope", headers=auth(reader)).status_code == 404

        changes = get("/signs/changes", since=t_mid.isoformat())
        assert {ms_track(world, f) for f in changes["updated"]} == {"0", "1", "2"}
        assert changes["created"] == [] and changes["removed"] == []

        ms.insert_done_journey(stack.settings, journey_data, ids["E"], 4,
                               ms.journey_result(world, rng, only=("9",), road_end_m=40.0))
        t_e = utc_now()
        created = get("/signs/changes", since=t_mid.isoformat())["created"]
        assert [ms_track(world, f) for f in created] == ["9"]
        deleted = client.delete(f"/api/v1/journeys/{ids['E']}", headers=auth(ADMIN_KEY))
        assert deleted.status_code == 204
        assert client.delete(f"/api/v1/journeys/{ids['E']}",
                             headers=auth(ADMIN_KEY)).status_code == 404
        changes = get("/signs/changes", since=t_e.isoformat())
        assert [r["id"] for r in changes["removed"]] == [created[0]["id"]]
        assert created[0]["id"] not in {f["id"] for f in get("/signs", bbox=box)["features"]}
        assert get(f"/signs/{created[0]['id']}")["properties"]["removed_at"] is not None
        assert client.get(f"/api/v1/journeys/{ids['E']}",
                          headers=auth(ADMIN_KEY)).status_code == 404

        # Roles: the map is for readers and admins; deleting a journey for admins.
        for path in ("/signs?bbox=" + box, f"/signs/{by_track['0']['id']}",
                     "/signs/changes?since=2026-01-01T00:00:00Z"):
            assert client.get(f"/api/v1{path}", headers=auth(fleet)).status_code == 403
            assert client.get(f"/api/v1{path}").status_code == 401
            assert client.get(f"/api/v1{path}", headers=auth(ADMIN_KEY)).status_code == 200
        for key in (reader, fleet):
            assert client.delete(f"/api/v1/journeys/{ids['A']}",
                                 headers=auth(key)).status_code == 403
        assert client.get("/api/v1/signs", headers=auth(reader),
                          params={"bbox": box, "state": "gone"}).status_code == 422


def ms_track(world: ms.World, feature: dict) -> str:
    lon, lat, alt = feature["geometry"]["coordinates"]
    cls = feature["properties"]["class"]
    return min((t for t, s in world.signs.items() if s[0] == cls),
               key=lambda t: world.error_m(t, lat, lon, alt))


def test_antimeridian_bbox(stack, journey_data):
    world = ms.make_world(2)  # signs 20 m and 40 m east of the origin: put 180 deg at 30 m
    world.lon0 = 180.0 - 30.0 / (ms.M_PER_DEG_LAT * np.cos(np.radians(world.lat0)))
    ms.insert_done_journey(stack.settings, journey_data, f"j-{secrets.token_hex(4)}", 0,
                           ms.journey_result(world, np.random.default_rng(2)))
    with stack.client() as client:
        def n_signs(bbox: str) -> int:
            response = client.get("/api/v1/signs", headers=auth(ADMIN_KEY), params={"bbox": bbox})
            assert response.status_code == 200, response.text
            return len(response.json()["features"])

        lat = world.lat0
        assert n_signs(f"179.999,{lat - 0.001},-179.999,{lat + 0.001}") == 2
        assert n_signs(f"179.999,{lat - 0.001},180,{lat + 0.001}") == 1
        assert n_signs(f"-180,{lat - 0.001},-179.999,{lat + 0.001}") == 1


def test_calibration_flag_is_shown_on_the_journey(stack, journey_data):
    stored = ms.CAMERA.__class__(**{**ms.CAMERA.__dict__, "cx": ms.CAMERA.cx + 4.0})
    journey_id = f"j-{secrets.token_hex(4)}"
    ms.insert_done_journey(stack.settings, journey_data, journey_id, 0,
                           ms.journey_result(ms.make_world(1), np.random.default_rng(1)),
                           known_camera=stored)
    with stack.client() as client:
        body = client.get(f"/api/v1/journeys/{journey_id}", headers=auth(ADMIN_KEY)).json()
    assert body["calibration_flag"]["reason"] == (
        "self-calibration differs from the stored one in cx")
    assert body["calibration_flag"]["relative_deviation"]["cx"] == pytest.approx(4.0 / 64)


@pytest.mark.postgres
def test_postgres_map_page_is_read_from_the_covering_index_alone(pg_url):
    query = page_query(BBox(8.0, 49.0, 8.5, 49.5), "stop", None, None, (49.1, 8.2, "ms-0"), 100)
    sql = str(query.compile(dialect=postgresql.dialect(), compile_kwargs={"literal_binds": True}))
    with session_scope(pg_url) as session:
        session.execute(text("SET LOCAL enable_seqscan = off"))
        plan = "\n".join(session.scalars(text("EXPLAIN " + sql)))
    # In the index's order (no sort) and without the table (index-only).
    assert "Index Only Scan using ix_map_signs_live_lat_lon" in plan and "Sort" not in plan, plan


def test_a_running_journey_cannot_be_deleted(stack):
    from tests.utils.stack import upload

    key = stack.key("fleet")
    with stack.client() as client:
        journey_id = upload(client, key, bf_zip())
        with session_scope(stack.url) as session:
            session.execute(text("UPDATE journeys SET status = 'running' WHERE id = :i"),
                            {"i": journey_id})
        response = client.delete(f"/api/v1/journeys/{journey_id}", headers=auth(ADMIN_KEY))
        assert response.status_code == 409
        assert response.json() == {"detail": f"journey {journey_id} is running"}
        assert client.get(f"/api/v1/journeys/{journey_id}", headers=auth(key)).status_code == 200
