//! How `auto` ([`ClipPrecision::Auto`], [`VggPrecision::Auto`]) chooses between f32 and bf16
//! products on the CPU: by timing the network's own product shapes both ways at start (about a
//! quarter of a second), and taking bf16 only where it is at least [`MIN_SPEEDUP`] times as
//! fast. A CPU flag alone does not tell: the same AVX-512 BF16 runs 1.2 to 2 times the f32 rate
//! on an AMD Zen 4 and under the f32 rate on an Intel Sapphire Rapids. `CLIPGAUSSIAN_CPU_BF16`
//! ([`CPU_BF16_ENV`]) forces either.

use std::fmt;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use candle_core::{DType, Device, Tensor, Var};

use crate::clip::ClipVisionConfig;
use crate::error::{Result, StyleLossError};
use crate::nn::Linear;
use crate::precision::{cpu_multiplies_bf16, ClipPrecision, VggPrecision, CPU_BF16_ENV};
use crate::seeded::seeded_values;
use crate::vgg::Vgg19Widths;
use crate::vgg_channels_last::{ConvReluChannelsLast, KernelWidths, MEASURED};

/// How much faster bf16 products must time than f32 for `auto` to take them: their rounding
/// (errors in docs/benchmarks.md) is only worth a clear gain, and a tie within the timing's
/// noise keeps f32.
pub const MIN_SPEEDUP: f64 = 1.1;

/// The most token rows CLIP's probe multiplies: products of more rows run at the same rate,
/// so a run of many patches is timed on a slice of its rows.
const MAX_PROBE_ROWS: usize = 512;

/// Timed runs of each format (after one untimed run that warms the thread pool and the
/// kernels' buffers); the fastest counts.
const TIMED_RUNS: usize = 2;

/// Seconds the same products took in each format (the fastest of [`TIMED_RUNS`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bf16Timing {
    /// With f32 products.
    pub f32_seconds: f64,
    /// With bf16 products.
    pub bf16_seconds: f64,
}

impl Bf16Timing {
    /// How many times faster bf16 ran (below 1: slower); 0 when either time is not positive
    /// and finite, so that a broken timing never picks bf16.
    pub fn speedup(&self) -> f64 {
        let (f, b) = (self.f32_seconds, self.bf16_seconds);
        if f.is_finite() && b.is_finite() && f > 0.0 && b > 0.0 {
            f / b
        } else {
            0.0
        }
    }
}

/// What `auto` chose for one network, and why.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum AutoChoice {
    /// `CLIPGAUSSIAN_CPU_BF16` forced bf16 (`true`) or f32 (`false`).
    Forced(bool),
    /// Not the CPU: f32 (bf16 products are the CPU's kernels).
    NotCpu,
    /// The CPU has no AVX-512 BF16 dot product (its kernel would widen bf16 to f32): f32.
    NoInstructions,
    /// No layer of the network would run bf16 products (VGG's narrower than
    /// [`KernelWidths::bf16_backward`] channels): f32, untimed.
    NoBf16Layer,
    /// Timed both ways: bf16 when it ran at least [`MIN_SPEEDUP`] times as fast.
    Timed(Bf16Timing),
}

impl AutoChoice {
    /// Whether the network runs bf16 products.
    pub fn takes_bf16(&self) -> bool {
        match self {
            Self::Forced(bf16) => *bf16,
            Self::NotCpu | Self::NoInstructions | Self::NoBf16Layer => false,
            Self::Timed(timing) => timing.speedup() >= MIN_SPEEDUP,
        }
    }

    /// The choice as CLIP's format.
    pub fn clip(&self) -> ClipPrecision {
        if self.takes_bf16() {
            ClipPrecision::Bf16
        } else {
            ClipPrecision::F32
        }
    }

    /// The choice as VGG's format.
    pub fn vgg(&self) -> VggPrecision {
        if self.takes_bf16() {
            VggPrecision::Bf16
        } else {
            VggPrecision::F32
        }
    }
}

