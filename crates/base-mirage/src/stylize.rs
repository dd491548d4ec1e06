//! 2D stylization (CLIPGaussian on MiraGe): a picture, fitted first unless a fitted model is
//! given, is stylized on both mirror cameras with the paper's 2D settings, and the result is
//! rendered at exactly the picture's resolution.
//!
//! Every input (configuration, the output folder and its checkpoint, picture, model file and
//! its fit to the picture ([`crate::model_file`]), patch size against the picture, style image,
//! CLIP configuration, the presence of the weight files) is checked before the fit, so such a
//! bad input costs no time and leaves nothing behind.
//! Outputs in `out`:
//! - `stylized.png`: the stylized picture, the size of the original;
//! - `preview.png`: the original and the stylized picture, left and right;
//! - `model.ply`: the stylized model (MiraGe PLY), to stylize again or interpolate;
//! - `base.ply`: the fitted model when this run fitted it (a resumed run reuses it);
//! - `original.png`: the picture when it is not a file (the embedded default, or the render of a
//!   model given alone);
//! - `config.json`, `losses.json`, `losses.png` and `checkpoint/` (see gs-stylize; marked
//!   finished once the rest is written).

use std::path::{Path, PathBuf};

use gs_core::gaussians::PARAM_NAMES;
use gs_core::image::picture_size;
use gs_core::image_loss::psnr;
use gs_core::model::BaseModel;
use gs_core::wide_pictures::{shrunk_size, AUTHORS_MAX_WIDTH};
use gs_core::{GaussianSet, Image};
use gs_stylize::drive::{InputPixels, Modality, OnStep};
use gs_stylize::export::gaussians_at;
use gs_stylize::rates::{gaussian_stylization, GroupRates};
use gs_stylize::stylize::check_patches_fit;
use gs_stylize::viewer;
use gs_stylize::{
    Batches, PreparedRun, RenderClamp, RunError, RunOptions, StyleSettings, StylizeError,
    StylizeJob, StylizeOutcome,
};
use serde::{Deserialize, Serialize};

use crate::fit::{
    fit_logged, render_picture, write_psnr_plot, Fitted, PictureFitSettings, FIT_PSNR_PNG,
};
use crate::flat::FlatGaussians;
use crate::mirror::{extent, mirror_views, mirrored, DEFAULT_DISTANCE};
use crate::model_file::{check_fits_picture, read_model, write_model, FittedTo};
use crate::picture::{default_picture, load_picture, PictureError};

/// The style of the README's main job and of a run that names none.
pub const DEFAULT_STYLE_PROMPT: &str = "Starry Night by Vincent van Gogh";

/// The stylized picture.
pub const STYLIZED_PNG: &str = "stylized.png";
/// Original and stylized picture side by side, as every modality writes it.
pub use gs_stylize::outputs::PREVIEW_PNG;
/// The stylized model.
pub const MODEL_PLY: &str = "model.ply";
/// The model fitted by this run.
pub const BASE_PLY: &str = "base.ply";
/// The embedded default picture, written when it is the one stylized.
pub const ORIGINAL_PNG: &str = "original.png";

/// Everything a 2D stylization run needs (a flat JSON object: `configs/2d.json`). The
/// defaults are the paper's 2D settings (the paper; docs/fidelity.md): lambdas 5 / 90 / 0.8 / 0, feature_lr
/// 0.0025 (`learning_rates`), 4999 steps, 64 patches of 128 x 128, styled "Starry Night by Vincent van Gogh".
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PictureStylizeConfig {
    /// The picture (PNG or JPEG, any size); none: the model's own render when a model is
    /// given (the content target is then what the model shows), else the embedded default
    /// picture.
    pub picture: Option<PathBuf>,
    /// A model of the picture fitted earlier (MiraGe PLY); none: fit one first.
    pub model: Option<PathBuf>,
    /// The output folder.
    pub out: Option<PathBuf>,
    /// Colour behind transparent picture pixels and behind the Gaussians, RGB in `[0, 1]`;
    /// also read as `white`, `black` or `"R,G,B"` ([`gs_stylize::background`]).
    #[serde(deserialize_with = "gs_stylize::background::deserialize")]
    pub background: [f32; 3],
    /// A picture wider than this is shrunk to it, pixels, as MiraGe's loader shrinks it (PIL's
    /// bicubic of the 8-bit picture; default 1600); 0 keeps every picture at its size.
    pub max_width: u32,
    /// Distance of the cameras from the picture plane, world units (MiraGe: 1).
    pub distance: f64,
    /// Gaussians of the fit (when no model is given).
    pub fit_gaussians: usize,
    /// Steps of the fit (when no model is given).
    pub fit_steps: u64,
    /// SH degree of the fit (when no model is given).
    pub fit_sh_degree: usize,
    /// The learning rate of each parameter group (`means`, `scales`, `rotations`,
    /// `opacities`, `sh_dc`, `sh_rest`), by name (see gs-stylize's `rates`); the paper's:
    /// those of 3D with `feature_lr` 0.0025 (`sh_dc`, and a twentieth of it for `sh_rest`).
    pub learning_rates: GroupRates,
    /// The style, the losses and the model files.
    #[serde(flatten)]
    pub style: StyleSettings,
}

