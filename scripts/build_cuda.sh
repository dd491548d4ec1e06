#!/usr/bin/env bash
# Builds the release binaries with the style loss on candle's CUDA device, on any x86-64 Linux
# machine with Python 3, GPU or not. nvcc, the CUDA headers and the cuBLAS / cuRAND / NVRTC
# libraries come from PyPI (CUDA 13.0 wheels) into target/cuda-toolkit; the CUDA driver
# (libcuda.so.1) is only needed to run, so the link uses a stub of it, as the CUDA toolkit's
# own lib/stubs/libcuda.so.
#
#   scripts/build_cuda.sh             # for the GPU nvidia-smi reports, else PTX for 8.0 (Ampere)
#   CUDA_COMPUTE_CAP=89 scripts/build_cuda.sh    # for one compute capability (here an RTX 4090)
#   scripts/build_cuda.sh --cuda 12   # CUDA 12.0, for NVIDIA drivers 525 to 579
#   scripts/build_cuda.sh --pack      # also packs the binaries into one small file (below)
#   scripts/build_cuda.sh --dry-run   # says what it would build, fetches and builds nothing
#
# Which CUDA: 13 (the default) needs an NVIDIA driver 580 or newer; `nvidia-smi` prints the
# driver's version and the newest CUDA it runs ("CUDA Version"). For an older driver (from 525
# on) build with --cuda 12. PyPI has no CUDA 12 compiler, so that build uses a CUDA 12 toolkit
# installed on the build machine: CUDA_HOME, else CUDA_PATH, else /usr/local/cuda-12*,
# /usr/local/cuda or /opt/cuda, the first whose nvcc is 12.x (NVIDIA's cuda-toolkit-12-0 package,
# or conda's cuda-nvcc and cuda-libraries-dev 12.0). The kernels are PTX, which a driver
# compiles only when it runs that CUDA version or a newer one: CUDA 12.0's runs on every driver
# from 525 on, 12.N's needs the driver of CUDA 12.N.
#
# The compute capability: CUDA_COMPUTE_CAP when set; else that of the first GPU nvidia-smi lists;
# else 80, whose PTX the driver compiles for every GPU from Ampere (8.0) on, newer ones included.
# The binaries carry an RPATH to the libraries fetched here, so they run on this machine without
# LD_LIBRARY_PATH; elsewhere, point the loader at the same CUDA's libraries (see below).
#
# Output: target/cuda/release/clipgaussian-2d, clipgaussian-3d, clipgaussian-video and
# clipgaussian-4d (whose deformation network runs on the CUDA device too), and the timing
# examples target/cuda/release/examples/{step_timing,style_loss_timing,vgg_op_timing,
# benchmark_4d,make_fit_scene}; stripped copies of all nine (52-69 MB each, without the debug
# information; make_fit_scene, the 3D fit's scene, is small) in target/cuda/dist, which
# scripts/gpu_check.sh runs. With --pack, also target/cuda/dist.tar.xz: the nine in one xz stream whose window spans them all, so the CUDA kernels they share are
# stored once (about 20 MB in all, under a 64 MiB upload to a GPU machine; about 2 minutes);
# `scripts/gpu_check.sh --bin target/cuda/dist.tar.xz` unpacks it. With --cuda 12 the same
# under target/cuda12. To run them, the loader needs the NVIDIA driver and that CUDA's cuBLAS,
# cuRAND and NVRTC, for example those of PyTorch's wheels (CUDA 13):
#   export LD_LIBRARY_PATH=$(python3 -c 'import nvidia, os; print(os.path.join(nvidia.__path__[0], "cu13", "lib"))'):$LD_LIBRARY_PATH
set -euo pipefail
cd "$(dirname "$0")/.."

usage="usage: scripts/build_cuda.sh [--cuda 12|13] [--pack] [--dry-run]"
dry_run=false
pack=false
cuda_major=13
while [ $# -gt 0 ]; do
    case "$1" in
        --dry-run) dry_run=true ;;
        --pack) pack=true ;;
        --cuda)
            cuda_major=${2:-}
            shift
            ;;
        *) echo "$usage" >&2; exit 2 ;;
    esac
    shift
