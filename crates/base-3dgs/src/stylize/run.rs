//! One 3D stylization run, in the order of [`gs_stylize::drive`]: check the run (settings,
//! output folder, weights, style, device), load the PLY and the dataset and check the preview
//! views, stylize, then write the stylized PLY, in the input's format and with its extra
//! properties, and the before/after previews, and mark the run's checkpoint finished.

use std::path::{Path, PathBuf};

use gs_core::image_loss::mean_psnr;
use gs_core::model::BaseModel;
use gs_core::ply::{read_ply, write_ply, PlyFormat, PlyGaussians};
use gs_core::splats::{read_splats_with_format, write_splats, SplatFormat};
use gs_core::GaussianSet;
use gs_stylize::drive::{InputPixels, Modality, OnStep};
use gs_stylize::outputs::{write_previews, StepLosses};
use gs_stylize::progress::with_loading_progress;
use gs_stylize::viewer;
use gs_stylize::{
    Batches, PreparedRun, RenderClamp, RunError, RunOptions, StyleSettings, StylizeError,
    StylizeJob, StylizeOutcome,
};

use super::config::BackgroundPixels;
use super::model_views::model_scene;
use super::SceneStylizeConfig;
use crate::dataset::nerf_synthetic;
use crate::dataset::{colmap, Background, Dataset, DatasetError, Layout, LoadOptions};
use crate::fit::{fit, initial_gaussians, render_views, SceneFit, SceneFitSettings};

/// The stylized PLY in the output folder (`model.ply`, as the 2D and video runs name theirs).
pub const MODEL_PLY: &str = "model.ply";

/// Why a 3D run could not run: the failures every modality shares (a 3D run has none of its
/// own yet).
pub type SceneStylizeError = RunError<std::convert::Infallible>;

/// What a finished run produced.
#[derive(Clone, Debug)]
pub struct SceneSummary {
    /// The stylized parameters.
    pub gaussians: GaussianSet,
    /// The losses of every step, including those before a resume.
    pub losses: Vec<StepLosses>,
    /// The stylized PLY.
    pub stylized_ply: PathBuf,
}

/// Runs the stylization `config` describes (see the module documentation). Bad inputs are
/// reported before anything is written, the run's own checks before the scene is loaded; a
/// fresh run refuses an output folder that holds the checkpoint of an unfinished run
/// ([`gs_stylize::prepare::check_out_folder`]). When [`RunOptions::stop`] is set, the run ends
/// after the current step with a checkpoint of it and [`StylizeError::Interrupted`].
pub fn run(
    config: &SceneStylizeConfig,
    options: &RunOptions,
) -> Result<SceneSummary, SceneStylizeError> {
    gs_stylize::drive::run(config, options)
}

/// The inputs of a 3D run: the trained scene when given (with the PLY's format, extra
/// properties and comments, written back into the stylized PLY) and its dataset.
#[derive(Debug)]
pub struct SceneInput {
    given: Option<(PlyGaussians, PlyFormat)>,
    dataset: Dataset,
}

impl Modality for SceneStylizeConfig {
    type Model = GaussianSet;
    type Inputs = SceneInput;
    type Fit = GaussianSet;
    type Outputs = SceneSummary;
    type Error = SceneStylizeError;

    /// The scene a run without `model` fits first (INRIA PLY).
    const BASE_MODEL: &'static str = "base.ply";
    const FITTED: &'static str = "the scene";

    fn settings(&self) -> &StyleSettings {
        &self.style
    }

    fn out(&self) -> Result<&Path, SceneStylizeError> {
        Ok(self.out_path())
    }

    fn check(&self) -> Result<(), SceneStylizeError> {
        Ok(self.validate()?)
    }

    fn given_model(&self) -> Option<&Path> {
        self.model_path()
    }

