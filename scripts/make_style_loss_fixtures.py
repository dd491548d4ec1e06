#!/usr/bin/env python3
"""Generate the PyTorch reference fixtures of the `style-loss` crate.

How to run (from the repository root; needs only PyPI):

    python3 -m venv /tmp/style-loss-venv
    /tmp/style-loss-venv/bin/pip install torch torchvision transformers open_clip_torch safetensors
    /tmp/style-loss-venv/bin/python scripts/make_style_loss_fixtures.py

It writes `crates/style-loss/tests/fixtures/` (a few hundred kB). The Rust tests read these files
and need neither Python nor a network. Everything uses random weights with a fixed seed: tiny CLIP
and tiny-channel VGG-19 models that keep the real layer structure and checkpoint layouts
(transformers `CLIPModel`, torchvision `vgg19().features`), so real weights load the same way.

Oracles, one per Rust component:
  * CLIP towers and the directional loss gradient: `transformers.CLIPModel` (float64).
  * Resizes: `torch.nn.functional.interpolate` (bicubic, align_corners=False, no antialias) and
    torchvision `resize` (bilinear with antialias, as `transforms.Resize` does on tensors).
  * Perspective warp: torchvision `functional.perspective` with fill 0, as `RandomPerspective`
    calls it on tensors.
  * VGG features: torchvision's VGG with vgg19's layer list (channels divided by 16), once with
    random biases and once as torchvision initialises it (Kaiming weights, zero biases: exact
    zeros before the ReLUs), on random images and on images with flat regions (white
    backgrounds, constant borders, flat fields), where 2x2 max-pool windows tie.
  * Token ids: `transformers.CLIPTokenizer` built from CLIP's real BPE vocabulary (shipped by
    open_clip), cross-checked against open_clip's `SimpleTokenizer` (OpenAI's original code).
  * The four losses together: the authors' training step (3D/train_style.py) transcribed with the
    patch augmentation parameters drawn here and written out; the render has flat regions and
    pixels exactly equal to the ground truth (ties in max pooling, zeros in |render - gt|).
"""

import copy
import gzip
import json
import os
from pathlib import Path

import open_clip
import open_clip.tokenizer
import torch
import torch.nn.functional as F
import torchvision.transforms.functional as TF
from safetensors.torch import save_file
from torchvision.models.vgg import VGG, make_layers
from torchvision.transforms import InterpolationMode, RandomPerspective
from transformers import CLIPConfig, CLIPModel, CLIPTokenizer

OUT = Path(__file__).resolve().parent.parent / "crates" / "style-loss" / "tests" / "fixtures"
CLIP_MEAN = torch.tensor([0.48145466, 0.4578275, 0.40821073], dtype=torch.float64).view(1, 3, 1, 1)
CLIP_STD = torch.tensor([0.26862954, 0.26130258, 0.27577711], dtype=torch.float64).view(1, 3, 1, 1)
IMAGENET_MEAN = torch.tensor([0.485, 0.456, 0.406], dtype=torch.float64).view(1, 3, 1, 1)
IMAGENET_STD = torch.tensor([0.229, 0.224, 0.225], dtype=torch.float64).view(1, 3, 1, 1)
# vgg19 ("E") with every channel count divided by 16: same layers, same `features.N` indices.
TINY_VGG19_CFG = [4, 4, "M", 8, 8, "M", 16, 16, 16, 16, "M", 32, 32, 32, 32, "M", 32, 32, 32, 32, "M"]
RELU4_2, RELU5_2 = 22, 31


def f32(tensors):
    """Detach, make contiguous, store as float32 (ids stay int64)."""
    out = {}
    for name, t in tensors.items():
        t = t.detach().contiguous()
        out[name] = t if t.dtype == torch.int64 else t.to(torch.float32)
    return out


def save(name, tensors):
    save_file(f32(tensors), str(OUT / name))


def clip_normalize(image, size):
    """The authors' clip_normalize with 224 replaced by the model's image size."""
    image = F.interpolate(image, size=size, mode="bicubic")
    return (image - CLIP_MEAN) / CLIP_STD


