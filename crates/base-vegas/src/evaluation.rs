//! The scores of a stylized video: the paper's CLIP metrics of every frame against the
//! original's (consecutive frames for CLIP-CONS and CLIP-F) and the temporal consistency
//! ([`crate::temporal`]).

use std::error::Error;
use std::path::Path;

use gs_stylize::animation::FRAMES_DIR;
use gs_stylize::evaluation::{check_count, score_images, ClipFiles, Metrics, Scoring};
use serde::Serialize;

use crate::stylize::VideoStylizeConfig;
use crate::temporal::{temporal_consistency, TemporalConsistency};
use crate::video_input::{load_video, DEFAULT_FOLDER_FPS};

/// The scores of a stylized video, as `clipgaussian-video eval` prints and writes them.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct VideoMetrics {
    /// The CLIP metrics.
    #[serde(flatten)]
    pub clip: Metrics,
    /// The temporal consistency of both videos.
    #[serde(flatten)]
    pub temporal: TemporalConsistency,
}

impl VideoMetrics {
    /// The table `eval` prints: the CLIP metrics as every binary prints them, then the
    /// temporal consistency (`n/a` where the video is too short for the range).
    pub fn lines(&self) -> String {
        let rmse = |v: Option<f64>| v.map_or("n/a (too few frames)".into(), |v| format!("{v:.4}"));
        let t = &self.temporal;
        format!(
            "{}short-range RMSE: {} (original {})\nlong-range RMSE:  {} (original {})\n",
            self.clip.lines(),
            rmse(t.short_range_rmse),
            rmse(t.original_short_range_rmse),
            rmse(t.long_range_rmse),
            rmse(t.original_long_range_rmse)
        )
    }
}

/// Scores the stylized frames `renders` (a folder of frames or a video file) against the
/// original `video` of as many frames, read at the renders' width when wider (as the run
/// that made them shrank them), transparent pixels over `background` in both.
pub fn evaluate_video(
    renders: &Path,
    video: &Path,
    background: [f32; 3],
    scoring: &Scoring,
) -> Result<VideoMetrics, Box<dyn Error + Send + Sync>> {
    gs_stylize::evaluation::check_prompts(&scoring.style, &scoring.source_prompt)?;
    let stylized = load_video(renders, background, DEFAULT_FOLDER_FPS, 0)?;
    let original = load_video(video, background, DEFAULT_FOLDER_FPS, stylized.size().0)?;
    check_count(
        renders,
        stylized.frames.len(),
        &video.display().to_string(),
        original.frames.len(),
    )?;
    let labels: Vec<(String, String)> = (0..stylized.frames.len())
        .map(|i| {
            (
                format!("{} frame {i}", renders.display()),
                format!("{} frame {i}", video.display()),
            )
        })
        .collect();
    let clip = score_images(
        &stylized.frames,
        &original.frames,
        &labels,
        scoring,
        [0.0; 3],
    )?;
    Ok(VideoMetrics {
        clip,
        temporal: temporal_consistency(&stylized.frames, &original.frames),
    })
}

/// Scores the finished run of `config` (the frames it wrote in `out/frames`) against its
/// video, with the run's style and source prompt and the CLIP of `clip`.
pub fn evaluate_run(
    config: &VideoStylizeConfig,
    clip: ClipFiles,
) -> Result<VideoMetrics, Box<dyn Error + Send + Sync>> {
    let out = config.out.as_deref().ok_or("the run has no out folder")?;
    let video = config.video.as_deref().ok_or("the run has no video")?;
    evaluate_video(
        &out.join(FRAMES_DIR),
        video,
        config.background,
        &Scoring::of_run(&config.style, clip),
    )
}
