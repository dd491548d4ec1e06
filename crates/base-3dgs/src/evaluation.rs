//! The paper's CLIP metrics (CLIP-S, CLIP-SIM, CLIP-CONS, CLIP-F) of a folder of renders
//! against a folder of ground truths: pictures are paired by file name and taken in file-name
//! order (CLIP-CONS and CLIP-F use consecutive pairs in that order). The cheap checks come
//! first (the prompts, as stylization checks them; the folders; the pictures' sizes), CLIP's
//! files and the scoring after. [`evaluate_run`] scores a finished stylization on its scene's
//! test views.

use std::error::Error;
use std::path::{Path, PathBuf};

use candle_core::Device;
use gs_core::splats::read_splats;
use gs_stylize::evaluation::{
    check_prompts, check_sizes, picture_names, resolve_clip, score, score_images, Scoring,
};
pub use gs_stylize::evaluation::{write_metrics, ClipFiles, EvalError, Metrics, Style};
use gs_stylize::picture::load_picture;
use gs_wgpu::backend::OpenDevice;

use crate::dataset::nerf_synthetic::{self, Split};
use crate::dataset::{colmap, Background, Layout, LoadOptions};
use crate::render_views::render_names;
use crate::stylize::{SceneStylizeConfig, StylizeError, MODEL_PLY};

/// The folder of a finished run's output where [`evaluate_run`] writes its renders of the
/// test views (named after their pictures, with `.png`).
pub const TEST_VIEWS_DIR: &str = "test_views";

/// Orders names as people number views: runs of digits compare by value, so `r_2` comes before
/// `r_10` (CLIP-CONS and CLIP-F pair each view with the next one in this order).
fn natural_key(name: &str) -> Vec<(String, u128)> {
    let mut key = Vec::new();
    let mut text = String::new();
    let mut chars = name.chars().peekable();
    while let Some(c) = chars.next() {
        if c.is_ascii_digit() {
            let mut digits = c.to_string();
            while let Some(d) = chars.next_if(|d| d.is_ascii_digit()) {
                digits.push(d);
            }
            let value = digits.parse::<u128>().unwrap_or(u128::MAX);
            key.push((std::mem::take(&mut text), value));
        } else {
            text.push(c);
        }
    }
    key.push((text, 0));
    key
}

/// The names present in both folders in natural order (`r_2` before `r_10`); an error naming
/// every picture that is in one folder only, or when there is none.
pub fn matching_names(renders: &Path, ground_truths: &Path) -> Result<Vec<String>, EvalError> {
    let r = picture_names(renders)?;
    let g = picture_names(ground_truths)?;
    if r.is_empty() {
        return Err(EvalError::Empty {
            path: renders.to_path_buf(),
        });
    }
    if r != g {
        return Err(EvalError::Unmatched {
            renders: renders.to_path_buf(),
            ground_truths: ground_truths.to_path_buf(),
            only_renders: r.difference(&g).cloned().collect(),
            only_ground_truths: g.difference(&r).cloned().collect(),
        });
    }
    let mut names: Vec<String> = r.into_iter().collect();
    names.sort_by_cached_key(|n| (natural_key(n), n.clone()));
    Ok(names)
}