impl Default for PictureStylizeConfig {
    fn default() -> Self {
        let fit = PictureFitSettings::default();
        let mut style = StyleSettings::paper_2d();
        style.style_prompt = Some(DEFAULT_STYLE_PROMPT.to_string());
        Self {
            picture: None,
            model: None,
            out: None,
            background: fit.background,
            max_width: AUTHORS_MAX_WIDTH,
            distance: DEFAULT_DISTANCE,
            fit_gaussians: fit.gaussians,
            fit_steps: fit.steps,
            fit_sh_degree: fit.sh_degree,
            learning_rates: gaussian_stylization(0.0025),
            style,
        }
    }
}

impl PictureStylizeConfig {
    /// The fit this configuration asks for.
    pub fn fit_settings(&self) -> PictureFitSettings {
        PictureFitSettings {
            gaussians: self.fit_gaussians,
            steps: self.fit_steps,
            sh_degree: self.fit_sh_degree,
            seed: self.style.seed,
            distance: self.distance,
            background: self.background,
            ..PictureFitSettings::default()
        }
    }

    /// The required output folder.
    fn out_path(&self) -> Result<&Path, PictureStylizeError> {
        self.out
            .as_deref()
            .ok_or_else(|| PictureStylizeError::Config("out: is required (--out FOLDER)".into()))
    }
}

/// Why a 2D run could not run: the failures every modality shares, and the 2D run's own
/// ([`PictureFailure`]).
pub type PictureStylizeError = RunError<PictureFailure>;

/// What fails in a 2D run only; each names the file at fault.
#[derive(Debug, thiserror::Error)]
pub enum PictureFailure {
    /// The picture.
    #[error("{0}")]
    Picture(#[from] PictureError),
    /// The model file (the reader's or writer's error names it).
    #[error("model {source}")]
    Model {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        source: gs_core::ply::PlyError,
    },
}

impl From<PictureError> for PictureStylizeError {
    fn from(e: PictureError) -> Self {
        Self::Own(e.into())
    }
}

/// What a finished run produced.
#[derive(Clone, Debug)]
pub struct PictureSummary {
    /// The stylized model.
    pub model: FlatGaussians,
    /// The stylized picture, the size of the original.
    pub stylized: Image,
    /// Total loss of every step.
    pub losses: Vec<f32>,
}

/// Loads the picture the configuration names as the run reads it, or the embedded default.
pub fn original_picture(config: &PictureStylizeConfig) -> Result<Image, PictureStylizeError> {
    match &config.picture {
        Some(path) => Ok(load_picture(path, config.background, config.max_width)?),
        None => Ok(default_picture()),
    }
}

/// How the picture is named in errors: its file, or "the default picture".
fn picture_label(config: &PictureStylizeConfig) -> String {
    config
        .picture
        .as_ref()
        .map_or("the default picture".to_string(), |p| {
            p.display().to_string()
        })
}

/// Runs the 2D stylization `config` describes (see the module documentation).
pub fn run(
    config: &PictureStylizeConfig,
    options: &RunOptions,
) -> Result<PictureSummary, PictureStylizeError> {
    gs_stylize::drive::run(config, options)
}

/// The picture of a 2D run and how it is named in errors.
#[derive(Debug)]
pub struct PictureInput {
    picture: Image,
    label: String,
    /// The model's Gaussians before stylizing (set when the job is made), for the viewer.
    base: Option<GaussianSet>,
}

impl PictureInput {
    /// What a model of this picture was fitted to.
    fn fitted_to(&self, distance: f64) -> FittedTo {
        FittedTo {
            width: self.picture.width,
            height: self.picture.height,
            distance,
        }
    }
}

impl PictureStylizeConfig {
    /// `model` seen by the front camera at `picture`'s size, over the run's background.
    fn front_view(
        &self,
        model: &mut FlatGaussians,
        picture: &Image,
        run: &PreparedRun,
    ) -> Result<Image, PictureStylizeError> {
        Ok(render_picture(
            model,
            picture.width,
            picture.height,
            self.distance,
            false,
            self.background,
            run.backend(),
        )?)
    }
}

impl PictureStylizeConfig {
    /// The picture of a model given without one: its render by the front camera at the size
    /// it records, and how errors name it.
    fn model_picture(
        &self,
        path: &Path,
        run: &PreparedRun,
    ) -> Result<(Image, String), PictureStylizeError> {
        let mut file = read_model(path)?;
        let Some((width, height)) = file.picture_size() else {
            return Err(PictureStylizeError::ModelMismatch {
                path: path.to_path_buf(),
                reason: "it records no picture size (MiraGe's own files do not), or one larger \
                         than a picture may be: give the picture with --picture"
                    .into(),
            });
        };
        let picture = render_picture(
            &mut file.model,
            width,
            height,
            self.distance,
            false,
            self.background,
            run.backend(),
        )?;
        if run.options().progress {
            eprintln!("picture: the model's own render, {width}x{height} (no --picture given)");
        }
        Ok((picture, format!("{} (its own render)", path.display())))
    }
}

impl Modality for PictureStylizeConfig {
    type Model = FlatGaussians;
    type Inputs = PictureInput;
    type Fit = Fitted;
    type Outputs = PictureSummary;
    type Error = PictureStylizeError;

