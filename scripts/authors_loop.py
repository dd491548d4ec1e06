"""The authors' training step, shared by the replay fixtures of the 3D and video loops
(`make_3d_replay_fixture.py`, `make_video_replay_fixture.py`): INRIA's rasterizer
(`graphdeco-inria/diff-gaussian-rasterization`, which CLIPGaussian's 3D code and VeGaS both
render with) transcribed densely in PyTorch, INRIA's cameras and ground-truth loaders, the tiny
CLIP and VGG-19 of the tests, and the losses of CLIPGaussian's `train_style.py`.

Not a script: imported by the two above (run them from the repository root).
"""

import math
import sys
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
import torchvision.transforms.functional as TF
from PIL import Image
from safetensors.torch import load_file
from torch import nn
from torchvision.models.vgg import make_layers
from torchvision.transforms import InterpolationMode
from transformers import CLIPModel

sys.path.insert(0, str(Path(__file__).resolve().parent))
from make_style_loss_fixtures import (  # noqa: E402
    CLIP_MEAN, CLIP_STD, TINY_VGG19_CFG, image_embeds, perspective, unit, vgg_features,
)

ROOT = Path(__file__).resolve().parent.parent
STYLE_FIXTURES = ROOT / "crates" / "style-loss" / "tests" / "fixtures"
TILE = 16

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = [1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
         0.5462742152960396]
SH_C3 = [-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435]



# --------------------------------------------------------------------------------------------
# INRIA's cameras and ground truth (scene/dataset_readers.py, utils/graphics_utils.py)
# --------------------------------------------------------------------------------------------
def inria_camera(c2w, width, height, fov_x):
    """A NeRF camera-to-world (OpenGL axes) as INRIA's loader turns it into a camera."""
    c2w = np.array(c2w, dtype=np.float64)
    c2w[:3, 1:3] *= -1
    w2c = np.linalg.inv(c2w)
    fx = width / (2 * math.tan(fov_x / 2))
    fov_y = 2 * math.atan(height / (2 * fx))
    return dict(w2c=torch.from_numpy(w2c), width=width, height=height,
                tan_x=math.tan(fov_x / 2), tan_y=math.tan(fov_y / 2),
                center=torch.from_numpy(c2w[:3, 3].copy()))


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


def ground_truth(path, rule, background, mirror=False):
    """`[3, H, W]` in float64: `file_colour`, the stored colours / 255 (INRIA since August 2024);
    `composited`, RGBA over `background` in float64 cut to 8 bits by
    `np.array(arr * 255.0, dtype=np.byte)` (INRIA before, VeGaS, MiraGe, D-MiSo). `mirror`: the
    picture flipped left to right first (`ImageOps.mirror`, VeGaS's mirror views)."""
    image = Image.open(path)
    if mirror:
        image = image.transpose(Image.Transpose.FLIP_LEFT_RIGHT)
    if rule == "file_colour":
        return torch.from_numpy(np.array(image)).permute(2, 0, 1)[:3].double() / 255.0
    norm = np.array(image.convert("RGBA")) / 255.0
    arr = norm[:, :, :3] * norm[:, :, 3:4] + background.numpy() * (1 - norm[:, :, 3:4])
    levels = np.array(arr * 255.0, dtype=np.byte).view(np.uint8)
    return torch.from_numpy(levels.copy()).permute(2, 0, 1).double() / 255.0


def save_rgba_picture(rgb, alpha, path):
    """Saves a render over black (`[3, H, W]` premultiplied colour, `[H, W]` alpha) as an 8-bit
    RGBA PNG with straight colours, as Blender writes NeRF-synthetic pictures: transparent pixels
    stored black."""
    straight = (rgb / alpha.clamp(min=1e-12)).clamp(0, 1)
    a8 = torch.round(alpha * 255)
    rgb8 = torch.where(a8 > 0, torch.round(straight * 255), torch.zeros_like(straight))
    rgba = torch.cat([rgb8, a8[None]], dim=0).permute(1, 2, 0).numpy().astype(np.uint8)
    Image.fromarray(rgba, "RGBA").save(path)


# --------------------------------------------------------------------------------------------
# INRIA's rasterizer (diff-gaussian-rasterization), dense
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


