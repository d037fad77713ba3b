"""Property-based tests of the HTTP API from its own OpenAPI schema (schemathesis, issue 13): every
operation gets generated valid and invalid input (schemathesis's examples, coverage and fuzzing
phases) against the real app on SQLite and on PostgreSQL, sent with an admin, a fleet and a reader key and with none,
and every answer must be documented: no 5xx, a declared status code, the declared content type and
a body matching the declared schema.

Each database holds an uploaded and finished journey (with signs) and a fused map, and each call on
a ``{journey_id}``/``{sign_id}`` route is repeated with an id that exists, so those routes answer
200 (and DELETE 204) too, not only 404. The multipart upload is generated as the schema declares it
(its ``bundle`` is arbitrary bytes, so it answers 422 "not a zip"); a real bundle is uploaded while
seeding.

SIGNMAP_FUZZ_EXAMPLES sets the fuzzing examples per operation (default 25). Under CI (``CI=true``)
the examples are derandomized, so a run is reproducible; elsewhere each run explores anew."""

from __future__ import annotations

import atexit
import os
import secrets
import shutil
import tempfile
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import schemathesis
from fastapi import FastAPI
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import (content_type_conformance,
                                               response_schema_conformance,
                                               status_code_conformance)
from sqlalchemy import select

from app.pipeline.bundle import read_bundle
from app.commands.service import create_service_app
from app.service.db.session import session_scope
from app.service.db.models import JourneyRow, MapSignRow, VehicleRow
from tests.utils import bundle_factory as bf
from tests.utils.results import map_support as ms
from tests.utils.results.service_support import bf_zip, finish, made_result
from tests.utils.stack import ADMIN_KEY, Stack, auth, make_settings, sqlite_stack, upload

EXAMPLES = int(os.environ.get("SIGNMAP_FUZZ_EXAMPLES", "25"))
CHECKS = [not_a_server_error, status_code_conformance, content_type_conformance,
          response_schema_conformance]
# The schema is read from the app when the module is collected, so that app and its (migrated)
# SQLite database are made then; the fixtures fill the databases when a test runs.
ROOT = Path(tempfile.mkdtemp(prefix="signmap-fuzz-"))
atexit.register(shutil.rmtree, ROOT, ignore_errors=True)
# Schemathesis sends keys of its own making: many unknown keys from one address, which the API
# would throttle (429 for every key) long before the runs reach every route.
UNTHROTTLED = dict(auth_failure_limit=10**9)
SQLITE = sqlite_stack(ROOT / "data", **UNTHROTTLED)
SQLITE_APP = create_service_app(SQLITE.settings)
schema = schemathesis.openapi.from_asgi("/openapi.json", SQLITE_APP)
STATUSES: Counter = Counter()  # (backend, operation, status) of every call, for the coverage test
FUZZ = settings(max_examples=EXAMPLES, deadline=None, database=None,
                derandomize=os.environ.get("CI") == "true",
                suppress_health_check=list(HealthCheck))


@dataclass
class Target:
    stack: Stack
    app: FastAPI
    keys: dict[str, str | None]  # role -> key (None: no Authorization header)
    existing: dict[str, str]  # path parameter -> an id that exists


def _seed(stack: Stack, app: FastAPI) -> Target:
    """An uploaded and finished journey with signs, a fused map of another journey, keys."""
    keys = dict(admin=ADMIN_KEY, fleet=stack.key("fleet"), reader=stack.key("reader"), none=None)
    with TestClient(app) as client:
        journey_id = upload(client, keys["fleet"], bf_zip())
    finish(stack, journey_id, made_result([("0", "stop", 49.01, 8.41, 114.0)]))
    world = ms.make_world(3)
    ms.insert_done_journey(stack.settings, _journey_data(stack), f"fuzz-{secrets.token_hex(4)}",
                           0, ms.journey_result(world, np.random.default_rng(0)))
    with session_scope(stack.url) as session:
        sign_id = session.scalars(select(MapSignRow.id).where(
            MapSignRow.lat_deg.between(world.lat0 - 0.01, world.lat0 + 0.01))).first()
        vehicle_id = f"fuzz-van-{secrets.token_hex(3)}"  # so that GET /vehicles/{id} answers 200
        session.add(VehicleRow(vehicle_id=vehicle_id,
                               gps_antenna_offset_m={"forward": -1.0, "left": 0.0, "up": 0.5}))
    # The factory bundle's camera (its journey's), so that GET /cameras/{camera_id} answers 200.
    return Target(stack, app, keys, {"journey_id": journey_id, "sign_id": sign_id,
                                     "camera_id": "test-cam", "vehicle_id": vehicle_id})


def _journey_data(stack: Stack):
    work = stack.settings.data_dir / "fuzz-bundle"
    work.mkdir(parents=True, exist_ok=True)
    (work / "b.zip").write_bytes(bf_zip())
    return read_bundle(work / "b.zip", work / "x", decode_images=False)


@pytest.fixture(scope="module")
def sqlite_target():
    yield _seed(SQLITE, SQLITE_APP)
    shutil.rmtree(ROOT, ignore_errors=True)


@pytest.fixture(scope="module")
def postgres_target(own_pg_url, tmp_path_factory):
    stack = Stack("postgres", make_settings(tmp_path_factory.mktemp("fuzz-pg") / "data",
                                            database_url=own_pg_url, **UNTHROTTLED))
    return _seed(stack, create_service_app(stack.settings))


