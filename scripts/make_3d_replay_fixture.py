#!/usr/bin/env python3
"""Replay the authors' 3D stylization loop in float64 PyTorch: the fixture of
`crates/base-3dgs/tests/authors_replay.rs`.

How to run (from the repository root; PyTorch, transformers and torchvision from PyPI):

    python3 -m venv /tmp/replay-venv
    /tmp/replay-venv/bin/pip install torch torchvision transformers safetensors pillow \
        open_clip_torch
    cargo test -p base-3dgs --test authors_replay -- --ignored write_replay_draws
    /tmp/replay-venv/bin/python scripts/make_3d_replay_fixture.py

The first command writes each scene's `draws.json` (our run's view order, patch crops and
warps, and text direction); this script writes the rest of each scene's folder in
`crates/base-3dgs/tests/fixtures/` (`SCENES` below):

  * a tiny NeRF-synthetic scene: `scene.ply` (48 Gaussians of SH degree 3 in INRIA's layout, some
    bright enough that renders exceed 1, some opaque enough that alpha reaches its 0.99 cap; in
    the `edges` scenes 39 more, at INRIA's rasterizer's thresholds for each camera) and
    `data/` (3 train and 2 test views, 64x48 RGBA pictures with transparent, partly transparent
    and opaque pixels);
  * `reference.safetensors`: every parameter group after 1 and after 10 updates of the loop;
  * `replay.json`: the variants replayed and the test's tolerance.

The loop is CLIPGaussian's `3D/train_style.py` (commit 1411e8d) on INRIA's gaussian-splatting
at the commit its install script pins (54c035f), transcribed here:
  * views: train and test cameras (no `--eval`); scene extent from both (`getNerfppNorm`);
  * ground truth: the stored colours / 255 (`utils/camera_utils.py`, `scene/cameras.py`), or, in
    the `composited` variant, INRIA's earlier loader (RGBA over the background in float64, then
    `np.array(arr * 255.0, dtype=np.byte)`);
  * render: INRIA's `diff-gaussian-rasterization` forward (near plane 0.2, EWA with the 1.3 tan
    Jacobian clamp and 0.3 low-pass, radius `ceil(3 sqrt(mid + sqrt(max(0.1, mid^2 - det))))`,
    tile rectangles in INRIA's pixel coordinates, alpha `min(0.99, o G)` skipped below 1/255,
    stop before transmittance 1e-4), differentiated by autograd except where INRIA's hand-written
    backward differs: the gradient passes through the 0.99 cap as if unclamped, a clamped
    Jacobian's `t.x` counts as independent of `t.z`, and the conic's gradient has
    `1 / (det^2 + 1e-7)` (`authors_loop.project`);
  * `rendered_image.clamp(0, 1)`, then the four losses of `train_style.py` (the patch draws are
    ours, given);
  * Adam (eps 1e-15) over xyz, f_dc, f_rest, opacity, scaling, rotation with INRIA's rates; the
    xyz rate `get_expon_lr_func(...)(iteration)` with the 1-based iteration before each step.
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
    ROOT, StyleStep, ground_truth, inria_camera, load_tiny_models, look_at_c2w, rasterize,
    save_rgba_picture,
)
from threshold_gaussians import placed, stacked  # noqa: E402

FIXTURES = ROOT / "crates" / "base-3dgs" / "tests" / "fixtures"
FOV_X = 0.9
COUNT = 48
# Each scene is a folder of its own, with its own draws.json. The second has odd sizes (partial
# tiles), closer cameras, and two Gaussians in front of the first camera: one at depth 0.1
# (inside INRIA's near plane 0.2: never drawn), one at depth 0.35 (drawn large). The last two
# add, for every camera, Gaussians at the rules that decide what INRIA draws
# (`make_raster_thresholds_fixture.py`'s kinds: past the right and bottom edges yet in a kept
# tile, near the left edge, tiny at window and tile edges, alpha just above and just below
# 1/255), and a stack in front of the first camera where pixels stop at transmittance 1e-4.
SCENES = [
    dict(folder="authors_replay", seed=20, radius=3.2, near_camera=False, edges=False),
    dict(folder="authors_replay_odd", seed=40, radius=2.4, near_camera=True, edges=False),
    dict(folder="authors_replay_edges", seed=60, radius=3.2, near_camera=False, edges=True),
    dict(folder="authors_replay_edges_odd", seed=61, radius=2.8, near_camera=False, edges=True),
]
# Gaussians placed per camera in the scenes with `edges`.
EDGE_KINDS = dict(past_right_edge=1, past_bottom_edge=1, near_left_edge=1, tiny=2, alpha_above=1,
                  alpha_below=1)
# The largest alpha of the `alpha_above` and `alpha_below` Gaussians: 1/255 (1 +- 0.5). A
# Gaussian drawn at all whose peak is within 3e-3 of 1/255 (as in make_raster_thresholds_fixture.py)
# has, once Adam moves it, pixels so close to 1/255 that float32 rounding decides them: its peak
# is flat, so a small change of its opacity takes many pixels across at once.
ALPHA_MARGIN = 0.5
# Opaque Gaussians stacked in front of the first camera, where pixels stop at transmittance 1e-4.
STACK = 4
TRAIN_VIEWS, TEST_VIEWS = 3, 2
# CLIPGaussian 3D/arguments/__init__.py (OptimizationParams) and INRIA's training_setup.
LAMBDAS = dict(directional=5.0, patch=90.0, content=0.8, background=1000.0)
RATES = dict(position_lr_init=1e-4, position_lr_final=1e-6, position_lr_max_steps=30_000,
             feature_lr=0.01, opacity_lr=0.05, scaling_lr=0.005, rotation_lr=0.001)
VARIANTS = [
    dict(name="authors_default", white_background=False, ground_truth="file_colour", object=False),
    dict(name="composited_white_object", white_background=True, ground_truth="composited",
         object=True),
]
# Relative to each group's update: our float32 run against this float64 replay. The same loop
# run here in float32 ends within 4.5e-5 of the float64 one (`float32_replay_error` in
# replay.json); INRIA's tile rectangles alone move it by 3e-3, its alpha-cap gradient by 0.4.
TOLERANCE = 2e-4


# --------------------------------------------------------------------------------------------
# Scene
# --------------------------------------------------------------------------------------------
def camera_eyes(radius):
    eyes = []
    for k in range(TRAIN_VIEWS + TEST_VIEWS):
        a = 2 * math.pi * k / (TRAIN_VIEWS + TEST_VIEWS) + 0.3
        eyes.append([radius * math.cos(a), radius * math.sin(a), 0.4 + 0.5 * (k % 3)])
    return eyes


def random_gaussians(gen, count):
    """INRIA's stored parameters (f32 values, as a PLY holds them)."""
    g = dict(
        xyz=(torch.rand(count, 3, generator=gen, dtype=torch.float64) - 0.5) * 1.6,
        f_dc=torch.randn(count, 1, 3, generator=gen, dtype=torch.float64) * 0.6,
        f_rest=torch.randn(count, 15, 3, generator=gen, dtype=torch.float64) * 0.15,
        opacity=torch.rand(count, 1, generator=gen, dtype=torch.float64) * 4 - 1,
        scaling=torch.log(torch.rand(count, 3, generator=gen, dtype=torch.float64) * 0.2 + 0.06),
        rotation=torch.randn(count, 4, generator=gen, dtype=torch.float64),
    )
    g["f_dc"][:8] = 3.0  # colour 0.5 + 0.85: renders above 1
    g["opacity"][8:16] = 6.0  # sigmoid 0.9975: alpha reaches the 0.99 cap near the centre
    return g


