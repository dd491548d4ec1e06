//! `clipgaussian-4d`: CLIPGaussian on dynamic scenes (D-NeRF datasets), held as D-MiSo models.
//!
//! - `stylize`: fits a scene (or takes a fitted model, ours or the authors') and stylizes it with
//!   a text or picture style. Ctrl-C stops after the current step and writes a checkpoint.
//! - `fit`: fits a scene and writes its model.
//! - `render`: renders a model at a dataset's views and times, or through time from one camera.
//! - `interpolate`: blends two models of the same cores (Gaussians and network weights).
//! - `eval`: the paper's CLIP metrics of rendered test views, in time order.

use gs_core::wide_pictures::AUTHORS_MAX_WIDTH;
use std::error::Error;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use base_dmiso::evaluation::evaluate_test_views;
use base_dmiso::fit::{self, mean_psnr, render_views, DynamicSceneFitSettings};
use base_dmiso::model_file;
use base_dmiso::stylize::{
    background_of, load_scene, read_model, run, sweep_views, DynamicSceneStylizeConfig, MODEL_FILE,
    SWEEP_DIR, SWEEP_MP4,
};
use base_dmiso::{interpolate, Dmiso};
use candle_core::Device;
use clap::{Args, Subcommand};
use gs_core::dataset::nerf_synthetic::{default_render_split, load_with_times};
use gs_core::dataset::{Background, LoadOptions};
use gs_core::GaussianSet;
use gs_stylize::animation::{write_frames, write_mp4, write_preview_gif, FRAMES_DIR, PREVIEW_GIF};
use gs_stylize::background::parse_background;
use gs_stylize::binary::ModalityBinary;
use gs_stylize::cli::{EvalStyleArgs, SplitArg, StyleArgs};
use gs_stylize::drive::{run_fit, FitCommand, FitWritten};
use gs_stylize::evaluation::write_metrics;
use gs_stylize::export::{gaussians_at, ExportArgs};
use gs_stylize::model_kind::{check_model, Binary};
use gs_stylize::model_views::ModelViewFlags;
use gs_stylize::outputs::{create_folder, into_new_folder, write_pair, PREVIEW_PNG};
use gs_stylize::selftest::ExtraCheck;
use gs_stylize::summary::write_summary;
use gs_stylize::viewer::{Animation, Shown};
use gs_stylize::writable::{check_output_file, check_output_folder};
use gs_stylize::{open_device, resolve_config, Override};
use gs_wgpu::backend::DeviceChoice;
use serde::Serialize;
use style_loss::compute_device;

