"""Gaussians placed at the rules by which INRIA's rasterizer decides what it draws, for the
fixtures that test those rules: `make_raster_thresholds_fixture.py` (the rasterizer alone) and
the replays of the authors' loops (`make_3d_replay_fixture.py`, `make_video_replay_fixture.py`).

Each kind is found by drawing candidates and keeping those that meet its rule, with every
decision about them (alpha against 1/255, transmittance against 1e-4, the tile rectangle's
edges, the radius' ceiling, the screen edges, the near plane) at least `MARGIN` (relative) from
its threshold, so that a float32 renderer must decide as the float64 reference.

Not a script: imported by the fixture scripts (run them from the repository root).
"""

import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from authors_loop import TILE, project  # noqa: E402

ALPHA_MIN = 1.0 / 255.0
T_MIN = 1e-4
# Relative margin every decision keeps.
MARGIN = 1e-4


def uniform(gen, n, lo, hi):
    return lo + (hi - lo) * torch.rand(n, generator=gen, dtype=torch.float64)


def random_quats(gen, n):
    return torch.randn(n, 4, generator=gen, dtype=torch.float64)


def gaussians_at(gen, cam, px, py, z, size_px, logit):
    """Gaussians centred at INRIA pixel `(px, py)` and camera depth `z`, of about `size_px`
    pixels' standard deviation (anisotropic, randomly turned), with opacity logit `logit`."""
    n = px.shape[0]
    width, height = cam["width"], cam["height"]
    fx, fy = width / (2 * cam["tan_x"]), height / (2 * cam["tan_y"])
    p_cam = torch.stack([(px + 0.5 - width / 2) * z / fx, (py + 0.5 - height / 2) * z / fy, z], 1)
    c2w = torch.linalg.inv(cam["w2c"])
    xyz = p_cam @ c2w[:3, :3].T + c2w[:3, 3]
    stretch = uniform(gen, 3 * n, 0.6, 1.5).view(n, 3)
    scale = (size_px * z / fx)[:, None] * stretch
    g = dict(
        xyz=xyz,
        f_dc=torch.randn(n, 1, 3, generator=gen, dtype=torch.float64) * 0.6,
        f_rest=torch.randn(n, 15, 3, generator=gen, dtype=torch.float64) * 0.15,
        opacity=logit[:, None].clone(),
        scaling=torch.log(scale),
        rotation=random_quats(gen, n),
    )
    return as_f32(g)


def as_f32(g):
    return {k: v.to(torch.float32).to(torch.float64) for k, v in g.items()}


def cat(parts):
    return {k: torch.cat([p[k] for p in parts]) for k in parts[0]}


def take(g, keep):
    return {k: v[keep] for k, v in g.items()}


def pixel_terms(proj, cam):
    """Per Gaussian and pixel (`[N, H*W]`): `exp(power)`, and whether the pixel is in the
    Gaussian's tile rectangle."""
    width, height = cam["width"], cam["height"]
    ys, xs = torch.meshgrid(torch.arange(height, dtype=torch.float64),
                            torch.arange(width, dtype=torch.float64), indexing="ij")
    pix_x, pix_y = xs.reshape(1, -1), ys.reshape(1, -1)
    tile_x, tile_y = torch.floor(pix_x / TILE), torch.floor(pix_y / TILE)
    in_rect = ((tile_x >= proj["x0"][:, None]) & (tile_x < proj["x1"][:, None])
               & (tile_y >= proj["y0"][:, None]) & (tile_y < proj["y1"][:, None]))
    dx, dy = proj["px"][:, None] - pix_x, proj["py"][:, None] - pix_y
    con = proj["conic"]
    power = (-0.5 * (con[:, 0:1] * dx * dx + con[:, 2:3] * dy * dy)
             - con[:, 1:2] * dx * dy)
    return torch.exp(power.clamp(max=0)), in_rect & proj["visible"][:, None]


