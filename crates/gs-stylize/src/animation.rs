//! The files of a stylized sequence of frames (a video's frames, a dynamic scene seen through
//! time): the frames as PNG, an animated GIF preview (original beside stylized, written in
//! Rust), and an mp4 through the `ffmpeg` program when it is installed. Each is written under a
//! temporary name and renamed, so a failure leaves nothing half made.

use std::path::{Path, PathBuf};
use std::process::Command;

use gs_core::Image;
use image::codecs::gif::{GifEncoder, Repeat};
use image::{Delay, Frame, RgbaImage};

/// The folder of stylized frames in an output folder (`00000.png`, `00001.png`, ...).
pub const FRAMES_DIR: &str = "frames";
/// The animated preview: original and stylized side by side.
pub const PREVIEW_GIF: &str = "preview.gif";
/// The stylized video, when `ffmpeg` is installed.
pub const STYLIZED_MP4: &str = "stylized.mp4";

/// The widest preview, pixels (both halves together); wider videos are scaled down for it.
pub const PREVIEW_MAX_WIDTH: u32 = 960;

/// Why an output could not be written.
#[derive(Debug, thiserror::Error)]
#[error("{}: {message}", path.display())]
pub struct AnimationError {
    /// The file or folder.
    pub path: PathBuf,
    /// What went wrong.
    pub message: String,
}

fn error(path: &Path, message: impl ToString) -> AnimationError {
    AnimationError {
        path: path.to_path_buf(),
        message: message.to_string(),
    }
}

/// The name of frame `index` in a frames folder.
pub fn frame_name(index: usize) -> String {
    format!("{index:05}.png")
}

/// Writes `frames` as `dir/00000.png, ...`: into `<dir>.tmp` first, then renamed over `dir`
/// (a `dir` of an earlier run is replaced).
pub fn write_frames(dir: &Path, frames: &[Image]) -> Result<(), AnimationError> {
    write_frames_with(dir, frames.len(), |k| Ok(frames[k].clone()))
}

/// [`write_frames`] of `count` frames made one at a time by `frame(k)` and written as they
/// come, so no more than one is held; an error of `frame` stops the writing (the folder is then
/// left as it was).
pub fn write_frames_with(
    dir: &Path,
    count: usize,
    mut frame: impl FnMut(usize) -> Result<Image, Box<dyn std::error::Error + Send + Sync>>,
) -> Result<(), AnimationError> {
    let tmp = gs_core::fs::temporary_path(dir);
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(|e| error(&tmp, e))?;
    }
    std::fs::create_dir_all(&tmp).map_err(|e| error(&tmp, e))?;
    let written = (0..count).try_for_each(|k| {
        let image = frame(k).map_err(|e| error(&tmp, e))?;
        image
            .save_png(&tmp.join(frame_name(k)))
            .map_err(|e| error(&tmp, e))
    });
    if let Err(e) = written {
        // The half-written folder goes; `dir` is as it was.
        let _ = std::fs::remove_dir_all(&tmp);
        return Err(e);
    }
    if dir.exists() {
        std::fs::remove_dir_all(dir).map_err(|e| error(dir, e))?;
    }
    std::fs::rename(&tmp, dir).map_err(|e| error(dir, e))
}

/// Writes the animated preview of `originals` beside `stylized` (one pair per frame, all of one
/// size) at `fps`, looping, scaled down to [`PREVIEW_MAX_WIDTH`] when wider.
pub fn write_preview_gif(
    path: &Path,
    originals: &[Image],
    stylized: &[Image],
    fps: f64,
) -> Result<(), AnimationError> {
    let delay_ms = (1000.0 / fps.max(1e-3)).round().clamp(10.0, 60_000.0) as u32;
    let mut bytes = Vec::new();
    {
        let mut encoder = GifEncoder::new_with_speed(&mut bytes, 10);
        encoder
            .set_repeat(Repeat::Infinite)
            .map_err(|e| error(path, e))?;
        for (a, b) in originals.iter().zip(stylized) {
            let pair = Image::side_by_side(&[a, b]).to_rgb8();
            let scale = (PREVIEW_MAX_WIDTH as f64 / pair.width() as f64).min(1.0);
            let rgb = if scale < 1.0 {
                let (w, h) = (
                    ((pair.width() as f64 * scale).round() as u32).max(1),
                    ((pair.height() as f64 * scale).round() as u32).max(1),
                );
                image::imageops::resize(&pair, w, h, image::imageops::FilterType::Triangle)
            } else {
                pair
            };
            let rgba: RgbaImage = image::DynamicImage::ImageRgb8(rgb).to_rgba8();
            let frame = Frame::from_parts(rgba, 0, 0, Delay::from_numer_denom_ms(delay_ms, 1));
            encoder.encode_frame(frame).map_err(|e| error(path, e))?;
        }
    }
    gs_core::fs::write_atomic(path, &bytes).map_err(|e| error(path, e))
}

