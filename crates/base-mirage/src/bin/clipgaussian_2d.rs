//! `clipgaussian-2d`: CLIPGaussian on pictures, held as MiraGe flat Gaussians.
//!
//! - `stylize`: fits a picture (or takes a fitted model) and stylizes it with a text or
//!   picture style; a model alone, its own render; with neither, the embedded default
//!   picture. Ctrl-C stops after the current step and writes a checkpoint to resume from.
//! - `fit`: fits a picture and writes its model.
//! - `render`: renders a model at the size it records (or a chosen one), from the front or
//!   the mirror camera.
//! - `interpolate`: blends two models of the same Gaussians.
//! - `eval`: the paper's CLIP metrics of a stylized picture against the original.

use std::error::Error;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use base_mirage::evaluation::evaluate_picture;
use base_mirage::fit::{
    fit_logged, render_picture, write_psnr_plot, Fitted, PictureFitSettings, FIT_PSNR_PNG,
};
use base_mirage::mirror::DEFAULT_DISTANCE;
use base_mirage::model_file::{read_model, write_model, FittedTo};
use base_mirage::picture::load_picture;
use base_mirage::stylize::{run, PictureStylizeConfig, PREVIEW_PNG, STYLIZED_PNG};
use clap::{Args, Subcommand};
use gs_core::image_loss::psnr;
use gs_core::mirror_pair::plane_camera;
use gs_core::wide_pictures::AUTHORS_MAX_WIDTH;
use gs_core::Image;
use gs_stylize::background::parse_background;
use gs_stylize::binary::{ModalityBinary, PlyModel};
use gs_stylize::cli::{EvalStyleArgs, StyleArgs};
use gs_stylize::drive::{run_fit, FitCommand, FitWritten};
use gs_stylize::evaluation::write_metrics;
use gs_stylize::export::{gaussians_at, ExportArgs};
use gs_stylize::model_kind::{check_model, Binary};
use gs_stylize::summary::write_summary;
use gs_stylize::viewer::Shown;
use gs_stylize::writable::check_output_file;
use gs_stylize::{open_device, resolve_config, Override, StylizeError};
use gs_wgpu::backend::{Backend, DeviceChoice};
use serde::Serialize;

/// Stylize a picture with a text or picture style ("Starry Night by Vincent van Gogh" and
/// the embedded default picture when neither a picture nor a model is given).
///
/// Fits the picture first unless --model gives a fitted one, then stylizes it with the
/// paper's 2D settings (configs/2d.json). A --model given without --picture is stylized
/// alone: the picture is its own render, at the size it records. Writes to --out:
/// stylized.png (the size of the picture), preview.png (original | stylized), model.ply (the
/// stylized model), viewer.html (both in a browser, with a slider from the fit to the
/// stylized model),
/// base.ply and fit_psnr.png (the fit and its PSNR per step, when this run fitted),
/// original.png (the embedded default picture or the model's own render, when no --picture
/// is given), losses.json, losses.png, config.json and checkpoint/. The
/// configuration comes from --config (the paper's defaults when absent), then the flags,
/// then every --set field=value in order. Every input is checked before the fit starts; a
/// --model fitted to a picture of another aspect ratio is refused. Ctrl-C stops after the
/// current step and writes a checkpoint (a second Ctrl-C quits at once); run the same
/// command with --resume to continue. A finished run's checkpoint does not hold the
/// folder: the same command runs again, and --resume continues only with more --steps.
#[derive(Args, Debug, Serialize)]
struct StylizeArgs {
    /// JSON configuration (configs/2d.json is the paper's; configs/2d-preview.json is quick).
    #[arg(long)]
    #[serde(skip)]
    config: Option<PathBuf>,
    /// The picture, PNG or JPEG of any size (default: the render of --model when it is given,
    /// else the embedded picture).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    picture: Option<PathBuf>,
    /// A model of the picture fitted earlier (MiraGe PLY from `fit`); default: fit first.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    model: Option<PathBuf>,
    /// The output folder (created when absent).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    out: Option<PathBuf>,
    /// Gaussians of the fit.
    #[arg(long)]
    #[serde(rename = "fit_gaussians", skip_serializing_if = "Option::is_none")]
    gaussians: Option<usize>,
    /// Steps of the fit.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    fit_steps: Option<u64>,
    /// Colour behind transparent pixels and behind the Gaussians: white, black or R,G,B
    /// (default black, as MiraGe).
    #[arg(long, value_parser = parse_background)]
    #[serde(skip_serializing_if = "Option::is_none")]
    background: Option<[f32; 3]>,
    /// A picture wider than this is shrunk to it, pixels (PIL's bicubic, as MiraGe; default
    /// 1600); 0 keeps every picture at its size.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    max_width: Option<u32>,
    /// The style (default "Starry Night by Vincent van Gogh"), model files, device and run
    /// controls; `--resume` also reuses `<out>/base.ply`.
    #[command(flatten)]
    #[serde(skip)]
    style: StyleArgs,
}

