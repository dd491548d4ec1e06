//! The command-line pieces every modality's binary shares: the `stylize` flags (flattened into
//! its own arguments with clap) and their translation into configuration overrides (the flags
//! first, then each `--set field=value` in order), the `interpolate` subcommand, and the exit
//! of every subcommand ([`exit_code`]: the error line and the exit code); the binaries'
//! skeleton is [`crate::binary`]. Model
//! files the binaries cannot find are reported with these flags ([`crate::weights`]); outputs
//! are checked before any work ([`crate::writable`]).

use std::error::Error;
use std::path::PathBuf;
use std::process::ExitCode;

use gs_core::dataset::nerf_synthetic::Split;

use gs_wgpu::backend::DeviceChoice;
use serde::Serialize;
use serde_json::Value;

use crate::error::causes;
use crate::evaluation::{ClipFiles, Scoring, Style};
use crate::interrupt::{stop_on_ctrl_c, INTERRUPTED_EXIT};
use crate::model_kind::{check_model, Binary};
use crate::writable::check_output_file;
use crate::{Override, RunOptions, StylizeError};

/// The style, the model files, the device and the run controls of `stylize`.
#[derive(clap::Args, Debug)]
pub struct StyleArgs {
    /// The flags that set a field of the shared settings.
    #[command(flatten)]
    pub settings: StyleFlags,
    /// Any configuration field, e.g. `--set num_patches=16`; `FIELD.KEY=VALUE` sets one key of
    /// an object field, e.g. one parameter group's learning rate: `--set
    /// learning_rates.GROUP=0.005` (or `=frozen`; the groups are listed in the configuration's
    /// `learning_rates`). `--set clip_precision=auto --set vgg_precision=auto` times CLIP's
    /// linear layers and VGG's backward in bf16 against f32 at start and keeps the faster
    /// (bf16 only from 1.1 times as fast; $CLIPGAUSSIAN_CPU_BF16=0 or 1 forces f32 or bf16).
    #[arg(long = "set", value_name = "FIELD=VALUE")]
    pub set: Vec<String>,
    /// Continue the run from `<out>/checkpoint/` (a finished run: only with more --steps).
    #[arg(long)]
    pub resume: bool,
    /// Show no progress (else a bar on a terminal, or a line every 5 % of the steps when
    /// stderr is a file or a pipe).
    #[arg(long)]
    pub quiet: bool,
}

/// The `stylize` flags that set a field of [`crate::StyleSettings`], each named as its field
/// (the field a given flag sets is its serialized name; an absent flag sets nothing).
#[derive(clap::Args, Debug, Serialize)]
pub struct StyleFlags {
    /// The style as text.
    #[arg(long, conflicts_with = "style_image")]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub style_prompt: Option<String>,
    /// The style as a picture (PNG or JPEG; it replaces a prompt the configuration gives).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub style_image: Option<PathBuf>,
    /// The source prompt the style direction starts from (default "a Photo").
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub source_prompt: Option<String>,
    /// Stylization steps: optimizer updates (default 4999, the updates of the authors' 5000
    /// iterations).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub steps: Option<u64>,
    /// CLIP config.json (default: ViT-B/32).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub clip_config: Option<PathBuf>,
    /// CLIP weights, safetensors (default: $CLIPGAUSSIAN_CLIP_B32_WEIGHTS, else the Hugging
    /// Face cache, else downloaded from the Hugging Face Hub into that cache on first use).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub clip_weights: Option<PathBuf>,
    /// CLIP tokenizer.json (default: $CLIPGAUSSIAN_CLIP_TOKENIZER, else the Hugging Face cache,
    /// else downloaded on first use).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tokenizer: Option<PathBuf>,
    /// VGG-19 weights, safetensors in torchvision's layout (default:
    /// $CLIPGAUSSIAN_VGG19_WEIGHTS, else the Hugging Face cache, else downloaded on first use).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vgg_weights: Option<PathBuf>,
    /// Where the run computes: cpu, gpu, or auto (a real GPU when there is one, else the cpu;
    /// the default). The Gaussians render and train there through wgpu; CLIP and VGG run on
    /// candle's CUDA or Metal device in builds with that feature, else on the cpu.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub device: Option<DeviceChoice>,
}

