"""Real-service tests (marker ``postgres``: PostgreSQL + Redis; ``browser``: Chromium and
Playwright): skipped where the service is missing, failed under CI, and listed at the end of the run
with why (issue 13: `scripts/test.sh` used to skip them silently). Kept apart from ``conftest.py``
so that this plugin imports nothing but pytest (``tests/project/test_run_summary.py`` runs it in an
inner session)."""

from __future__ import annotations

import os
from typing import NoReturn

import pytest


def running_in_ci() -> bool:
    """``CI`` is set to something other than empty, 0, false or no (.ci/run sets CI=true)."""
    return os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")


def service_unavailable(message: str) -> NoReturn:
    """A real service (PostgreSQL, Redis, the browser) is missing: skip the test, or fail it under
    CI. The session's summary lists these skips (``RealServiceSkips``)."""
    if running_in_ci():
        pytest.fail(f"{message} (CI is set: real-service tests must run, not be skipped)")
    pytest.skip(message)


# Marker of the real-service tests -> (what they need, how to get it).
REAL_SERVICES = {
    "postgres": ("PostgreSQL + Redis",
                 "start PostgreSQL on 127.0.0.1:5432 and Redis on 127.0.0.1:6379, or point "
                 "SIGNMAP_TEST_POSTGRES_URL / SIGNMAP_TEST_REDIS_URL at them "
                 "(.ci/run starts both)"),
    "browser": ("a browser (Chromium + Playwright)",
                "install Debian's chromium at /usr/bin/chromium (apt-get install chromium) and "
                "the test extras (pip install -e '.[test]'); .ci/run installs chromium"),
}


class RealServiceSkips:
    """Collects the skipped tests marked ``postgres`` or ``browser`` and ends the run with a section
    saying which were skipped and why; under CI any such skip fails the run (whatever skipped it:
    ``service_unavailable`` already fails the test itself, this catches every other skip)."""

    def __init__(self) -> None:
        self.skipped: list[tuple[str, str, str]] = []  # (marker, nodeid, reason)

    def pytest_runtest_logreport(self, report) -> None:
        if not report.skipped or hasattr(report, "wasxfail"):
            return
        marker = next((m for m in REAL_SERVICES if m in report.keywords), None)
        if marker is None:
            return
        reason = str(report.longrepr)
        if isinstance(report.longrepr, tuple):
            reason = report.longrepr[2]
        reason = (reason.removeprefix("Skipped: ").strip().splitlines() or ["no reason given"])[0]
        self.skipped.append((marker, report.nodeid, reason))

    @pytest.hookimpl(trylast=True)
    def pytest_sessionfinish(self, session) -> None:
        if self.skipped and running_in_ci() and session.exitstatus == pytest.ExitCode.OK:
            session.exitstatus = pytest.ExitCode.TESTS_FAILED

    def pytest_terminal_summary(self, terminalreporter) -> None:
        if not self.skipped:
            return
        tr = terminalreporter
        tr.section("real-service tests skipped", sep="=", red=running_in_ci(),
                   yellow=not running_in_ci())
        by_reason: dict[tuple[str, str], list[str]] = {}
        for marker, nodeid, reason in self.skipped:
            by_reason.setdefault((marker, reason), []).append(nodeid)
        for marker in REAL_SERVICES:
            reasons = [(reason, ids) for (m, reason), ids in by_reason.items() if m == marker]
            if not reasons:
                continue
            need, how = REAL_SERVICES[marker]
            n = sum(len(ids) for _, ids in reasons)
            tr.line(f"{n} test{'s' * (n != 1)} needing {need} (marker {marker}) skipped:")
            for reason, ids in reasons:
                files: dict[str, int] = {}
                for nodeid in ids:
                    files[nodeid.split("::")[0]] = files.get(nodeid.split("::")[0], 0) + 1
                tr.line(f"  because {reason}")
                tr.line("    in " + ", ".join(f"{f} ({k})" for f, k in files.items()))
            tr.line(f"  to run them: {how}")
        if running_in_ci():
            tr.line("CI is set: real-service tests must not be skipped, so this run fails.",
                    red=True, bold=True)


def register_real_service_skips(config) -> None:
    """Call from ``pytest_configure``: adds the section and the CI rule to the session."""
    config.pluginmanager.register(RealServiceSkips(), "signmap-real-service-skips")