impl StylizeArgs {
    /// The flags as overrides, then the `--set` ones.
    fn overrides(&self) -> Result<Vec<Override>, StylizeError> {
        self.style.overrides(self)
    }
}

/// The 2D binary's own subcommands.
#[derive(Subcommand, Debug)]
enum PictureCommand {
    /// Fit a picture with flat Gaussians (no stylization).
    ///
    /// Writes to --out: model.ply (MiraGe PLY, recording the picture's size), fitted.png (the
    /// front camera's render, the size of the picture), preview.png (picture | fit),
    /// fit_psnr.png (the PSNR of each step, front and mirror camera) and fit.json (steps, time
    /// and PSNR), and prints the PSNR.
    Fit(FitArgs),
}

/// Write a model's Gaussians in a splat format viewers open.
///
/// The flat Gaussians as they render (in the plane z = 0 of the front camera), written in
/// the format --out's name ends in (or --format): INRIA PLY, SuperSplat compressed PLY, SPZ,
/// .splat or glTF (.glb).
#[derive(Args, Debug)]
struct PictureExportArgs {
    #[command(flatten)]
    export: ExportArgs,
}

/// Arguments of `fit`.
#[derive(Args, Debug)]
struct FitArgs {
    /// The picture, PNG or JPEG of any size.
    #[arg(long)]
    picture: PathBuf,
    /// The output folder (created after the fit; files of the same names are replaced).
    #[arg(long)]
    out: PathBuf,
    /// Number of Gaussians.
    #[arg(long, default_value_t = PictureFitSettings::default().gaussians)]
    gaussians: usize,
    /// Optimizer steps.
    #[arg(long, default_value_t = PictureFitSettings::default().steps)]
    steps: u64,
    /// SH degree of the colours (0 to 3).
    #[arg(long, default_value_t = PictureFitSettings::default().sh_degree)]
    sh_degree: usize,
    /// Seed of the initial Gaussians and the camera order.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Colour behind transparent pixels and behind the Gaussians: white, black or R,G,B.
    #[arg(long, value_parser = parse_background, default_value = "black")]
    background: [f32; 3],
    /// A picture wider than this is shrunk to it, pixels (PIL's bicubic, as MiraGe); 0 keeps
    /// every picture at its size.
    #[arg(long, default_value_t = AUTHORS_MAX_WIDTH)]
    max_width: u32,
    /// Distance of the cameras from the picture plane, world units.
    #[arg(long, default_value_t = DEFAULT_DISTANCE)]
    distance: f64,
    /// Where to fit: cpu, gpu, or auto (a real GPU when there is one, else the cpu).
    #[arg(long, default_value_t = DeviceChoice::Auto)]
    device: DeviceChoice,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

/// Render a model from the front camera (or the mirror camera) to a PNG.
#[derive(Args, Debug)]
struct RenderArgs {
    /// The model, MiraGe PLY.
    #[arg(long)]
    model: PathBuf,
    /// Width of the picture, pixels (default: the fitted picture's, which our model files
    /// record).
    #[arg(long)]
    width: Option<u32>,
    /// Height of the picture, pixels (default: the fitted picture's).
    #[arg(long)]
    height: Option<u32>,
    /// Render from the mirror camera (the picture flipped left to right).
    #[arg(long)]
    mirror: bool,
    /// The background colour: white, black or R,G,B.
    #[arg(long, value_parser = parse_background, default_value = "black")]
    background: [f32; 3],
    /// Distance of the camera from the picture plane (default: the fit's, which our model
    /// files record, else the fit's default).
    #[arg(long)]
    distance: Option<f64>,
    /// Where to render: cpu, gpu, or auto (a real GPU when there is one, else the cpu).
    #[arg(long, default_value_t = DeviceChoice::Auto)]
    device: DeviceChoice,
    /// The output PNG (its folder must exist; a file of that name is replaced).
    #[arg(long)]
    out: PathBuf,
}

/// The paper's CLIP metrics (CLIP-S, CLIP-SIM) of a stylized picture against the original.
///
/// Scores (x100) the picture `--renders` against `--gt` for the style and writes them as
/// JSON (CLIP-CONS and CLIP-F need several views: null here).
#[derive(Args, Debug)]
struct EvalArgs {
    /// The stylized picture (e.g. `<stylize out>/stylized.png`).
    #[arg(long)]
    renders: PathBuf,
    /// The reference: the original picture.
    #[arg(long)]
    gt: PathBuf,
    /// The style and the CLIP model.
    #[command(flatten)]
    style: EvalStyleArgs,
    /// The colour behind transparent pixels: white, black or R,G,B (black by default, as
    /// `stylize` composites the picture).
    #[arg(long, value_parser = parse_background, default_value = "black")]
    background: [f32; 3],
    /// Where to write the scores as JSON (its folder must exist; checked before any work).
    #[arg(long, default_value = "metrics.json")]
    out: PathBuf,
}

/// Runs `eval`.
fn eval(args: &EvalArgs) -> Result<(), Box<dyn Error>> {
    check_output_file(&args.out)?;
    let metrics = evaluate_picture(
        &args.renders,
        &args.gt,
        args.background,
        &args.style.scoring(),
    )?;
    print!("{}", metrics.lines());
    write_metrics(&args.out, &metrics)?;
    println!("wrote {}", args.out.display());
    Ok(())
}

/// Runs `stylize`.
fn stylize(args: &StylizeArgs) -> Result<(), Box<dyn Error>> {
    let started = std::time::Instant::now();
    if let Some(model) = &args.model {
        check_model(Binary::Picture, "--model", model)?;
    }
    let config: PictureStylizeConfig = resolve_config(args.config.as_deref(), &args.overrides()?)?;
    let summary = run(&config, &args.style.run_options()?)?;
    let out = config.out.as_deref().expect("run checked out");
    println!(
        "wrote {} and {} ({}x{}, {} Gaussians, final loss {:.4})",
        out.join(STYLIZED_PNG).display(),
        out.join(PREVIEW_PNG).display(),
        summary.stylized.width,
        summary.stylized.height,
        summary.model.params().len(),
        summary.losses.last().copied().unwrap_or(f32::NAN)
    );
    print!(
        "{}",
        write_summary("clipgaussian-2d stylize", started, out)?
    );
    Ok(())
}

/// Runs `fit`.
fn fit(args: &FitArgs) -> Result<(), Box<dyn Error>> {
    let settings = PictureFitSettings {
        gaussians: args.gaussians,
        steps: args.steps,
        sh_degree: args.sh_degree,
        seed: args.seed,
        background: args.background,
        distance: args.distance,
        ..PictureFitSettings::default()
    };
    let command = FitCommand {
        out: &args.out,
        device: args.device,
        progress: !args.quiet,
        what: "the picture",
        steps: settings.steps,
        stages: Vec::new(),
    };
    run_fit(
        &command,
        |_| {
            Ok(load_picture(
                &args.picture,
                args.background,
                args.max_width,
            )?)
        },
        |picture, backend, on_step| Ok(fit_logged(picture, &settings, backend, on_step)?),
        |picture, fitted, backend, seconds| {
            let psnr_db = write_fit(picture, fitted, &settings, backend, &args.out)?;
            let line = format!(
                "fitted {} ({}x{}) with {} Gaussians in {seconds:.1} s: PSNR {psnr_db:.2} dB; \
                 wrote {}",
                args.picture.display(),
                picture.width,
                picture.height,
                settings.gaussians,
                args.out.display()
            );
            Ok(FitWritten {
                line,
                psnr_db,
                gaussians: settings.gaussians,
                test_psnr_db: None,
                seconds,
            })
        },
    )
}

/// Writes the fit of `picture` into `out`: model.ply, fitted.png, fit_psnr.png and
/// preview.png; returns the fitted picture's PSNR, dB.
fn write_fit(
    picture: &Image,
    fitted: Fitted,
    settings: &PictureFitSettings,
    backend: &Backend,
    out: &Path,
) -> Result<f64, Box<dyn Error>> {
    let Fitted {
        mut model,
        psnr: log,
    } = fitted;
    let render = render_picture(
        &mut model,
        picture.width,
        picture.height,
        settings.distance,
        false,
        settings.background,
        backend,
    )?;
    let fitted_to = FittedTo {
        width: picture.width,
        height: picture.height,
        distance: settings.distance,
    };
    write_model(&out.join("model.ply"), &model, &fitted_to)?;
    render.save_png(&out.join("fitted.png"))?;
    write_psnr_plot(&out.join(FIT_PSNR_PNG), &log)?;
    Image::side_by_side(&[picture, &render]).save_png(&out.join(PREVIEW_PNG))?;
    Ok(psnr(&render, picture))
}

/// Runs `render`.
fn render(args: &RenderArgs) -> Result<(), Box<dyn Error>> {
    check_model(Binary::Picture, "--model", &args.model)?;
    check_output_file(&args.out)?;
    let file = read_model(&args.model)?;
    let recorded = file.fitted_to;
    let size = |flag: &str, given: Option<u32>, recorded: Option<u32>| {
        given.or(recorded).ok_or_else(|| {
            format!(
                "{}: the model records no picture size (a MiraGe PLY, not one of ours); give \
                 {flag}",
                args.model.display()
            )
        })
    };
    let width = size("--width", args.width, recorded.map(|r| r.width))?;
    let height = size("--height", args.height, recorded.map(|r| r.height))?;
    let distance = args
        .distance
        .or(recorded.map(|r| r.distance))
        .unwrap_or(DEFAULT_DISTANCE);
    let mut model = file.model;
    let backend = open_device(args.device)?;
    let image = render_picture(
        &mut model,
        width,
        height,
        distance,
        args.mirror,
        args.background,
        &backend,
    )?;
    image.save_png(&args.out)?;
    println!("wrote {} ({width}x{height})", args.out.display());
    Ok(())
}

/// Runs `export`.
fn export(args: &ExportArgs) -> Result<(), Box<dyn Error>> {
    args.check(Binary::Picture, false)?;
    let file = read_model(&args.model)?;
    if !args.is_html() {
        println!("{}", args.write_at(&file.model, &[0.0], false)?);
        return Ok(());
    }
    // The page shows the picture's camera and its mirror, as the model was fitted.
    let fitted = file.fitted_to.ok_or_else(|| {
        format!(
            "{}: the model records no picture size (a MiraGe PLY, not one of ours), so the \
             page has no camera; export it with `render` instead",
            args.model.display()
        )
    })?;
    let camera = |mirrored| plane_camera(fitted.width, fitted.height, fitted.distance, mirrored);
    let cameras = vec![
        ("picture".to_string(), camera(false)?),
        ("mirror".to_string(), camera(true)?),
    ];
    let stylized = match &args.b {
        Some(b) => Some(gaussians_at(&read_model(b)?.model, 0.0)?),
        None => None,
    };
    let base = gaussians_at(&file.model, 0.0)?;
    println!(
        "{}",
        args.write_page(
            Shown::Still {
                base: &base,
                stylized: stylized.as_ref(),
            },
            cameras,
            [1.0; 3],
        )?
    );
    Ok(())
}

/// The 2D binary's part of the skeleton every binary shares.
struct Picture;

impl ModalityBinary for Picture {
    const BINARY: Binary = Binary::Picture;
    const ABOUT: &'static str =
        "CLIPGaussian on pictures (MiraGe flat Gaussians): stylize, fit, render, interpolate, \
         eval";
    const INTERPOLATE_HELP: &'static str =
        "Interpolate two models of the same Gaussians parameter by parameter.\n\nWrites `(1 - t) A \
         + t B` (opacities in logit space, scales in log space, quaternions normalized), e.g. \
         between two stylizations of one fit.";

