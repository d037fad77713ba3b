"""Fixtures of the suite (the helpers they use, and that tests import, are in ``tests/utils``).

Service fixtures: the embedded stack (SQLite, jobs in the API process) and the real stack
(a throw-away PostgreSQL database migrated by Alembic, Redis, real Celery worker processes).

Without PostgreSQL/Redis the real-stack tests are skipped, except under CI (``CI=true``), where they
fail; the run ends with a "real-service tests skipped" section saying which were skipped and why
(``tests/utils/real_services.py``, which also covers the browser tests). Locations:
SIGNMAP_TEST_POSTGRES_URL (a database to connect to for CREATE DATABASE) and SIGNMAP_TEST_REDIS_URL.
The run also ends by saying how many ``extended`` tests it left out (``tests/utils/extended.py``).
"""

from __future__ import annotations

import os
import re
import secrets
from pathlib import Path
from typing import Iterator

import pytest

from tests.utils.backends import (REDIS_URL, SESSION_TAG, backend_unavailable, forget_queues,
                                  pg_database)
from tests.utils.extended import register_extended_left_out
from tests.utils.journeys import synthetic_journey, video_journey
from tests.utils.real_services import register_real_service_skips
from tests.utils.stack import Stack, make_settings, sqlite_stack


def pytest_configure(config) -> None:
    register_real_service_skips(config)
    register_extended_left_out(config)


def pytest_collection_modifyitems(items) -> None:
    # schemathesis makes one item per API operation, named for it, but under pytest 9 they all keep
    # the test function's node id (it renames them through ``_nodeid``, which pytest 9 no longer
    # reads); pytest-xdist schedules by node id and ran one operation of each such test.
    # tests/service/api/test_api_schema_fuzz.py checks that every operation was called. Under
    # pytest 8 the renaming works, no item matches, and pytest 9's private module is never imported.
    for item in items:
        module_path, _, name = item.nodeid.rpartition("::")
        if item.name != name and item.name.startswith(name + "["):
            from _pytest.nodeid import coerce_node_id

            item._id = coerce_node_id(f"{module_path}::{item.name}")
    # Test files are handed to the xdist workers in this order (``--dist loadfile``): the files
    # that run COLMAP on rendered journeys (minutes each) first, the many quick ones after them to
    # fill in, so that no long file starts last and leaves the other core idle at the end.
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


@pytest.fixture(scope="session")
def pg_url() -> Iterator[str]:
    """A PostgreSQL database shared by the session's tests that do not care what else is in it."""
    with pg_database(f"signmap_test_{SESSION_TAG}") as url:
        yield url


@pytest.fixture(scope="module")
def own_pg_url(request) -> Iterator[str]:
    """A PostgreSQL database of the test module's own, for tests that assert what the whole map
    holds (the shared one has whatever the session's other tests put at the same place)."""
    module = request.module.__name__.rsplit(".", 1)[-1]
    with pg_database(f"signmap_test_{SESSION_TAG}_{module}") as url:
        yield url


@pytest.fixture(scope="session")
def redis_url() -> Iterator[str]:
    import redis

    client = redis.Redis.from_url(REDIS_URL)
    try:
        client.ping()
    except Exception as exc:  # noqa: BLE001
        backend_unavailable("Redis", re.sub(r"//[^/@]*@", "//***@", REDIS_URL), exc)  # no password
    yield REDIS_URL
    forget_queues(client, f"signmap_test_{SESSION_TAG}")


@pytest.fixture(scope="session")
def s3_endpoint() -> Iterator[str]:
    """A real S3-compatible HTTP endpoint for the session: moto's server on a free local port."""
    from moto.server import ThreadedMotoServer

    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    yield f"http://{host}:{port}"
    server.stop()


@pytest.fixture
def s3_storage_url(s3_endpoint, monkeypatch) -> str:
    """A fresh bucket on the session's S3 endpoint, with the standard AWS_* variables set for this
    test and the worker processes it starts; returns the SIGNMAP_STORAGE_URL naming it."""
    import boto3

    for name in [n for n in os.environ if n.startswith("AWS_")]:
        monkeypatch.delenv(name)
    monkeypatch.setenv("AWS_ENDPOINT_URL", s3_endpoint)
    monkeypatch.setenv("AWS_ACCESS_KEY_ID", "signmap-test")
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", "signmap-test-secret")
    bucket = f"signmap-test-{secrets.token_hex(4)}"
    boto3.client("s3").create_bucket(Bucket=bucket)
    return f"s3://{bucket}/bundles"


@pytest.fixture(params=["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def stack(request, tmp_path) -> Stack:
    """The service on SQLite, then on PostgreSQL + Redis; jobs are queued but not run."""
    if request.param == "sqlite":
        return sqlite_stack(tmp_path / "data")
    return Stack("postgres", make_settings(tmp_path / "data",
                                           database_url=request.getfixturevalue("pg_url"),
                                           broker_url=request.getfixturevalue("redis_url")))


@pytest.fixture(scope="session")
def turn_journey_bundle(tmp_path_factory) -> tuple[Path, dict]:
    """A small rendered journey with one turn: (bundle.zip, truth.json as a dict)."""
    return synthetic_journey(tmp_path_factory, "turn", turns=1)


# The camera's clock of the video journeys: this far ahead of GPS time, and not declared. Whole
# seconds, because an MP4's creation_time holds whole seconds (3.4 s would be written as 3).
VIDEO_CLOCK_ERROR_S = 3.0


@pytest.fixture(scope="session")
def turn_video_bundle(tmp_path_factory, turn_journey_bundle) -> Path:
    """The turn journey as a dash cam uploads it: video.mp4 (H.264) and a 10 Hz NMEA log, the
    camera's clock VIDEO_CLOCK_ERROR_S ahead of GPS time (undeclared), detections by frame index."""
    return video_journey(tmp_path_factory, turn_journey_bundle[0], "turn-video", gps_format="nmea",
                         gps_rate_hz=10.0, clock_error_s=VIDEO_CLOCK_ERROR_S)


# KITTI's GPS/INS unit relative to its camera (forward, left, up; metres): 1.09 m behind, 0.25 m
# left of and 0.72 m below it.
KITTI_ANTENNA_OFFSET_M = (-1.09, 0.25, -0.72)


@pytest.fixture(scope="session")
def offset_journey_bundle(tmp_path_factory) -> tuple[Path, dict]:
    """The turn journey's first 80 frames (the turn and 6 signs) with GPS fixes from an antenna at
    KITTI_ANTENNA_OFFSET_M, declared in the manifest: (bundle.zip, truth.json as a dict)."""
    return synthetic_journey(tmp_path_factory, "turn-antenna", turns=1, n_frames=80,
                             gps_antenna_offset_m=KITTI_ANTENNA_OFFSET_M)


@pytest.fixture(scope="session")
def straight_journey_bundle(tmp_path_factory) -> tuple[Path, dict]:
    """A straight journey in another world, filmed by the same camera as the turn journey."""
    return synthetic_journey(tmp_path_factory, "straight", turns=0, world_seed=1, seed=1)
