#!/usr/bin/env python3
"""Replay the authors' video stylization loop in float64 PyTorch: the fixture of
`crates/base-vegas/tests/authors_replay.rs`.

How to run (from the repository root; PyTorch, transformers and torchvision from PyPI):

    python3 -m venv /tmp/replay-venv
    /tmp/replay-venv/bin/pip install torch torchvision transformers safetensors pillow \
        open_clip_torch
    cargo test -p base-vegas --test authors_replay -- --ignored write_replay_draws
    /tmp/replay-venv/bin/python scripts/make_video_replay_fixture.py

The first command writes each scene's `draws.json` (our run's view order, patch crops and
warps, and text direction); this script writes the rest of each scene's folder in
`crates/base-vegas/tests/fixtures/` (`authors_replay/`, and `authors_replay_edges/` whose model
adds 8 folded Gaussians past the frame's edges by more than their radius yet drawn by INRIA's
rasterizer in some frame and view, placed as `threshold_gaussians.py` places them):

  * `frames/0000.png` ... (3 frames of 64x48 or 70x52 RGBA, transparent, partly transparent and
    opaque pixels) and `model.ply`, a VeGaS model of 40 folded Gaussians in VeGaS's layout (some
    bright enough that renders exceed 1, some opaque enough that alpha reaches its cap, some too
    narrow in time to be drawn in every frame);
  * `reference.safetensors`: the colours (`sh_dc`) after 1 and after 10 updates;
  * `replay.json`: the test's tolerance and the float32 replay's own error.

The loop is CLIPGaussian's `Video/train_style.py` (PR #15) on VeGaS (gmum/VeGaS 7508bcc):
  * views: every frame from the camera at `-d` and its mirror image (`ImageOps.mirror`) from
    the camera at `+d` (`models/scenes/dataset_readers.py`), `camera_angle_x` 0.6911112070083618;
  * ground truth: RGBA over black in float64, then `np.array(arr * 255.0, dtype=np.byte)`;
  * frame `f` at time `sum(softmax(time_func)[:f])`; its Gaussians as VeGaS's `render()` builds
    them (means moved by the motion polynomial of `sigmoid(m) - t`, scales times
    `exp(-(sigmoid(m) - t)^2 / (2 exp(sigma)^2))` around a flat 1e-8, rotation about the plane's
    normal by `2 pi sigmoid(rot)`, the Gaussians with `delta <= 0.01` or a scale `<= 1e-4`
    left out), rendered by INRIA's rasterizer, **not clamped**;
  * the directional, patch and content losses (no background term), Adam (eps 1e-15) over the
    colours alone at `feature_lr`.
"""

import json
import math
import sys
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import save_file

sys.path.insert(0, str(Path(__file__).resolve().parent))
from authors_loop import (  # noqa: E402
    ROOT, StyleStep, ground_truth, inria_camera, load_tiny_models, rasterize, save_rgba_picture,
)
from threshold_gaussians import ALPHA_MIN, MARGIN, cat, decisions_have_margin, take  # noqa: E402

FIXTURES = ROOT / "crates" / "base-vegas" / "tests" / "fixtures"
# Each scene is a folder of its own with its own draws.json: the model's and the target's seeds,
# and how many Gaussians are placed past the frame's right or bottom edge by more than their
# radius yet inside a tile INRIA's `getRect` keeps (drawn by INRIA, in some frame and view).
SCENES = [
    dict(folder="authors_replay", seeds=(30, 31), edges=0),
    dict(folder="authors_replay_edges", seeds=(50, 51), edges=8),
]
CAMERA_ANGLE_X = 0.6911112070083618
DISTANCE = 1.0
FRAMES = 3
COUNT = 40
POLY = 7
FLAT = 1e-8
# The paper's video settings (our defaults): CLIPGaussian's code has feature_lr 0.025.
LAMBDAS = dict(directional=5.0, patch=90.0, content=0.5, background=0.0)
FEATURE_LR = 0.02
# Relative to the colours' update: our float32 run against this float64 replay.
TOLERANCE = 2e-4