def scene_gaussians(scene, gen, width, height):
    """The scene's model (f32 values, as its PLY holds them)."""
    g = random_gaussians(gen, COUNT)
    if scene["edges"]:
        parts = [g]
        for eye in camera_eyes(scene["radius"]):
            camera = inria_camera(look_at_c2w(eye), width, height, FOV_X)
            for kind, count in EDGE_KINDS.items():
                parts.append(placed(gen, camera, kind, count, alpha_margin=ALPHA_MARGIN))
        first = inria_camera(look_at_c2w(camera_eyes(scene["radius"])[0]), width, height, FOV_X)
        parts.append(stacked(gen, first, STACK))
        g = {k: torch.cat([p[k] for p in parts]) for k in g}
    if scene["near_camera"]:
        eye = np.array(camera_eyes(scene["radius"])[0])
        forward = torch.from_numpy(-eye / np.linalg.norm(eye))
        right = torch.from_numpy(np.cross(-eye / np.linalg.norm(eye), [0.0, 0.0, 1.0]))
        for k, (depth, side) in enumerate([(0.1, 0.0), (0.35, 0.05)]):
            g["xyz"][20 + k] = torch.from_numpy(eye) + depth * forward + side * right
            # Anisotropic: an isotropic Gaussian's rotation gradient is pure rounding noise,
            # which Adam's first steps turn into full steps of either sign.
            g["scaling"][20 + k] = torch.log(torch.tensor([0.02, 0.035, 0.015], dtype=torch.float64))
    return {k: v.to(torch.float32).to(torch.float64) for k, v in g.items()}