    /// A NeRF-synthetic scene's sizes from its json files (and one picture header a split);
    /// none for a COLMAP scene, one whose files do not read (the loading reports them) or a run
    /// without data.
    fn input_pixels(&self) -> Result<Option<InputPixels>, SceneStylizeError> {
        let Some(data) = self.data.as_deref() else {
            return Ok(None);
        };
        if !matches!(Layout::detect(data), Some(Layout::NerfSynthetic)) {
            return Ok(None);
        }
        let options = LoadOptions {
            downscale: self.resolution,
            max_width: self.max_width,
            ..LoadOptions::default()
        };
        Ok(
            nerf_synthetic::training_pixels(data, self.train_splits, &options)
                .ok()
                .map(InputPixels::new),
        )
    }

    /// The PLY and the dataset (or, without data, the model's views and renders:
    /// [`model_scene`]; without a model, the dataset its fit trains on), with the preview
    /// views checked against it.
    fn load_inputs(
        &self,
        run: &PreparedRun,
        _model: Option<&Path>,
    ) -> Result<SceneInput, SceneStylizeError> {
        let given = match self.model_path() {
            Some(path) => Some(read_splats_with_format(path).map_err(StylizeError::from)?),
            None => None,
        };
        let dataset = match (self.data.as_deref(), &given, self.model_path()) {
            (Some(data), _, _) => load_dataset(self, data, run.options().progress)?,
            (None, Some((ply, _)), Some(path)) => model_scene(self, path, &ply.gaussians, run)?,
            _ => return Err(StylizeError::Input("--model or --data is required".into()).into()),
        };
        let count = dataset.views.len();
        if let Some(v) = self.preview_views.iter().find(|&&v| v >= count) {
            return Err(StylizeError::Input(format!(
                "preview_views: view {v} does not exist (the run has {count}; set them \
                 with --set preview_views=[0])"
            ))
            .into());
        }
        Ok(SceneInput { given, dataset })
    }

    /// The scene the inputs read, or (`own_fit`, a resumed run that fitted) the fit it kept.
    fn read_model(
        &self,
        scene: &SceneInput,
        path: &Path,
        own_fit: bool,
        _run: &PreparedRun,
    ) -> Result<GaussianSet, SceneStylizeError> {
        match (&scene.given, own_fit) {
            (Some((ply, _)), false) => Ok(ply.gaussians.clone()),
            _ => Ok(read_ply(path).map_err(StylizeError::from)?.gaussians),
        }
    }

    fn fit_steps(&self) -> u64 {
        if self.model.is_some() {
            0
        } else {
            self.fit_steps
        }
    }

    /// INRIA 3DGS's fit ([`crate::fit`]) of the training views, from the dataset's points or
    /// `fit_gaussians` random ones.
    fn fit(
        &self,
        scene: &SceneInput,
        run: &PreparedRun,
        on_step: OnStep<'_>,
    ) -> Result<GaussianSet, SceneStylizeError> {
        let settings = SceneFitSettings {
            steps: self.fit_steps,
            random_points: self.fit_gaussians,
            background: scene.dataset.background,
            seed: self.style.seed,
            ..SceneFitSettings::default()
        };
        let dataset = &scene.dataset;
        let start = SceneFit::new(initial_gaussians(dataset.points.as_ref(), &settings));
        let fitted = fit(
            &dataset.views,
            &dataset.images,
            start,
            dataset.extent,
            &settings,
            run.backend(),
            on_step,
        )
        .map_err(|e| StylizeError::Input(format!("the fit: {e}")))?;
        Ok(fitted.gaussians)
    }

    /// Writes the fit as INRIA PLY at `path` ([`Self::BASE_MODEL`]).
    fn keep_fit(
        &self,
        _scene: &SceneInput,
        fit: GaussianSet,
        path: &Path,
    ) -> Result<GaussianSet, SceneStylizeError> {
        write_ply(
            path,
            &PlyGaussians::new(fit.clone()),
            PlyFormat::BinaryLittleEndian,
        )
        .map_err(StylizeError::from)?;
        Ok(fit)
    }

    /// The fit's mean PSNR over the training views.
    fn fit_psnr(
        &self,
        scene: &SceneInput,
        model: &mut GaussianSet,
        run: &PreparedRun,
    ) -> Result<Option<f64>, SceneStylizeError> {
        let dataset = &scene.dataset;
        let renders = render_views(model, &dataset.views, dataset.background, run.backend())
            .map_err(StylizeError::from)?;
        Ok(Some(mean_psnr(&renders, &dataset.images)))
    }