def camera_c2w(distance):
    """VeGaS's `create_transform_matrix`: the plane y = 0 seen from y = distance."""
    s = float(np.sign(distance))
    return [[-s, 0.0, 0.0, 0.0], [0.0, 0.0, s, distance], [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, 1.0]]


def random_folded(gen, count, width, height, spread=1.8):
    """VeGaS's stored parameters (f32 values, as its PLY holds them), centred within `spread`
    times the half frame."""
    fx = width / (2 * math.tan(CAMERA_ANGLE_X / 2))
    top = DISTANCE * height / (2 * fx)
    right = top * width / height
    r = lambda *shape: torch.rand(*shape, generator=gen, dtype=torch.float64)
    n = lambda *shape: torch.randn(*shape, generator=gen, dtype=torch.float64)
    xyz = torch.stack([(r(count) - 0.5) * spread * right, torch.zeros(count),
                       (r(count) - 0.5) * spread * top], dim=1)
    g = dict(
        xyz=xyz,
        f_dc=n(count, 1, 3) * 0.6,
        opacity=r(count, 1) * 4 - 1,
        scaling=torch.log(r(count, 3) * 0.06 + 0.02),
        rotation=n(count, 1),
        m=n(count, 1),
        sigma=torch.log(r(count, 1) * 0.8 + 0.2),
        w1=n(count, 2 * POLY) * 0.05,
        time_func=n(FRAMES - 1) * 0.3,
    )
    g["f_dc"][:6] = 3.0  # colour 0.5 + 0.85: renders above 1
    g["opacity"][6:12] = 6.0  # sigmoid 0.9975: alpha reaches the 0.99 cap near the centre
    g["sigma"][12:18] = math.log(0.06)  # narrow in time: left out of some frames
    return {k: v.to(torch.float32).to(torch.float64) for k, v in g.items()}


def write_ply(path, g):
    n = g["xyz"].shape[0]
    columns = [g["xyz"], torch.zeros(n, 3, dtype=torch.float64), g["f_dc"][:, 0], g["opacity"],
               g["scaling"], g["rotation"], g["m"], g["sigma"], g["w1"]]
    data = torch.cat(columns, dim=1).numpy().astype("<f4")
    names = (["x", "y", "z", "nx", "ny", "nz"] + [f"f_dc_{i}" for i in range(3)] + ["opacity"]
             + [f"scale_{i}" for i in range(3)] + ["rot_0", "m_0", "sigma_0"]
             + [f"w1_{i}" for i in range(2 * POLY)])
    assert data.shape[1] == len(names)
    header = "ply\nformat binary_little_endian 1.0\n" + f"element vertex {n}\n"
    header += "".join(f"property float {name}\n" for name in names)
    header += "element time 1\n" + "".join(f"property float time_func_{i}\n" for i in range(FRAMES - 1))
    header += "end_header\n"
    times = g["time_func"].numpy().astype("<f4")
    path.write_bytes(header.encode("ascii") + data.tobytes() + times.tobytes())


def frame_gaussians(g, frame):
    """The Gaussians of `frame` as VeGaS's `render()` builds them, in INRIA's stored form
    (log-scales, quaternions) for `rasterize`; the colours stay linked to `g["f_dc"]`."""
    built, keep, _ = frame_all(g, frame)
    return take(built, keep)


