//! `clipgaussian-3d`: CLIPGaussian on 3DGS scenes (INRIA PLY files).
//!
//! - `stylize`: stylizes a trained scene with its dataset; Ctrl-C stops after the current step
//!   and writes a checkpoint to resume from.
//! - `render`: renders a PLY from a dataset's cameras or from one camera file.
//! - `interpolate`: blends two PLY files of the same Gaussians.
//! - `eval`: the paper's CLIP metrics of a folder of renders against its ground truths.

use gs_core::wide_pictures::AUTHORS_MAX_WIDTH;
use std::error::Error;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use base_3dgs::dataset::nerf_synthetic::Split;
use base_3dgs::dataset::{inria_cameras, GroundTruth, ImageProgress};
use base_3dgs::dataset::{Background, LoadOptions};
use base_3dgs::evaluation::{evaluate_folders, write_metrics};
use base_3dgs::fit::{
    self as scene_fit, has_checkpoint, initial_gaussians, load_checkpoint, load_fit_data,
    psnr_chart, render_views, save_checkpoint, FitData, SceneFit, SceneFitSettings,
};
use base_3dgs::render_views::{camera_from_file, dataset_cameras, render_to_folder};
use base_3dgs::stylize::{run, Override, SceneStylizeConfig, StylizeError};
use clap::{Args, Subcommand};
use gs_core::camera::Camera;
use gs_core::densify::DensifySettings;
use gs_core::image_loss::mean_psnr;
use gs_core::ply::{write_ply, PlyFormat, PlyGaussians};
use gs_core::splats::{read_splats_with_format, write_splats, SplatFormat};
use gs_stylize::animation::write_frames;
use gs_stylize::animation::FRAMES_DIR;
use gs_stylize::background::parse_background;
use gs_stylize::binary::{ModalityBinary, PlyModel};
use gs_stylize::checkpoint::checkpoint_dir;
use gs_stylize::cli::{EvalStyleArgs, SplitArg, StyleArgs};
use gs_stylize::drive::{run_fit, FitCommand, FitWritten};
use gs_stylize::export::ExportArgs;
use gs_stylize::model_kind::{check_model, Binary};
use gs_stylize::model_views::ModelViewFlags;
use gs_stylize::open_device;
use gs_stylize::outputs::into_new_folder;
use gs_stylize::outputs::{write_pair, FIT_PSNR_PNG, PREVIEW_PNG};
use gs_stylize::summary::write_summary;
use gs_stylize::viewer::Shown;
use gs_stylize::writable::{check_output_file, check_output_folder};
use gs_wgpu::backend::Backend;
use gs_wgpu::backend::DeviceChoice;
use serde::Serialize;

