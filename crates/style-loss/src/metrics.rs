//! The paper's evaluation metrics (CLIP ViT-L/14, reported x100): CLIP-S, CLIP-SIM, CLIP-CONS
//! and CLIP-F, from rendered views, their ground truths and the style.
//!
//! Conventions: embeddings are rows of `[n, dim]` tensors (any float dtype, normalized or not:
//! every cosine normalizes its arguments); row `i` of the renders pairs with row `i` of the
//! ground truths, and consecutive rows are consecutive views. Sums are taken in `f64`. The
//! cosine of a zero vector (e.g. the difference of two identical embeddings) is defined as 0,
//! never NaN. Nothing here is differentiated: inputs are detached.

use candle_core::{DType, Device, Tensor};

use crate::clip::{normalize_channels, ClipModel, CLIP_MEAN, CLIP_STD};
use crate::error::{Result, StyleLossError};
use crate::nn::l2_normalize;
use crate::pil_resize::pil_bicubic_resize;
use crate::style_direction::prompt_embedding;
use crate::tokenizer::ClipTokenizer;

/// Images encoded per forward pass of the vision tower in [`image_embeddings`].
const EMBEDDING_BATCH: usize = 16;

/// The paper's scores, each already multiplied by 100.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClipScores {
    /// CLIP-S: `100 mean_i cos(E_r_i, E_style)`.
    pub s: f64,
    /// CLIP-SIM: `100 mean_i cos(E_r_i - E_gt_i, E_style - E_neutral)`.
    pub sim: f64,
    /// CLIP-CONS: `100 mean_i cos(E_r_{i+1} - E_r_i, E_gt_{i+1} - E_gt_i)`; `None` for fewer
    /// than two views.
    pub cons: Option<f64>,
    /// CLIP-F: `100 mean_i cos(E_r_i, E_r_{i+1}) / mean_i cos(E_gt_i, E_gt_{i+1})`; `None` for
    /// fewer than two views.
    pub f: Option<f64>,
}

impl ClipScores {
    /// All four scores from embeddings `renders` and `ground_truths` `[n, dim]` (same `n`) and
    /// the style and neutral embeddings `[dim]`. CLIP-CONS and CLIP-F are `None` when `n < 2`;
    /// errors are those of the single metrics (empty lists, mismatched shapes, a zero mean
    /// ground-truth similarity in CLIP-F).
    pub fn from_embeddings(
        renders: &Tensor,
        ground_truths: &Tensor,
        style: &Tensor,
        neutral: &Tensor,
    ) -> Result<Self> {
        let r = rows(renders, "renders")?;
        let gt = rows(ground_truths, "ground_truths")?;
        let style = vector(style, "style")?;
        let neutral = vector(neutral, "neutral")?;
        let paired = r.len() >= 2;
        Ok(Self {
            s: s_of(&r, &style)?,
            sim: sim_of(&r, &gt, &style, &neutral)?,
            cons: if paired {
                Some(cons_of(&r, &gt)?)
            } else {
                None
            },
            f: if paired { Some(f_of(&r, &gt)?) } else { None },
        })
    }
}