def decisions_have_margin(g, cam):
    """Per Gaussian: every decision of INRIA's rules about it keeps the relative margin."""
    with torch.no_grad():
        proj = project(g, cam)
        falloff, inside = pixel_terms(proj, cam)
        alpha = proj["opacity"][:, None] * falloff
        alpha_ok = (~inside | ((alpha / ALPHA_MIN - 1).abs() > MARGIN)).all(dim=1)
        width, height = cam["width"], cam["height"]
        conic = proj["conic"]
        det = conic[:, 0] * conic[:, 2] - conic[:, 1] ** 2
        # The radius' ceiling, from the 2D covariance (the inverse of the conic).
        a, c, b = conic[:, 2] / det, conic[:, 0] / det, -conic[:, 1] / det
        mid = 0.5 * (a + c)
        three_sigma = 3 * torch.sqrt(mid + torch.sqrt(torch.clamp(mid * mid - (a * c - b * b), min=0.1)))
        ceil_ok = (three_sigma - torch.round(three_sigma)).abs() > MARGIN
        r = proj["radius"]
        edges = [(proj["px"] - r) / TILE, (proj["px"] + r + TILE - 1) / TILE,
                 (proj["py"] - r) / TILE, (proj["py"] + r + TILE - 1) / TILE,
                 proj["px"] + 0.5 - r - width, proj["py"] + 0.5 - r - height,
                 proj["px"] + 0.5 + r, proj["py"] + 0.5 + r]
        rect_ok = torch.stack([(e - torch.round(e)).abs() > MARGIN for e in edges]).all(dim=0)
        depth_ok = (proj["tz"] - 0.2).abs() > MARGIN
        return alpha_ok & ceil_ok & rect_ok & depth_ok, proj, alpha.where(inside, torch.zeros_like(alpha))


def first(cam, make, accept, count, what):
    """`count` Gaussians from batches of `make()` that `accept` and whose decisions keep their
    margin."""
    found = []
    for _ in range(50):
        g = make()
        ok, proj, alpha = decisions_have_margin(g, cam)
        keep = ok & accept(g, proj, alpha)
        found.append(take(g, keep))
        if sum(f["xyz"].shape[0] for f in found) >= count:
            return take(cat(found), torch.arange(count))
    raise RuntimeError(f"no {what} Gaussian found")


