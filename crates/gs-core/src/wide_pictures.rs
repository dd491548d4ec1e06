//! The size rule of the authors' loaders for wide pictures: INRIA 3DGS's `loadCam` at its
//! default resolution (`-r -1`), which VeGaS, MiraGe and D-MiSo copy, shrinks a picture wider
//! than 1600 pixels to 1600 pixels wide with PIL's `Image.resize` (bicubic) of its 8-bit levels.

use crate::pil_resize::pil_bicubic_resize;
use crate::Image;

/// Width beyond which the authors' loaders shrink a picture, pixels.
pub const AUTHORS_MAX_WIDTH: u32 = 1600;

/// The size `loadCam` gives a `width x height` picture wider than `max_width`: with
/// `scale = width / max_width`, `(int(width / scale), int(height / scale))`, computed in `f64` as
/// Python does (at least one pixel high); a picture no wider, or any picture when `max_width` is
/// 0, keeps its size.
pub fn shrunk_size(width: u32, height: u32, max_width: u32) -> (u32, u32) {
    if width <= max_width || max_width == 0 {
        return (width, height);
    }
    let scale = f64::from(width) / f64::from(max_width);
    let shrink = |side: u32| ((f64::from(side) / scale) as u32).max(1);
    (shrink(width), shrink(height))
}

/// `image`, whose values are whole 8-bit levels / 255 (a loaded picture), shrunk to
/// [`shrunk_size`] by PIL's bicubic resize of its levels when it is wider than `max_width`;
/// unchanged when it is not, or when `max_width` is 0 (keep every size).
pub fn shrink_wide(image: Image, max_width: u32) -> Image {
    let (w, h) = (image.width as usize, image.height as usize);
    let (ow, oh) = shrunk_size(image.width, image.height, max_width);
    if (ow, oh) == (image.width, image.height) {
        return image;
    }
    let level = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    let mut planes = vec![0u8; 3 * w * h];
    for (p, rgb) in image.data.chunks_exact(3).enumerate() {
        for c in 0..3 {
            planes[c * w * h + p] = level(rgb[c]);
        }
    }
    let (ow, oh) = (ow as usize, oh as usize);
    let resized = pil_bicubic_resize(&planes, 3, (h, w), (oh, ow))
        .expect("three planes of a non-empty picture to a non-empty size");
    let mut data = Vec::with_capacity(3 * ow * oh);
    for p in 0..ow * oh {
        data.extend((0..3).map(|c| f32::from(resized[c * ow * oh + p]) / 255.0));
    }
    Image {
        width: ow as u32,
        height: oh as u32,
        data,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_follow_pythons_arithmetic() {
        assert_eq!(shrunk_size(1600, 900, 1600), (1600, 900));
        assert_eq!(shrunk_size(1920, 1080, 1600), (1600, 900));
        // 1080 / (1921 / 1600) = 899.53...: truncated.
        assert_eq!(shrunk_size(1921, 1080, 1600), (1600, 899));
        assert_eq!(
            shrunk_size(4000, 1, 1600),
            (1600, 1),
            "at least one pixel high"
        );
    }

    #[test]
    fn a_wide_picture_is_shrunk_by_pils_bicubic_and_others_are_kept() {
        let (w, h) = (1700u32, 6u32);
        let data: Vec<f32> = (0..w * h * 3)
            .map(|i| f32::from((i * 37 % 256) as u8) / 255.0)
            .collect();
        let image = Image {
            width: w,
            height: h,
            data,
        };
        assert_eq!(shrink_wide(image.clone(), 0), image);
        assert_eq!(shrink_wide(image.clone(), 2000), image);
        let shrunk = shrink_wide(image.clone(), AUTHORS_MAX_WIDTH);
        assert_eq!((shrunk.width, shrunk.height), (1600, 5));
        // The same as PIL's resize of the planes (pil_bicubic_resize is tested against Pillow).
        let planes: Vec<u8> = (0..3)
            .flat_map(|c| {
                image
                    .data
                    .chunks_exact(3)
                    .map(move |p| (p[c] * 255.0).round() as u8)
            })
            .collect();
        let want = pil_bicubic_resize(&planes, 3, (6, 1700), (5, 1600)).unwrap();
        for (p, rgb) in shrunk.data.chunks_exact(3).enumerate() {
            for c in 0..3 {
                assert_eq!(rgb[c], f32::from(want[c * 8000 + p]) / 255.0);
            }
        }
    }
}