/// Stylize a dynamic scene with a text or picture style.
///
/// Fits the D-NeRF scene first unless --model gives a fitted one (our model.safetensors, or
/// the folder D-MiSo's train.py wrote), then stylizes it with the paper's 4D settings
/// (configs/4d.json; configs/4d-keep-background.json keeps the background): batches of 4
/// consecutive views, the sub-Gaussians, triangles, deformation network and time-rotation
/// layer trained together. Writes to --out: model.safetensors, base.safetensors (the fit,
/// when this run fitted), frames/ (the test views at their times), preview.png (the first
/// sweep frame, original | stylized), sweep/ with preview.gif
/// (original | stylized through time) and sweep.mp4 (when ffmpeg is installed), viewer.html
/// (the scene in a browser at 24 times: a time slider and a style slider from the fit to the
/// stylized model), losses.json, losses.png, config.json and checkpoint/. The configuration comes from --config (the
/// paper's defaults when absent), then the flags, then every --set field=value in order.
/// Ctrl-C stops after the current step and writes a checkpoint; run the same command with
/// --resume to continue.
#[derive(Args, Debug, Serialize)]
struct StylizeArgs {
    /// JSON configuration (configs/4d.json is the paper's).
    #[arg(long)]
    #[serde(skip)]
    config: Option<PathBuf>,
    /// The D-NeRF scene folder (transforms_train.json and transforms_test.json with a time per
    /// frame, RGBA pictures). Without it a --model is stylized alone: the views come from
    /// --cameras, else from the cameras.json in the model's folder (or beside its file), else
    /// from an orbit made from the model, at times evenly from 0 to 1 (or --times), and each
    /// view's ground truth is the model's own render.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    data: Option<PathBuf>,
    /// A fitted model: a .safetensors file from `fit`/`stylize`, or the folder D-MiSo's train.py
    /// wrote (-m); default: fit first.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    model: Option<PathBuf>,
    /// Without --data: the cameras, or the orbit made from the model (up is +z, D-NeRF's).
    #[command(flatten)]
    #[serde(flatten)]
    views: ModelViewFlags,
    /// Without --data: the views' times, this many evenly spaced from 0 to 1, view i at the
    /// (i mod N)-th (at least 1, at most the number of views); default: view i of n at time
    /// i / (n - 1).
    #[arg(long, conflicts_with = "data")]
    #[serde(skip_serializing_if = "Option::is_none")]
    times: Option<usize>,
    /// The iteration of an authors' model folder to read (best, or a number); default: best,
    /// else the highest.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    iteration: Option<String>,
    /// The output folder (created when absent).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    out: Option<PathBuf>,
    /// Consecutive views per step, their losses summed and divided by it (the paper: 4).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    batch_size: Option<usize>,
    /// The colour the pictures are composited over and the scene renders over: white, black or
    /// R,G,B in [0, 1] (default: the background the model records, else white).
    #[arg(long, value_parser = parse_background)]
    #[serde(skip_serializing_if = "Option::is_none")]
    background: Option<[f32; 3]>,
    /// A picture wider than this is shrunk to it, pixels (Pillow's bicubic, as D-MiSo's loader
    /// at its default -r -1; default 1600); 0 keeps every picture at its size.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    max_width: Option<u32>,
    /// Random starting Gaussians (cores) of the fit, as the other binaries' `--gaussians`
    /// (`--points` is the same flag).
    #[arg(long = "gaussians", visible_alias = "points")]
    #[serde(rename = "fit_gaussians", skip_serializing_if = "Option::is_none")]
    points: Option<usize>,
    /// Steps of the fit.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    fit_steps: Option<u64>,
    /// The style, model files, device and run controls; `--resume` also reuses
    /// `<out>/base.safetensors`.
    #[command(flatten)]
    #[serde(skip)]
    style: StyleArgs,
}

/// The 4D binary's own subcommands.
#[derive(Subcommand, Debug)]
enum DynamicSceneCommand {
    /// Fit a D-NeRF scene with D-MiSo (no stylization).
    ///
    /// Writes to --out: model.safetensors, frames/ (the test views at their times; the
    /// training views, when the scene has no test split), preview.png (the first of them:
    /// picture | fit), preview.gif (all of them, picture | fit) and fit.json (steps, time and
    /// the training views' mean PSNR), and prints the mean PSNR of the views it wrote.
    Fit(FitArgs),
}

