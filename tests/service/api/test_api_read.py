"""GET /journeys/{id}, /journeys/{id}/signs and /signs?bbox= answer exactly the contract's shapes,
from rows stored the way a worker stores them (``state.store_result``)."""

from __future__ import annotations

import pytest
from sqlalchemy import text
from sqlalchemy.dialects import postgresql

from app.service.db.session import session_scope
from app.service.db.queries import BBox, map_signs_query
from tests.utils.results.service_support import bf_zip, finish, made_result
from tests.utils.stack import ADMIN_KEY, auth, upload

LAT, LON = 49.0112, 8.4185


def test_done_journey_and_its_signs_follow_the_contract(stack):
    key = stack.key("fleet")
    with stack.client() as client:
        journey_id = upload(client, key, bf_zip())
        finish(stack, journey_id, made_result([("0", "stop", LAT, LON, 114.25),
                                               ("1", "yield", LAT + 1e-4, LON, 113.5)]))
        journey = client.get(f"/api/v1/journeys/{journey_id}", headers=auth(key)).json()
        signs = client.get(f"/api/v1/journeys/{journey_id}/signs", headers=auth(key)).json()
    assert {k: journey[k] for k in ("id", "status", "stage", "progress", "error", "n_frames",
                                    "n_signs", "calibration_source", "attempts")} == {
        "id": journey_id, "status": "done", "stage": "done", "progress": 1.0, "error": None,
        "n_frames": 5, "n_signs": 2, "calibration_source": "self", "attempts": 1}
    assert journey["calibration"] == {"fx": 50.0, "fy": 51.0, "cx": 31.5, "cy": 23.5,
                                      "k1": -0.1, "k2": 0.01}
    assert journey["timings_s"] == {"total_s": 2.0}
    assert signs["type"] == "FeatureCollection" and len(signs["features"]) == 2
    stop = signs["features"][0]
    assert stop["type"] == "Feature" and stop["id"] == f"{journey_id}:0"
    assert stop["geometry"] == {"type": "Point", "coordinates": [LON, LAT, 114.25]}
    props = stop["properties"]
    assert (props["id"], props["class"], props["track_id"], props["journey_id"]) == \
        (f"{journey_id}:0", "stop", "0", journey_id)
    # Boxes come from the bundle's detections.csv (track 0: x1 = 10 + 3 i).
    assert props["observations"] == [
        {"frame": "000000", "x": 1.0, "y": -0.5, "z": 12.0, "box": [10.0, 10.0, 18.0, 18.0]},
        {"frame": "000001", "x": 0.8, "y": -0.5, "z": 11.0, "box": [13.0, 10.0, 21.0, 18.0]}]
    assert signs["features"][1]["properties"]["class"] == "yield"
    # Which way each sign faces and its 95 % horizontal radius (issue 12).
    assert [(f["properties"]["facing_deg"], f["properties"]["r95_h_m"])
            for f in signs["features"]] == [(0.0, 0.5), (90.0, 0.6)]


def test_altitude_is_omitted_when_the_journey_had_none(stack):
    key = stack.key("fleet")
    with stack.client() as client:
        journey_id = upload(client, key, bf_zip())
        finish(stack, journey_id, made_result([("0", "stop", LAT, LON, None)]))
        signs = client.get(f"/api/v1/journeys/{journey_id}/signs", headers=auth(key)).json()
    assert signs["features"][0]["geometry"]["coordinates"] == [LON, LAT]


def test_signs_of_an_unfinished_journey_are_an_empty_collection(stack):
    key = stack.key("fleet")
    with stack.client() as client:
        journey_id = upload(client, key, bf_zip())
        signs = client.get(f"/api/v1/journeys/{journey_id}/signs", headers=auth(key))
        missing = client.get("/api/v1/journeys/no-such-id/signs", headers=auth(key))
    assert signs.json() == {"type": "FeatureCollection", "features": []}
    assert missing.status_code == 404 and missing.json()["detail"] == "journey no-such-id not found"


@pytest.mark.parametrize("bbox, detail", [
    ("1,2,3", "bbox must be minlon,minlat,maxlon,maxlat"),
    ("a,2,3,4", "bbox values must be numbers"),
    ("1,2,181,4", "bbox longitudes must be within [-180, 180]"),
    ("1,-91,3,4", "bbox latitudes must be within [-90, 90]"),
    ("1,5,3,4", "bbox minlat must not exceed maxlat"),
])
def test_bad_bbox_is_400(stack, bbox, detail):
    reader = stack.key("reader")
    with stack.client() as client:
        response = client.get("/api/v1/signs", headers=auth(reader), params={"bbox": bbox})
    assert response.status_code == 400 and response.json() == {"detail": detail}


def test_missing_bbox_is_422(stack):
    with stack.client() as client:
        response = client.get("/api/v1/signs", headers=auth(ADMIN_KEY))
    assert response.status_code == 422 and response.json()["detail"][0]["loc"] == ["query", "bbox"]


@pytest.mark.postgres
def test_postgres_bbox_query_uses_the_gist_index(pg_url):
    query = map_signs_query("postgresql", BBox(8.0, 49.0, 8.5, 49.5), "stop")
    sql = str(query.compile(dialect=postgresql.dialect(), compile_kwargs={"literal_binds": True}))
    with session_scope(pg_url) as session:
        session.execute(text("SET LOCAL enable_seqscan = off"))
        plan = "\n".join(session.scalars(text("EXPLAIN " + sql)))
    assert "ix_journey_signs_lonlat" in plan, plan


def test_openapi_documents_the_upload_and_the_answers(tmp_path):
    from tests.utils.stack import sqlite_stack

    stack = sqlite_stack(tmp_path / "data")
    with stack.client() as client:
        assert client.get("/docs").status_code == 200
        spec = client.get("/openapi.json").json()
    upload_op = spec["paths"]["/api/v1/journeys"]["post"]
    body = upload_op["requestBody"]["content"]["multipart/form-data"]["schema"]
    assert body["properties"]["bundle"]["format"] == "binary"
    assert set(upload_op["responses"]) >= {"200", "202", "400", "401", "403", "413", "415", "422"}
    journey = spec["components"]["schemas"]["JourneyOut"]
    assert journey["examples"][0]["status"] == "done"
    assert {"id", "status", "stage", "progress", "error", "calibration", "n_frames",
            "n_signs"} <= set(journey["required"])
