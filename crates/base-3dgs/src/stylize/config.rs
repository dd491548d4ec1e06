//! The run configuration of a 3D stylization: a flat JSON file (`configs/3d.json`) of the 3D
//! fields and the shared [`StyleSettings`], edited by `field=value` overrides, with unknown
//! fields refused ([`gs_stylize::resolve_config`]), then checked.

use std::path::{Path, PathBuf};

use gs_core::dataset::nerf_synthetic::TrainSplits;
use gs_core::dataset::GroundTruth;
use gs_core::gaussians::PARAM_NAMES;
use gs_stylize::model_views::ModelViews;
use gs_stylize::rates::{gaussian_stylization, GroupRates};
use gs_stylize::{resolve_config, Override, StyleSettings, StylizeError};
use serde::{Deserialize, Serialize};

/// Which ground-truth pixels the background loss holds to the background colour.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BackgroundPixels {
    /// Pixels whose three ground-truth values sum (in `f32`) to the background's sum, as the
    /// authors' `torch.sum(gt_image, dim=0) == torch.sum(background)`.
    #[default]
    GroundTruthColour,
    /// Pixels whose alpha is 0 (`ALPHA_BACKGROUND_BELOW`).
    Alpha,
}

/// Everything a 3D stylization run needs. The defaults are the paper's
/// ([`StyleSettings::paper_3d`]) and those of the authors' 3D code: rendering over black at
/// full resolution up to 1600 pixels wide, the stored colours as ground truth, the train and
/// test views.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneStylizeConfig {
    /// The trained 3DGS scene (INRIA PLY).
    pub model: Option<PathBuf>,
    /// The dataset folder: NeRF-synthetic when it has `transforms_train.json`, else COLMAP.
    /// Without it the run needs only the model: its views are cameras from `cameras`, else
    /// from the INRIA `cameras.json` beside the model, else an orbit made from the model
    /// (`orbit`), and each view's ground truth is the model's own render.
    pub data: Option<PathBuf>,
    /// Without `data`: where the views come from (`cameras`, `orbit`, `orbit_views`,
    /// `width`, `height`, `up`; see [`ModelViews`]).
    #[serde(flatten)]
    pub views: ModelViews,
    /// The output folder.
    pub out: Option<PathBuf>,
    /// Resolution divisor of the dataset images (3DGS's `-r`): 1 keeps them (but see
    /// `max_width`); `f > 1` divides their sizes by `f` (Python's rounding).
    pub resolution: u32,
    /// With `resolution` 1, pictures wider than this many pixels are shrunk to it, the cameras
    /// with them (Pillow's bicubic of the 8-bit picture), as INRIA's loader does at its default
    /// `-r -1` (default 1600); 0 keeps every picture at its size (INRIA's `-r 1`).
    pub max_width: u32,
    /// The colour renders are composited over, and transparent pixels where `ground_truth` is
    /// `composited`: `white` (the authors' `-w`), `black` (the default: the authors' commands
    /// pass no `-w`), `"R,G,B"` or `[r, g, b]` in `[0, 1]`.
    #[serde(deserialize_with = "gs_stylize::background::deserialize")]
    pub background: [f32; 3],
    /// How a picture with transparency becomes the ground truth: `file_colour` (the default, as
    /// the INRIA 3DGS commit the authors' 3D code pins: the stored colours, alpha ignored, so a
    /// NeRF-synthetic scene's transparent pixels are black even over white) or `composited`
    /// (over the background, cut to 8 bits, as INRIA 3DGS before August 2024 and the other
    /// modalities' loaders).
    pub ground_truth: GroundTruth,
    /// Whether the scene is an object whose background the background loss holds (the
    /// authors' `--object`): off by default, as the authors' example commands; the paper weighs
    /// the term 1000 (`lambda_background`) for objects.
    pub object: bool,
    /// Which pixels the background loss holds to the background: `ground_truth_colour` (the
    /// default, as the authors' `--object` term: pixels whose ground-truth colours sum to the
    /// background's; with `file_colour` over black that is the transparent pixels, stored black,
    /// and any opaque pure-black one) or `alpha` (pixels whose alpha is 0; a dataset whose
    /// pictures lack alpha then has no term). With `alpha` and `file_colour`, the term pulls
    /// transparent pixels to their stored colour, not to a white background.
    pub background_mask: BackgroundPixels,
    /// Which NeRF-synthetic splits train: `train_and_test` (the default: the authors' commands
    /// pass no `--eval`, so INRIA's loader trains on both and takes the extent of both) or
    /// `train`. A COLMAP scene always trains on all its pictures, as INRIA's without `--eval`.
    pub train_splits: TrainSplits,
    /// Views rendered before and after into the preview pictures (indices into the training
    /// views: the train split's frames, then the test split's).
    pub preview_views: Vec<usize>,
    /// The learning rate of each parameter group of the scene's Gaussians (`means`, `scales`,
    /// `rotations`, `opacities`, `sh_dc`, `sh_rest`), by name (see gs-stylize's `rates`); the
    /// paper's: `means` `1e-4 -> 1e-6` times the scene extent over 30,000 steps, 0.005, 0.001,
    /// 0.05, `feature_lr` 0.01 and a twentieth of it.
    pub learning_rates: GroupRates,
    /// Random starting Gaussians of the fit that runs when `model` is not given and the
    /// dataset has no points (NeRF-synthetic; `--gaussians`): INRIA's 100,000.
    pub fit_gaussians: usize,
    /// Steps of that fit (INRIA's 30,000; see `clipgaussian-3d fit`).
    pub fit_steps: u64,
    /// The settings every modality shares (style, weights, patches, models).
    #[serde(flatten)]
    pub style: StyleSettings,
}

