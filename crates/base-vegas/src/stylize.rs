//! Video stylization (CLIPGaussian on VeGaS): a video, fitted first unless a fitted model is
//! given, is stylized over all its frames and their mirrors, one view per step in shuffled
//! order, with the paper's video settings (`configs/video.json`): colours only (`f_dc` at the
//! paper's `feature_lr` 0.02 in `learning_rates`; positions, shapes, motion, opacity and the time function frozen, as the
//! authors' video script), and the result is rendered at the video's resolution, frame count
//! and frame rate.
//!
//! Every input (configuration, output folder and checkpoint, video, model file against the
//! video, patch size, style image, CLIP configuration, weight files) is checked before the fit.
//! Outputs in `out`:
//! - `frames/00000.png ...`: the stylized frames, the size of the original;
//! - `preview.gif`: original and stylized side by side, animated;
//! - `stylized.mp4`: the stylized video (when `ffmpeg` is installed);
//! - `model.ply`: the stylized model (VeGaS PLY), to stylize again or interpolate;
//! - `base.ply`: the fitted model when this run fitted it (a resumed run reuses it);
//! - `config.json`, `losses.json`, `losses.png` and `checkpoint/` (see gs-stylize).

use std::path::{Path, PathBuf};

use gs_core::mirror_pair::{plane_camera, DEFAULT_DISTANCE};
use gs_core::model::BaseModel;
use gs_core::Image;
use gs_stylize::drive::{InputPixels, Modality, OnStep};
use gs_stylize::outputs::{write_pair, PREVIEW_PNG};
use gs_stylize::progress::with_loading_progress;
use gs_stylize::rates::{GroupRate, GroupRates};
use gs_stylize::stylize::check_patches_fit;
use gs_stylize::viewer;
use gs_stylize::{
    Batches, PreparedRun, RenderClamp, RunError, RunOptions, StyleSettings, StylizeError,
    StylizeJob, StylizeOutcome,
};
use serde::{Deserialize, Serialize};

use crate::fit::{
    fit, mean_psnr, render_frames, training_targets, training_views, FrameRenderer,
    VideoFitSettings,
};
use crate::folded::{FoldedGaussians, GROUP_NAMES};
use crate::model_file::{read_header, read_model, write_model, VegasFileError, VideoRecord};
use crate::video_input::{
    frame_files, load_video_with_progress, Video, VideoInputError, DEFAULT_FOLDER_FPS,
};
use gs_core::image::picture_size;
use gs_core::wide_pictures::{shrunk_size, AUTHORS_MAX_WIDTH};
use gs_stylize::animation::{
    write_frames, write_mp4_or_warn, write_preview_gif, FRAMES_DIR, PREVIEW_GIF, STYLIZED_MP4,
};

/// The stylized model.
pub const MODEL_PLY: &str = "model.ply";
/// The model fitted by this run.
pub const BASE_PLY: &str = "base.ply";

/// Everything a video stylization needs (a flat JSON object: `configs/video.json`). The
/// defaults are the paper's video settings: lambdas 5 / 90 / 0.5 / 0, feature_lr 0.02, 4999
/// steps, 64 patches of 128 x 128.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct VideoStylizeConfig {
    /// The video: a folder of numbered PNG or JPEG frames, or a video file (through ffmpeg);
    /// none with a `model`: the model's own frames, rendered at the size and rate it records
    /// (the content target is then what the model shows).
    pub video: Option<PathBuf>,
    /// A model of the video fitted earlier (VeGaS PLY); none: fit one first.
    pub model: Option<PathBuf>,
    /// The output folder.
    pub out: Option<PathBuf>,
    /// Frame rate of a folder of frames (a video file has its own), frames per second.
    pub fps: f64,
    /// Frames wider than this are shrunk to it, pixels, as VeGaS's loader shrinks them (PIL's
    /// bicubic of the 8-bit frame; default 1600); 0 keeps every frame at its size.
    pub max_width: u32,
    /// Colour behind transparent pixels and behind the Gaussians, RGB in `[0, 1]` (VeGaS:
    /// black); `white`, `black`, `"R,G,B"` or `[r, g, b]` in a configuration.
    #[serde(deserialize_with = "gs_stylize::background::deserialize")]
    pub background: [f32; 3],
    /// Distance of the cameras from the plane, world units (VeGaS: 1).
    pub distance: f64,
    /// Folded Gaussians of the fit (when no model is given).
    pub fit_gaussians: usize,
    /// Steps of the fit (when no model is given).
    pub fit_steps: u64,
    /// The learning rate of each parameter group of the folded Gaussians (`xyz`, `scaling`,
    /// `rotation`, `m`, `sigma`, `w`, `opacity`, `f_dc`, `time`), by name, or `"frozen"` (see
    /// gs-stylize's `rates`); the paper's: colours only, `f_dc` at 0.02, every other group
    /// frozen.
    pub learning_rates: GroupRates,
    /// The style, the losses and the model files.
    #[serde(flatten)]
    pub style: StyleSettings,
}