def write_ply(path, g):
    n = g["xyz"].shape[0]
    columns = [g["xyz"], torch.zeros(n, 3, dtype=torch.float64), g["f_dc"].transpose(1, 2).flatten(1),
               g["f_rest"].transpose(1, 2).flatten(1), g["opacity"], g["scaling"], g["rotation"]]
    data = torch.cat(columns, dim=1).numpy().astype("<f4")
    names = (["x", "y", "z", "nx", "ny", "nz"] + [f"f_dc_{i}" for i in range(3)]
             + [f"f_rest_{i}" for i in range(45)] + ["opacity"] + [f"scale_{i}" for i in range(3)]
             + [f"rot_{i}" for i in range(4)])
    assert data.shape[1] == len(names)
    header = "ply\nformat binary_little_endian 1.0\n" + f"element vertex {n}\n"
    header += "".join(f"property float {name}\n" for name in names) + "end_header\n"
    path.write_bytes(header.encode("ascii") + data.tobytes())


def write_scene(scene, draws):
    """The model, the pictures (renders of another random set, with alpha) and the json files."""
    out = FIXTURES / scene["folder"]
    gen = torch.Generator().manual_seed(scene["seed"])
    width, height = draws["width"], draws["height"]
    model = scene_gaussians(scene, gen, width, height)
    write_ply(out / "scene.ply", model)
    target = {k: v.to(torch.float32).to(torch.float64) for k, v in random_gaussians(gen, COUNT).items()}
    target["opacity"][:] = target["opacity"].clamp(max=2.0)
    data = out / "data"
    splits = {"train": [], "test": []}
    for k, eye in enumerate(camera_eyes(scene["radius"])):
        split = "train" if k < TRAIN_VIEWS else "test"
        name = f"r_{len(splits[split])}"
        c2w = look_at_c2w(eye)
        camera = inria_camera(c2w, width, height, FOV_X)
        with torch.no_grad():
            rgb, alpha = rasterize(target, camera, torch.zeros(3, dtype=torch.float64))
        (data / split).mkdir(parents=True, exist_ok=True)
        save_rgba_picture(rgb, alpha, data / split / f"{name}.png")
        splits[split].append(dict(file_path=f"./{split}/{name}", rotation=0.0,
                                  transform_matrix=c2w.tolist()))
    for split, frames in splits.items():
        with open(data / f"transforms_{split}.json", "w") as f:
            json.dump(dict(camera_angle_x=FOV_X, frames=frames), f, indent=1)


def read_views(out):
    """Train then test frames (no --eval), each as INRIA reads it."""
    views = []
    for split in ("train", "test"):
        meta = json.load(open(out / "data" / f"transforms_{split}.json"))
        for frame in meta["frames"]:
            path = out / "data" / (frame["file_path"] + ".png")
            views.append(dict(path=path, c2w=frame["transform_matrix"]))
    return views


def scene_extent(cameras):
    """getNerfppNorm's radius: 1.1 x the largest distance of a camera centre from their mean."""
    centers = torch.stack([c["center"] for c in cameras])
    return 1.1 * (centers - centers.mean(0)).norm(dim=1).max().item()


