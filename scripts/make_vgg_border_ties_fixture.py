#!/usr/bin/env python3
"""Generate `crates/style-loss/tests/fixtures/vgg_border_ties_reference.safetensors`: the VGG
content loss and its image gradient where a ReLU decision is a hair from 0, near every border.

How to run (from the repository root; needs only PyPI):

    python3 -m venv /tmp/vgg-ties-venv
    /tmp/vgg-ties-venv/bin/pip install torch safetensors
    /tmp/vgg-ties-venv/bin/python scripts/make_vgg_border_ties_fixture.py

The network is the committed tiny VGG-19 with torchvision's initialisation
(`tiny_vgg19_torchvision_init.safetensors`: Kaiming weights, zero biases). Each render is 2x2
repeated noise with eight flat regions: a 5-pixel strip along each border and a 7x7 block one
block in from each corner. Each region's colour is chosen so that one conv1_1 channel's
pre-activation over a flat neighbourhood is, in exact arithmetic on the float32-normalised input
(the input every float32 implementation sees), within 1e-9 of the size of its terms from 0,
with a known sign (both signs appear). Summed in float32 in some order, that sign is decided by
rounding: a whole region's ReLU gates (and the all-zero max-pool windows after them) open or
close together, and the content gradient moves by 1e-2 or more. An implementation that decides
as the exact sum does matches; one that decides by its own rounding does not.

Three sizes (128x96, 61x45 with odd pooling tails, 97x131). The script checks, at each size,
that PyTorch's float32 convolution gives each region the exact sign and that PyTorch's float32
gradient is within 1e-5 of the float64 network run on the float32-normalised input, and redraws
a colour otherwise; the stored reference is PyTorch's float32 loss and gradient. `--seed N`
draws other colours and noise (to check the crate on cases it was not written against).
"""

import argparse
import copy
from pathlib import Path

import torch
import torch.nn as nn
import torch.nn.functional as F
from safetensors.torch import load_file, save_file

FIXTURES = Path(__file__).resolve().parent.parent / "crates" / "style-loss" / "tests" / "fixtures"
WIDTHS = [4, 4, "M", 8, 8, "M", 16, 16, 16, 16, "M", 32, 32, 32, 32, "M", 32, 32, 32, 32, "M"]
RELU4_2, RELU5_2 = 22, 31
MEAN32 = torch.tensor([0.485, 0.456, 0.406], dtype=torch.float32).view(1, 3, 1, 1)
STD32 = torch.tensor([0.229, 0.224, 0.225], dtype=torch.float32).view(1, 3, 1, 1)
SIZES = [(128, 96), (61, 45), (97, 131)]
STRIP = 5


def features():
    layers, channels = [], 3
    for width in WIDTHS:
        if width == "M":
            layers.append(nn.MaxPool2d(2, 2))
        else:
            layers += [nn.Conv2d(channels, width, 3, padding=1), nn.ReLU()]
            channels = width
    net = nn.Sequential(*layers)
    weights = load_file(str(FIXTURES / "tiny_vgg19_torchvision_init.safetensors"))
    net.load_state_dict({k[len("features."):]: v for k, v in weights.items()})
    return net.eval()


def normalised(render):
    """ImageNet normalisation in float32, as the crate and PyTorch's float32 run compute it."""
    return (render.float() - MEAN32) / STD32


def relu4_2_and_5_2(net, x):
    kept = {}
    for index, layer in enumerate(net):
        x = layer(x)
        if index in (RELU4_2, RELU5_2):
            kept[index] = x
        if index == RELU5_2:
            return kept[RELU4_2], kept[RELU5_2]


def content_loss_and_grad(net, render, gt, dtype):
    """Loss and image gradient with the network in `dtype`, on the float32-normalised images."""
    net = copy.deepcopy(net).to(dtype)
    x = normalised(render).to(dtype).requires_grad_(True)
    with torch.no_grad():
        g4, g5 = relu4_2_and_5_2(net, normalised(gt).to(dtype))
    f4, f5 = relu4_2_and_5_2(net, x)
    loss = ((f4 - g4) ** 2).mean() + ((f5 - g5) ** 2).mean()
    loss.backward()
    return loss.detach(), (x.grad / STD32.to(dtype)).detach()


