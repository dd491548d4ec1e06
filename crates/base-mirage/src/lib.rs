//! base-mirage: the MiraGe base model of CLIPGaussian for 2D images.
//!
//! A picture is held as flat 3D Gaussians near the plane `y = 0`, seen by two cameras: the
//! picture itself from `(0, -d, 0)` and its horizontal mirror from `(0, +d, 0)` (MiraGe's
//! "mirror" camera setting).
//!
//! - [`mirror`]: the camera pair, the mirrored target and the scene extent (gs-core's
//!   [`gs_core::mirror_pair`], which VeGaS shares).
//! - [`flat`]: the flat Gaussians as a [`gs_core::model::BaseModel`] (one scale held at 1e-8,
//!   the other two clamped to `[1e-8, 1]`).
//! - [`init`]: MiraGe's random initialisation on the picture plane.
//! - [`fit`]: fitting a picture with L1 + D-SSIM on both cameras.
//! - [`picture`]: loading a picture and the embedded default one.
//! - [`model_file`]: model files: is it a 2D model, which picture was it fitted to.
//! - [`stylize`](mod@stylize): the 2D stylization run (`clipgaussian-2d stylize`).
//! - [`evaluation`]: the paper's CLIP metrics of a stylized picture (`clipgaussian-2d eval`).
//!
//! The model renders through gs-core's calls like any other, on the cpu or a GPU:
//!
//! ```
//! use base_mirage::init::initial_gaussians;
//! use base_mirage::mirror::{plane_camera, plane_half_size};
//! use gs_wgpu::backend::{DeviceChoice, OpenDevice};
//! use gs_core::model::View;
//!
//! let (width, height) = (48, 32);
//! let (half_width, half_height) = plane_half_size(width, height, 1.0);
//! let mut model = initial_gaussians(500, 0, half_width, half_height, 7);
//! let backend = DeviceChoice::Cpu.open()?;
//! let front = View::still(plane_camera(width, height, 1.0, false)?);
//! let picture = backend.model_renderer(&mut model)?.render(&front, [0.0; 3])?;
//! assert_eq!((picture.width, picture.height), (width, height));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod evaluation;
pub mod fit;
pub mod flat;
pub mod init;
pub use gs_core::mirror_pair as mirror;
pub mod model_file;
pub mod picture;
pub mod stylize;
