//! The four CLIPGaussian losses of one view and their gradient with respect to the rendered
//! image: directional (CLIP), patch (CLIP on warped crops), content (VGG-19) and background
//! (L1 on background pixels), weighted and summed.

use candle_core::{DType, Tensor};
use rand::Rng;

use crate::clip::ClipModel;
use crate::cpu_elements::generic_path;
use crate::error::{Result, StyleLossError};
use crate::patches::{PatchAugmentation, PatchSettings};
use crate::style_direction::StyleDirection;
use crate::terms;
use crate::transfers::join_counted;
use crate::vgg::{Vgg19Features, VggFeatures};

/// The weights `lambda` of the four terms. A zero weight skips all work for its term.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LossWeights {
    /// `lambda_d` of the directional loss (paper: 5).
    pub directional: f64,
    /// `lambda_p` of the patch loss (paper: 90).
    pub patch: f64,
    /// `lambda_c` of the content loss (paper: 0.8; 0.5 for video).
    pub content: f64,
    /// `lambda_b` of the background loss (paper: 1000 for 3D objects, 0 for scenes).
    pub background: f64,
}

impl Default for LossWeights {
    /// The paper's 3D scene weights: 5, 90, 0.8, 0.
    fn default() -> Self {
        Self {
            directional: 5.0,
            patch: 90.0,
            content: 0.8,
            background: 0.0,
        }
    }
}

/// One value per term (unweighted); a skipped term is 0.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LossTerms {
    /// `L_d`.
    pub directional: f64,
    /// `L_p`.
    pub patch: f64,
    /// `L_c`.
    pub content: f64,
    /// `L_b`.
    pub background: f64,
}

/// The result of [`StyleLoss::loss_and_grad`].
#[derive(Clone, Debug)]
pub struct StyleLossOutput {
    /// The unweighted terms.
    pub terms: LossTerms,
    /// `sum lambda_i L_i`.
    pub total: f64,
    /// `d total / d image`, in the shape the image was given.
    pub grad: Tensor,
}

/// The background target of a view: which pixels are background and their ground truth.
#[derive(Clone, Debug)]
struct BackgroundTarget {
    gt: Tensor,
    /// `[1, 1, h, w]`, 1 on background pixels.
    mask: Tensor,
    /// Number of background pixels.
    count: f64,
}

/// What a view contributes to the losses, computed once from its ground-truth image.
#[derive(Clone, Debug)]
pub struct ViewCache {
    height: usize,
    width: usize,
    /// Normalized CLIP embedding of the ground truth `[1, dim]` (directional or patch loss).
    clip_embedding: Option<Tensor>,
    /// VGG features of the ground truth (content loss).
    vgg: Option<VggFeatures>,
    /// Background pixels (background loss).
    background: Option<BackgroundTarget>,
}

impl ViewCache {
    /// The cached normalized CLIP embedding `[1, dim]` of the ground truth, if any.
    pub fn clip_embedding(&self) -> Option<&Tensor> {
        self.clip_embedding.as_ref()
    }

    /// The tensors it holds, by name (for [`ViewCache::save`]).
    fn named_tensors(&self) -> Vec<(&'static str, &Tensor)> {
        let mut named = Vec::new();
        if let Some(e) = &self.clip_embedding {
            named.push(("clip_embedding", e));
        }
        if let Some(v) = &self.vgg {
            named.push(("vgg.relu4_2", &v.relu4_2));
            named.push(("vgg.relu5_2", &v.relu5_2));
        }
        if let Some(b) = &self.background {
            named.push(("background.gt", &b.gt));
            named.push(("background.mask", &b.mask));
        }
        named
    }

    /// Bytes of its tensors.
    pub fn bytes(&self) -> u64 {
        self.named_tensors()
            .iter()
            .map(|(_, t)| (t.elem_count() * t.dtype().size_in_bytes()) as u64)
            .sum()
    }

    /// Writes the cache to `path` (safetensors, every value as held: reading it back with
    /// [`ViewCache::load`] gives the same losses bit for bit).
    pub fn save(&self, path: &std::path::Path) -> Result<()> {
        let tensors: std::collections::HashMap<String, Tensor> = self
            .named_tensors()
            .into_iter()
            .map(|(name, t)| (name.to_string(), t.clone()))
            .collect();
        candle_core::safetensors::save(&tensors, path)?;
        Ok(())
    }