def near_zero_colour(conv, rng):
    """A colour (float32 RGB), the conv1_1 channel whose pre-activation over a flat neighbourhood
    of it is a hair from 0, and that pre-activation's exact sign."""
    weight = conv.weight.detach().double()
    taps = weight.sum((2, 3))  # [cout, 3]: a flat neighbourhood sums each channel's nine taps
    while True:
        channel = int(torch.randint(0, weight.shape[0], (1,), generator=rng))
        sign = 1.0 if torch.rand(1, generator=rng).item() < 0.5 else -1.0
        red_green = torch.rand(2, generator=rng) * 0.6 + 0.2
        x = normalised(torch.cat([red_green, torch.zeros(1)]).view(1, 3, 1, 1)).double().flatten()
        w = taps[channel]
        blue_x = -(x[0] * w[0] + x[1] * w[1]) / w[2]
        blue = float(blue_x * 0.225 + 0.406)
        if not 0.05 < blue < 0.95:
            continue
        base = torch.tensor([red_green[0], red_green[1], blue], dtype=torch.float32)
        # Every colour within 40 float32 steps of `base` in each channel.
        steps = torch.arange(-40, 41, dtype=torch.float32)
        ulp = torch.nextafter(base, torch.full_like(base, 2.0)) - base
        grid = torch.stack(torch.meshgrid(steps, steps, steps, indexing="ij"), -1).reshape(-1, 3)
        colours = base + grid * ulp
        xs = normalised(colours.view(-1, 3, 1, 1)).double().reshape(-1, 3)
        pre = xs @ w
        scale = (xs.abs() * w.abs()).sum(1)
        fits = (pre * sign > 0) & (pre.abs() < 1e-9 * scale) & (pre.abs() > 1e-13 * scale)
        if fits.any():
            best = torch.nonzero(fits).flatten()[torch.argmin(pre[fits].abs())]
            return colours[best], channel, float(torch.sign(pre[best]))


def regions(h, w):
    """(rows, columns) slices of the eight flat regions and a probe pixel inside each."""
    blocks = [(STRIP + 2, STRIP + 2), (STRIP + 2, w - STRIP - 9), (h - STRIP - 9, STRIP + 2),
              (h - STRIP - 9, w - STRIP - 9)]
    out = [((slice(0, STRIP), slice(None)), (STRIP // 2, w // 2)),
           ((slice(h - STRIP, h), slice(None)), (h - 1 - STRIP // 2, w // 2)),
           ((slice(None), slice(0, STRIP)), (h // 2, STRIP // 2)),
           ((slice(None), slice(w - STRIP, w)), (h // 2, w - 1 - STRIP // 2))]
    out += [((slice(y, y + 7), slice(x, x + 7)), (y + 3, x + 3)) for y, x in blocks]
    return out


def render_and_gt(h, w, colours, rng):
    low = torch.rand(1, 3, -(-h // 2), -(-w // 2), generator=rng)
    render = low.repeat_interleave(2, 2).repeat_interleave(2, 3)[..., :h, :w].clone()
    for ((rows, cols), _), (colour, _, _) in zip(regions(h, w), colours):
        render[..., rows, cols] = colour.view(3, 1, 1)
    gt = render.clone()
    inner = (slice(STRIP + 10, h - STRIP - 10), slice(STRIP + 10, w - STRIP - 10))
    gt[(..., *inner)] = torch.rand(gt[(..., *inner)].shape, generator=rng)
    return render, gt


def case(net, h, w, seed):
    rng = torch.Generator().manual_seed(seed)
    conv = net[0]
    colours = [near_zero_colour(conv, rng) for _ in regions(h, w)]
    for _ in range(50):
        render, gt = render_and_gt(h, w, colours, torch.Generator().manual_seed(seed + 1))
        pre = F.conv2d(normalised(render), conv.weight, conv.bias, padding=1)[0]
        wrong = [k for k, ((_, (y, x)), (_, channel, sign)) in enumerate(zip(regions(h, w), colours))
                 if (pre[channel, y, x].item() > 0) != (sign > 0)]
        if wrong:
            for k in wrong:
                colours[k] = near_zero_colour(conv, rng)
            continue
        loss, grad = content_loss_and_grad(net, render, gt, torch.float32)
        _, exact = content_loss_and_grad(net, render, gt, torch.float64)
        error = ((grad.double() - exact).norm() / exact.norm()).item()
        if error < 1e-5:
            return render, gt, loss, grad, error
        colours = [near_zero_colour(conv, rng) for _ in regions(h, w)]
    raise RuntimeError(f"{h}x{w}: no colours PyTorch's float32 decides exactly")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=0,
                        help="added to every size's seed: other colours and noise (default 0, "
                             "the committed fixture)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    net = features()
    tensors = {}
    for h, w in SIZES:
        render, gt, loss, grad, error = case(net, h, w, seed=h * 1000 + w + 7919 * args.seed)
        name = f"{h}x{w}"
        print(f"{name}: loss {loss.item():.6e}, PyTorch float32 gradient vs float64 {error:.1e}")
        tensors.update({f"{name}.render": render, f"{name}.gt": gt, f"{name}.loss": loss.reshape(1),
                        f"{name}.grad": grad})
    save_file({k: v.float().contiguous() for k, v in tensors.items()},
              str(FIXTURES / "vgg_border_ties_reference.safetensors"))


if __name__ == "__main__":
    main()