/// Arguments of `fit`.
#[derive(Args, Debug)]
struct FitArgs {
    /// The D-NeRF scene folder.
    #[arg(long)]
    data: PathBuf,
    /// The output folder (created after the fit; files of the same names are replaced).
    #[arg(long)]
    out: PathBuf,
    /// Random starting Gaussians (cores), as the other binaries' `--gaussians` (`--points` is
    /// the same flag).
    #[arg(long = "gaussians", visible_alias = "points", default_value_t = DynamicSceneFitSettings::default().points)]
    points: usize,
    /// Optimizer steps of the whole fit.
    #[arg(long, default_value_t = DynamicSceneFitSettings::default().steps)]
    steps: u64,
    /// Steps of the static warm-up.
    #[arg(long, default_value_t = DynamicSceneFitSettings::default().warm_up)]
    warm_up: u64,
    /// The step at which the sub-Gaussians are created.
    #[arg(long, default_value_t = DynamicSceneFitSettings::default().subs_from)]
    subs_from: u64,
    /// Cores kept with sub-Gaussians.
    #[arg(long, default_value_t = DynamicSceneFitSettings::default().sub_cores)]
    sub_cores: usize,
    /// Sub-Gaussians per core.
    #[arg(long, default_value_t = DynamicSceneFitSettings::default().subs_per_core)]
    subs_per_core: usize,
    /// Consecutive views per step, as `stylize --batch-size` (`--batch` is the same flag).
    #[arg(long = "batch-size", visible_alias = "batch", default_value_t = DynamicSceneFitSettings::default().batch)]
    batch: usize,
    /// Width of the deformation network.
    #[arg(long, default_value_t = DynamicSceneFitSettings::default().deform_width)]
    deform_width: usize,
    /// Seed of the starting model, the cores drawn and the view order.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// The colour the pictures are composited over: white (D-MiSo's -w), black or R,G,B in
    /// [0, 1].
    #[arg(long, value_parser = parse_background, default_value = "white")]
    background: [f32; 3],
    /// A picture wider than this is shrunk to it, pixels (Pillow's bicubic, as D-MiSo's loader
    /// at its default -r -1); 0 keeps every picture at its size.
    #[arg(long, default_value_t = AUTHORS_MAX_WIDTH)]
    max_width: u32,
    /// Where to fit: cpu, gpu, or auto (a real GPU when there is one, else the cpu).
    #[arg(long, default_value_t = DeviceChoice::Auto)]
    device: DeviceChoice,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

/// Render a model at the views and times of a dataset split, and optionally through time
/// from the split's first camera (sweep/ and, with ffmpeg, sweep.mp4).
#[derive(Args, Debug)]
struct RenderArgs {
    /// The model: a .safetensors file, or the folder D-MiSo's train.py wrote.
    #[arg(long)]
    model: PathBuf,
    /// The iteration of an authors' model folder (best, or a number).
    #[arg(long)]
    iteration: Option<String>,
    /// The D-NeRF scene whose cameras and times to render.
    #[arg(long)]
    data: PathBuf,
    /// The split (default: test where the scene has one, else train).
    #[arg(long, value_enum)]
    split: Option<SplitArg>,
    /// Frames of a sweep through time from the split's first camera (0: none).
    #[arg(long, default_value_t = 0)]
    sweep: usize,
    /// Frame rate of the sweep's mp4.
    #[arg(long, default_value_t = 24.0)]
    fps: f64,
    /// Render over white, black or R,G,B in [0, 1] (default: the background the model
    /// records, else white).
    #[arg(long, value_parser = parse_background)]
    background: Option<[f32; 3]>,
    /// A picture wider than this is shrunk to it, pixels (Pillow's bicubic, as D-MiSo's loader
    /// at its default -r -1); 0 keeps every picture at its size.
    #[arg(long, default_value_t = AUTHORS_MAX_WIDTH)]
    max_width: u32,
    /// Where to render: cpu, gpu, or auto.
    #[arg(long, default_value_t = DeviceChoice::Auto)]
    device: DeviceChoice,
    /// The output folder (frames/ and, with --sweep, sweep/ and sweep.mp4 in it).
    #[arg(long)]
    out: PathBuf,
}

/// Write the Gaussians at a time (or at many) in a splat format viewers open.
///
/// The Gaussians the model renders at --time (in [0, 1]), written to --out in the format
/// its name ends in (or --format); with --times N, the Gaussians at N evenly spaced times
/// from 0 to 1, one file each, into the folder --out (00000.ply, ...; --format picks the
/// format, default ply). A viewer page (--format html, or an .html name) holds the Gaussians at
/// every one of those times (a time slider), and with --b those of its stylization.
#[derive(Args, Debug)]
struct DynamicSceneExportArgs {
    #[command(flatten)]
    export: ExportArgs,
    /// The time to export, in [0, 1].
    #[arg(long, default_value_t = 0.0, conflicts_with = "times")]
    time: f64,
    /// Export the Gaussians at this many evenly spaced times from 0 to 1 (at least 2), one file
    /// each, into the folder --out.
    #[arg(long)]
    times: Option<usize>,
}

/// Score rendered test views against the dataset's test pictures: CLIP-S, CLIP-SIM,
/// CLIP-CONS and CLIP-F over the views in time order (CLIP ViT-L/14, x100).
#[derive(Args, Debug)]
struct EvalArgs {
    /// The rendered test views (e.g. `<stylize out>/frames`): 00000.png ... in the order of
    /// transforms_test.json.
    #[arg(long)]
    renders: PathBuf,
    /// The reference: the D-NeRF scene, whose test split the renders are scored against
    /// (`--data` is the same flag).
    #[arg(long = "gt", visible_alias = "data", value_name = "SCENE")]
    data: PathBuf,
    /// The style and the CLIP model.
    #[command(flatten)]
    style: EvalStyleArgs,
    /// The colour the test pictures are composited over (that of the renders): white, black
    /// or R,G,B in [0, 1].
    #[arg(long, value_parser = parse_background, default_value = "white")]
    background: [f32; 3],
    /// A picture wider than this is shrunk to it, pixels (Pillow's bicubic, as D-MiSo's loader
    /// at its default -r -1); 0 keeps every picture at its size.
    #[arg(long, default_value_t = AUTHORS_MAX_WIDTH)]
    max_width: u32,
    /// Where to write the scores as JSON, printed too (metrics.json by default, as every
    /// binary's eval; its folder must exist; checked before any work).
    #[arg(long, default_value = "metrics.json")]
    out: PathBuf,
}

/// `test`, `train` or `val`.
/// The candle device of the deformation network for `choice` (the style loss's).
fn net_device(choice: DeviceChoice) -> Result<Device, Box<dyn Error>> {
    Ok(compute_device::open_for(choice)?.0)
}

/// Runs `stylize`.
fn stylize(args: &StylizeArgs) -> Result<(), Box<dyn Error>> {
    let started = std::time::Instant::now();
    if let Some(model) = &args.model {
        check_model(Binary::DynamicScene, "--model", model)?;
    }
    let overrides: Vec<Override> = args.style.overrides(args)?;
    let config: DynamicSceneStylizeConfig = resolve_config(args.config.as_deref(), &overrides)?;
    let summary = run(&config, &args.style.run_options()?)?;
    let out = config.out.as_deref().expect("run checked out");
    println!(
        "wrote {} ({} cores of {} sub-Gaussians), {} test views to {}, {} sweep frames to {}{}",
        out.join(MODEL_FILE).display(),
        summary.model.cores(),
        summary.model.subs_per_core(),
        summary.test_renders.len(),
        out.join(FRAMES_DIR).display(),
        summary.sweep.len(),
        out.join(SWEEP_DIR).display(),
        if summary.wrote_mp4 {
            format!(" and {}", out.join(SWEEP_MP4).display())
        } else {
            " (no mp4: ffmpeg is not installed)".into()
        },
    );
    print!(
        "{}",
        write_summary("clipgaussian-4d stylize", started, out)?
    );
    Ok(())
}

/// Frame rate of the fit's `preview.gif` (its views, one after another).
const FIT_PREVIEW_FPS: f64 = 12.0;

/// Runs `fit`.
fn fit(args: &FitArgs) -> Result<(), Box<dyn Error>> {
    let bg = Background::from_rgb(args.background);
    let settings = DynamicSceneFitSettings {
        points: args.points,
        steps: args.steps,
        warm_up: args.warm_up,
        subs_from: args.subs_from,
        sub_cores: args.sub_cores,
        subs_per_core: args.subs_per_core,
        batch: args.batch,
        deform_width: args.deform_width,
        seed: args.seed,
        background: bg.rgb(),
        ..DynamicSceneFitSettings::default()
    };
    settings.check()?;
    let device = net_device(args.device)?;
    let command = FitCommand {
        out: &args.out,
        device: args.device,
        progress: !args.quiet,
        what: "the scene",
        steps: settings.steps,
        stages: settings.stages().to_vec(),
    };
    run_fit(
        &command,
        |progress| {
            Ok(load_scene(
                &args.data,
                bg,
                args.max_width,
                Some(progress.clone()),
            )?)
        },
        |(train, _), backend, on_step| {
            Ok(fit::fit(
                &train.views,
                &train.images,
                train.extent,
                &settings,
                backend,
                &device,
                on_step,
            )?)
        },
        |(train, test), mut model, backend, seconds| {
            model_file::save(&model, &args.out.join(MODEL_FILE), Some(bg))?;
            let (views, images, which) = match test {
                Some(test) => (&test.views, &test.images, "test"),
                None => (&train.views, &train.images, "training"),
            };
            let renders = render_views(&mut model, views, bg.rgb(), backend)?;
            write_frames(&args.out.join(FRAMES_DIR), &renders)?;
            write_pair(&args.out.join(PREVIEW_PNG), &images[0], &renders[0])?;
            write_preview_gif(
                &args.out.join(PREVIEW_GIF),
                images,
                &renders,
                FIT_PREVIEW_FPS,
            )?;
            let shown_psnr = mean_psnr(&renders, images);
            // fit.json holds the training views' PSNR, as a stylize that fits writes it.
            let psnr_db = match test {
                Some(_) => {
                    let train_renders = render_views(&mut model, &train.views, bg.rgb(), backend)?;
                    mean_psnr(&train_renders, &train.images)
                }
                None => shown_psnr,
            };
            let line = format!(
                "fitted {} ({} training views) in {seconds:.1} s: {} cores of {} sub-Gaussians, \
                 mean PSNR {shown_psnr:.2} dB over the {which} views; wrote {}",
                args.data.display(),
                train.views.len(),
                model.cores(),
                model.subs_per_core(),
                args.out.display()
            );
            Ok(FitWritten {
                line,
                psnr_db,
                gaussians: model.cores() * model.subs_per_core(),
                test_psnr_db: None,
                seconds,
            })
        },
    )
}

/// Runs `render`.
fn render(args: &RenderArgs) -> Result<(), Box<dyn Error>> {
    check_model(Binary::DynamicScene, "--model", &args.model)?;
    check_output_folder(&args.out)?;
    if !(args.fps.is_finite() && args.fps > 0.0) {
        return Err(format!("--fps {} must be positive", args.fps).into());
    }
    let bg = background_of(
        args.background,
        model_file::recorded_background(&args.model)?,
    );
    let options = LoadOptions {
        background: bg,
        downscale: 1,
        max_width: args.max_width,
        ..LoadOptions::default()
    };
    let split = match args.split {
        Some(split) => split.into(),
        None => default_render_split(&args.data)?,
    };
    let split = load_with_times(&args.data, split, &options)?;
    let backend = open_device(args.device)?;
    let mut model = read_model(
        &args.model,
        args.iteration.as_deref(),
        &net_device(args.device)?,
    )?;
    let renders = render_views(&mut model, &split.views, bg.rgb(), &backend)?;
    create_folder(&args.out)?;
    write_frames(&args.out.join(FRAMES_DIR), &renders)?;
    let mut line = format!(
        "wrote {} views to {} (mean PSNR {:.2} dB against the pictures)",
        renders.len(),
        args.out.join(FRAMES_DIR).display(),
        mean_psnr(&renders, &split.images)
    );
    if args.sweep > 0 {
        let views = sweep_views(&split.views[0].camera, args.sweep);
        let sweep = render_views(&mut model, &views, bg.rgb(), &backend)?;
        let dir = args.out.join(SWEEP_DIR);
        write_frames(&dir, &sweep)?;
        let mp4 = write_mp4(&dir, args.fps, &args.out.join(SWEEP_MP4))?;
        line += &format!(
            ", {} sweep frames to {}{}",
            sweep.len(),
            dir.display(),
            if mp4 {
                " and sweep.mp4"
            } else {
                " (no mp4: ffmpeg is not installed)"
            }
        );
    }
    println!("{line}");
    Ok(())
}

/// Runs `export`.
fn export(args: &DynamicSceneExportArgs) -> Result<(), Box<dyn Error>> {
    let export = &args.export;
    export.check(
        Binary::DynamicScene,
        args.times.is_some() && !export.is_html(),
    )?;
    let times: Vec<f64> = match args.times {
        Some(n) if n >= 2 => (0..n).map(|i| i as f64 / (n - 1) as f64).collect(),
        Some(n) => return Err(format!("--times {n}: give at least 2 (or --time for one)").into()),
        None if (0.0..=1.0).contains(&args.time) => vec![args.time],
        None => return Err(format!("--time {}: times lie in [0, 1]", args.time).into()),
    };
    let (model, recorded) = DynamicScene::read_model(&export.model)?;
    if !export.is_html() {
        println!("{}", export.write_at(&model, &times, args.times.is_some())?);
        return Ok(());
    }
    // The page: the Gaussians at each time (a frame of its time slider), seen from the
    // cameras.json of the model's folder or 16 views of an orbit made from them (up is +z).
    let snapshots = |m: &Dmiso| -> Result<Vec<GaussianSet>, String> {
        times.iter().map(|&t| gaussians_at(m, t)).collect()
    };
    let base = snapshots(&model)?;
    let stylized = match &export.b {
        Some(b) => Some(snapshots(&DynamicScene::read_model(b)?.0)?),
        None => None,
    };
    let cameras = export.page_cameras(&base[0], [0.0, 0.0, 1.0])?;
    let shown = Shown::Animated(
        Animation::snapshots(&base, stylized.as_deref())
            .map_err(|e| format!("--model {}: {e}", export.model.display()))?,
    );
    let background = background_of(None, recorded).rgb();
    println!("{}", export.write_page(shown, cameras, background)?);
    Ok(())
}

/// Runs `eval`.
fn eval(args: &EvalArgs) -> Result<(), Box<dyn Error>> {
    check_output_file(&args.out)?;
    let metrics = evaluate_test_views(
        &args.renders,
        &args.data,
        Background::from_rgb(args.background),
        args.max_width,
        &args.style.scoring(),
    )
    .map_err(|e| e as Box<dyn Error>)?;
    print!("{}", metrics.lines());
    write_metrics(&args.out, &metrics)?;
    println!("wrote {}", args.out.display());
    Ok(())
}

/// The 4D binary's part of the skeleton every binary shares.
struct DynamicScene;

impl ModalityBinary for DynamicScene {
    const BINARY: Binary = Binary::DynamicScene;
    const ABOUT: &'static str =
        "CLIPGaussian on dynamic scenes (D-MiSo): stylize, fit, render, interpolate, eval";
    const INTERPOLATE_HELP: &'static str =
        "Interpolate two models of the same cores parameter by parameter: `(1 - t) A + t B` \
         of every Gaussian parameter and every network weight, e.g. between two stylizations \
         of one fit.";
    const SELFTEST_HELP: Option<&'static str> = Some(
        "Check the device: every part of a stylization on small seeded inputs against the \
         cpu.\n\nRuns the render and its backward, Adam, each loss term and the loss \
         gradient, and the deformation network forward and backward on the chosen device and \
         compares each with the cpu f32 result (on the cpu, the loss with its generic \
         composition, the one a GPU runs); prints a table (part, device, max error, \
         tolerance, time) and exits with an error when a part differs.",
    );

