#!/usr/bin/env python3
"""Small D-MiSo models in the authors' exact on-disk layout, with float64 reference values.

D-MiSo (github waczjoan/D-MiSo) is the 4D base model of CLIPGaussian: G triangle "cores"
(the pseudomesh), K sub-Gaussians attached to each core, a deformation MLP that moves and
reshapes every triangle for a time t, and a Linear(17, 4) that turns a sub's stored rotation and
the time into a rotation applied on top of the core's frame. This script re-expresses those
semantics in plain torch (written from the fact sheet of the model, not copied from the authors'
code), stores a tiny random model the way the authors' training run stores one, and records what
the model produces at one time t together with autograd gradients of a linear probe loss.

How to run (from the repository root; PyPI only, CPU torch is enough):

    python3 -m venv /tmp/tv && /tmp/tv/bin/pip install torch numpy plyfile safetensors
    /tmp/tv/bin/python scripts/make_dmiso_fixture.py

It writes (default --out crates/base-dmiso/tests/fixtures) one folder per fixture:

    <name>/cfg_args                                        str(Namespace(...)) of the ModelParams
    <name>/point_cloud/iteration_best/point_cloud.ply      one row per core (61 float properties)
    <name>/point_cloud/iteration_best/model_params.pt      torch.save(dict of nn.Parameter + K, flag)
    <name>/deform/iteration_best/deform.pth                torch.save(DeformNetwork.state_dict())
    <name>/time_net/iteration_best/deform.pth              torch.save(Linear(17, 4).state_dict())
    <name>/expected.safetensors                            reference values (float32), see below

Fixtures (different on purpose):
  * dmiso_small:     seed 1, G=5 cores, K=3 subs per core, deform width W=32, t=0.37, PyTorch's
                     default nn.Linear init everywhere (the heads rescaled, see HEADS below).
  * dmiso_zero_bias: seed 2, G=3, K=2, W=16, t=1.0, every bias of the deformation network and of
                     the time-rotation Linear set to exactly 0.

Model (per triangle g, time t; N = G*K subs, sub index = g*K + k):
  PE_n(x) = [x, sin(x), cos(x), sin(2x), cos(2x), ..., sin(2^(n-1)x), cos(2^(n-1)x)] (per-frequency
  blocks of x's size, no pi). Vertices use n=10 (63-D), time n=6 (13-D, is_blender).
  Network on the DETACHED pseudomesh: h1 = PE(v1)*PE(v2)*PE(v3); t_emb = timenet(PE_t(t)),
  timenet = Linear(13,W)-ReLU-Linear(W,30); h = [h1, t_emb]; 8 x (Linear, ReLU), after layer 4 (and
  its ReLU) h = [h1, t_emb, h]; heads gaussian_warp (dv1, 3), gaussian_v2 (3), gaussian_v3 (3),
  gaussian_rot (4), no activations.
  Deformed triangle (pseudomesh NOT detached here): e2 = R(d_rot) (v2-v1), e3 = R(d_rot) (v3-v1),
  R = rotation of d_rot/|d_rot| (w,x,y,z); v1' = v1+dv1; v2' = v2+dv1+e2/|e2|*dv2;
  v3' = v3+dv1+e3/|e3|*dv3.
  Core frame (eps = 1e-8): a = v2'-v1', b = v3'-v1'; r1 = cross(a/|a|, b/|b|), r1 /= |r1|+eps;
  r2 = a/(|a|+eps); r3 = b - (b.r1)r1 - (b.r2)r2, r3 /= |r3|+eps; S = [1e-8, |a|+eps, |b.r3|];
  q_core = normalize(std(matrix_to_quaternion([r1 r2 r3] as columns))) (pytorch3d algorithm with
  the 0.1 floor on the denominators, standardised to w >= 0).
  Subs: mean = v1' + alpha0*n + alpha1*a/|a| + alpha2*b/|b|, n = cross(a,b)/|cross(a,b)|;
  log_scale = attached_scale + log(S) (the model uses exp(attached_scale)*S);
  quat = normalize(time_net([attached_rotation, PE_t(t)])) (x) q_core, Hamilton (w,x,y,z), the
  product not renormalised; opacity logit = attached_opacity; SH = [dc, rest] ([N,16,3]).

HEADS: with PyTorch's default init the head outputs (dominated by the biases at width 16-32) are
  as large as the triangles, and with zero biases they are tiny. So the weight AND bias of
  gaussian_warp / gaussian_v2 / gaussian_v3 are multiplied by one factor per head, chosen from a
  float32 forward at the fixture's time so that max|dv1| = 0.1 and max|dv2|, max|dv3| = 0.15 x the
  shortest canonical edge. gaussian_rot is left as initialised (its output is normalised).

expected.safetensors (all float32; computed in float64 from the stored float32 values):
  time [1]; deform_out [G,13] = [dv1, dv2, dv3, d_rot]; means [N,3]; log_scales [N,3];
  quats [N,4]; opacity_logits [N]; sh_dc [N,3]; sh_rest [N,15,3];
  grad_means, grad_log_scales, grad_quats, grad_opacity_logits, grad_sh_dc, grad_sh_rest (random
  normal upstream gradients of the same shapes); loss [1] = sum over those six of value*grad;
  d_pseudomesh [G,3,3] (only through the non-detached deformation path), d_alpha [G,K,3],
  d_attached_scale [N,3], d_attached_rotation [N,4], d_attached_opacity [N,1],
  d_attached_features_dc [N,1,3], d_attached_features_rest [N,15,3], d_time_net.weight [4,17],
  d_time_net.bias [4], and d_deform.<name> for every tensor of deform.pth's state dict.
"""

