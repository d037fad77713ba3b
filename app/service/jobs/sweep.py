"""Removing what crashes leave behind (the layout is in ``app.service.storage``).

* ``incoming/``: an API process killed mid-upload leaves its partial ``<id>.zip`` and ``<id>.d/``.
  Several API processes may share data_dir, so only entries untouched for ``incoming_max_age_s``
  are taken for dead: the API sweeps them at start and every ``sweep_interval_s``.
* ``work/<journey>-<n>/``: a worker killed mid-job leaves its run's files. A directory is kept
  only while its journey is ``running`` with attempt ``n``; workers sweep at start and after every
  requeue of stale journeys (``worker.tasks``, ``app.service.jobs.embedded``).
* expired dashboard sessions (``db.crud.forget_expired``), swept with ``incoming/``.
"""

from __future__ import annotations

import logging
import shutil
import threading
import time
from pathlib import Path

from sqlalchemy import select

from app.service.db.crud import forget_expired
from app.service.db.session import session_scope
from app.service.db.models import JourneyRow
from app.settings import Settings

log = logging.getLogger(__name__)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def _mtime(path: Path) -> float:
    try:
        return path.lstat().st_mtime
    except FileNotFoundError:  # finished meanwhile
        return float("inf")


def sweep_incoming(data_dir: Path, max_age_s: float) -> list[str]:
    """Delete uploads in ``incoming/`` whose files were all untouched for ``max_age_s``; an upload's
    ``<id>.zip`` and ``<id>.d`` go together, aged by the newer of the two. Returns the names."""
    directory = data_dir / "incoming"
    if not directory.is_dir():
        return []
    uploads: dict[str, list[Path]] = {}
    for path in directory.iterdir():
        uploads.setdefault(path.name.split(".", 1)[0], []).append(path)
    cutoff = time.time() - max_age_s
    removed = []
    for paths in uploads.values():
        if max(_mtime(p) for p in paths) < cutoff:
            for path in paths:
                _remove(path)
                removed.append(path.name)
    if removed:
        log.warning("removed %d orphaned upload files from %s: %s", len(removed), directory,
                    ", ".join(sorted(removed)))
    return removed


def sweep_work(data_dir: Path, url: str) -> list[str]:
    """Delete ``work/<journey>-<n>`` directories of runs that are not running; returns the names."""
    directory = data_dir / "work"
    if not directory.is_dir():
        return []
    # Listed before the database is read: a directory made after this listing is not looked at,
    # and one listed here was made after its run's claim was committed, so the read sees the claim.
    names = [p.name for p in directory.iterdir()]
    if not names:
        return []
    with session_scope(url) as session:
        live = {f"{journey_id}-{attempt}" for journey_id, attempt in session.execute(
            select(JourneyRow.id, JourneyRow.attempts).where(JourneyRow.status == "running"))}
    removed = [name for name in names if name not in live]
    for name in removed:
        _remove(directory / name)
    if removed:
        log.warning("removed work directories of runs that ended without cleaning up: %s",
                    ", ".join(sorted(removed)))
    return removed


def sweep_api(settings: Settings) -> None:
    """The API's sweep: orphaned uploads and expired dashboard sessions."""
    sweep_incoming(settings.data_dir, settings.incoming_max_age_s)
    with session_scope(settings.effective_database_url) as session:
        n = forget_expired(session)
    if n:
        log.info("forgot %d expired dashboard sessions", n)


class Sweeper:
    """Runs ``sweep_api`` now and then every ``sweep_interval_s`` in a daemon thread."""

    def __init__(self, settings: Settings):
        self.settings = settings
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="signmap-api-sweep", daemon=True)

    def start(self) -> None:
        sweep_api(self.settings)  # at start in the caller: a failure here is a startup failure
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()

    def _loop(self) -> None:
        while not self._stop.wait(max(1.0, self.settings.sweep_interval_s)):
            try:
                sweep_api(self.settings)
            except Exception:
                log.exception("API sweep failed")
