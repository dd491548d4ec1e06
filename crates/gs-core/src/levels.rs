//! A picture's 8-bit levels as PIL reads them, and the 8-bit alpha composite of the authors'
//! loaders: what the ground truth of a dataset ([`crate::dataset`]) and a picture read alone
//! ([`crate::Image::load_8bit_composite`], [`crate::Image::load_stored_colours`]) are made of.

/// One pixel of 8-bit levels (as PIL reads every file) composited as INRIA
/// 3DGS's `readCamerasFromTransforms` does it: `arr = (c / 255) (a / 255) + bg (1 - a / 255)` in
/// `f64`, then `np.array(arr * 255.0, dtype=np.byte)`, which truncates towards zero, so
/// `floor(arr * 255)`, a whole level in `0..=255`.
pub fn composite_8bit(rgb: [u8; 3], alpha: u8, background: [f32; 3]) -> [u8; 3] {
    let a = f64::from(alpha) / 255.0;
    // `arr` lies in [0, 1]; the cast saturates at the ends.
    let level = |c: usize| {
        let arr = (f64::from(rgb[c]) / 255.0) * a + f64::from(background[c]) * (1.0 - a);
        (arr * 255.0).floor() as u8
    };
    [level(0), level(1), level(2)]
}

/// 8-bit levels as values in `[0, 1]` (level / 255).
pub(crate) fn as_unit_values(levels: &image::RgbaImage) -> image::Rgba32FImage {
    image::Rgba32FImage::from_fn(levels.width(), levels.height(), |x, y| {
        image::Rgba(levels.get_pixel(x, y).0.map(|v| f32::from(v) / 255.0))
    })
}

/// The picture's 8-bit RGBA levels as PIL reads it: 8-bit files as they are; 16-bit RGB, RGBA
/// and grey-alpha files by the high byte of each value (PIL's `RGB;16B` unpacking); 16-bit grey
/// clipped to 255 (PIL's `I;16` converted to RGBA); other formats through the image crate.
pub(crate) fn pil_levels(decoded: &image::DynamicImage) -> image::RgbaImage {
    use image::DynamicImage as D;
    let high_byte = |v: u16| (v >> 8) as u8;
    match decoded {
        D::ImageRgb16(_) | D::ImageRgba16(_) | D::ImageLumaA16(_) => {
            let wide = decoded.to_rgba16();
            image::RgbaImage::from_fn(wide.width(), wide.height(), |x, y| {
                image::Rgba(wide.get_pixel(x, y).0.map(high_byte))
            })
        }
        D::ImageLuma16(grey) => image::RgbaImage::from_fn(grey.width(), grey.height(), |x, y| {
            let v = grey.get_pixel(x, y).0[0].min(255) as u8;
            image::Rgba([v, v, v, 255])
        }),
        _ => decoded.to_rgba8(),
    }
}

/// The stored colours and alpha of `decoded` as PIL's levels ([`pil_levels`]) / 255.
pub(crate) fn stored_levels(decoded: &image::DynamicImage) -> image::Rgba32FImage {
    as_unit_values(&pil_levels(decoded))
}

/// `decoded`'s levels as PIL reads them ([`pil_levels`]) composited over `background` by
/// [`composite_8bit`], the file's alpha kept for the mask.
pub(crate) fn composited_levels(
    decoded: &image::DynamicImage,
    background: [f32; 3],
) -> image::RgbaImage {
    let mut levels = pil_levels(decoded);
    for p in levels.pixels_mut() {
        let [r, g, b, a] = p.0;
        let [r, g, b] = composite_8bit([r, g, b], a, background);
        *p = image::Rgba([r, g, b, a]);
    }
    levels
}

/// `decoded` composited over `background` by [`composite_8bit`] from its levels as PIL reads
/// them ([`pil_levels`]), as `f32` levels / 255 with the file's alpha kept for the mask.
pub(crate) fn composited_8bit(
    decoded: &image::DynamicImage,
    background: [f32; 3],
) -> image::Rgba32FImage {
    as_unit_values(&composited_levels(decoded, background))
}