import argparse
import copy
from argparse import Namespace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from plyfile import PlyData, PlyElement
from safetensors.torch import save_file
from torch import nn

EPS = 1e-8
VERT_FREQS = 10
TIME_FREQS = 6  # is_blender
DEPTH = 8
SKIP = DEPTH // 2
T_EMB = 30

FIXTURES = {
    "dmiso_small": dict(seed=1, G=5, K=3, W=32, t=0.37, zero_bias=False),
    "dmiso_zero_bias": dict(seed=2, G=3, K=2, W=16, t=1.0, zero_bias=True),
}


def posenc(x, n_freqs):
    """[x, sin(x), cos(x), sin(2x), cos(2x), ...] along the last dim, frequencies 2^0..2^(n-1)."""
    parts = [x]
    for k in range(n_freqs):
        f = 2.0**k
        parts.append(torch.sin(x * f))
        parts.append(torch.cos(x * f))
    return torch.cat(parts, dim=-1)


class DeformNet(nn.Module):
    """Module names match the authors' DeformNetwork (is_blender, not 6-DoF) state dict."""

    def __init__(self, width):
        super().__init__()
        vert_ch = 3 * (1 + 2 * VERT_FREQS)
        time_ch = 1 + 2 * TIME_FREQS
        self.vert_ch = vert_ch
        in_ch = vert_ch + T_EMB
        self.timenet = nn.Sequential(nn.Linear(time_ch, width), nn.ReLU(), nn.Linear(width, T_EMB))
        layers = [nn.Linear(in_ch, width)]
        for i in range(DEPTH - 1):
            layers.append(nn.Linear(width + in_ch, width) if i == SKIP else nn.Linear(width, width))
        self.linear = nn.ModuleList(layers)
        self.gaussian_warp = nn.Linear(width, 3)
        self.gaussian_v2 = nn.Linear(width, 3)
        self.gaussian_v3 = nn.Linear(width, 3)
        self.gaussian_rot = nn.Linear(width, 4)

    def forward(self, v1, v2, v3, t):
        h1 = posenc(v1, VERT_FREQS) * posenc(v2, VERT_FREQS) * posenc(v3, VERT_FREQS)
        t_emb = self.timenet(posenc(t, TIME_FREQS))
        h = torch.cat([h1, t_emb], dim=-1)
        for i, layer in enumerate(self.linear):
            h = torch.relu(layer(h))
            if i == SKIP:
                h = torch.cat([h1, t_emb, h], dim=-1)
        return (self.gaussian_warp(h), self.gaussian_v2(h), self.gaussian_v3(h),
                self.gaussian_rot(h))