def unit(x):
    return x / x.norm(dim=-1, keepdim=True)


# --------------------------------------------------------------------------------------------
# Tiny CLIP
# --------------------------------------------------------------------------------------------
def make_tiny_clip():
    config = CLIPConfig(
        text_config=dict(
            vocab_size=1000, hidden_size=32, intermediate_size=64, num_hidden_layers=2,
            num_attention_heads=4, max_position_embeddings=77, bos_token_id=998,
            eos_token_id=999, pad_token_id=999, hidden_act="quick_gelu",
        ),
        vision_config=dict(
            hidden_size=24, intermediate_size=48, num_hidden_layers=2, num_attention_heads=4,
            image_size=64, patch_size=16, hidden_act="quick_gelu",
        ),
        projection_dim=16,
    )
    model = CLIPModel(config)
    # Weights large enough that attention is far from uniform and every term matters.
    with torch.no_grad():
        for name, p in model.named_parameters():
            if "norm" in name or "layrnorm" in name:
                p.copy_((1.0 if name.endswith("weight") else 0.0) + 0.2 * torch.randn_like(p))
            elif name.endswith("bias"):
                p.copy_(0.1 * torch.randn_like(p))
            elif p.dim() >= 2 and "embedding" not in name:
                fan_in = p[0].numel()
                p.copy_(torch.randn_like(p) * 1.5 / fan_in**0.5)
            else:
                p.copy_(0.5 * torch.randn_like(p))
    model.save_pretrained(str(OUT / "tiny_clip"), safe_serialization=True)
    for extra in OUT.joinpath("tiny_clip").iterdir():
        if extra.name not in ("config.json", "model.safetensors"):
            extra.unlink()
    return model.double().eval()


def image_embeds(model, pixels):
    return model.get_image_features(pixel_values=pixels).pooler_output


def text_embeds(model, ids):
    return model.get_text_features(input_ids=ids).pooler_output


def random_ids(rows, lengths, eos):
    ids = torch.full((rows, 77), eos, dtype=torch.int64)
    for r, n in enumerate(lengths):
        ids[r, 0] = eos - 1  # bos
        ids[r, 1 : n - 1] = torch.randint(0, eos - 1, (n - 2,))
    return ids


def clip_fixtures(model):
    size = model.config.vision_config.image_size
    eos = model.config.text_config.eos_token_id
    pixels = torch.randn(2, 3, size, size, dtype=torch.float64)
    ids = random_ids(3, [5, 12, 77], eos)
    style_ids = random_ids(3, [7, 9, 11], eos)
    source_ids = random_ids(2, [6, 8], eos)
    with torch.no_grad():
        img = unit(image_embeds(model, pixels))
        txt = unit(text_embeds(model, ids))
        style = unit(text_embeds(model, style_ids).mean(0))
        source = unit(text_embeds(model, source_ids).mean(0))
        direction = unit(style - source)

    # Directional loss and its image gradient (render 40x56 is bicubic-upsampled to 64x64).
    render = torch.rand(1, 3, 40, 56, dtype=torch.float64, requires_grad=True)
    gt = torch.rand(1, 3, 40, 56, dtype=torch.float64)
    with torch.no_grad():
        gt_embed = unit(image_embeds(model, clip_normalize(gt, size)))
    e = unit(image_embeds(model, clip_normalize(render, size)))
    d = unit(e - gt_embed)
    loss = (1 - torch.cosine_similarity(d, direction.view(1, -1), dim=1)).mean()
    loss.backward()
    save(
        "clip_reference.safetensors",
        dict(
            pixel_values=pixels, image_embeds=img, input_ids=ids, text_embeds=txt,
            style_ids=style_ids, source_ids=source_ids, style_embed=style, source_embed=source,
            style_direction=direction, render=render, gt=gt, gt_embed=gt_embed,
            directional_loss=loss.reshape(1), directional_grad=render.grad,
        ),
    )


