"""The embedded worker's job process dies with the API process (issue 70): an API killed with
SIGKILL cannot end its job itself, and a job running on alone would work on a journey the next API
start requeues and runs again.

A stand-in API (a process running the real ``EmbeddedWorker``) runs a job that blocks instead of a
journey, so the test needs no COLMAP run: it is the launcher and the tie that are under test."""

from __future__ import annotations

import multiprocessing
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from app.service.jobs import embedded
from tests.utils.paths import REPO
from tests.utils.stack import settings_env, sqlite_stack

# The stand-in API: the real worker, whose job process runs ``blocking_job`` below.
STAND_IN = """
import time
from app.service.jobs import embedded
from app.settings import Settings
from tests.service.jobs.test_orphaned_job import blocking_job
embedded._child_main = blocking_job
worker = embedded.EmbeddedWorker(Settings())
worker.start()
worker.submit("orphan-test")
time.sleep(600)
"""


def blocking_job(journey_id, settings, api_pid):
    """The job process's real start (``embedded._child_main``), with a journey that never ends."""
    import app.service.jobs.run as run

    def block(_journey_id, settings):
        (settings.data_dir / "job.pid").write_text(str(os.getpid()))
        time.sleep(600)

    run.run_journey = block
    embedded._child_main(journey_id, settings, api_pid)


def _alive(pid: int) -> bool:
    """Running, not a zombie (in a container PID 1 may never reap an orphan)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _wait(condition, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.1)
    return True


def test_the_job_process_dies_with_a_killed_api(tmp_path):
    stack = sqlite_stack(tmp_path / "data")
    pid_file = stack.settings.data_dir / "job.pid"
    api = subprocess.Popen([sys.executable, "-c", STAND_IN], cwd=REPO,
                           env=settings_env(stack.settings), start_new_session=True,
                           stdout=subprocess.DEVNULL, stderr=(tmp_path / "api.log").open("wb"))
    job_pid = None
    try:
        assert _wait(lambda: pid_file.exists() and pid_file.read_text(), 30), \
            f"the job never started:\n{(tmp_path / 'api.log').read_text()}"
        job_pid = int(pid_file.read_text())
        assert _alive(job_pid) and os.getpgid(job_pid) == job_pid  # its own group, as in use
        os.kill(api.pid, signal.SIGKILL)
        assert api.wait(10) == -signal.SIGKILL
        assert _wait(lambda: not _alive(job_pid), 5), "the job process outlived its API"
    finally:
        if api.poll() is None:
            os.kill(api.pid, signal.SIGKILL)
            api.wait(10)
        if job_pid is not None and _alive(job_pid):
            os.kill(job_pid, signal.SIGKILL)


def test_a_job_process_whose_api_died_before_it_was_tied_ends_at_once(tmp_path):
    """The race: the API died between spawning the job and the job's prctl. The job sees that its
    parent is not the API that spawned it and ends before it starts the journey."""
    stack = sqlite_stack(tmp_path / "data")
    not_the_parent = os.getppid()  # alive, and not the job's parent: as if reparented
    job = multiprocessing.get_context("spawn").Process(
        target=embedded._child_main, args=("never-run", stack.settings, not_the_parent))
    job.start()
    job.join(30)
    assert job.exitcode == -signal.SIGKILL
