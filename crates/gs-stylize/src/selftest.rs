//! The `selftest` subcommand of every binary: on the chosen device, the parts a stylization
//! runs (render, its backward, Adam, the four loss terms and their gradient, and what a
//! modality adds) on small seeded inputs, each compared with the CPU f32 result. On the CPU
//! the loss is compared with its generic composition ([`style_loss::GenericPath`]), the one a
//! GPU runs, so the check means something there too.

use std::ops::ControlFlow;
use std::time::Instant;

use candle_core::{Device, Tensor};
use gs_core::adam::{AdamHyper, GroupConfig, LrSchedule};
use gs_core::model::{BaseModel, View};
use gs_core::raster::GradMask;
use gs_core::sampler::ViewSampler;
use gs_core::train::{Objective, ObjectiveValue, TrainConfig};
use gs_core::{Camera, GaussianSet, Image};
use gs_wgpu::backend::{Backend, DeviceChoice, OpenDevice, Trainer};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use style_loss::clip::{ClipTextConfig, ClipVisionConfig};
use style_loss::{
    compute_device, style_rng, ClipConfig, ClipModel, GenericPath, LossWeights, NamedTensors,
    PatchSettings, StyleDirection, StyleLoss, Vgg19Features, Vgg19Widths,
};

/// An error as the text the `selftest` reports.
fn text(e: impl std::fmt::Display) -> String {
    e.to_string()
}

/// One compared part.
#[derive(Clone, Debug, PartialEq)]
pub struct Check {
    /// What was run.
    pub part: String,
    /// Where it ran, and what it was compared with.
    pub device: String,
    /// Largest difference from the reference, relative to the reference's largest magnitude.
    pub error: f64,
    /// The largest `error` that passes.
    pub tolerance: f64,
    /// Seconds the part took on the device.
    pub seconds: f64,
}

impl Check {
    /// Whether the part agrees with its reference.
    pub fn passed(&self) -> bool {
        self.error <= self.tolerance
    }
}

/// A modality's own part: given the loss device, its check.
pub type ExtraCheck = Box<dyn FnOnce(&Device) -> Result<Check, String>>;

/// Runs every part on `choice` (the rasterizer's and the loss's devices, as a stylization opens
/// them) and `extra`, and returns the checks; an error when a device does not open or a part
/// fails to run.
pub fn run_selftest(choice: DeviceChoice, extra: Vec<ExtraCheck>) -> Result<Vec<Check>, String> {
    let backend = choice.open().map_err(|e| e.to_string())?;
    let (loss_device, _) = compute_device::open_for(choice).map_err(|e| e.to_string())?;
    let mut checks = vec![render_check(&backend)?, adam_check(&backend)?];
    checks.extend(loss_checks(&loss_device)?);
    for check in extra {
        checks.push(check(&loss_device)?);
    }
    Ok(checks)
}

/// The checks as a markdown table, one row per part.
pub fn table(checks: &[Check]) -> String {
    let mut out = String::from(
        "| part | device | max error | tolerance | time (s) | |\n|---|---|---|---|---|---|\n",
    );
    for c in checks {
        // Parts timed together (the loss terms, within one step) show no time of their own.
        let seconds = if c.seconds > 0.0 {
            format!("{:.3}", c.seconds)
        } else {
            String::new()
        };
        out += &format!(
            "| {} | {} | {:.2e} | {:.0e} | {seconds} | {} |\n",
            c.part,
            c.device,
            c.error,
            c.tolerance,
            if c.passed() { "ok" } else { "MISMATCH" }
        );
    }
    out
}

/// `max |a - b| / max |b|` (0 when both are empty or zero); infinite when the lengths differ
/// or a difference is not a number (a NaN on one side).
pub fn relative_max_error(a: &[f32], b: &[f32]) -> f64 {
    let scale = b.iter().fold(0f64, |m, &v| m.max(f64::from(v).abs()));
    let mut diff = 0f64;
    for (&x, &y) in a.iter().zip(b) {
        let d = (f64::from(x) - f64::from(y)).abs();
        if d.is_nan() {
            return f64::INFINITY;
        }
        diff = diff.max(d);
    }
    if a.len() != b.len() {
        return f64::INFINITY;
    }
    if scale > 0.0 {
        diff / scale
    } else {
        diff
    }
}