def _deletable_journey(stack: Stack) -> str:
    """A finished journey of its own, for one DELETE to remove (the seeded ones stay)."""
    journey_id = f"fuzz-del-{secrets.token_hex(4)}"
    with session_scope(stack.url) as session:
        session.add(JourneyRow(id=journey_id, owner_key_id=None, camera_id="fuzz-cam",
                            bundle_sha256=secrets.token_hex(32), bundle_bytes=1,
                            status="failed", progress=0.0, n_frames=5, attempts=1))
    return journey_id


def _call(case, target: Target, key: str | None) -> None:
    response = case.call_and_validate(app=target.app, headers=auth(key) if key else {},
                                      checks=CHECKS)
    STATUSES[target.stack.name, case.operation.label, response.status_code] += 1


def _fuzz(case, target: Target) -> None:
    for key in target.keys.values():
        _call(case, target, key)
    names = set(case.path_parameters or {}) & set(target.existing)
    if names:  # again on ids that exist (DELETE on a journey of its own)
        case.path_parameters.update(
            {name: (_deletable_journey(target.stack) if case.method.upper() == "DELETE"
                    else target.existing[name]) for name in names})
        _call(case, target, target.keys["admin"])


@schema.parametrize()
@FUZZ
def test_every_answer_is_documented(case, sqlite_target):
    _fuzz(case, sqlite_target)


@pytest.mark.postgres
@schema.parametrize()
@FUZZ
def test_every_answer_is_documented_on_postgres(case, postgres_target):
    _fuzz(case, postgres_target)


@pytest.mark.parametrize("backend", ["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def test_the_fuzzing_reached_every_route(backend):
    """The runs above did more than bounce off auth: each route answered a success at least once."""
    statuses = Counter({(label, code): n for (name, label, code), n in STATUSES.items()
                        if name == backend})
    if not statuses:
        pytest.skip("run together with the fuzzing tests above")
    labels = {label for label, _ in statuses}
    # Every operation ran (under pytest-xdist, tests sharing a node id used to run only once).
    assert labels == {op.ok().label for op in schema.get_all_operations()}, labels
    unanswered = sorted(label for label in labels
                        if label != "POST /api/v1/journeys"
                        and not any(statuses[label, code] for code in (200, 204)))
    assert not unanswered, f"never answered 2xx: {unanswered}; statuses: {dict(statuses)}"
    assert statuses["POST /api/v1/journeys", 422] > 0


@pytest.mark.parametrize("path", ["/api/v1/signs/changes?since={}",
                                  "/api/v1/signs?bbox=8.4,49.0,8.5,49.1&since={}"])
@pytest.mark.parametrize("since", ["0001-01-01T00:00:00%2B00:01", "9999-12-31T23:59:00-00:01"])
def test_a_since_out_of_range_is_a_400(stack, path, since):
    """Found by the fuzzing: converting such a time to UTC overflowed in the route (a 500)."""
    with stack.client() as client:
        response = client.get(path.format(since), headers=auth(ADMIN_KEY))
        assert response.status_code == 400, response.text
        assert "is out of range" in response.json()["detail"]
        assert client.get("/api/v1/health").status_code == 200


@pytest.mark.parametrize("path", ["/api/v1/journeys/a%00b", "/api/v1/journeys/a%00b/signs",
                                  "/api/v1/signs/a%00b", "/api/v1/signs?bbox=1,1,2,2&class=a%00b",
                                  "/api/v1/signs?bbox=1,1,2,2&cursor=a%00b"])
def test_a_nul_in_an_id_or_filter_is_a_422(stack, path):
    """Found while fuzzing: PostgreSQL text cannot hold NUL, and the query failed with a 500."""
    with stack.client() as client:
        response = client.get(path, headers=auth(ADMIN_KEY))
        assert response.status_code == 422, response.text
        assert response.json()["detail"][0]["type"] == "string_pattern_mismatch"
        response = client.delete("/api/v1/journeys/a%00b", headers=auth(ADMIN_KEY))
        assert response.status_code == 422, response.text
        assert client.get("/api/v1/health").status_code == 200


@pytest.mark.parametrize("field, value, detail", [
    ("camera_id", "cam\u0000",
     "camera_id: Value error, must not contain control characters ('\\x00' at character 4)"),
    ("vehicle_id", "van\u0000",
     "vehicle_id: Value error, must not contain control characters ('\\x00' at character 4)"),
    ("captured_at", "2026-11-20T08:15:00Z\u0000",
     "captured_at: Value error, must not contain control characters ('\\x00' at character 21)"),
    ("camera_id", "c" * 201, "camera_id: String should have at most 200 characters"),
    ("vehicle_id", "v" * 201, "vehicle_id: String should have at most 200 characters"),
])
def test_manifest_text_the_database_cannot_hold_is_a_422(stack, field, value, detail):
    """Found while fuzzing: on PostgreSQL such a manifest was accepted by validation and then
    failed the journey's INSERT with a 500, its bundle already kept in bundles/."""
    fleet = stack.key("fleet")
    files = bf.valid_files()
    files["manifest.json"] = bf.manifest_bytes(**{field: value})
    with stack.client() as client:
        response = client.post("/api/v1/journeys", headers=auth(fleet),
                               files={"bundle": ("journey.zip", bf.zip_bytes(files),
                                                 "application/zip")})
        assert response.status_code == 422, response.text
        assert response.json()["detail"] == f"manifest.json is invalid: {detail}"
        assert client.get("/api/v1/health").status_code == 200
    assert stack.count_journeys(fleet) == 0
    assert stack.stored_files() == []
