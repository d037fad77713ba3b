"""Storage outages (issue 70, items 4 and 5): a database made unwritable answers 503 JSON and
/health says so, the API process never dies of SIGBUS (no memory-mapped SQLite file); a full disk
answers 507 JSON and leaves no upload behind."""

from __future__ import annotations

import errno
import json
import logging
import shutil
import signal
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from sqlalchemy.exc import OperationalError

from app.service.db.session import get_engine
from app.service.storage import LocalBundleStore
from tests.utils import bundle_factory as bf
from tests.utils.paths import REPO
from tests.utils.stack import auth, sqlite_stack


def _post(client, key: str, data: bytes):
    return client.post("/api/v1/journeys", headers=auth(key),
                       files={"bundle": ("journey.zip", data, "application/zip")})


def _chattr_works(tmp_path: Path) -> str | None:
    """Why `chattr +i` cannot be used here (None: it can): it needs root (CAP_LINUX_IMMUTABLE)
    and a file system with the flag (ext4, xfs, btrfs; not tmpfs or overlayfs)."""
    if shutil.which("chattr") is None:
        return "no chattr"
    probe = tmp_path / "chattr-probe"
    probe.write_bytes(b"")
    done = subprocess.run(["chattr", "+i", str(probe)], capture_output=True, text=True)
    if done.returncode != 0:
        return f"chattr +i fails here: {done.stderr.strip()}"
    subprocess.run(["chattr", "-i", str(probe)], check=True)
    return None


# Run in a child process: the bug was the process dying of SIGBUS, which would take pytest with it.
_IMMUTABLE_SCENARIO = textwrap.dedent("""
    import json, os, subprocess, sys
    from pathlib import Path
    from tests.utils import bundle_factory as bf
    from tests.utils.stack import auth, sqlite_stack

    stack = sqlite_stack(Path(sys.argv[1]))
    db = Path(stack.url.removeprefix("sqlite:///"))
    key = stack.key("fleet")
    seen = {}

    def post(n_frames):
        response = client.post("/api/v1/journeys", headers=auth(key), files={
            "bundle": ("j.zip", bf.zip_bytes(bf.valid_files(n_frames=n_frames)),
                       "application/zip")})
        return [response.status_code, response.json()]

    def chattr(flag):
        files = [str(p) for p in db.parent.glob(db.name + "*")]
        subprocess.run(["chattr", flag, *files], check=True)
        return sorted(Path(f).name for f in files)

    with stack.client() as client:
        seen["before"] = post(5)
        seen["health_before"] = client.get("/api/v1/health").json()
        seen["files"] = chattr("+i")
        try:
            os.sync()  # clean pages: a mapped one would now fault on its next write (SIGBUS)
            seen["during"] = post(6)
            seen["health_during"] = [client.get("/api/v1/health").status_code,
                                     client.get("/api/v1/health").json()]
        finally:
            chattr("-i")
        seen["after"] = post(7)
        seen["health_after"] = client.get("/api/v1/health").json()
    print(json.dumps(seen))
""")


def test_an_immutable_database_answers_503_and_the_api_lives_on(tmp_path):
    reason = _chattr_works(tmp_path)
    if reason:
        pytest.skip(reason)
    data_dir = tmp_path / "data"
    try:
        done = subprocess.run([sys.executable, "-c", _IMMUTABLE_SCENARIO, str(data_dir)],
                              cwd=REPO, capture_output=True, text=True, timeout=300)
    finally:  # never leave an immutable file behind: tmp_path could not be removed
        files = [str(p) for p in data_dir.glob("signmap.db*")]
        if files:
            subprocess.run(["chattr", "-i", *files], check=False)
    assert done.returncode != -signal.SIGBUS, "the API process died of SIGBUS"
    assert done.returncode == 0, done.stderr[-3000:]
    seen = json.loads(done.stdout.strip().splitlines()[-1])
    # Rollback-journal mode: the database file alone, no -wal or -shm (mapped) file.
    assert seen["files"] == ["signmap.db"]
    assert seen["before"][0] == 202 and seen["health_before"] == {"status": "ok"}
    assert seen["during"] == [503, {"detail": "the database is unavailable; try again later"}]
    status, body = seen["health_during"]
    assert status == 503
    assert body["detail"].startswith("the database accepts no writes (")
    assert seen["after"][0] == 202 and seen["health_after"] == {"status": "ok"}


def test_sqlite_runs_without_memory_mapped_files(tmp_path):
    """WAL's -shm wal-index is always mapped, whatever mmap_size says: the cause of the SIGBUS."""
    stack = sqlite_stack(tmp_path / "data")
    with get_engine(stack.url).connect() as connection:
        assert connection.exec_driver_sql("PRAGMA journal_mode").scalar() == "delete"
        assert connection.exec_driver_sql("PRAGMA mmap_size").scalar() == 0


