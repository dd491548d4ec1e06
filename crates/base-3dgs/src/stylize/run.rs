//! One 3D stylization run: check the run ([`gs_stylize::prepare`]: settings, output folder,
//! weights, style, device), load the PLY and the dataset and check the preview views, stylize
//! ([`gs_stylize::PreparedRun::stylize`], which checks the rest before creating the output
//! folder), then write the stylized PLY, in the input's format and with its extra
//! properties, and the before/after previews, and mark the run's checkpoint finished.

use std::path::PathBuf;

use gs_core::model::BaseModel;
use gs_core::ply::{read_ply_with_format, write_ply, PlyError, PlyGaussians};
use gs_core::GaussianSet;
use gs_stylize::checkpoint::mark_finished;
use gs_stylize::outputs::{write_previews, StepLosses};
use gs_stylize::{
    prepare, Batches, RenderClamp, RunOptions, StylizeError, StylizeJob, StylizeOutcome,
};

use super::config::BackgroundPixels;
use super::StylizeConfig;
use crate::dataset::nerf_synthetic::{self, Split};
use crate::dataset::{colmap, Background, Dataset, DatasetError, Layout, LoadOptions};

/// The stylized PLY in the output folder.
pub const STYLIZED_PLY: &str = "stylized.ply";

/// What a finished run produced.
#[derive(Clone, Debug)]
pub struct RunSummary {
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
/// ([`gs_stylize::run::check_out_folder`]). When [`RunOptions::stop`] is set, the run ends
/// after the current step with a checkpoint of it and [`StylizeError::Interrupted`].
pub fn run(config: &StylizeConfig, options: &RunOptions) -> Result<RunSummary, StylizeError> {
    config.validate()?;
    let prepared = prepare(&config.style, config.out_path(), options.clone())?;
    let backend = prepared.backend();
    let (ply, format) = read_ply_with_format(config.ply_path()).map_err(ply_error)?;
    let dataset = load_dataset(config)?;
    let count = dataset.views.len();
    if let Some(v) = config.preview_views.iter().find(|&&v| v >= count) {
        return Err(StylizeError::Input(format!(
            "preview_views: view {v} does not exist (the dataset has {count})"
        )));
    }
    let masks = config
        .object
        .then(|| background_masks(&dataset, config.background_mask))
        .flatten();
    let model = ply.gaussians.clone();
    let job = StylizeJob {
        groups: config
            .learning_rates
            .optimizer_groups(&model.group_names(), dataset.extent)?,
        model,
        views: dataset.views.clone(),
        images: dataset.images,
        labels: dataset
            .image_paths
            .iter()
            .map(|p| p.display().to_string())
            .collect(),
        masks,
        background: dataset.background,
        batches: Batches::ONE,
        render_clamp: RenderClamp::Unit,
    };
    let out = config.out_path();
    let StylizeOutcome { model, losses } = prepared.stylize(config, job)?;

    let stylized_ply = out.join(STYLIZED_PLY);
    let mut stylized = PlyGaussians {
        gaussians: model,
        extras: ply.extras,
        comments: ply.comments,
    };
    write_ply(&stylized_ply, &stylized, format).map_err(ply_error)?;
    let mut base = ply.gaussians;
    write_previews(
        out,
        &mut base,
        &mut stylized.gaussians,
        &dataset.views,
        &config.preview_views,
        dataset.background,
        backend,
    )?;
    mark_finished(out, config.style.steps)?;
    Ok(RunSummary {
        gaussians: stylized.gaussians,
        losses,
        stylized_ply,
    })
}

/// A PLY error as a run error (it names the file).
fn ply_error(e: PlyError) -> StylizeError {
    StylizeError::Input(format!("PLY: {e}"))
}

/// The dataset in `data`: NeRF-synthetic when `transforms_train.json` is there, COLMAP when
/// `sparse/` is.
fn load_dataset(config: &StylizeConfig) -> Result<Dataset, StylizeError> {
    let data = config.data_path();
    let options = LoadOptions {
        background: Background::from_rgb(config.background),
        ground_truth: config.ground_truth,
        downscale: config.resolution,
        max_width: config.max_width,
    };
    let wrap = |e: DatasetError| StylizeError::Input(format!("dataset {}: {e}", data.display()));
    match Layout::detect(data) {
        Some(Layout::NerfSynthetic) => {
            nerf_synthetic::load_training(data, config.train_splits, &options).map_err(wrap)
        }
        Some(Layout::Colmap) => colmap::load(data, &options).map_err(wrap),
        None => Err(StylizeError::Input(format!(
            "dataset {}: neither {} (NeRF-synthetic) nor sparse/ (COLMAP) was found",
            data.display(),
            Split::Train.file_name()
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