# --------------------------------------------------------------------------------------------
# Resizes and the perspective warp
# --------------------------------------------------------------------------------------------
def resize_fixtures():
    tensors = {}
    cases = {
        "bicubic_up": ((2, 3, 13, 17), (30, 41), "bicubic"),
        "bicubic_down": ((1, 3, 50, 37), (20, 24), "bicubic"),
        "bicubic_to_224": ((1, 1, 96, 80), (224, 224), "bicubic"),
        "bilinear_aa_up": ((1, 3, 24, 24), (64, 64), "bilinear_aa"),
        "bilinear_aa_down": ((1, 2, 45, 31), (16, 12), "bilinear_aa"),
    }
    for name, (shape, size, mode) in cases.items():
        x = torch.rand(*shape, dtype=torch.float64, requires_grad=True)
        if mode == "bicubic":
            y = F.interpolate(x, size=size, mode="bicubic", align_corners=False)
        else:
            y = TF.resize(x, list(size), interpolation=InterpolationMode.BILINEAR, antialias=True)
        upstream = torch.randn_like(y)
        (y * upstream).sum().backward()
        tensors.update({f"{name}.input": x, f"{name}.output": y, f"{name}.upstream": upstream,
                        f"{name}.grad": x.grad})
    save("resize_reference.safetensors", tensors)
    json.dump({n: {"mode": m, "size": list(s)} for n, (_, s, m) in cases.items()},
              open(OUT / "resize_reference.json", "w"), indent=1)


def perspective(img, endpoints):
    h, w = img.shape[-2:]
    start = [[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]]
    return TF.perspective(img, start, endpoints, InterpolationMode.BILINEAR, fill=[0.0] * img.shape[1])


def perspective_fixtures():
    h, w = 24, 20
    cases = {
        "identity": [[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]],
        "strongest": [[5, 6], [w - 6, 6], [w - 6, h - 7], [5, h - 7]],
    }
    for k in range(3):
        _, end = RandomPerspective.get_params(w, h, 0.5)
        cases[f"random{k}"] = end
    tensors = {}
    for name, end in cases.items():
        x = torch.rand(1, 3, h, w, dtype=torch.float64, requires_grad=True)
        y = perspective(x, end)
        upstream = torch.randn_like(y)
        (y * upstream).sum().backward()
        tensors.update({f"{name}.input": x, f"{name}.output": y, f"{name}.upstream": upstream,
                        f"{name}.grad": x.grad})
    save("perspective_reference.safetensors", tensors)
    json.dump(cases, open(OUT / "perspective_reference.json", "w"), indent=1)


# --------------------------------------------------------------------------------------------
# Tiny VGG-19
# --------------------------------------------------------------------------------------------
def make_tiny_vgg():
    vgg = VGG(make_layers(TINY_VGG19_CFG), init_weights=True)
    with torch.no_grad():
        for name, p in vgg.features.named_parameters():
            if name.endswith("bias"):
                p.copy_(0.05 * torch.randn_like(p))
    weights = {f"features.{k}": v for k, v in vgg.features.state_dict().items()}
    save("tiny_vgg19.safetensors", weights)
    return vgg.features.double().eval()


def make_torchvision_init_vgg():
    """torchvision's own initialisation: Kaiming-normal weights (fan_out) and zero biases, so a
    channel that is zero everywhere in a neighbourhood gives a pre-activation of exactly 0."""
    vgg = VGG(make_layers(TINY_VGG19_CFG), init_weights=True)
    weights = {f"features.{k}": v for k, v in vgg.features.state_dict().items()}
    save("tiny_vgg19_torchvision_init.safetensors", weights)
    return vgg.features.double().eval()


def vgg_features(features, image):
    """Run torchvision's features up to index 31 and keep the outputs of 22 and 31."""
    x = (image - IMAGENET_MEAN.to(image.dtype)) / IMAGENET_STD.to(image.dtype)
    kept = {}
    for index, layer in enumerate(features):
        x = layer(x)
        if index in (RELU4_2, RELU5_2):
            kept[index] = x.clone()
        if index == RELU5_2:
            break
    return kept[RELU4_2], kept[RELU5_2]