def test_a_database_left_in_wal_mode_leaves_it(tmp_path):
    stack = sqlite_stack(tmp_path / "data")
    path = stack.url.removeprefix("sqlite:///")
    get_engine(stack.url).dispose()
    with sqlite3.connect(path) as old:  # as an earlier version left it
        assert old.execute("PRAGMA journal_mode=WAL").fetchone() == ("wal",)
    old.close()
    with get_engine(stack.url).connect() as connection:
        assert connection.exec_driver_sql("PRAGMA journal_mode").scalar() == "delete"
    assert sorted(p.name for p in Path(path).parent.glob("signmap.db*")) == ["signmap.db"]


def test_health_names_a_write_outage(tmp_path, monkeypatch):
    """The write probe's verdict, whatever made the database refuse (here: a read-only open, which
    is what SQLite falls back to when the file cannot be opened for writing)."""
    stack = sqlite_stack(tmp_path / "data")
    with stack.client() as client:
        assert client.get("/api/v1/health").json() == {"status": "ok"}
        monkeypatch.setattr("app.service.app.write_refusal",
                            lambda url: "attempt to write a readonly database")
        response = client.get("/api/v1/health")
    assert response.status_code == 503
    assert response.json() == {"detail": "the database accepts no writes (attempt to write a "
                                         "readonly database): uploads and jobs fail until it does"}


def test_the_write_probe_sees_a_read_only_sqlite_database(tmp_path, monkeypatch):
    """query_only stands in for a file SQLite could only open read-only (as root, chmod does not
    make one; the chattr test above does it for real where chattr works)."""
    from app.service.db import session as session_module

    stack = sqlite_stack(tmp_path / "data")
    assert session_module.write_refusal(stack.url) is None
    pragmas = session_module._sqlite_pragmas

    def read_only(dbapi_connection, record):
        pragmas(dbapi_connection, record)
        dbapi_connection.execute("PRAGMA query_only=1")

    monkeypatch.setattr(session_module, "_sqlite_pragmas", read_only)
    assert session_module.write_refusal(stack.url) == "attempt to write a readonly database"


def _full(*_args, **_kwargs):
    raise OSError(errno.ENOSPC, "No space left on device")


@pytest.mark.parametrize("where", ["bundle store", "incoming file", "database"])
def test_a_full_disk_answers_507_and_stores_nothing(tmp_path, monkeypatch, caplog, where):
    stack = sqlite_stack(tmp_path / "data")
    key = stack.key("fleet")
    data = bf.zip_bytes(bf.valid_files())
    if where == "bundle store":
        monkeypatch.setattr(LocalBundleStore, "put", _full)
    elif where == "incoming file":
        monkeypatch.setattr("app.service.api.upload._BundlePart._part_data", _full)
    else:
        def commit(self):
            raise OperationalError("COMMIT", {}, _sqlite_full())
        monkeypatch.setattr("sqlalchemy.orm.Session.commit", commit)
    with stack.client() as client, caplog.at_level(logging.ERROR, "app.service.app"):
        response = _post(client, key, data)
    monkeypatch.undo()
    assert response.status_code == 507, response.text
    assert response.json() == {"detail": "storage is full on the server; try again later"}
    full_lines = [r for r in caplog.records if "storage is full" in r.getMessage()]
    assert len(full_lines) == 1 and full_lines[0].exc_info is None
    assert stack.count_journeys(key) == 0
    assert stack.stored_files() == []


def _sqlite_full() -> sqlite3.OperationalError:
    exc = sqlite3.OperationalError("database or disk is full")
    exc.sqlite_errorcode = 13  # SQLITE_FULL
    return exc


def test_any_other_error_is_still_500(tmp_path, monkeypatch):
    stack = sqlite_stack(tmp_path / "data")
    key = stack.key("fleet")
    monkeypatch.setattr(LocalBundleStore, "put", lambda *a: (_ for _ in ()).throw(
        OSError(errno.EIO, "Input/output error")))
    with stack.client() as client:
        response = _post(client, key, bf.zip_bytes(bf.valid_files()))
    assert response.status_code == 500
    assert response.json() == {"detail": "internal error (OSError); see the server log"}


@pytest.mark.postgres
def test_the_write_probe_sees_a_read_only_postgresql_database(own_pg_url):
    from sqlalchemy import text

    from app.service.db.session import write_refusal

    assert write_refusal(own_pg_url) is None
    engine = get_engine(own_pg_url)
    name = engine.url.database
    with engine.connect().execution_options(isolation_level="AUTOCOMMIT") as connection:
        connection.execute(text(f'ALTER DATABASE "{name}" SET default_transaction_read_only = on'))
    engine.dispose()  # the setting holds for sessions opened from now on
    try:
        assert write_refusal(own_pg_url) == ("transactions are read-only "
                                             "(default_transaction_read_only is on)")
    finally:
        with engine.connect().execution_options(isolation_level="AUTOCOMMIT") as connection:
            connection.execute(text("SET default_transaction_read_only = off"))
            connection.execute(text(f'ALTER DATABASE "{name}" RESET default_transaction_read_only'))
        engine.dispose()
