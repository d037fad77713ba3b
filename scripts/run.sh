#!/usr/bin/env bash
# The main job on a fresh machine: install into .venv, render a synthetic journey with one turn,
# run the whole pipeline on it (`signmap process`) and print the signs with their error against
# the generator's ground truth. RUN_DIR keeps the files (default: a new temporary directory).
# PYTHON picks the interpreter for a new .venv (default: the newest python3.13/3.12/3.11/python3).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/venv.sh  # any Python >= 3.11 ($PYTHON, else python3.13 ... python3)
ensure_venv
.venv/bin/python -m pip install --quiet -e '.[test]'
export PATH="$PWD/.venv/bin:$PATH"
work=${RUN_DIR:-$(mktemp -d /tmp/signmap-run.XXXXXX)}
echo "files in $work"
if [ ! -f "$work/journey/bundle.zip" ]; then
  echo "rendering a synthetic journey (120 frames, one turn)..."
  signmap synth --seed 0 --frames 120 --turns 1 --out "$work/journey" >/dev/null
fi
signmap process "$work/journey/bundle.zip" --out "$work/signs.geojson"
python -m bench.compare "$work/signs.report.json" "$work/journey/truth.json"
cat <<EOF

signmap is installed in $PWD/.venv. To use it from your shell:
  source $PWD/.venv/bin/activate     # then: signmap --help
or call it by its path, without activating:
  $PWD/.venv/bin/signmap --help
EOF