/// Stylize a trained 3DGS scene (a splat file, with or without its dataset) with a text or
/// picture style.
///
/// Without --data the run trains on views of the model itself (see --data) and says where
/// its cameras came from. Without --model it fits the dataset first, as `fit` does
/// (--fit-steps, --gaussians), and keeps the fit as base.ply and fit.json.
///
/// Writes to `--out`: model.ply (the stylized scene, in the input's PLY format with its
/// extra properties; also model.spz, model.splat, model.compressed.ply or model.glb when the
/// input was one), preview.png (before | after of the first `preview_views` entry; the
/// others preview_viewNNN.png), viewer.html (the scene in a browser, with a slider from the
/// base model to the stylized one; up to 1,000,000 Gaussians), losses.json, losses.png,
/// config.json (the resolved configuration) and checkpoint/. The configuration comes from `--config` (the paper's
/// defaults when absent), then the flags, then every `--set field=value` in order. The
/// output folder is checked before the scene is loaded. Ctrl-C stops after the current
/// step and writes a checkpoint (a second Ctrl-C quits at once); run the same command with `--resume` to continue. A finished run's
/// checkpoint does not hold the folder: the same command runs again, and `--resume`
/// continues only with more `--steps`.
#[derive(Args, Debug, Serialize)]
struct StylizeArgs {
    /// JSON configuration (configs/3d.json, configs/3d-light.json).
    #[arg(long)]
    #[serde(skip)]
    config: Option<PathBuf>,
    /// The trained scene: INRIA PLY, or SuperSplat compressed PLY, SPZ, .splat, glTF .glb or
    /// SOG (`--ply` is the same flag); default: fit --data first.
    #[arg(long = "model", visible_alias = "ply", value_name = "PLY")]
    #[serde(rename = "model", skip_serializing_if = "Option::is_none")]
    ply: Option<PathBuf>,
    /// The dataset folder: NeRF-synthetic, nerfstudio / instant-ngp (transforms.json) or
    /// COLMAP (sparse/, or dense/ from image_undistorter); distorted cameras are undistorted.
    /// Without it the model alone is stylized: the views come from --cameras, else from the
    /// INRIA cameras.json beside the model, else from an orbit made from the model, and each
    /// view's ground truth is the model's own render.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    data: Option<PathBuf>,
    /// Without --data: the cameras, or the orbit made from the model.
    #[command(flatten)]
    #[serde(flatten)]
    views: ModelViewFlags,
    /// The output folder (created when absent).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    out: Option<PathBuf>,
    /// Resolution divisor of the dataset images (3DGS's -r; default 1, the images as they
    /// are up to --max-width, or the configuration's `resolution`); `images_<r>/` is read when the
    /// dataset has it.
    #[arg(short = 'r', long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    resolution: Option<u32>,
    /// With resolution 1, a picture wider than this is shrunk to it, pixels (Pillow's bicubic,
    /// as INRIA's loader at its default -r -1; default 1600); 0 keeps every picture at its size.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    max_width: Option<u32>,
    /// The colour renders are composited over: white, black or R,G,B in [0, 1] (default
    /// black, as the authors' commands, or the configuration's `background`).
    #[arg(long, value_parser = parse_background)]
    #[serde(skip_serializing_if = "Option::is_none")]
    background: Option<[f32; 3]>,
    /// Without --model: random starting Gaussians of the fit that runs first, when the
    /// dataset has no points (NeRF-synthetic), as the other binaries' `--gaussians` (default
    /// 100,000, INRIA's).
    #[arg(long = "gaussians")]
    #[serde(rename = "fit_gaussians", skip_serializing_if = "Option::is_none")]
    gaussians: Option<usize>,
    /// Without --model: steps of that fit (default 30,000, INRIA's; see `fit`).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    fit_steps: Option<u64>,
    /// The style, model files, device and run controls; `--resume` also reuses
    /// `<out>/base.ply`, the fit a run without --model made.
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

/// Render a PLY from the cameras of a dataset or from one camera file.
///
/// Writes into `--out`'s `frames/` (the folder of rendered views in every binary) one PNG
/// per dataset view, named after the dataset's image, or `render.png` for a camera file.
/// Inputs are checked before the output folder is created.
#[derive(Args, Debug)]
struct RenderArgs {
    /// The scene: INRIA PLY, or SuperSplat compressed PLY, SPZ, .splat, glTF .glb or SOG
    /// (`--ply` is the same flag).
    #[arg(long = "model", visible_alias = "ply", value_name = "PLY")]
    ply: PathBuf,
    /// A dataset folder (NeRF-synthetic or COLMAP) whose cameras to render from; each picture
    /// is named after its dataset image, with the extension .png. Its pictures are not
    /// decoded (only a header where the cameras need a size) and need not all be there.
    #[arg(long, required_unless_present = "camera", conflicts_with = "camera")]
    data: Option<PathBuf>,
    /// The split: NeRF-synthetic's `transforms_<split>.json`, or the split lists of a
    /// transforms.json (default: test where the scene has one, else train); COLMAP scenes have
    /// none.
    #[arg(long, value_enum, requires = "data")]
    split: Option<SplitArg>,
    /// Resolution divisor of the dataset's cameras (3DGS's -r); `images_<r>/` is read when the
    /// dataset has it.
    #[arg(short = 'r', long, default_value_t = 1, requires = "data")]
    resolution: u32,
    /// With resolution 1, a dataset camera wider than this is shrunk to it, pixels (as INRIA's
    /// loader at its default -r -1); 0 keeps every camera at its size.
    #[arg(long, default_value_t = AUTHORS_MAX_WIDTH, requires = "data")]
    max_width: u32,
    /// One camera as JSON, written to render.png. OpenCV axes (x right, y down, z forward),
    /// intrinsics in pixels, `world_to_camera` a rigid 4x4 transform, row-major:
    /// `{"width": 800, "height": 800, "fx": 1111.1, "fy": 1111.1, "cx": 400, "cy": 400,
    /// "world_to_camera": [[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]}`
    #[arg(long)]
    camera: Option<PathBuf>,
    /// The output folder (created when absent; pictures of the same names are replaced;
    /// checked before any work).
    #[arg(long)]
    out: PathBuf,
    /// The background colour: white, black or R,G,B in [0, 1] (black by default, as `stylize`
    /// renders unless its `background` is set).
    #[arg(long, value_parser = parse_background, default_value = "black")]
    background: [f32; 3],
    /// Where to render: cpu, gpu, or auto (a real GPU when there is one, else the cpu).
    #[arg(long, default_value_t = DeviceChoice::Auto)]
    device: DeviceChoice,
}

/// The paper's CLIP metrics (CLIP-S, CLIP-SIM, CLIP-CONS, CLIP-F) of renders.
///
/// Scores (x100) a folder of renders against a folder of ground truths and writes them as
/// JSON. Pictures (.png, .jpg, .jpeg) are paired by file name and taken in
/// file-name order: CLIP-CONS and CLIP-F compare consecutive pictures in that order.
#[derive(Args, Debug)]
struct EvalArgs {
    /// The folder of rendered pictures.
    #[arg(long)]
    renders: PathBuf,
    /// The folder of ground-truth pictures, with the same file names as the renders.
    #[arg(long)]
    gt: PathBuf,
    /// The style and the CLIP model.
    #[command(flatten)]
    style: EvalStyleArgs,
    /// The colour behind transparent pixels of the pictures: white, black or R,G,B in [0, 1]
    /// (black by default, the background `stylize` renders over unless its `background` is
    /// set).
    #[arg(long, value_parser = parse_background, default_value = "black")]
    background: [f32; 3],
    /// Where to write the scores as JSON (its folder must exist; checked before any work).
    #[arg(long, default_value = "metrics.json")]
    out: PathBuf,
}

/// Runs `stylize`, stopping after the current step on the first Ctrl-C.
fn stylize(args: &StylizeArgs) -> Result<(), Box<dyn Error>> {
    if let Some(model) = &args.ply {
        check_model(Binary::Scene, "--model", model)?;
    }
    let started = std::time::Instant::now();
    let overrides = args.overrides()?;
    let config = SceneStylizeConfig::resolve(args.config.as_deref(), &overrides)?;
    let summary = run(&config, &args.style.run_options()?)?;
    let last = summary.losses.last().map_or(f32::NAN, |l| l.total);
    println!(
        "wrote {} ({} Gaussians, final loss {last:.4})",
        summary.stylized_ply.display(),
        summary.gaussians.len()
    );
    print!(
        "{}",
        write_summary(
            "clipgaussian-3d stylize",
            started,
            config.out.as_deref().expect("run checked out")
        )?
    );
    Ok(())
}

/// Runs `render`.
fn render(args: &RenderArgs) -> Result<(), Box<dyn Error>> {
    check_model(Binary::Scene, "--model", &args.ply)?;
    check_output_folder(&args.out)?;
    let ply = Scene::read_model(&args.ply)?.ply;
    let cameras = match (&args.data, &args.camera) {
        (Some(data), _) => {
            let split = args.split.map(Split::from);
            let options = LoadOptions {
                background: Background::from_rgb(args.background),
                downscale: args.resolution,
                max_width: args.max_width,
                ..LoadOptions::default()
            };
            dataset_cameras(data, split, &options)?
        }
        (None, Some(camera)) => vec![camera_from_file(camera)?],
        (None, None) => return Err("one of --data and --camera is required".into()),
    };
    let backend = open_device(args.device)?;
    let frames = args.out.join(FRAMES_DIR);
    let written = render_to_folder(&ply.gaussians, &cameras, args.background, &frames, &backend)?;
    println!("wrote {} picture(s) to {}", written.len(), frames.display());
    Ok(())
}

/// Runs `eval`.
fn eval(args: &EvalArgs) -> Result<(), Box<dyn Error>> {
    check_output_file(&args.out)?;
    let metrics = evaluate_folders(
        &args.renders,
        &args.gt,
        &args.style.style(),
        &args.style.source_prompt,
        &args.style.clip_files(),
        args.background,
    )?;
    print!("{}", metrics.lines());
    write_metrics(&args.out, &metrics)?;
    println!("wrote {}", args.out.display());
    Ok(())
}

/// Runs `export`.
fn export(args: &ExportArgs) -> Result<(), Box<dyn Error>> {
    args.check(Binary::Scene, false)?;
    let scene = Scene::read_model(&args.model)?.ply;
    if !args.is_html() {
        println!("{}", args.write_file(&scene)?);
        return Ok(());
    }
    // The page's cameras: a cameras.json beside the model, else 16 of an orbit made from it
    // (3DGS's y-down frame).
    let cameras = args.page_cameras(&scene.gaussians, [0.0, -1.0, 0.0])?;
    let stylized = match &args.b {
        Some(b) => Some(Scene::read_model(b)?.ply.gaussians),
        None => None,
    };
    println!(
        "{}",
        args.write_page(
            Shown::Still {
                base: &scene.gaussians,
                stylized: stylized.as_ref(),
            },
            cameras,
            [0.0; 3],
        )?
    );
    Ok(())
}

/// The 3D binary's own subcommands.
#[derive(Subcommand, Debug)]
enum SceneCommand {
    /// Fit a 3DGS scene to a dataset's pictures, as INRIA 3DGS's train.py (no stylization).
    ///
    /// Starts from the dataset's points (COLMAP's points3D) or, without them
    /// (NeRF-synthetic), from --gaussians random points in the cube [-1.3, 1.3]^3; trains
    /// L1 + 0.2 D-SSIM with INRIA's rates, one SH degree more every 1,000 steps, and
    /// densifies (clone and split by the view-space gradient, prune) from step 500 to
    /// 15,000 every 100, the opacities reset every 3,000. Writes to --out:
    /// point_cloud/iteration_<steps>/point_cloud.ply and cameras.json (INRIA's layout, which
    /// `stylize --model` and viewers read), frames/ (the test views with --eval, else the
    /// training views), preview.png (the first of them: picture | fit), fit_psnr.png (each
    /// step's PSNR) and fit.json (steps, time, Gaussians, training and test PSNR). Ctrl-C
    /// stops after the current step and writes a checkpoint (a second Ctrl-C quits at once);
    /// the same command with --resume goes on exactly where it stopped.
    Fit(FitArgs),
}

/// Arguments of `fit`.
#[derive(Args, Debug)]
struct FitArgs {
    /// The dataset folder: NeRF-synthetic or COLMAP (sparse/, or dense/ from
    /// image_undistorter).
    #[arg(long)]
    data: PathBuf,
    /// The output folder (created after the fit; files of the same names are replaced).
    #[arg(long)]
    out: PathBuf,
    /// Optimizer steps (INRIA's --iterations).
    #[arg(long, default_value_t = SceneFitSettings::default().steps)]
    steps: u64,
    /// Random starting Gaussians when the dataset has no points (NeRF-synthetic), as the
    /// other binaries' `--gaussians`.
    #[arg(long, default_value_t = SceneFitSettings::default().random_points)]
    gaussians: usize,
    /// The most Gaussians densification may make (default: no cap, as INRIA); past it, the
    /// Gaussians of the largest gradients grow first. For a GPU or a machine of little memory.
    #[arg(long)]
    max_gaussians: Option<usize>,
    /// The highest SH degree (INRIA's --sh_degree).
    #[arg(long, default_value_t = SceneFitSettings::default().sh_degree)]
    sh_degree: usize,
    /// No densification after this step (INRIA's --densify_until_iter); 0 fits the starting
    /// Gaussians only.
    #[arg(long, default_value_t = DensifySettings::default().until)]
    densify_until: u64,
    /// Hold out the test views (INRIA's --eval): NeRF-synthetic's test split, every 8th COLMAP
    /// picture by name; they are rendered and scored, not trained on.
    #[arg(long)]
    eval: bool,
    /// Resolution divisor of the dataset images (3DGS's -r); `images_<r>/` is read when the
    /// dataset has it.
    #[arg(short = 'r', long, default_value_t = 1)]
    resolution: u32,
    /// With resolution 1, a picture wider than this is shrunk to it, pixels (INRIA's loader
    /// at its default -r -1); 0 keeps every picture at its size.
    #[arg(long, default_value_t = AUTHORS_MAX_WIDTH)]
    max_width: u32,
    /// The colour renders are drawn on and pictures composited over: white, black or R,G,B
    /// in [0, 1] (default black, as INRIA).
    #[arg(long, value_parser = parse_background, default_value = "black", conflicts_with = "white_background")]
    background: [f32; 3],
    /// The same as --background white (INRIA's -w).
    #[arg(short = 'w', long)]
    white_background: bool,
    /// How a picture with transparency becomes the ground truth: file_colour (the stored
    /// colours, alpha ignored, as the INRIA commit CLIPGaussian pins) or composited (over the
    /// background, cut to 8 bits, as INRIA before August 2024).
    #[arg(long, value_parser = parse_ground_truth, default_value = "file_colour")]
    ground_truth: GroundTruth,
    /// Seed of the random points, the view order and the split samples.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Where to fit: cpu, gpu, or auto (a real GPU when there is one, else the cpu).
    #[arg(long, default_value_t = DeviceChoice::Auto)]
    device: DeviceChoice,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
    /// Continue the fit a Ctrl-C stopped, from `<out>/checkpoint/` (the same command with
    /// --resume; a larger --steps goes further).
    #[arg(long)]
    resume: bool,
}

/// `file_colour` or `composited`, as the configurations name them.
fn parse_ground_truth(text: &str) -> Result<GroundTruth, String> {
    serde_json::from_value(serde_json::Value::String(text.into()))
        .map_err(|_| format!("{text:?}: one of file_colour, composited"))
}

/// Runs `fit`.
fn fit(args: &FitArgs) -> Result<(), Box<dyn Error>> {
    let background = if args.white_background {
        [1.0; 3]
    } else {
        args.background
    };
    let densify = (args.densify_until > 0).then(|| DensifySettings {
        until: args.densify_until,
        max_len: args.max_gaussians,
        ..DensifySettings::default()
    });
    let settings = SceneFitSettings {
        steps: args.steps,
        sh_degree: args.sh_degree,
        random_points: args.gaussians,
        densify,
        background,
        seed: args.seed,
        ..SceneFitSettings::default()
    };
    settings.check()?;
    let options = |progress: &ImageProgress| LoadOptions {
        background: Background::from_rgb(background),
        ground_truth: args.ground_truth,
        downscale: args.resolution,
        max_width: args.max_width,
        progress: Some(progress.clone()),
    };
    let checkpoint = checkpoint_dir(&args.out);
    match (args.resume, has_checkpoint(&checkpoint)) {
        (true, false) => {
            return Err(format!(
                "--resume: there is no checkpoint of a stopped fit in {}: run without --resume",
                checkpoint.display()
            )
            .into())
        }
        (false, true) => {
            return Err(format!(
                "{} holds the checkpoint of a stopped fit: pass --resume to continue it, or \
                 choose another output folder",
                args.out.display()
            )
            .into())
        }
        _ => {}
    }
    let command = FitCommand {
        out: &args.out,
        device: args.device,
        progress: !args.quiet,
        what: "the scene",
        steps: settings.steps,
        stages: Vec::new(),
    };
    run_fit(
        &command,
        |progress| Ok(load_fit_data(&args.data, &options(progress), args.eval)?),
        |data, backend, on_step| {
            let started = Instant::now();
            let start = if args.resume {
                load_checkpoint(&checkpoint)?
            } else {
                SceneFit::new(initial_gaussians(data.train.points.as_ref(), &settings))
            };
            let mut fitted = scene_fit::fit(
                &data.train.views,
                &data.train.images,
                start,
                data.train.extent,
                &settings,
                backend,
                on_step,
            )?;
            if fitted.steps < settings.steps {
                // The time of this run counts in the fit's when it goes on.
                fitted.seconds += started.elapsed().as_secs_f64();
                save_checkpoint(&checkpoint, &fitted)?;
                let step = fitted.steps;
                return Err(StylizeError::Interrupted {
                    step,
                    out: args.out.clone(),
                }
                .into());
            }
            Ok(fitted)
        },
        |data, fitted, backend, seconds| write_fit(args, data, fitted, backend, seconds),
    )
}

/// Writes a fit's outputs (see `fit`'s help) and says what it did.
fn write_fit(
    args: &FitArgs,
    data: &FitData,
    fitted: SceneFit,
    backend: &Backend,
    seconds: f64,
) -> Result<FitWritten, Box<dyn Error>> {
    let out = &args.out;
    let ply_dir = out
        .join("point_cloud")
        .join(format!("iteration_{}", fitted.steps));
    std::fs::create_dir_all(&ply_dir)?;
    let fitted_seconds = fitted.seconds;
    let gaussians = fitted.gaussians;
    write_ply(
        &ply_dir.join("point_cloud.ply"),
        &PlyGaussians::new(gaussians.clone()),
        PlyFormat::BinaryLittleEndian,
    )?;
    let train = &data.train;
    let names: Vec<(&Camera, String)> = train
        .views
        .iter()
        .zip(&train.image_paths)
        .map(|(v, p)| {
            let stem = p.file_stem().map(|s| s.to_string_lossy().into_owned());
            (&v.camera, stem.unwrap_or_default())
        })
        .collect();
    inria_cameras::write(&out.join(inria_cameras::FILE_NAME), &names)?;
    psnr_chart(&fitted.psnr).write_png(&out.join(FIT_PSNR_PNG))?;
    let train_renders = render_views(&gaussians, &train.views, train.background, backend)?;
    let psnr_db = mean_psnr(&train_renders, &train.images);
    let (shown, pictures, test_psnr_db) = match &data.test {
        Some((views, images)) => {
            let renders = render_views(&gaussians, views, train.background, backend)?;
            let psnr = mean_psnr(&renders, images);
            (renders, images.as_slice(), Some(psnr))
        }
        None => (train_renders, train.images.as_slice(), None),
    };
    write_frames(&out.join(FRAMES_DIR), &shown)?;
    write_pair(&out.join(PREVIEW_PNG), &pictures[0], &shown[0])?;
    // A finished fit needs no checkpoint.
    let checkpoint = checkpoint_dir(out);
    if checkpoint.exists() {
        std::fs::remove_dir_all(&checkpoint)?;
    }
    let test = match test_psnr_db {
        Some(p) => format!(", test {p:.2} dB"),
        None => String::new(),
    };
    // A fit that went on from a stopped one took that one's time too.
    let seconds = seconds + fitted_seconds;
    let line = format!(
        "fitted {} ({} training views) in {seconds:.1} s: {} Gaussians, PSNR training \
         {psnr_db:.2} dB{test}; wrote {}",
        args.data.display(),
        train.views.len(),
        gaussians.len(),
        out.display()
    );
    Ok(FitWritten {
        line,
        psnr_db,
        gaussians: gaussians.len(),
        test_psnr_db,
        seconds,
    })
}

/// Write a scene in a splat format viewers open.
///
/// Reads --model in any format it knows (INRIA PLY, SuperSplat compressed PLY, SPZ, .splat,
/// glTF .glb, SOG .sog or meta.json) and writes --out in the format its name ends in (or
/// --format): INRIA PLY (every property kept), compressed PLY, SPZ, .splat (degree-0 colour
/// only), glTF (.glb, turned y-up) or SOG (.sog, or a folder's meta.json).
#[derive(Args, Debug)]
struct SceneExportArgs {
    #[command(flatten)]
    export: ExportArgs,
}

/// The 3D binary's part of the skeleton every binary shares.
struct Scene;

impl ModalityBinary for Scene {
    const BINARY: Binary = Binary::Scene;
    const ABOUT: &'static str =
        "CLIPGaussian on 3D Gaussian splatting scenes: stylize, render, interpolate, eval";
    const INTERPOLATE_HELP: &'static str =
        "Interpolate two scenes of the same Gaussians parameter by parameter.\n\nWrites \
         `(1 - t) A + t B` (opacities in logit space, scales in log space, quaternions \
         normalized). A and B may be in any splat format the scene readers know; --out is \
         written in the format its name ends in, INRIA PLY with A's extra properties and PLY \
         format otherwise.";

