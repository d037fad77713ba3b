"""``signmap bench api`` in miniature (issue 13): real serve (and worker) processes, a few clients,
uploads that fail fast in the job, map reads; no request errors and every accepted upload ended
exactly once. And the accounting itself: a lost upload or a job that ended twice is reported."""

from __future__ import annotations

import os
from collections import Counter
from pathlib import Path

import pytest

from app.service.db.session import session_scope
from app.service.db.models import JourneyRow
from bench.service.api_load import Options, ok, run_api_bench
from bench.service.api_stack import Service, account
from tests.utils.backends import PG_URL, REDIS_URL
from tests.utils.stack import sqlite_stack


@pytest.fixture(scope="module")
def synth_cache(tmp_path_factory):
    cache = os.environ.get("SIGNMAP_TEST_SYNTH_CACHE")
    return tmp_path_factory.mktemp("synth") if not cache else cache


@pytest.mark.parametrize("backend", ["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def test_bench_api_smoke(request, tmp_path, synth_cache, backend):
    if backend == "postgres":  # skipped (or, under CI, failed) without the real services
        request.getfixturevalue("pg_url"), request.getfixturevalue("redis_url")
    opts = Options(backends=(backend,), clients=3, requests=12, uploads=2, processed=0,
                   big_uploads=2, big_upload_mb=2.0,
                   drain_timeout_s=120, map_signs=50, out_dir=tmp_path / "out",
                   cache_dir=Path(synth_cache),
                   postgres_url=PG_URL, redis_url=REDIS_URL)
    md, js, report = run_api_bench(opts, "bench api smoke")
    run = report["runs"][0]
    assert ok(report), (run["errors"], run["jobs"])
    jobs = run["jobs"]
    # Straight journeys of a camera nobody calibrated: parked, waiting for their camera.
    assert jobs["accepted"] == 2 and jobs["waiting"] == 2 and jobs["failed"] == jobs["done"] == 0
    assert run["stats"]["upload (new)"]["n"] + run["stats"]["upload (same bytes)"]["n"] == 3
    assert sum(s["n"] for k, s in run["stats"].items() if "while jobs run" not in k) == 15
    assert "| map read (street) |" in md.read_text() and js.exists()
    # Issue 15's upload throughput, in miniature: 2 distinct ~2 MB uploads, none lost.
    big = run["uploads"]
    assert big["stats"]["n"] == 2 and big["stats"]["accepted"] == 2
    assert big["stats"]["errors"] == 0 and not big["errors"]
    assert big["jobs"]["waiting"] == 2 and big["jobs"]["failed"] == big["jobs"]["done"] == 0
    assert not big["jobs"]["missing"] and not big["jobs"]["unfinished"]
    assert not big["jobs"]["ended_not_once"]
    assert all("has no turn" in reason for reason in big["jobs"]["failure_reasons"])
    assert 1.9 <= big["mb_each"] <= 2.5 and big["stats"]["uploads_per_s"] > 0
    assert big["stats"]["validate_p50_s"] is not None  # read back from the API's log
    assert "## Upload throughput: 2 uploads of" in md.read_text()


def test_the_accounting_reports_lost_and_twice_ended_uploads(tmp_path):
    stack = sqlite_stack(tmp_path / "data")
    with session_scope(stack.url) as session:
        session.add(JourneyRow(id="j-twice", owner_key_id=None, camera_id="c", bundle_sha256="0" * 64,
                            bundle_bytes=1, status="failed", progress=0.0, n_frames=5,
                            attempts=1, error="no turn"))
    log = tmp_path / "api.log"
    log.write_text("".join("2026-11-25 INFO app.service.jobs.run: journey j-twice: failed at "
                           "calibrate: no turn\n" for _ in range(2)))
    service = Service("sqlite", "http://127.0.0.1:1", stack.settings, "f", "r", [log])
    jobs = account(service, Counter({"j-twice": 1, "j-lost": 1}), {"sha": {"a", "b"}})
    assert jobs["missing"] == ["j-lost"]
    assert jobs["ended_not_once"] == ["j-lost", "j-twice"]
    assert jobs["repeats_split"] == ["sha"]
    assert not ok({"runs": [{"errors": [], "jobs": jobs}]})
    clean = account(service, Counter(), {})
    assert ok({"runs": [{"errors": [], "jobs": clean}]})
    # A lost big upload fails the bench as a lost small one does.
    assert not ok({"runs": [{"errors": [], "jobs": clean,
                             "uploads": {"errors": [], "jobs": jobs}}]})
    # A re-upload of the failed journey queued it again: two endings are then right.
    assert account(service, Counter({"j-twice": 2}), {})["ended_not_once"] == []