/// Encodes the frames of `frames_dir` (as [`write_frames`] names them) at `fps` into the mp4
/// `path` (H.264, even-sized, `yuv420p` for any player) with `ffmpeg`: `Ok(false)` when
/// `ffmpeg` is not installed (an older file at `path` is then removed, so that it cannot be
/// taken for this video's), an error with its message when it fails.
pub fn write_mp4(frames_dir: &Path, fps: f64, path: &Path) -> Result<bool, AnimationError> {
    let tmp = gs_core::fs::temporary_path(path).with_extension("tmp.mp4");
    let out = Command::new("ffmpeg")
        .args(["-nostdin", "-y", "-v", "error", "-framerate"])
        .arg(format!("{fps}"))
        .arg("-i")
        .arg(frames_dir.join("%05d.png"))
        .args([
            "-vf",
            "pad=ceil(iw/2)*2:ceil(ih/2)*2",
            "-pix_fmt",
            "yuv420p",
        ])
        .arg(&tmp)
        .output();
    let out = match out {
        Ok(out) => out,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            if path.exists() {
                std::fs::remove_file(path).map_err(|e| error(path, e))?;
            }
            return Ok(false);
        }
        Err(e) => return Err(error(path, format!("ffmpeg: {e}"))),
    };
    if !out.status.success() {
        let _ = std::fs::remove_file(&tmp);
        return Err(error(
            path,
            format!(
                "ffmpeg failed: {}",
                String::from_utf8_lossy(&out.stderr).trim()
            ),
        ));
    }
    std::fs::rename(&tmp, path).map_err(|e| error(path, e))?;
    Ok(true)
}

/// [`write_mp4`] after a run whose frames (in `frames_dir`) are its results: a failure is a
/// warning on stderr naming the frames, not an error. Whether the mp4 was written.
pub fn write_mp4_or_warn(frames_dir: &Path, fps: f64, path: &Path) -> bool {
    match write_mp4(frames_dir, fps, path) {
        Ok(wrote) => wrote,
        Err(e) => {
            eprintln!("warning: {e}; the frames are in {}", frames_dir.display());
            false
        }
    }
}

#[cfg(test)]
mod tests {
    use image::AnimationDecoder;

    use super::*;

    /// Frames made one at a time are written in order; a frame that fails leaves no folder
    /// and no temporary one behind, and an existing folder as it was.
    #[test]
    fn frames_made_one_at_a_time_are_written_or_nothing_is() {
        let dir = tempfile::tempdir().unwrap();
        let frames = dir.path().join("frames");
        let grey = |k: usize| Image {
            width: 3,
            height: 2,
            data: vec![k as f32 / 4.0; 18],
        };
        write_frames_with(&frames, 3, |k| Ok(grey(k))).unwrap();
        let names: Vec<String> = (0..3).map(frame_name).collect();
        for (k, name) in names.iter().enumerate() {
            let back = Image::load(&frames.join(name), [0.0; 3]).unwrap();
            assert!((back.data[0] - k as f32 / 4.0).abs() < 1.0 / 255.0);
        }
        let e = write_frames_with(&frames, 5, |k| {
            if k == 2 {
                Err("frame 2 cannot be rendered".into())
            } else {
                Ok(grey(k))
            }
        })
        .unwrap_err();
        assert!(e.to_string().contains("frame 2 cannot be rendered"), "{e}");
        assert!(!gs_core::fs::temporary_path(&frames).exists());
        assert_eq!(std::fs::read_dir(&frames).unwrap().count(), 3, "as it was");
    }

    fn frames(n: usize, w: u32, h: u32, base: f32) -> Vec<Image> {
        (0..n)
            .map(|k| Image::filled(w, h, [base, k as f32 / n as f32, 0.5]))
            .collect()
    }

    #[test]
    fn frames_are_written_in_order_and_replace_an_older_folder() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join(FRAMES_DIR);
        write_frames(&out, &frames(5, 8, 6, 0.2)).unwrap();
        write_frames(&out, &frames(3, 8, 6, 0.2)).unwrap();
        let mut names: Vec<String> = std::fs::read_dir(&out)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(names, ["00000.png", "00001.png", "00002.png"]);
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            1,
            "no temporary folder"
        );
    }

    #[test]
    fn the_preview_is_an_animated_gif_of_both_halves() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(PREVIEW_GIF);
        write_preview_gif(&path, &frames(4, 10, 8, 0.0), &frames(4, 10, 8, 1.0), 12.5).unwrap();
        let decoder = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(
            std::fs::File::open(&path).unwrap(),
        ))
        .unwrap();
        let decoded = decoder.into_frames().collect_frames().unwrap();
        assert_eq!(decoded.len(), 4);
        let first = decoded[0].buffer();
        assert_eq!(first.dimensions(), (20, 8));
        assert!(
            first.get_pixel(2, 2).0[0] < 30 && first.get_pixel(15, 2).0[0] > 225,
            "original left, stylized right"
        );
        assert_eq!(decoded[1].delay().numer_denom_ms(), (80, 1));
    }

    #[test]
    fn a_wide_preview_is_scaled_down() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(PREVIEW_GIF);
        write_preview_gif(
            &path,
            &frames(2, 700, 40, 0.0),
            &frames(2, 700, 40, 1.0),
            24.0,
        )
        .unwrap();
        let decoder = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(
            std::fs::File::open(&path).unwrap(),
        ))
        .unwrap();
        let decoded = decoder.into_frames().collect_frames().unwrap();
        assert_eq!(decoded[0].buffer().dimensions(), (PREVIEW_MAX_WIDTH, 27));
    }
}
