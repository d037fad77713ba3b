"""The ``extended`` tests a run leaves out (the default suite deselects them: pyproject.toml's
``addopts``), counted and named in one line at the end of the run, so that nobody takes the
default run for all there is. Imports nothing but pytest, like ``real_services``."""

from __future__ import annotations

import pytest

RUN_THEM = "bash scripts/test.sh -m extended"
_WORKER_KEY = "signmap_extended_left_out"


class ExtendedLeftOut:
    """Counts the deselected tests marked ``extended``. Under pytest-xdist the workers collect and
    deselect, not the controller that prints the summary: each worker hands its count over in
    ``workeroutput`` (all of them collect the same tests, so any one count is the run's)."""

    def __init__(self) -> None:
        self.count = 0

    def pytest_deselected(self, items) -> None:
        self.count += sum(1 for item in items if item.get_closest_marker("extended"))

    def pytest_sessionfinish(self, session) -> None:
        workeroutput = getattr(session.config, "workeroutput", None)
        if workeroutput is not None:
            workeroutput[_WORKER_KEY] = self.count

    @pytest.hookimpl(optionalhook=True)
    def pytest_testnodedown(self, node, error) -> None:
        self.count = max(self.count, getattr(node, "workeroutput", {}).get(_WORKER_KEY, 0))

    def pytest_terminal_summary(self, terminalreporter) -> None:
        if self.count:
            s = "s" * (self.count != 1)
            terminalreporter.write_sep("=", f"{self.count} extended test{s} left out "
                                            f"(to run them: {RUN_THEM})", yellow=True)


def register_extended_left_out(config) -> None:
    """Call from ``pytest_configure``: adds the line to the end of the session."""
    config.pluginmanager.register(ExtendedLeftOut(), "signmap-extended-left-out")
