//! The paper's CLIP metrics of a 2D stylization: the stylized picture scored against the
//! picture it was made from (one view, so CLIP-CONS and CLIP-F are `null`).

use std::error::Error;
use std::path::Path;

use gs_core::Image;
use gs_stylize::evaluation::{score_images, ClipFiles, EvalError, Metrics, Scoring};

use crate::stylize::{original_picture, PictureStylizeConfig, STYLIZED_PNG};

/// Scores the picture `stylized` against `original` (both read with transparent pixels over
/// `background`), as `clipgaussian-2d eval` does.
pub fn evaluate_picture(
    stylized: &Path,
    original: &Path,
    background: [f32; 3],
    scoring: &Scoring,
) -> Result<Metrics, EvalError> {
    gs_stylize::evaluation::check_prompts(&scoring.style, &scoring.source_prompt)?;
    let (render, truth) = (
        Image::load(stylized, background)?,
        Image::load(original, background)?,
    );
    let labels = [(
        stylized.display().to_string(),
        original.display().to_string(),
    )];
    score_images(&[render], &[truth], &labels, scoring, background)
}

/// Scores the finished run of `config` (its `stylized.png` in `out`) against its picture as
/// the run read it (the embedded default when it names none), with the run's style and source
/// prompt and the CLIP of `clip`.
pub fn evaluate_run(
    config: &PictureStylizeConfig,
    clip: ClipFiles,
) -> Result<Metrics, Box<dyn Error + Send + Sync>> {
    let scoring = Scoring::of_run(&config.style, clip);
    gs_stylize::evaluation::check_prompts(&scoring.style, &scoring.source_prompt)?;
    let out = config.out.as_deref().ok_or("the run has no out folder")?;
    let stylized = out.join(STYLIZED_PNG);
    let render = Image::load(&stylized, config.background)?;
    let truth = original_picture(config)?;
    let labels = [(
        stylized.display().to_string(),
        config.picture.as_ref().map_or_else(
            || "the default picture".to_string(),
            |p| p.display().to_string(),
        ),
    )];
    Ok(score_images(
        &[render],
        &[truth],
        &labels,
        &scoring,
        config.background,
    )?)
}
