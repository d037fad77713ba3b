"""Helpers of the camera tests: journeys of a camera as a worker leaves them (self-calibrated, or
waiting for their camera), a registration body for the factory bundle's 64x48 camera, and
rendered bundles under a camera id of the test's own."""

from __future__ import annotations

import io
import json
import secrets
import zipfile
from pathlib import Path

import pytest

from app.service.db.models import JourneyRow
from app.service.db.session import session_scope
from app.service.jobs import fusion, state
from tests.utils import bundle_factory as bf
from tests.utils.results.service_support import bf_zip, made_result
from tests.utils.stack import sqlite_stack, upload

# A calibration of the factory bundle's 64x48 camera, as an operator registers it.
BODY = {"width": 64, "height": 48, "fx": 55.0, "fy": 55.5, "cx": 31.5, "cy": 23.5, "k1": -0.1,
        "k2": 0.01}


@pytest.fixture
def sqlite(tmp_path):
    """The SQLite stack; jobs are queued but not run."""
    return sqlite_stack(tmp_path / "data")


def camera_files(camera_id: str, n_frames: int = 5) -> dict[str, bytes]:
    """The factory bundle (a straight road, 64x48 frames) of ``camera_id``; ``n_frames`` makes
    each journey's bytes its own."""
    return {**bf.valid_files(n_frames=n_frames),
            "manifest.json": bf.manifest_bytes(camera_id=camera_id)}


def new_camera() -> str:
    return f"cam-{secrets.token_hex(4)}"


def self_calibrated(stack, client, key: str, camera_id: str, fx: float, n_frames: int = 5,
                    source: str = "self", window=None) -> str:
    """A journey of ``camera_id`` uploaded with ``key`` and stored as a worker stores one that
    self-calibrated to ``fx`` (fy = fx + 1, ``made_result``'s camera otherwise), flagged against
    the camera's stored calibration as the job flags it; ``source`` "supplied": one given that
    calibration instead; ``window``: its calibration's turn window. Returns its id."""
    from app.pipeline.bundle import read_bundle

    files = camera_files(camera_id, n_frames)
    journey_id = upload(client, key, bf_zip(files))
    work = stack.settings.data_dir / "test-extract" / secrets.token_hex(4)
    work.mkdir(parents=True)
    (work / "b.zip").write_bytes(bf_zip(files))
    journey = read_bundle(work / "b.zip", work / "x", decode_images=False)
    settings = stack.settings
    with session_scope(stack.url) as session:
        attempt = state.claim(session, journey_id, 60, 3)
        stored = state.stored_calibration(session, camera_id, journey_id,
                                          agree_rel=settings.calibration_flag_rel,
                                          newest=settings.calibration_consensus_newest)
    with session_scope(stack.url) as session:
        assert fusion.store_journey(session, journey_id, attempt, journey,
                                    made_result([("0", "stop", 49.0112, 8.4185, 114.0)], source,
                                                fx=fx, window=window),
                                    {"total_s": 1.0}, stored.camera if stored else None,
                                    settings, stored.source if stored else None)
    return journey_id


def waiting(stack, client, key: str, camera_id: str, n_frames: int = 5) -> str:
    """A straight journey of ``camera_id`` run by the real job: no turn, no calibration of its
    camera, so it waits for one (the factory bundle's few frames take a second)."""
    from app.service.jobs.run import run_journey

    journey_id = upload(client, key, bf_zip(camera_files(camera_id, n_frames)))
    run_journey(journey_id, stack.settings)
    row = journey(stack, journey_id)
    assert (row.status, row.stage) == ("queued", "waiting_for_camera"), row.error
    return journey_id


def journey(stack, journey_id: str) -> JourneyRow:
    with session_scope(stack.url) as session:
        return session.get(JourneyRow, journey_id)


def with_camera_id(bundle: Path, camera_id: str, out: Path) -> Path:
    """``bundle`` (a zip) with its manifest's camera_id replaced."""
    with zipfile.ZipFile(bundle) as src:
        files = {name: src.read(name) for name in src.namelist()}
    manifest = json.loads(files["manifest.json"])
    files["manifest.json"] = json.dumps({**manifest, "camera_id": camera_id}).encode()
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_STORED) as dst:
        for name, data in files.items():
            dst.writestr(name, data)
    out.write_bytes(buffer.getvalue())
    return out