def frame_all(g, frame):
    """Every Gaussian of `frame` built as `frame_gaussians`, whether VeGaS keeps it, and how
    far each of its culling tests is from its threshold (relative)."""
    t = torch.softmax(g["time_func"], dim=0)[:frame].sum()
    m = torch.sigmoid(g["m"][:, 0])
    u = (m - t)[:, None]
    xz = g["xyz"][:, [0, 2]]
    for i, w in enumerate(torch.chunk(g["w1"], chunks=POLY, dim=-1)):
        xz = xz + w * u ** (i + 1)
    means = torch.stack([xz[:, 0], torch.zeros_like(xz[:, 0]), xz[:, 1]], dim=1)
    width = torch.exp(g["sigma"][:, 0])
    delta = torch.exp(((m - t) ** 2 / width ** 2) / -2)[:, None]
    scale = torch.exp(g["scaling"])
    scales = delta * torch.stack([scale[:, 0], torch.full_like(scale[:, 0], FLAT), scale[:, 2]], dim=1)
    keep = (delta > 0.01).all(dim=1) & (scales[:, [0, 2]] > 1e-4).all(dim=1)
    angle = torch.sigmoid(g["rotation"][:, 0]) * 2 * torch.pi / 2
    zeros = torch.zeros_like(angle)
    quats = torch.stack([torch.cos(angle), zeros, torch.sin(angle), zeros], dim=1)
    f_rest = torch.zeros(g["f_dc"].shape[0], 15, 3, dtype=g["f_dc"].dtype)
    built = dict(xyz=means, f_dc=g["f_dc"], f_rest=f_rest, opacity=g["opacity"],
                 scaling=torch.log(scales), rotation=quats)
    margin = torch.minimum((delta[:, 0] / 0.01 - 1).abs(),
                           (scales[:, [0, 2]] / 1e-4 - 1).abs().min(dim=1).values)
    return built, keep, margin


def cameras_of(width, height):
    """The camera of the frames and the camera of their mirror images."""
    return [inria_camera(camera_c2w(d), width, height, CAMERA_ANGLE_X) for d in (-DISTANCE, DISTANCE)]


def edge_folded(gen, count, width, height):
    """`count` folded Gaussians that lie past the frame's right or bottom edge by more than
    their radius in some frame and view, where INRIA still draws them; every decision about
    them in every frame and view (VeGaS's culling included) keeps its margin."""
    n = 1024
    fx = width / (2 * math.tan(CAMERA_ANGLE_X / 2))
    top = DISTANCE * height / (2 * fx)
    right = top * width / height
    found = []
    for _ in range(60):
        g = random_folded(gen, n, width, height)
        # Centres up to 16 pixels past one of the four edges (each camera sees x mirrored).
        u = lambda: torch.rand(n, generator=gen, dtype=torch.float64)
        side = torch.randint(4, (n,), generator=gen)
        sign = torch.where(side % 2 == 0, 1.0, -1.0).double()
        across = u() * 16 / fx
        x = torch.where(side < 2, sign * (right + across), (u() - 0.5) * 2 * right)
        z = torch.where(side >= 2, sign * (top + across), (u() - 0.5) * 2 * top)
        g["xyz"] = torch.stack([x, torch.zeros(n, dtype=torch.float64), z], dim=1)
        g["scaling"] = torch.log(torch.stack([u(), u(), u()], dim=1) * 0.05 + 0.015)
        g["opacity"][:] = u()[:, None] * 3 + 4
        g = {k: v.to(torch.float32).to(torch.float64) for k, v in g.items()}
        ok = torch.ones(n, dtype=torch.bool)
        past_and_drawn = torch.zeros(n, dtype=torch.bool)
        for f in range(FRAMES):
            with torch.no_grad():
                built, keep, margin = frame_all(g, f)
            ok &= margin > MARGIN
            index = torch.nonzero(keep).flatten()
            for camera in cameras_of(width, height):
                fine, proj, alpha = decisions_have_margin(take(built, keep), camera)
                drawn = alpha.max(dim=1).values >= ALPHA_MIN * (1 + 3e-3)
                past = ((proj["px"] + 0.5 - proj["radius"] >= width)
                        | (proj["py"] + 0.5 - proj["radius"] >= height))
                ok[index] &= fine
                past_and_drawn[index] |= drawn & past
        g.pop("time_func")
        found.append(take(g, ok & past_and_drawn))
        if sum(p["xyz"].shape[0] for p in found) >= count:
            return take(cat(found), torch.arange(count))
    raise RuntimeError("no folded Gaussian past the frame's edges found")