    type Stylize = StylizeArgs;
    type Own = PictureCommand;
    type Render = RenderArgs;
    type Export = PictureExportArgs;
    type Eval = EvalArgs;
    type Model = PlyModel;

    /// The PLY as it is (`render` and `export` check more: [`read_model`]).
    fn read_model(path: &Path) -> Result<PlyModel, Box<dyn Error>> {
        PlyModel::read(path)
    }

    fn write_model(path: &Path, model: &PlyModel) -> Result<(), Box<dyn Error>> {
        model.write(path)
    }

    fn blend(a: &PlyModel, b: &PlyModel, t: f32) -> Result<PlyModel, String> {
        PlyModel::blend(a, b, t)
    }

    fn gaussian_count(model: &PlyModel) -> usize {
        model.ply.gaussians.len()
    }

    fn stylize(args: &StylizeArgs) -> Result<(), Box<dyn Error>> {
        stylize(args)
    }

    fn own(command: &PictureCommand) -> Result<(), Box<dyn Error>> {
        match command {
            PictureCommand::Fit(args) => fit(args),
        }
    }

    fn render(args: &RenderArgs) -> Result<(), Box<dyn Error>> {
        render(args)
    }

    fn export(args: &PictureExportArgs) -> Result<(), Box<dyn Error>> {
        export(&args.export)
    }