/// The reason, as a run prints it after the format: "bf16 1.6x faster here", "bf16 is 1.4x
/// slower on this CPU", ...
impl fmt::Display for AutoChoice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Forced(bf16) => write!(f, "{CPU_BF16_ENV}={}", u8::from(*bf16)),
            Self::NotCpu => f.write_str("bf16 products run on the CPU only"),
            Self::NoInstructions => f.write_str("this CPU has no AVX-512 BF16"),
            Self::NoBf16Layer => f.write_str("no layer of 256 channels or more, where bf16 runs"),
            Self::Timed(timing) => {
                let speedup = timing.speedup();
                if self.takes_bf16() {
                    write!(f, "bf16 {speedup:.1}x faster here")
                } else if speedup >= 1.0 {
                    write!(
                        f,
                        "bf16 only {speedup:.2}x faster on this CPU, under the {MIN_SPEEDUP}x \
                         that pays for its rounding"
                    )
                } else if speedup > 0.0 {
                    write!(f, "bf16 is {:.1}x slower on this CPU", 1.0 / speedup)
                } else {
                    f.write_str("the timing of bf16 failed")
                }
            }
        }
    }
}

/// `CLIPGAUSSIAN_CPU_BF16` read: `Some(false)` for `0`, `false`, `off`, `no`; `Some(true)` for
/// `1`, `true`, `on`, `yes`; `None` when unset or empty; any other value is refused.
pub fn cpu_bf16_switch() -> Result<Option<bool>> {
    match std::env::var(CPU_BF16_ENV) {
        Err(_) => Ok(None),
        Ok(value) => parse_switch(&value),
    }
}

/// [`cpu_bf16_switch`] of a given value.
fn parse_switch(value: &str) -> Result<Option<bool>> {
    match value.trim().to_ascii_lowercase().as_str() {
        "" => Ok(None),
        "0" | "false" | "off" | "no" => Ok(Some(false)),
        "1" | "true" | "on" | "yes" => Ok(Some(true)),
        _ => Err(StyleLossError::Config {
            field: CPU_BF16_ENV.into(),
            value: value.into(),
            reason: "must be 0 (f32 products) or 1 (bf16 products), or unset to let `auto` \
                     time both"
                .into(),
        }),
    }
}

/// The choice from what is known of the machine: the switch first, then the device, the
/// instructions and whether any layer would change; `time` runs only when all of those leave
/// the question open.
fn choose(
    switch: Option<bool>,
    on_cpu: bool,
    instructions: bool,
    has_bf16_layer: bool,
    time: impl FnOnce() -> Result<Bf16Timing>,
) -> Result<AutoChoice> {
    Ok(match switch {
        Some(bf16) => AutoChoice::Forced(bf16),
        None if !on_cpu => AutoChoice::NotCpu,
        None if !instructions => AutoChoice::NoInstructions,
        None if !has_bf16_layer => AutoChoice::NoBf16Layer,
        None => AutoChoice::Timed(time()?),
    })
}

/// The products of one pass of CLIP's vision tower that `auto` times: `rows` token rows (the
/// images of a batch times the tokens of an image) through a `hidden -> intermediate` layer and
/// its input gradient (the MLP's two shapes, two thirds of the tower's products).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ClipProducts {
    /// Token rows of one batch.
    pub rows: usize,
    /// The residual width (768 for ViT-B/32).
    pub hidden: usize,
    /// The MLP's width (3072 for ViT-B/32).
    pub intermediate: usize,
}

impl ClipProducts {
    /// The products of `images` images a batch (a run's patches and its whole view) through a
    /// vision tower of `config`.
    pub fn of(config: &ClipVisionConfig, images: usize) -> Self {
        let side = config.image_size / config.patch_size.max(1);
        Self {
            rows: images.max(1) * (side * side + 1),
            hidden: config.hidden_size,
            intermediate: config.intermediate_size,
        }
    }
}

/// `auto`'s choice for CLIP on `device`, timing `products` when the CPU has the instructions.
pub fn choose_clip(device: &Device, products: ClipProducts) -> Result<AutoChoice> {
    choose(
        cpu_bf16_switch()?,
        device.is_cpu(),
        cpu_multiplies_bf16(),
        true,
        || time_clip(products),
    )
}