/// Scores the renders in `renders` against the pictures of the same names in `ground_truths`
/// (see the module documentation), transparent pixels over `background`, with the neutral
/// prompt `source_prompt`.
pub fn evaluate_folders(
    renders: &Path,
    ground_truths: &Path,
    style: &Style,
    source_prompt: &str,
    clip_files: &ClipFiles,
    background: [f32; 3],
) -> Result<Metrics, EvalError> {
    check_prompts(style, source_prompt)?;
    let names = matching_names(renders, ground_truths)?;
    // The sizes from the files' headers; the pictures are read a few at a time as they are
    // scored.
    let sizes = |dir: &Path| -> Result<Vec<(usize, usize)>, EvalError> {
        names
            .iter()
            .map(|n| {
                let (w, h) = gs_core::image::picture_size(&dir.join(n))?;
                Ok((w as usize, h as usize))
            })
            .collect()
    };
    let labels: Vec<(String, String)> = names
        .iter()
        .map(|n| {
            (
                renders.join(n).display().to_string(),
                ground_truths.join(n).display().to_string(),
            )
        })
        .collect();
    check_sizes(&labels, &sizes(renders)?, &sizes(ground_truths)?)?;
    let clip = resolve_clip(clip_files)?;
    let load = |path: PathBuf| load_picture(&path, background, &Device::Cpu);
    score(
        &clip,
        names.len(),
        |i| {
            let name = &names[i];
            Ok((load(renders.join(name))?, load(ground_truths.join(name))?))
        },
        style,
        source_prompt,
        background,
    )
}

/// Scores the finished run of `config`: its `model.ply` rendered (on the run's device,
/// over its background) from the views a test would use, written into `out/test_views/` and
/// scored as written (as `eval` would score that folder) against their pictures as the run
/// loads them (its background, `resolution` and `max_width`), with the run's style and source
/// prompt and the CLIP of `clip`. The views are a NeRF-synthetic scene's test split, or every
/// picture of a COLMAP scene (which has no split; the run trains on all of them).
pub fn evaluate_run(
    config: &SceneStylizeConfig,
    clip: ClipFiles,
) -> Result<Metrics, Box<dyn Error + Send + Sync>> {
    let scoring = Scoring::of_run(&config.style, clip);
    check_prompts(&scoring.style, &scoring.source_prompt)?;
    // CLIP's files found before the test views are loaded and rendered.
    resolve_clip(&scoring.clip)?;
    let data = config.data.as_deref().ok_or("the run has no data")?;
    let out = config.out.as_deref().ok_or("the run has no out folder")?;
    let options = LoadOptions {
        background: Background::from_rgb(config.background),
        ground_truth: config.ground_truth,
        downscale: config.resolution,
        max_width: config.max_width,
        progress: None,
    };
    let test = match Layout::detect(data) {
        Some(Layout::NerfSynthetic) => nerf_synthetic::load(data, Split::Test, &options)?,
        Some(Layout::Colmap) => colmap::load(data, &options)?,
        None => return Err(format!("dataset {}: {}", data.display(), Layout::LOOKED_FOR).into()),
    };
    let stylized = read_splats(&out.join(MODEL_PLY))?.gaussians;
    // A lost device is the run's kind of error (worth running again), not a bad input.
    let backend = config.style.device.open().map_err(StylizeError::Device)?;
    let renderer = backend.renderer(&stylized).map_err(StylizeError::Device)?;
    let dir = out.join(TEST_VIEWS_DIR);
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let names = render_names(data, &test.image_paths)?;
    let mut renders = Vec::with_capacity(names.len());
    let mut labels = Vec::with_capacity(names.len());
    for ((view, name), picture) in test.views.iter().zip(&names).zip(&test.image_paths) {
        let path = dir.join(name);
        renderer
            .render(&view.camera, test.background)
            .map_err(StylizeError::Device)?
            .save_png(&path)?;
        // Scored as written, 8-bit, as `eval` scores the folder.
        renders.push(gs_core::Image::load(&path, test.background)?);
        labels.push((path.display().to_string(), picture.display().to_string()));
    }
    Ok(score_images(
        &renders,
        &test.images,
        &labels,
        &scoring,
        test.background,
    )?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn natural_order_puts_numbered_views_in_sequence() {
        let mut names = vec![
            "r_10.png",
            "r_2.png",
            "r_1.png",
            "r_100.png",
            "a.png",
            "r_02.png",
        ];
        names.sort_by_cached_key(|n| (natural_key(n), n.to_string()));
        assert_eq!(
            names,
            [
                "a.png",
                "r_1.png",
                "r_02.png",
                "r_2.png",
                "r_10.png",
                "r_100.png"
            ]
        );
    }
}
