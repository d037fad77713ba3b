"""Checks made before the API or a worker says it is up: the data dir is writable, the database is
reachable, migrated and takes writes. Each failure is one line naming the path or the URL (password
hidden)."""

from __future__ import annotations

import tempfile
from pathlib import Path

from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import create_engine, pool
from sqlalchemy.engine import make_url

from app.pipeline.detect.model import DetectorError, load_detector
from app.service.db.session import REPO_ROOT, write_refusal
from app.settings import Settings


class StartupError(Exception):
    """The service cannot run as configured; ``str(exc)`` says why in one line."""


def safe_url(url: str) -> str:
    """``url`` with its password masked, for messages and logs."""
    try:
        return make_url(url).render_as_string(hide_password=True)
    except Exception:  # not parseable: show no part of it that could hold a secret
        return url.split("@")[-1]


def _one_line(exc: BaseException) -> str:
    text = str(getattr(exc, "orig", None) or exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def check_data_dir(data_dir: Path) -> None:
    """data_dir exists (or is made) and a file can be written in it."""
    try:
        data_dir.mkdir(parents=True, exist_ok=True)
        # A real write, not os.access: access() says yes to root on a read-only mount.
        with tempfile.TemporaryFile(dir=data_dir):
            pass
    except OSError as exc:
        raise StartupError(f"data dir {data_dir.resolve()} is not writable: "
                           f"{exc.strerror or exc}") from None


def head_revision() -> str:
    config = Config(str(REPO_ROOT / "alembic.ini"))
    config.set_main_option("script_location", str(REPO_ROOT / "migrations"))
    return ScriptDirectory.from_config(config).get_current_head()


def current_revision(url: str, timeout_s: float = 5.0) -> str | None:
    """The migration the database at ``url`` is at (None before the first); StartupError when it
    does not answer."""
    connect_args = ({"connect_timeout": int(max(1, timeout_s))} if url.startswith("postgresql")
                    else {})
    engine = create_engine(url, poolclass=pool.NullPool, connect_args=connect_args)
    try:
        with engine.connect() as connection:
            return MigrationContext.configure(connection).get_current_revision()
    except Exception as exc:
        raise StartupError(f"database {safe_url(url)} is unreachable: {_one_line(exc)}") from None
    finally:
        engine.dispose()


def check_database(url: str, timeout_s: float = 5.0) -> None:
    """The database at ``url`` answers and is at the newest migration."""
    current = current_revision(url, timeout_s)
    head = head_revision()
    if current != head:
        raise StartupError(f"database {safe_url(url)} is at schema revision {current or 'none'}, "
                           f"this version needs {head}: run `signmap db upgrade`")


def check_database_writable(url: str, timeout_s: float = 5.0) -> None:
    """The database at ``url`` takes writes: a read-only one would accept the service's start and
    then fail every upload and job."""
    try:
        refusal = write_refusal(url, timeout_s)
    except Exception as exc:
        raise StartupError(f"database {safe_url(url)} is unreachable: {_one_line(exc)}") from None
    if refusal:
        raise StartupError(f"database {safe_url(url)} accepts no writes: {refusal}")


def check_detector(settings: Settings) -> None:
    """The configured sign detector (if any) loads and has an output layout it can decode."""
    if settings.detector.model is None:
        return
    try:
        load_detector(settings.detector)
    except DetectorError as exc:
        raise StartupError(str(exc)) from None


def check(settings: Settings) -> None:
    """Every startup check; raises StartupError on the first failure."""
    check_data_dir(settings.data_dir)
    check_database(settings.effective_database_url)
    check_database_writable(settings.effective_database_url)
    check_detector(settings)
