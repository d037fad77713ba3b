"""The end of a run says what it left out: which real-service tests (markers ``postgres`` and
``browser``) it skipped and why, under CI a skipped real-service test failing the run (issue 13:
`scripts/test.sh` used to skip them silently), and how many ``extended`` tests it deselected and
how to run them (issue 64). Runs small inner pytest sessions with the suite's plugins
(``RealServiceSkips``, ``ExtendedLeftOut``)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.utils.extended import RUN_THEM
from tests.utils.paths import REPO
from tests.utils.real_services import running_in_ci

INNER_CONFTEST = """\
from tests.utils.real_services import register_real_service_skips


def pytest_configure(config):
    register_real_service_skips(config)
"""

INNER_TESTS = """\
import pytest

from tests.utils.real_services import service_unavailable


@pytest.mark.postgres
def test_pg():
    service_unavailable("PostgreSQL is not reachable (connection refused)")


@pytest.mark.postgres
def test_pg_too():
    service_unavailable("PostgreSQL is not reachable (connection refused)")


@pytest.mark.browser
def test_browser():
    pytest.skip("/usr/bin/chromium is missing")


def test_other_skip():
    pytest.skip("not a real-service test")


def test_ok():
    pass
"""


@pytest.fixture
def inner(tmp_path):
    (tmp_path / "conftest.py").write_text(INNER_CONFTEST)
    (tmp_path / "test_inner.py").write_text(INNER_TESTS)
    (tmp_path / "pytest.ini").write_text("[pytest]\nmarkers =\n    postgres\n    browser\n")

    def run(*args: str, ci: str | None = None) -> subprocess.CompletedProcess:
        env = {k: v for k, v in os.environ.items() if k not in ("CI", "PYTEST_ADDOPTS")}
        env["PYTHONPATH"] = str(REPO)
        if ci is not None:
            env["CI"] = ci
        return subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", *args],
                              cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    return run


def _section(stdout: str) -> list[str]:
    lines = stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if "real-service tests skipped" in line)
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("====")),
               len(lines))
    section = lines[start + 1:end]
    while section and not section[-1].strip():
        section.pop()
    return section


def test_skipped_real_service_tests_are_listed_with_why(inner):
    out = inner()
    assert out.returncode == 0, out.stdout + out.stderr
    section = _section(out.stdout)
    assert section[:3] == [
        "2 tests needing PostgreSQL + Redis (marker postgres) skipped:",
        "  because PostgreSQL is not reachable (connection refused)",
        "    in test_inner.py (2)",
    ]
    assert section[3].startswith("  to run them: start PostgreSQL on 127.0.0.1:5432 and Redis")
    assert section[4:7] == [
        "1 test needing a browser (Chromium + Playwright) (marker browser) skipped:",
        "  because /usr/bin/chromium is missing",
        "    in test_inner.py (1)",
    ]
    assert section[7].startswith("  to run them: install Debian's chromium")
    assert "not a real-service test" not in "\n".join(section)


def test_nothing_skipped_says_nothing(inner):
    out = inner("-k", "ok or other_skip")
    assert out.returncode == 0
    assert "real-service tests skipped" not in out.stdout


def test_under_ci_a_skipped_real_service_test_fails_the_run(inner):
    ci = "true"
    out = inner(ci=ci)
    assert out.returncode == 1, out.stdout
    assert "2 failed" in out.stdout  # service_unavailable fails the test itself under CI
    assert "CI is set: real-service tests must run, not be skipped" in out.stdout
    # a real-service test skipped any other way still fails the run
    out = inner("-k", "browser or ok", ci=ci)
    assert out.returncode == 1, out.stdout
    assert "1 passed, 1 skipped" in out.stdout
    assert section_end(out.stdout) == (
        "CI is set: real-service tests must not be skipped, so this run fails.")


def test_ci_false_is_not_ci(inner):
    out = inner("-k", "browser or ok", ci="false")
    assert out.returncode == 0, out.stdout


@pytest.mark.parametrize("value, ci", [("true", True), ("1", True), ("yes", True), ("", False),
                                       ("0", False), ("false", False), ("False", False)])
def test_running_in_ci(monkeypatch, value, ci):
    monkeypatch.setenv("CI", value)
    assert running_in_ci() is ci


def section_end(stdout: str) -> str:
    return _section(stdout)[-1]


EXTENDED_CONFTEST = """\
from tests.utils.extended import register_extended_left_out


def pytest_configure(config):
    register_extended_left_out(config)
"""

EXTENDED_TESTS = """\
import pytest


@pytest.mark.extended
def test_long():
    pass


@pytest.mark.extended
def test_longer():
    pass


def test_quick():
    pass
"""


@pytest.mark.parametrize("workers", ["0", "2"])  # under pytest-xdist the workers deselect
def test_the_run_says_how_many_extended_tests_it_left_out(tmp_path, workers):
    (tmp_path / "conftest.py").write_text(EXTENDED_CONFTEST)
    (tmp_path / "test_inner.py").write_text(EXTENDED_TESTS)
    (tmp_path / "pytest.ini").write_text("[pytest]\naddopts = -m 'not extended'\n"
                                         "markers =\n    extended\n")
    env = {k: v for k, v in os.environ.items() if k not in ("CI", "PYTEST_ADDOPTS")}
    # Only xdist, not the dozen plugins installed: a worker then starts in a second, not twenty.
    env.update(PYTHONPATH=str(REPO), PYTEST_DISABLE_PLUGIN_AUTOLOAD="1")

    def run(*args: str) -> str:
        out = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-p",
                              "xdist", "-n", workers, *args], cwd=tmp_path, env=env,
                             capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stdout + out.stderr
        return out.stdout

    line = f"2 extended tests left out (to run them: {RUN_THEM})"
    assert line in run()
    assert "extended test" not in run("-m", "extended")


def test_the_suite_counts_the_extended_tests_it_leaves_out(pytestconfig):
    assert pytestconfig.pluginmanager.has_plugin("signmap-extended-left-out")