impl Default for SceneStylizeConfig {
    fn default() -> Self {
        Self {
            model: None,
            data: None,
            views: ModelViews::default(),
            out: None,
            resolution: 1,
            max_width: gs_core::wide_pictures::AUTHORS_MAX_WIDTH,
            background: [0.0; 3],
            ground_truth: GroundTruth::FileColour,
            object: false,
            background_mask: BackgroundPixels::GroundTruthColour,
            train_splits: TrainSplits::TrainAndTest,
            preview_views: vec![0],
            learning_rates: gaussian_stylization(0.01),
            fit_gaussians: 100_000,
            fit_steps: 30_000,
            style: StyleSettings::paper_3d(),
        }
    }
}

impl SceneStylizeConfig {
    /// The configuration in `file` (the defaults when `None`, and for the fields it leaves out)
    /// with `overrides` applied in order, then checked with [`SceneStylizeConfig::validate`].
    /// Unknown fields and values of the wrong type are errors naming the field.
    pub fn resolve(file: Option<&Path>, overrides: &[Override]) -> Result<Self, StylizeError> {
        let config: Self = resolve_config(file, overrides)?;
        config.validate()?;
        Ok(config)
    }

    /// Checks what deserializing cannot: the required paths, `data` against `cameras` and
    /// `orbit`, the orbit's size, the shared settings
    /// ([`StyleSettings::validate`]), the learning rates and the resolution divisor.
    pub fn validate(&self) -> Result<(), StylizeError> {
        let bad = |field: &str, why: &str| Err(StylizeError::Config(format!("{field}: {why}")));
        if self.out.is_none() {
            return bad("out", "is required (--out FOLDER)");
        }
        if self.model.is_none() && self.data.is_none() {
            return bad(
                "model",
                "is required (--model PLY), unless --data gives a dataset to fit first",
            );
        }
        if self.model.is_none() && (self.fit_steps == 0 || self.fit_gaussians == 0) {
            return bad(
                "fit_steps, fit_gaussians",
                "the fit that runs without --model needs at least 1 step and 1 Gaussian",
            );
        }
        self.views.validate(self.data.is_some())?;
        self.style.validate()?;
        self.learning_rates.check(&PARAM_NAMES)?;
        if self.resolution == 0 {
            return bad(
                "resolution",
                "must be at least 1 (-r 1 keeps the images as they are)",
            );
        }
        Ok(())
    }

    /// The trained scene, when given (without it, the run fits one to `data` first).
    pub fn model_path(&self) -> Option<&Path> {
        self.model.as_deref()
    }

    /// The required `out` path.
    pub fn out_path(&self) -> &Path {
        self.out.as_deref().expect("validated: out is set")
    }
}