impl StyleArgs {
    /// How to run: `--resume`, the progress unless `--quiet`, and the process's Ctrl-C
    /// handler as the stop flag.
    pub fn run_options(&self) -> Result<RunOptions, ctrlc::Error> {
        Ok(RunOptions {
            resume: self.resume,
            progress: !self.quiet,
            stop: stop_on_ctrl_c()?,
        })
    }

    /// The overrides of the modality's own flags (`modality`: a flags type whose serialized
    /// fields are configuration fields, absent flags left out), then of these flags, then of
    /// every `--set`. A style image clears the prompt a configuration may give, so that
    /// exactly one style remains.
    pub fn overrides(&self, modality: &impl Serialize) -> Result<Vec<Override>, StylizeError> {
        let mut overrides = Vec::new();
        for flags in [flag_fields(modality)?, flag_fields(&self.settings)?] {
            overrides.extend(flags.into_iter().map(|(field, v)| Override::new(&field, v)));
        }
        if self.settings.style_image.is_some() {
            overrides.push(Override::new("style_prompt", Value::Null));
        }
        for s in &self.set {
            overrides.push(Override::parse(s)?);
        }
        Ok(overrides)
    }
}

/// The configuration fields `flags` sets: its serialized fields, by name.
fn flag_fields(flags: &impl Serialize) -> Result<serde_json::Map<String, Value>, StylizeError> {
    match serde_json::to_value(flags) {
        Ok(Value::Object(fields)) => Ok(fields),
        Ok(other) => Err(StylizeError::Config(format!(
            "flags serialize as {other}, not as configuration fields"
        ))),
        Err(e) => Err(StylizeError::Config(format!("a flag's value: {e}"))),
    }
}

/// The `--split` of `render`: which views of a NeRF-synthetic (or D-NeRF, or nerfstudio
/// `transforms.json`) scene to render.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum SplitArg {
    /// transforms_train.json.
    Train,
    /// transforms_test.json.
    Test,
    /// transforms_val.json.
    Val,
}

impl From<SplitArg> for Split {
    fn from(split: SplitArg) -> Self {
        match split {
            SplitArg::Train => Split::Train,
            SplitArg::Test => Split::Test,
            SplitArg::Val => Split::Val,
        }
    }
}

/// The style and the CLIP model of `eval` (the paper's CLIP metrics, ViT-L/14 by default).
#[derive(clap::Args, Debug)]
pub struct EvalStyleArgs {
    /// The style as text.
    #[arg(
        long,
        required_unless_present = "style_image",
        conflicts_with = "style_image"
    )]
    pub style_prompt: Option<String>,
    /// The style as a picture.
    #[arg(long)]
    pub style_image: Option<PathBuf>,
    /// The neutral prompt of CLIP-SIM (the training source prompt).
    #[arg(long, default_value = style_loss::DEFAULT_SOURCE_PROMPT)]
    pub source_prompt: String,
    /// CLIP config.json (default: ViT-L/14, the paper's evaluation model).
    #[arg(long)]
    pub clip_config: Option<PathBuf>,
    /// CLIP weights, safetensors (default: ViT-L/14 from $CLIPGAUSSIAN_CLIP_L14_WEIGHTS, else
    /// the Hugging Face cache, else downloaded from the Hugging Face Hub into that cache on
    /// first use).
    #[arg(long)]
    pub clip_weights: Option<PathBuf>,
    /// CLIP tokenizer.json (default: $CLIPGAUSSIAN_CLIP_TOKENIZER, else the Hugging Face
    /// cache, else downloaded on first use).
    #[arg(long)]
    pub tokenizer: Option<PathBuf>,
}

impl EvalStyleArgs {
    /// The style (clap has checked that exactly one of prompt and picture is given).
    pub fn style(&self) -> Style {
        Style::given(self.style_image.as_ref(), self.style_prompt.as_ref())
    }