/// `auto`'s choice for VGG-19 of `widths` on `device`, timing its layers of bf16 width.
pub fn choose_vgg(device: &Device, widths: Vgg19Widths) -> Result<AutoChoice> {
    choose_vgg_with(device, widths, MEASURED)
}

/// [`choose_vgg`] with the layer algorithms of `kernels`
/// (`vgg_channels_last::MEASURED` outside tests), timing its layers of bf16 width.
pub(crate) fn choose_vgg_with(
    device: &Device,
    widths: Vgg19Widths,
    kernels: KernelWidths,
) -> Result<AutoChoice> {
    let bf16_widths: Vec<usize> = distinct_bf16_widths(widths, kernels);
    choose(
        cpu_bf16_switch()?,
        device.is_cpu(),
        cpu_multiplies_bf16(),
        !bf16_widths.is_empty(),
        || time_vgg(&bf16_widths, kernels),
    )
}

/// The widths of `widths`' blocks whose layers run bf16 products (the first block's first
/// layer, from 3 channels, never does), once each, in order.
fn distinct_bf16_widths(widths: Vgg19Widths, kernels: KernelWidths) -> Vec<usize> {
    let mut out: Vec<usize> = Vec::new();
    for &w in &widths.0 {
        if w >= kernels.bf16_backward && !out.contains(&w) {
            out.push(w);
        }
    }
    out
}

/// The fastest of [`TIMED_RUNS`] runs of `f32` and of `bf16`, after one untimed run of each,
/// the formats alternating so that a slow moment of the machine falls on both.
fn time_both(
    mut f32_run: impl FnMut() -> candle_core::Result<()>,
    mut bf16_run: impl FnMut() -> candle_core::Result<()>,
) -> Result<Bf16Timing> {
    f32_run()?;
    bf16_run()?;
    let mut timing = Bf16Timing {
        f32_seconds: f64::INFINITY,
        bf16_seconds: f64::INFINITY,
    };
    for _ in 0..TIMED_RUNS {
        let start = Instant::now();
        f32_run()?;
        timing.f32_seconds = timing.f32_seconds.min(start.elapsed().as_secs_f64());
        let start = Instant::now();
        bf16_run()?;
        timing.bf16_seconds = timing.bf16_seconds.min(start.elapsed().as_secs_f64());
    }
    Ok(timing)
}

/// Times CLIP's MLP shapes (a layer's value and its input gradient) with f32 and with bf16
/// weights, as `load_linear` holds them in each format.
fn time_clip(products: ClipProducts) -> Result<Bf16Timing> {
    let ClipProducts {
        hidden,
        intermediate,
        ..
    } = products;
    let rows = products.rows.clamp(1, MAX_PROBE_ROWS);
    let cpu = Device::Cpu;
    let scale = 1.0 / (hidden.max(1) as f32).sqrt();
    let weight = Tensor::from_vec(
        seeded_values(intermediate * hidden, 1, scale),
        (intermediate, hidden),
        &cpu,
    )?;
    let bias = Tensor::from_vec(seeded_values(intermediate, 2, 0.1), intermediate, &cpu)?;
    let x = Tensor::from_vec(seeded_values(rows * hidden, 3, 1.0), (rows, hidden), &cpu)?;
    let g = Tensor::from_vec(
        seeded_values(rows * intermediate, 4, 1e-3),
        (rows, intermediate),
        &cpu,
    )?;
    let f32_layer = Linear::new(weight.clone(), Some(bias.clone()))?;
    let bf16_layer = Linear::new(weight.to_dtype(DType::BF16)?, Some(bias))?;
    let run = |layer: &Linear| -> candle_core::Result<()> {
        layer.value(&x)?;
        layer.input_gradient(&g)?;
        Ok(())
    };
    time_both(|| run(&f32_layer), || run(&bf16_layer))
}

