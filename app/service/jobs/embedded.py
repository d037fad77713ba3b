"""The embedded worker: without a broker, the API process runs journeys itself, one at a time.

A dispatcher thread takes journey ids from an in-memory queue and runs each job (the same
``jobs.run_journey`` the Celery task calls) in a spawned child process of its own process group:
the API stays responsive, a crash of the job cannot take the API down, and stopping the API can end
the job with its COLMAP grandchildren. The job process is tied to the API process as COLMAP's are to
it (``lifeline.die_with_parent``): an API killed with SIGKILL, which can end nothing, takes its job
with it, instead of leaving it running alone on a journey the next API start requeues and runs
again. The queue is memory only, so on start (and every half ``stale_after_s``, and after every
job) the database is swept: stale running journeys are requeued, journeys waiting for a camera
that has a calibration now are woken (``jobs.cameras.wake_calibrated``: a job's own wakes come
this way, its process has no queue to submit to), queued ones submitted (not those waiting for
their camera), and work dirs of runs no longer running deleted.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import queue
import signal
import threading

from app import logs
from app.pipeline.colmap.lifeline import die_with_parent
from app.service.jobs import cameras, state
from app.service.db.session import session_scope
from app.service.jobs.sweep import sweep_work
from app.settings import Settings

log = logging.getLogger(__name__)


def _exit_on_signal(signum: int, _frame) -> None:
    # An exception rather than the default death, so that the pipeline's own children are ended.
    raise SystemExit(128 + signum)


def _child_main(journey_id: str, settings: Settings, api_pid: int) -> None:
    # First: an API killed from now on must not leave this process behind (killed before, it is
    # seen here as a changed parent). The signal comes when the spawning *thread* ends; that is
    # the dispatcher thread, which outlives the job (it joins it; ``stop`` ends the job first).
    die_with_parent(api_pid)
    os.setpgid(0, 0)
    signal.signal(signal.SIGTERM, _exit_on_signal)
    logs.configure(settings.log_level)
    from app.service.jobs.run import run_journey

    run_journey(journey_id, settings)


class EmbeddedWorker:
    def __init__(self, settings: Settings):
        self.settings = settings
        self._queue: queue.Queue[str] = queue.Queue()
        self._pending: set[str] = set()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._child: multiprocessing.process.BaseProcess | None = None
        self._thread = threading.Thread(target=self._loop, name="signmap-embedded-worker",
                                        daemon=True)

    def start(self) -> None:
        self._thread.start()

    def submit(self, journey_id: str) -> None:
        with self._lock:
            if journey_id in self._pending:
                return
            self._pending.add(journey_id)
        self._queue.put(journey_id)

    def stop(self, timeout_s: float = 10.0) -> None:
        """Stop taking jobs and end the running one; its journey is requeued by the next start."""
        self._stop.set()
        self._queue.put("")  # wakes the dispatcher
        child = self._child
        if child is not None and child.pid is not None and child.is_alive():
            log.info("stopping the running job (pid %d)", child.pid)
            self._signal_group(child.pid, signal.SIGTERM)
            child.join(timeout_s)
            if child.is_alive():
                self._signal_group(child.pid, signal.SIGKILL)
        self._thread.join(timeout_s)

    @staticmethod
    def _signal_group(pid: int, sig: int) -> None:
        try:
            os.killpg(pid, sig)
        except ProcessLookupError:  # the child has not made its own group yet
            try:
                os.kill(pid, sig)
            except ProcessLookupError:
                pass

    def sweep(self) -> None:
        """Requeue stale running journeys, wake those waiting for a calibrated camera, delete the
        work dirs of runs no longer running and submit every queued journey."""
        url = self.settings.effective_database_url
        with session_scope(url) as session:
            requeued = state.requeue_stale(session, self.settings.stale_after_s,
                                              self.settings.max_attempts)
        if requeued:
            log.warning("requeued journeys with a stale heartbeat: %s", ", ".join(requeued))
        cameras.wake_calibrated(url, self.settings, None)  # submitted with the queued ones
        with session_scope(url) as session:
            ids = state.queued_ids(session)
        sweep_work(self.settings.data_dir, self.settings.effective_database_url)
        for journey_id in ids:
            self.submit(journey_id)

    def _loop(self) -> None:
        ctx = multiprocessing.get_context("spawn")
        sweep_every_s = max(1.0, self.settings.stale_after_s / 2)
        while not self._stop.is_set():
            try:
                self.sweep()
            except Exception:
                log.exception("embedded worker: sweep failed")
            try:
                journey_id = self._queue.get(timeout=sweep_every_s)
            except queue.Empty:
                continue
            if self._stop.is_set():
                return
            with self._lock:
                self._pending.discard(journey_id)
            self._child = ctx.Process(target=_child_main,
                                      args=(journey_id, self.settings, os.getpid()),
                                      name=f"signmap-job-{journey_id}")
            self._child.start()
            self._child.join()
            if self._child.exitcode != 0:
                # Killed or crashed: requeue (or give up on) the journey now, not once stale.
                log.log(logging.INFO if self._stop.is_set() else logging.ERROR,
                        "journey %s: job process ended with exit code %s", journey_id,
                        self._child.exitcode)
                try:
                    with session_scope(self.settings.effective_database_url) as session:
                        state.abandon(session, journey_id)
                except Exception:
                    # The database is down or read-only (what likely ended the job): the loop
                    # must outlive it; the sweep requeues the journey once it is stale.
                    log.exception("journey %s: could not be requeued now", journey_id)
            self._child = None
