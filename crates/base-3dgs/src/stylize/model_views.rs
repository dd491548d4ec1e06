//! The views of a 3D run given only a model (no `data`): cameras from `cameras`, else from the
//! INRIA `cameras.json` beside the model, else an orbit made from the model
//! ([`gs_core::orbit`]); each view's ground truth is the model's own render over the run's
//! background, clamped to `[0, 1]` as a picture holds it (not rounded to 8 bits), rendered
//! once before the first step. The content loss then holds the stylized scene to what the base
//! model shows, which is what the dataset's pictures stand for in a run with data.

use std::path::{Path, PathBuf};

use gs_core::dataset::inria_cameras;
use gs_core::dataset::nerf_synthetic::{self, Split, TrainSplits};
use gs_core::dataset::LoadOptions;
use gs_core::dataset::{colmap, scene_extent, Dataset, DatasetError, DatasetView, Layout};
use gs_core::model::View;
use gs_core::orbit::{orbit, OrbitKind, RobustBounds};
use gs_core::{GaussianSet, Image};
use gs_stylize::progress::with_loading_progress;
use gs_stylize::{PreparedRun, StylizeError};

use super::SceneStylizeConfig;

/// A rendered view differing from the background by less than this anywhere is empty (it
/// would not change an 8-bit picture).
const EMPTY: f32 = 0.5 / 255.0;

/// The dataset of a run without `data`: the views as the module documentation says, the
/// model's renders as their pictures, the extent INRIA's rule gives their cameras (the
/// model's robust radius where they all stand at one point, as the inside orbit's). Prints
/// where the cameras came from when the run shows progress.
pub(crate) fn model_dataset(
    config: &SceneStylizeConfig,
    model: &GaussianSet,
    run: &PreparedRun,
) -> Result<Dataset, StylizeError> {
    let model_path = config.model_path();
    let bounds = RobustBounds::of(model)
        .map_err(|e| StylizeError::Input(format!("model {}: {e}", model_path.display())))?;
    let (views, from) = cameras(config, &bounds)?;
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
            let mut image = renderer.render(&view.view.camera, config.background)?;
            image.data.iter_mut().for_each(|v| *v = v.clamp(0.0, 1.0));
            images.push(image);
            progress.report(done + 1, views.len());
        }
        Ok::<_, StylizeError>(images)
    })?;
    if images.iter().all(|i| is_empty(i, config.background)) {
        return Err(StylizeError::Input(format!(
            "model {}: none of the {} view(s) {from} sees any of its Gaussians; give cameras \
             that see it with --cameras (an INRIA cameras.json, a transforms file or a COLMAP \
             folder)",
            model_path.display(),
            views.len()
        )));
    }
    let n = views.len();
    let views: Vec<View> = views.into_iter().map(|v| v.view).collect();
    let extent = match scene_extent(&views) {
        e if e > 1e-9 * bounds.radius => e,
        _ => bounds.radius,
    };
    Ok(Dataset {
        image_paths: (0..n)
            .map(|i| PathBuf::from(format!("view {i:03}")))
            .collect(),
        views,
        images,
        masks: vec![None; n],
        background: config.background,
        extent,
        points: None,
        undistorted: vec![None; n],
    })
}

/// Whether every pixel of `image` is within [`EMPTY`] of `background`.
fn is_empty(image: &Image, background: [f32; 3]) -> bool {
    image
        .data
        .chunks_exact(3)
        .all(|p| (0..3).all(|k| (p[k] - background[k]).abs() < EMPTY))
}

