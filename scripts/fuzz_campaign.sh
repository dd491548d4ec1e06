#!/usr/bin/env bash
# A fuzz campaign over every reader: runs each fuzz test of the workspace (the harness in
# crates/gs-core/tests/fuzz/mod.rs mutates small valid files: truncations, bit flips, byte
# runs, numbers replaced by huge, negative and odd ones) with FUZZ_CASES cases per reader
# (default 2000; CI runs 500) and prints a markdown table of cases, refusals and reads per
# reader. A panic, an allocation past 256 MB or an error that does not name its file fails the
# test, and the script exits non-zero.
#
#   bash scripts/fuzz_campaign.sh [cases]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
CASES="${1:-2000}"
LOG=$(mktemp)
trap 'rm -f "$LOG"' EXIT
tests=(
  "-p gs-core --test fuzz_readers"
  "-p base-3dgs --test fuzz_camera_file"
  "-p base-vegas --test fuzz_model_file"
  "-p base-dmiso --test fuzz_model_file"
  "-p gs-stylize --test fuzz_checkpoint"
  "-p clipgaussian --test fuzz_batch"
)
status=0
for t in "${tests[@]}"; do
  # shellcheck disable=SC2086
  FUZZ_CASES="$CASES" cargo test -q $t -- --nocapture --test-threads 1 >>"$LOG" 2>&1 || status=1
done
echo "| reader (file) | seed | cases | refused | read | panics |"
echo "|---|---|---|---|---|---|"
sed -n 's/^.*fuzz \([^ ]*\) (seed \([0-9]*\)): \([0-9]*\) cases, \([0-9]*\) refused, \([0-9]*\) read, \([0-9]*\) panics$/| \1 | \2 | \3 | \4 | \5 | \6 |/p' "$LOG"
if [ "$status" -ne 0 ]; then
  grep -E "panicked|FAILED" "$LOG" | head -20 >&2
  echo "a fuzz test failed" >&2
fi
exit "$status"
