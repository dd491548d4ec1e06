//! base-vegas: the VeGaS base model of CLIPGaussian for videos.
//!
//! A video is held as folded Gaussians on the plane `y = 0`: each has a plane position,
//! in-plane scales and rotation, and a temporal centre, width and motion polynomial, and
//! becomes, at each frame's learned time, a flat 3D Gaussian that moves, shrinks and fades out
//! away from its temporal centre. Each frame is seen from `(0, -d, 0)` and, mirrored, from
//! `(0, +d, 0)`, as MiraGe sees a picture.
//!
//! - [`frame`]: one frame's Gaussians from the folded ones, and its backward.
//! - [`time`]: the learned time function mapping frames to times.
//! - [`init`]: VeGaS's random initialisation on the plane.
//! - [`fit`]: fitting a video with L1 + D-SSIM over its frames and their mirrors.
//! - [`folded`]: the model behind [`gs_core::model::BaseModel`].
//! - [`model_file`]: VeGaS's model PLY (time element included), read and written.
//! - [`stylize`](mod@stylize): the video stylization run (`clipgaussian-video stylize`).
//! - [`temporal`]: temporal consistency (frame-gap RMSE) for `eval`.
//! - [`evaluation`]: the scores of a stylized video (`clipgaussian-video eval`).
//! - [`video_input`]: reading a video (a folder of frames, or a video file through `ffmpeg`).

pub mod evaluation;
pub mod fit;
pub mod folded;
pub mod frame;
pub mod init;
pub mod model_file;
mod ply_vertex;
pub mod stylize;
pub mod temporal;
pub mod time;
pub mod video_input;
pub mod viewer;