    /// The cache [`ViewCache::save`] wrote to `path`, for a view of `height x width`, its
    /// tensors on `device`.
    pub fn load(
        path: &std::path::Path,
        height: usize,
        width: usize,
        device: &candle_core::Device,
    ) -> Result<Self> {
        let mut tensors = candle_core::safetensors::load(path, device)?;
        let vgg = match (tensors.remove("vgg.relu4_2"), tensors.remove("vgg.relu5_2")) {
            (Some(relu4_2), Some(relu5_2)) => Some(VggFeatures { relu4_2, relu5_2 }),
            _ => None,
        };
        let background = match (
            tensors.remove("background.gt"),
            tensors.remove("background.mask"),
        ) {
            (Some(gt), Some(mask)) => {
                let count = scalar(&mask.sum_all()?)?;
                Some(BackgroundTarget { gt, mask, count })
            }
            _ => None,
        };
        Ok(Self {
            height,
            width,
            clip_embedding: tensors.remove("clip_embedding"),
            vgg,
            background,
        })
    }
}

/// The background mask the reference derives from a ground-truth image: 1 where every channel
/// equals `color` exactly, else 0. `gt` is `[3, h, w]` or `[1, 3, h, w]`; result `[h, w]`.
pub fn background_mask_from_color(gt: &Tensor, color: [f32; 3]) -> Result<Tensor> {
    let gt = as_batch_of_one(gt, "gt")?;
    let color = Tensor::new(&color, gt.device())?.reshape((1, 3, 1, 1))?;
    let equal = gt.broadcast_eq(&color)?.to_dtype(DType::F32)?;
    Ok(equal.min_keepdim(1)?.squeeze(1)?.squeeze(0)?)
}

/// `[3, h, w]` or `[1, 3, h, w]` -> `[1, 3, h, w]`.
fn as_batch_of_one(image: &Tensor, name: &str) -> Result<Tensor> {
    let image = match image.rank() {
        3 => image.unsqueeze(0)?,
        _ => image.clone(),
    };
    match image.dims() {
        [1, 3, _, _] => Ok(image.to_dtype(DType::F32)?),
        dims => Err(StyleLossError::Input {
            name: name.into(),
            reason: format!("shape {dims:?}, expected [3, h, w] or [1, 3, h, w]"),
        }),
    }
}

fn scalar(t: &Tensor) -> Result<f64> {
    Ok(t.to_dtype(DType::F64)?.to_scalar::<f64>()?)
}

/// One of the four terms; the discriminant indexes [`StyleLoss::term_tensors`]'s array.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Term {
    Directional = 0,
    Patch = 1,
    Content = 2,
    Background = 3,
}

impl Term {
    /// The term's name in messages.
    fn name(self) -> &'static str {
        match self {
            Term::Directional => "directional",
            Term::Patch => "patch",
            Term::Content => "content",
            Term::Background => "background",
        }
    }

    /// Its weight `lambda`.
    fn weight(self, weights: &LossWeights) -> f64 {
        match self {
            Term::Directional => weights.directional,
            Term::Patch => weights.patch,
            Term::Content => weights.content,
            Term::Background => weights.background,
        }
    }
}

/// The terms that run CLIP.
const CLIP_TERMS: [Term; 2] = [Term::Directional, Term::Patch];
/// The terms computed on the image itself (VGG-19 features, pixels).
const IMAGE_TERMS: [Term; 2] = [Term::Content, Term::Background];

/// A group of terms' weighted sum and image gradient, and the values of the terms that are on.
struct GroupValue {
    present: Vec<(Term, Tensor)>,
    total: Tensor,
    grad: Tensor,
}

/// The error for a view cache built without `what`.
fn missing_from_cache(what: &str) -> StyleLossError {
    StyleLossError::Input {
        name: "cache".into(),
        reason: format!("the view cache has no {what}; build it with this StyleLoss"),
    }
}

/// The ground truth's CLIP embedding of a view cache.
fn clip_embedding_of(cache: &ViewCache) -> Result<&Tensor> {
    cache
        .clip_embedding
        .as_ref()
        .ok_or_else(|| missing_from_cache("CLIP embedding"))
}

/// `(a(), b())`: at once on the CPU (two rayon tasks, their transfers counted on this thread),
/// one after the other on a GPU and under [`crate::GenericPath`], which stands for it.
fn at_once<RA: Send, RB: Send>(
    device: &candle_core::Device,
    a: impl FnOnce() -> RA + Send,
    b: impl FnOnce() -> RB + Send,
) -> (RA, RB) {
    if device.is_cpu() && !generic_path() {
        join_counted(a, b)
    } else {
        (a(), b())
    }
}