    /// The CLIP files given.
    pub fn clip_files(&self) -> ClipFiles {
        ClipFiles {
            config: self.clip_config.clone(),
            weights: self.clip_weights.clone(),
            tokenizer: self.tokenizer.clone(),
        }
    }

    /// The style, the source prompt and the CLIP files given.
    pub fn scoring(&self) -> Scoring {
        Scoring {
            style: self.style(),
            source_prompt: self.source_prompt.clone(),
            clip: self.clip_files(),
        }
    }
}

/// Arguments of `interpolate`, the same in every binary: blends two models of the same
/// Gaussians (e.g. two stylizations of one base model) parameter by parameter.
#[derive(clap::Args, Debug)]
pub struct InterpolateArgs {
    /// The first model (t = 0); a PLY's extra properties and format are kept.
    #[arg(long)]
    pub a: PathBuf,
    /// The second model (t = 1), of the same Gaussians (and frames, cores, network) as A.
    #[arg(long)]
    pub b: PathBuf,
    /// The interpolation parameter; values outside [0, 1] extrapolate.
    #[arg(long, allow_negative_numbers = true)]
    pub t: f32,
    /// The output model.
    #[arg(long)]
    pub out: PathBuf,
}

impl InterpolateArgs {
    /// Checks before any work that `--a` and `--b` are models `binary` opens (another
    /// binary's are refused naming it: [`check_model`]) and that `--out` can be written
    /// ([`check_output_file`]).
    pub fn check(&self, binary: Binary) -> Result<(), Box<dyn Error>> {
        check_model(binary, "--a", &self.a)?;
        check_model(binary, "--b", &self.b)?;
        check_output_file(&self.out)?;
        Ok(())
    }

    /// Why `--a` and `--b` do not blend: `source`, naming both files.
    pub fn mismatch(&self, source: impl Into<Box<dyn Error + Send + Sync>>) -> StylizeError {
        StylizeError::Interpolate {
            a: self.a.clone(),
            b: self.b.clone(),
            source: source.into(),
        }
    }
}

/// Arguments of the `selftest` subcommand every binary has.
#[derive(clap::Args, Debug)]
pub struct SelftestArgs {
    /// Where to run the parts: cpu, gpu (wgpu for the rasterizer and Adam, CUDA or Metal for the
    /// loss when built with them) or auto (a GPU when there is one, else the cpu).
    #[arg(long, default_value = "auto")]
    pub device: DeviceChoice,
}

impl SelftestArgs {
    /// Runs every part ([`crate::selftest::run_selftest`]) and the modality's `extra` ones on
    /// the device, prints the table, and fails naming the parts that differ from the cpu.
    pub fn run(&self, extra: Vec<crate::selftest::ExtraCheck>) -> Result<(), Box<dyn Error>> {
        let checks = crate::selftest::run_selftest(self.device, extra)?;
        print!("{}", crate::selftest::table(&checks));
        let failed: Vec<&str> = checks
            .iter()
            .filter(|c| !c.passed())
            .map(|c| c.part.as_str())
            .collect();
        if failed.is_empty() {
            Ok(())
        } else {
            Err(format!("selftest: {} differ from the cpu", failed.join(", ")).into())
        }
    }
}

/// A subcommand's result as the process's exit: nothing more on success; on failure the error
/// on one `error: ...` line (and the lines of [`StylizeError::Several`]) and exit code
/// [`INTERRUPTED_EXIT`] when the run was stopped by Ctrl-C (a [`StylizeError::Interrupted`] or
/// [`StylizeError::InterruptedFit`] anywhere in the error's chain), else 1.
pub fn exit_code(result: Result<(), Box<dyn Error>>) -> ExitCode {
    let Err(e) = result else {
        return ExitCode::SUCCESS;
    };
    eprintln!("error: {e}");
    let interrupted = causes(e.as_ref()).any(|c| {
        matches!(
            c.downcast_ref::<StylizeError>(),
            Some(StylizeError::Interrupted { .. } | StylizeError::InterruptedFit { .. })
        )
    });
    if interrupted {
        ExitCode::from(INTERRUPTED_EXIT)
    } else {
        ExitCode::FAILURE
    }
}