/// 40 seeded Gaussians of SH degree 1 in front of a 48 x 40 camera.
fn scene() -> (GaussianSet, Camera) {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut g = GaussianSet::zeros(40, 1);
    for (values, lo, hi) in [
        (&mut g.means, -0.7, 0.7),
        (&mut g.log_scales, -2.4, -1.4),
        (&mut g.quats, -1.0, 1.0),
        (&mut g.opacity_logits, -1.0, 5.0),
        (&mut g.sh_dc, -1.0, 1.5),
        (&mut g.sh_rest, -0.2, 0.2),
    ] {
        for v in values.iter_mut() {
            *v = rng.random_range(lo..hi);
        }
    }
    let camera = Camera::look_at([0.3, -0.4, -3.0], [0.0; 3], [0.0, -1.0, 0.0], 0.8, 48, 40)
        .expect("a valid camera");
    (g, camera)
}

/// The render and every gradient of its backward on `backend`, against the cpu's.
fn render_check(backend: &Backend) -> Result<Check, String> {
    let (g, camera) = scene();
    let run = |b: &Backend| -> Result<(Vec<f32>, Vec<f32>), String> {
        let renderer = b.renderer(&g).map_err(|e| e.to_string())?;
        let render = renderer
            .render_differentiable(&camera, [0.2, 0.3, 0.4])
            .map_err(|e| e.to_string())?;
        let image = render.image().data;
        let upstream: Vec<f32> = (0..image.len())
            .map(|i| ((i * 7919) % 101) as f32 / 101.0 - 0.5)
            .collect();
        let grads = render
            .backward(&upstream, GradMask::ALL)
            .map_err(|e| e.to_string())?;
        let flat = grads.gaussians.arrays().concat();
        Ok((image, flat))
    };
    let start = Instant::now();
    let (image, grads) = run(backend)?;
    let seconds = start.elapsed().as_secs_f64();
    let (cpu_image, cpu_grads) = run(&Backend::Cpu)?;
    Ok(Check {
        part: "render and its backward".into(),
        device: format!("{} vs cpu", backend.describe()),
        error: relative_max_error(&image, &cpu_image).max(relative_max_error(&grads, &cpu_grads)),
        tolerance: 1e-3,
        seconds,
    })
}

/// L = sum of the render.
struct Sum;

impl Objective for Sum {
    type Error = std::convert::Infallible;
    fn evaluate(&mut self, _: usize, image: &Image) -> Result<ObjectiveValue, Self::Error> {
        Ok(ObjectiveValue {
            loss: image.data.iter().sum(),
            terms: Vec::new(),
            grad: vec![1.0; image.data.len()],
        })
    }
}

/// Three Adam steps of every group on `backend`, against the cpu's.
fn adam_check(backend: &Backend) -> Result<Check, String> {
    let (g, camera) = scene();
    let run = |b: &Backend| -> Result<Vec<f32>, String> {
        let groups = g
            .group_names()
            .iter()
            .map(|n| GroupConfig::new(n.clone(), LrSchedule::Constant(0.01)))
            .collect();
        let mut trainer =
            Trainer::new(b, g.clone(), groups, AdamHyper::default()).map_err(|e| e.to_string())?;
        trainer
            .train(
                &[View::still(camera.clone())],
                &mut Sum,
                &mut ViewSampler::new(1, 0),
                &TrainConfig {
                    steps: 3,
                    background: [0.0; 3],
                },
                |_| ControlFlow::Continue(()),
            )
            .map_err(|e| e.to_string())?;
        Ok(trainer.into_model().arrays().concat())
    };
    let start = Instant::now();
    let ours = run(backend)?;
    let seconds = start.elapsed().as_secs_f64();
    let cpu = run(&Backend::Cpu)?;
    Ok(Check {
        part: "three Adam steps".into(),
        device: format!("{} vs cpu", backend.describe()),
        error: relative_max_error(&ours, &cpu),
        tolerance: 1e-4,
        seconds,
    })
}

/// A tiny random CLIP (ViT of 2 layers on 64-pixel images) and VGG-19 (channels / 16), the
/// same values on every device.
fn tiny_loss(device: &Device) -> Result<StyleLoss, String> {
    let config = ClipConfig {
        projection_dim: 16,
        text: ClipTextConfig {
            vocab_size: 100,
            hidden_size: 32,
            intermediate_size: 64,
            num_hidden_layers: 1,
            num_attention_heads: 4,
            eos_token_id: 99,
            ..ClipTextConfig::default()
        },
        vision: ClipVisionConfig {
            hidden_size: 24,
            intermediate_size: 48,
            num_hidden_layers: 2,
            num_attention_heads: 4,
            image_size: 64,
            patch_size: 16,
            ..ClipVisionConfig::default()
        },
    };
    let weights = NamedTensors::random(device);
    let clip = ClipModel::from_tensors(&config, &weights, device).map_err(text)?;
    let vgg =
        Vgg19Features::from_tensors(&weights, Vgg19Widths([4, 8, 16, 32, 32])).map_err(text)?;
    let style: Vec<f32> = (0..16).map(|i| ((i * 37) % 11) as f32 - 5.0).collect();
    let style = Tensor::from_vec(style, 16, device).map_err(text)?;
    let zero = style.zeros_like().map_err(text)?;
    let direction = StyleDirection::from_embeddings(&style, &zero).map_err(text)?;
    let patches = PatchSettings {
        patch_size: 32,
        num_patches: 4,
        distortion_scale: 0.5,
    };
    StyleLoss::new(
        clip,
        Some(vgg),
        direction,
        LossWeights {
            background: 50.0,
            ..LossWeights::default()
        },
        patches,
    )
    .map_err(text)
}