    const BASE_MODEL: &'static str = BASE_PLY;
    const FITTED: &'static str = "the picture";

    fn settings(&self) -> &StyleSettings {
        &self.style
    }

    fn out(&self) -> Result<&Path, PictureStylizeError> {
        self.out_path()
    }

    /// Checks the background and the learning rates.
    fn check(&self) -> Result<(), PictureStylizeError> {
        if self.background.iter().any(|c| !(0.0..=1.0).contains(c)) {
            return Err(PictureStylizeError::Config(format!(
                "background: {:?} must have channels in [0, 1] (--background R,G,B)",
                self.background
            )));
        }
        self.learning_rates.check(&PARAM_NAMES)?;
        Ok(())
    }

    fn given_model(&self) -> Option<&Path> {
        self.model.as_deref()
    }

    /// The picture's size from its header: two views (the picture and its mirror image) at
    /// its size once shrunk to `max_width`; none for the embedded default.
    fn input_pixels(&self) -> Result<Option<InputPixels>, PictureStylizeError> {
        let Some(path) = &self.picture else {
            return Ok(None);
        };
        // A file whose header does not read is reported by the loading, as any bad picture.
        let Ok((w, h)) = picture_size(path) else {
            return Ok(None);
        };
        let (vw, vh) = shrunk_size(w, h, self.max_width);
        let view = u64::from(vw) * u64::from(vh);
        Ok(Some(InputPixels {
            views: vec![view; 2],
            largest_stored: u64::from(w) * u64::from(h),
        }))
    }

    /// The picture (a model given alone: its own render), checked against the patch size.
    fn load_inputs(
        &self,
        run: &PreparedRun,
        _model: Option<&Path>,
    ) -> Result<PictureInput, PictureStylizeError> {
        let (picture, label) = match (&self.picture, &self.model) {
            (None, Some(model)) => self.model_picture(model, run)?,
            _ => (original_picture(self)?, picture_label(self)),
        };
        check_patches_fit(
            &self.style,
            std::slice::from_ref(&picture),
            std::slice::from_ref(&label),
        )?;
        Ok(PictureInput {
            picture,
            label,
            base: None,
        })
    }

    /// A MiraGe PLY, checked against the picture (a model of another size is refused; one of
    /// the same aspect ratio fitted at another size is taken with a warning).
    fn read_model(
        &self,
        inputs: &PictureInput,
        path: &Path,
        _own_fit: bool,
        _run: &PreparedRun,
    ) -> Result<FlatGaussians, PictureStylizeError> {
        let file = read_model(path)?;
        let (w, h) = (inputs.picture.width, inputs.picture.height);
        if let Some(warning) = check_fits_picture(path, &file, w, h, self.distance, &inputs.label)?
        {
            eprintln!("warning: {warning}");
        }
        Ok(file.model)
    }

