#!/usr/bin/env bash
# The identification bar on the independent simulator's recordings (issue 12): runs
#   ../shared/data/independent/score FLEXID --part ident
# and fails when a fit that visits every level predicts the fresh recording worse than
# 1.5 times the sensor noise. Skips (exit 77) when the folder is absent.
#   tests/independent_ident_gate.sh FLEXID_BINARY SHARED_DATA_DIR
set -euo pipefail
flexid="$1"
score="$2/independent/score"
if [[ ! -x "$score" ]]; then
  echo "independent set not found at $score: skipped"
  exit 77
fi
out="$("$score" "$flexid" --part ident)"
echo "$out"
worst="$(sed -n 's/^identification worst \([0-9.]*\)x noise.*/\1/p' <<<"$out")"
if [[ -z "$worst" ]]; then
  echo "no 'identification worst' line in the scorer's output" >&2
  exit 1
fi
if awk -v w="$worst" 'BEGIN { exit !(w > 1.5) }'; then
  echo "FAIL: worst fit that visits every level predicts at ${worst}x the noise (bar 1.5x)" >&2
  exit 1
fi
echo "pass: worst ${worst}x the noise (bar 1.5x)"
