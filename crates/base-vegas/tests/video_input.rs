//! Reading a video: frame folders in natural order, and every bad input answered with an
//! error that names the file.

use std::path::Path;

use base_vegas::video_input::{load_video, VideoInputError, DEFAULT_FOLDER_FPS};
use gs_core::Image;

/// A `w x h` frame whose red channel is `value / 255`.
fn write_frame(path: &Path, w: u32, h: u32, value: u8) {
    let mut img = Image::filled(w, h, [value as f32 / 255.0, 0.5, 0.25]);
    img.data[0] = 1.0;
    img.save_png(path).unwrap();
}

#[test]
fn a_folder_of_frames_is_read_in_natural_order() {
    let dir = tempfile::tempdir().unwrap();
    for (name, value) in [("10.png", 10), ("9.png", 9), ("00001.png", 1), ("2.PNG", 2)] {
        write_frame(&dir.path().join(name), 20, 12, value);
    }
    std::fs::write(dir.path().join("notes.txt"), "not a frame").unwrap();
    let video = load_video(dir.path(), [0.0; 3], DEFAULT_FOLDER_FPS, 0).unwrap();
    assert_eq!(video.frames.len(), 4);
    assert_eq!(video.size(), (20, 12));
    assert_eq!(video.fps, DEFAULT_FOLDER_FPS);
    let reds: Vec<u8> = video
        .frames
        .iter()
        .map(|f| (f.data[3] * 255.0).round() as u8)
        .collect();
    assert_eq!(reds, vec![1, 2, 9, 10]);
    assert!(video.labels[3].ends_with("10.png"), "{:?}", video.labels);
}

fn error_of(path: &Path) -> String {
    let e = load_video(path, [0.0; 3], DEFAULT_FOLDER_FPS, 0).unwrap_err();
    e.to_string()
}

#[test]
fn bad_folders_are_answered_with_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let e = error_of(&empty);
    assert!(
        e.contains("empty") && e.contains("no PNG or JPEG frames"),
        "{e}"
    );

    let single = dir.path().join("single");
    std::fs::create_dir(&single).unwrap();
    write_frame(&single.join("0.png"), 16, 16, 3);
    let e = error_of(&single);
    assert!(
        e.contains("single frame") && e.contains("at least 2"),
        "{e}"
    );

    let sizes = dir.path().join("sizes");
    std::fs::create_dir(&sizes).unwrap();
    write_frame(&sizes.join("0.png"), 16, 16, 3);
    write_frame(&sizes.join("1.png"), 16, 16, 3);
    write_frame(&sizes.join("2.png"), 18, 16, 3);
    let e = error_of(&sizes);
    assert!(
        e.contains("2.png is 18x16") && e.contains("0.png) is 16x16"),
        "{e}"
    );

    let broken = dir.path().join("broken");
    std::fs::create_dir(&broken).unwrap();
    write_frame(&broken.join("0.png"), 16, 16, 3);
    std::fs::write(broken.join("1.jpg"), b"not a jpeg").unwrap();
    let e = error_of(&broken);
    assert!(e.starts_with("frame ") && e.contains("1.jpg"), "{e}");

    let e = error_of(&dir.path().join("nowhere"));
    assert!(e.contains("nowhere") && e.contains("no such file"), "{e}");

    let text = dir.path().join("clip.txt");
    std::fs::write(&text, "x").unwrap();
    let e = error_of(&text);
    assert!(e.contains("clip.txt") && e.contains("mp4"), "{e}");
}

/// A folder holding a PNG and a JPEG copy of the same frames is refused, naming both copies,
/// instead of being read as a video of twice the length.
#[test]
fn a_folder_of_one_frame_in_two_formats_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["0001.png", "0002.png", "0001.jpg", "0002.JPG"] {
        std::fs::write(dir.path().join(name), b"not decoded").unwrap();
    }
    let e = load_video(dir.path(), [0.0; 3], DEFAULT_FOLDER_FPS, 0).unwrap_err();
    assert!(matches!(e, VideoInputError::MixedFormats { .. }), "{e}");
    let text = e.to_string();
    assert!(
        text.contains("0001.jpg") && text.contains("0001.png") && text.contains("one format"),
        "{text}"
    );
}

