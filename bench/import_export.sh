#!/usr/bin/env bash
# Bulk import and export of a 1,000,000-sample recording (DESIGN.md, "Targets": import
# < 2 s, export < 1 s), offline on a database file:
#   flexid --db FILE trials import big.csv --actuator S1
#   flexid --db FILE trials export 1 --out back.csv
# The recording comes from flexid-rig --out (a 2/4/6/8 V staircase, 400 s per step and its
# rest, at 500 Hz: 2000 s, 1,000,000 samples, ~29 MB of CSV). Each figure is the best of
# RUNS runs (import into a fresh file each time); wall-clock and CPU (user + sys) times are
# both printed, since on a busy machine the wall clock also measures the other processes.
# The exported rows must equal the imported ones, byte for byte.
#
# Usage: bench/import_export.sh [BUILD_DIR] [RUNS]   (default: build, 3)
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
build=$(cd "${1:-$here/../build}" && pwd)
runs=${2:-3}
flexid=$build/clients/flexid
rig=$build/clients/flexid-rig
for program in "$flexid" "$rig"; do
  [[ -x $program ]] || { echo "import_export.sh: $program not built" >&2; exit 2; }
done

work=$(mktemp -d "${TMPDIR:-/tmp}/flexid-import-export.XXXXXX")
trap 'rm -rf "$work"' EXIT

"$rig" --out "$work/big.csv" --protocol staircase:levels=2/4/6/8,dwell=400 --rate-hz 500 \
  --noise-mm 0.02 --seed 1 >/dev/null
rows=$(($(wc -l <"$work/big.csv") - 1))
bytes=$(stat -c %s "$work/big.csv")

# Runs "$@" and prints "wall cpu" in seconds.
timed() {
  local TIMEFORMAT='%R %U %S' t
  t=$({ time "$@" >/dev/null; } 2>&1)
  awk '{printf "%.3f %.3f\n", $1, $2 + $3}' <<<"$t"
}

best_import_wall=999 best_import_cpu=999 best_export_wall=999 best_export_cpu=999
for ((run = 1; run <= runs; run++)); do
  rm -f "$work"/bench.db*
  read -r wall cpu < <(timed "$flexid" --db "$work/bench.db" trials import "$work/big.csv" \
    --actuator S1)
  best_import_wall=$(awk -v a="$best_import_wall" -v b="$wall" 'BEGIN {print (b < a ? b : a)}')
  best_import_cpu=$(awk -v a="$best_import_cpu" -v b="$cpu" 'BEGIN {print (b < a ? b : a)}')
  read -r wall cpu < <(timed "$flexid" --db "$work/bench.db" trials export 1 --out "$work/back.csv")
  best_export_wall=$(awk -v a="$best_export_wall" -v b="$wall" 'BEGIN {print (b < a ? b : a)}')
  best_export_cpu=$(awk -v a="$best_export_cpu" -v b="$cpu" 'BEGIN {print (b < a ? b : a)}')
done

if ! cmp -s <(tail -n +2 "$work/big.csv") <(grep -v '^#' "$work/back.csv" | tail -n +2); then
  echo "import_export.sh: the exported rows differ from the imported ones" >&2
  exit 1
fi

verdict() { awk -v t="$1" -v limit="$2" 'BEGIN {print (t < limit ? "meets" : "MISSES")}'; }
echo "recording: $rows samples, $bytes bytes of CSV; best of $runs runs; $(nproc) CPUs," \
  "load average $(cut -d' ' -f1 /proc/loadavg)"
printf 'import: %6.3f s wall, %6.3f s CPU  (%.2f M samples/s wall)  target < 2 s: %s\n' \
  "$best_import_wall" "$best_import_cpu" "$(awk -v n="$rows" -v t="$best_import_wall" \
  'BEGIN {print n / t / 1e6}')" "$(verdict "$best_import_wall" 2)"
printf 'export: %6.3f s wall, %6.3f s CPU  (%.2f M samples/s wall)  target < 1 s: %s\n' \
  "$best_export_wall" "$best_export_cpu" "$(awk -v n="$rows" -v t="$best_export_wall" \
  'BEGIN {print n / t / 1e6}')" "$(verdict "$best_export_wall" 1)"
echo "round trip: exported rows identical to the input"
