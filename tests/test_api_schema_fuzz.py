"""Property-based tests of the HTTP API from its own OpenAPI schema (schemathesis, issue 13): every
operation gets generated valid and invalid input (schemathesis's examples, coverage and fuzzing
phases) against the real app on SQLite, sent with an admin, a fleet and a reader key and with none,
and every answer must be documented: no 5xx, a declared status code, the declared content type and
a body matching the declared schema.

The data dir holds an uploaded and finished journey (with signs) and a fused map, and each call on
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
from pathlib import Path

import numpy as np
import pytest
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import (content_type_conformance,
                                               response_schema_conformance,
                                               status_code_conformance)

from app.pipeline.bundle import read_bundle
from app.service.app import create_app
from app.service.db import session_scope
from app.service.models import Journey, MapSign
from tests import map_support as ms
from tests.conftest import ADMIN_KEY, auth, sqlite_stack, upload
from tests.service_support import bf_zip, finish, made_result

EXAMPLES = int(os.environ.get("SIGNMAP_FUZZ_EXAMPLES", "25"))
CHECKS = [not_a_server_error, status_code_conformance, content_type_conformance,
          response_schema_conformance]
# The schema is read from the app when the module is collected, so the app and its (migrated)
# database are made then; the ``seeded`` fixture fills the database when a test runs.
ROOT = Path(tempfile.mkdtemp(prefix="signmap-fuzz-"))
atexit.register(shutil.rmtree, ROOT, ignore_errors=True)
STACK = sqlite_stack(ROOT / "data")
APP = create_app(STACK.settings)
schema = schemathesis.openapi.from_asgi("/openapi.json", APP)
KEYS: dict[str, str | None] = {}  # role -> key (None: no Authorization header)
EXISTING: dict[str, str] = {}  # path parameter -> an id that exists
STATUSES: Counter = Counter()  # (operation, status) of every call, for the coverage test


@pytest.fixture(scope="module", autouse=True)
def seeded():
    KEYS.update(admin=ADMIN_KEY, fleet=STACK.key("fleet"), reader=STACK.key("reader"), none=None)
    with TestClient(APP) as client:
        journey_id = upload(client, KEYS["fleet"], bf_zip())
    finish(STACK, journey_id, made_result([("0", "stop", 49.01, 8.41, 114.0)]))
    ms.insert_done_journey(STACK.settings, _journey_data(), "fuzz-map-journey", 0,
                           ms.journey_result(ms.make_world(3), np.random.default_rng(0)))
    with session_scope(STACK.url) as session:
        EXISTING.update(journey_id=journey_id, sign_id=session.query(MapSign.id).first()[0])
    yield
    shutil.rmtree(ROOT, ignore_errors=True)


def _journey_data():
    work = ROOT / "bundle"
    work.mkdir(parents=True, exist_ok=True)
    (work / "b.zip").write_bytes(bf_zip())
    return read_bundle(work / "b.zip", work / "x", decode_images=False)


def _deletable_journey() -> str:
    """A finished journey of its own, for one DELETE to remove (the seeded ones stay)."""
    journey_id = f"fuzz-del-{secrets.token_hex(4)}"
    with session_scope(STACK.url) as session:
        session.add(Journey(id=journey_id, owner_key_id=None, camera_id="fuzz-cam",
                            bundle_sha256=secrets.token_hex(32), bundle_bytes=1,
                            status="failed", progress=0.0, n_frames=5, attempts=1))
    return journey_id


def _call(case, key: str | None) -> None:
    response = case.call_and_validate(headers=auth(key) if key else {}, checks=CHECKS)
    STATUSES[case.operation.label, response.status_code] += 1


@schema.parametrize()
@settings(max_examples=EXAMPLES, deadline=None, database=None,
          derandomize=os.environ.get("CI") == "true", suppress_health_check=list(HealthCheck))
def test_every_answer_is_documented(case):
    for key in KEYS.values():
        _call(case, key)
    names = set(case.path_parameters or {}) & set(EXISTING)
    if names:  # again on ids that exist (DELETE on a journey of its own)
        case.path_parameters.update(
            {name: _deletable_journey() if case.method.upper() == "DELETE" else EXISTING[name]
             for name in names})
        _call(case, KEYS["admin"])


def test_the_fuzzing_reached_every_route():
    """The run above did more than bounce off auth: each route answered a success at least once."""
    if not STATUSES:
        pytest.skip("run together with test_every_answer_is_documented")
    labels = {label for label, _ in STATUSES}
    unanswered = sorted(label for label in labels
                        if label != "POST /api/v1/journeys"
                        and not any(STATUSES[label, code] for code in (200, 204)))
    assert not unanswered, f"never answered 2xx: {unanswered}; statuses: {dict(STATUSES)}"
    assert STATUSES["POST /api/v1/journeys", 422] > 0


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