def quat_to_matrix(q):
    q = q / q.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    rows = [
        torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ]
    return torch.stack(rows, dim=-2)


def hamilton(p, q):
    pw, px, py, pz = p.unbind(-1)
    qw, qx, qy, qz = q.unbind(-1)
    return torch.stack([
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    ], dim=-1)


def sqrt_pos(x):
    """sqrt(max(x, 0)) with a zero gradient where x <= 0."""
    return torch.where(x > 0, torch.sqrt(torch.where(x > 0, x, torch.ones_like(x))),
                       torch.zeros_like(x))


def matrix_to_quat(m):
    """pytorch3d's matrix_to_quaternion (w first), standardised to w >= 0; not normalised."""
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    q_abs = sqrt_pos(torch.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22,
                                  1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1))
    cands = torch.stack([
        torch.stack([q_abs[..., 0] ** 2, m21 - m12, m02 - m20, m10 - m01], -1),
        torch.stack([m21 - m12, q_abs[..., 1] ** 2, m10 + m01, m02 + m20], -1),
        torch.stack([m02 - m20, m10 + m01, q_abs[..., 2] ** 2, m12 + m21], -1),
        torch.stack([m10 - m01, m20 + m02, m21 + m12, q_abs[..., 3] ** 2], -1),
    ], dim=-2)
    cands = cands / (2.0 * q_abs.clamp(min=0.1)[..., None])
    best = q_abs.argmax(dim=-1)
    q = torch.gather(cands, -2, best[..., None, None].expand(*best.shape, 1, 4)).squeeze(-2)
    return torch.where(q[..., :1] < 0, -q, q)


def core_frame(v1, v2, v3):
    """(S [G,3], unnormalised w>=0 quaternion [G,4], log|[s2, s3]| [G,2]) of the triangles."""
    a = v2 - v1
    b = v3 - v1
    a_len = a.norm(dim=-1, keepdim=True)
    b_len = b.norm(dim=-1, keepdim=True)
    r1 = torch.cross(a / a_len, b / b_len, dim=-1)
    r1 = r1 / (r1.norm(dim=-1, keepdim=True) + EPS)
    s2 = a_len + EPS
    r2 = a / s2
    r3 = b - (b * r1).sum(-1, keepdim=True) * r1 - (b * r2).sum(-1, keepdim=True) * r2
    r3 = r3 / (r3.norm(dim=-1, keepdim=True) + EPS)
    s3 = (b * r3).sum(-1, keepdim=True)
    q = matrix_to_quat(torch.stack([r1, r2, r3], dim=-1))
    s23 = torch.cat([s2, s3], dim=-1).abs()
    scale = torch.cat([torch.full_like(s2, 1e-8), s23], dim=-1)
    return scale, q, torch.log(s23)


def deform_triangles(pm, dv1, dv2, dv3, drot):
    v1, v2, v3 = pm[:, 0], pm[:, 1], pm[:, 2]
    rot = quat_to_matrix(drot)
    e2 = (rot @ (v2 - v1)[..., None])[..., 0]
    e3 = (rot @ (v3 - v1)[..., None])[..., 0]
    return (v1 + dv1,
            v2 + dv1 + e2 / e2.norm(dim=-1, keepdim=True) * dv2,
            v3 + dv1 + e3 / e3.norm(dim=-1, keepdim=True) * dv3)


