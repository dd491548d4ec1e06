#!/usr/bin/env python3
"""Replay the authors' 3D stylization loop in float64 PyTorch: the fixture of
`crates/base-3dgs/tests/authors_replay.rs`.

How to run (from the repository root; PyTorch, transformers and torchvision from PyPI):

    python3 -m venv /tmp/replay-venv
    /tmp/replay-venv/bin/pip install torch torchvision transformers safetensors pillow \
        open_clip_torch
    cargo test -p base-3dgs --test authors_replay -- --ignored write_replay_draws
    /tmp/replay-venv/bin/python scripts/make_3d_replay_fixture.py

The first command writes `draws.json` (our run's view order, patch crops and warps, and text
direction); this script writes the rest of `crates/base-3dgs/tests/fixtures/authors_replay/`:

  * a tiny NeRF-synthetic scene: `scene.ply` (48 Gaussians of SH degree 3 in INRIA's layout, some
    bright enough that renders exceed 1, some opaque enough that alpha reaches its 0.99 cap) and
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
    backward differs: the gradient passes through the 0.99 cap as if unclamped;
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
from PIL import Image
from safetensors.torch import load_file, save_file
from torch import nn
from torchvision.models.vgg import make_layers
from transformers import CLIPModel

sys.path.insert(0, str(Path(__file__).resolve().parent))
from make_style_loss_fixtures import (  # noqa: E402
    CLIP_MEAN, CLIP_STD, TINY_VGG19_CFG, image_embeds, perspective, unit, vgg_features,
)
import torch.nn.functional as F  # noqa: E402
import torchvision.transforms.functional as TF  # noqa: E402
from torchvision.transforms import InterpolationMode  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "crates" / "base-3dgs" / "tests" / "fixtures" / "authors_replay"
STYLE_FIXTURES = ROOT / "crates" / "style-loss" / "tests" / "fixtures"
FOV_X = 0.9
SH_DEGREE = 3
COUNT = 48
TRAIN_VIEWS, TEST_VIEWS = 3, 2
TILE = 16
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

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = [1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
         0.5462742152960396]
SH_C3 = [-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435]


# --------------------------------------------------------------------------------------------
# Scene
# --------------------------------------------------------------------------------------------
def look_at_c2w(eye):
    """Blender camera-to-world (the camera looks along its -z, y up) looking at the origin."""
    eye = np.asarray(eye, dtype=np.float64)
    forward = -eye / np.linalg.norm(eye)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, up, -forward, eye
    return c2w


def camera_eyes():
    eyes = []
    for k in range(TRAIN_VIEWS + TEST_VIEWS):
        a = 2 * math.pi * k / (TRAIN_VIEWS + TEST_VIEWS) + 0.3
        eyes.append([3.2 * math.cos(a), 3.2 * math.sin(a), 0.4 + 0.5 * (k % 3)])
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


def write_scene(gen):
    """The model, the pictures (renders of another random set, with alpha) and the json files."""
    model = random_gaussians(gen, COUNT)
    write_ply(OUT / "scene.ply", model)
    target = random_gaussians(gen, COUNT)
    target["opacity"][:] = target["opacity"].clamp(max=2.0)
    width, height = DRAWS["width"], DRAWS["height"]
    data = OUT / "data"
    splits = {"train": [], "test": []}
    for k, eye in enumerate(camera_eyes()):
        split = "train" if k < TRAIN_VIEWS else "test"
        name = f"r_{len(splits[split])}"
        c2w = look_at_c2w(eye)
        camera = inria_camera(c2w, width, height)
        with torch.no_grad():
            rgb, alpha = rasterize(target, camera, torch.zeros(3, dtype=torch.float64))
        straight = (rgb / alpha.clamp(min=1e-12)).clamp(0, 1)
        a8 = torch.round(alpha * 255)
        rgb8 = torch.where(a8 > 0, torch.round(straight * 255), torch.zeros_like(straight))
        rgba = torch.cat([rgb8, a8[None]], dim=0).permute(1, 2, 0).numpy().astype(np.uint8)
        (data / split).mkdir(parents=True, exist_ok=True)
        Image.fromarray(rgba, "RGBA").save(data / split / f"{name}.png")
        splits[split].append(dict(file_path=f"./{split}/{name}", rotation=0.0,
                                  transform_matrix=c2w.tolist()))
    for split, frames in splits.items():
        with open(data / f"transforms_{split}.json", "w") as f:
            json.dump(dict(camera_angle_x=FOV_X, frames=frames), f, indent=1)


# --------------------------------------------------------------------------------------------
# INRIA's cameras and ground truth (scene/dataset_readers.py, utils/graphics_utils.py)
# --------------------------------------------------------------------------------------------
def inria_camera(c2w, width, height):
    c2w = np.array(c2w, dtype=np.float64)
    c2w[:3, 1:3] *= -1
    w2c = np.linalg.inv(c2w)
    fx = width / (2 * math.tan(FOV_X / 2))
    fov_y = 2 * math.atan(height / (2 * fx))
    return dict(w2c=torch.from_numpy(w2c), width=width, height=height,
                tan_x=math.tan(FOV_X / 2), tan_y=math.tan(fov_y / 2),
                center=torch.from_numpy(c2w[:3, 3].copy()))


def read_views():
    """Train then test frames (no --eval), each as INRIA reads it."""
    views = []
    for split in ("train", "test"):
        meta = json.load(open(OUT / "data" / f"transforms_{split}.json"))
        for frame in meta["frames"]:
            path = OUT / "data" / (frame["file_path"] + ".png")
            views.append(dict(path=path, c2w=frame["transform_matrix"]))
    return views


def scene_extent(cameras):
    """getNerfppNorm's radius: 1.1 x the largest distance of a camera centre from their mean."""
    centers = torch.stack([c["center"] for c in cameras])
    return 1.1 * (centers - centers.mean(0)).norm(dim=1).max().item()


