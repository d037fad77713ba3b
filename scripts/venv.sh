# Sourced by scripts/run.sh and scripts/test.sh: find a Python >= 3.11 and make sure .venv uses one.
#
#   find_python    prints the interpreter to use: $PYTHON when set (it must be >= 3.11), else the
#                  first of python3.13, python3.12, python3.11, python3 on the PATH that is >= 3.11;
#                  exits 1 with a message saying what is needed when there is none.
#   ensure_venv    creates .venv (in the current directory) with it when .venv has no working
#                  Python, and recreates it when .venv was made by a Python older than 3.11.

SIGNMAP_MIN_PYTHON=3.11
SIGNMAP_PYTHON_CANDIDATES="python3.13 python3.12 python3.11 python3"

# python_version PY: "MAJOR.MINOR" of interpreter PY, or nothing when it does not run.
python_version() {
  "$1" -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>/dev/null || true
}

# version_ok X.Y: true when X.Y >= $SIGNMAP_MIN_PYTHON.
version_ok() {
  local major=${1%%.*} minor=${1#*.}
  local want_major=${SIGNMAP_MIN_PYTHON%%.*} want_minor=${SIGNMAP_MIN_PYTHON#*.}
  case "$major$minor" in *[!0-9]*|"") return 1 ;; esac
  [ "$major" -gt "$want_major" ] ||
    { [ "$major" -eq "$want_major" ] && [ "$minor" -ge "$want_minor" ]; }
}

find_python() {
  local candidate version tried=""
  if [ -n "${PYTHON:-}" ]; then
    version=$(python_version "$PYTHON")
    if [ -z "$version" ]; then
      echo "Signmap needs Python $SIGNMAP_MIN_PYTHON or newer; PYTHON=$PYTHON does not run." >&2
      exit 1
    fi
    if ! version_ok "$version"; then
      echo "Signmap needs Python $SIGNMAP_MIN_PYTHON or newer;" \
        "PYTHON=$PYTHON is Python $version." >&2
      exit 1
    fi
    echo "$PYTHON"
    return 0
  fi
  for candidate in $SIGNMAP_PYTHON_CANDIDATES; do
    command -v "$candidate" >/dev/null 2>&1 || continue
    version=$(python_version "$candidate")
    if version_ok "$version"; then
      command -v "$candidate"
      return 0
    fi
    tried="$tried $candidate${version:+ ($version)}"
  done
  {
    echo "Signmap needs Python $SIGNMAP_MIN_PYTHON or newer (3.11, 3.12 or 3.13), and none was"
    echo "found on the PATH (looked for $SIGNMAP_PYTHON_CANDIDATES${tried:+; found only$tried})."
    echo "Install one (e.g. 'apt-get install python3.11 python3.11-venv') or point PYTHON at it:"
    echo "  PYTHON=/path/to/python3.12 bash $0"
  } >&2
  exit 1
}

ensure_venv() {
  local python version
  if [ -x .venv/bin/python ]; then
    version=$(python_version .venv/bin/python)
    if version_ok "$version"; then
      return 0
    fi
    python=$(find_python) || exit 1
    echo "the existing .venv was made by Python ${version:-(one that no longer runs)};" \
      "Signmap needs $SIGNMAP_MIN_PYTHON or newer: recreating .venv with $python" >&2
  else
    python=$(find_python) || exit 1
    echo "creating .venv with $python (Python $(python_version "$python"))" >&2
  fi
  "$python" -m venv --clear .venv
}