def construct(p, net, time_net, t):
    """Everything the renderer sees at time t; p holds the model_params tensors."""
    pm = p["pseudomesh"]
    g = pm.shape[0]
    k = p["alpha"].shape[1]
    pmd = pm.detach()
    t_g = torch.full((g, 1), t, dtype=pm.dtype)
    dv1, dv2, dv3, drot = net(pmd[:, 0], pmd[:, 1], pmd[:, 2], t_g)
    v1, v2, v3 = deform_triangles(pm, dv1, dv2, dv3, drot)
    scale, q, _ = core_frame(v1, v2, v3)
    q_core = F.normalize(q, dim=-1)
    a = v2 - v1
    b = v3 - v1
    n = torch.cross(a, b, dim=-1)
    basis = torch.stack([n / n.norm(dim=-1, keepdim=True), a / a.norm(dim=-1, keepdim=True),
                         b / b.norm(dim=-1, keepdim=True)], dim=1)
    means = (v1[:, None, :] + torch.bmm(p["alpha"], basis)).reshape(g * k, 3)
    log_scales = p["attached_scale"] + torch.log(scale).repeat_interleave(k, dim=0)
    t_n = torch.full((g * k, 1), t, dtype=pm.dtype)
    q_t = time_net(torch.cat([p["attached_rotation"], posenc(t_n, TIME_FREQS)], dim=-1))
    quats = hamilton(F.normalize(q_t, dim=-1), q_core.repeat_interleave(k, dim=0))
    return {
        "deform_out": torch.cat([dv1, dv2, dv3, drot], dim=-1),
        "means": means,
        "log_scales": log_scales,
        "quats": quats,
        "opacity_logits": p["attached_opacity"][:, 0],
        "sh_dc": p["attached_features_dc"][:, 0, :],
        "sh_rest": p["attached_features_rest"],
        "_verts": (v1, v2, v3),
    }


def random_triangles(gen, g):
    """Non-degenerate triangles inside [-1,1]^3, legs 0.15-0.4, angle at v1 in 45..135 degrees."""
    tris = []
    while len(tris) < g:
        v1 = torch.rand(3, generator=gen, dtype=torch.float64) * 1.2 - 0.6
        d2 = F.normalize(torch.randn(3, generator=gen, dtype=torch.float64), dim=0)
        d3 = F.normalize(torch.randn(3, generator=gen, dtype=torch.float64), dim=0)
        if abs(float(d2 @ d3)) > 0.7:
            continue
        l2, l3 = (torch.rand(2, generator=gen, dtype=torch.float64) * 0.25 + 0.15).tolist()
        tri = torch.stack([v1, v1 + l2 * d2, v1 + l3 * d3])
        if tri.abs().max() < 1.0:
            tris.append(tri)
    return torch.stack(tris).float()


def edge_lengths(v1, v2, v3):
    return torch.stack([(v2 - v1).norm(dim=-1), (v3 - v1).norm(dim=-1), (v3 - v2).norm(dim=-1)], -1)


def write_ply(path, pm, core_dc, core_rest, core_opacity):
    _, q, log_s23 = core_frame(pm[:, 0].double(), pm[:, 1].double(), pm[:, 2].double())
    g = pm.shape[0]
    names = ["x", "y", "z", "nx", "ny", "nz"] + [f"f_dc_{i}" for i in range(3)]
    names += [f"f_rest_{i}" for i in range(45)] + ["opacity", "scale_0", "scale_1"]
    names += [f"rot_{i}" for i in range(4)]
    cols = np.concatenate([
        pm[:, 0].numpy(),
        np.zeros((g, 3), np.float32),
        core_dc.transpose(1, 2).reshape(g, -1).numpy(),     # [G,1,3] -> [G,3]
        core_rest.transpose(1, 2).reshape(g, -1).numpy(),   # channel-major: 15 R, 15 G, 15 B
        core_opacity.numpy(),
        log_s23.float().numpy(),
        q.float().numpy(),
    ], axis=1).astype(np.float32)
    assert cols.shape[1] == len(names) == 61
    elements = np.empty(g, dtype=[(name, "f4") for name in names])
    elements[:] = list(map(tuple, cols))
    PlyData([PlyElement.describe(elements, "vertex")]).write(str(path))


