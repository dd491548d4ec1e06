#!/usr/bin/env bash
# One command for a machine with an NVIDIA GPU: proves and times the GPU path from binaries built
# elsewhere by scripts/build_cuda.sh (no Rust toolchain, no network needed here).
#
#   scripts/gpu_check.sh [--bin DIR] [--out FILE] [--part-timeout SECONDS] [--fit-steps N]
#                        [--fit-only] [--dry-run]
#
# DIR holds the binaries, or is the .tar.xz that `build_cuda.sh --pack` writes, unpacked here
# into a temporary folder (default target/cuda/dist, what build_cuda.sh writes: clipgaussian-2d,
# -3d, -video, -4d, and the examples step_timing, style_loss_timing, vgg_op_timing and
# benchmark_4d); FILE is the markdown report (default gpu_check.md). In order, each part's
# command, exit status and output go into the report:
#   1. the GPU and driver (nvidia-smi);
#   2. `selftest --device gpu` of every binary in DIR (each part against the cpu);
#   3. the 3D step timing (300,000 Gaussians of SH degree 3, 800x800, 64 patches of 128), with
#      CLIP in f32 and in f16;
#   4. the style loss alone on CUDA (style_loss_timing) with CLIP in f32, in f16 (the authors'
#      setting), and with CLIP's linear layers in bf16 (clip_precision bf16, whose CUDA form is
#      candle's conversions around cuBLAS's bf16 product), and the content term's pieces
#      (vgg_op_timing: each convolution, the ReLU, the max pool and its backward);
#   5. the 4D stylization step (benchmark_4d stylize: a batch of 4 views of 800x800, 2000 cores
#      of 500 sub-Gaussians) with the rasterizer, the network and the loss on the GPU;
#   6. the authors' PyTorch loss on the same GPU (scripts/time_style_loss_torch.py cuda, f32 and
#      f16) when the python3 on the PATH has torch and transformers;
#   7. with --fit-steps N (default 0: skipped), the 3D fit (`clipgaussian-3d fit --eval`, INRIA's
#      schedule, densifying from 100,000 random points) of N steps on an 800x800 NeRF-synthetic
#      scene of 100 training and 20 test views rendered from 20,000 known Gaussians by the
#      make_fit_scene example; its time is compared with INRIA's published figures for a
#      scene of its final size. --fit-only runs parts 1 and 7 alone (for a 30,000-step fit, give
#      it --part-timeout 570).
# A part that fails is recorded and the others still run; the exit status is that of the last
# part that failed (0 when none did).
# A part still running after SECONDS (default 150) is stopped and recorded with exit 124, so one
# hung part cannot use up a lease's time; the report is written part by part, so what ran before
# an interruption is kept.
# The binaries need CUDA 13's libraries on the loader path: when LD_LIBRARY_PATH does not have
# them, the ones of the python3's nvidia wheels (PyTorch's) are added. --dry-run prints the
# commands and runs none.
set -uo pipefail
cd "$(dirname "$0")/.."

bin=target/cuda/dist
out=gpu_check.md
part_timeout=150
fit_steps=0
fit_only=false
dry_run=false
usage="usage: scripts/gpu_check.sh [--bin DIR] [--out FILE] [--part-timeout SECONDS] [--fit-steps N] [--fit-only] [--dry-run]"
while [ $# -gt 0 ]; do
    case "$1" in
        --bin) bin=$2; shift 2 ;;
        --out) out=$2; shift 2 ;;
        --part-timeout) part_timeout=$2; shift 2 ;;
        --fit-steps) fit_steps=$2; shift 2 ;;
        --fit-only) fit_only=true; shift ;;
        --dry-run) dry_run=true; shift ;;
        *) echo "$usage" >&2; exit 2 ;;
    esac
done
if ! [[ "$fit_steps" =~ ^[0-9]+$ ]]; then
    echo "--fit-steps: $fit_steps is not a whole number; $usage" >&2
    exit 2
fi
if $fit_only && [ "$fit_steps" -eq 0 ]; then
    echo "--fit-only runs the 3D fit alone: give it --fit-steps N" >&2
    exit 2
fi

# A packed build: unpacked with python3's tarfile (the GPU machine may have no xz).
if ! $dry_run && [[ "$bin" == *.tar.xz ]]; then
    unpacked=$(mktemp -d)
    trap 'rm -rf "$unpacked"' EXIT
    python3 -c 'import sys, tarfile; tarfile.open(sys.argv[1]).extractall(sys.argv[2])' \
        "$bin" "$unpacked" || { echo "could not unpack $bin" >&2; exit 2; }
    bin=$unpacked
