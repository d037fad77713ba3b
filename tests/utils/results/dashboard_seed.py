"""Journeys put straight into the service's tables, as a worker would have stored them (no COLMAP)."""

from __future__ import annotations

import hashlib
import uuid
from pathlib import Path

from app.service import storage
from app.service.jobs import state
from app.service.db.session import session_scope
from app.service.db.models import JourneyRow
from app.settings import Settings
from tests.utils import bundle_factory as bf
from tests.utils.results.service_support import made_result

try:
    from app.service.jobs.fusion import store_and_fuse as _store_and_fuse
except ImportError:  # before map fusion: the map is the union of the journeys' signs
    _store_and_fuse = None

LAT0, LON0 = float(bf.LAT0), float(bf.LON0)
SIGNS = [("0", "stop", LAT0 + 2e-5, LON0 + 3e-5, 112.0), ("1", "yield", LAT0 + 4e-5, LON0 + 1e-5, None)]


def add_journey(settings: Settings, status: str = "queued", camera_id: str = "test-cam",
                progress: float = 0.0, stage: str | None = None, error: str | None = None,
                signs=SIGNS, fx: float = 50.0) -> str:
    """A journey with the factory bundle stored; ``done`` ones get ``signs`` and a calibration
    through the job's own store_result."""
    data = bf.zip_bytes(bf.valid_files())
    sha = hashlib.sha256(data + camera_id.encode() + uuid.uuid4().bytes).hexdigest()
    path = storage.bundle_path(Path(settings.data_dir), sha)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    journey_id = str(uuid.uuid4())
    url = settings.effective_database_url
    with session_scope(url) as session:
        session.add(JourneyRow(id=journey_id, camera_id=camera_id, bundle_sha256=sha,
                            bundle_bytes=len(data), status="queued", progress=0.0, n_frames=5,
                            attempts=0))
    if status == "queued":
        return journey_id
    with session_scope(url) as session:
        attempt = state.claim(session, journey_id, 60, 3)
    if status == "done":
        from app.pipeline.bundle import read_bundle

        journey = read_bundle(path, Path(settings.data_dir) / "seed" / journey_id,
                              decode_images=False)
        result, timings_s = made_result(signs, fx=fx), {"turns": 0.5, "calibrate": 1.5,
                                                         "total_s": 2.0}
        if _store_and_fuse is not None:  # the job's own store, which also updates the fused map
            assert _store_and_fuse(url, journey_id, attempt, journey, result, timings_s, None,
                                   settings)
        else:
            with session_scope(url) as session:
                assert state.store_result(session, journey_id, attempt, journey, result,
                                             timings_s)
    elif status == "failed":
        with session_scope(url) as session:
            state.fail(session, journey_id, attempt, stage or "calibrate",
                          error or "no turn found")
    elif status == "running":
        with session_scope(url) as session:
            state.beat(session, journey_id, attempt, stage or "ego-motion", progress)
    return journey_id


def set_progress(settings: Settings, journey_id: str, progress: float, stage: str) -> None:
    with session_scope(settings.effective_database_url) as session:
        row = session.get(JourneyRow, journey_id)
        row.progress, row.stage = progress, stage
