//! Conversions between gs-core's interleaved HWC `Vec<f32>` images and candle's `[1, 3, h, w]`.

use candle_core::{Device, Tensor};

use crate::error::{Result, StyleLossError};

/// An RGB image stored row-major with interleaved channels (`[h, w, 3]`) -> `[1, 3, h, w]`.
pub fn hwc_to_tensor(
    pixels: &[f32],
    height: usize,
    width: usize,
    device: &Device,
) -> Result<Tensor> {
    if pixels.len() != height * width * 3 {
        return Err(StyleLossError::Input {
            name: "pixels".into(),
            reason: format!(
                "{} values for a {height}x{width} RGB image ({} expected)",
                pixels.len(),
                height * width * 3
            ),
        });
    }
    let hwc = Tensor::from_slice(pixels, (height, width, 3), device)?;
    crate::transfers::record_upload(std::mem::size_of_val(pixels));
    Ok(hwc.permute((2, 0, 1))?.contiguous()?.unsqueeze(0)?)
}

/// `[1, 3, h, w]` or `[3, h, w]` -> interleaved `[h, w, 3]` values (e.g. a gradient for gs-core).
pub fn tensor_to_hwc(image: &Tensor) -> Result<Vec<f32>> {
    let chw = match image.rank() {
        4 => image.squeeze(0)?,
        _ => image.clone(),
    };
    let (channels, _, _) = chw.dims3()?;
    if channels != 3 {
        return Err(StyleLossError::Input {
            name: "image".into(),
            reason: format!("shape {:?}, expected 3 channels", image.dims()),
        });
    }
    let values = chw
        .permute((1, 2, 0))?
        .flatten_all()?
        .to_dtype(candle_core::DType::F32)?
        .to_vec1::<f32>()?;
    crate::transfers::record_read(std::mem::size_of_val(values.as_slice()));
    Ok(values)
}
