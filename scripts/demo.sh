#!/usr/bin/env bash
# A walk through the default stack (SQLite + the API's embedded worker), as a fleet integrator would
# use it: render a synthetic journey, start `signmap serve`, make keys, upload with curl, poll the
# journey until it is done and print its signs and the map. Needs the project installed in .venv
# (bash scripts/run.sh or scripts/test.sh does that), curl and jq (checked first). DEMO_DIR keeps
# the files; PORT picks the port.
set -euo pipefail
cd "$(dirname "$0")/.."
missing=""
for tool in curl jq; do
  command -v "$tool" >/dev/null 2>&1 || missing="$missing $tool"
done
if [ -n "$missing" ]; then
  echo "scripts/demo.sh needs curl and jq; missing:$missing" >&2
  echo "install them (e.g. 'apt-get install curl jq' or 'brew install curl jq')" \
    "and run it again" >&2
  exit 1
fi
if [ ! -x .venv/bin/signmap ]; then
  echo "scripts/demo.sh needs signmap installed in .venv: run 'bash scripts/run.sh' first" >&2
  exit 1
fi
export PATH="$PWD/.venv/bin:$PATH"
work=${DEMO_DIR:-$(mktemp -d /tmp/signmap-demo.XXXXXX)}
port=${PORT:-8765}
api="http://127.0.0.1:$port/api/v1"
export SIGNMAP_DATA_DIR="$work/data"
unset SIGNMAP_DATABASE_URL SIGNMAP_BROKER_URL
echo "demo files in $work"

if [ ! -f "$work/journey/bundle.zip" ]; then
  echo "rendering a synthetic journey (about a minute)..."
  signmap synth --turns 1 --out "$work/journey" >/dev/null
fi
signmap db upgrade
fleet=$(signmap keys create --role fleet --name demo-fleet)
reader=$(signmap keys create --role reader --name demo-reader)

signmap serve --port "$port" >"$work/serve.log" 2>&1 &
server=$!
trap 'kill "$server" 2>/dev/null; wait "$server" 2>/dev/null || true' EXIT
until curl -sf "$api/health" >/dev/null; do
  kill -0 "$server" 2>/dev/null || { cat "$work/serve.log"; exit 1; }
  sleep 0.5
done

id=$(curl -sf -H "Authorization: Bearer $fleet" -F "bundle=@$work/journey/bundle.zip" \
  "$api/journeys" | jq -r .id)
echo "uploaded journey $id"
while true; do
  journey=$(curl -sf -H "Authorization: Bearer $fleet" "$api/journeys/$id")
  status=$(jq -r .status <<<"$journey")
  printf '  %-8s %-12s %3.0f%%\n' "$status" "$(jq -r '.stage // "-"' <<<"$journey")" \
    "$(jq '.progress * 100' <<<"$journey")"
  [ "$status" = done ] || [ "$status" = failed ] && break
  sleep 5
done
jq '{status, error, calibration, calibration_source, n_signs, timings_s}' <<<"$journey"
[ "$status" = done ] || exit 1

echo "the journey's signs:"
curl -sf -H "Authorization: Bearer $fleet" "$api/journeys/$id/signs" |
  jq -c '.features[] | {id: .properties.track_id, class: .properties.class, lonlatalt: .geometry.coordinates}'
bbox=$(jq -r '[.signs[].lon] as $x | [.signs[].lat] as $y |
  "\($x | min - 0.001),\($y | min - 0.001),\($x | max + 0.001),\($y | max + 0.001)"' \
  "$work/journey/truth.json")
echo "the map in bbox=$bbox (reader key):"
curl -sf -H "Authorization: Bearer $reader" "$api/signs?bbox=$bbox" | jq '.features | length'