    type Stylize = StylizeArgs;
    type Own = DynamicSceneCommand;
    type Render = RenderArgs;
    type Export = DynamicSceneExportArgs;
    type Eval = EvalArgs;
    type Model = (Dmiso, Option<Background>);

    /// The model (on the cpu, a folder's last iteration) and the background it records.
    fn read_model(path: &Path) -> Result<Self::Model, Box<dyn Error>> {
        let model = read_model(path, None, &Device::Cpu)?;
        Ok((model, model_file::recorded_background(path)?))
    }

    /// As our `model.safetensors`.
    fn write_model(path: &Path, (model, background): &Self::Model) -> Result<(), Box<dyn Error>> {
        Ok(model_file::save(model, path, *background)?)
    }

    fn blend(
        (a, background): &Self::Model,
        (b, _): &Self::Model,
        t: f32,
    ) -> Result<Self::Model, String> {
        Ok((interpolate(a, b, t)?, *background))
    }

    fn gaussian_count((model, _): &Self::Model) -> usize {
        model.len()
    }

    fn stylize(args: &StylizeArgs) -> Result<(), Box<dyn Error>> {
        stylize(args)
    }

    fn own(command: &DynamicSceneCommand) -> Result<(), Box<dyn Error>> {
        match command {
            DynamicSceneCommand::Fit(args) => fit(args),
        }
    }

