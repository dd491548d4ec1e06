//! `clipgaussian-video`: CLIPGaussian on videos, held as VeGaS folded Gaussians.
//!
//! - `stylize`: fits a video (or takes a fitted model) and stylizes it with a text or picture
//!   style. Ctrl-C stops after the current step and writes a checkpoint to resume from.
//! - `fit`: fits a video and writes its model.
//! - `render`: renders every frame of a model.
//! - `interpolate`: blends two models of the same Gaussians.
//! - `eval`: the paper's CLIP metrics and temporal consistency of stylized frames.

use std::error::Error;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use base_vegas::evaluation::evaluate_video;
use base_vegas::fit::{self, mean_psnr, render_frames, FrameRenderer, VideoFitSettings};
use base_vegas::folded::{interpolate, view_time, FoldedGaussians};
use base_vegas::model_file::{read_model, write_model, VideoRecord};
use base_vegas::stylize::{run, VideoStylizeConfig, MODEL_PLY};
use base_vegas::video_input::{load_video_with_progress, DEFAULT_FOLDER_FPS};
use base_vegas::viewer::animation;
use clap::{Args, Subcommand};
use gs_core::mirror_pair::{plane_camera, DEFAULT_DISTANCE};
use gs_core::wide_pictures::AUTHORS_MAX_WIDTH;
use gs_stylize::animation::{
    write_frames, write_frames_with, write_mp4, write_preview_gif, FRAMES_DIR, PREVIEW_GIF,
    STYLIZED_MP4,
};
use gs_stylize::background::parse_background;
use gs_stylize::binary::ModalityBinary;
use gs_stylize::cli::{EvalStyleArgs, StyleArgs};
use gs_stylize::drive::{run_fit, FitCommand, FitWritten};
use gs_stylize::export::ExportArgs;
use gs_stylize::model_kind::{check_model, Binary};
use gs_stylize::outputs::{create_folder, into_new_folder, write_json, write_pair, PREVIEW_PNG};
use gs_stylize::summary::write_summary;
use gs_stylize::viewer::Shown;
use gs_stylize::writable::{check_output_file, check_output_folder};
use gs_stylize::{open_device, resolve_config, Override};
use gs_wgpu::backend::DeviceChoice;
use serde::Serialize;

/// Stylize a video with a text or picture style.
///
/// Fits the video first unless --model gives a fitted one, then stylizes its colours with
/// the paper's video settings (configs/video.json; configs/video-light.json is the light
/// variant). A --model given without --video is stylized alone: the video is its own frames,
/// rendered at the size and frame rate it records. Writes to --out: frames/00000.png ...
/// (the stylized frames, the size of the video), preview.png (the first frame, original | stylized), preview.gif (original |
/// stylized, animated), stylized.mp4 (when ffmpeg is
/// installed), model.ply (the stylized model), base.ply (the fit, when this run fitted),
/// viewer.html (the video in a browser: a frame slider and a style slider from the fit to the
/// stylized model), losses.json, losses.png, config.json and checkpoint/. The configuration comes from
/// --config (the paper's defaults when absent), then the flags, then every --set
/// field=value in order. Ctrl-C stops after the current step and writes a checkpoint; run
/// the same command with --resume to continue.
#[derive(Args, Debug, Serialize)]
struct StylizeArgs {
    /// JSON configuration (configs/video.json is the paper's).
    #[arg(long)]
    #[serde(skip)]
    config: Option<PathBuf>,
    /// The video: a folder of numbered PNG or JPEG frames (sorted naturally), or an mp4, webm,
    /// mov, mkv or avi file (read through ffmpeg); default with --model: the model's own
    /// frames.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    video: Option<PathBuf>,
    /// A model of the video fitted earlier (VeGaS PLY from `fit`); default: fit first.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    model: Option<PathBuf>,
    /// The output folder (created when absent).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    out: Option<PathBuf>,
    /// Frame rate of a frames folder, frames per second (a video file has its own).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    fps: Option<f64>,
    /// Frames wider than this are shrunk to it, pixels (PIL's bicubic, as VeGaS; default 1600);
    /// 0 keeps every frame at its size.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    max_width: Option<u32>,
    /// Folded Gaussians of the fit.
    #[arg(long)]
    #[serde(rename = "fit_gaussians", skip_serializing_if = "Option::is_none")]
    gaussians: Option<usize>,
    /// Steps of the fit.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    fit_steps: Option<u64>,
    /// The colour behind transparent pixels of the frames and behind the Gaussians: white,
    /// black or R,G,B (default black, as VeGaS).
    #[arg(long, value_parser = parse_background)]
    #[serde(skip_serializing_if = "Option::is_none")]
    background: Option<[f32; 3]>,
    /// The style, model files, device and run controls; `--resume` also reuses
    /// `<out>/base.ply`.
    #[command(flatten)]
    #[serde(skip)]
    style: StyleArgs,
}

