"""What the service echoes of its input (issue 70): a log line per record whatever a client sent
(a newline in a camera id forged an ``ERROR`` line), error details that do not send a 60 KB id
back, and a 403 that lists the roles a call needs in plain words."""

from __future__ import annotations

import io
import logging
import os
import subprocess
import sys

import pytest

from app.service.api.schemas import MAX_ECHOED_ID_CHARS
from tests.utils.paths import REPO
from tests.utils.stack import auth, sqlite_stack

FORGED = "\n2026-01-01 00:00:00,000 ERROR app.service.auth: FORGED admin key leaked"

_SERVE_LOGGING = f"""
import logging
from app.commands.service import _logging
from app.settings import Settings

_logging(Settings())  # as `signmap serve` sets up logging
log = logging.getLogger("app.service.api.routes.journeys")
log.info("journey j1 queued: camera %s, key 3", {("cam-1" + FORGED + chr(13) + chr(27) + "[2K")!r})
log.info("upload by key 3 rejected: %s", {("row 2 names frame x" + FORGED + chr(0x2028))!r})
try:
    raise ValueError("boom")
except ValueError:
    log.exception("a traceback keeps its lines")
"""


def test_a_forged_line_in_a_logged_value_stays_on_its_line(tmp_path):
    env = {**os.environ, "SIGNMAP_DATA_DIR": str(tmp_path), "SIGNMAP_LOG_LEVEL": "INFO"}
    result = subprocess.run([sys.executable, "-c", _SERVE_LOGGING], cwd=REPO, env=env,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    lines = result.stderr.splitlines()
    assert not [line for line in lines if "FORGED" in line and " INFO " not in line], lines
    queued = [line for line in lines if "queued" in line]
    assert len(queued) == 1 and queued[0].endswith(
        "camera cam-1\\n2026-01-01 00:00:00,000 ERROR app.service.auth: FORGED admin key "
        "leaked\\r\\x1b[2K, key 3"), lines
    assert [line for line in lines if "rejected" in line][0].endswith("leaked\\u2028")
    # The formatter's own line breaks (a traceback) are kept.
    assert "Traceback (most recent call last):" in lines
    assert "ValueError: boom" in lines


def test_the_celery_workers_log_lines_are_escaped_too():
    from celery.signals import after_setup_logger

    import worker.celery_app  # noqa: F401 - connects the signal, as `signmap worker` imports it

    out = io.StringIO()
    logger = logging.getLogger("test-celery-root")
    logger.propagate = False
    logger.addHandler(logging.StreamHandler(out))
    after_setup_logger.send(sender=None, logger=logger, loglevel=logging.INFO, logfile=None,
                            format="", colorize=False)
    logger.warning("journey %s failed", "j1" + FORGED)
    assert out.getvalue().count("\n") == 1
    assert "j1\\n2026" in out.getvalue()


@pytest.fixture
def service(tmp_path):
    stack = sqlite_stack(tmp_path / "data")
    with stack.client() as client:
        yield stack, client


def test_a_60_kb_id_is_not_echoed_whole(service):
    stack, client = service
    long_id = "a" * 60_000
    for method, path, role in (("GET", f"/api/v1/journeys/{long_id}", "fleet"),
                               ("GET", f"/api/v1/journeys/{long_id}/signs", "fleet"),
                               ("DELETE", f"/api/v1/journeys/{long_id}", "admin"),
                               ("GET", f"/api/v1/signs/{long_id}", "reader")):
        response = client.request(method, path, headers=auth(stack.key(role)))
        assert response.status_code == 404, (method, path[:40], response.text[:200])
        detail = response.json()["detail"]
        assert len(detail) < MAX_ECHOED_ID_CHARS + 20, (path[:40], detail[:200])
        assert detail.endswith("a\u2026 not found"), detail
    # An id within the limit is echoed as it is.
    response = client.get("/api/v1/journeys/no-such-journey", headers=auth(stack.key("fleet")))
    assert response.json()["detail"] == "journey no-such-journey not found"


def test_a_403_names_each_role_once_with_its_article(service):
    stack, client = service
    response = client.delete("/api/v1/journeys/x", headers=auth(stack.key("fleet")))
    assert response.status_code == 403
    assert response.json()["detail"] == "this call needs an admin key, not fleet"
    response = client.get("/api/v1/journeys", headers=auth(stack.key("reader")))
    assert response.status_code == 403
    assert response.json()["detail"] == "this call needs a fleet or admin key, not reader"


@pytest.mark.parametrize("url", [
    "/api/v1/signs?bbox=1,2,3,4&limit=" + "x" * 60_000,
    "/api/v1/tiles/1/2/" + "3" * 60_000 + ".mvt",
])
def test_fastapis_own_422_cuts_the_value_it_echoes(tmp_path, url):
    stack = sqlite_stack(tmp_path / "data")
    with stack.client() as client:
        answer = client.get(url, headers=auth(stack.key("reader")))
    assert answer.status_code == 422
    assert len(answer.content) < 1000  # was 60 KB
    (error,) = answer.json()["detail"]
    assert len(error["input"]) == MAX_ECHOED_ID_CHARS and error["loc"][0] in ("query", "path")