/// A video file goes through ffmpeg: without it, the error names the program and the frames
/// alternative; with it, a file it cannot decode is its error, naming the file.
#[test]
fn a_video_file_needs_ffmpeg_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let clip = dir.path().join("clip.mp4");
    std::fs::write(&clip, b"not really an mp4").unwrap();
    let e = load_video(&clip, [0.0; 3], DEFAULT_FOLDER_FPS, 0).unwrap_err();
    let has_ffmpeg = std::process::Command::new("ffprobe")
        .arg("-version")
        .output()
        .is_ok();
    if has_ffmpeg {
        assert!(matches!(e, VideoInputError::Decoder { .. }), "{e}");
    } else {
        assert!(
            matches!(
                e,
                VideoInputError::MissingProgram {
                    program: "ffprobe",
                    ..
                }
            ),
            "{e}"
        );
        let text = e.to_string();
        assert!(
            text.contains("ffmpeg") && text.contains("folder of numbered"),
            "{text}"
        );
    }
    assert!(e.to_string().contains("clip.mp4"), "{e}");
}

/// Where ffmpeg is installed: frames written as an mp4 (`gs_stylize::animation::write_mp4`) read back
/// through ffmpeg with their count, size and frame rate. Where it is not, the mp4 is not
/// written and says so (`Ok(false)`).
#[test]
fn frames_round_trip_through_an_mp4_when_ffmpeg_is_installed() {
    use gs_stylize::animation::{write_frames, write_mp4};
    let dir = tempfile::tempdir().unwrap();
    let frames: Vec<Image> = (0..5)
        .map(|k| Image::filled(34, 20, [0.1 + 0.15 * k as f32, 0.5, 0.3]))
        .collect();
    let folder = dir.path().join("frames");
    write_frames(&folder, &frames).unwrap();
    let mp4 = dir.path().join("clip.mp4");
    let written = write_mp4(&folder, 12.0, &mp4).unwrap();
    let has_ffmpeg = std::process::Command::new("ffmpeg")
        .arg("-version")
        .output()
        .is_ok();
    assert_eq!(written, has_ffmpeg);
    if written {
        let video = load_video(&mp4, [0.0; 3], DEFAULT_FOLDER_FPS, 0).unwrap();
        assert_eq!(video.frames.len(), 5);
        assert_eq!(video.size(), (34, 20));
        assert!((video.fps - 12.0).abs() < 1e-9, "fps {}", video.fps);
        let red = (video.frames[4].data[0] * 255.0).round();
        assert!((red - (0.7f32 * 255.0).round()).abs() <= 6.0, "red {red}");
    } else {
        assert!(!mp4.exists());
    }
}

/// A 256 x 256 RGBA frame whose pixel (x, y) is grey level x at alpha y.
fn write_rgba_ramp(path: &Path) {
    image::RgbaImage::from_fn(256, 256, |x, y| {
        image::Rgba([x as u8, x as u8, x as u8, y as u8])
    })
    .save(path)
    .unwrap();
}

#[test]
fn transparent_frames_are_composited_and_cut_to_8_bits_as_vegas_reads_them() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["0.png", "1.png"] {
        write_rgba_ramp(&dir.path().join(name));
    }
    for background in [[0.0; 3], [1.0; 3]] {
        let video = load_video(dir.path(), background, DEFAULT_FOLDER_FPS, 0).unwrap();
        let frame = &video.frames[1];
        for (a, c) in [
            (0, 200),
            (1, 255),
            (77, 130),
            (128, 255),
            (254, 3),
            (255, 64),
        ] {
            let want = gs_core::levels::composite_8bit([c as u8; 3], a as u8, background)
                .map(|v| f32::from(v) / 255.0);
            assert_eq!(
                frame.pixel(c, a),
                want,
                "colour {c} alpha {a} over {background:?}"
            );
        }
    }
}

#[test]
fn frames_wider_than_the_limit_are_shrunk_as_vegas_shrinks_them() {
    let dir = tempfile::tempdir().unwrap();
    for (k, name) in ["0.png", "1.png"].iter().enumerate() {
        image::RgbImage::from_fn(1700, 9, |x, y| {
            let v = ((x * 7 + y * 13 + k as u32 * 5) % 256) as u8;
            image::Rgb([v, 255 - v, v / 2])
        })
        .save(dir.path().join(name))
        .unwrap();
    }
    let full = load_video(dir.path(), [0.0; 3], DEFAULT_FOLDER_FPS, 0).unwrap();
    assert_eq!(full.size(), (1700, 9));
    let shrunk = load_video(dir.path(), [0.0; 3], DEFAULT_FOLDER_FPS, 1600).unwrap();
    // int(9 / (1700 / 1600)) = 8.
    assert_eq!(shrunk.size(), (1600, 8));
    for (big, small) in full.frames.iter().zip(&shrunk.frames) {
        assert_eq!(
            *small,
            gs_core::wide_pictures::shrink_wide(big.clone(), 1600)
        );
    }
}
