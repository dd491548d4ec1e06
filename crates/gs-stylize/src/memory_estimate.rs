//! How much memory a stylization will need, printed before the per-view cache and the first
//! step, and the refusal of a run that cannot fit in the machine's memory (with the numbers and
//! what to lower), instead of a run the kernel kills hours in.
//!
//! A model of the peak resident size on the CPU, calibrated with `style_loss_timing 1 <term>`
//! (release, 800x800 render, 64 patches, full CLIP ViT-B/32 and VGG-19; docs/benchmarks.md):
//! the models and the process about 1.3 GB, the content term about 3.2 kB per render pixel
//! (VGG-19's activations kept for its backward), the patch term about 80 MB per patch (CLIP's
//! activations of one 224x224 crop), each view's cached ground truth about 52 bytes per pixel
//! (VGG features and CLIP embedding; 16 more with the background term's target; at most
//! `view_cache_mb` in memory) and its picture 12,
//! and 20 bytes per model parameter (values, Adam's two moments, gradient, a host copy). It
//! errs high: a machine with less memory than the estimate is refused, one with less memory
//! available than the estimate is warned about.

use crate::config::StyleSettings;
use crate::StylizeError;

/// Bytes of the models (CLIP, VGG-19) and the process, when any loss term runs.
const MODELS: f64 = 1.3e9;
/// Bytes per render pixel of the content term (VGG-19 forward kept for the backward).
const CONTENT_PER_PIXEL: f64 = 3.2e3;
/// Bytes per patch of the patch term (CLIP forward and backward of one crop).
const PER_PATCH: f64 = 80e6;
/// Bytes per pixel of a view's cached ground truth (VGG features, CLIP embedding; measured 21 MB
/// a view at 854x480 with `view_cache_memory`, 51 bytes a pixel, the embedding included), held
/// in memory up to `view_cache_mb`.
const CACHE_PER_PIXEL: f64 = 52.0;
/// Bytes per pixel the background term adds to a view's cache (its target picture and mask).
const BACKGROUND_PER_PIXEL: f64 = 16.0;
/// Bytes per pixel of a view's picture (`f32` RGB) and background mask, always in memory.
const PICTURE_PER_PIXEL: f64 = 12.0;
/// Bytes per model parameter.
const PER_PARAMETER: f64 = 20.0;
/// Bytes per pixel of a picture while it is decoded: its 8-bit RGBA and its `f32` RGBA.
const DECODE_PER_PIXEL: f64 = 20.0;

/// The estimate, in bytes, by part.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MemoryEstimate {
    /// CLIP, VGG-19 and the process.
    pub models: f64,
    /// The largest step: the loss terms of the largest view.
    pub step: f64,
    /// Every view's cached ground truth.
    pub views: f64,
    /// The model's parameters and optimizer state.
    pub model: f64,
    /// Decoding the largest input picture at its stored size (0 once the inputs are loaded).
    pub decode: f64,
}

impl MemoryEstimate {
    /// The estimate for `settings` over views of `view_pixels` pixels each and a model of
    /// `parameters` values.
    pub fn of(settings: &StyleSettings, view_pixels: &[u64], parameters: usize) -> Self {
        let largest = view_pixels.iter().copied().max().unwrap_or(0) as f64;
        let content = if settings.lambda_content > 0.0 {
            CONTENT_PER_PIXEL * largest
        } else {
            0.0
        };
        let patches = if settings.lambda_patch > 0.0 {
            PER_PATCH * settings.num_patches as f64
        } else {
            0.0
        };
        Self {
            models: MODELS,
            step: content + patches,
            views: {
                let pixels = view_pixels.iter().sum::<u64>() as f64;
                let budget = settings.view_cache_mb as f64 * f64::from(1u32 << 20);
                let background = if settings.lambda_background > 0.0 {
                    BACKGROUND_PER_PIXEL
                } else {
                    0.0
                };
                ((CACHE_PER_PIXEL + background) * pixels).min(budget) + PICTURE_PER_PIXEL * pixels
            },
            model: PER_PARAMETER * parameters as f64,
            decode: 0.0,
        }
    }

    /// The same estimate before the inputs are decoded, the largest of them
    /// `largest_picture` pixels as stored (before any shrinking).
    pub fn before_decoding(self, largest_picture: u64) -> Self {
        Self {
            decode: DECODE_PER_PIXEL * largest_picture as f64,
            ..self
        }
    }

    /// The whole estimate, bytes.
    pub fn total(&self) -> f64 {
        self.models + self.step + self.views + self.model + self.decode
    }

    /// `memory: about 8.5 GB (models 1.3 GB, step 7.2 GB, view caches 0.1 GB, model 0.1 GB)`,
    /// with `, decoding 2.0 GB` before the inputs are decoded.
    pub fn line(&self) -> String {
        let decode = if self.decode > 0.0 {
            format!(", decoding {}", gb(self.decode))
        } else {
            String::new()
        };
        format!(
            "memory: about {} (models {}, step {}, view caches {}, model {}{decode})",
            gb(self.total()),
            gb(self.models),
            gb(self.step),
            gb(self.views),
            gb(self.model)
        )
    }
}

/// `7.9 GB`.
fn gb(bytes: f64) -> String {
    format!("{:.1} GB", bytes / 1e9)
}

/// The machine's memory, bytes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MachineMemory {
    /// All of it.
    pub total: f64,
    /// What the kernel says a new process can have without swapping.
    pub available: f64,
}

