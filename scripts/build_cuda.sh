#!/usr/bin/env bash
# Builds the release binaries with the style loss on candle's CUDA device, on any x86-64 Linux
# machine with Python 3, GPU or not. nvcc, the CUDA headers and the cuBLAS / cuRAND / NVRTC
# libraries come from PyPI (CUDA 13.0 wheels) into target/cuda-toolkit; the CUDA driver
# (libcuda.so.1) is only needed to run, so the link uses a stub of it, as the CUDA toolkit's
# own lib/stubs/libcuda.so.
#
#   scripts/build_cuda.sh     # compute capability 9.0 (H100); CUDA_COMPUTE_CAP=89 for an RTX 4090
#
# Output: target/cuda/release/clipgaussian-2d, clipgaussian-3d and clipgaussian-4d (whose
# deformation network runs on the CUDA device too), and the timing examples
# target/cuda/release/examples/{step_timing,style_loss_timing,benchmark_4d}; stripped copies of
# all six (52-67 MB each, without the debug information; each under the device's 64 MiB carry
# limit, so one a call) in target/cuda/dist. To run them, the loader needs the
# NVIDIA driver and CUDA 13's cuBLAS, cuRAND and NVRTC, for example those of PyTorch's wheels:
#   export LD_LIBRARY_PATH=$(python3 -c 'import nvidia, os; print(os.path.join(nvidia.__path__[0], "cu13", "lib"))'):$LD_LIBRARY_PATH
set -euo pipefail
cd "$(dirname "$0")/.."

cuda_version=13.0
toolkit=$PWD/target/cuda-toolkit
if [ ! -e "$toolkit/ready" ]; then
    rm -rf "$toolkit"
    python3 -m venv "$toolkit/venv"
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
export CUDA_COMPUTE_CAP=${CUDA_COMPUTE_CAP:-90}
nvcc --version | tail -n 2

export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-target/cuda}
cargo build --release \
    -p base-mirage -p base-3dgs -p base-dmiso -p integration-tests -p style-loss \
    --features base-mirage/cuda,base-3dgs/cuda,base-dmiso/cuda,integration-tests/cuda,style-loss/cuda \
    --bins --example step_timing --example style_loss_timing --example benchmark_4d
mkdir -p "$CARGO_TARGET_DIR/dist"
for binary in clipgaussian-2d clipgaussian-3d clipgaussian-4d examples/step_timing \
    examples/style_loss_timing examples/benchmark_4d; do
    strip -o "$CARGO_TARGET_DIR/dist/$(basename "$binary")" "$CARGO_TARGET_DIR/release/$binary"
done
echo "built with CUDA $cuda_version (compute capability $CUDA_COMPUTE_CAP) in $CARGO_TARGET_DIR/release"
