//! The style loss as a gs-core training objective: renders come in as gs-core images (HWC),
//! cross to candle once per step, and dL/dimage goes back; the ground truth of every view is
//! cached once at construction, in memory up to a budget and on disk past it ([`CacheBudget`]),
//! so a run's memory does not grow with its number of views.

use std::path::PathBuf;

use candle_core::Device;
use gs_core::train::{Objective, ObjectiveValue};
use gs_core::Image;

use crate::error::{Result, StyleLossError};
use crate::image_layout::{hwc_to_tensor, tensor_to_hwc};
use crate::losses::{StyleLoss, ViewCache};
use crate::patches::{style_rng, StyleRng};

/// How much of the views' ground-truth caches (CLIP embedding, VGG features, background
/// target: about 21 MB a view at 854x480 with VGG-19) a [`StyleObjective`] holds in memory.
#[derive(Clone, Debug, PartialEq)]
pub struct CacheBudget {
    /// Bytes of caches held in memory, in view order; the caches past it are written to
    /// `spill` and read back (tens of milliseconds) each time their view is used.
    pub resident_bytes: u64,
    /// The folder caches past the budget go to: the objective's own (whatever a stopped run
    /// left in it is removed first; it is removed with the objective); `None` holds every cache
    /// in memory, whatever the budget.
    pub spill: Option<PathBuf>,
}

impl CacheBudget {
    /// Every cache in memory.
    pub fn unbounded() -> Self {
        Self {
            resident_bytes: u64::MAX,
            spill: None,
        }
    }
}

/// A view's cache, in memory or in a file.
#[derive(Debug)]
enum StoredCache {
    Resident(ViewCache),
    Spilled(PathBuf),
}

/// [`StyleLoss`] over a fixed set of views, with the per-view cache and a seeded patch stream.
#[derive(Debug)]
pub struct StyleObjective {
    loss: StyleLoss,
    caches: Vec<StoredCache>,
    /// The spill folder this objective writes, removed when it is dropped.
    made_spill: Option<PathBuf>,
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
        Self::with_progress(
            loss,
            targets,
            masks,
            seed,
            device,
            &CacheBudget::unbounded(),
            &mut |_, _| {},
        )
    }

    /// [`StyleObjective::new`] with the caches held as `budget` says, calling
    /// `cached(done, total)` after each view's cache (the CLIP embedding and VGG features of
    /// its ground truth: seconds a view on a CPU), so that a run can show how far it is before
    /// its first step.
    pub fn with_progress(
        loss: StyleLoss,
        targets: &[Image],
        masks: Option<&[Vec<f32>]>,
        seed: u64,
        device: &Device,
        budget: &CacheBudget,
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
        let mut resident = 0u64;
        let mut made_spill = None;
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
            let cache = loss.cache_view(&gt, mask.as_ref())?;
            let bytes = cache.bytes();
            caches.push(match &budget.spill {
                Some(dir) if resident.saturating_add(bytes) > budget.resident_bytes => {
                    if made_spill.is_none() {
                        if dir.exists() {
                            std::fs::remove_dir_all(dir).map_err(|e| spill_error(dir, e))?;
                        }
                        std::fs::create_dir_all(dir).map_err(|e| spill_error(dir, e))?;
                        made_spill = Some(dir.clone());
                    }
                    let path = dir.join(format!("view{i:05}.safetensors"));
                    cache.save(&path)?;
                    StoredCache::Spilled(path)
                }
                _ => {
                    resident += bytes;
                    StoredCache::Resident(cache)
                }
            });
            cached(i + 1, targets.len());
        }
        Ok(Self {
            loss,
            caches,
            made_spill,
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

    /// How many views' caches are held in memory (the others are read from the spill folder).
    pub fn resident_views(&self) -> usize {
        self.caches
            .iter()
            .filter(|c| matches!(c, StoredCache::Resident(_)))
            .count()
    }
}

impl Drop for StyleObjective {
    fn drop(&mut self) {
        if let Some(dir) = &self.made_spill {
            // A folder left behind only costs disk space; nothing to report from a drop.
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}

/// A spill folder that cannot be written.
fn spill_error(dir: &std::path::Path, source: std::io::Error) -> StyleLossError {
    StyleLossError::Input {
        name: "view cache folder".into(),
        reason: format!("{}: {source}", dir.display()),
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
        let loaded;
        let cache = match &self.caches[view] {
            StoredCache::Resident(cache) => cache,
            StoredCache::Spilled(path) => {
                loaded = ViewCache::load(path, h as usize, w as usize, &self.device)?;
                &loaded
            }
        };
        let out = self.loss.loss_and_grad(&tensor, cache, &mut self.rng)?;
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
