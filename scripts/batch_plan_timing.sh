#!/usr/bin/env bash
# `batch plan` time against the number of jobs: a 2D manifest of I inputs (tiny generated
# pictures, each its own file) x S prompts for each size, planned by the given clipgaussian
# binary (default target/release/clipgaussian), timed with /usr/bin/time. Prints a markdown
# table of jobs, seconds, peak memory and the size of jobs.json.
#
#   bash scripts/batch_plan_timing.sh [binary] [sizes as IxS ...]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
BIN="${1:-target/release/clipgaussian}"
shift || true
if [ "$#" -gt 0 ]; then SIZES=("$@"); else SIZES=(25x40 100x100 200x200 200x350 500x500); fi
[ -x "$BIN" ] || { echo "no binary at $BIN (cargo build --release -p clipgaussian)" >&2; exit 1; }
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
python3 - "$WORK" <<'PY'
import struct, sys, zlib
work = sys.argv[1]
def png(path, shade):
    raw = b"".join(b"\x00" + bytes([shade, 255 - shade, 128]) * 4 for _ in range(4))
    chunk = lambda t, d: struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d))
    data = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 4, 4, 8, 2, 0, 0, 0)) \
        + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")
    open(path, "wb").write(data)
for i in range(500):
    png(f"{work}/p{i}.png", i % 256)
PY
echo "| jobs | inputs x styles | plan (s) | peak memory (MB) | jobs.json (MB) |"
echo "|---|---|---|---|---|"
for size in "${SIZES[@]}"; do
  inputs=${size%x*}; styles=${size#*x}
  python3 - "$WORK" "$inputs" "$styles" <<'PY'
import json, sys
work, inputs, styles = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
manifest = {
    "modality": "2d",
    "set": {"steps": 10, "device": "cpu"},
    "inputs": [{"picture": f"p{i}.png"} for i in range(inputs)],
    "styles": [{"style_prompt": f"style number {s}"} for s in range(styles)],
}
json.dump(manifest, open(f"{work}/manifest.json", "w"))
PY
  rm -rf "$WORK/batch"
  /usr/bin/time -f "%e %M" -o "$WORK/time" "$BIN" batch plan "$WORK/manifest.json" --out "$WORK/batch" >/dev/null
  read -r seconds kb <"$WORK/time"
  mb=$(python3 -c "import os; print(round(os.path.getsize('$WORK/batch/jobs.json') / 1e6, 1))")
  echo "| $((inputs * styles)) | $inputs x $styles | $seconds | $((kb / 1024)) | $mb |"
done
