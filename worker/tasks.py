"""Celery tasks and the worker's recovery of journeys whose worker died.

Every worker sweeps the database at start and then every half ``stale_after_s``: a journey left
``running`` with a heartbeat older than ``stale_after_s`` (its worker was killed) is put back to
``queued`` and sent again, journeys waiting for a camera that has a calibration now are woken and
sent (``jobs.cameras.wake_calibrated``: a wake that was lost), and the work dirs of runs no longer
running are deleted. Duplicate deliveries are harmless: ``run_journey`` claims the row first.
"""

from __future__ import annotations

import logging
import tempfile
import threading
from pathlib import Path

from celery.signals import worker_ready, worker_shutdown

from app.service.jobs import cameras, fusion, state, sweep
from app.service.db.session import session_scope
from app.service.jobs.run import run_journey
from worker.celery_app import FUSE_JOURNEY, RUN_JOURNEY, app, settings

log = logging.getLogger(__name__)
_stop_sweeping = threading.Event()
# Touched by every sweep, also while a job runs: the container healthcheck reads its age.
ALIVE_FILE = Path(tempfile.gettempdir()) / "signmap-worker.alive"


def send(journey_id: str) -> None:
    """Queue a journey for any worker (one woken, or put back to the queue by its own run)."""
    app.send_task(RUN_JOURNEY, args=[journey_id], queue=settings.celery_queue)


@app.task(name=RUN_JOURNEY, acks_late=True, reject_on_worker_lost=True)
def run_journey_task(journey_id: str) -> None:
    run_journey(journey_id, settings, submit=send)


@app.task(name=FUSE_JOURNEY, acks_late=True, reject_on_worker_lost=True)
def fuse_journey_task(journey_id: str) -> None:
    """Re-fuse the map around a stored journey (repairs a fusion that failed after the store)."""
    fusion.refuse_around(settings.effective_database_url, journey_id, settings)


def sweep_once() -> list[str]:
    # Sent before the commit: if the broker is down, the journeys stay stale for the next sweep.
    with session_scope(settings.effective_database_url) as session:
        ids = state.requeue_stale(session, settings.stale_after_s, settings.max_attempts)
        for journey_id in ids:
            send(journey_id)
            log.warning("journey %s: its worker stopped beating; sent again", journey_id)
    # Work dirs of runs that no longer run (the requeued ones' included), e.g. of a killed worker.
    sweep.sweep_work(settings.data_dir, settings.effective_database_url)
    # Journeys waiting for a camera calibrated meanwhile whose wake was lost (sent after their
    # commit: a claim drops a journey it still sees waiting).
    cameras.wake_calibrated(settings.effective_database_url, settings, send)
    return ids


def _sweep_forever() -> None:
    while True:
        try:
            sweep_once()
            ALIVE_FILE.touch()
        except Exception:
            log.exception("recovery sweep failed")
        if _stop_sweeping.wait(max(1.0, settings.stale_after_s / 2)):
            return


@worker_ready.connect
def _start_sweeping(**_kwargs) -> None:
    threading.Thread(target=_sweep_forever, name="signmap-sweep", daemon=True).start()


@worker_shutdown.connect
def _stop(**_kwargs) -> None:
    _stop_sweeping.set()
