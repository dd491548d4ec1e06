#!/usr/bin/env python3
"""A small VeGaS model file in the authors' exact layout, for base-vegas's loading test.

Mirrors `GaussianModel.save_ply` of gmum/VeGaS (models/... gaussian_model.py): the vertex
attributes in its `construct_list_of_attributes` order (x, y, z, nx, ny, nz, f_dc_*, f_rest_*
(none at SH degree 0), opacity, scale_*, rot_0, m_0, sigma_0, w1_*), all 'f4', written with
plyfile as `PlyElement.describe(elements, 'vertex')`, then the element 'time' with one row of
time_func_0..time_func_{F-2}. Values are seeded, and the JSON beside it lists them.

How to run (PyPI only): pip install numpy plyfile, then
    python3 scripts/make_vegas_fixture.py crates/base-vegas/tests/fixtures
"""

import json
import sys
from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyElement

N, P, FRAMES = 7, 7, 5
out = Path(sys.argv[1])
rng = np.random.default_rng(11)

xyz = rng.uniform(-0.5, 0.5, (N, 3)).astype(np.float32)
xyz[:, 1] = 0.0
normals = np.zeros_like(xyz)
f_dc = rng.uniform(-1, 1, (N, 3)).astype(np.float32)
opacity = rng.uniform(-2, 2, (N, 1)).astype(np.float32)
scale = rng.uniform(-5, -2, (N, 3)).astype(np.float32)
rot = rng.uniform(-2, 2, (N, 1)).astype(np.float32)
m = rng.uniform(-2, 2, (N, 1)).astype(np.float32)
sigma = rng.uniform(-3, 0, (N, 1)).astype(np.float32)
w1 = rng.uniform(-1, 1, (N, 2 * P)).astype(np.float32)
time_func = rng.uniform(0.5, 1.5, FRAMES - 1).astype(np.float32)

names = ["x", "y", "z", "nx", "ny", "nz"]
names += [f"f_dc_{i}" for i in range(3)]
names += ["opacity"] + [f"scale_{i}" for i in range(3)] + ["rot_0", "m_0", "sigma_0"]
names += [f"w1_{i}" for i in range(2 * P)]
dtype_full = [(name, "f4") for name in names]
elements = np.empty(N, dtype=dtype_full)
attributes = np.concatenate((xyz, normals, f_dc, opacity, scale, rot, m, sigma, w1), axis=1)
elements[:] = list(map(tuple, attributes))
vertex = PlyElement.describe(elements, "vertex")
time_dtype = [(f"time_func_{i}", "f4") for i in range(FRAMES - 1)]
time_elements = np.empty(1, dtype=time_dtype)
time_elements[:] = [tuple(time_func)]
time = PlyElement.describe(time_elements, "time")
PlyData([vertex, time]).write(str(out / "vegas_model.ply"))

expected = {
    "gaussians": N,
    "frames": FRAMES,
    "xyz": xyz.tolist(),
    "f_dc": f_dc.tolist(),
    "opacity": opacity[:, 0].tolist(),
    "scale_0_2": scale[:, [0, 2]].tolist(),
    "rot": rot[:, 0].tolist(),
    "m": m[:, 0].tolist(),
    "sigma": sigma[:, 0].tolist(),
    "w1": w1.tolist(),
    "time_func": time_func.tolist(),
}
(out / "vegas_model.json").write_text(json.dumps(expected))