    type Stylize = StylizeArgs;
    type Own = SceneCommand;
    type Render = RenderArgs;
    type Export = SceneExportArgs;
    type Eval = EvalArgs;
    type Model = PlyModel;

    /// Any splat format the scene readers know; PLY's format kept.
    fn read_model(path: &Path) -> Result<PlyModel, Box<dyn Error>> {
        let (ply, format) = read_splats_with_format(path)?;
        Ok(PlyModel { ply, format })
    }

    /// In the format the name ends in; INRIA PLY (in the model's PLY format) otherwise.
    fn write_model(path: &Path, model: &PlyModel) -> Result<(), Box<dyn Error>> {
        match SplatFormat::from_path(path) {
            Some(SplatFormat::Ply) | None => model.write(path),
            Some(format) => Ok(write_splats(path, &model.ply, format)?),
        }
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

    fn own(command: &SceneCommand) -> Result<(), Box<dyn Error>> {
        match command {
            SceneCommand::Fit(args) => fit(args),
        }
    }

    fn render(args: &RenderArgs) -> Result<(), Box<dyn Error>> {
        into_new_folder(&args.out, || render(args))
    }

    fn export(args: &SceneExportArgs) -> Result<(), Box<dyn Error>> {
        export(&args.export)
    }

    fn eval(args: &EvalArgs) -> Result<(), Box<dyn Error>> {
        eval(args)
    }
}

fn main() -> ExitCode {
    gs_stylize::binary::main::<Scene>()
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
            "--model",
            "m.ply",
            "--data",
            "d",
            "--out",
            "o",
            "-r",
            "2",
            "--max-width",
            "3",
            "--background",
            "white",
            "--orbit-views",
            "7",
            "--width",
            "30",
            "--height",
            "20",
            "--gaussians",
            "500",
            "--fit-steps",
            "40",
        ];
        let own_fields = [
            ("model", json!("m.ply")),
            ("data", json!("d")),
            ("orbit_views", json!(7)),
            ("width", json!(30)),
            ("height", json!(20)),
            ("out", json!("o")),
            ("resolution", json!(2)),
            ("max_width", json!(3)),
            ("background", json!([1.0, 1.0, 1.0])),
            ("fit_gaussians", json!(500)),
            ("fit_steps", json!(40)),
        ];
        gs_stylize::test_support::assert_flags_set::<SceneStylizeConfig>(
            &own_flags,
            &own_fields,
            |line| {
                let line = Line::parse_from(line);
                line.args.overrides().unwrap()
            },
        );
        // The camera flags of a run without data, one at a time (they exclude each other).
        for (flag, value, field) in [
            ("--cameras", "c.json", "cameras"),
            ("--orbit", "inside", "orbit"),
        ] {
            gs_stylize::test_support::assert_flags_set::<SceneStylizeConfig>(
                &["--model", "m.spz", "--out", "o", flag, value],
                &[
                    ("model", json!("m.spz")),
                    ("out", json!("o")),
                    (field, json!(value)),
                ],
                |line| {
                    let line = Line::parse_from(line);
                    line.args.overrides().unwrap()
                },
            );
        }
    }
}
