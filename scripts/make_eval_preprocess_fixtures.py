#!/usr/bin/env python3
"""Generate the fixtures of the `eval` preprocess test (`style-loss`, tests/eval_preprocess_matches_pil.rs).

How to run (from the repository root; needs only PyPI):

    python3 -m venv /tmp/eval-preprocess-venv
    /tmp/eval-preprocess-venv/bin/pip install torch torchvision "pillow>=9.1,<13" numpy safetensors
    /tmp/eval-preprocess-venv/bin/python scripts/make_eval_preprocess_fixtures.py

It writes `crates/style-loss/tests/fixtures/eval_preprocess_reference.{safetensors,json}` (about
40 kB). The oracle is the authors' evaluation (`metrics.py` of kornelhowil/CLIPGaussian): every view is
a PNG file written by 3DGS's `render.py` (torchvision `save_image`, 8 bits), opened with
`PIL.Image.open` and passed through OpenAI CLIP's `preprocess`, i.e. `clip._transform(n_px)`:
`Resize(n_px, BICUBIC)`, `CenterCrop(n_px)`, `convert("RGB")`, `ToTensor()`, `Normalize(CLIP mean,
std)` on the PIL image. ViT-L/14 uses `n_px = 224`; the small cases use a smaller `n_px` so that the
stored inputs and outputs stay small while the downscale factors stay realistic (800 -> 224 is 3.6).

Pillow version: the authors ran 3DGS's conda environment (Python 3.7, torchvision 0.13.1, so Pillow
9.x at most). Pillow 9 to 12 resample horizontally, then vertically, always (checked: 9.5.0, 10.4.0,
11.3.0, 12.0.0 give identical results). Pillow 13.0.0 sometimes takes the vertical pass first
(seen only when the height shrinks), which moves some pixels by one 8-bit step, so this script
refuses Pillow 13 and later. The fixtures were made with Pillow 9.5.0 (`pip install --target DIR
pillow==9.5.0` and `PYTHONPATH=DIR` in front of a torch venv also works).

Inputs are procedural 8-bit RGB images `[3, h, w]` (`pattern` below; the Rust test has the same
formulas and checks them against the FNV-1a 64-bit hash of each input stored in the JSON): hash
noise, a flat colour, sharp edges (one-pixel stripes, a 3-pixel checkerboard, a step) and a mix of
ramps, checkerboard, noise and stripes. Cases:
  * `preprocess.<name>`: the preprocessed pixels before `ToTensor` (`[3, n, n]` uint8) and, for a
    few cases, after `Normalize` (`[1, 3, n, n]` float32), for `n` in the JSON.
  * `resize.<name>`: Pillow's `Image.resize(..., BICUBIC)` alone on 8-bit RGB, to sizes that the
    preprocess never asks for (one axis unchanged, one up and one down).
  * `large`: a 600 x 800 `mix` input preprocessed at 224 (ViT-L/14's size); only checksums are
    stored: per-channel row and column sums of the uint8 output and its FNV-1a 64-bit hash.
"""

import io
import json
from pathlib import Path

import numpy as np
import torch
import PIL
from PIL import Image
from safetensors.torch import save_file
from torchvision import transforms
from torchvision.transforms import InterpolationMode

OUT = Path(__file__).resolve().parent.parent / "crates" / "style-loss" / "tests" / "fixtures"
CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)


def clip_transform(n_px):
    """OpenAI CLIP's `clip._transform` (clip/clip.py), with its PIL-level steps split out."""
    pil_steps = transforms.Compose([
        transforms.Resize(n_px, interpolation=InterpolationMode.BICUBIC),
        transforms.CenterCrop(n_px),
        lambda image: image.convert("RGB"),
    ])
    tensor_steps = transforms.Compose([
        transforms.ToTensor(),
        transforms.Normalize(CLIP_MEAN, CLIP_STD),
    ])
    return pil_steps, tensor_steps


def through_png(chw):
    """The uint8 `[3, h, w]` array as the authors' metric sees it: written to PNG and reopened."""
    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(chw.transpose(1, 2, 0))).save(buffer, "PNG")
    buffer.seek(0)
    return Image.open(buffer)


def chw(image):
    return np.asarray(image.convert("RGB")).transpose(2, 0, 1).copy()


def hash_noise(c, y, x, seed):
    """Pseudo-random byte: a multiplicative hash of the coordinates (wrapping 32-bit integers)."""
    key = ((x * 73856093) ^ (y * 19349663) ^ (c * 83492791) ^ (seed * 2246822519)) & 0xFFFFFFFF
    return ((key * 2654435761) & 0xFFFFFFFF) >> 24