    /// Every view of the dataset, one per step, the loss seeing the render clamped to [0, 1];
    /// the background term where the scene is an `object`.
    fn job(
        &self,
        scene: &mut SceneInput,
        model: GaussianSet,
        _run: &PreparedRun,
    ) -> Result<StylizeJob<GaussianSet>, SceneStylizeError> {
        let dataset = &scene.dataset;
        let masks = self
            .object
            .then(|| background_masks(dataset, self.background_mask))
            .flatten();
        Ok(StylizeJob {
            groups: self
                .learning_rates
                .optimizer_groups(&model.group_names(), dataset.extent)?,
            model,
            views: dataset.views.clone(),
            images: dataset.images.clone(),
            labels: dataset
                .image_paths
                .iter()
                .map(|p| p.display().to_string())
                .collect(),
            masks,
            background: dataset.background,
            batches: Batches::ONE,
            render_clamp: RenderClamp::Unit,
        })
    }

    /// The stylized PLY, in the input's format with its extra properties (and, for a scene
    /// read from another splat format, the scene in that format as well), and the previews.
    fn write_outputs(
        &self,
        scene: SceneInput,
        outcome: StylizeOutcome<GaussianSet>,
        run: &PreparedRun,
    ) -> Result<SceneSummary, SceneStylizeError> {
        let out = run.out();
        let SceneInput { given, dataset } = scene;
        let (ply, format) = match given {
            Some(given) => given,
            None => {
                let base = read_ply(&out.join(Self::BASE_MODEL)).map_err(StylizeError::from)?;
                (base, PlyFormat::BinaryLittleEndian)
            }
        };
        let stylized_ply = out.join(MODEL_PLY);
        let mut stylized = PlyGaussians {
            gaussians: outcome.model,
            extras: ply.extras,
            comments: ply.comments,
            normals: ply.normals,
        };
        write_ply(&stylized_ply, &stylized, format).map_err(StylizeError::from)?;
        // A scene read from another splat format is written in it too (`model.spz`, ...).
        if let Some(input) = self.model_path().and_then(SplatFormat::from_path) {
            if input != SplatFormat::Ply {
                let path = out.join(format!("model{}", input.extension()));
                write_splats(&path, &stylized, input).map_err(StylizeError::from)?;
            }
        }
        let mut base = ply.gaussians;
        write_previews(
            out,
            &mut base,
            &mut stylized.gaussians,
            &dataset.views,
            &self.preview_views,
            dataset.background,
            run.backend(),
        )?;
        if base.len() <= viewer::MAX_GAUSSIANS {
            viewer::write_viewer(
                &out.join(viewer::VIEWER_HTML),
                &viewer::ViewerScene {
                    title: format!("{}: {}", self.scene_name(), self.style.label()),
                    shown: viewer::Shown::Still {
                        base: &base,
                        stylized: Some(&stylized.gaussians),
                    },
                    cameras: viewer::named_cameras(&dataset.views, &dataset.image_paths),
                    background: dataset.background,
                },
            )?;
        } else if run.options().progress {
            eprintln!(
                "{}: not written for {} Gaussians (a viewer holds at most {} for now)",
                viewer::VIEWER_HTML,
                base.len(),
                viewer::MAX_GAUSSIANS
            );
        }
        Ok(SceneSummary {
            gaussians: stylized.gaussians,
            losses: outcome.losses,
            stylized_ply,
        })
    }
}

impl SceneStylizeConfig {
    /// The scene's name in titles: the model's path, or the dataset's for a run that fitted.
    fn scene_name(&self) -> String {
        match (self.model_path(), self.data.as_deref()) {
            (Some(path), _) | (None, Some(path)) => path.display().to_string(),
            (None, None) => String::new(),
        }
    }
}