def ground_truth(path, rule, background):
    image = Image.open(path)
    if rule == "file_colour":
        return torch.from_numpy(np.array(image)).permute(2, 0, 1)[:3].double() / 255.0
    norm = np.array(image.convert("RGBA")) / 255.0
    arr = norm[:, :, :3] * norm[:, :, 3:4] + background.numpy() * (1 - norm[:, :, 3:4])
    levels = np.array(arr * 255.0, dtype=np.byte).view(np.uint8)
    return torch.from_numpy(levels.copy()).permute(2, 0, 1).double() / 255.0


# --------------------------------------------------------------------------------------------
# INRIA's rasterizer (diff-gaussian-rasterization), dense, in float64
# --------------------------------------------------------------------------------------------
def build_rotation(q):
    q = q / q.norm(dim=1, keepdim=True)
    r, x, y, z = q.unbind(1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - r * z), 2 * (x * z + r * y),
        2 * (x * y + r * z), 1 - 2 * (x * x + z * z), 2 * (y * z - r * x),
        2 * (x * z - r * y), 2 * (y * z + r * x), 1 - 2 * (x * x + y * y),
    ], dim=1).view(-1, 3, 3)


def eval_sh(sh, d):
    """INRIA's utils/sh_utils.py eval_sh for degree 3; sh [N, 16, 3], d [N, 3] unit."""
    x, y, z = (d[:, i:i + 1] for i in range(3))
    xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
    basis = [
        SH_C0 * torch.ones_like(x), -SH_C1 * y, SH_C1 * z, -SH_C1 * x,
        SH_C2[0] * xy, SH_C2[1] * yz, SH_C2[2] * (2 * zz - xx - yy), SH_C2[3] * xz,
        SH_C2[4] * (xx - yy),
        SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * xy * z, SH_C3[2] * y * (4 * zz - xx - yy),
        SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy), SH_C3[4] * x * (4 * zz - xx - yy),
        SH_C3[5] * z * (xx - yy), SH_C3[6] * x * (xx - 3 * yy),
    ]
    return sum(b * sh[:, i] for i, b in enumerate(basis))


def capped_alpha(raw):
    """min(0.99, raw) whose gradient is raw's everywhere, as INRIA's backward computes it."""
    return raw - (raw - 0.99).clamp(min=0).detach()


