#!/usr/bin/env bash
# The whole test suite: creates .venv when missing, installs the project with its test extras and
# runs pytest (arguments are passed on, e.g. `bash scripts/test.sh -m "not slow"`).
# Real-stack tests need PostgreSQL on 127.0.0.1:5432 and Redis on 127.0.0.1:6379 (.ci/run starts
# them); without them they are skipped, or fail when CI is set.
set -euo pipefail
cd "$(dirname "$0")/.."
python=${PYTHON:-python3.11}
if [ ! -x .venv/bin/python ]; then
  "$python" -m venv .venv
fi
.venv/bin/python -m pip install --quiet -e '.[test]'
exec .venv/bin/python -m pytest -ra "$@"