done
case "$cuda_major" in
    13)
        cuda_version=13.0
        toolkit=$PWD/target/cuda-toolkit
        default_target=target/cuda
        ;;
    12)
        toolkit=""
        for candidate in "${CUDA_HOME:-}" "${CUDA_PATH:-}" /usr/local/cuda-12* /usr/local/cuda /opt/cuda; do
            [ -n "$candidate" ] && [ -x "$candidate/bin/nvcc" ] || continue
            release=$("$candidate/bin/nvcc" --version 2>/dev/null | grep -oE 'release [0-9]+\.[0-9]+' | cut -d' ' -f2 || true)
            if [[ "$release" == 12.* ]]; then
                toolkit=$candidate
                cuda_version=$release
                break
            fi
        done
        if [ -z "$toolkit" ]; then
            echo "--cuda 12 builds with a CUDA 12 toolkit installed on this machine (PyPI has no CUDA 12 nvcc)," >&2
            echo "and none was found in CUDA_HOME, CUDA_PATH, /usr/local/cuda-12*, /usr/local/cuda or /opt/cuda:" >&2
            echo "install one (NVIDIA's cuda-toolkit-12-0 package runs on every driver from 525 on) and set CUDA_HOME to it" >&2
            exit 2
        fi
        default_target=target/cuda12
        ;;
    *)
        echo "--cuda $cuda_major: give 13 (NVIDIA driver 580 or newer) or 12 (driver 525 or newer)" >&2
        exit 2
        ;;
esac
if [ -z "${CUDA_COMPUTE_CAP:-}" ]; then
    found=""
    if command -v nvidia-smi >/dev/null 2>&1; then
        found=$(nvidia-smi --query-gpu=compute_cap --format=csv,noheader 2>/dev/null | head -n 1 | tr -d ' .' || true)
    fi
    if [[ "$found" =~ ^[0-9]+$ ]]; then
        CUDA_COMPUTE_CAP=$found
        why="the GPU nvidia-smi reports"
    else
        CUDA_COMPUTE_CAP=80
        why="no GPU found: PTX for 8.0, which the driver compiles for every GPU from Ampere on"
    fi
else
    why="CUDA_COMPUTE_CAP"
fi
if ! [[ "$CUDA_COMPUTE_CAP" =~ ^[0-9]+$ ]]; then
    echo "CUDA_COMPUTE_CAP=$CUDA_COMPUTE_CAP: give the compute capability as digits, e.g. 89 for 8.9" >&2
    exit 2
fi
export CUDA_COMPUTE_CAP
echo "CUDA $cuda_version, compute capability $CUDA_COMPUTE_CAP ($why), toolkit in $toolkit"
if [ "$cuda_major" = 12 ] && [ "$cuda_version" != 12.0 ]; then
    echo "note: PTX from CUDA $cuda_version runs on drivers of CUDA $cuda_version or newer; CUDA 12.0's on every driver from 525 on"
fi
if $dry_run; then
    if [ "$cuda_major" = 13 ]; then
        echo "dry run: would fetch the toolkit (unless $toolkit/ready exists) and build into ${CARGO_TARGET_DIR:-$default_target}"
    else
        echo "dry run: would build with the installed toolkit into ${CARGO_TARGET_DIR:-$default_target}"
    fi
    exit 0
fi
# Lays out CUDA 13's wheels as a toolkit: they share one folder, nvidia/cu13.
toolkit_13() {
    "$toolkit/venv/bin/pip" install --quiet \
        "nvidia-cuda-nvcc==$cuda_version.*" "nvidia-cuda-crt==$cuda_version.*" \
        "nvidia-nvvm==$cuda_version.*" "nvidia-cuda-cccl==$cuda_version.*" \
        "nvidia-cuda-runtime==$cuda_version.*" "nvidia-cuda-nvrtc==$cuda_version.*" \
        "nvidia-cublas<13.1" "nvidia-curand"
    wheels=$("$toolkit/venv/bin/python" -c 'import nvidia, os; print(os.path.join(nvidia.__path__[0], "cu13"))')
    for dir in bin include nvvm; do
        ln -s "$wheels/$dir" "$toolkit/$dir"
    done
    mkdir -p "$toolkit/lib"
    # The unversioned names the linker asks for.
    for lib in cublas cublasLt nvrtc curand cudart; do
        ln -s "$(ls "$wheels"/lib/lib$lib.so.* | head -n 1)" "$toolkit/lib/lib$lib.so"
    done
}