def rasterize(g, cam, background):
    """`[3, H, W]` colour and `[H, W]` alpha of `g` (INRIA's stored parameters)."""
    dtype = g["xyz"].dtype
    w2c, width, height = cam["w2c"].to(dtype), cam["width"], cam["height"]
    tan_x, tan_y = cam["tan_x"], cam["tan_y"]
    fx, fy = width / (2 * tan_x), height / (2 * tan_y)
    xyz = g["xyz"]
    p_view = xyz @ w2c[:3, :3].T + w2c[:3, 3]
    tz = p_view[:, 2]
    # Projection: full_proj_transform with znear 0.01 / zfar 100 gives w = z and
    # x_ndc = x / (tan_x (z + 1e-7)); ndc2Pix(v, S) = ((v + 1) S - 1) / 2.
    p_w = 1.0 / (tz + 1e-7)
    px = ((p_view[:, 0] / tan_x * p_w + 1) * width - 1) * 0.5
    py = ((p_view[:, 1] / tan_y * p_w + 1) * height - 1) * 0.5
    # EWA: cov2D = J W Sigma W^T J^T + 0.3 I, Jacobian at x/z, y/z clamped to 1.3 tan.
    rot = build_rotation(g["rotation"])
    scale = torch.exp(g["scaling"])
    m = rot * scale[:, None, :]
    sigma = m @ m.transpose(1, 2)
    limx, limy = 1.3 * tan_x, 1.3 * tan_y
    tx = (p_view[:, 0] / tz).clamp(-limx, limx) * tz
    ty = (p_view[:, 1] / tz).clamp(-limy, limy) * tz
    zeros = torch.zeros_like(tz)
    jac = torch.stack([
        torch.stack([fx / tz, zeros, -fx * tx / tz ** 2], dim=1),
        torch.stack([zeros, fy / tz, -fy * ty / tz ** 2], dim=1),
    ], dim=1)
    t = jac @ w2c[:3, :3]
    cov = t @ sigma @ t.transpose(1, 2)
    a, b, c = cov[:, 0, 0] + 0.3, cov[:, 0, 1], cov[:, 1, 1] + 0.3
    det = a * c - b * b
    conic = torch.stack([c / det, -b / det, a / det], dim=1)
    with torch.no_grad():
        mid = 0.5 * (a + c)
        lam = mid + torch.sqrt(torch.clamp(mid * mid - det, min=0.1))
        radius = torch.ceil(3 * torch.sqrt(lam))
        grid_x, grid_y = (width + TILE - 1) // TILE, (height + TILE - 1) // TILE
        trunc = lambda v: torch.trunc(v)  # C's (int) cast
        x0 = trunc((px - radius) / TILE).clamp(0, grid_x)
        x1 = trunc((px + radius + TILE - 1) / TILE).clamp(0, grid_x)
        y0 = trunc((py - radius) / TILE).clamp(0, grid_y)
        y1 = trunc((py + radius + TILE - 1) / TILE).clamp(0, grid_y)
        visible = (tz > 0.2) & (det != 0) & ((x1 - x0) * (y1 - y0) > 0)
    # Colour from SH at the direction from the camera centre, + 0.5, clamped at 0.
    direction = xyz - cam["center"].to(dtype)
    direction = direction / direction.norm(dim=1, keepdim=True)
    sh = torch.cat([g["f_dc"], g["f_rest"]], dim=1)
    colour = torch.clamp_min(eval_sh(sh, direction) + 0.5, 0.0)
    opacity = torch.sigmoid(g["opacity"][:, 0])

    order = torch.sort(tz.detach(), stable=True).indices
    order = order[visible[order]]
    ys, xs = torch.meshgrid(torch.arange(height, dtype=dtype),
                            torch.arange(width, dtype=dtype), indexing="ij")
    pix_x, pix_y = xs.reshape(-1, 1), ys.reshape(-1, 1)
    tile_x, tile_y = torch.floor(pix_x / TILE), torch.floor(pix_y / TILE)
    in_rect = ((tile_x >= x0[order]) & (tile_x < x1[order])
               & (tile_y >= y0[order]) & (tile_y < y1[order]))
    dx, dy = px[order] - pix_x, py[order] - pix_y
    con = conic[order]
    power = -0.5 * (con[:, 0] * dx * dx + con[:, 2] * dy * dy) - con[:, 1] * dx * dy
    alpha = capped_alpha(opacity[order] * torch.exp(power))
    valid = in_rect & (power <= 0) & (alpha >= 1.0 / 255.0)
    alpha = torch.where(valid, alpha, torch.zeros_like(alpha))
    one_minus = 1 - alpha
    t_before = torch.cumprod(torch.cat([torch.ones_like(one_minus[:, :1]), one_minus[:, :-1]], 1), 1)
    stops = valid & (t_before * one_minus < 1e-4)
    keep = valid & (torch.cumsum(stops.to(torch.int64), dim=1) == 0)
    weight = torch.where(keep, alpha * t_before, torch.zeros_like(alpha))
    t_final = torch.where(keep, one_minus, torch.ones_like(one_minus)).prod(dim=1)
    rgb = weight @ colour[order] + t_final[:, None] * background
    return rgb.T.reshape(3, height, width), (1 - t_final).reshape(height, width)