impl Default for VideoStylizeConfig {
    fn default() -> Self {
        let fit = VideoFitSettings::default();
        Self {
            video: None,
            model: None,
            out: None,
            fps: DEFAULT_FOLDER_FPS,
            max_width: AUTHORS_MAX_WIDTH,
            background: fit.background,
            distance: DEFAULT_DISTANCE,
            fit_gaussians: fit.gaussians,
            fit_steps: fit.steps,
            learning_rates: stylize_rates(0.02),
            style: StyleSettings::paper_video(),
        }
    }
}

impl VideoStylizeConfig {
    /// The fit this configuration asks for.
    pub fn fit_settings(&self) -> VideoFitSettings {
        VideoFitSettings {
            gaussians: self.fit_gaussians,
            steps: self.fit_steps,
            seed: self.style.seed,
            distance: self.distance,
            background: self.background,
            ..VideoFitSettings::default()
        }
    }
}

/// The learning rates of a video stylization: SH DC at `feature_lr`, every other group
/// frozen (the paper's "colours only").
pub fn stylize_rates(feature_lr: f64) -> GroupRates {
    GroupRates::new(GROUP_NAMES.iter().map(|&name| {
        let rate = if name == "f_dc" {
            GroupRate::Constant(feature_lr)
        } else {
            GroupRate::Frozen
        };
        (name, rate)
    }))
}

/// Why a video run could not run: the failures every modality shares, and the video run's
/// own ([`VideoFailure`]).
pub type VideoStylizeError = RunError<VideoFailure>;