    fn eval(args: &EvalArgs) -> Result<(), Box<dyn Error>> {
        eval(args)
    }
}

fn main() -> ExitCode {
    gs_stylize::binary::main::<Picture>()
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;
    use serde_json::json;

    /// `stylize`'s flags alone.
    #[derive(Parser)]
    struct Line {
        #[command(flatten)]
        args: StylizeArgs,
    }

    #[test]
    fn every_stylize_flag_sets_its_configuration_field() {
        let own_flags = [
            "--picture",
            "p.png",
            "--model",
            "m.ply",
            "--out",
            "o",
            "--gaussians",
            "7",
            "--fit-steps",
            "9",
            "--background",
            "white",
            "--max-width",
            "3",
        ];
        let own_fields = [
            ("picture", json!("p.png")),
            ("model", json!("m.ply")),
            ("out", json!("o")),
            ("fit_gaussians", json!(7)),
            ("fit_steps", json!(9)),
            ("background", json!([1.0, 1.0, 1.0])),
            ("max_width", json!(3)),
        ];
        gs_stylize::test_support::assert_flags_set::<PictureStylizeConfig>(
            &own_flags,
            &own_fields,
            |line| {
                let line = Line::parse_from(line);
                line.args.overrides().unwrap()
            },
        );
    }
}