# --------------------------------------------------------------------------------------------
# The loop (3D/train_style.py)
# --------------------------------------------------------------------------------------------
def clip_normalize(image, size):
    """The authors' clip_normalize (bicubic squash to the model's size, CLIP's mean and std)
    in the image's precision."""
    image = F.interpolate(image, size=size, mode="bicubic")
    return (image - CLIP_MEAN.to(image.dtype)) / CLIP_STD.to(image.dtype)


def load_tiny_models():
    clip = CLIPModel.from_pretrained(str(STYLE_FIXTURES / "tiny_clip")).double().eval()
    vgg = nn.Sequential(*make_layers(TINY_VGG19_CFG))
    weights = load_file(str(STYLE_FIXTURES / "tiny_vgg19.safetensors"))
    vgg.load_state_dict({k.removeprefix("features."): v for k, v in weights.items()})
    for p in list(clip.parameters()) + list(vgg.parameters()):
        p.requires_grad_(False)
    return clip, vgg.double().eval()


def expon_lr(step, lr_init, lr_final, max_steps):
    t = np.clip(step / max_steps, 0, 1)
    return float(np.exp(np.log(lr_init) * (1 - t) + np.log(lr_final) * t))


def replay(variant, start, clip, vgg, dtype):
    """The loop in `dtype`: every parameter after update 1 and after the last."""
    clip, vgg = clip.to(dtype), vgg.to(dtype)
    background = torch.tensor([1.0, 1.0, 1.0] if variant["white_background"] else [0.0] * 3,
                              dtype=dtype)
    views = read_views()
    cameras = [inria_camera(v["c2w"], DRAWS["width"], DRAWS["height"]) for v in views]
    extent = scene_extent(cameras)
    size = clip.config.vision_config.image_size
    gts, clip_gt, vgg_gt = [], [], []
    with torch.no_grad():
        for v in views:
            gt = ground_truth(v["path"], variant["ground_truth"], background.double()).to(dtype)
            gts.append(gt)
            clip_gt.append(unit(image_embeds(clip, clip_normalize(gt[None], size))))
            vgg_gt.append(vgg_features(vgg, gt[None]))
    params = {k: v.to(dtype).detach().clone().requires_grad_(True) for k, v in start.items()}
    group_lr = dict(xyz=RATES["position_lr_init"] * extent, f_dc=RATES["feature_lr"],
                    f_rest=RATES["feature_lr"] / 20.0, opacity=RATES["opacity_lr"],
                    scaling=RATES["scaling_lr"], rotation=RATES["rotation_lr"])
    optimizer = torch.optim.Adam([dict(params=[params[k]], lr=lr, name=k) for k, lr in group_lr.items()],
                                 lr=0.0, eps=1e-15)
    direction = torch.tensor(DRAWS["style_direction"], dtype=dtype)
    patch = DRAWS["patch_size"]
    after = {}
    for iteration, step in enumerate(DRAWS["steps"], start=1):
        for group in optimizer.param_groups:
            if group["name"] == "xyz":
                group["lr"] = expon_lr(iteration, RATES["position_lr_init"] * extent,
                                       RATES["position_lr_final"] * extent,
                                       RATES["position_lr_max_steps"])
        view = step["view"]
        rgb, _ = rasterize(params, cameras[view], background)
        image = rgb.clamp(0, 1)
        gt = gts[view]
        f4, f5 = vgg_features(vgg, image[None])
        loss_c = ((vgg_gt[view][0] - f4) ** 2).mean() + ((vgg_gt[view][1] - f5) ** 2).mean()
        crops = []
        for p in step["patches"]:
            crop = image[None, :, p["top"]:p["top"] + patch, p["left"]:p["left"] + patch]
            warped = perspective(crop, p["corners"])
            crops.append(TF.resize(warped, [size], interpolation=InterpolationMode.BILINEAR,
                                   antialias=True))
        features = unit(image_embeds(clip, clip_normalize(torch.cat(crops), size)))
        d = unit(features - clip_gt[view])
        loss_patch = (1 - torch.cosine_similarity(d, direction.repeat(len(crops), 1), dim=1)).mean()
        if variant["object"]:
            color_sum = gt.to(torch.float32).sum(0)  # the authors' CUDA tensors are float32
            mask = color_sum == background.to(torch.float32).sum()
            loss_bg = (image - gt).abs().mean(0)[mask].mean()
        else:
            loss_bg = 0.0
        features = unit(image_embeds(clip, clip_normalize(image[None], size)))
        d = unit(features - clip_gt[view])
        loss_d = (1 - torch.cosine_similarity(d, direction[None], dim=1)).mean()
        loss = (LAMBDAS["directional"] * loss_d + LAMBDAS["patch"] * loss_patch
                + LAMBDAS["content"] * loss_c + LAMBDAS["background"] * loss_bg)
        loss.backward()
        optimizer.step()
        optimizer.zero_grad(set_to_none=True)
        if iteration in (1, len(DRAWS["steps"])):
            after[iteration] = {k: v.detach().clone() for k, v in params.items()}
        print(f"{variant['name']} ({dtype}) iteration {iteration}: view {view} loss {loss.item():.6f} "
              f"render max {rgb.max().item():.3f}")
    return after