/// Refuses an image whose size is not the one its view was cached at.
fn check_view_size(image: &Tensor, cache: &ViewCache) -> Result<()> {
    let (_, _, height, width) = image.dims4()?;
    if (height, width) != (cache.height, cache.width) {
        return Err(StyleLossError::Input {
            name: "image".into(),
            reason: format!(
                "{height}x{width}, but the view was cached at {}x{}",
                cache.height, cache.width
            ),
        });
    }
    Ok(())
}

/// The style loss of a stylization run: models, style direction, weights, patch settings.
#[derive(Clone, Debug)]
pub struct StyleLoss {
    clip: ClipModel,
    vgg: Option<Vgg19Features>,
    direction: StyleDirection,
    weights: LossWeights,
    patches: PatchSettings,
}

impl StyleLoss {
    /// Checks that every term with a positive weight has what it needs (VGG for the content
    /// loss) and that the weights are finite and non-negative. Models are taken by value: a
    /// clone of a [`ClipModel`] or [`Vgg19Features`] shares its weights (candle tensors are
    /// reference-counted), so pass clones to build several losses on one model. For one term
    /// alone, without the others' models, see [`crate::terms`].
    pub fn new(
        clip: ClipModel,
        vgg: Option<Vgg19Features>,
        direction: StyleDirection,
        weights: LossWeights,
        patches: PatchSettings,
    ) -> Result<Self> {
        let all = [
            ("directional", weights.directional),
            ("patch", weights.patch),
            ("content", weights.content),
            ("background", weights.background),
        ];
        for (name, w) in all {
            if !(w.is_finite() && w >= 0.0) {
                return Err(StyleLossError::Config {
                    field: format!("weights.{name}"),
                    value: w.to_string(),
                    reason: "must be finite and >= 0".into(),
                });
            }
        }
        if weights.content > 0.0 && vgg.is_none() {
            return Err(StyleLossError::Config {
                field: "weights.content".into(),
                value: weights.content.to_string(),
                reason: "a content loss needs VGG-19 weights".into(),
            });
        }
        if weights.patch > 0.0 && patches.num_patches == 0 {
            return Err(StyleLossError::Config {
                field: "patches.num_patches".into(),
                value: "0".into(),
                reason: "a patch loss needs at least one patch".into(),
            });
        }
        let expected_dim = clip.config().projection_dim;
        if direction.as_tensor().dims() != [expected_dim] {
            return Err(StyleLossError::Input {
                name: "direction".into(),
                reason: format!(
                    "shape {:?}, the CLIP model embeds in {expected_dim} dimensions",
                    direction.as_tensor().dims()
                ),
            });
        }
        Ok(Self {
            clip,
            vgg,
            direction,
            weights,
            patches,
        })
    }

    /// The weights.
    pub fn weights(&self) -> LossWeights {
        self.weights
    }

    /// The patch settings.
    pub fn patch_settings(&self) -> &PatchSettings {
        &self.patches
    }

    /// Computes what a view needs, once: the GT's CLIP embedding and VGG features, and its
    /// background mask (`[h, w]`, 1 = background; see [`background_mask_from_color`]) when the
    /// background loss is on. `gt` is `[3, h, w]` or `[1, 3, h, w]` in [0, 1]. On the CPU the
    /// CLIP embedding and the VGG features are computed at once.
    pub fn cache_view(&self, gt: &Tensor, background_mask: Option<&Tensor>) -> Result<ViewCache> {
        let gt = as_batch_of_one(gt, "gt")?.detach();
        let (_, _, height, width) = gt.dims4()?;
        let w = &self.weights;
        let clip_embedding = || -> Result<Option<Tensor>> {
            Ok(if w.directional > 0.0 || w.patch > 0.0 {
                Some(self.clip.encode_images(&gt)?.detach())
            } else {
                None
            })
        };
        let vgg = || -> Result<Option<VggFeatures>> {
            Ok(match (&self.vgg, w.content > 0.0) {
                (Some(vgg), true) => Some(vgg.forward(&gt)?.detach()),
                _ => None,
            })
        };
        let (clip_embedding, vgg) = at_once(gt.device(), clip_embedding, vgg);
        let (clip_embedding, vgg) = (clip_embedding?, vgg?);
        let background = match (background_mask, w.background > 0.0) {
            (Some(mask), true) => {
                if mask.dims() != [height, width] {
                    return Err(StyleLossError::Input {
                        name: "background_mask".into(),
                        reason: format!("shape {:?}, expected [{height}, {width}]", mask.dims()),
                    });
                }
                let mask = mask.to_dtype(DType::F32)?.reshape((1, 1, height, width))?;
                let count = scalar(&mask.sum_all()?)?;
                Some(BackgroundTarget {
                    gt: gt.clone(),
                    mask,
                    count,
                })
            }
            (None, true) => {
                return Err(StyleLossError::Input {
                    name: "background_mask".into(),
                    reason: "the background weight is positive but no mask was given".into(),
                })
            }
            (_, false) => None,
        };
        Ok(ViewCache {
            height,
            width,
            clip_embedding,
            vgg,
            background,
        })
    }

