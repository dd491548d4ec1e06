#!/usr/bin/env python3
"""The 8-bit ground truth of INRIA 3DGS's (and D-MiSo's) `readCamerasFromTransforms` for every
8-bit colour level and alpha, over black and over white: gs-core's NeRF-synthetic loader must
give exactly these levels.

The lines below are the loader's own arithmetic: RGBA / 255 in float64, colour times alpha plus
background times (1 - alpha), then `np.array(arr * 255.0, dtype=np.byte)` (a cast that truncates,
and wraps into int8; viewing the bytes as uint8, as `Image.fromarray(..., "RGB")` does, gives
the truncated level).

Output: `composite_8bit.bin`, 2 x 256 x 256 bytes: background (black, white), then alpha level,
then colour level.

How to run (PyPI only): pip install numpy, then
    python3 scripts/make_composite_fixture.py crates/gs-core/tests/fixtures
"""

import sys
from pathlib import Path

import numpy as np

out = Path(sys.argv[1])
levels = np.arange(256)
# im_data[alpha, colour] = (colour, colour, colour, alpha), as an RGBA picture.
im_data = np.zeros((256, 256, 4), dtype=np.uint8)
im_data[:, :, :3] = levels[None, :, None]
im_data[:, :, 3] = levels[:, None]
tables = []
for bg in (np.array([0, 0, 0]), np.array([1, 1, 1])):
    norm_data = im_data / 255.0
    arr = norm_data[:, :, :3] * norm_data[:, :, 3:4] + bg * (1 - norm_data[:, :, 3:4])
    with np.errstate(invalid="ignore"):
        cut = np.array(arr * 255.0, dtype=np.byte).view(np.uint8)
    assert (cut[:, :, 0] == cut[:, :, 1]).all() and (cut[:, :, 0] == cut[:, :, 2]).all()
    tables.append(cut[:, :, 0])
(out / "composite_8bit.bin").write_bytes(np.stack(tables).astype(np.uint8).tobytes())
# How often truncation differs from rounding: the cases the fixture exists for.
for name, t, bg in zip(("black", "white"), tables, (0, 1)):
    a = levels[:, None] / 255.0
    exact = (levels[None, :] / 255.0 * a + bg * (1 - a)) * 255.0
    print(name, "levels below the rounded value:", int((t < np.round(exact)).sum()))
