"""What `signmap db upgrade` and `signmap serve` print when they start: only what a user can act
on. No Alembic chatter (the SQL dialect, each migration's notes) and no internal issue numbers."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

from alembic.config import Config
from alembic.script import ScriptDirectory

from app.service.startup import head_revision
from tests.utils.paths import REPO
from tests.utils.stack import make_settings, settings_env

ISSUE_NUMBER = re.compile(r"\bissues? #?\d+", re.IGNORECASE)


def _env(data_dir: Path) -> dict:
    env = settings_env(make_settings(data_dir))
    env["PYTHONPATH"] = str(REPO)
    return env


def _signmap(*args: str, env: dict) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "app.cli", *args], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=120)


def test_db_upgrade_says_in_one_line_what_it_did(tmp_path):
    env = _env(tmp_path / "data")
    first = _signmap("db", "upgrade", env=env)
    assert first.returncode == 0, first.stderr
    url = f"sqlite:///{tmp_path / 'data' / 'signmap.db'}"
    assert first.stdout == f"database {url}: schema revision none -> {head_revision()}\n"
    assert first.stderr == ""
    again = _signmap("db", "upgrade", env=env)
    assert again.stdout == f"database {url}: already at schema revision {head_revision()}\n"
    assert again.stderr == ""


def test_serve_starts_without_migration_notes(tmp_path):
    """A fresh SQLite data dir: serve migrates it and says it is up, in uvicorn's lines and ours."""
    server = subprocess.Popen([sys.executable, "-m", "app.cli", "serve", "--port", "0"], cwd=REPO,
                              env=_env(tmp_path / "data"), stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True)
    lines = []
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            line = server.stdout.readline()
            if not line:
                break
            lines.append(line)
            if "Uvicorn running on" in line:
                break
    finally:
        server.terminate()
        server.wait(timeout=30)
    text = "".join(lines)
    assert "Uvicorn running on" in text, text
    assert "Signmap API up" in text
    assert not re.search("alembic|Context impl|Running upgrade", text, re.IGNORECASE), text
    assert not ISSUE_NUMBER.search(text), text


def test_no_migration_note_names_an_issue():
    """`alembic upgrade` and `alembic history` show each migration's docstring."""
    config = Config(str(REPO / "alembic.ini"))
    config.set_main_option("script_location", str(REPO / "migrations"))
    docs = {rev.revision: rev.longdoc for rev in ScriptDirectory.from_config(config).walk_revisions()}
    assert docs and not {rev: doc for rev, doc in docs.items() if ISSUE_NUMBER.search(doc)}