    /// Draws the crops and warps of one step's patch loss from `rng` (empty when the patch
    /// weight is 0).
    pub fn sample_patches<R: Rng + ?Sized>(
        &self,
        rng: &mut R,
        height: usize,
        width: usize,
    ) -> Result<Vec<PatchAugmentation>> {
        if self.weights.patch > 0.0 {
            self.patches.sample(rng, height, width)
        } else {
            Ok(Vec::new())
        }
    }

    /// The differentiable terms for `image` `[1, 3, h, w]`, each a scalar tensor, `None` when
    /// the weight is 0 (or, for the background, when the view has no background pixel).
    pub fn term_tensors(
        &self,
        image: &Tensor,
        cache: &ViewCache,
        patches: &[PatchAugmentation],
    ) -> Result<[Option<Tensor>; 4]> {
        check_view_size(image, cache)?;
        Ok([
            self.term_tensor(Term::Directional, image, cache, patches)?,
            self.term_tensor(Term::Patch, image, cache, patches)?,
            self.term_tensor(Term::Content, image, cache, patches)?,
            self.term_tensor(Term::Background, image, cache, patches)?,
        ])
    }

    /// One term of [`Self::term_tensors`] (the image's size already checked).
    fn term_tensor(
        &self,
        term: Term,
        image: &Tensor,
        cache: &ViewCache,
        patches: &[PatchAugmentation],
    ) -> Result<Option<Tensor>> {
        if term.weight(&self.weights) <= 0.0 {
            return Ok(None);
        }
        Ok(match term {
            Term::Directional => Some(terms::directional(
                &self.clip,
                &self.direction,
                image,
                clip_embedding_of(cache)?,
            )?),
            Term::Patch => Some(terms::patch(
                &self.clip,
                &self.direction,
                image,
                clip_embedding_of(cache)?,
                patches,
                self.patches.patch_size,
            )?),
            Term::Content => match &self.vgg {
                Some(vgg) => {
                    let gt = cache
                        .vgg
                        .as_ref()
                        .ok_or_else(|| missing_from_cache("VGG features"))?;
                    Some(terms::content(vgg, image, gt)?)
                }
                None => None,
            },
            Term::Background => {
                let target = cache
                    .background
                    .as_ref()
                    .ok_or_else(|| missing_from_cache("background mask"))?;
                if target.count > 0.0 {
                    Some(terms::background(
                        image,
                        &target.gt,
                        &target.mask,
                        target.count,
                    )?)
                } else {
                    None
                }
            }
        })
    }

    /// The values of the terms of `group` that are on, in the group's order. CLIP's two terms,
    /// both on, share one pass of the vision tower ([`terms::directional_and_patch`]).
    fn group_terms(
        &self,
        group: &[Term],
        image: &Tensor,
        cache: &ViewCache,
        patches: &[PatchAugmentation],
    ) -> Result<Vec<(Term, Tensor)>> {
        let on = |t: &Term| t.weight(&self.weights) > 0.0;
        if group == CLIP_TERMS && group.iter().all(on) {
            let (directional, patch) = terms::directional_and_patch(
                &self.clip,
                &self.direction,
                image,
                clip_embedding_of(cache)?,
                patches,
                self.patches.patch_size,
            )?;
            return Ok(vec![(Term::Directional, directional), (Term::Patch, patch)]);
        }
        let mut values = Vec::with_capacity(group.len());
        for &term in group {
            if let Some(value) = self.term_tensor(term, image, cache, patches)? {
                values.push((term, value));
            }
        }
        Ok(values)
    }

