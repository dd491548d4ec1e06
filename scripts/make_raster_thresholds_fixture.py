#!/usr/bin/env python3
"""INRIA's rasterizer at its thresholds: the fixture of `crates/gs-core/tests/inria_thresholds.rs`.

Each case is a camera, a set of Gaussians (INRIA's stored parameters, f32 values, SH degree 3)
and a random gradient of the picture; the script writes the picture and the gradient of
`sum(rgb * grad)` with respect to every parameter, both computed in float64 by the dense
transcription of INRIA's `diff-gaussian-rasterization` in `authors_loop.py` (the rasterizer of
CLIPGaussian's 3D code, VeGaS, MiraGe and D-MiSo). Besides random Gaussians, every case holds
Gaussians placed at each rule that decides whether a Gaussian is drawn at a pixel:

  * `past_right_edge`, `past_bottom_edge`: centres past the last column or row by more than their
    radius, yet inside a tile INRIA's `getRect` keeps (it culls only an empty rectangle), and
    opaque enough to reach 1/255 on the picture's last pixels;
  * `near_left_edge`, `near_top_edge`: rectangles that only just reach the first tile;
  * `tiny`: splats of 1 to 3 pixels centred near the edges of 8-column windows and of tiles;
  * `alpha_above`, `alpha_below`: opacity set so that the largest alpha over their pixels is
    1/255 times (1 + 3e-3) or (1 - 3e-3);
  * `stop`: opaque splats stacked on one spot, so that pixels stop at transmittance 1e-4;
  * `near_plane`: depths just past and just inside INRIA's near plane 0.2.

Every Gaussian keeps a margin from each decision (alpha against 1/255, transmittance against
1e-4, tile-rectangle edges, the radius' ceiling, the screen edge) of at least 1e-4 relative, so
that a float32 renderer must decide as this float64 one.

Output: `crates/gs-core/tests/fixtures/inria_thresholds/cases.json` (cameras and the kind of
every Gaussian) and one `<case>.safetensors` each (parameters, output gradient, picture and alpha
as float32 values; the parameter gradients in float64).

How to run (from the repository root; PyTorch, torchvision, transformers, open_clip_torch and
safetensors from PyPI, as `make_3d_replay_fixture.py`):

    /tmp/replay-venv/bin/python scripts/make_raster_thresholds_fixture.py
"""

import json
import math
import sys
from pathlib import Path

import torch
from safetensors.torch import save_file

sys.path.insert(0, str(Path(__file__).resolve().parent))
from authors_loop import ROOT, inria_camera, look_at_c2w, rasterize  # noqa: E402
from threshold_gaussians import (  # noqa: E402
    MARGIN, cat, decisions_have_margin, placed, random_in_view, stacked, stopped_pixels, take,
    transmittance_margin,
)

OUT = ROOT / "crates" / "gs-core" / "tests" / "fixtures" / "inria_thresholds"
FOV_X = 0.9
# Cases: picture sizes whose width and height are and are not multiples of the tile.
CASES = [
    dict(name="square_96", seed=1, width=96, height=96, eye_angle=0.3),
    dict(name="odd_61x45", seed=2, width=61, height=45, eye_angle=1.9),
    dict(name="wide_100x37", seed=3, width=100, height=37, eye_angle=3.4),
    dict(name="tall_48x80", seed=4, width=48, height=80, eye_angle=5.0),
]
RANDOM = 40
# Placed Gaussians of each kind per case.
PLACED = dict(past_right_edge=3, past_bottom_edge=3, near_left_edge=2, near_top_edge=2, tiny=8,
              alpha_above=3, alpha_below=3, near_plane=4)
STACK = 5


def build_case(case):
    gen = torch.Generator().manual_seed(case["seed"])
    a = case["eye_angle"]
    c2w = look_at_c2w([3.0 * math.cos(a), 3.0 * math.sin(a), 0.9])
    cam = inria_camera(c2w, case["width"], case["height"], FOV_X)
    parts, kinds = [random_in_view(gen, cam, RANDOM)], ["random"] * RANDOM
    for kind, count in PLACED.items():
        parts.append(placed(gen, cam, kind, count))
        kinds += [kind] * count
    parts.append(stacked(gen, cam, STACK))
    kinds += ["stop"] * STACK
    g = cat(parts)
    # Shuffle, so that the placed Gaussians are not all at the end of the lists.
    perm = torch.randperm(len(kinds), generator=gen)
    g = take(g, perm)
    kinds = [kinds[i] for i in perm.tolist()]
    margin = transmittance_margin(g, cam)
    assert margin > MARGIN, f"{case['name']}: a transmittance test {margin:.1e} from 1e-4"
    ok, _, _ = decisions_have_margin(g, cam)
    assert ok.all(), f"{case['name']}: Gaussians {torch.nonzero(~ok).flatten().tolist()} lack margin"
    stopped = stopped_pixels(g, cam)
    assert stopped > 0, f"{case['name']}: no pixel stops at transmittance 1e-4"
    print(f"{case['name']}: {stopped} pixels stop at transmittance 1e-4")
    return g, kinds, cam


def main():
    OUT.mkdir(parents=True, exist_ok=True)
    index = []
    for case in CASES:
        g, kinds, cam = build_case(case)
        gen = torch.Generator().manual_seed(1000 + case["seed"])
        width, height = case["width"], case["height"]
        out_grad = torch.randn(3, height, width, generator=gen, dtype=torch.float64)
        out_grad = out_grad.to(torch.float32).to(torch.float64)
        background = torch.tensor([0.2, 0.5, 0.9], dtype=torch.float64)
        params = {k: v.clone().requires_grad_(True) for k, v in g.items()}
        rgb, alpha = rasterize(params, cam, background)
        (rgb * out_grad).sum().backward()
        tensors = {f"param.{k}": v.to(torch.float32).contiguous() for k, v in g.items()}
        tensors.update({f"grad.{k}": v.grad.contiguous() for k, v in params.items()})
        tensors["out_grad"] = out_grad.permute(1, 2, 0).to(torch.float32).contiguous()
        tensors["rgb"] = rgb.detach().permute(1, 2, 0).to(torch.float32).contiguous()
        tensors["alpha"] = alpha.detach().to(torch.float32).contiguous()
        save_file(tensors, str(OUT / f"{case['name']}.safetensors"))
        drawn = (params["opacity"].grad[:, 0] != 0)
        counts = {k: sum(1 for i, kk in enumerate(kinds) if kk == k and drawn[i]) for k in set(kinds)}
        print(f"{case['name']}: {len(kinds)} Gaussians, with a gradient by kind: {counts}")
        index.append(dict(name=case["name"], width=width, height=height, fov_x=FOV_X,
                          w2c=cam["w2c"].tolist(), background=background.tolist(), kinds=kinds))
    with open(OUT / "cases.json", "w") as f:
        json.dump(dict(cases=index), f, indent=1)
    total = sum(p.stat().st_size for p in OUT.iterdir())
    print(f"wrote {OUT} ({total / 1e3:.0f} kB)")


if __name__ == "__main__":
    main()
