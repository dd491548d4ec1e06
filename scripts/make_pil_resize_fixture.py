#!/usr/bin/env python3
"""Pillow's bicubic `Image.resize` of RGBA and RGB pictures, the oracle of
`gs_core::pil_resize` (INRIA 3DGS's loader resizes every picture this way: `PILtoTorch` calls
`pil_image.resize(resolution)`, whose default filter is bicubic).

An RGBA picture is resized premultiplied by Pillow (`RGBA` to `RGBa`, resize, back to `RGBA`),
so the picture holds every alpha level, alpha 0 under non-zero colours, and sharp edges between
transparent and opaque regions, where premultiplying matters most.

Output: `pil_resize.bin` and `pil_resize.json` (the cases: input and output sizes and byte
offsets). The input pictures are written too, so the test reads exactly what Pillow read.

Written with Pillow 12.0 (Pillow 13.0 writes the same bytes). How to run (PyPI only):
pip install numpy "pillow<13", then
    python3 scripts/make_pil_resize_fixture.py crates/gs-core/tests/fixtures
"""

import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image

out = Path(sys.argv[1])
rng = np.random.default_rng(7)
h, w = 37, 53
rgba = rng.integers(0, 256, size=(h, w, 4), dtype=np.uint8)
rgba[:, :, 3] = np.arange(h * w).reshape(h, w) % 256  # every alpha level
rgba[:10, :20, 3] = 0  # transparent block under random colours
rgba[10:20, 20:40, 3] = 255  # opaque block
rgba[25:, :, :3] = 250  # bright rows: overshoot above 255 when sharpened
rgba[25:, 26:, 3] = rng.integers(0, 2, size=(h - 25, w - 26), dtype=np.uint8) * 255

blob = bytearray()
cases = []


def add(name, mode, pixels, size):
    image = Image.fromarray(pixels, mode)
    resized = np.asarray(image.resize(size, Image.Resampling.BICUBIC))
    entry = dict(name=name, mode=mode, input=[pixels.shape[0], pixels.shape[1]],
                 output=[size[1], size[0]], input_offset=len(blob))
    blob.extend(pixels.tobytes())
    entry["output_offset"] = len(blob)
    blob.extend(resized.tobytes())
    cases.append(entry)


for size in [(19, 13), (40, 28), (53, 37), (80, 61), (31, 37)]:
    add(f"rgba_{size[0]}x{size[1]}", "RGBA", rgba, size)
    add(f"rgb_{size[0]}x{size[1]}", "RGB", np.ascontiguousarray(rgba[:, :, :3]), size)

(out / "pil_resize.bin").write_bytes(bytes(blob))
(out / "pil_resize.json").write_text(json.dumps(cases, indent=1) + "\n")
print(f"wrote {len(cases)} cases, {len(blob)} bytes")
