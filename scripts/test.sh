#!/usr/bin/env bash
# The whole test suite: creates .venv when missing, installs the project with its test extras and
# runs pytest (arguments are passed on, e.g. `bash scripts/test.sh -m "not slow"`).
# PYTHON picks the interpreter for a new .venv (default: the newest python3.13/3.12/3.11/python3).
# Real-service tests need PostgreSQL on 127.0.0.1:5432 and Redis on 127.0.0.1:6379 (.ci/run starts
# them) and, for the dashboard, /usr/bin/chromium; without them they are skipped and the run ends
# with a "real-service tests skipped" section saying which and why; under CI=true they fail the run.
# Tests run in one pytest-xdist worker per core (SIGNMAP_TEST_WORKERS overrides; 0: in this
# process), a test file's tests in the same worker, so that a module's fixtures (a real stack, a
# rendered corpus) are made once: 1.4 times faster than one process on the 2-core machine.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/venv.sh  # any Python >= 3.11 ($PYTHON, else python3.13 ... python3)
ensure_venv
.venv/bin/python -m pip install --quiet -e '.[test]'
exec .venv/bin/python -m pytest -ra -n "${SIGNMAP_TEST_WORKERS:-auto}" --dist loadfile "$@"
