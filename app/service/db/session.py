"""Engines, sessions and migrations. Engines are kept per process id, so that a forked child never
uses its parent's pooled connections."""

from __future__ import annotations

import logging
import os
import sqlite3
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from alembic import command
from alembic.config import Config
from sqlalchemy import Engine, NullPool, create_engine, event, text
from sqlalchemy.exc import OperationalError
from sqlalchemy.orm import Session, sessionmaker

REPO_ROOT = Path(__file__).resolve().parents[3]
log = logging.getLogger(__name__)

_SESSIONS: dict[tuple[str, int], sessionmaker[Session]] = {}
_LOCK = threading.Lock()


def _sqlite_pragmas(dbapi_connection, _record) -> None:
    # No memory-mapped file, ever: a write to a mapped page that the file system refuses (the file
    # made immutable with `chattr +i`, its disk gone) is not an error SQLite can return but SIGBUS,
    # which kills the API and its embedded worker without a line logged. WAL mode maps its -shm
    # wal-index whatever mmap_size says (only locking_mode=EXCLUSIVE keeps it in heap memory, and
    # that locks out the job processes), so the rollback journal is used: every write is a plain
    # write() whose failure is an OperationalError (answered 503). Its cost: a commit waits for the
    # readers of that moment, and readers wait (busy timeout) while a commit writes, short waits
    # here where each transaction is a few rows. Foreign keys are off by default in SQLite.
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA mmap_size=0")  # 0 in most builds, not guaranteed by all
    if cursor.execute("PRAGMA journal_mode").fetchone()[0].lower() == "wal":
        _leave_wal(cursor)
    cursor.execute("PRAGMA foreign_keys=ON")
    cursor.close()


def _leave_wal(cursor) -> None:
    """Switch a database made by an earlier version (WAL is recorded in the file) to the rollback
    journal. That needs the only connection to it: while an older process still has it open, this
    connection stays in WAL, and the next one tries again."""
    busy_ms = cursor.execute("PRAGMA busy_timeout").fetchone()[0]
    cursor.execute("PRAGMA busy_timeout=0")  # fail at once rather than hold up a request
    try:
        cursor.execute("PRAGMA journal_mode=DELETE")
    except sqlite3.OperationalError as exc:
        log.warning("SQLite database still in WAL mode (%s): another process has it open; it "
                    "leaves WAL when this one is alone with it (restart every Signmap process "
                    "to make it so)", exc)
    finally:
        cursor.execute(f"PRAGMA busy_timeout={int(busy_ms)}")


def _create_engine(url: str, **kwargs) -> Engine:
    if not url.startswith("sqlite"):
        return create_engine(url, pool_pre_ping=True, **kwargs)
    if url.startswith("sqlite:///"):
        Path(url.removeprefix("sqlite:///")).parent.mkdir(parents=True, exist_ok=True)
    connect_args = {"check_same_thread": False, "timeout": 30, **kwargs.pop("connect_args", {})}
    engine = create_engine(url, connect_args=connect_args, **kwargs)
    event.listen(engine, "connect", _sqlite_pragmas)
    return engine


def write_refusal(url: str, timeout_s: float = 5.0) -> str | None:
    """Why the database at ``url`` would refuse a write now (None: it takes writes). Raises
    SQLAlchemyError when it cannot be asked.

    SQLite: a fresh connection (a pooled one opened before the file became read-only still believes
    it writable) commits a write that changes nothing. Rolling it back would prove nothing: the
    database file is only written at commit. PostgreSQL: whether the server or the session is
    read-only, without writing (a standby, ``default_transaction_read_only``)."""
    if url.startswith("sqlite"):
        engine = _create_engine(url, poolclass=NullPool, connect_args={"timeout": timeout_s})
        try:
            with engine.connect() as connection:
                connection.execute(text("UPDATE alembic_version SET version_num = version_num"))
                connection.commit()
        except OperationalError as exc:
            return str(exc.orig).strip().splitlines()[0] if exc.orig else type(exc).__name__
        finally:
            engine.dispose()
        return None
    with get_engine(url).connect() as connection:
        standby, read_only = connection.execute(text(
            "SELECT pg_is_in_recovery(), current_setting('transaction_read_only')")).one()
    if standby:
        return "the server is a read-only standby (in recovery)"
    if read_only == "on":
        return "transactions are read-only (default_transaction_read_only is on)"
    return None


def _sessionmaker(url: str) -> sessionmaker[Session]:
    key = (url, os.getpid())
    with _LOCK:
        if key not in _SESSIONS:
            _SESSIONS[key] = sessionmaker(_create_engine(url), expire_on_commit=False)
        return _SESSIONS[key]


def get_engine(url: str) -> Engine:
    return _sessionmaker(url).kw["bind"]


def new_session(url: str) -> Session:
    """A fresh session on the database at ``url``; the caller commits and closes it."""
    return _sessionmaker(url)()


@contextmanager
def session_scope(url: str) -> Iterator[Session]:
    """A session that commits on success and rolls back on any exception."""
    with _sessionmaker(url)() as session, session.begin():
        yield session


def upgrade(url: str, revision: str = "head") -> None:
    """Bring the database at ``url`` to ``revision`` with the Alembic migrations."""
    get_engine(url)  # creates the SQLite file's directory
    config = Config(str(REPO_ROOT / "alembic.ini"))
    config.set_main_option("script_location", str(REPO_ROOT / "migrations"))
    config.attributes["url"] = url
    command.upgrade(config, revision)


@contextmanager
def temporary_database(admin_url: str, name: str) -> Iterator[str]:
    """A new, empty PostgreSQL database ``name`` on the server of ``admin_url``, dropped (with any
    connections still open to it) at the end; yields its URL."""
    admin = create_engine(admin_url, isolation_level="AUTOCOMMIT")
    try:
        with admin.connect() as conn:
            conn.execute(text(f'CREATE DATABASE "{name}"'))
        url = admin.url.set(database=name).render_as_string(hide_password=False)
        try:
            yield url
        finally:
            get_engine(url).dispose()
            with admin.connect() as conn:
                conn.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
    finally:
        admin.dispose()