/// The dataset in `data`: NeRF-synthetic when `transforms_train.json` is there, COLMAP when
/// `sparse/` is; the progress of its pictures shown when `show`.
fn load_dataset(
    config: &SceneStylizeConfig,
    data: &Path,
    show: bool,
) -> Result<Dataset, StylizeError> {
    with_loading_progress(show, "loading pictures", |progress| {
        let options = LoadOptions {
            background: Background::from_rgb(config.background),
            ground_truth: config.ground_truth,
            downscale: config.resolution,
            max_width: config.max_width,
            progress: Some(progress.clone()),
        };
        load_layout(config, data, &options)
    })
    .inspect(|dataset| {
        if show {
            for line in dataset.undistortion_summary() {
                eprintln!("lens undone for {line}");
            }
        }
    })
}

/// The dataset in `data` with `options`, of the layout found there.
fn load_layout(
    config: &SceneStylizeConfig,
    data: &Path,
    options: &LoadOptions,
) -> Result<Dataset, StylizeError> {
    let wrap = |source: DatasetError| StylizeError::Dataset {
        path: data.to_path_buf(),
        source: Box::new(source),
    };
    match Layout::detect(data) {
        Some(Layout::NerfSynthetic) => {
            nerf_synthetic::load_training(data, config.train_splits, options).map_err(wrap)
        }
        Some(Layout::Colmap) => colmap::load(data, options).map_err(wrap),
        None => Err(StylizeError::Input(format!(
            "dataset {}: {}",
            data.display(),
            Layout::LOOKED_FOR
        ))),
    }
}

/// The background mask of every view (1 = background) as `rule` says; `None` (no background
/// term) under [`BackgroundPixels::Alpha`] when a view has no alpha.
fn background_masks(dataset: &Dataset, rule: BackgroundPixels) -> Option<Vec<Vec<f32>>> {
    match rule {
        BackgroundPixels::Alpha => dataset
            .masks
            .iter()
            .map(|m| m.as_ref().map(|m| m.data.clone()))
            .collect(),
        BackgroundPixels::GroundTruthColour => {
            let [r, g, b] = dataset.background;
            let background_sum = r + g + b;
            Some(
                dataset
                    .images
                    .iter()
                    .map(|image| {
                        image
                            .data
                            .chunks_exact(3)
                            .map(|p| f32::from(u8::from(p[0] + p[1] + p[2] == background_sum)))
                            .collect()
                    })
                    .collect(),
            )
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gs_core::dataset::BackgroundMask;
    use gs_core::Image;

    /// One view of three pixels: white, nearly white, black; alpha 0 only at the black one.
    fn dataset(background: [f32; 3]) -> Dataset {
        let data = vec![1.0, 1.0, 1.0, 1.0, 1.0, 254.0 / 255.0, 0.0, 0.0, 0.0];
        Dataset {
            views: Vec::new(),
            images: vec![Image {
                width: 3,
                height: 1,
                data,
            }],
            masks: vec![Some(BackgroundMask {
                width: 3,
                height: 1,
                data: vec![0.0, 0.0, 1.0],
            })],
            image_paths: Vec::new(),
            background,
            extent: 1.0,
            points: None,
            undistorted: vec![None],
        }
    }

    #[test]
    fn the_authors_mask_is_the_pixels_whose_colours_sum_to_the_background() {
        let white = background_masks(&dataset([1.0; 3]), BackgroundPixels::GroundTruthColour);
        assert_eq!(white, Some(vec![vec![1.0, 0.0, 0.0]]));
        let black = background_masks(&dataset([0.0; 3]), BackgroundPixels::GroundTruthColour);
        assert_eq!(black, Some(vec![vec![0.0, 0.0, 1.0]]));
        let alpha = background_masks(&dataset([1.0; 3]), BackgroundPixels::Alpha);
        assert_eq!(alpha, Some(vec![vec![0.0, 0.0, 1.0]]));
        let mut without_alpha = dataset([1.0; 3]);
        without_alpha.masks = vec![None];
        assert_eq!(
            background_masks(&without_alpha, BackgroundPixels::Alpha),
            None
        );
        assert_eq!(
            background_masks(&without_alpha, BackgroundPixels::GroundTruthColour),
            white,
            "the colour rule needs no alpha"
        );
    }
}