/// Times one layer of each width in `bf16_widths` (`width -> width`, forward and backward, on
/// a picture of `8192 / width` pixels a side, as many products as each block of VGG-19 runs
/// relative to the others), built with an f32 and with a bf16 backward.
fn time_vgg(bf16_widths: &[usize], kernels: KernelWidths) -> Result<Bf16Timing> {
    let cpu = Device::Cpu;
    let mut layers = Vec::new();
    for (seed, &width) in (10u64..).zip(bf16_widths) {
        let side = (8192 / width).clamp(4, 64);
        let scale = 1.0 / ((9 * width) as f32).sqrt();
        let weight = Tensor::from_vec(
            seeded_values(width * width * 9, seed, scale),
            (width, width, 3, 3),
            &cpu,
        )?;
        let bias = Tensor::from_vec(seeded_values(width, seed + 1, 0.05), width, &cpu)?;
        let dims = (1, side, side, width);
        let n = side * side * width;
        let x = Var::from_vec(seeded_values(n, seed + 2, 1.0), dims, &cpu)?;
        let g = Tensor::from_vec(seeded_values(n, seed + 3, 1e-3), dims, &cpu)?;
        let f32_conv = ConvReluChannelsLast::new(&weight, &bias, false, kernels)?;
        let bf16_conv = ConvReluChannelsLast::new(&weight, &bias, true, kernels)?;
        layers.push((x, g, f32_conv, bf16_conv));
    }
    let scratch = Arc::new(Mutex::new(Vec::new()));
    let run = |bf16: bool| -> candle_core::Result<()> {
        for (x, g, f32_conv, bf16_conv) in &layers {
            let conv = if bf16 { bf16_conv } else { f32_conv };
            let y = conv.forward(x.as_tensor(), &scratch)?;
            y.mul(g)?.sum_all()?.backward()?;
        }
        Ok(())
    };
    time_both(|| run(false), || run(true))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn timed(f32_seconds: f64, bf16_seconds: f64) -> AutoChoice {
        AutoChoice::Timed(Bf16Timing {
            f32_seconds,
            bf16_seconds,
        })
    }

    /// A timing that the test's case must not run.
    fn untimed() -> Result<Bf16Timing> {
        panic!("timed where the choice was already made")
    }

    #[test]
    fn the_switch_the_device_the_instructions_and_the_layers_decide_before_any_timing() {
        let fast = || {
            Ok(Bf16Timing {
                f32_seconds: 2.0,
                bf16_seconds: 1.0,
            })
        };
        assert_eq!(
            choose(Some(false), true, true, true, untimed).unwrap(),
            AutoChoice::Forced(false)
        );
        // Forced bf16 holds even where the instructions are absent or nothing would change.
        assert_eq!(
            choose(Some(true), false, false, false, untimed).unwrap(),
            AutoChoice::Forced(true)
        );
        assert_eq!(
            choose(None, false, true, true, untimed).unwrap(),
            AutoChoice::NotCpu
        );
        assert_eq!(
            choose(None, true, false, true, untimed).unwrap(),
            AutoChoice::NoInstructions
        );
        assert_eq!(
            choose(None, true, true, false, untimed).unwrap(),
            AutoChoice::NoBf16Layer
        );
        assert_eq!(
            choose(None, true, true, true, fast).unwrap(),
            timed(2.0, 1.0)
        );
        for choice in [
            AutoChoice::Forced(false),
            AutoChoice::NotCpu,
            AutoChoice::NoInstructions,
            AutoChoice::NoBf16Layer,
        ] {
            assert!(!choice.takes_bf16(), "{choice:?}");
            assert_eq!(choice.clip(), ClipPrecision::F32);
            assert_eq!(choice.vgg(), VggPrecision::F32);
        }
        assert_eq!(AutoChoice::Forced(true).clip(), ClipPrecision::Bf16);
        assert_eq!(AutoChoice::Forced(true).vgg(), VggPrecision::Bf16);
        // A failed timing is an error, not a choice.
        let failed = || {
            Err(StyleLossError::Config {
                field: "probe".into(),
                value: String::new(),
                reason: "failed".into(),
            })
        };
        assert!(choose(None, true, true, true, failed).is_err());
    }

    /// bf16 is taken from exactly `MIN_SPEEDUP` times the f32 rate, and never when slower,
    /// tied, or timed as nothing or as not a number.
    #[test]
    fn timings_choose_bf16_only_from_the_minimum_speedup() {
        let at = |f32_seconds: f64| timed(f32_seconds, 1.0);
        assert!(at(MIN_SPEEDUP).takes_bf16());
        assert!(at(2.0).takes_bf16());
        assert!(!at(MIN_SPEEDUP - 1e-9).takes_bf16());
        assert!(!at(1.0).takes_bf16());
        assert!(!at(0.5).takes_bf16());
        for (f, b) in [
            (1.0, 0.0),
            (0.0, 1.0),
            (f64::NAN, 1.0),
            (1.0, f64::NAN),
            (f64::INFINITY, 1.0),
            (2.0, -1.0),
        ] {
            assert!(!timed(f, b).takes_bf16(), "{f} / {b}");
            assert_eq!(timed(f, b).to_string(), "the timing of bf16 failed");
        }
        assert_eq!(at(1.6).to_string(), "bf16 1.6x faster here");
        assert_eq!(
            timed(1.0, 1.4).to_string(),
            "bf16 is 1.4x slower on this CPU"
        );
        assert_eq!(
            at(1.05).to_string(),
            "bf16 only 1.05x faster on this CPU, under the 1.1x that pays for its rounding"
        );
        assert_eq!(
            AutoChoice::Forced(false).to_string(),
            "CLIPGAUSSIAN_CPU_BF16=0"
        );
        assert_eq!(
            AutoChoice::NoInstructions.to_string(),
            "this CPU has no AVX-512 BF16"
        );
    }

    #[test]
    fn the_switch_takes_its_words_and_refuses_others() {
        for off in ["0", "false", "OFF", " no "] {
            assert_eq!(parse_switch(off).unwrap(), Some(false), "{off}");
        }
        for on in ["1", "true", "On", "yes"] {
            assert_eq!(parse_switch(on).unwrap(), Some(true), "{on}");
        }
        assert_eq!(parse_switch("").unwrap(), None);
        let e = parse_switch("2").unwrap_err().to_string();
        assert!(e.contains(&format!("{CPU_BF16_ENV} = 2:")), "{e}");
    }

    /// ViT-B/32 at 224: 50 tokens an image, so a batch of 9 images is 450 rows.
    #[test]
    fn clips_products_count_the_tokens_of_the_batch() {
        let vit = crate::clip::ClipConfig::vit_b_32().vision;
        assert_eq!(
            ClipProducts::of(&vit, 9),
            ClipProducts {
                rows: 450,
                hidden: 768,
                intermediate: 3072
            }
        );
        assert_eq!(ClipProducts::of(&vit, 0).rows, 50);
    }

    #[test]
    fn vgg_times_each_bf16_width_once() {
        let vgg19 = Vgg19Widths::default();
        assert_eq!(distinct_bf16_widths(vgg19, MEASURED), vec![256, 512]);
        assert!(distinct_bf16_widths(Vgg19Widths([5, 8, 6, 7, 9]), MEASURED).is_empty());
        let low = KernelWidths {
            bf16_backward: 7,
            ..MEASURED
        };
        assert_eq!(
            distinct_bf16_widths(Vgg19Widths([5, 8, 6, 7, 9]), low),
            vec![8, 7, 9]
        );
    }

    /// The probes run the real layers both ways and time something (small shapes here).
    #[test]
    fn the_probes_time_both_formats() {
        let clip = time_clip(ClipProducts {
            rows: 20,
            hidden: 16,
            intermediate: 64,
        })
        .unwrap();
        let low = KernelWidths {
            bf16_backward: 8,
            ..MEASURED
        };
        let vgg = time_vgg(&[8, 16], low).unwrap();
        for t in [clip, vgg] {
            assert!(t.speedup() > 0.0, "{t:?}");
        }
    }
}
