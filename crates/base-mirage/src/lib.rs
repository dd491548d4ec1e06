//! base-mirage: the MiraGe base model of CLIPGaussian for 2D images.
//!
//! A picture is held as flat 3D Gaussians near the plane `y = 0`, seen by two cameras: the
//! picture itself from `(0, -d, 0)` and its horizontal mirror from `(0, +d, 0)` (MiraGe's
//! "mirror" camera setting).
//!
//! - [`mirror`]: the camera pair, the mirrored target and the scene extent.
//! - [`flat`]: the flat Gaussians as a [`gs_core::model::BaseModel`] (one scale held at 1e-8,
//!   the other two clamped to `[1e-8, 1]`).
//! - [`init`]: MiraGe's random initialisation on the picture plane.
//! - [`fit`]: fitting a picture with L1 + D-SSIM on both cameras.
//! - [`picture`]: loading a picture and the embedded default one.
//! - [`background`]: background colours as users write them (`white`, `black`, `R,G,B`).
//! - [`model_file`]: model files: is it a 2D model, which picture was it fitted to.
//! - [`stylize`](mod@stylize): the 2D stylization run (`clipgaussian-2d stylize`).

pub mod background;
pub mod fit;
pub mod flat;
pub mod init;
pub mod mirror;
pub mod model_file;
pub mod picture;
pub mod stylize;
