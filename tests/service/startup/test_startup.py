"""Startup checks and JSON errors (issue 13, finding 6): `serve`, `worker`, `db upgrade` and `keys
create` refuse to start, with one line naming the URL or path, when the database is unreachable or
the data dir is read-only; /health answers 503 JSON when the database goes away; any unhandled
error answers JSON 500."""

from __future__ import annotations

import logging
import os
import secrets
import shutil
import socket
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlalchemy.exc import OperationalError

from app.commands.service import create_service_app
from app.service.db.session import upgrade
from app.service.startup import StartupError
from tests.utils.backends import pg_database
from tests.utils.paths import REPO
from tests.utils.stack import make_settings, settings_env

def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]  # closed again when the socket is


def _run(command: str, env: dict, timeout_s: float = 60) -> subprocess.CompletedProcess:
    try:
        return subprocess.run([sys.executable, "-m", "app.cli", command, "--port",
                               str(_closed_port())] if command == "serve" else
                              [sys.executable, "-m", "app.cli", *command.split()],
                              cwd=REPO, env=env, capture_output=True, text=True,
                              timeout=timeout_s)
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"`signmap {command}` was still running after {timeout_s} s: it started "
                    f"instead of refusing; output: {(exc.stderr or b'')[-2000:]!r}")


def _env(tmp_path: Path, **overrides) -> dict:
    env = settings_env(make_settings(tmp_path / "data", **overrides))
    env["PYTHONPATH"] = str(REPO)
    return env


@pytest.mark.parametrize("command", ["serve", "worker", "db upgrade", "keys create --role admin"])
def test_an_unreachable_database_stops_serve_and_worker(tmp_path, command):
    port = _closed_port()
    url = f"postgresql+psycopg://signmap:s3cret@127.0.0.1:{port}/signmap"
    done = _run(command, _env(tmp_path, database_url=url, broker_url="redis://127.0.0.1:6379/13"))
    assert done.returncode == 1, done.stderr[-2000:]
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith(f"signmap {command.removesuffix(' --role admin')}: database postgresql+psycopg://signmap:***@"
                           f"127.0.0.1:{port}/signmap is unreachable: "), last
    assert "s3cret" not in done.stderr + done.stdout
    assert "Signmap API up" not in done.stderr and "ready" not in done.stderr
    assert "Traceback" not in done.stderr


def test_keys_create_on_an_unmigrated_database_says_to_upgrade(tmp_path):
    done = _run("keys create --role admin", _env(tmp_path))
    assert done.returncode == 1 and done.stdout == "", done.stderr[-2000:]
    assert done.stderr.strip().endswith("run `signmap db upgrade`"), done.stderr[-2000:]
    assert "Traceback" not in done.stderr


@contextmanager
def _read_only(data_dir: Path):
    """``data_dir`` made read-only for this process: by permissions, or for root (whom they do not
    stop) by the immutable attribute (``chattr +i``), which stops root too."""
    if os.geteuid() != 0:
        data_dir.chmod(0o555)
        try:
            yield
        finally:
            data_dir.chmod(0o755)
        return
    chattr = shutil.which("chattr")
    made = chattr and subprocess.run([chattr, "+i", str(data_dir)], capture_output=True)
    if not made or made.returncode != 0:
        pytest.skip(f"running as root, and the immutable attribute is not available here to make "
                    f"a directory read-only for root: {made.stderr.decode()[-200:] if made else 'no chattr'}")
    try:
        yield
    finally:
        subprocess.run([chattr, "-i", str(data_dir)], check=True)


@pytest.mark.parametrize("existing", [False, True], ids=["empty", "existing"])
def test_a_read_only_data_dir_stops_serve_naming_the_path(tmp_path, existing):
    data_dir = tmp_path / "data"
    data_dir.mkdir()
    if existing:
        upgrade(make_settings(data_dir).effective_database_url)
    with _read_only(data_dir):
        done = _run("serve", _env(tmp_path))
    assert done.returncode == 1, done.stderr[-2000:]
    last = done.stderr.strip().splitlines()[-1]
    expected = "Operation not permitted" if os.geteuid() == 0 else "Permission denied"
    assert last == f"signmap serve: data dir {data_dir} is not writable: {expected}"


def test_an_unmigrated_database_is_refused_at_start(tmp_path):
    settings = make_settings(tmp_path / "data")
    with pytest.raises(StartupError, match=r"database sqlite:///.*signmap.db is at schema revision "
                                            r"none, this version needs \w+: run `signmap db upgrade`"):
        with TestClient(create_service_app(settings)):
            pass


@pytest.mark.postgres
def test_health_answers_503_json_when_the_database_goes_away(tmp_path, pg_url):
    with pg_database(f"signmap_test_gone_{secrets.token_hex(3)}") as url:
        settings = make_settings(tmp_path / "data", database_url=url)
        client = TestClient(create_service_app(settings), raise_server_exceptions=False)
        with client:
            assert client.get("/api/v1/health").json() == {"status": "ok"}
            from sqlalchemy import create_engine, text

            from tests.utils.backends import PG_URL

            admin = create_engine(PG_URL, isolation_level="AUTOCOMMIT")
            with admin.connect() as conn:
                conn.execute(text(f'DROP DATABASE "{url.rsplit("/", 1)[1]}" WITH (FORCE)'))
            admin.dispose()
            answer = client.get("/api/v1/health")
            assert answer.status_code == 503
            assert answer.json() == {"detail": "the database is unreachable (OperationalError)"}
            answer = client.get("/api/v1/journeys", headers={"Authorization": "Bearer x"})
            assert answer.status_code == 503
            assert answer.json() == {"detail": "the database is unavailable; try again later"}


def test_an_unhandled_error_answers_json_500_and_is_logged(tmp_path, caplog):
    settings = make_settings(tmp_path / "data")
    upgrade(settings.effective_database_url)
    app = create_service_app(settings)

    @app.get("/api/v1/boom")
    def boom():
        raise RuntimeError("kaboom")

    @app.get("/api/v1/db-boom")
    def db_boom():
        raise OperationalError("SELECT 1", {}, Exception("database is locked"))

    # As a real server would: the exception is not raised into the client.
    with TestClient(app, raise_server_exceptions=False) as client, caplog.at_level(logging.ERROR):
        answer = client.get("/api/v1/boom")
        assert answer.status_code == 500
        assert answer.headers["content-type"] == "application/json"
        assert answer.json() == {"detail": "internal error (RuntimeError); see the server log"}
        answer = client.get("/api/v1/db-boom")
        assert answer.status_code == 503
        assert answer.json() == {"detail": "the database is unavailable; try again later"}
        assert client.get("/api/v1/health").json() == {"status": "ok"}  # still answering
    logged = [r for r in caplog.records if "GET /api/v1/boom: internal error" in r.getMessage()]
    assert len(logged) == 1 and logged[0].exc_info[1].args == ("kaboom",)