fi

# CUDA 13's libraries from the python3's nvidia wheels, when the loader does not have them.
if ! $dry_run && command -v python3 >/dev/null 2>&1; then
    wheels=$(python3 -c 'import nvidia, os; print(os.path.join(nvidia.__path__[0], "cu13", "lib"))' 2>/dev/null || true)
    if [ -n "$wheels" ] && [ -d "$wheels" ]; then
        export LD_LIBRARY_PATH="$wheels${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
    fi
fi

status=0
if ! $dry_run; then
    {
        echo "# GPU check ($(date -u +%Y-%m-%d\ %H:%M\ UTC))"
        echo
        echo "Binaries from \`$bin\`."
    } > "$out"
fi

# part TITLE COMMAND...: runs COMMAND, appends its title, command, status and output to the report.
part() {
    local title=$1
    shift
    if $dry_run; then
        echo "$title: $*"
        return
    fi
    echo "== $title" >&2
    local log
    log=$(mktemp)
    local start=$SECONDS
    timeout "$part_timeout" "$@" > "$log" 2>&1
    local rc=$?
    echo "   exit $rc after $((SECONDS - start)) s" >&2
    {
        echo
        echo "## $title"
        echo
        echo "\`$*\`: exit $rc$([ $rc -eq 124 ] && echo ", stopped after $part_timeout s") ($((SECONDS - start)) s)"
        echo
        if grep -q '^|' "$log"; then
            grep '^|' "$log"
            echo
            echo '<details><summary>other output</summary>'
            echo
            echo '```'
            grep -v '^|' "$log" | tail -n 40
            echo '```'
            echo '</details>'
        else
            echo '```'
            tail -n 60 "$log"
            echo '```'
        fi
    } >> "$out"
    rm -f "$log"
    if [ $rc -ne 0 ]; then
        status=$rc
    fi
}

if command -v nvidia-smi >/dev/null 2>&1; then
    part "GPU" nvidia-smi --query-gpu=name,driver_version,compute_cap,memory.total --format=csv
else
    part "GPU" echo "nvidia-smi not found"
fi
if ! $fit_only; then
for binary in clipgaussian-2d clipgaussian-3d clipgaussian-video clipgaussian-4d; do
    if [ -x "$bin/$binary" ] || $dry_run; then
        part "$binary selftest" "$bin/$binary" selftest --device gpu
    fi
done
part "3D step, CLIP f32" "$bin/step_timing" 300000 gpu 3 f32 800x800
part "3D step, CLIP f16" "$bin/step_timing" 300000 gpu 3 f16 800x800
part "style loss, CUDA, CLIP f32" env STYLE_LOSS_DEVICE=cuda STYLE_LOSS_PRECISION=f32 \
    "$bin/style_loss_timing" 3
part "style loss, CUDA, CLIP f16" env STYLE_LOSS_DEVICE=cuda STYLE_LOSS_PRECISION=f16 \
    "$bin/style_loss_timing" 3
part "style loss, CUDA, CLIP bf16 products" env STYLE_LOSS_DEVICE=cuda STYLE_LOSS_PRECISION=bf16 \
    "$bin/style_loss_timing" 3
part "VGG-19's pieces, CUDA" env STYLE_LOSS_DEVICE=cuda "$bin/vgg_op_timing"
part "4D stylization step" env BENCHMARK_4D_DEVICE=gpu "$bin/benchmark_4d" 0 stylize
if $dry_run || python3 -c 'import torch, transformers' >/dev/null 2>&1; then
    part "the authors' loss in PyTorch, cuda f32" python3 scripts/time_style_loss_torch.py 16 3 cuda f32
    part "the authors' loss in PyTorch, cuda f16" python3 scripts/time_style_loss_torch.py 16 3 cuda f16
else
    part "the authors' loss in PyTorch" echo "python3 has no torch or transformers: skipped"
fi
fi
if [ "$fit_steps" -gt 0 ]; then
    scene=$(mktemp -d)
    part "3D fit's scene (800x800, 100 + 20 views of 20,000 Gaussians)" \
        "$bin/make_fit_scene" "$scene/data" 20000 100 20 800 1
    part "3D fit, $fit_steps steps" "$bin/clipgaussian-3d" fit --data "$scene/data" \
        --out "$scene/fit" --steps "$fit_steps" --eval --device gpu --quiet
    if [ -f "$scene/fit/fit.json" ]; then
        part "3D fit's report" cat "$scene/fit/fit.json"
    fi
    rm -rf "$scene"
fi
if ! $dry_run; then
    echo "wrote $out (exit $status)"
fi
exit $status
