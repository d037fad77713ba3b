"""What crashes leave behind is removed (issue 13, finding 5), with real processes: COLMAP children
die with a SIGKILLed parent; orphaned uploads in incoming/ are swept when the API starts and
periodically, live ones kept; work dirs of runs no longer running are swept when a worker starts
(embedded and Celery)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import uuid
from datetime import timedelta
from pathlib import Path

import pytest

from app.service.db.session import session_scope
from app.service.db.models import JourneyRow, utc_now
from tests.utils.paths import REPO
from tests.utils.stack import CeleryWorker, Stack, make_settings, sqlite_stack

# Spawns the COLMAP pool exactly as run_sfm does, busies its processes and prints their pids.
PARENT = """
import json, multiprocessing.resource_tracker as rt, sys, time
from app.pipeline.colmap.sfm import colmap_pool
pool = colmap_pool(2)
futures = [pool.submit(time.sleep, 600) for _ in range(2)]
while len(pool._processes) < 2 or rt._resource_tracker._pid is None:
    time.sleep(0.05)
time.sleep(1.0)  # the children have run their initializer
print(json.dumps({"children": list(pool._processes), "tracker": rt._resource_tracker._pid}),
      flush=True)
time.sleep(600)
"""


def _alive(pid: int) -> bool:
    """Running (a zombie nobody reaped counts as gone: in a container PID 1 may never reap it)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads process states from /proc")
def test_colmap_children_die_with_their_killed_parent():
    parent = subprocess.Popen([sys.executable, "-c", PARENT], cwd=REPO, stdout=subprocess.PIPE,
                              env={**os.environ, "PYTHONPATH": str(REPO)}, text=True)
    others: list[int] = []
    try:
        pids = json.loads(parent.stdout.readline())
        others += [*pids["children"], pids["tracker"]]
        assert len(others) == 3 and all(_alive(pid) for pid in others)
        parent.send_signal(signal.SIGKILL)
        parent.wait(10)
        deadline = time.monotonic() + 5
        while any(_alive(pid) for pid in others) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert [pid for pid in others if _alive(pid)] == [], "outlived their parent"
    finally:
        for pid in [parent.pid, *others]:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def _age(path: Path, seconds: float) -> None:
    then = time.time() - seconds
    os.utime(path, (then, then), follow_symlinks=False)


def test_orphaned_uploads_are_swept_at_start_and_periodically(tmp_path):
    stack = sqlite_stack(tmp_path / "data", sweep_interval_s=1.0)
    incoming = stack.settings.data_dir / "incoming"
    (incoming / "dead.d" / "frames").mkdir(parents=True)
    (incoming / "dead.d" / "frames" / "0.jpg").write_bytes(b"x" * 1000)
    (incoming / "dead.zip").write_bytes(b"z" * 1000)
    (incoming / "partial.zip").write_bytes(b"p" * 100)  # a receive that was killed
    (incoming / "live.zip").write_bytes(b"l" * 100)  # another API process is receiving it
    (incoming / "checking.zip").write_bytes(b"c" * 100)  # received an hour ago ...
    (incoming / "checking.d").mkdir()  # ... and being validated now
    for name in ("dead.d/frames/0.jpg", "dead.d/frames", "dead.d", "dead.zip", "partial.zip",
                 "checking.zip"):
        _age(incoming / name, 2 * 3600)
    with stack.client():
        assert sorted(p.name for p in incoming.iterdir()) == ["checking.d", "checking.zip",
                                                             "live.zip"]
        for name in ("live.zip", "checking.zip", "checking.d"):
            _age(incoming / name, 2 * 3600)  # their API process died too
        deadline = time.monotonic() + 10
        while any(incoming.iterdir()) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert list(incoming.iterdir()) == []  # by the running API's periodic sweep


def _journeys_with_work_dirs(stack: Stack) -> tuple[dict[str, Path], dict[str, Path]]:
    """Journeys in every state with work dirs; returns (dirs to keep, dirs to remove) by name."""
    ids = {name: str(uuid.uuid4()) for name in ("live", "done", "stale")}
    now = utc_now()
    with session_scope(stack.url) as session:
        for name, status, attempts, beat in (("live", "running", 2, now),
                                             ("done", "done", 1, None),
                                             ("stale", "running", 1, now - timedelta(hours=1))):
            session.add(JourneyRow(id=ids[name], camera_id="c", bundle_sha256="0" * 64,
                                bundle_bytes=1, status=status, progress=0.0, n_frames=3,
                                attempts=attempts, heartbeat_at=beat))
    work = stack.settings.data_dir / "work"
    keep = {"live run": work / f"{ids['live']}-2"}
    remove = {"live journey's older run": work / f"{ids['live']}-1",
              "done run": work / f"{ids['done']}-1",
              "stale run (its worker died)": work / f"{ids['stale']}-1",
              "unknown": work / f"{uuid.uuid4()}-1"}
    for path in [*keep.values(), *remove.values()]:
        (path / "pipeline").mkdir(parents=True)
        (path / "pipeline" / "features.db").write_bytes(b"f" * 1000)
    return keep, remove


def _wait_swept(keep: dict[str, Path], remove: dict[str, Path], timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while any(p.exists() for p in remove.values()) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert [name for name, p in remove.items() if p.exists()] == []
    assert [name for name, p in keep.items() if not p.exists()] == []


def test_work_dirs_of_dead_runs_are_swept_when_the_embedded_worker_starts(tmp_path):
    stack = sqlite_stack(tmp_path / "data", embedded_worker=True)
    keep, remove = _journeys_with_work_dirs(stack)
    with stack.client():
        _wait_swept(keep, remove, timeout_s=20)


@pytest.mark.postgres
def test_work_dirs_of_dead_runs_are_swept_when_a_celery_worker_starts(tmp_path, own_pg_url,
                                                                      redis_url):
    stack = Stack("postgres", make_settings(tmp_path / "data", database_url=own_pg_url,
                                            broker_url=redis_url))
    keep, remove = _journeys_with_work_dirs(stack)
    worker = CeleryWorker(stack.settings, tmp_path / "worker.log")
    try:
        _wait_swept(keep, remove, timeout_s=60)
    finally:
        worker.stop()