/// The machine's memory from `/proc/meminfo` (`MemTotal`, `MemAvailable`); `None` where it
/// cannot be read (another system), and then nothing is refused.
pub fn machine_memory() -> Option<MachineMemory> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let field = |name: &str| -> Option<f64> {
        let line = text.lines().find(|l| l.starts_with(name))?;
        let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
        Some(kb * 1024.0)
    };
    Some(MachineMemory {
        total: field("MemTotal:")?,
        available: field("MemAvailable:")?,
    })
}

/// Refuses a run whose estimate exceeds the machine's memory, naming the numbers and what to
/// lower; returns a note to print when it exceeds only the memory available now.
pub fn check_memory(
    estimate: &MemoryEstimate,
    machine: Option<MachineMemory>,
) -> Result<Option<String>, StylizeError> {
    let Some(machine) = machine else {
        return Ok(None);
    };
    let need = estimate.total();
    if need > machine.total {
        return Err(StylizeError::Memory(format!(
            "this run needs about {} of memory and this machine has {} in all ({}); lower \
             --set num_patches=N (about 80 MB each), the views' size (--max-width, or a \
             dataset's -r; a picture's stored size counts while it is decoded), or run on a \
             machine with more memory",
            gb(need),
            gb(machine.total),
            estimate.line().trim_start_matches("memory: ")
        )));
    }
    Ok((need > machine.available).then(|| {
        format!(
            "note: this run needs about {} of memory and {} is available now; it may swap",
            gb(need),
            gb(machine.available)
        )
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(num_patches: usize) -> StyleSettings {
        StyleSettings {
            style_prompt: Some("fire".into()),
            num_patches,
            ..StyleSettings::paper_3d()
        }
    }

    #[test]
    fn the_estimate_follows_the_paper_settings_measured() {
        // 800x800 with 64 patches: about 7.8 GB measured (style_loss_timing 1 all).
        let e = MemoryEstimate::of(&settings(64), &[640_000], 0);
        assert!((7.0e9..9.0e9).contains(&e.total()), "{}", e.line());
        assert!(
            e.line()
                .starts_with("memory: about 8.5 GB (models 1.3 GB, step 7.2 GB"),
            "{}",
            e.line()
        );
        // No patch term: no patches' memory.
        let mut no_patches = settings(64);
        no_patches.lambda_patch = 0.0;
        let e = MemoryEstimate::of(&no_patches, &[640_000], 0);
        assert!(e.step < 2.1e9, "{}", e.line());
        // Views' caches add up, the step takes the largest view.
        let e = MemoryEstimate::of(&settings(8), &[1000, 4000, 2000], 1000);
        // The paper's 3D settings have the background term: 52 + 16 bytes of cache and 12 of
        // picture a pixel; without it 52 + 12.
        assert_eq!(e.views, 80.0 * 7000.0);
        let mut no_background = settings(8);
        no_background.lambda_background = 0.0;
        let nb = MemoryEstimate::of(&no_background, &[1000, 4000, 2000], 1000);
        assert_eq!(nb.views, 64.0 * 7000.0);
        // Past view_cache_mb the caches go to disk: only the pictures grow with the views.
        let mut bounded = settings(8);
        bounded.view_cache_mb = 1;
        let b = MemoryEstimate::of(&bounded, &[100_000; 40], 1000);
        assert_eq!(b.views, f64::from(1u32 << 20) + 12.0 * 4e6);
        assert_eq!(e.model, 20_000.0);
        assert_eq!(e.step, 3.2e3 * 4000.0 + 8.0 * 80e6);
    }

    #[test]
    fn an_oversized_run_is_refused_with_what_to_lower() {
        let machine = MachineMemory {
            total: 16e9,
            available: 6e9,
        };
        // A 5000x5000 picture: 80 GB of VGG activations alone.
        let huge = MemoryEstimate::of(&settings(64), &[25_000_000], 0);
        let err = check_memory(&huge, Some(machine)).unwrap_err().to_string();
        assert!(err.contains("this machine has 16.0 GB"), "{err}");
        assert!(
            err.contains("--set num_patches=N") && err.contains("--max-width"),
            "{err}"
        );
        // Fits in all of it but not in what is free now: a note, not an error.
        let fits = MemoryEstimate::of(&settings(64), &[640_000], 0);
        let note = check_memory(&fits, Some(machine)).unwrap().unwrap();
        assert!(
            note.starts_with("note: ") && !note.contains("error"),
            "{note}"
        );
        // Nothing known of the machine: nothing refused.
        assert_eq!(check_memory(&huge, None).unwrap(), None);
        let small = MemoryEstimate::of(&settings(4), &[10_000], 100);
        assert_eq!(check_memory(&small, Some(machine)).unwrap(), None);
        // A picture shrunk to small views but stored at 30000x30000: 18 GB to decode it.
        let stored_huge = small.before_decoding(900_000_000);
        assert_eq!(stored_huge.decode, 20.0 * 9e8);
        assert!(
            stored_huge.line().ends_with(", decoding 18.0 GB)"),
            "{}",
            stored_huge.line()
        );
        let err = check_memory(&stored_huge, Some(machine))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("stored size counts while it is decoded"),
            "{err}"
        );
    }

    #[test]
    fn this_machines_memory_is_read() {
        if let Some(m) = machine_memory() {
            assert!(m.total > 0.0 && m.available > 0.0 && m.available <= m.total);
        }
    }
}