    /// The weighted sum of the terms of `group` that are on, its gradient with respect to
    /// `image` (one backward pass), and each such term's value; `None` when none is on.
    fn group_value_and_grad(
        &self,
        group: &[Term],
        image: &Tensor,
        cache: &ViewCache,
        patches: &[PatchAugmentation],
    ) -> Result<Option<GroupValue>> {
        if group.iter().all(|t| t.weight(&self.weights) <= 0.0) {
            return Ok(None);
        }
        let mut present = Vec::with_capacity(group.len());
        let (total, grad) = terms::value_tensor_and_grad(image, |x| {
            let mut total: Option<Tensor> = None;
            for (term, value) in self.group_terms(group, x, cache, patches)? {
                let weighted = (&value * term.weight(&self.weights))?;
                present.push((term, value.detach()));
                total = Some(match total {
                    Some(t) => (t + weighted)?,
                    None => weighted,
                });
            }
            // No term on (a view without background pixels): a constant 0, gradient zeros.
            match total {
                Some(total) => Ok(total),
                None => Ok(Tensor::zeros((), DType::F32, x.device())?),
            }
        })?;
        Ok(Some(GroupValue {
            present,
            total,
            grad,
        }))
    }

    /// Total loss and `d total / d image` for one view with patches drawn from `rng`.
    /// `image` is `[3, h, w]` or `[1, 3, h, w]`, f32 linear in [0, 1]; the gradient has its
    /// shape.
    pub fn loss_and_grad<R: Rng + ?Sized>(
        &self,
        image: &Tensor,
        cache: &ViewCache,
        rng: &mut R,
    ) -> Result<StyleLossOutput> {
        let patches = self.sample_patches(rng, cache.height, cache.width)?;
        self.loss_and_grad_with_patches(image, cache, &patches)
    }

    /// As [`Self::loss_and_grad`] with given patch augmentations.
    pub fn loss_and_grad_with_patches(
        &self,
        image: &Tensor,
        cache: &ViewCache,
        patches: &[PatchAugmentation],
    ) -> Result<StyleLossOutput> {
        let batched = as_batch_of_one(image, "image")?;
        check_view_size(&batched, cache)?;
        // Two independent graphs, CLIP's terms and the image-space ones, each with its own
        // backward pass; their gradients add. On the CPU they run at once, each filling the
        // other's idle moments (small ops, waits between products); a GPU, and the generic
        // path that stands for it, runs them one after the other.
        let (clip, image_space) = at_once(
            batched.device(),
            || self.group_value_and_grad(&CLIP_TERMS, &batched, cache, patches),
            || self.group_value_and_grad(&IMAGE_TERMS, &batched, cache, patches),
        );
        let groups: Vec<GroupValue> = [clip?, image_space?].into_iter().flatten().collect();
        let present: Vec<(Term, Tensor)> = groups.iter().flat_map(|g| g.present.clone()).collect();
        let (total, grad) = match groups.as_slice() {
            [] => (
                Tensor::zeros((), DType::F32, batched.device())?,
                batched.zeros_like()?,
            ),
            [one] => (one.total.clone(), one.grad.clone()),
            [a, b] => ((&a.total + &b.total)?, (&a.grad + &b.grad)?),
            _ => unreachable!("two groups at most"),
        };
        // One transfer for the step: the terms, the total and the gradient's squared norm.
        let mut parts = present
            .iter()
            .map(|(_, t)| t.to_dtype(DType::F32)?.reshape(1))
            .collect::<candle_core::Result<Vec<_>>>()?;
        parts.push(total.to_dtype(DType::F32)?.reshape(1)?);
        parts.push(grad.sqr()?.sum_all()?.to_dtype(DType::F32)?.reshape(1)?);
        let read = Tensor::cat(&parts, 0)?
            .to_dtype(DType::F64)?
            .to_vec1::<f64>()?;
        crate::transfers::record_read(std::mem::size_of_val(read.as_slice()));
        let mut values = [0f64; 4];
        for ((term, _), &value) in present.iter().zip(&read) {
            if !value.is_finite() {
                return Err(StyleLossError::NonFinite {
                    what: format!("the {} loss ({value})", term.name()),
                });
            }
            values[*term as usize] = value;
        }
        let (total, grad_norm) = (read[read.len() - 2], read[read.len() - 1]);
        if !grad_norm.is_finite() {
            return Err(StyleLossError::NonFinite {
                what: "the image gradient".into(),
            });
        }
        Ok(StyleLossOutput {
            terms: LossTerms {
                directional: values[0],
                patch: values[1],
                content: values[2],
                background: values[3],
            },
            total,
            grad: grad.reshape(image.dims())?,
        })
    }
}
