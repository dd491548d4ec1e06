#!/usr/bin/env python3
"""PyTorch baseline for docs/benchmarks.md (section style-loss): the authors' loss step
(3D/train_style.py) at paper settings with random weights, timed per term on this machine.

How to run (PyPI only): pip install torch torchvision transformers, then
    python3 scripts/time_style_loss_torch.py [threads] [repeats] [cpu|cuda] [f32|f16]
It mirrors `cargo run -p style-loss --release --example style_loss_timing`: ViT-B/32-sized CLIP
vision tower, VGG-19 up to conv5_2, one 800x800 render, 64 patches of 128. The device defaults to
the cpu and CLIP's precision to f32; `cuda f16` is the authors' setting (CLIP in fp16 on the GPU).
STYLE_LOSS_SIZE and STYLE_LOSS_PATCHES set the render's side and the patches (as for the example).
"""

import os
import sys
import time

import torch
import torch.nn.functional as F
from torchvision import transforms
from torchvision.models import vgg19
from transformers import CLIPVisionConfig, CLIPVisionModelWithProjection

torch.set_num_threads(int(sys.argv[1]) if len(sys.argv) > 1 else torch.get_num_threads())
REPEATS = int(sys.argv[2]) if len(sys.argv) > 2 else 1
DEVICE = torch.device(sys.argv[3] if len(sys.argv) > 3 else "cpu")
SIDE = int(os.environ.get("STYLE_LOSS_SIZE", "800"))
PATCHES = int(os.environ.get("STYLE_LOSS_PATCHES", "64"))
CLIP_DTYPE = {"f32": torch.float32, "f16": torch.float16}[sys.argv[4] if len(sys.argv) > 4 else "f32"]
MEAN = torch.tensor([0.48145466, 0.4578275, 0.40821073], device=DEVICE).view(1, 3, 1, 1)
STD = torch.tensor([0.26862954, 0.26130258, 0.27577711], device=DEVICE).view(1, 3, 1, 1)
IN_MEAN = torch.tensor([0.485, 0.456, 0.406], device=DEVICE).view(1, 3, 1, 1)
IN_STD = torch.tensor([0.229, 0.224, 0.225], device=DEVICE).view(1, 3, 1, 1)

clip = CLIPVisionModelWithProjection(CLIPVisionConfig(hidden_act="quick_gelu", projection_dim=512))
clip = clip.eval().to(DEVICE, CLIP_DTYPE)
vgg = vgg19().features[:32].eval().to(DEVICE)
for p in list(clip.parameters()) + list(vgg.parameters()):
    p.requires_grad_(False)


def encode(x):
    x = (F.interpolate(x, size=224, mode="bicubic") - MEAN) / STD
    e = clip(pixel_values=x.to(CLIP_DTYPE)).image_embeds.float()
    return e / e.norm(dim=-1, keepdim=True)


def features(x):
    x = (x - IN_MEAN) / IN_STD
    out = {}
    for i, layer in enumerate(vgg):
        x = layer(x)
        if i in (22, 31):
            out[i] = x
    return out


cropper = transforms.RandomCrop(128)
augment = transforms.Compose([transforms.RandomPerspective(fill=0, p=1, distortion_scale=0.5), transforms.Resize(224)])
gt = torch.rand(1, 3, SIDE, SIDE, device=DEVICE)
gt[:, :, :100] = 1.0
direction = F.normalize(torch.randn(1, 512, device=DEVICE), dim=-1)
with torch.no_grad():
    gt_embed = encode(gt)
    gt_feat = features(gt)


def step(d, p, c, b):
    render = torch.rand(1, 3, SIDE, SIDE, device=DEVICE, requires_grad=True)
    loss = 0
    if c:
        f = features(render)
        loss = loss + c * (((f[22] - gt_feat[22]) ** 2).mean() + ((f[31] - gt_feat[31]) ** 2).mean())
    if p:
        crops = torch.cat([augment(cropper(render)) for _ in range(PATCHES)])
        dirs = F.normalize(encode(crops) - gt_embed, dim=-1)
        loss = loss + p * (1 - torch.cosine_similarity(dirs, direction.repeat(PATCHES, 1), dim=1)).mean()
    if b:
        mask = gt[0].sum(0) == 3.0
        loss = loss + b * (render - gt).abs().mean(dim=1)[0][mask].mean()
    if d:
        dirs = F.normalize(encode(render) - gt_embed, dim=-1)
        loss = loss + d * (1 - torch.cosine_similarity(dirs, direction, dim=1)).mean()
    loss.backward()


def synchronize():
    if DEVICE.type == "cuda":
        torch.cuda.synchronize()


print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, {DEVICE}, CLIP {CLIP_DTYPE}")
for name, w in [("directional", (5, 0, 0, 0)), ("patch", (0, 90, 0, 0)), ("content", (0, 0, 0.8, 0)),
                ("background", (0, 0, 0, 1000)), ("all four terms", (5, 90, 0.8, 1000))]:
    best = float("inf")
    for _ in range(REPEATS):
        synchronize()
        start = time.perf_counter()
        step(*w)
        synchronize()
        best = min(best, time.perf_counter() - start)
    print(f"| {name} | {best:.4f} |")