    fn render(args: &RenderArgs) -> Result<(), Box<dyn Error>> {
        into_new_folder(&args.out, || render(args))
    }

    fn export(args: &DynamicSceneExportArgs) -> Result<(), Box<dyn Error>> {
        export(args)
    }

    fn eval(args: &EvalArgs) -> Result<(), Box<dyn Error>> {
        eval(args)
    }

    /// The deformation network's forward and backward.
    fn self_checks() -> Vec<ExtraCheck> {
        vec![Box::new(base_dmiso::deform_net::self_check)]
    }
}

fn main() -> ExitCode {
    gs_stylize::binary::main::<DynamicScene>()
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
            "--data",
            "d",
            "--model",
            "m",
            "--iteration",
            "best",
            "--out",
            "o",
            "--batch-size",
            "2",
            "--background",
            "white",
            "--max-width",
            "3",
            "--gaussians",
            "7",
            "--fit-steps",
            "9",
        ];
        let own_fields = [
            ("data", json!("d")),
            ("model", json!("m")),
            ("iteration", json!("best")),
            ("out", json!("o")),
            ("batch_size", json!(2)),
            ("background", json!([1.0, 1.0, 1.0])),
            ("max_width", json!(3)),
            ("fit_gaussians", json!(7)),
            ("fit_steps", json!(9)),
        ];
        gs_stylize::test_support::assert_flags_set::<DynamicSceneStylizeConfig>(
            &own_flags,
            &own_fields,
            |line| {
                let line = Line::parse_from(line);
                line.args.style.overrides(&line.args).unwrap()
            },
        );
        // The view flags of a run without data (--cameras and --orbit exclude each other).
        for (flag, value, field, set) in [
            ("--cameras", "c.json", "cameras", json!("c.json")),
            ("--orbit", "object", "orbit", json!("object")),
        ] {
            gs_stylize::test_support::assert_flags_set::<DynamicSceneStylizeConfig>(
                &[
                    "--model",
                    "m",
                    "--out",
                    "o",
                    flag,
                    value,
                    "--orbit-views",
                    "5",
                    "--width",
                    "6",
                    "--height",
                    "7",
                ],
                &[
                    ("model", json!("m")),
                    ("out", json!("o")),
                    (field, set),
                    ("orbit_views", json!(5)),
                    ("width", json!(6)),
                    ("height", json!(7)),
                ],
                |line| {
                    let line = Line::parse_from(line);
                    line.args.style.overrides(&line.args).unwrap()
                },
            );
        }
    }
}
