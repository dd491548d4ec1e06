#!/usr/bin/env bash
# A small NeRF-synthetic scene rendered from known Gaussians, for `clipgaussian-3d fit`'s
# tests and benchmarks (the tests write their own the same way, in a temporary folder).
#
#   scripts/make_fit_scene.sh OUT [GAUSSIANS TRAIN TEST SIZE SEED]
set -euo pipefail
cd "$(dirname "$0")/.."
cargo run --release -q -p base-3dgs --example make_fit_scene -- "$@"
