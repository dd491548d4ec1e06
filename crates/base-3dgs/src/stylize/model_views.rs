//! The dataset of a 3D run given only a model (no `data`): the views
//! [`gs_stylize::model_views`] chooses, each with the model's own render over the run's
//! background as its ground truth, rendered once before the first step. The content loss then
//! holds the stylized scene to what the base model shows, which is what the dataset's pictures
//! stand for in a run with data.

use std::path::Path;

use gs_core::dataset::{Dataset, LoadOptions};
use gs_core::model::View;
use gs_core::orbit::RobustBounds;
use gs_core::GaussianSet;
use gs_stylize::model_views::{all_empty, model_dataset, model_picture, nothing_seen};
use gs_stylize::progress::with_loading_progress;
use gs_stylize::{PreparedRun, StylizeError};

use super::SceneStylizeConfig;

/// The dataset of a run without `data`: the views, the model's renders as their pictures
/// ([`model_dataset`]). Prints where the cameras came from when the run shows
/// progress.
pub(crate) fn model_scene(
    config: &SceneStylizeConfig,
    model_path: &Path,
    model: &GaussianSet,
    run: &PreparedRun,
) -> Result<Dataset, StylizeError> {
    let bounds = RobustBounds::of(model)
        .map_err(|e| StylizeError::Input(format!("model {}: {e}", model_path.display())))?;
    let options = LoadOptions {
        downscale: config.resolution,
        max_width: config.max_width,
        ..LoadOptions::default()
    };
    let (views, from) = config
        .views
        .views(model_path, &bounds, config.train_splits, &options)?;
    let show = run.options().progress;
    if show {
        eprintln!(
            "cameras: {} view(s) {from}; the ground truth is the model's own render",
            views.len()
        );
    }
    let images = with_loading_progress(show, "rendering the model's views", |progress| {
        let renderer = run.backend().renderer(model)?;
        let mut images = Vec::with_capacity(views.len());
        for (done, view) in views.iter().enumerate() {
            images.push(model_picture(
                renderer.render(&view.view.camera, config.background)?,
            ));
            progress.report(done + 1, views.len());
        }
        Ok::<_, StylizeError>(images)
    })?;
    if all_empty(&images, config.background) {
        return Err(nothing_seen(model_path, views.len(), &from));
    }
    let views: Vec<View> = views.into_iter().map(|v| v.view).collect();
    Ok(model_dataset(views, images, config.background, &bounds))
}
