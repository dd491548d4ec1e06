//! Pictures as CLIP inputs: the style image of a run and the renders and ground truths an
//! evaluation scores.

use std::path::Path;

use candle_core::{Device, Tensor};
use gs_core::{GsError, Image};
use style_loss::image_layout::hwc_to_tensor;

/// The PNG or JPEG picture `path` as a `[1, 3, h, w]` tensor in `[0, 1]` on `device`,
/// transparent pixels composited over `background`. Errors name the file.
pub fn load_picture(path: &Path, background: [f32; 3], device: &Device) -> Result<Tensor, GsError> {
    as_tensor(path, &Image::load(path, background)?, device)
}

/// The style image `path` as the authors read it (`ToTensor()(image)[:3]`): its stored colours
/// as a `[1, 3, h, w]` tensor in `[0, 1]` on `device`, alpha ignored. Errors name the file.
pub fn load_style_picture(path: &Path, device: &Device) -> Result<Tensor, GsError> {
    as_tensor(path, &Image::load_stored_colours(path)?, device)
}

/// `image` (read from `path`, which errors name) as a `[1, 3, h, w]` tensor on `device`.
fn as_tensor(path: &Path, image: &Image, device: &Device) -> Result<Tensor, GsError> {
    hwc_to_tensor(
        &image.data,
        image.height as usize,
        image.width as usize,
        device,
    )
    .map_err(|e| GsError::Image {
        path: path.to_path_buf(),
        source: Box::new(e),
    })
}