    fn fit_steps(&self) -> u64 {
        self.fit_steps
    }

    fn fit(
        &self,
        inputs: &PictureInput,
        run: &PreparedRun,
        on_step: OnStep<'_>,
    ) -> Result<Fitted, PictureStylizeError> {
        Ok(fit_logged(
            &inputs.picture,
            &self.fit_settings(),
            run.backend(),
            on_step,
        )?)
    }

    /// Writes the fitted model and the plot of its PSNR ([`FIT_PSNR_PNG`]).
    fn keep_fit(
        &self,
        inputs: &PictureInput,
        fit: Fitted,
        path: &Path,
    ) -> Result<FlatGaussians, PictureStylizeError> {
        write_model(path, &fit.model, &inputs.fitted_to(self.distance))?;
        write_psnr_plot(&self.out_path()?.join(FIT_PSNR_PNG), &fit.psnr)?;
        Ok(fit.model)
    }

    /// The PSNR of the fitted picture, seen by the front camera at the picture's size.
    fn fit_psnr(
        &self,
        inputs: &PictureInput,
        model: &mut FlatGaussians,
        run: &PreparedRun,
    ) -> Result<Option<f64>, PictureStylizeError> {
        let render = self.front_view(model, &inputs.picture, run)?;
        Ok(Some(psnr(&render, &inputs.picture)))
    }

    /// Both mirror cameras, the picture and its mirror image, one view per step.
    fn job(
        &self,
        inputs: &mut PictureInput,
        model: FlatGaussians,
        _run: &PreparedRun,
    ) -> Result<StylizeJob<FlatGaussians>, PictureStylizeError> {
        inputs.base = Some(gaussians_at(&model, 0.0).map_err(StylizeError::Input)?);
        let PictureInput { picture, label, .. } = inputs;
        let views = mirror_views(picture.width, picture.height, self.distance)
            .map_err(StylizeError::from)?;
        Ok(StylizeJob {
            groups: self
                .learning_rates
                .optimizer_groups(&model.group_names(), extent(self.distance))?,
            model,
            views: views.to_vec(),
            images: vec![picture.clone(), mirrored(picture)],
            labels: vec![label.clone(), format!("{label}, mirrored")],
            masks: None,
            background: self.background,
            batches: Batches::ONE,
            render_clamp: RenderClamp::Off,
        })
    }

    /// The stylized picture at the original's size, the model and the preview.
    fn write_outputs(
        &self,
        inputs: PictureInput,
        outcome: StylizeOutcome<FlatGaussians>,
        run: &PreparedRun,
    ) -> Result<PictureSummary, PictureStylizeError> {
        let out = run.out();
        let fitted_to = inputs.fitted_to(self.distance);
        let picture = inputs.picture.clone();
        let mut model = outcome.model;
        let stylized = self.front_view(&mut model, &picture, run)?;
        write_model(&out.join(MODEL_PLY), &model, &fitted_to)?;
        let save = |image: &Image, name: &str| {
            image
                .save_png(&out.join(name))
                .map_err(|e| PictureStylizeError::from(StylizeError::from(e)))
        };
        save(&stylized, STYLIZED_PNG)?;
        save(&Image::side_by_side(&[&picture, &stylized]), PREVIEW_PNG)?;
        if let Some(base) = &inputs.base {
            let after = gaussians_at(&model, 0.0).map_err(StylizeError::Input)?;
            let views = mirror_views(picture.width, picture.height, self.distance)
                .map_err(StylizeError::from)?;
            viewer::write_viewer(
                &out.join(viewer::VIEWER_HTML),
                &viewer::ViewerScene {
                    title: format!("{}: {}", inputs.label, self.style.label()),
                    shown: viewer::Shown::Still {
                        base,
                        stylized: Some(&after),
                    },
                    cameras: vec![
                        ("picture".into(), views[0].camera.clone()),
                        ("mirror".into(), views[1].camera.clone()),
                    ],
                    background: self.background,
                },
            )?;
        }
        if self.picture.is_none() {
            save(&picture, ORIGINAL_PNG)?;
        }
        Ok(PictureSummary {
            model,
            stylized,
            losses: outcome.losses.iter().map(|l| l.total).collect(),
        })
    }
}