/// The views the module documentation chooses, and where they came from, in words.
fn cameras(
    config: &SceneStylizeConfig,
    bounds: &RobustBounds,
) -> Result<(Vec<DatasetView>, String), StylizeError> {
    let options = LoadOptions {
        downscale: config.resolution,
        max_width: config.max_width,
        ..LoadOptions::default()
    };
    if let Some(path) = &config.cameras {
        let views = camera_file(path, config.train_splits, &options)?;
        return Ok((views, format!("from {}", path.display())));
    }
    let beside = inria_cameras::beside(config.model_path());
    let kind = match (config.orbit, beside) {
        (Some(kind), _) => kind,
        (None, Some(path)) => {
            let views = inria_cameras::read(&path, &options).map_err(|e| dataset(&path, e))?;
            return Ok((views, format!("from {} (beside the model)", path.display())));
        }
        (None, None) => bounds.default_kind(),
    };
    let cameras = orbit(
        bounds,
        kind,
        config.orbit_views,
        (config.width, config.height),
        config.up,
    )
    .map_err(|e| StylizeError::Input(format!("orbit: {e}")))?;
    let how = match (kind, config.orbit) {
        (OrbitKind::Object, None) => {
            "an object orbit (chosen: the model's centre is filled; \
                                       --orbit inside looks out from it)"
        }
        (OrbitKind::Inside, None) => {
            "an inside orbit (chosen: the model's centre is hollow; \
                                       --orbit object looks in from around it)"
        }
        (OrbitKind::Object, Some(_)) => "an object orbit",
        (OrbitKind::Inside, Some(_)) => "an inside orbit",
    };
    let c = bounds.centre;
    let from = format!(
        "of {how}, {}x{} pixels, about the model's centre [{:.3}, {:.3}, {:.3}] of radius {:.3}",
        config.width, config.height, c[0], c[1], c[2], bounds.radius
    );
    Ok((cameras.into_iter().map(orbit_view).collect(), from))
}

/// An orbit camera as a view without a picture.
fn orbit_view(camera: gs_core::Camera) -> DatasetView {
    DatasetView {
        view: View::still(camera),
        picture: PathBuf::new(),
    }
}

/// `source` as the run's error about the camera file `path`.
fn dataset(path: &Path, source: DatasetError) -> StylizeError {
    StylizeError::Dataset {
        path: path.to_path_buf(),
        source: Box::new(source),
    }
}

/// The cameras of `path`: an INRIA `cameras.json` (a JSON array), or the dataset folder it is
/// or is in (a transforms file's folder; a COLMAP folder, or its `sparse/` or `sparse/0`),
/// the NeRF splits as `splits` says. No picture is decoded.
fn camera_file(
    path: &Path,
    splits: TrainSplits,
    options: &LoadOptions,
) -> Result<Vec<DatasetView>, StylizeError> {
    let fail = |e| dataset(path, e);
    if path.is_file() && starts_as_array(path).map_err(fail)? {
        return inria_cameras::read(path, options).map_err(fail);
    }
    let start = if path.is_file() {
        path.parent()
    } else {
        Some(path)
    };
    let found = std::iter::successors(start, |p| p.parent())
        .take(3)
        .find_map(|folder| Layout::detect(folder).map(|layout| (folder, layout)));
    match found {
        Some((folder, Layout::NerfSynthetic)) => {
            let wrap = |e| dataset(folder, e);
            let mut views = nerf_synthetic::views(folder, Split::Train, options).map_err(wrap)?;
            if splits == TrainSplits::TrainAndTest
                && nerf_synthetic::has_split(folder, Split::Test).map_err(wrap)?
            {
                views.extend(nerf_synthetic::views(folder, Split::Test, options).map_err(wrap)?);
            }
            Ok(views)
        }
        Some((folder, Layout::Colmap)) => {
            colmap::views(folder, options).map_err(|e| dataset(folder, e))
        }
        None if !path.exists() => Err(StylizeError::Input(format!(
            "cameras {}: not found",
            path.display()
        ))),
        None => Err(StylizeError::Input(format!(
            "cameras {}: not cameras this reader knows: an INRIA cameras.json (a JSON array), \
             a NeRF or nerfstudio transforms file or its folder, or a COLMAP folder",
            path.display()
        ))),
    }
}

/// Whether the file at `path` starts, after white space, with `[`.
fn starts_as_array(path: &Path) -> Result<bool, DatasetError> {
    use std::io::Read;
    let io = |source| DatasetError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut head = Vec::new();
    std::fs::File::open(path)
        .map_err(io)?
        .take(4096)
        .read_to_end(&mut head)
        .map_err(io)?;
    Ok(head.iter().find(|b| !b.is_ascii_whitespace()) == Some(&b'['))
}