if [ "$cuda_major" = 13 ] && [ ! -e "$toolkit/ready" ]; then
    rm -rf "$toolkit"
    python3 -m venv "$toolkit/venv"
    toolkit_13
    # A stub of the driver library: every cu* entry point cudarc declares, doing nothing. At run
    # time the real libcuda.so.1 (same soname) is loaded instead.
    cudarc=$(cargo metadata --format-version 1 --features style-loss/cuda 2>/dev/null |
        python3 -c 'import json, sys, os
print(next(os.path.dirname(p["manifest_path"]) for p in json.load(sys.stdin)["packages"] if p["name"] == "cudarc"))')
    grep -oE 'pub unsafe fn cu[A-Za-z0-9_]+' "$cudarc/src/driver/sys/mod.rs" | sort -u |
        sed -E 's/pub unsafe fn (.*)/void \1(void) {}/' > "$toolkit/libcuda_stub.c"
    cc -shared -fPIC -Wl,-soname,libcuda.so.1 -o "$toolkit/lib/libcuda.so" "$toolkit/libcuda_stub.c"
    touch "$toolkit/ready"
fi
export CUDA_PATH="$toolkit" CUDA_ROOT="$toolkit" CUDA_HOME="$toolkit"
export PATH="$toolkit/bin:$PATH"
nvcc --version | tail -n 2
# Where the libraries really are (the wheels' folder, or the installed toolkit's lib64), for
# the binaries' RPATH.
if [ "$cuda_major" = 13 ]; then
    libs=$(dirname "$(readlink -f "$toolkit/lib/libcublas.so")")
else
    libs=$(dirname "$(readlink -f "$(ls "$toolkit"/lib64/libcublas.so* | head -n 1)")")
fi
export RUSTFLAGS="${RUSTFLAGS:-} -C link-arg=-Wl,-rpath,$libs"

export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$default_target}
cargo build --release \
    -p base-mirage -p base-3dgs -p base-vegas -p base-dmiso -p integration-tests -p style-loss \
    --features base-mirage/cuda,base-3dgs/cuda,base-vegas/cuda,base-dmiso/cuda,integration-tests/cuda,style-loss/cuda \
    --bins --example step_timing --example style_loss_timing --example vgg_op_timing \
    --example benchmark_4d --example make_fit_scene
# Only this build's binaries: nothing stale is packed or checked.
rm -rf "$CARGO_TARGET_DIR/dist"
mkdir -p "$CARGO_TARGET_DIR/dist"
for binary in clipgaussian-2d clipgaussian-3d clipgaussian-video clipgaussian-4d \
    examples/step_timing examples/style_loss_timing examples/vgg_op_timing examples/benchmark_4d \
    examples/make_fit_scene; do
    strip -o "$CARGO_TARGET_DIR/dist/$(basename "$binary")" "$CARGO_TARGET_DIR/release/$binary"
done
echo "built with CUDA $cuda_version (compute capability $CUDA_COMPUTE_CAP) in $CARGO_TARGET_DIR/release"
if $pack; then
    # One block with a window larger than the eight together: each shared kernel is kept once.
    tar -C "$CARGO_TARGET_DIR/dist" -cf - . |
        xz -T1 --lzma2=preset=3,dict=768MiB > "$CARGO_TARGET_DIR/dist.tar.xz.tmp"
    mv "$CARGO_TARGET_DIR/dist.tar.xz.tmp" "$CARGO_TARGET_DIR/dist.tar.xz"
    echo "packed: $CARGO_TARGET_DIR/dist.tar.xz ($(du -h "$CARGO_TARGET_DIR/dist.tar.xz" | cut -f1))"
fi