def write_scene(scene, out, draws):
    width, height = draws["width"], draws["height"]
    gen = torch.Generator().manual_seed(scene["seeds"][0])
    model = random_folded(gen, COUNT, width, height)
    if scene["edges"]:
        edges = edge_folded(gen, scene["edges"], width, height)
        model = {k: torch.cat([v, edges[k]]) if k in edges else v for k, v in model.items()}
    write_ply(out / "model.ply", model)
    target = random_folded(torch.Generator().manual_seed(scene["seeds"][1]), COUNT, width, height)
    target["opacity"][:] = target["opacity"].clamp(max=2.0)
    target["f_dc"][:] = target["f_dc"].clamp(max=1.2)
    camera = cameras_of(width, height)[0]
    (out / "frames").mkdir(parents=True, exist_ok=True)
    for f in range(FRAMES):
        with torch.no_grad():
            rgb, alpha = rasterize(frame_gaussians(target, f), camera, torch.zeros(3, dtype=torch.float64))
        save_rgba_picture(rgb, alpha, out / "frames" / f"{f:04d}.png")
    return model


def replay(out, start, clip, vgg, draws, dtype):
    """The loop in `dtype`: the colours after update 1 and after the last."""
    width, height = draws["width"], draws["height"]
    background = torch.zeros(3, dtype=dtype)
    cameras = cameras_of(width, height)
    gts = [ground_truth(out / "frames" / f"{f:04d}.png", "composited", background.double(), mirror)
           for f in range(FRAMES) for mirror in (False, True)]
    step = StyleStep(clip, vgg, gts, draws["style_direction"], draws["patch_size"], LAMBDAS, dtype)
    g = {k: v.to(dtype).detach().clone() for k, v in start.items()}
    g["f_dc"].requires_grad_(True)
    optimizer = torch.optim.Adam([dict(params=[g["f_dc"]], lr=FEATURE_LR, name="f_dc")], lr=0.0,
                                 eps=1e-15)
    after = {}
    for iteration, drawn in enumerate(draws["steps"], start=1):
        view = drawn["view"]
        rgb, _ = rasterize(frame_gaussians(g, view // 2), cameras[view % 2], background)
        loss = step.loss(rgb, view, drawn["patches"])
        loss.backward()
        optimizer.step()
        optimizer.zero_grad(set_to_none=True)
        if iteration in (1, len(draws["steps"])):
            after[iteration] = g["f_dc"].detach().clone()
        print(f"({dtype}) iteration {iteration}: view {view} loss {loss.item():.6f} "
              f"render max {rgb.max().item():.3f}")
    return after


def main():
    torch.manual_seed(0)
    clip, vgg = load_tiny_models()
    for scene in SCENES:
        out = FIXTURES / scene["folder"]
        draws = json.load(open(out / "draws.json"))
        assert draws["views"] == 2 * FRAMES
        start = write_scene(scene, out, draws)
        exact = replay(out, start, clip, vgg, draws, torch.float64)
        single = replay(out, start, clip, vgg, draws, torch.float32)
        tensors, noise = {}, {}
        for iteration, f_dc in exact.items():
            key = f"after_{iteration}.sh_dc"
            tensors[key] = f_dc.reshape(-1, 3).contiguous()
            update = (f_dc - start["f_dc"]).norm().item()
            noise[key] = (single[iteration].double() - f_dc).norm().item() / update
        save_file(tensors, str(out / "reference.safetensors"))
        with open(out / "replay.json", "w") as f:
            json.dump(dict(tolerance=TOLERANCE, lambdas=LAMBDAS, feature_lr=FEATURE_LR,
                           float32_replay_error=noise), f, indent=1)
        total = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
        print(f"wrote {out} ({total / 1e3:.0f} kB)")


if __name__ == "__main__":
    main()
