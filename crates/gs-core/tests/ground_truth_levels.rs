//! The ground truth of a NeRF-synthetic (or D-NeRF) scene is INRIA 3DGS's: RGBA composited over
//! the background in float64 and cut to whole 8-bit levels. The oracle is
//! `fixtures/composite_8bit.bin`, written by `scripts/make_composite_fixture.py` with the
//! loader's own numpy lines, for every colour level and alpha over black and over white.

mod common;

use gs_core::dataset::nerf_synthetic::{self, Split};
use gs_core::dataset::{Background, GroundTruth, LoadOptions};
use gs_core::levels::composite_8bit;

const TABLES: &[u8] = include_bytes!("fixtures/composite_8bit.bin");

/// The authors' level of colour `c` at alpha `a` over black (`white == false`) or white.
fn authors_level(white: bool, a: usize, c: usize) -> u8 {
    TABLES[usize::from(white) * 65536 + a * 256 + c]
}

#[test]
fn every_colour_and_alpha_gives_the_authors_8_bit_level() {
    let mut truncated = 0;
    for (white, bg) in [(false, [0.0; 3]), (true, [1.0; 3])] {
        for a in 0..256 {
            for c in 0..256 {
                let want = authors_level(white, a, c);
                let got = composite_8bit([c as u8; 3], a as u8, bg);
                assert_eq!(got, [want; 3], "colour {c} alpha {a} white {white}");
                let exact = (c as f64 / 255.0 * (a as f64 / 255.0)
                    + f64::from(bg[0]) * (1.0 - a as f64 / 255.0))
                    * 255.0;
                truncated += usize::from(f64::from(want) < exact.round());
            }
        }
    }
    // The fixture covers the case it exists for: levels that rounding would put one higher.
    assert!(truncated > 10_000, "{truncated}");
}

/// A 256 x 256 RGBA picture whose pixel (x, y) is grey level x at alpha y, and a NeRF-synthetic
/// scene of one frame showing it.
fn write_scene(root: &std::path::Path) {
    let picture = image::RgbaImage::from_fn(256, 256, |x, y| {
        let (c, a) = (x as u8, y as u8);
        image::Rgba([c, c, c, a])
    });
    picture.save(root.join("r_0.png")).unwrap();
    common::write_one_frame_transforms(root);
}

#[test]
fn a_loaded_scene_holds_the_authors_levels_and_alpha_gives_the_mask() {
    let dir = tempfile::tempdir().unwrap();
    write_scene(dir.path());
    for (white, background) in [(false, Background::Black), (true, Background::White)] {
        let options = LoadOptions {
            background,
            downscale: 1,
            ..LoadOptions::default()
        };
        let data = nerf_synthetic::load(dir.path(), Split::Train, &options).unwrap();
        let image = &data.images[0];
        for a in 0..256u32 {
            for c in 0..256u32 {
                let want = f32::from(authors_level(white, a as usize, c as usize)) / 255.0;
                assert_eq!(image.pixel(c, a), [want; 3], "colour {c} alpha {a}");
            }
        }
        let mask = data.masks[0].as_ref().unwrap();
        assert!(
            mask.data[..256].iter().all(|&m| m == 1.0),
            "alpha 0 is background"
        );
        assert!(mask.data[256..].iter().all(|&m| m == 0.0));
    }
}

#[test]
fn file_colour_keeps_the_stored_colours_whatever_the_alpha_and_background() {
    let dir = tempfile::tempdir().unwrap();
    write_scene(dir.path());
    let options = LoadOptions {
        background: Background::White,
        ground_truth: GroundTruth::FileColour,
        downscale: 1,
        ..LoadOptions::default()
    };
    let data = nerf_synthetic::load(dir.path(), Split::Train, &options).unwrap();
    let image = &data.images[0];
    for a in [0u32, 1, 128, 254, 255] {
        for c in 0..256u32 {
            let want = c as f32 / 255.0;
            assert_eq!(image.pixel(c, a), [want; 3], "colour {c} alpha {a}");
        }
    }
    let mask = data.masks[0].as_ref().unwrap();
    assert_eq!(mask.background_count(), 256, "alpha still gives the mask");
}

#[test]
fn sixteen_bit_pictures_are_read_by_their_high_byte_as_pil_reads_them() {
    let dir = tempfile::tempdir().unwrap();
    // (value, alpha) pairs where the high byte and v / 65535 give different levels.
    let pixels: [(u16, u16); 4] = [
        (0xFF00, 0xFFFF),
        (0x0100, 0xFFFF),
        (0x80FF, 0x8000),
        (0xFFFF, 0x00FF),
    ];
    let picture = image::ImageBuffer::<image::Rgba<u16>, Vec<u16>>::from_fn(4, 1, |x, _| {
        let (v, a) = pixels[x as usize];
        image::Rgba([v, v, v, a])
    });
    picture.save(dir.path().join("r_0.png")).unwrap();
    common::write_one_frame_transforms(dir.path());
    for ground_truth in [GroundTruth::Composited, GroundTruth::FileColour] {
        let options = LoadOptions {
            background: Background::White,
            ground_truth,
            downscale: 1,
            ..LoadOptions::default()
        };
        let image = &nerf_synthetic::load(dir.path(), Split::Train, &options)
            .unwrap()
            .images[0];
        for (x, &(v, a)) in pixels.iter().enumerate() {
            let (c, a) = ((v >> 8) as usize, (a >> 8) as usize);
            let want = match ground_truth {
                GroundTruth::Composited => authors_level(true, a, c),
                GroundTruth::FileColour => c as u8,
            };
            let want = f32::from(want) / 255.0;
            assert_eq!(
                image.pixel(x as u32, 0),
                [want; 3],
                "{ground_truth:?} pixel {x}"
            );
        }
    }
}