def project(g, cam):
    """INRIA's `preprocessCUDA` for every Gaussian of `g` (its stored parameters): pixel
    position `px, py` (INRIA's pixel coordinates, centres at integers), `conic`, `radius`, tile
    rectangle `x0, x1, y0, y1`, `visible` (not culled), `colour`, `opacity`, depth `tz`."""
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
    # INRIA's backward (`computeCov2DCUDA`) takes a clamped t.x as independent of tz in
    # `dL_dtz`: the Jacobian's t.x, t.y detached where clamped.
    ux, uy = p_view[:, 0] / tz, p_view[:, 1] / tz
    tx = torch.where((ux < -limx) | (ux > limx), tx.detach(), tx)
    ty = torch.where((uy < -limy) | (uy > limy), ty.detach(), ty)
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
    # INRIA's backward of the conic has `denom2inv = 1 / (det^2 + 1e-7)` for `1 / det^2`.
    damp = (det * det / (det * det + 1e-7)).detach()[:, None]
    conic = conic.detach() + (conic - conic.detach()) * damp
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
        # getRect's empty rectangle is the only screen-space cull.
        visible = (tz > 0.2) & (det != 0) & ((x1 - x0) * (y1 - y0) > 0)
    # Colour from SH at the direction from the camera centre, + 0.5, clamped at 0 (the gradient
    # passes where the sum is exactly 0: INRIA's `clamped` is `result < 0`).
    direction = xyz - cam["center"].to(dtype)
    direction = direction / direction.norm(dim=1, keepdim=True)
    sh = torch.cat([g["f_dc"], g["f_rest"]], dim=1)
    colour = torch.clamp_min(eval_sh(sh, direction) + 0.5, 0.0)
    opacity = torch.sigmoid(g["opacity"][:, 0])
    return dict(px=px, py=py, conic=conic, radius=radius, x0=x0, x1=x1, y0=y0, y1=y1,
                visible=visible, colour=colour, opacity=opacity, tz=tz)


def rasterize(g, cam, background):
    """`[3, H, W]` colour and `[H, W]` alpha of `g` (INRIA's stored parameters)."""
    dtype = g["xyz"].dtype
    width, height = cam["width"], cam["height"]
    proj = project(g, cam)
    px, py, conic, tz = proj["px"], proj["py"], proj["conic"], proj["tz"]
    x0, x1, y0, y1 = proj["x0"], proj["x1"], proj["y0"], proj["y1"]
    visible, colour, opacity = proj["visible"], proj["colour"], proj["opacity"]

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
# The step of train_style.py
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



class StyleStep:
    """The losses of CLIPGaussian's `train_style.py` for views whose ground truth is given:
    directional, patch (the crops and warps given), content, and (when `background` is given)
    the background term on the pixels whose ground-truth colours sum to the background's."""

    def __init__(self, clip, vgg, gts, direction, patch_size, lambdas, dtype):
        self.clip, self.vgg = clip.to(dtype), vgg.to(dtype)
        self.size = clip.config.vision_config.image_size
        self.gts = [gt.to(dtype) for gt in gts]
        self.direction = torch.tensor(direction, dtype=dtype)
        self.patch = patch_size
        self.lambdas = lambdas
        with torch.no_grad():
            self.clip_gt = [unit(image_embeds(self.clip, clip_normalize(gt[None], self.size)))
                            for gt in self.gts]
            self.vgg_gt = [vgg_features(self.vgg, gt[None]) for gt in self.gts]

    def loss(self, image, view, patches, background=None):
        gt, patch = self.gts[view], self.patch
        f4, f5 = vgg_features(self.vgg, image[None])
        loss_c = ((self.vgg_gt[view][0] - f4) ** 2).mean() + ((self.vgg_gt[view][1] - f5) ** 2).mean()
        crops = []
        for p in patches:
            crop = image[None, :, p["top"]:p["top"] + patch, p["left"]:p["left"] + patch]
            warped = perspective(crop, p["corners"])
            crops.append(TF.resize(warped, [self.size], interpolation=InterpolationMode.BILINEAR,
                                   antialias=True))
        features = unit(image_embeds(self.clip, clip_normalize(torch.cat(crops), self.size)))
        d = unit(features - self.clip_gt[view])
        loss_patch = (1 - torch.cosine_similarity(d, self.direction.repeat(len(crops), 1), dim=1)).mean()
        loss_bg = 0.0
        if background is not None:
            # The authors' CUDA tensors are float32, and so is their mask's sum.
            mask = gt.to(torch.float32).sum(0) == background.to(torch.float32).sum()
            loss_bg = (image - gt).abs().mean(0)[mask].mean()
        features = unit(image_embeds(self.clip, clip_normalize(image[None], self.size)))
        d = unit(features - self.clip_gt[view])
        loss_d = (1 - torch.cosine_similarity(d, self.direction[None], dim=1)).mean()
        l = self.lambdas
        return (l["directional"] * loss_d + l["patch"] * loss_patch + l["content"] * loss_c
                + l["background"] * loss_bg)