def make_fixture(out_dir, name, seed, G, K, W, t, zero_bias):
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)
    n = G * K

    # Networks: PyTorch default init (global RNG seeded above).
    net = DeformNet(W)
    time_net = nn.Linear(4 + 1 + 2 * TIME_FREQS, 4)
    if zero_bias:
        with torch.no_grad():
            for mod in net.modules():
                if isinstance(mod, nn.Linear):
                    mod.bias.zero_()
            time_net.bias.zero_()

    pm = random_triangles(gen, G)

    def rnd(*shape, scale=1.0):
        return (torch.randn(*shape, generator=gen) * scale).float().contiguous()

    params = {
        "pseudomesh": pm,
        "alpha": rnd(G, K, 3, scale=0.05),
        "attached_scale": (torch.rand(n, 3, generator=gen) * 1.5 - 1.0).float(),
        "attached_rotation": rnd(n, 4),
        "attached_opacity": rnd(n, 1),
        "attached_features_dc": rnd(n, 1, 3, scale=0.5),
        "attached_features_rest": rnd(n, 15, 3, scale=0.1),
    }
    core_dc = rnd(G, 1, 3, scale=0.5)
    core_rest = rnd(G, 15, 3, scale=0.1)
    core_opacity = rnd(G, 1)

    # Rescale the position heads (see HEADS in the docstring).
    min_edge = float(edge_lengths(pm[:, 0], pm[:, 1], pm[:, 2]).min())
    gains = []
    with torch.no_grad():
        outs = net(pm[:, 0], pm[:, 1], pm[:, 2], torch.full((G, 1), t))
        for head, out, target in zip([net.gaussian_warp, net.gaussian_v2, net.gaussian_v3], outs[:3],
                                     [0.1, 0.15 * min_edge, 0.15 * min_edge]):
            factor = target / float(out.abs().max())
            gains.append(round(factor, 4))
            head.weight.mul_(factor)
            head.bias.mul_(factor)

    # ---- files in the authors' layout ----
    root = out_dir / name
    pc_dir = root / "point_cloud" / "iteration_best"
    deform_dir = root / "deform" / "iteration_best"
    tnet_dir = root / "time_net" / "iteration_best"
    for d in (pc_dir, deform_dir, tnet_dir):
        d.mkdir(parents=True, exist_ok=True)

    cfg = dict(data_device="cuda", deform_depth=DEPTH, deform_width=W, eval=True, images="images",
               is_6dof=False, is_blender=True, load2gpu_on_the_fly=False, model_path="/out/trex",
               num_gauss=G, num_splat=K, resolution=-1, sh_degree=3, source_path="/data/trex",
               white_background=True)
    (root / "cfg_args").write_text(str(Namespace(**dict(sorted(cfg.items())))))

    write_ply(pc_dir / "point_cloud.ply", pm, core_dc, core_rest, core_opacity)
    saved = {key: nn.Parameter(val.clone().contiguous()) for key, val in params.items()}
    saved["num_splats"] = K
    saved["use_attached_gauss"] = True
    torch.save(saved, pc_dir / "model_params.pt")
    torch.save(net.state_dict(), deform_dir / "deform.pth")
    torch.save(time_net.state_dict(), tnet_dir / "deform.pth")

    # ---- reference values, float64 from the stored float32 values ----
    net64 = copy.deepcopy(net).double()
    tnet64 = copy.deepcopy(time_net).double()
    p64 = {key: val.double().requires_grad_(True) for key, val in params.items()}
    res = construct(p64, net64, tnet64, t)

    value_keys = ["means", "log_scales", "quats", "opacity_logits", "sh_dc", "sh_rest"]
    upstream = {key: torch.randn(res[key].shape, generator=gen, dtype=torch.float64)
                for key in value_keys}
    loss = sum((res[key] * upstream[key]).sum() for key in value_keys)
    tensors = list(p64.values()) + list(tnet64.parameters()) + list(net64.parameters())
    grads = torch.autograd.grad(loss, tensors, allow_unused=True)
    grads = [torch.zeros_like(x) if gr is None else gr for x, gr in zip(tensors, grads)]
    it = iter(grads)

    expected = {"time": torch.tensor([t], dtype=torch.float64)}
    expected["deform_out"] = res["deform_out"]
    for key in value_keys:
        expected[key] = res[key]
    for key in value_keys:
        expected["grad_" + key] = upstream[key]
    expected["loss"] = loss.reshape(1)
    for key in p64:
        expected["d_" + key] = next(it)
    for key, _ in tnet64.named_parameters():
        expected["d_time_net." + key] = next(it)
    deform_grads = {}
    for key, _ in net64.named_parameters():
        deform_grads[key] = next(it)
        expected["d_deform." + key] = deform_grads[key]
    assert set(deform_grads) == set(net.state_dict())
    save_file({key: val.detach().float().contiguous() for key, val in expected.items()},
              str(root / "expected.safetensors"))
    (root / "expected.safetensors").chmod(0o644)

    # ---- sanity numbers ----
    with torch.no_grad():
        p32 = {key: val.clone() for key, val in params.items()}
        res32 = construct(p32, net, time_net, t)
        f32_err = max(float((res32[key].double() - res[key].detach()).abs().max())
                      for key in ["deform_out", "means", "log_scales", "quats"])
        v1, v2, v3 = (v.detach() for v in res["_verts"])
        pre = []
        h1 = posenc(pm[:, 0].double(), VERT_FREQS) * posenc(pm[:, 1].double(), VERT_FREQS) \
            * posenc(pm[:, 2].double(), VERT_FREQS)
        t_pe = posenc(torch.full((G, 1), t, dtype=torch.float64), TIME_FREQS)
        pre.append(net64.timenet[0](t_pe))
        t_emb = net64.timenet(t_pe)
        h = torch.cat([h1, t_emb], -1)
        for i, layer in enumerate(net64.linear):
            pre.append(layer(h))
            h = torch.relu(pre[-1])
            if i == SKIP:
                h = torch.cat([h1, t_emb, h], -1)
        relu_margin = min(float(x[x != 0].abs().min()) for x in pre)
        dead = sum(int((x <= 0).all(dim=0).sum()) for x in pre)
        a, b = v2 - v1, v3 - v1
        r1 = F.normalize(torch.cross(a, b, dim=-1), dim=-1)
        frame = torch.stack([r1, F.normalize(a, dim=-1), F.normalize(torch.cross(r1, a, dim=-1),
                                                                  dim=-1)], -1)
        d = torch.diagonal(frame, dim1=-2, dim2=-1)
        qa = torch.stack([1 + d.sum(-1), 1 + d[:, 0] - d[:, 1] - d[:, 2],
                          1 - d[:, 0] + d[:, 1] - d[:, 2], 1 - d[:, 0] - d[:, 1] + d[:, 2]], -1)
        qa_sorted = qa.clamp(min=0).sqrt().sort(dim=-1, descending=True).values
        argmax_margin = float((qa_sorted[:, 0] - qa_sorted[:, 1]).min())
        q_t = tnet64(torch.cat([p64["attached_rotation"].detach(),
                                posenc(torch.full((n, 1), t, dtype=torch.float64), TIME_FREQS)], -1))
    print(f"{name}: G={G} K={K} W={W} t={t}")
    print(f"  max|deform_out| per part: dv1 {res['deform_out'][:, 0:3].abs().max():.4g}, "
          f"dv2 {res['deform_out'][:, 3:6].abs().max():.4g}, "
          f"dv3 {res['deform_out'][:, 6:9].abs().max():.4g}, "
          f"d_rot {res['deform_out'][:, 9:13].abs().max():.4g} "
          f"(min |d_rot| {res['deform_out'][:, 9:13].norm(dim=-1).min():.4g})")
    print(f"  edges: canonical min {min_edge:.4g}, deformed min "
          f"{edge_lengths(v1, v2, v3).min():.4g} max {edge_lengths(v1, v2, v3).max():.4g}")
    print(f"  min |time_net out| {q_t.norm(dim=-1).min():.4g}; loss {loss.item():.6g}; "
          f"float32-vs-float64 max abs diff {f32_err:.3g}")
    print(f"  min |ReLU pre-activation| {relu_margin:.3g}; units dead on all cores {dead}; "
          f"min q_abs argmax margin {argmax_margin:.3g}; head gains {gains}")
    for key, gr in deform_grads.items():
        print(f"  max|d_deform.{key}| = {gr.abs().max():.4g}")
    for key in p64:
        print(f"  max|d_{key}| = {expected['d_' + key].abs().max():.4g}")


def main():
    repo = Path(__file__).resolve().parent.parent
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=repo / "crates/base-dmiso/tests/fixtures",
                        help="folder that receives one sub-folder per fixture")
    args = parser.parse_args()
    torch.set_num_threads(1)
    for name, spec in FIXTURES.items():
        make_fixture(args.out, name, **spec)


if __name__ == "__main__":
    main()