def vgg_fixtures(features):
    image = torch.rand(1, 3, 36, 52, dtype=torch.float64, requires_grad=True)
    f4, f5 = vgg_features(features, image)
    w4, w5 = torch.randn_like(f4), torch.randn_like(f5)
    ((f4 * w4).sum() + (f5 * w5).sum()).backward()
    save("vgg_reference.safetensors",
         dict(image=image, relu4_2=f4, relu5_2=f5, upstream4_2=w4, upstream5_2=w5, grad=image.grad))


def object_on_white(h, w):
    """A white background with a random object in a box: flat around, textured inside."""
    top, bottom, left, right = h // 4, 3 * h // 4, w // 4, 2 * w // 3
    image = torch.ones(1, 3, h, w, dtype=torch.float64)
    image[:, :, top:bottom, left:right] = torch.rand(1, 3, bottom - top, right - left, dtype=torch.float64)
    return image


def noise_in_black_border(h, w, border):
    image = torch.zeros(1, 3, h, w, dtype=torch.float64)
    image[:, :, border:-border, border:-border] = torch.rand(1, 3, h - 2 * border, w - 2 * border, dtype=torch.float64)
    return image


def two_flat_fields(h, w, left, right):
    """Two flat colours side by side (split at an odd column) with a small noisy blob."""
    image = torch.empty(1, 3, h, w, dtype=torch.float64)
    image[..., : w // 2 + 1] = left
    image[..., w // 2 + 1 :] = right
    image[:, :, 4:12, 6:16] = torch.rand(1, 3, 8, 10, dtype=torch.float64)
    return image


def vgg_tie_fixtures(vggs):
    """The content loss (conv4_2 + conv5_2 MSE) and its image gradient on images with flat
    regions, rectangular, for both weight sets: render and ground truth share their flat parts,
    as a render and its view do.

    In float32, the precision a run has: in float64 rounding differs between positions and breaks
    a few of the ties float32 keeps (4 of 597 windows at the second pool of `white_background`),
    which would test rounding noise instead of the tie rule."""
    cases = {
        "white_background": ("torchvision_init", lambda: object_on_white(40, 56)),
        "constant_border": ("torchvision_init", lambda: noise_in_black_border(52, 36, 6)),
        "flat_fields": ("random_bias", lambda: two_flat_fields(44, 60, 0.2, 0.9)),
        "flat_gray": ("random_bias", lambda: torch.full((1, 3, 32, 48), 0.5, dtype=torch.float64)),
        "white_background_random_bias": ("random_bias", lambda: object_on_white(48, 40)),
    }
    vggs = {name: copy.deepcopy(features).float() for name, features in vggs.items()}
    tensors = {}
    for name, (weights, make) in cases.items():
        render = make().float().requires_grad_(True)
        gt = make().float() if name != "flat_gray" else torch.full_like(render, 0.6)
        features = vggs[weights]
        with torch.no_grad():
            gt4, gt5 = vgg_features(features, gt)
        f4, f5 = vgg_features(features, render)
        loss = ((f4 - gt4) ** 2).mean() + ((f5 - gt5) ** 2).mean()
        loss.backward()
        tensors.update({f"{name}.render": render, f"{name}.gt": gt, f"{name}.loss": loss.reshape(1),
                        f"{name}.grad": render.grad})
    save("vgg_ties_reference.safetensors", tensors)
    json.dump({name: weights for name, (weights, _) in cases.items()},
              open(OUT / "vgg_ties_reference.json", "w"), indent=1)


# --------------------------------------------------------------------------------------------
# The four losses of one stylization step
# --------------------------------------------------------------------------------------------
def loss_fixtures(model, vgg):
    size = model.config.vision_config.image_size
    h, w, patch, num_patch = 80, 72, 32, 3
    weights = dict(directional=5.0, patch=90.0, content=0.8, background=50.0)
    background = torch.ones(3, dtype=torch.float64)
    gt = torch.rand(1, 3, h, w, dtype=torch.float64) * 0.99
    gt[:, :, 50:, 10:40] = 1.0  # exactly the background colour: the background-loss mask
    render_init = torch.rand(1, 3, h, w, dtype=torch.float64)
    render_init[:, :, 50:70, 10:40] = 1.0  # equal to the ground truth there: |render - gt| = 0
    render_init[:, :, :16, :] = 0.25  # a flat band: tied max-pool windows in VGG
    direction = unit(torch.randn(model.config.projection_dim, dtype=torch.float64))
    crops, corners = [], []
    for _ in range(num_patch):
        crops.append([int(torch.randint(0, h - patch + 1, (1,))), int(torch.randint(0, w - patch + 1, (1,)))])
        corners.append(RandomPerspective.get_params(patch, patch, 0.5)[1])

    with torch.no_grad():
        gt_embed = unit(image_embeds(model, clip_normalize(gt, size)))
        gt4, gt5 = vgg_features(vgg, gt)

    def terms(render):
        f4, f5 = vgg_features(vgg, render)
        content = ((gt4 - f4) ** 2).mean() + ((gt5 - f5) ** 2).mean()
        patches = []
        for (top, left), end in zip(crops, corners):
            crop = render[:, :, top : top + patch, left : left + patch]
            warped = perspective(crop, end)
            patches.append(TF.resize(warped, [size], interpolation=InterpolationMode.BILINEAR, antialias=True))
        e = unit(image_embeds(model, clip_normalize(torch.cat(patches), size)))
        d = unit(e - gt_embed)
        patch_loss = (1 - torch.cosine_similarity(d, direction.repeat(num_patch, 1), dim=1)).mean()
        mask = gt[0].sum(0) == background.sum()
        bg = (render[0] - gt[0]).abs().mean(0)[mask].mean()
        e = unit(image_embeds(model, clip_normalize(render, size)))
        d = unit(e - gt_embed)
        directional = (1 - torch.cosine_similarity(d, direction.view(1, -1), dim=1)).mean()
        return dict(directional=directional, patch=patch_loss, content=content, background=bg)

    tensors = dict(render=render_init, gt=gt, style_direction=direction, gt_embed=gt_embed,
                   gt_relu4_2=gt4, gt_relu5_2=gt5)
    values = {}
    for name in list(weights) + ["total"]:
        render = render_init.clone().requires_grad_(True)
        t = terms(render)
        loss = sum(weights[k] * t[k] for k in weights) if name == "total" else t[name]
        loss.backward()
        values[name] = loss.detach().item()
        tensors[f"grad.{name}"] = render.grad
    save("loss_reference.safetensors", tensors)
    json.dump(dict(patch_size=patch, num_patch=num_patch, weights=weights, crops=crops,
                   corners=corners, background=background.tolist(), values=values),
              open(OUT / "loss_reference.json", "w"), indent=1)


# --------------------------------------------------------------------------------------------
# Tokenizer
# --------------------------------------------------------------------------------------------
PROMPTS = [
    "Starry Night by Vincent van Gogh",
    "a Photo",
    "fire",
    "a bad photo of a fire.",
    "a photo of the hard to see Starry Night by Vincent van Gogh.",
    "itap of my fire.",
    "the  embroidered\tCafé's crème-brûlée, 1889!",
    " ".join(["fire"] * 90),
]


def openai_vocab():
    """CLIP's vocabulary, built exactly as OpenAI's SimpleTokenizer builds it."""
    bpe_path = Path(open_clip.__file__).parent / "bpe_simple_vocab_16e6.txt.gz"
    merges = gzip.open(bpe_path).read().decode("utf-8").split("\n")[1 : 49152 - 256 - 2 + 1]
    merges = [tuple(m.split()) for m in merges]
    byte_chars = list(open_clip.tokenizer.bytes_to_unicode().values())
    vocab = byte_chars + [c + "</w>" for c in byte_chars] + ["".join(m) for m in merges]
    vocab += ["<|startoftext|>", "<|endoftext|>"]
    return {tok: i for i, tok in enumerate(vocab)}, merges


def used_merges(pretokenized_words, ranks):
    """The merges BPE applies to these words; any subset containing them tokenizes them alike."""
    used = set()
    for word in pretokenized_words:
        parts = list(word[:-1]) + [word[-1] + "</w>"]
        while len(parts) > 1:
            pairs = [(ranks.get((a, b), 1 << 30), i) for i, (a, b) in enumerate(zip(parts, parts[1:]))]
            rank, i = min(pairs)
            if rank == 1 << 30:
                break
            pair = (parts[i], parts[i + 1])
            used.add(pair)
            merged, j = [], 0
            while j < len(parts):
                if j + 1 < len(parts) and (parts[j], parts[j + 1]) == pair:
                    merged.append(parts[j] + parts[j + 1])
                    j += 2
                else:
                    merged.append(parts[j])
                    j += 1
            parts = merged
    return used


def tokenizer_fixtures():
    vocab, merges = openai_vocab()
    full = CLIPTokenizer(vocab=vocab, merges=merges)
    golden = full(PROMPTS, padding="max_length", truncation=True, max_length=77)["input_ids"]

    # Independent check with OpenAI's own tokenizer code (it pads with 0 instead of end tokens).
    simple = open_clip.tokenizer.SimpleTokenizer()
    for prompt, ids in zip(PROMPTS, golden):
        ref = simple([prompt])[0].tolist()
        n = ref.index(0) if 0 in ref else 77
        assert ids[:n] == ref[:n], (prompt, ids[:n], ref[:n])
        assert all(i == 49407 for i in ids[n:]), prompt

    # Keep the tokenizer.json small: only the merges these prompts use (ids and ranks unchanged).
    backend = full.backend_tokenizer
    words = []
    for prompt in PROMPTS:
        normalized = backend.normalizer.normalize_str(prompt)
        words += [w for w, _ in backend.pre_tokenizer.pre_tokenize_str(normalized)]
    ranks = {m: r for r, m in enumerate(merges)}
    keep = used_merges(words, ranks)
    doc = json.loads(backend.to_str())
    doc["model"]["merges"] = [m for m in doc["model"]["merges"] if tuple(m if isinstance(m, list) else m.split()) in keep]
    base = set(list(vocab)[:512]) | {"<|startoftext|>", "<|endoftext|>"}
    base |= {"".join(m) for m in keep}
    doc["model"]["vocab"] = {t: i for t, i in doc["model"]["vocab"].items() if t in base}
    os.makedirs(OUT / "tokenizer", exist_ok=True)
    path = OUT / "tokenizer" / "tokenizer.json"
    path.write_text(json.dumps(doc, ensure_ascii=False))

    from tokenizers import Tokenizer

    subset = Tokenizer.from_file(str(path))
    subset.enable_padding(length=77, pad_id=49407, pad_token="<|endoftext|>")
    subset.enable_truncation(77)
    for prompt, ids in zip(PROMPTS, golden):
        assert subset.encode(prompt).ids == ids, prompt
    rows = [json.dumps(dict(prompt=p, ids=ids), ensure_ascii=False) for p, ids in zip(PROMPTS, golden)]
    (OUT / "tokenizer_reference.json").write_text("[\n" + ",\n".join(rows) + "\n]\n")


def main():
    torch.manual_seed(0)
    OUT.mkdir(parents=True, exist_ok=True)
    model = make_tiny_clip()
    clip_fixtures(model)
    resize_fixtures()
    perspective_fixtures()
    vgg = make_tiny_vgg()
    vgg_fixtures(vgg)
    vgg_torchvision_init = make_torchvision_init_vgg()
    loss_fixtures(model, vgg_torchvision_init)
    tokenizer_fixtures()
    vgg_tie_fixtures(dict(random_bias=vgg, torchvision_init=vgg_torchvision_init))
    total = sum(f.stat().st_size for f in OUT.rglob("*") if f.is_file())
    print(f"wrote {OUT} ({total / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
