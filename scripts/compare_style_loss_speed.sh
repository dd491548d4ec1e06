#!/usr/bin/env bash
# One command, one run: the style loss + image gradient at the paper's settings (800x800 render,
# 64 patches, VGG-19 at 800x800, ViT-B/32-sized CLIP, random weights) in this crate (release
# build) and in the authors' PyTorch code, back to back on this machine, best of REPEATS each,
# with the ratio per term (candle / PyTorch; <= 1 means no slower).
#
#   scripts/compare_style_loss_speed.sh [repeats] [threads]
#
# Needs Python with torch, torchvision and transformers from PyPI (PYTHON picks the
# interpreter, default python3).
set -euo pipefail
cd "$(dirname "$0")/.."
repeats="${1:-2}"
threads="${2:-$(nproc)}"
python="${PYTHON:-python3}"

cargo build --release -p style-loss --example style_loss_timing >&2
candle=$(RAYON_NUM_THREADS="$threads" target/release/examples/style_loss_timing "$repeats")
torch=$("$python" scripts/time_style_loss_torch.py "$threads" "$repeats")
echo "$candle" | head -2
echo "$torch" | head -1
"$python" - "$candle" "$torch" <<'PY'
import sys

def rows(text, column):
    out = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) > column:
            try:
                out[cells[0].split(" (")[0]] = float(cells[column])
            except ValueError:
                pass
    return out

candle, torch = rows(sys.argv[1], 2), rows(sys.argv[2], 1)
print("| term | candle (s) | PyTorch (s) | ratio |")
print("|---|---|---|---|")
for term, seconds in candle.items():
    if term in torch:
        print(f"| {term} | {seconds:.2f} | {torch[term]:.2f} | {seconds / max(torch[term], 1e-9):.2f} |")
PY
