#!/usr/bin/env bash
# End-to-end test of flexid-dashboard in headless Chromium (registered in ctest as
# dashboard_e2e). Usage: tests/dashboard/run_e2e.sh BUILD_DIR
#
# As deploy/demo, on a private LCM port (udpm://239.255.76.67:<random>?ttl=0, this host
# only): flexidd on a temporary database, knowing actuators S1 and S2 and refusing others
# (so that S3's samples get no prediction at all), the dashboard on 127.0.0.1 (a free
# port), the virtual rig records a 2 V and an 8 V trial of S1, flexidd identifies a model
# from them; then e2e.mjs opens the page in Chromium while the rig plays a fresh trial (the
# charts must update and the model line show the version), S2 (no model) and S3 (unknown
# to flexidd) publish (their charts must grow from the samples alone), S1 plays a trial
# with back-relaxation (an alert must appear), `flexid diagnose --propose` stores the
# augmented model (the page must list it as a proposal) and `flexid models activate`
# activates it (the page must show it active); flexid-control makes S1 follow a staircase in
# closed loop (the page must draw the reference). Screenshot:
# BUILD_DIR/test-artifacts/dashboard.png, and also $FLEXID_DOCS_SCREENSHOT when set.
#
# Exit 0 passed, 1 failed, 77 skipped (no /usr/bin/chromium or no
# tests/dashboard/node_modules/playwright-core: `npm ci` in tests/dashboard).
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
build="$(cd "${1:?usage: run_e2e.sh BUILD_DIR}" && pwd)"
chromium="${FLEXID_CHROMIUM:-/usr/bin/chromium}"

if [ ! -x "$chromium" ]; then
  echo "dashboard_e2e: SKIPPED: $chromium not found (apt-get install chromium)"
  exit 77
fi
if [ ! -f "$here/node_modules/playwright-core/package.json" ] || ! command -v node > /dev/null; then
  echo "dashboard_e2e: SKIPPED: node or playwright-core missing (cd tests/dashboard && npm ci)"
  exit 77
fi
for b in daemon/flexidd clients/flexid clients/flexid-rig clients/flexid-control clients/flexid-dashboard; do
  [ -x "$build/$b" ] || { echo "dashboard_e2e: $build/$b not built" >&2; exit 1; }
done

started=$(date +%s)
tmp="$(mktemp -d "${TMPDIR:-/tmp}/flexid-dashboard-e2e.XXXXXX")"
pids=()
cleanup() {
  local status=$?
  for pid in "${pids[@]}"; do kill -TERM "$pid" 2> /dev/null || true; done
  for pid in "${pids[@]}"; do wait "$pid" 2> /dev/null || true; done
  # In the sanitizer build (deploy/sanitize) a report of flexidd or the dashboard fails the test.
  if grep -l -e 'ERROR: [A-Za-z]*Sanitizer' -e ': runtime error: ' "$tmp"/*.out "$tmp"/*.err \
      > "$tmp/reports" 2> /dev/null; then
    while read -r f; do echo "--- sanitizer report in $(basename "$f")" >&2; cat "$f" >&2; done < "$tmp/reports"
    status=1
  fi
  rm -rf "$tmp"
  exit "$status"
}
trap cleanup EXIT

# A free UDP port for the test's own bus.
port="$(node -e "const s = require('dgram').createSocket('udp4');
  s.bind(0, '127.0.0.1', () => { console.log(s.address().port); s.close(); });")"
lcm="udpm://239.255.76.67:$port?ttl=0"
flexid=("$build/clients/flexid" --lcm "$lcm")
echo "dashboard_e2e: bus $lcm, scratch $tmp"

printf '%s\n' 'accept_unknown_actuators = false' '[[actuators]]' 'id = "S1"' \
  '[[actuators]]' 'id = "S2"' > "$tmp/flexidd.toml"
"$build/daemon/flexidd" --config "$tmp/flexidd.toml" --db "$tmp/t.db" --lcm "$lcm" \
  --log-file "$tmp/flexidd.log" > "$tmp/flexidd.out" 2>&1 &
pids+=($!)
for _ in $(seq 100); do "${flexid[@]}" rpc status --timeout 0.2 > /dev/null 2>&1 && break; sleep 0.1; done
"${flexid[@]}" rpc status --timeout 5 > /dev/null || { cat "$tmp/flexidd.out" >&2; exit 1; }
# flexidd created its key next to the database; the rig's trial control and "identify" are
# signed with it (README "Security").
export FLEXID_KEY_FILE="$tmp/flexidd.key"

: > "$tmp/dashboard.out"  # before the background start: sed below must find it
"$build/clients/flexid-dashboard" --lcm "$lcm" --listen 127.0.0.1:0 > "$tmp/dashboard.out" \
  2> "$tmp/dashboard.err" &
pids+=($!)
url=""
for _ in $(seq 100); do
  url="$(sed -n 's|^flexid-dashboard: serving \(http://[^ ]*\) .*|\1|p' "$tmp/dashboard.out")"
  [ -n "$url" ] && break
  sleep 0.1
done
[ -n "$url" ] || { echo "dashboard_e2e: the dashboard printed no URL" >&2; cat "$tmp/dashboard.err" >&2; exit 1; }
echo "dashboard_e2e: $(cat "$tmp/dashboard.out")"

# Message time runs on from run to run (each 440 s trial plus a minute at rest), as in deploy/demo.
start=$(( $(date +%s) * 1000000 ))
run_rig() {
  "$build/clients/flexid-rig" --lcm "$lcm" --actuator S1 --speed 100 --noise-mm 0.02 \
    --trial-control --start-utime "$start" --protocol "$@" > /dev/null
  start=$(( start + 500000000 ))
}

echo "dashboard_e2e: recording a 2 V and an 8 V trial"
run_rig square:level=2,period=220,duty=0.5,cycles=2
run_rig square:level=8,period=220,duty=0.5,cycles=2
sleep 0.5
echo "dashboard_e2e: identifying S1"
"${flexid[@]}" rpc identify '{"actuator": "S1", "latest": 2}' --timeout 120 > "$tmp/identify.json"
version="$(node -e "const r = JSON.parse(require('fs').readFileSync('$tmp/identify.json'));
  if (!r.active || !(r.version > 0)) process.exit(1); console.log(r.version);")" \
  || { echo "dashboard_e2e: identification failed" >&2; cat "$tmp/identify.json" >&2; exit 1; }
echo "dashboard_e2e: model v$version active"

mkdir -p "$build/test-artifacts"
export DASHBOARD_URL="$url" RIG="$build/clients/flexid-rig" FLEXID="$build/clients/flexid" \
  CONTROL="$build/clients/flexid-control" \
  LCM_URL="$lcm" \
  RIG_START_UTIME="$start" MODEL_VERSION="$version" CHROMIUM="$chromium" \
  SCREENSHOT="$build/test-artifacts/dashboard.png"
status=0
node "$here/e2e.mjs" || status=$?
if [ "$status" -ne 0 ]; then
  echo "--- flexid-dashboard stderr" >&2; cat "$tmp/dashboard.err" >&2
  echo "--- flexidd log (tail)" >&2; tail -20 "$tmp/flexidd.log" >&2 || true
fi
echo "dashboard_e2e: took $(( $(date +%s) - started )) s"
exit "$status"