# --------------------------------------------------------------------------------------------
# The loop (3D/train_style.py)
# --------------------------------------------------------------------------------------------
def expon_lr(step, lr_init, lr_final, max_steps):
    t = np.clip(step / max_steps, 0, 1)
    return float(np.exp(np.log(lr_init) * (1 - t) + np.log(lr_final) * t))


def replay(out, variant, start, clip, vgg, draws, dtype):
    """The loop in `dtype`: every parameter after update 1 and after the last."""
    background = torch.tensor([1.0, 1.0, 1.0] if variant["white_background"] else [0.0] * 3,
                              dtype=dtype)
    views = read_views(out)
    cameras = [inria_camera(v["c2w"], draws["width"], draws["height"], FOV_X) for v in views]
    extent = scene_extent(cameras)
    gts = [ground_truth(v["path"], variant["ground_truth"], background.double()) for v in views]
    step = StyleStep(clip, vgg, gts, draws["style_direction"], draws["patch_size"], LAMBDAS, dtype)
    params = {k: v.to(dtype).detach().clone().requires_grad_(True) for k, v in start.items()}
    group_lr = dict(xyz=RATES["position_lr_init"] * extent, f_dc=RATES["feature_lr"],
                    f_rest=RATES["feature_lr"] / 20.0, opacity=RATES["opacity_lr"],
                    scaling=RATES["scaling_lr"], rotation=RATES["rotation_lr"])
    optimizer = torch.optim.Adam([dict(params=[params[k]], lr=lr, name=k) for k, lr in group_lr.items()],
                                 lr=0.0, eps=1e-15)
    after = {}
    for iteration, drawn in enumerate(draws["steps"], start=1):
        for group in optimizer.param_groups:
            if group["name"] == "xyz":
                group["lr"] = expon_lr(iteration, RATES["position_lr_init"] * extent,
                                       RATES["position_lr_final"] * extent,
                                       RATES["position_lr_max_steps"])
        view = drawn["view"]
        rgb, _ = rasterize(params, cameras[view], background)
        image = rgb.clamp(0, 1)
        loss = step.loss(image, view, drawn["patches"], background if variant["object"] else None)
        loss.backward()
        optimizer.step()
        optimizer.zero_grad(set_to_none=True)
        if iteration in (1, len(draws["steps"])):
            after[iteration] = {k: v.detach().clone() for k, v in params.items()}
        print(f"{variant['name']} ({dtype}) iteration {iteration}: view {view} "
              f"loss {loss.item():.6f} render max {rgb.max().item():.3f}")
    return after


# Our names and layouts of INRIA's groups (sh_rest [N, 15, 3] flattened as stored).
OUR_NAMES = dict(xyz="means", f_dc="sh_dc", f_rest="sh_rest", opacity="opacity_logits",
                 scaling="log_scales", rotation="quats")


def main():
    torch.manual_seed(0)
    clip, vgg = load_tiny_models()
    for scene in SCENES:
        out = FIXTURES / scene["folder"]
        draws = json.load(open(out / "draws.json"))
        write_scene(scene, draws)
        start = scene_gaussians(scene, torch.Generator().manual_seed(scene["seed"]),
                                draws["width"], draws["height"])
        tensors, noise = {}, {}
        for variant in VARIANTS:
            exact = replay(out, variant, start, clip, vgg, draws, torch.float64)
            single = replay(out, variant, start, clip, vgg, draws, torch.float32)
            for iteration, params in exact.items():
                key = f"{variant['name']}.after_{iteration}"
                for k, v in params.items():
                    tensors[f"{key}.{OUR_NAMES[k]}"] = v.reshape(v.shape[0], -1)
                    update = (v - start[k]).norm().item()
                    noise[f"{key}.{OUR_NAMES[k]}"] = (single[iteration][k].double() - v).norm().item() / update
        save_file({k: v.contiguous() for k, v in tensors.items()}, str(out / "reference.safetensors"))
        with open(out / "replay.json", "w") as f:
            json.dump(dict(variants=VARIANTS, tolerance=TOLERANCE, lambdas=LAMBDAS, rates=RATES,
                           float32_replay_error=noise), f, indent=1)
        total = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
        print(f"wrote {out} ({total / 1e3:.0f} kB)")


if __name__ == "__main__":
    main()