def placed(gen, cam, kind, count, alpha_margin=3e-3):
    """`count` Gaussians of `kind` for camera `cam`; `alpha_above` and `alpha_below` have their
    largest alpha at 1/255 times (1 +- `alpha_margin`)."""
    width, height = cam["width"], cam["height"]
    n = 512
    drawn = lambda g, proj, alpha: alpha.max(dim=1).values >= ALPHA_MIN * (1 + 3e-3)

    def at(px, py, size, logit, z=None):
        z = uniform(gen, n, 2.0, 3.5) if z is None else z
        return lambda: gaussians_at(gen, cam, px(), py(), z, size(), logit())

    rows = lambda: uniform(gen, n, 0, height - 1)
    cols = lambda: uniform(gen, n, 0, width - 1)
    wide = lambda: uniform(gen, n, 1.5, 4.0)
    opaque = lambda: uniform(gen, n, 2.0, 7.0)
    if kind == "past_right_edge":
        make = at(lambda: uniform(gen, n, width, width + 14), rows, wide, opaque)
        accept = lambda g, p, a: drawn(g, p, a) & (p["px"] + 0.5 - p["radius"] >= width)
    elif kind == "past_bottom_edge":
        make = at(cols, lambda: uniform(gen, n, height, height + 14), wide, opaque)
        accept = lambda g, p, a: drawn(g, p, a) & (p["py"] + 0.5 - p["radius"] >= height)
    elif kind == "near_left_edge":
        make = at(lambda: uniform(gen, n, -14, -2), rows, wide, opaque)
        accept = lambda g, p, a: drawn(g, p, a) & (p["px"] + 0.5 + p["radius"] < 3)
    elif kind == "near_top_edge":
        make = at(cols, lambda: uniform(gen, n, -14, -2), wide, opaque)
        accept = lambda g, p, a: drawn(g, p, a) & (p["py"] + 0.5 + p["radius"] < 3)
    elif kind == "tiny":
        def px():
            edge = torch.tensor([7.5, 15.5], dtype=torch.float64)[torch.randint(2, (n,), generator=gen)]
            tile = torch.randint((width + TILE - 1) // TILE, (n,), generator=gen).double()
            return (TILE * tile + edge + uniform(gen, n, -1.5, 1.5)).clamp(-0.4, width - 0.6)
        make = at(px, rows, lambda: uniform(gen, n, 0.05, 1.0), lambda: uniform(gen, n, -1.0, 6.0))
        accept = drawn
    elif kind in ("alpha_above", "alpha_below"):
        target = ALPHA_MIN * (1 + alpha_margin if kind == "alpha_above" else 1 - alpha_margin)

        def make():
            g = gaussians_at(gen, cam, cols(), rows(), uniform(gen, n, 2.0, 3.5),
                             uniform(gen, n, 0.8, 3.0), torch.zeros(n, dtype=torch.float64))
            with torch.no_grad():
                proj = project(g, cam)
                falloff, inside = pixel_terms(proj, cam)
                peak = falloff.where(inside, torch.zeros_like(falloff)).max(dim=1).values
            o = (target / peak.clamp(min=1e-30)).clamp(max=0.9)
            g["opacity"] = torch.log(o / (1 - o))[:, None]
            return as_f32(g)

        accept = lambda g, p, a: p["visible"]
    elif kind == "near_plane":
        z = torch.tensor([0.2, 0.2], dtype=torch.float64).repeat(n // 2) * (
            1 + torch.tensor([5e-3, -5e-3], dtype=torch.float64).repeat(n // 2))
        make = at(cols, rows, lambda: uniform(gen, n, 0.5, 2.0), opaque, z=z)
        accept = lambda g, p, a: torch.ones_like(p["visible"])
    else:
        raise ValueError(kind)
    return first(cam, make, accept, count, kind)


def stacked(gen, cam, n):
    """`n` opaque splats on one spot, front to back: pixels there stop at transmittance 1e-4."""
    for _ in range(50):
        px = torch.full((n,), cam["width"] * 0.4, dtype=torch.float64) + uniform(gen, n, -1, 1)
        py = torch.full((n,), cam["height"] * 0.6, dtype=torch.float64) + uniform(gen, n, -1, 1)
        z = torch.linspace(1.6, 2.8, n, dtype=torch.float64)
        # One capped splat, the rest below the cap, so that no pixel meets the tie 0.01 * 0.01.
        logit = torch.tensor([6.0] + [2.5 + 0.4 * k for k in range(n - 1)], dtype=torch.float64)
        g = gaussians_at(gen, cam, px, py, z, uniform(gen, n, 2.5, 5.0), logit)
        if decisions_have_margin(g, cam)[0].all() and transmittance_margin(g, cam) > MARGIN:
            return g
    raise RuntimeError("no stack found whose decisions keep their margin")


def random_in_view(gen, cam, count):
    make = lambda: gaussians_at(
        gen, cam, uniform(gen, 256, -4, cam["width"] + 4), uniform(gen, 256, -4, cam["height"] + 4),
        uniform(gen, 256, 1.5, 4.5), uniform(gen, 256, 0.7, 6.0), uniform(gen, 256, -2.0, 4.0))
    return first(cam, make, lambda g, p, a: p["visible"], count, "random")


def transmittance_tests(g, cam):
    """Every pixel's transmittance tests `T (1 - alpha)` of the Gaussians it evaluates, in
    depth order up to and including the one that stops it (INRIA's `test_T < 1e-4`)."""
    with torch.no_grad():
        proj = project(g, cam)
        order = torch.sort(proj["tz"], stable=True).indices
        order = order[proj["visible"][order]]
        falloff, inside = pixel_terms(take(proj, order), cam)
        alpha = (proj["opacity"][order][:, None] * falloff).clamp(max=0.99)
        valid = inside & (alpha >= ALPHA_MIN)
        one_minus = torch.where(valid, 1 - alpha, torch.ones_like(alpha))
        before = torch.cumprod(torch.cat([torch.ones_like(one_minus[:1]), one_minus[:-1]]), 0)
        return (before * one_minus)[valid & (before >= T_MIN)]


def transmittance_margin(g, cam):
    """The smallest relative distance of a transmittance test from 1e-4."""
    return ((transmittance_tests(g, cam) / T_MIN - 1).abs()).min().item()


def stopped_pixels(g, cam):
    """How many pixels stop at transmittance 1e-4."""
    return int((transmittance_tests(g, cam) < T_MIN).sum())