/// Where the style embedding comes from.
#[derive(Clone, Copy, Debug)]
pub enum StyleReference<'a> {
    /// A style prompt, embedded through the 79 ImageNet templates (as training does).
    Prompt(&'a str),
    /// A style image `[3, h, w]` or `[1, 3, h, w]` in [0, 1], embedded with
    /// [`evaluation_preprocess`] like the renders.
    Image(&'a Tensor),
}

/// The authors' evaluation preprocess (their `metrics.py`: OpenAI CLIP's `preprocess` of each
/// PNG file, `Resize(size, BICUBIC)`, `CenterCrop(size)`, `ToTensor`, `Normalize`) of one image
/// `[3, h, w]` or `[1, c, h, w]` (`c >= 3`; only the first three channels are used) in [0, 1],
/// to CLIP input `[1, 3, size, size]` (`size` = 224 for ViT-L/14) on the image's device:
/// 1. to 8 bits as torchvision's `save_image` writes the authors' renders to PNG:
///    `floor(clamp(255 x + 0.5, 0, 255))` (an image read from an 8-bit file, `k / 255`, comes
///    back to `k` unchanged); a NaN pixel is an error;
/// 2. resize so that the short side is `size` and the long side `floor(size * long / short)`
///    (torchvision's `Resize(size)`) with Pillow's bicubic on 8-bit RGB
///    ([`pil_bicubic_resize`]): antialiased when shrinking, horizontal then vertical pass with
///    8-bit rounding and clamping after each;
/// 3. centre crop `size x size` (offsets `round((extent - size) / 2)`, ties to even, as Python's
///    `round` in torchvision's `CenterCrop`);
/// 4. `ToTensor` (`k / 255` in f32) and CLIP's per-channel normalization.
///
/// The training loss does not use this: it squashes with non-antialiased bicubic
/// ([`crate::clip::clip_preprocess`]), as the authors' training does.
pub fn evaluation_preprocess(image: &Tensor, size: usize) -> Result<Tensor> {
    let image = match image.rank() {
        3 => image.unsqueeze(0)?,
        4 => image.clone(),
        rank => {
            return Err(StyleLossError::Input {
                name: "image".into(),
                reason: format!("rank {rank}, expected [3, h, w] or [1, c, h, w]"),
            })
        }
    };
    let (n, c, h, w) = image.dims4()?;
    if n != 1 || c < 3 || h == 0 || w == 0 || size == 0 {
        return Err(StyleLossError::Input {
            name: "image".into(),
            reason: format!(
                "shape [{n}, {c}, {h}, {w}] and size {size}: expected one non-empty image with \
                 at least 3 channels and a positive size"
            ),
        });
    }
    let values = image
        .detach()
        .narrow(1, 0, 3)?
        .to_dtype(DType::F32)?
        .to_device(&Device::Cpu)?
        .flatten_all()?
        .to_vec1::<f32>()?;
    let bytes = values
        .iter()
        .map(|&v| to_8_bits(v))
        .collect::<Option<Vec<u8>>>()
        .ok_or_else(|| StyleLossError::NonFinite {
            what: "image (NaN pixel)".into(),
        })?;
    let (short, long) = (h.min(w), h.max(w));
    let long_out = size * long / short;
    let (oh, ow) = if h <= w {
        (size, long_out)
    } else {
        (long_out, size)
    };
    let resized = pil_bicubic_resize(&bytes, 3, (h, w), (oh, ow))?;
    let offset = |extent: usize| ((extent - size) as f64 / 2.0).round_ties_even() as usize;
    let (top, left) = (offset(oh), offset(ow));
    let cropped: Vec<f32> = resized
        .chunks_exact(ow)
        .enumerate()
        .filter(|(row, _)| (top..top + size).contains(&(row % oh)))
        .flat_map(|(_, line)| &line[left..left + size])
        .map(|&v| f32::from(v) / 255.0)
        .collect();
    let pixels = Tensor::from_vec(cropped, (1, 3, size, size), image.device())?;
    Ok(normalize_channels(&pixels, CLIP_MEAN, CLIP_STD)?)
}

/// torchvision `save_image`'s 8-bit conversion of one value in f32 (`x * 255 + 0.5`, clamped,
/// truncated); `None` for NaN.
fn to_8_bits(value: f32) -> Option<u8> {
    if value.is_nan() {
        return None;
    }
    Some((value * 255.0 + 0.5).clamp(0.0, 255.0) as u8)
}

/// Normalized embeddings `[n, projection_dim]` of `images` (each as
/// [`evaluation_preprocess`] takes it, on any device; sizes may differ), detached, on the
/// model's device.
pub fn image_embeddings(clip: &ClipModel, images: &[Tensor]) -> Result<Tensor> {
    if images.is_empty() {
        return Err(StyleLossError::Input {
            name: "images".into(),
            reason: "no image to embed".into(),
        });
    }
    let preprocess = |image: &Tensor| -> Result<Tensor> {
        Ok(evaluation_preprocess(image, clip.image_size())?.to_device(clip.device())?)
    };
    let embeddings = images
        .chunks(EMBEDDING_BATCH)
        .map(|chunk| {
            let pixels = chunk.iter().map(preprocess).collect::<Result<Vec<_>>>()?;
            Ok(l2_normalize(
                &clip.encode_pixels(&Tensor::cat(&pixels, 0)?)?,
            )?)
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(Tensor::cat(&embeddings, 0)?.detach())
}

/// All four scores of rendered views against their ground truths (paired by index, consecutive
/// entries being consecutive views), for a style given by `style` and the neutral prompt
/// `source_prompt` (the training source prompt, e.g. [`crate::DEFAULT_SOURCE_PROMPT`]),
/// embedded through the 79 templates. See [`ClipScores::from_embeddings`] for `None` and errors;
/// the number of renders and ground truths must match.
pub fn evaluate(
    clip: &ClipModel,
    tokenizer: &ClipTokenizer,
    style: StyleReference<'_>,
    source_prompt: &str,
    renders: &[Tensor],
    ground_truths: &[Tensor],
) -> Result<ClipScores> {
    if renders.len() != ground_truths.len() {
        return Err(StyleLossError::Input {
            name: "ground_truths".into(),
            reason: format!(
                "{} ground truths for {} renders",
                ground_truths.len(),
                renders.len()
            ),
        });
    }
    evaluate_pairs(clip, tokenizer, style, source_prompt, renders.len(), |i| {
        Ok::<_, StyleLossError>((renders[i].clone(), ground_truths[i].clone()))
    })
}

/// [`evaluate`] of `count` pairs (`count >= 1`) that `pair` gives by index, a render and its
/// ground truth (as [`image_embeddings`] takes them), asked for in order and 16 at a time: only
/// their embeddings are kept, so the pictures of a large evaluation need not all be in memory.
/// The scores are those of [`evaluate`] on the same pictures.
pub fn evaluate_pairs<E: From<StyleLossError>>(
    clip: &ClipModel,
    tokenizer: &ClipTokenizer,
    style: StyleReference<'_>,
    source_prompt: &str,
    count: usize,
    mut pair: impl FnMut(usize) -> std::result::Result<(Tensor, Tensor), E>,
) -> std::result::Result<ClipScores, E> {
    let style = match style {
        StyleReference::Prompt(prompt) => prompt_embedding(clip, tokenizer, prompt)?,
        StyleReference::Image(image) => image_embeddings(clip, std::slice::from_ref(image))?
            .squeeze(0)
            .map_err(StyleLossError::from)?,
    };
    let neutral = prompt_embedding(clip, tokenizer, source_prompt)?;
    let (mut renders, mut truths) = (Vec::new(), Vec::new());
    for first in (0..count).step_by(EMBEDDING_BATCH) {
        let (chunk_renders, chunk_truths): (Vec<Tensor>, Vec<Tensor>) = (first
            ..(first + EMBEDDING_BATCH).min(count))
            .map(&mut pair)
            .collect::<std::result::Result<Vec<_>, E>>()?
            .into_iter()
            .unzip();
        renders.push(image_embeddings(clip, &chunk_renders)?);
        truths.push(image_embeddings(clip, &chunk_truths)?);
    }
    let cat = |parts: &[Tensor]| -> Result<Tensor> {
        if parts.is_empty() {
            return Err(StyleLossError::Input {
                name: "images".into(),
                reason: "no image to embed".into(),
            });
        }
        Ok(Tensor::cat(parts, 0)?)
    };
    Ok(ClipScores::from_embeddings(
        &cat(&renders)?,
        &cat(&truths)?,
        &style,
        &neutral,
    )?)
}

/// CLIP-S, x100: `100 mean_i cos(renders_i, style)` for `renders` `[n, dim]` (`n >= 1`) and
/// `style` `[dim]`.
pub fn clip_s(renders: &Tensor, style: &Tensor) -> Result<f64> {
    s_of(&rows(renders, "renders")?, &vector(style, "style")?)
}

/// CLIP-SIM, x100: `100 mean_i cos(renders_i - ground_truths_i, style - neutral)` for `[n, dim]`
/// lists (`n >= 1`) and `[dim]` style and neutral embeddings. A render equal to its ground
/// truth contributes 0.
pub fn clip_sim(
    renders: &Tensor,
    ground_truths: &Tensor,
    style: &Tensor,
    neutral: &Tensor,
) -> Result<f64> {
    sim_of(
        &rows(renders, "renders")?,
        &rows(ground_truths, "ground_truths")?,
        &vector(style, "style")?,
        &vector(neutral, "neutral")?,
    )
}

/// CLIP-CONS, x100: `100 mean_i cos(renders_{i+1} - renders_i, ground_truths_{i+1} -
/// ground_truths_i)` for `[n, dim]` lists. An error for `n < 2` (no consecutive pair).
pub fn clip_cons(renders: &Tensor, ground_truths: &Tensor) -> Result<f64> {
    cons_of(
        &rows(renders, "renders")?,
        &rows(ground_truths, "ground_truths")?,
    )
}

/// CLIP-F, x100: `100 mean_i cos(renders_i, renders_{i+1}) / mean_i cos(ground_truths_i,
/// ground_truths_{i+1})` for `[n, dim]` lists. An error for `n < 2` and when the ground-truth
/// mean is zero.
pub fn clip_f(renders: &Tensor, ground_truths: &Tensor) -> Result<f64> {
    f_of(
        &rows(renders, "renders")?,
        &rows(ground_truths, "ground_truths")?,
    )
}

type Rows = Vec<Vec<f64>>;

fn rows(t: &Tensor, name: &str) -> Result<Rows> {
    if t.rank() != 2 || t.dim(0)? == 0 || t.dim(1)? == 0 {
        return Err(StyleLossError::Input {
            name: name.into(),
            reason: format!("shape {:?}, expected non-empty [n, dim]", t.dims()),
        });
    }
    let rows = t.detach().to_dtype(DType::F64)?.to_vec2::<f64>()?;
    if rows.iter().flatten().any(|v| !v.is_finite()) {
        return Err(StyleLossError::NonFinite { what: name.into() });
    }
    Ok(rows)
}

fn vector(t: &Tensor, name: &str) -> Result<Vec<f64>> {
    if t.rank() != 1 {
        return Err(StyleLossError::Input {
            name: name.into(),
            reason: format!("shape {:?}, expected [dim]", t.dims()),
        });
    }
    Ok(rows(&t.unsqueeze(0)?, name)?.remove(0))
}

fn check_width(a: &Rows, b: &[f64], names: (&str, &str)) -> Result<()> {
    if a[0].len() != b.len() {
        return Err(StyleLossError::Input {
            name: names.1.into(),
            reason: format!(
                "dimension {}, {} have dimension {}",
                b.len(),
                names.0,
                a[0].len()
            ),
        });
    }
    Ok(())
}

fn check_paired(r: &Rows, gt: &Rows, min_rows: usize) -> Result<()> {
    if r.len() != gt.len() {
        return Err(StyleLossError::Input {
            name: "ground_truths".into(),
            reason: format!("{} ground truths for {} renders", gt.len(), r.len()),
        });
    }
    check_width(r, &gt[0], ("renders", "ground_truths"))?;
    if r.len() < min_rows {
        return Err(StyleLossError::Input {
            name: "renders".into(),
            reason: format!(
                "{} views; at least {min_rows} consecutive views are needed",
                r.len()
            ),
        });
    }
    Ok(())
}

/// Cosine similarity; 0 when either vector is zero.
fn cosine(a: &[f64], b: &[f64]) -> f64 {
    let dot: f64 = a.iter().zip(b).map(|(x, y)| x * y).sum();
    let na = a.iter().map(|x| x * x).sum::<f64>().sqrt();
    let nb = b.iter().map(|x| x * x).sum::<f64>().sqrt();
    if na == 0.0 || nb == 0.0 {
        0.0
    } else {
        dot / (na * nb)
    }
}

fn sub(a: &[f64], b: &[f64]) -> Vec<f64> {
    a.iter().zip(b).map(|(x, y)| x - y).collect()
}

fn mean(values: impl ExactSizeIterator<Item = f64>) -> f64 {
    let n = values.len() as f64;
    values.sum::<f64>() / n
}

fn s_of(r: &Rows, style: &[f64]) -> Result<f64> {
    check_width(r, style, ("renders", "style"))?;
    Ok(100.0 * mean(r.iter().map(|e| cosine(e, style))))
}

fn sim_of(r: &Rows, gt: &Rows, style: &[f64], neutral: &[f64]) -> Result<f64> {
    check_paired(r, gt, 1)?;
    check_width(r, style, ("renders", "style"))?;
    check_width(r, neutral, ("renders", "neutral"))?;
    let direction = sub(style, neutral);
    Ok(100.0
        * mean(
            r.iter()
                .zip(gt)
                .map(|(e, g)| cosine(&sub(e, g), &direction)),
        ))
}

fn cons_of(r: &Rows, gt: &Rows) -> Result<f64> {
    check_paired(r, gt, 2)?;
    Ok(100.0
        * mean(
            r.windows(2)
                .zip(gt.windows(2))
                .map(|(rw, gw)| cosine(&sub(&rw[1], &rw[0]), &sub(&gw[1], &gw[0]))),
        ))
}

fn f_of(r: &Rows, gt: &Rows) -> Result<f64> {
    check_paired(r, gt, 2)?;
    let rendered = mean(r.windows(2).map(|w| cosine(&w[0], &w[1])));
    let truth = mean(gt.windows(2).map(|w| cosine(&w[0], &w[1])));
    if truth == 0.0 {
        return Err(StyleLossError::Input {
            name: "ground_truths".into(),
            reason: "CLIP-F divides by the mean cosine of consecutive ground-truth embeddings, \
                     which is 0"
                .into(),
        });
    }
    Ok(100.0 * rendered / truth)
}
