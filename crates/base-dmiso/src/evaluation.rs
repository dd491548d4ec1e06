//! The paper's CLIP metrics of a 4D stylization: its renders of the D-NeRF scene's test views
//! (`00000.png ...` in the order of `transforms_test.json`) against the test pictures, with
//! consecutive pairs in time order for CLIP-CONS and CLIP-F.

use std::error::Error;
use std::path::Path;

use gs_core::dataset::nerf_synthetic::{load_with_times, Split};
use gs_core::dataset::{Background, LoadOptions};
use gs_core::Image;
use gs_stylize::animation::FRAMES_DIR;
use gs_stylize::evaluation::{check_names, score_images, ClipFiles, Metrics, Scoring};

use crate::model_file::recorded_background;
use crate::stylize::{DynamicSceneStylizeConfig, MODEL_FILE};

/// Scores the renders in `renders` against the test split of the D-NeRF scene `data`, its
/// pictures composited over `background` and shrunk to `max_width` when wider (0: kept), as
/// `clipgaussian-4d eval` does.
pub fn evaluate_test_views(
    renders: &Path,
    data: &Path,
    background: Background,
    max_width: u32,
    scoring: &Scoring,
) -> Result<Metrics, Box<dyn Error + Send + Sync>> {
    gs_stylize::evaluation::check_prompts(&scoring.style, &scoring.source_prompt)?;
    let options = LoadOptions {
        background,
        downscale: 1,
        max_width,
        ..LoadOptions::default()
    };
    let test = load_with_times(data, Split::Test, &options)?;
    let count = test.views.len();
    let name = |i: usize| format!("{i:05}.png");
    check_names(
        renders,
        &(0..count).map(name).collect(),
        &format!("the test split of {}", data.display()),
    )?;
    let mut order: Vec<usize> = (0..count).collect();
    order.sort_by(|&a, &b| test.views[a].time.total_cmp(&test.views[b].time));
    let rendered = order
        .iter()
        .map(|&i| Image::load(&renders.join(name(i)), [0.0; 3]))
        .collect::<Result<Vec<_>, _>>()?;
    let labels: Vec<(String, String)> = order
        .iter()
        .map(|&i| {
            (
                renders.join(name(i)).display().to_string(),
                test.image_paths[i].display().to_string(),
            )
        })
        .collect();
    // The test pictures moved into time order, not copied.
    let mut pictures: Vec<Option<Image>> = test.images.into_iter().map(Some).collect();
    let truths: Vec<Image> = order
        .iter()
        .map(|&i| pictures[i].take().expect("an order visits each view once"))
        .collect();
    Ok(score_images(
        &rendered,
        &truths,
        &labels,
        scoring,
        background.rgb(),
    )?)
}

/// Scores the finished run of `config` (the test views it rendered into `out/frames`) against
/// its scene's test split, over the background the run used, with the run's style and source
/// prompt and the CLIP of `clip`.
pub fn evaluate_run(
    config: &DynamicSceneStylizeConfig,
    clip: ClipFiles,
) -> Result<Metrics, Box<dyn Error + Send + Sync>> {
    let out = config.out.as_deref().ok_or("the run has no out folder")?;
    let data = config.data.as_deref().ok_or("the run has no data")?;
    let recorded = match config.background {
        Some(_) => None,
        None => recorded_background(&out.join(MODEL_FILE))?,
    };
    let background = config.background(recorded);
    evaluate_test_views(
        &out.join(FRAMES_DIR),
        data,
        background,
        config.max_width,
        &Scoring::of_run(&config.style, clip),
    )
}
