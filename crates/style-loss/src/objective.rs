//! The style loss as a gs-core training objective: renders come in as gs-core images (HWC),
//! cross to candle once per step, and dL/dimage goes back; the ground truth of every view is
//! cached once at construction.

use candle_core::Device;
use gs_core::train::{Objective, ObjectiveValue};
use gs_core::Image;

use crate::error::{Result, StyleLossError};
use crate::image_layout::{hwc_to_tensor, tensor_to_hwc};
use crate::losses::{StyleLoss, ViewCache};
use crate::patches::{style_rng, StyleRng};

/// [`StyleLoss`] over a fixed set of views, with the per-view cache and a seeded patch stream.
#[derive(Debug)]
pub struct StyleObjective {
    loss: StyleLoss,
    caches: Vec<ViewCache>,
    sizes: Vec<(u32, u32)>,
    rng: StyleRng,
    device: Device,
}

impl StyleObjective {
    /// Caches every view's ground truth (`targets[i]` is view `i`) and, when given, its
    /// background mask (`[h * w]` values, 1 = background, row-major). Patches are drawn from a
    /// stream seeded with `seed`; `device` is where CLIP and VGG run.
    pub fn new(
        loss: StyleLoss,
        targets: &[Image],
        masks: Option<&[Vec<f32>]>,
        seed: u64,
        device: &Device,
    ) -> Result<Self> {
        Self::with_progress(loss, targets, masks, seed, device, &mut |_, _| {})
    }

    /// [`StyleObjective::new`], calling `cached(done, total)` after each view's cache (the
    /// CLIP embedding and VGG features of its ground truth: seconds a view on a CPU), so that a
    /// run can show how far it is before its first step.
    pub fn with_progress(
        loss: StyleLoss,
        targets: &[Image],
        masks: Option<&[Vec<f32>]>,
        seed: u64,
        device: &Device,
        cached: &mut dyn FnMut(usize, usize),
    ) -> Result<Self> {
        if let Some(m) = masks {
            if m.len() != targets.len() {
                return Err(StyleLossError::Input {
                    name: "masks".into(),
                    reason: format!("{} masks for {} views", m.len(), targets.len()),
                });
            }
        }
        let mut caches = Vec::with_capacity(targets.len());
        for (i, t) in targets.iter().enumerate() {
            let (h, w) = (t.height as usize, t.width as usize);
            let gt = hwc_to_tensor(&t.data, h, w, device)?;
            let mask = match masks {
                Some(m) => {
                    if m[i].len() != h * w {
                        return Err(StyleLossError::Input {
                            name: format!("masks[{i}]"),
                            reason: format!("{} values for a {w}x{h} view", m[i].len()),
                        });
                    }
                    Some(candle_core::Tensor::from_slice(&m[i], (h, w), device)?)
                }
                None => None,
            };
            caches.push(loss.cache_view(&gt, mask.as_ref())?);
            cached(i + 1, targets.len());
        }
        Ok(Self {
            loss,
            caches,
            sizes: targets.iter().map(|t| (t.width, t.height)).collect(),
            rng: style_rng(seed),
            device: device.clone(),
        })
    }

    /// The patch stream, e.g. to save it in a checkpoint and restore it with
    /// [`StyleObjective::set_rng`].
    pub fn rng(&self) -> &StyleRng {
        &self.rng
    }

    /// Replaces the patch stream (when resuming a run).
    pub fn set_rng(&mut self, rng: StyleRng) {
        self.rng = rng;
    }
}

impl Objective for StyleObjective {
    type Error = StyleLossError;

    fn evaluate(&mut self, view: usize, image: &Image) -> Result<ObjectiveValue> {
        let Some(&(w, h)) = self.sizes.get(view) else {
            return Err(StyleLossError::Input {
                name: "view".into(),
                reason: format!("view {view} of {} cached views", self.sizes.len()),
            });
        };
        if (image.width, image.height) != (w, h) {
            return Err(StyleLossError::Input {
                name: "image".into(),
                reason: format!(
                    "view {view} is rendered at {}x{} but its ground truth is {w}x{h}",
                    image.width, image.height
                ),
            });
        }
        let tensor = hwc_to_tensor(&image.data, h as usize, w as usize, &self.device)?;
        let out = self
            .loss
            .loss_and_grad(&tensor, &self.caches[view], &mut self.rng)?;
        let weights = self.loss.weights();
        let terms = [
            ("directional", weights.directional, out.terms.directional),
            ("patch", weights.patch, out.terms.patch),
            ("content", weights.content, out.terms.content),
            ("background", weights.background, out.terms.background),
        ]
        .into_iter()
        .filter(|(_, weight, _)| *weight > 0.0)
        .map(|(name, weight, value)| (name.to_string(), (weight * value) as f32))
        .collect();
        Ok(ObjectiveValue {
            loss: out.total as f32,
            terms,
            grad: tensor_to_hwc(&out.grad)?,
        })
    }
}