def pattern(kind, h, w, seed=0):
    """Procedural 8-bit image `[3, h, w]`, identical to `pattern` in the Rust test.

    noise: `hash_noise` everywhere. flat: (200, 100, 30). edges: red one-pixel vertical stripes,
    green 3-pixel checkerboard, blue step at the middle column. mix: hash noise in the top-right
    quarter, one-pixel stripes in the bottom-left quarter, elsewhere a horizontal ramp (red), a
    vertical ramp (green) and a 37-pixel checkerboard (blue)."""
    out = np.zeros((3, h, w), dtype=np.uint8)
    for c in range(3):
        for y in range(h):
            for x in range(w):
                if kind == "noise":
                    v = hash_noise(c, y, x, seed)
                elif kind == "flat":
                    v = (200, 100, 30)[c]
                elif kind == "edges":
                    v = (255 * (x % 2), 255 * ((y // 3 + x // 3) % 2), 255 * (x >= w // 2))[c]
                elif x >= w // 2 and y < h // 2:
                    v = hash_noise(c, y, x, seed)
                elif x < w // 2 and y >= h // 2:
                    v = 255 * ((x + c) % 2)
                else:
                    v = (x * 255 // (w - 1), y * 255 // (h - 1), 255 * ((x // 37 + y // 37) % 2))[c]
                out[c, y, x] = v
    return out


def fnv1a64(data):
    h = 0xCBF29CE484222325
    for byte in data:
        h ^= int(byte)
        h = (h * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return h


def main():
    major, minor = (int(p) for p in PIL.__version__.split(".")[:2])
    assert (9, 1) <= (major, minor) < (13, 0), f"needs Pillow 9.1 to 12.x, not {PIL.__version__}"
    # name: (kind, h, w, seed, n_px, store the float output)
    cases = {
        "noise_landscape": ("noise", 61, 83, 1, 24, True),   # -> 24x32, crop columns 4..28
        "noise_portrait": ("noise", 97, 40, 2, 24, False),   # -> 58x24, crop rows 17..41
        "noise_small": ("noise", 13, 18, 3, 24, True),       # upscale -> 24x33, crop round(4.5) = 4
        "noise_large_factor": ("noise", 150, 200, 4, 24, False),  # factor 6.25 -> 24x32
        "flat": ("flat", 50, 70, 0, 24, False),
        "edges": ("edges", 90, 64, 0, 24, True),             # -> 33x24, crop rows round(4.5) = 4
        "mix": ("mix", 120, 96, 5, 24, False),               # factor 4 -> 30x24
        "exact_size": ("noise", 24, 24, 6, 24, False),       # no resize, no crop
        "no_resize_crop": ("noise", 24, 31, 7, 24, False),   # short side already 24: crop round(3.5) = 4
        "odd_margin": ("noise", 33, 20, 8, 20, False),       # short side already 20: crop round(6.5) = 6
    }
    tensors, meta = {}, {"pillow": PIL.__version__, "preprocess": {}, "resize": {}}
    for name, (kind, h, w, seed, n_px, store_output) in cases.items():
        array = pattern(kind, h, w, seed)
        pil_steps, tensor_steps = clip_transform(n_px)
        pil_out = pil_steps(through_png(array))
        tensors[f"preprocess.{name}.pixels"] = torch.from_numpy(chw(pil_out))
        if store_output:
            tensors[f"preprocess.{name}.output"] = tensor_steps(pil_out).unsqueeze(0).contiguous()
        meta["preprocess"][name] = {"kind": kind, "input": [h, w], "seed": seed, "size": n_px,
                                    "input_fnv1a64": f"{fnv1a64(array.tobytes()):016x}"}
    resizes = {
        "width_only": ((40, 30, 9), (40, 17)),
        "height_only": ((40, 30, 10), (13, 30)),
        "up_and_down": ((31, 29, 11), (57, 11)),
    }
    for name, ((h, w, seed), (oh, ow)) in resizes.items():
        array = pattern("noise", h, w, seed)
        out = through_png(array).resize((ow, oh), Image.Resampling.BICUBIC)
        tensors[f"resize.{name}.output"] = torch.from_numpy(chw(out))
        meta["resize"][name] = {"kind": "noise", "input": [h, w], "seed": seed, "size": [oh, ow],
                                "input_fnv1a64": f"{fnv1a64(array.tobytes()):016x}"}
    h, w, seed = 600, 800, 12
    array = pattern("mix", h, w, seed)
    pil_steps, _ = clip_transform(224)
    large = chw(pil_steps(through_png(array)))
    tensors["large.row_sums"] = torch.from_numpy(large.astype(np.int64).sum(axis=2))
    tensors["large.col_sums"] = torch.from_numpy(large.astype(np.int64).sum(axis=1))
    meta["large"] = {"kind": "mix", "input": [h, w], "seed": seed, "size": 224,
                     "input_fnv1a64": f"{fnv1a64(array.tobytes()):016x}",
                     "output_fnv1a64": f"{fnv1a64(large.tobytes()):016x}"}
    save_file(tensors, OUT / "eval_preprocess_reference.safetensors")
    with open(OUT / "eval_preprocess_reference.json", "w") as f:
        json.dump(meta, f, indent=1)
        f.write("\n")
    print(f"wrote {len(tensors)} tensors; large output fnv1a64 {meta['large']['output_fnv1a64']}")


if __name__ == "__main__":
    main()