/// The four terms and the image gradient of one step on `device`, as f32 values (terms
/// first), with the time it took.
fn loss_values(device: &Device) -> Result<(Vec<f32>, f64), String> {
    let loss = tiny_loss(device)?;
    let (h, w) = (48usize, 56usize);
    let pattern = |seed: usize| -> Vec<f32> {
        (0..3 * h * w)
            .map(|i| (((i * 7919 + seed) % 997) as f32 / 997.0).clamp(0.0, 1.0))
            .collect()
    };
    let image = Tensor::from_vec(pattern(1), (1, 3, h, w), device).map_err(text)?;
    let gt = Tensor::from_vec(pattern(5), (1, 3, h, w), device).map_err(text)?;
    let mask: Vec<f32> = (0..h * w)
        .map(|i| f32::from(u8::from(i % 5 == 0)))
        .collect();
    let mask = Tensor::from_vec(mask, (h, w), device).map_err(text)?;
    let cache = loss.cache_view(&gt, Some(&mask)).map_err(text)?;
    let patches = loss.sample_patches(&mut style_rng(0), h, w).map_err(text)?;
    let start = Instant::now();
    let out = loss
        .loss_and_grad_with_patches(&image, &cache, &patches)
        .map_err(text)?;
    let seconds = start.elapsed().as_secs_f64();
    let t = &out.terms;
    let mut values = vec![
        t.directional as f32,
        t.patch as f32,
        t.content as f32,
        t.background as f32,
    ];
    let grad = out.grad.flatten_all().and_then(|g| g.to_vec1::<f32>());
    values.extend(grad.map_err(text)?);
    Ok((values, seconds))
}

/// The loss terms and their gradient on `device` against the cpu (on the cpu: the fast
/// kernels against the generic composition).
fn loss_checks(device: &Device) -> Result<Vec<Check>, String> {
    let (ours, seconds) = loss_values(device)?;
    let (reference, against) = if device.is_cpu() {
        let _generic = GenericPath::on();
        (loss_values(&Device::Cpu)?.0, "the generic composition")
    } else {
        (loss_values(&Device::Cpu)?.0, "cpu")
    };
    let name = compute_device::describe(device);
    let mut checks: Vec<Check> = ["directional", "patch", "content", "background"]
        .iter()
        .enumerate()
        .map(|(i, term)| Check {
            part: format!("{term} loss"),
            device: format!("{name} vs {against}"),
            error: relative_max_error(&ours[i..=i], &reference[i..=i]),
            tolerance: 1e-4,
            seconds: 0.0,
        })
        .collect();
    checks.push(Check {
        part: "loss gradient (four terms)".into(),
        device: format!("{name} vs {against}"),
        error: relative_max_error(&ours[4..], &reference[4..]),
        tolerance: 1e-3,
        seconds,
    });
    Ok(checks)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn selftest_on_the_cpu_passes_and_prints_every_part() {
        let checks = run_selftest(DeviceChoice::Cpu, Vec::new()).unwrap();
        let parts: Vec<&str> = checks.iter().map(|c| c.part.as_str()).collect();
        assert_eq!(
            parts,
            [
                "render and its backward",
                "three Adam steps",
                "directional loss",
                "patch loss",
                "content loss",
                "background loss",
                "loss gradient (four terms)"
            ]
        );
        assert!(checks.iter().all(Check::passed), "{}", table(&checks));
        // The loss was compared with another composition: not bit-identical.
        assert!(checks.last().unwrap().error > 0.0);
        let t = table(&checks);
        assert!(
            t.contains("| content loss | cpu vs the generic composition |"),
            "{t}"
        );
    }

    #[test]
    fn errors_are_relative_to_the_reference_and_a_mismatch_shows() {
        assert_eq!(relative_max_error(&[1.0, 2.5], &[1.0, 2.0]), 0.25);
        assert_eq!(relative_max_error(&[f32::NAN], &[1.0]), f64::INFINITY);
        let bad = Check {
            part: "x".into(),
            device: "cpu".into(),
            error: 0.5,
            tolerance: 1e-3,
            seconds: 0.0,
        };
        assert!(!bad.passed() && table(&[bad]).contains("MISMATCH"));
    }
}
