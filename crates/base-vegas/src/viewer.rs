//! A VeGaS model in the viewer page (`gs_stylize::viewer`): its parameter groups and the
//! script that makes a frame's Gaussians from them in the page (`viewer_frame.js`, the twin of
//! [`crate::frame::build_frame`] at [`crate::time::frame_time`]), so the page's time slider
//! plays the video and its style slider blends two models' groups.

use gs_core::model::BaseModel;
use gs_stylize::viewer::Animation;

use crate::folded::FoldedGaussians;
use crate::frame::build_frame;

/// The page's script: `frameAt(groups, frame)`.
pub const FRAME_SCRIPT: &str = include_str!("viewer_frame.js");

/// The animation of `base` (and, for the style slider, `stylized`, a stylization of it), boxed
/// as [`gs_stylize::viewer::Shown::Animated`] holds it.
pub fn animation(base: &FoldedGaussians, stylized: Option<&FoldedGaussians>) -> Box<Animation> {
    let groups = |model: &FoldedGaussians| -> Vec<(String, Vec<f32>)> {
        model
            .groups()
            .iter()
            .map(|g| (g.name.to_string(), g.values.to_vec()))
            .collect()
    };
    Box::new(Animation {
        script: FRAME_SCRIPT,
        models: std::iter::once(base).chain(stylized).map(groups).collect(),
        frames: base.frames(),
        count: base.params().len(),
        degree: 0,
        first: build_frame(base.params(), base.time_of(0)).0,
    })
}
