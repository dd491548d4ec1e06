//! `stylize-3d`: stylizes a trained 3DGS scene (INRIA PLY + its dataset) with CLIPGaussian and
//! writes the stylized PLY, before/after pictures, the losses and the resolved configuration.
//!
//! The configuration comes from `--config` (e.g. `configs/3d.json`; the paper's defaults when
//! absent), then the flags below, then every `--set field=value` in order.

use std::path::PathBuf;
use std::process::ExitCode;

use base_3dgs::stylize::{run, Override, RunOptions, StylizeConfig, StylizeError};
use clap::Parser;

/// Command-line arguments.
#[derive(Parser, Debug)]
#[command(
    name = "stylize-3d",
    version,
    about = "CLIPGaussian 3D stylization of a 3DGS scene"
)]
struct Cli {
    /// JSON configuration (configs/3d.json, configs/3d-light.json).
    #[arg(long)]
    config: Option<PathBuf>,
    /// The trained scene, INRIA PLY.
    #[arg(long)]
    ply: Option<PathBuf>,
    /// The dataset folder (NeRF-synthetic or COLMAP).
    #[arg(long)]
    data: Option<PathBuf>,
    /// The output folder.
    #[arg(long)]
    out: Option<PathBuf>,
    /// The style as text.
    #[arg(long)]
    style_prompt: Option<String>,
    /// The style as a picture.
    #[arg(long)]
    style_image: Option<PathBuf>,
    /// The source prompt (default "a Photo").
    #[arg(long)]
    source_prompt: Option<String>,
    /// Optimizer steps.
    #[arg(long)]
    steps: Option<u64>,
    /// Resolution divisor of the dataset images.
    #[arg(short = 'r', long)]
    resolution: Option<u32>,
    /// CLIP config.json (default: ViT-B/32).
    #[arg(long)]
    clip_config: Option<PathBuf>,
    /// CLIP weights (safetensors).
    #[arg(long)]
    clip_weights: Option<PathBuf>,
    /// CLIP tokenizer.json.
    #[arg(long)]
    tokenizer: Option<PathBuf>,
    /// VGG-19 weights (safetensors, torchvision layout).
    #[arg(long)]
    vgg_weights: Option<PathBuf>,
    /// Any configuration field, e.g. `--set feature_lr=0.002 --set preview_views=[0,3]`.
    #[arg(long = "set", value_name = "FIELD=VALUE")]
    set: Vec<String>,
    /// Continue the run from `<out>/checkpoint/`.
    #[arg(long)]
    resume: bool,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

impl Cli {
    /// The flags as overrides, then the `--set` ones.
    fn overrides(&self) -> Result<Vec<Override>, StylizeError> {
        let path = |p: &Option<PathBuf>| p.as_ref().map(|p| p.display().to_string());
        let flags = [
            ("ply", path(&self.ply).map(Into::into)),
            ("data", path(&self.data).map(Into::into)),
            ("out", path(&self.out).map(Into::into)),
            ("style_prompt", self.style_prompt.clone().map(Into::into)),
            ("style_image", path(&self.style_image).map(Into::into)),
            ("source_prompt", self.source_prompt.clone().map(Into::into)),
            ("steps", self.steps.map(Into::into)),
            ("resolution", self.resolution.map(Into::into)),
            ("clip_config", path(&self.clip_config).map(Into::into)),
            ("clip_weights", path(&self.clip_weights).map(Into::into)),
            ("tokenizer", path(&self.tokenizer).map(Into::into)),
            ("vgg_weights", path(&self.vgg_weights).map(Into::into)),
        ];
        let mut overrides: Vec<Override> = flags
            .into_iter()
            .filter_map(|(field, value): (&str, Option<serde_json::Value>)| {
                value.map(|v| Override::new(field, v))
            })
            .collect();
        for s in &self.set {
            overrides.push(Override::parse(s)?);
        }
        Ok(overrides)
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = cli.overrides().and_then(|overrides| {
        let config = StylizeConfig::resolve(cli.config.as_deref(), &overrides)?;
        let options = RunOptions {
            resume: cli.resume,
            progress: !cli.quiet,
        };
        run(&config, &options)
    });
    match result {
        Ok(summary) => {
            let last = summary.losses.last().map_or(f32::NAN, |l| l.total);
            println!(
                "wrote {} ({} Gaussians, final loss {last:.4})",
                summary.stylized_ply.display(),
                summary.gaussians.len()
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