# Our names and layouts of INRIA's groups (sh_rest [N, 15, 3] flattened as stored).
OUR_NAMES = dict(xyz="means", f_dc="sh_dc", f_rest="sh_rest", opacity="opacity_logits",
                 scaling="log_scales", rotation="quats")


def main():
    torch.manual_seed(0)
    gen = torch.Generator().manual_seed(20)
    OUT.mkdir(parents=True, exist_ok=True)
    write_scene(gen)
    start = random_gaussians(torch.Generator().manual_seed(20), COUNT)
    clip, vgg = load_tiny_models()
    tensors, noise = {}, {}
    for variant in VARIANTS:
        exact = replay(variant, start, clip, vgg, torch.float64)
        single = replay(variant, start, clip, vgg, torch.float32)
        for iteration, params in exact.items():
            key = f"{variant['name']}.after_{iteration}"
            for k, v in params.items():
                tensors[f"{key}.{OUR_NAMES[k]}"] = v.reshape(v.shape[0], -1)
                update = (v - start[k]).norm().item()
                noise[f"{key}.{OUR_NAMES[k]}"] = (single[iteration][k].double() - v).norm().item() / update
    save_file({k: v.contiguous() for k, v in tensors.items()}, str(OUT / "reference.safetensors"))
    with open(OUT / "replay.json", "w") as f:
        json.dump(dict(variants=VARIANTS, tolerance=TOLERANCE, lambdas=LAMBDAS, rates=RATES,
                       float32_replay_error=noise), f, indent=1)
    total = sum(p.stat().st_size for p in OUT.rglob("*") if p.is_file())
    print(f"wrote {OUT} ({total / 1e3:.0f} kB)")


DRAWS = json.load(open(OUT / "draws.json"))

if __name__ == "__main__":
    main()