/// What fails in a video run only; each names the file at fault.
#[derive(Debug, thiserror::Error)]
pub enum VideoFailure {
    /// The video.
    #[error("{0}")]
    Input(#[from] VideoInputError),
    /// A model file.
    #[error("{0}")]
    Model(#[from] VegasFileError),
}

impl From<VideoInputError> for VideoStylizeError {
    fn from(e: VideoInputError) -> Self {
        Self::Own(e.into())
    }
}

impl From<VegasFileError> for VideoStylizeError {
    fn from(e: VegasFileError) -> Self {
        Self::Own(e.into())
    }
}

/// What a finished run produced.
#[derive(Clone, Debug)]
pub struct VideoSummary {
    /// The stylized model.
    pub model: FoldedGaussians,
    /// The stylized frames, the size of the original.
    pub frames: Vec<Image>,
    /// Whether `stylized.mp4` was written (ffmpeg installed).
    pub wrote_mp4: bool,
}

/// Reads the model at `path` and checks it against a video of `frames` frames of `size` seen
/// from `distance` (a model that records its video must match its aspect ratio and distance).
pub fn model_of_video(
    path: &Path,
    frames: usize,
    size: (u32, u32),
    distance: f64,
) -> Result<FoldedGaussians, VideoStylizeError> {
    let (model, record) = read_model(path)?;
    let mismatch = |reason: String| VideoStylizeError::ModelMismatch {
        path: path.to_path_buf(),
        reason,
    };
    if model.frames() != frames {
        return Err(mismatch(format!(
            "it holds {} frames, the video {frames}",
            model.frames()
        )));
    }
    if let Some(r) = record {
        let (w, h) = size;
        if (r.width as u64 * h as u64) != (r.height as u64 * w as u64) {
            return Err(mismatch(format!(
                "it was fitted to {}x{} frames, the video's are {w}x{h} (another aspect ratio)",
                r.width, r.height
            )));
        }
        if (r.distance - distance).abs() > 1e-9 * distance.abs().max(1.0) {
            return Err(mismatch(format!(
                "it was fitted with the cameras at distance {}, this run has distance {distance}",
                r.distance
            )));
        }
    }
    Ok(model)
}

/// Runs the video stylization `config` describes (see the module documentation).
pub fn run(
    config: &VideoStylizeConfig,
    options: &RunOptions,
) -> Result<VideoSummary, VideoStylizeError> {
    gs_stylize::drive::run(config, options)
}

impl VideoStylizeConfig {
    /// What a model of `video` records with this configuration.
    fn record_of(&self, video: &Video) -> VideoRecord {
        let (width, height) = video.size();
        VideoRecord {
            width,
            height,
            fps: video.fps,
            distance: self.distance,
        }
    }
}

impl VideoStylizeConfig {
    /// The video of a model given without one: its own frames, rendered at the size and
    /// frame rate it records; a model that records none, or frames larger than a picture may
    /// be, is refused naming --video.
    fn model_video(&self, path: &Path, run: &PreparedRun) -> Result<Video, VideoStylizeError> {
        let (mut model, record) = read_model(path)?;
        let refused = |what: &str| VideoStylizeError::ModelMismatch {
            path: path.to_path_buf(),
            reason: format!("{what}: give the video with --video"),
        };
        let Some(record) = record else {
            return Err(refused(
                "it records no frame size (VeGaS's own files do not)",
            ));
        };
        let (w, h) = (record.width, record.height);
        if u64::from(w) * u64::from(h) > gs_core::image::MAX_PICTURE_PIXELS {
            return Err(refused(&format!(
                "it records {w}x{h} frames, more pixels than a picture may have"
            )));
        }
        let show = run.options().progress;
        if show {
            eprintln!(
                "video: the model's own {} frames, {w}x{h} at {} fps (no --video given)",
                model.frames(),
                record.fps
            );
        }
        let frames = with_loading_progress(show, "rendering the model's frames", |progress| {
            let mut renderer = FrameRenderer::new(
                &mut model,
                w,
                h,
                self.distance,
                self.background,
                run.backend(),
            )?;
            let count = renderer.frames();
            (0..count)
                .map(|f| {
                    let frame = renderer.render(f);
                    progress.report(f + 1, count);
                    frame
                })
                .collect::<Result<Vec<Image>, _>>()
        })?;
        let labels: Vec<String> = (0..frames.len())
            .map(|k| format!("{} frame {k} (its own render)", path.display()))
            .collect();
        check_patches_fit(&self.style, &frames[..1], &labels[..1])?;
        Ok(Video {
            frames,
            labels,
            fps: record.fps,
        })
    }
}

impl Modality for VideoStylizeConfig {
    type Model = FoldedGaussians;
    type Inputs = Video;
    type Fit = FoldedGaussians;
    type Outputs = VideoSummary;
    type Error = VideoStylizeError;

    const BASE_MODEL: &'static str = BASE_PLY;
    const FITTED: &'static str = "the video";

    fn settings(&self) -> &StyleSettings {
        &self.style
    }

    fn out(&self) -> Result<&Path, VideoStylizeError> {
        self.out
            .as_deref()
            .ok_or_else(|| VideoStylizeError::Config("out: is required (--out FOLDER)".into()))
    }

    /// Checks the video path, the frame rate and the learning rates.
    fn check(&self) -> Result<(), VideoStylizeError> {
        if self.video.is_none() && self.model.is_none() {
            return Err(VideoStylizeError::Config(
                "video: is required (--video PATH, a frames folder or a video file), unless a \
                 model is given alone (--model, whose own frames are then the video)"
                    .into(),
            ));
        }
        if !(self.fps.is_finite() && self.fps > 0.0) {
            return Err(VideoStylizeError::Config(format!(
                "fps: {} must be positive (--fps)",
                self.fps
            )));
        }
        self.learning_rates.check(&GROUP_NAMES)?;
        Ok(())
    }

    fn given_model(&self) -> Option<&Path> {
        self.model.as_deref()
    }

    /// A frames folder's sizes from its first frame's header: every frame and its mirror
    /// image at that size once shrunk to `max_width`; none for a video file (ffmpeg decodes
    /// it) or a folder whose first frame's header does not read (the loading reports it).
    fn input_pixels(&self) -> Result<Option<InputPixels>, VideoStylizeError> {
        if let (None, Some(model)) = (&self.video, &self.model) {
            // A model alone: the frames its header records (one that does not, or does not
            // read, is refused at loading).
            let Ok((frames, Some(record))) = read_header(model) else {
                return Ok(None);
            };
            let pixels = u64::from(record.width) * u64::from(record.height);
            return Ok(Some(InputPixels {
                views: vec![pixels; 2 * frames],
                largest_stored: pixels,
            }));
        }
        let Some(path) = self.video.as_deref().filter(|p| p.is_dir()) else {
            return Ok(None);
        };
        let Ok(files) = frame_files(path) else {
            return Ok(None);
        };
        let Ok((w, h)) = picture_size(&files[0]) else {
            return Ok(None);
        };
        let (vw, vh) = shrunk_size(w, h, self.max_width);
        Ok(Some(InputPixels {
            views: vec![u64::from(vw) * u64::from(vh); 2 * files.len()],
            largest_stored: u64::from(w) * u64::from(h),
        }))
    }

    /// The frames, checked against the patch size.
    fn load_inputs(
        &self,
        run: &PreparedRun,
        _model: Option<&Path>,
    ) -> Result<Video, VideoStylizeError> {
        let Some(path) = self.video.as_deref() else {
            let model = self
                .model
                .as_deref()
                .expect("checked: a video or a model is given");
            return self.model_video(model, run);
        };
        let video = with_loading_progress(run.options().progress, "loading frames", |progress| {
            load_video_with_progress(
                path,
                self.background,
                self.fps,
                self.max_width,
                Some(progress),
            )
        })?;
        check_patches_fit(&self.style, &video.frames[..1], &video.labels[..1])?;
        Ok(video)
    }

    /// A VeGaS PLY of as many frames as the video (of its aspect ratio and camera distance
    /// where it records them); this run's own fit must also hold `fit_gaussians`.
    fn read_model(
        &self,
        video: &Video,
        path: &Path,
        own_fit: bool,
        _run: &PreparedRun,
    ) -> Result<FoldedGaussians, VideoStylizeError> {
        let model = model_of_video(path, video.frames.len(), video.size(), self.distance)?;
        if own_fit && model.params().len() != self.fit_gaussians {
            return Err(VideoStylizeError::ModelMismatch {
                path: path.to_path_buf(),
                reason: format!(
                    "this run's fit holds {} Gaussians, but --gaussians is {}; resume with \
                     the same settings",
                    model.params().len(),
                    self.fit_gaussians
                ),
            });
        }
        Ok(model)
    }

    fn fit_steps(&self) -> u64 {
        self.fit_steps
    }

    fn fit(
        &self,
        video: &Video,
        run: &PreparedRun,
        on_step: OnStep<'_>,
    ) -> Result<FoldedGaussians, VideoStylizeError> {
        Ok(fit(
            &video.frames,
            &self.fit_settings(),
            run.backend(),
            on_step,
        )?)
    }

    fn keep_fit(
        &self,
        video: &Video,
        fit: FoldedGaussians,
        path: &Path,
    ) -> Result<FoldedGaussians, VideoStylizeError> {
        write_model(path, &fit, Some(self.record_of(video)))?;
        Ok(fit)
    }

    /// The mean PSNR of the fitted frames.
    fn fit_psnr(
        &self,
        video: &Video,
        model: &mut FoldedGaussians,
        run: &PreparedRun,
    ) -> Result<Option<f64>, VideoStylizeError> {
        let (w, h) = video.size();
        let renders = render_frames(model, w, h, self.distance, self.background, run.backend())?;
        Ok(Some(mean_psnr(&renders, &video.frames)))
    }

    /// Every frame and its mirror image, one view per step in shuffled order.
    fn job(
        &self,
        video: &mut Video,
        model: FoldedGaussians,
        _run: &PreparedRun,
    ) -> Result<StylizeJob<FoldedGaussians>, VideoStylizeError> {
        let (w, h) = video.size();
        let views =
            training_views(w, h, video.frames.len(), self.distance).map_err(StylizeError::from)?;
        let labels = video
            .labels
            .iter()
            .flat_map(|l| [l.clone(), format!("{l}, mirrored")])
            .collect();
        Ok(StylizeJob {
            groups: self
                .learning_rates
                .optimizer_groups(&model.group_names(), 1.0)?,
            model,
            views,
            images: training_targets(&video.frames),
            labels,
            masks: None,
            background: self.background,
            batches: Batches::ONE,
            render_clamp: RenderClamp::Off,
        })
    }

    /// The stylized frames, the model, the previews and the video.
    fn write_outputs(
        &self,
        video: Video,
        outcome: StylizeOutcome<FoldedGaussians>,
        run: &PreparedRun,
    ) -> Result<VideoSummary, VideoStylizeError> {
        let out = run.out();
        let (w, h) = video.size();
        let mut model = outcome.model;
        let stylized = render_frames(
            &mut model,
            w,
            h,
            self.distance,
            self.background,
            run.backend(),
        )?;
        write_model(&out.join(MODEL_PLY), &model, Some(self.record_of(&video)))?;
        let frames_dir = out.join(FRAMES_DIR);
        write_frames(&frames_dir, &stylized)?;
        write_pair(&out.join(PREVIEW_PNG), &video.frames[0], &stylized[0])?;
        write_preview_gif(&out.join(PREVIEW_GIF), &video.frames, &stylized, video.fps)?;
        let wrote_mp4 = write_mp4_or_warn(&frames_dir, video.fps, &out.join(STYLIZED_MP4));
        // The viewer: the base model (the one given, or this run's fit) and the stylized one,
        // played frame by frame in the page.
        let count = model.params().len();
        if count <= viewer::MAX_ANIMATED_GAUSSIANS {
            let base_path = self.model.clone().unwrap_or_else(|| out.join(BASE_PLY));
            let (base, _) = read_model(&base_path)?;
            let camera = plane_camera(w, h, self.distance, false).map_err(StylizeError::from)?;
            viewer::write_viewer(
                &out.join(viewer::VIEWER_HTML),
                &viewer::ViewerScene {
                    title: format!(
                        "{}: {}",
                        self.video.as_deref().unwrap_or(&base_path).display(),
                        self.style.label()
                    ),
                    shown: viewer::Shown::Animated(crate::viewer::animation(&base, Some(&model))),
                    cameras: vec![("frame".into(), camera)],
                    background: self.background,
                },
            )?;
        } else if run.options().progress {
            eprintln!(
                "{}: not written for {count} Gaussians (a viewer holds at most {} for now)",
                viewer::VIEWER_HTML,
                viewer::MAX_ANIMATED_GAUSSIANS
            );
        }
        Ok(VideoSummary {
            model,
            frames: stylized,
            wrote_mp4,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_colours_are_trained() {
        let config = VideoStylizeConfig::default();
        config.learning_rates.check(&GROUP_NAMES).unwrap();
        assert_eq!(config.learning_rates.trained(), ["f_dc"]);
        assert_eq!(
            config.learning_rates.get("f_dc"),
            Some(&GroupRate::Constant(0.02))
        );
        assert_eq!(
            (
                config.style.lambda_directional,
                config.style.lambda_patch,
                config.style.lambda_content
            ),
            (5.0, 90.0, 0.5)
        );
        assert_eq!(config.style.steps, 4999);
    }

    /// The background is written as the other binaries write it: `white`, `black`, `R,G,B`, or
    /// an array (the form `config.json` keeps).
    #[test]
    fn the_background_takes_names_and_colours() {
        use gs_stylize::{resolve_config, Override};
        let background = |value: serde_json::Value| {
            resolve_config::<VideoStylizeConfig>(None, &[Override::new("background", value)])
                .map(|c| c.background)
        };
        assert_eq!(background("white".into()).unwrap(), [1.0; 3]);
        assert_eq!(background("0.25,0.5,1".into()).unwrap(), [0.25, 0.5, 1.0]);
        assert_eq!(
            background(serde_json::json!([0.0, 0.5, 0.0])).unwrap(),
            [0.0, 0.5, 0.0]
        );
        let err = background("grey".into()).unwrap_err().to_string();
        assert!(err.contains("white, black or R,G,B"), "{err}");
    }
}