/// The video binary's own subcommands.
#[derive(Subcommand, Debug)]
enum VideoCommand {
    /// Fit a video with VeGaS folded Gaussians (no stylization).
    ///
    /// Writes to --out: model.ply (VeGaS PLY, recording the frame size and rate), frames/ (the
    /// fitted frames), preview.png (the first frame, original | fit), preview.gif (original |
    /// fit, animated) and fit.json (steps, time and mean PSNR), and prints the mean PSNR over
    /// the frames.
    Fit(FitArgs),
}

/// Arguments of `fit`.
#[derive(Args, Debug)]
struct FitArgs {
    /// The video: a frames folder or a video file (through ffmpeg).
    #[arg(long)]
    video: PathBuf,
    /// The output folder (created after the fit; files of the same names are replaced).
    #[arg(long)]
    out: PathBuf,
    /// Number of folded Gaussians.
    #[arg(long, default_value_t = VideoFitSettings::default().gaussians)]
    gaussians: usize,
    /// Optimizer steps (one frame or mirror frame each).
    #[arg(long, default_value_t = VideoFitSettings::default().steps)]
    steps: u64,
    /// Seed of the initial Gaussians and the view order.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Frame rate of a frames folder, frames per second.
    #[arg(long, default_value_t = DEFAULT_FOLDER_FPS)]
    fps: f64,
    /// Frames wider than this are shrunk to it, pixels (PIL's bicubic, as VeGaS); 0 keeps every
    /// frame at its size.
    #[arg(long, default_value_t = AUTHORS_MAX_WIDTH)]
    max_width: u32,
    /// The colour behind transparent pixels and behind the Gaussians: white, black (VeGaS's)
    /// or R,G,B in [0, 1].
    #[arg(long, value_parser = parse_background, default_value = "black")]
    background: [f32; 3],
    /// Where to fit: cpu, gpu, or auto (a real GPU when there is one, else the cpu).
    #[arg(long, default_value_t = DeviceChoice::Auto)]
    device: DeviceChoice,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

/// Render every frame of a model to a folder (frames/ and, with ffmpeg, stylized.mp4).
#[derive(Args, Debug)]
struct RenderArgs {
    /// The model, VeGaS PLY.
    #[arg(long)]
    model: PathBuf,
    /// Frame width, pixels (default: the recorded one).
    #[arg(long)]
    width: Option<u32>,
    /// Frame height, pixels (default: the recorded one).
    #[arg(long)]
    height: Option<u32>,
    /// Frame rate of the mp4 (default: the recorded one, else 24).
    #[arg(long)]
    fps: Option<f64>,
    /// Distance of the camera from the plane (default: the recorded one, else 1).
    #[arg(long)]
    distance: Option<f64>,
    /// The background colour: white, black or R,G,B in [0, 1] (the run's; VeGaS: black).
    #[arg(long, value_parser = parse_background, default_value = "black")]
    background: [f32; 3],
    /// Where to render: cpu, gpu, or auto.
    #[arg(long, default_value_t = DeviceChoice::Auto)]
    device: DeviceChoice,
    /// The output folder (frames/ and stylized.mp4 in it).
    #[arg(long)]
    out: PathBuf,
}

/// Write the Gaussians of a frame (or of every frame) in a splat format viewers open.
///
/// The Gaussians of --frame as they render, written to --out in the format its name ends
/// in (or --format); with --all-frames, one file per frame into the folder --out
/// (00000.ply, ...; --format picks the format, default ply).
#[derive(Args, Debug)]
struct VideoExportArgs {
    #[command(flatten)]
    export: ExportArgs,
    /// The frame to export, from 0.
    #[arg(long, default_value_t = 0, conflicts_with = "all_frames")]
    frame: usize,
    /// Export every frame, one file each, into the folder --out.
    #[arg(long)]
    all_frames: bool,
}

/// Score stylized frames against the original video: CLIP-S, CLIP-SIM, CLIP-CONS and
/// CLIP-F over consecutive frames (CLIP ViT-L/14, x100), and temporal consistency: the RMSE
/// between frames 1 and 7 apart (short and long range, values in [0, 1]) of the stylized
/// and of the original video. The paper warps frames along the optical flow before the
/// RMSE; these are unwarped (see docs), to be compared with the original's.
#[derive(Args, Debug)]
struct EvalArgs {
    /// The stylized frames (a folder, e.g. `<stylize out>/frames`, or a video file).
    #[arg(long)]
    renders: PathBuf,
    /// The reference: the original video (a frames folder or a video file) with as many
    /// frames (`--video` is the same flag).
    #[arg(long = "gt", visible_alias = "video", value_name = "VIDEO")]
    video: PathBuf,
    /// The style and the CLIP model.
    #[command(flatten)]
    style: EvalStyleArgs,
    /// The colour behind transparent pixels of both videos' frames: white, black or R,G,B in
    /// [0, 1] (black by default, the background stylize renders over unless told otherwise).
    #[arg(long, value_parser = parse_background, default_value = "black")]
    background: [f32; 3],
    /// Where to write the scores as JSON, printed too (metrics.json by default, as every
    /// binary's eval; its folder must exist; checked before any work).
    #[arg(long, default_value = "metrics.json")]
    out: PathBuf,
}

/// Runs `stylize`.
fn stylize(args: &StylizeArgs) -> Result<(), Box<dyn Error>> {
    let started = std::time::Instant::now();
    if let Some(model) = &args.model {
        check_model(Binary::Video, "--model", model)?;
    }
    let overrides: Vec<Override> = args.style.overrides(args)?;
    let config: VideoStylizeConfig = resolve_config(args.config.as_deref(), &overrides)?;
    let summary = run(&config, &args.style.run_options()?)?;
    let out = config.out.as_deref().expect("run checked out");
    let (w, h) = (summary.frames[0].width, summary.frames[0].height);
    println!(
        "wrote {} frames ({w}x{h}) to {}, {}{} and {} ({} Gaussians)",
        summary.frames.len(),
        out.join(FRAMES_DIR).display(),
        out.join(PREVIEW_GIF).display(),
        if summary.wrote_mp4 {
            format!(", {}", out.join(STYLIZED_MP4).display())
        } else {
            " (no mp4: ffmpeg is not installed)".into()
        },
        out.join(MODEL_PLY).display(),
        summary.model.params().len()
    );
    print!(
        "{}",
        write_summary("clipgaussian-video stylize", started, out)?
    );
    Ok(())
}

/// Runs `fit`.
fn fit(args: &FitArgs) -> Result<(), Box<dyn Error>> {
    let settings = VideoFitSettings {
        gaussians: args.gaussians,
        steps: args.steps,
        seed: args.seed,
        background: args.background,
        ..VideoFitSettings::default()
    };
    if !(args.fps.is_finite() && args.fps > 0.0) {
        return Err(format!("--fps {} must be positive", args.fps).into());
    }
    let command = FitCommand {
        out: &args.out,
        device: args.device,
        progress: !args.quiet,
        what: "the video",
        steps: settings.steps,
        stages: Vec::new(),
    };
    run_fit(
        &command,
        |progress| {
            Ok(load_video_with_progress(
                &args.video,
                settings.background,
                args.fps,
                args.max_width,
                Some(progress),
            )?)
        },
        |video, backend, on_step| Ok(fit::fit(&video.frames, &settings, backend, on_step)?),
        |video, mut model, backend, seconds| {
            let (w, h) = video.size();
            let fitted = render_frames(
                &mut model,
                w,
                h,
                settings.distance,
                settings.background,
                backend,
            )?;
            let record = VideoRecord {
                width: w,
                height: h,
                fps: video.fps,
                distance: settings.distance,
            };
            write_model(&args.out.join(MODEL_PLY), &model, Some(record))?;
            write_frames(&args.out.join(FRAMES_DIR), &fitted)?;
            write_pair(&args.out.join(PREVIEW_PNG), &video.frames[0], &fitted[0])?;
            write_preview_gif(
                &args.out.join(PREVIEW_GIF),
                &video.frames,
                &fitted,
                video.fps,
            )?;
            let psnr_db = mean_psnr(&fitted, &video.frames);
            let line = format!(
                "fitted {} ({} frames of {w}x{h}) with {} Gaussians in {seconds:.1} s: mean PSNR \
                 {psnr_db:.2} dB; wrote {}",
                args.video.display(),
                video.frames.len(),
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

/// Runs `render`.
fn render(args: &RenderArgs) -> Result<(), Box<dyn Error>> {
    check_model(Binary::Video, "--model", &args.model)?;
    check_output_folder(&args.out)?;
    let (mut model, record) = Video::read_model(&args.model)?;
    let size = match (args.width, args.height, record) {
        (Some(w), Some(h), Some(r))
            if u64::from(w) * u64::from(r.height) != u64::from(h) * u64::from(r.width) =>
        {
            return Err(format!(
                "{}x{} is not the aspect ratio of the {}x{} frames {} was fitted to",
                w,
                h,
                r.width,
                r.height,
                args.model.display()
            )
            .into())
        }
        (Some(w), Some(h), _) => (w, h),
        (None, None, Some(r)) => (r.width, r.height),
        (None, None, None) => {
            return Err(format!(
                "{} records no frame size: give --width and --height",
                args.model.display()
            )
            .into())
        }
        _ => return Err("give both --width and --height, or neither".into()),
    };
    let fps = args
        .fps
        .or(record.map(|r| r.fps))
        .unwrap_or(DEFAULT_FOLDER_FPS);
    if !(fps.is_finite() && fps > 0.0) {
        return Err(format!("--fps {fps} must be positive").into());
    }
    let distance = args
        .distance
        .or(record.map(|r| r.distance))
        .unwrap_or(DEFAULT_DISTANCE);
    let backend = open_device(args.device)?;
    // Frame by frame: a long video is never held whole.
    let mut renderer = FrameRenderer::new(
        &mut model,
        size.0,
        size.1,
        distance,
        args.background,
        &backend,
    )?;
    let frames = renderer.frames();
    create_folder(&args.out)?;
    let dir = args.out.join(FRAMES_DIR);
    write_frames_with(&dir, frames, |k| Ok(renderer.render(k)?))?;
    let mp4 = write_mp4(&dir, fps, &args.out.join(STYLIZED_MP4))?;
    println!(
        "wrote {} frames ({}x{}) to {}{}",
        frames,
        size.0,
        size.1,
        dir.display(),
        if mp4 {
            " and stylized.mp4"
        } else {
            " (no mp4: ffmpeg is not installed)"
        }
    );
    Ok(())
}

/// Runs `export`.
fn export(args: &VideoExportArgs) -> Result<(), Box<dyn Error>> {
    let export = &args.export;
    export.check(Binary::Video, args.all_frames)?;
    let (model, record) = Video::read_model(&export.model)?;
    if export.is_html() {
        // The page plays every frame from the camera the video was fitted with.
        let record = record.ok_or_else(|| {
            format!(
                "{}: the model records no frame size (a VeGaS PLY, not one of ours), so the \
                 page has no camera; export frames instead",
                export.model.display()
            )
        })?;
        let stylized = match &export.b {
            Some(b) => Some(Video::read_model(b)?.0),
            None => None,
        };
        let camera = plane_camera(record.width, record.height, record.distance, false)?;
        let shown = Shown::Animated(animation(&model, stylized.as_ref()));
        println!(
            "{}",
            export.write_page(shown, vec![("frame".into(), camera)], [0.0; 3])?
        );
        return Ok(());
    }
    let frames = model.frames();
    let chosen: Vec<usize> = if args.all_frames {
        (0..frames).collect()
    } else if args.frame < frames {
        vec![args.frame]
    } else {
        return Err(format!(
            "--frame {}: {} has frames 0 to {}",
            args.frame,
            export.model.display(),
            frames - 1
        )
        .into());
    };
    let times: Vec<f64> = chosen.iter().map(|&f| view_time(f, frames)).collect();
    println!("{}", export.write_at(&model, &times, args.all_frames)?);
    Ok(())
}

/// Runs `eval`.
fn eval(args: &EvalArgs) -> Result<(), Box<dyn Error>> {
    check_output_file(&args.out)?;
    let metrics = evaluate_video(
        &args.renders,
        &args.video,
        args.background,
        &args.style.scoring(),
    )
    .map_err(|e| e as Box<dyn Error>)?;
    print!("{}", metrics.lines());
    write_json(&args.out, &metrics)?;
    println!("wrote {}", args.out.display());
    Ok(())
}

/// The video binary's part of the skeleton every binary shares.
struct Video;

impl ModalityBinary for Video {
    const BINARY: Binary = Binary::Video;
    const ABOUT: &'static str =
        "CLIPGaussian on videos (VeGaS folded Gaussians): stylize, fit, render, interpolate, \
         eval";
    const INTERPOLATE_HELP: &'static str =
        "Interpolate two models of the same Gaussians and frames parameter by \
         parameter.\n\nWrites `(1 - t) A + t B` of every stored value, e.g. between two \
         stylizations of one fit.";

    type Stylize = StylizeArgs;
    type Own = VideoCommand;
    type Render = RenderArgs;
    type Export = VideoExportArgs;
    type Eval = EvalArgs;
    type Model = (FoldedGaussians, Option<VideoRecord>);

    /// The model and the video it records.
    fn read_model(path: &Path) -> Result<Self::Model, Box<dyn Error>> {
        Ok(read_model(path)?)
    }

    fn write_model(path: &Path, (model, video): &Self::Model) -> Result<(), Box<dyn Error>> {
        Ok(write_model(path, model, *video)?)
    }

    fn blend(
        (a, video): &Self::Model,
        (b, _): &Self::Model,
        t: f32,
    ) -> Result<Self::Model, String> {
        Ok((interpolate(a, b, t)?, *video))
    }

    fn gaussian_count((model, _): &Self::Model) -> usize {
        model.params().len()
    }

    fn stylize(args: &StylizeArgs) -> Result<(), Box<dyn Error>> {
        stylize(args)
    }

    fn own(command: &VideoCommand) -> Result<(), Box<dyn Error>> {
        match command {
            VideoCommand::Fit(args) => fit(args),
        }
    }

    fn render(args: &RenderArgs) -> Result<(), Box<dyn Error>> {
        into_new_folder(&args.out, || render(args))
    }

    fn export(args: &VideoExportArgs) -> Result<(), Box<dyn Error>> {
        export(args)
    }

    fn eval(args: &EvalArgs) -> Result<(), Box<dyn Error>> {
        eval(args)
    }
}

fn main() -> ExitCode {
    gs_stylize::binary::main::<Video>()
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
            "--video",
            "v",
            "--model",
            "m.ply",
            "--out",
            "o",
            "--fps",
            "12.5",
            "--max-width",
            "3",
            "--gaussians",
            "7",
            "--fit-steps",
            "9",
            "--background",
            "white",
        ];
        let own_fields = [
            ("video", json!("v")),
            ("model", json!("m.ply")),
            ("out", json!("o")),
            ("fps", json!(12.5)),
            ("max_width", json!(3)),
            ("fit_gaussians", json!(7)),
            ("fit_steps", json!(9)),
            ("background", json!([1.0, 1.0, 1.0])),
        ];
        gs_stylize::test_support::assert_flags_set::<VideoStylizeConfig>(
            &own_flags,
            &own_fields,
            |line| {
                let line = Line::parse_from(line);
                line.args.style.overrides(&line.args).unwrap()
            },
        );
    }
}
