//! The video a user gives: a folder of numbered frames (PNG or JPEG, as DAVIS ships them,
//! sorted naturally so that `9.png` comes before `10.png`), or a video file (mp4, webm, mov,
//! mkv, avi) decoded by the `ffmpeg` program. Transparent pixels are composited over the
//! background and the result cut to whole 8-bit levels, and frames wider than 1600 pixels are
//! shrunk to 1600 (unless asked otherwise), as VeGaS reads its frames.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicUsize, Ordering};

use gs_core::dataset::ImageProgress;
use gs_core::wide_pictures::shrink_wide;
use gs_core::{GsError, Image};
use rayon::prelude::*;

/// Frame rate given to a folder of frames when none is asked for, frames per second.
pub const DEFAULT_FOLDER_FPS: f64 = 24.0;

/// File extensions read as frames (compared without case).
pub const FRAME_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

/// File extensions read as video files through `ffmpeg` (compared without case).
pub const VIDEO_EXTENSIONS: [&str; 5] = ["mp4", "webm", "mov", "mkv", "avi"];

/// The frames of a video, all of one size.
#[derive(Clone, Debug, PartialEq)]
pub struct Video {
    /// The frames in order, linear RGB in `[0, 1]`.
    pub frames: Vec<Image>,
    /// Where each frame came from (its file, or `<video file> frame <k>`), for messages.
    pub labels: Vec<String>,
    /// Frames per second (the file's, or the one given for a folder).
    pub fps: f64,
}

impl Video {
    /// Width and height of every frame, pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.frames[0].width, self.frames[0].height)
    }
}

/// Why a video cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum VideoInputError {
    /// Nothing at the path.
    #[error("video {}: no such file or folder", .0.display())]
    Missing(PathBuf),
    /// A file that is neither a frame folder nor a video of a known kind.
    #[error("video {}: not a folder of frames nor a video file ({})", .0.display(), VIDEO_EXTENSIONS.join(", "))]
    UnknownKind(PathBuf),
    /// A folder without frames.
    #[error("video {}: the folder holds no PNG or JPEG frames", .0.display())]
    Empty(PathBuf),
    /// A single frame: VeGaS needs at least two to learn times.
    #[error("video {}: it has a single frame; a video needs at least 2 (use clipgaussian-2d for a picture)", .0.display())]
    SingleFrame(PathBuf),
    /// A frame that cannot be read or decoded.
    #[error("frame {label}: {source}")]
    Unreadable {
        /// The frame.
        label: String,
        /// Why.
        source: GsError,
    },
    /// A frame whose size differs from the first one's.
    #[error("frame {label} is {}x{}, but the first frame ({first}) is {}x{}; every frame must have the same size", .size.0, .size.1, .first_size.0, .first_size.1)]
    SizeMismatch {
        /// The frame.
        label: String,
        /// Its size.
        size: (u32, u32),
        /// The first frame.
        first: String,
        /// The first frame's size.
        first_size: (u32, u32),
    },
    /// A video file, and no `ffmpeg` or `ffprobe` program to read it.
    #[error("video {}: reading a video file needs the {program} program, which is not on PATH; install FFmpeg (it brings ffmpeg and ffprobe), or give a folder of numbered PNG or JPEG frames instead", path.display())]
    MissingProgram {
        /// The video file.
        path: PathBuf,
        /// `ffmpeg` or `ffprobe`.
        program: &'static str,
    },
    /// A folder holding two frames of the same number (a PNG and a JPEG copy of the frames).
    #[error("video {}: {} and {} are the same frame in two formats; keep one format in the folder", dir.display(), first.display(), second.display())]
    MixedFormats {
        /// The folder.
        dir: PathBuf,
        /// One copy of the frame.
        first: PathBuf,
        /// The other.
        second: PathBuf,
    },
    /// `ffmpeg` or `ffprobe` failed on the file.
    #[error("video {}: {program} failed: {message}", path.display())]
    Decoder {
        /// The video file.
        path: PathBuf,
        /// `ffmpeg` or `ffprobe`.
        program: &'static str,
        /// What it said.
        message: String,
    },
    /// A folder or temporary file that could not be read or made.
    #[error("{}: {source}", path.display())]
    Io {
        /// The path.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
}

/// Reads the video at `path` (a frame folder, or a video file through `ffmpeg`); transparent
/// pixels go over `background`; frames wider than `max_width` (0: none) are shrunk as VeGaS's
/// loader shrinks them ([`shrink_wide`]). A folder's frames play at `folder_fps`.
pub fn load_video(
    path: &Path,
    background: [f32; 3],
    folder_fps: f64,
    max_width: u32,
) -> Result<Video, VideoInputError> {
    load_video_with_progress(path, background, folder_fps, max_width, None)
}

/// [`load_video`], each frame told to `progress` as it is decoded.
pub fn load_video_with_progress(
    path: &Path,
    background: [f32; 3],
    folder_fps: f64,
    max_width: u32,
    progress: Option<&ImageProgress>,
) -> Result<Video, VideoInputError> {
    let mut video = read_video(path, background, folder_fps, progress)?;
    video.frames = std::mem::take(&mut video.frames)
        .into_par_iter()
        .map(|f| shrink_wide(f, max_width))
        .collect();
    Ok(video)
}

/// [`load_video`] at the frames' own size.
fn read_video(
    path: &Path,
    background: [f32; 3],
    folder_fps: f64,
    progress: Option<&ImageProgress>,
) -> Result<Video, VideoInputError> {
    if path.is_dir() {
        let files = frame_files(path)?;
        let video = decode_frames(&files, background, folder_fps, progress, |f| {
            f.display().to_string()
        })?;
        return check_count(video, path);
    }
    if !path.exists() {
        return Err(VideoInputError::Missing(path.to_path_buf()));
    }
    if !has_extension(path, &VIDEO_EXTENSIONS) {
        return Err(VideoInputError::UnknownKind(path.to_path_buf()));
    }
    let fps = probe_fps(path)?;
    let dir = tempfile::tempdir().map_err(|source| VideoInputError::Io {
        path: std::env::temp_dir(),
        source,
    })?;
    run_tool(
        path,
        "ffmpeg",
        Command::new("ffmpeg")
            .args(["-nostdin", "-v", "error", "-i"])
            .arg(path)
            .args(sync_option(&ffmpeg_version(path)?))
            .args(["-pix_fmt", "rgb24"])
            .arg(dir.path().join("%06d.png")),
    )?;
    let files = frame_files(dir.path())?;
    let video = decode_frames(&files, background, fps, progress, |f| {
        let stem = f
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        format!("{} frame {}", path.display(), stem.trim_start_matches('0'))
    })?;
    check_count(video, path)
}

/// The frame files of `dir` in natural order; an error when there are none.
pub fn frame_files(dir: &Path) -> Result<Vec<PathBuf>, VideoInputError> {
    let io = |source| VideoInputError::Io {
        path: dir.to_path_buf(),
        source,
    };
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let path = entry.map_err(io)?.path();
        if path.is_file() && has_extension(&path, &FRAME_EXTENSIONS) {
            files.push(path);
        }
    }
    if files.is_empty() {
        return Err(VideoInputError::Empty(dir.to_path_buf()));
    }
    files.sort_by(|a, b| {
        let name = |p: &PathBuf| p.file_name().map(|n| n.to_string_lossy().into_owned());
        natord::compare(&name(a).unwrap_or_default(), &name(b).unwrap_or_default())
    });
    let stem = |p: &PathBuf| p.file_stem().map(|s| s.to_ascii_lowercase());
    let mut by_stem: Vec<&PathBuf> = files.iter().collect();
    by_stem.sort_by_key(|p| stem(p));
    if let Some(pair) = by_stem.windows(2).find(|w| stem(w[0]) == stem(w[1])) {
        return Err(VideoInputError::MixedFormats {
            dir: dir.to_path_buf(),
            first: pair[0].clone(),
            second: pair[1].clone(),
        });
    }
    Ok(files)
}

/// Decodes `files` in parallel, telling `progress` of each, after checking from their headers
/// that every frame has the first one's size.
fn decode_frames(
    files: &[PathBuf],
    background: [f32; 3],
    fps: f64,
    progress: Option<&ImageProgress>,
    label: impl Fn(&Path) -> String + Sync,
) -> Result<Video, VideoInputError> {
    let labels: Vec<String> = files.iter().map(|f| label(f)).collect();
    // Every frame's size from its header first: a frame of another size is refused before
    // any frame is decoded.
    let sizes = files
        .par_iter()
        .zip(&labels)
        .map(|(f, l)| {
            gs_core::image::picture_size(f).map_err(|source| VideoInputError::Unreadable {
                label: l.clone(),
                source,
            })
        })
        .collect::<Result<Vec<(u32, u32)>, _>>()?;
    if let Some(k) = sizes.iter().position(|&s| s != sizes[0]) {
        return Err(VideoInputError::SizeMismatch {
            label: labels[k].clone(),
            size: sizes[k],
            first: labels[0].clone(),
            first_size: sizes[0],
        });
    }
    let done = AtomicUsize::new(0);
    let frames = files
        .par_iter()
        .zip(&labels)
        .map(|(f, l)| {
            let frame = Image::load_8bit_composite(f, background).map_err(|source| {
                VideoInputError::Unreadable {
                    label: l.clone(),
                    source,
                }
            });
            if let Some(progress) = progress {
                progress.report(done.fetch_add(1, Ordering::Relaxed) + 1, files.len());
            }
            frame
        })
        .collect::<Result<Vec<Image>, _>>()?;
    Ok(Video {
        frames,
        labels,
        fps,
    })
}

/// `video` when it has at least two frames.
fn check_count(video: Video, path: &Path) -> Result<Video, VideoInputError> {
    if video.frames.len() < 2 {
        return Err(VideoInputError::SingleFrame(path.to_path_buf()));
    }
    Ok(video)
}

/// The first line of `ffmpeg -version` (`ffmpeg version 6.1.1 ...`), run for the file `path`
/// (errors name it).
fn ffmpeg_version(path: &Path) -> Result<String, VideoInputError> {
    let text = run_tool(path, "ffmpeg", Command::new("ffmpeg").arg("-version"))?;
    Ok(text.lines().next().unwrap_or_default().to_string())
}

/// The option that keeps every decoded frame as it is (no frame dropped or duplicated) for the
/// ffmpeg whose `-version` line is `version_line`: `-fps_mode passthrough` from FFmpeg 5.1 on,
/// where `-vsync` is deprecated (and gone in 7), `-vsync passthrough` before. A version that
/// does not parse as `N.M` (a git build, `N-12345-g...`) is taken as a recent one.
fn sync_option(version_line: &str) -> [&'static str; 2] {
    let version = version_line
        .split_whitespace()
        .skip_while(|w| *w != "version")
        .nth(1)
        .unwrap_or_default()
        .trim_start_matches('n');
    let mut numbers = version
        .split(|c: char| !c.is_ascii_digit())
        .map(|n| n.parse::<u32>().ok());
    let (major, minor) = (numbers.next().flatten(), numbers.next().flatten());
    let old = match (major, minor) {
        (Some(major), Some(minor)) if version.starts_with(|c: char| c.is_ascii_digit()) => {
            (major, minor) < (5, 1)
        }
        _ => false,
    };
    if old {
        ["-vsync", "passthrough"]
    } else {
        ["-fps_mode", "passthrough"]
    }
}

/// The frame rate of the first video stream of `path`, by `ffprobe`: its average rate, or its
/// base rate where a container reports no average (`0/0`).
fn probe_fps(path: &Path) -> Result<f64, VideoInputError> {
    let out = run_tool(
        path,
        "ffprobe",
        Command::new("ffprobe")
            .args(["-v", "error", "-select_streams", "v:0"])
            .args([
                "-show_entries",
                "stream=avg_frame_rate,r_frame_rate",
                "-of",
                "csv=p=0",
            ])
            .arg(path),
    )?;
    let text = out.trim();
    let rate = |field: &str| -> Option<f64> {
        let r = match field.trim().split_once('/') {
            Some((n, d)) => n.parse::<f64>().ok()? / d.parse::<f64>().ok()?,
            None => field.trim().parse::<f64>().ok()?,
        };
        (r.is_finite() && r > 0.0).then_some(r)
    };
    // ffprobe prints the fields in its own order (r_frame_rate first); prefer the average.
    let fields: Vec<&str> = text.lines().next().unwrap_or("").split(',').collect();
    let (base, average) = (fields.first().copied(), fields.get(1).copied());
    average
        .and_then(rate)
        .or_else(|| base.and_then(rate))
        .ok_or_else(|| VideoInputError::Decoder {
            path: path.to_path_buf(),
            program: "ffprobe",
            message: format!("no frame rate in its answer {text:?}"),
        })
}

/// Runs `command` (the program `program`) on the video `path`: its standard output, or an
/// error naming the program (missing, or failed with its message).
fn run_tool(
    path: &Path,
    program: &'static str,
    command: &mut Command,
) -> Result<String, VideoInputError> {
    let out = command.output().map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => VideoInputError::MissingProgram {
            path: path.to_path_buf(),
            program,
        },
        _ => VideoInputError::Decoder {
            path: path.to_path_buf(),
            program,
            message: e.to_string(),
        },
    })?;
    if !out.status.success() {
        return Err(VideoInputError::Decoder {
            path: path.to_path_buf(),
            program,
            message: String::from_utf8_lossy(&out.stderr).trim().to_string(),
        });
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// Whether the extension of `path` is one of `extensions`, ignoring case.
fn has_extension(path: &Path, extensions: &[&str]) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| extensions.iter().any(|x| x.eq_ignore_ascii_case(e)))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// FFmpeg 4.4 to 9 as they print their version: `-vsync` before 5.1, `-fps_mode` since
    /// (7 removed `-vsync`), and a git build taken as recent.
    #[test]
    fn the_frame_sync_option_follows_the_ffmpeg_version() {
        for (line, option) in [
            (
                "ffmpeg version 4.4.2-0ubuntu0.22.04.1 Copyright (c) 2000-2021",
                "-vsync",
            ),
            ("ffmpeg version 5.0.3 Copyright", "-vsync"),
            ("ffmpeg version 5.1.6-0+deb12u1 Copyright", "-fps_mode"),
            ("ffmpeg version 6.1.1-3ubuntu5 Copyright", "-fps_mode"),
            ("ffmpeg version n7.1 Copyright", "-fps_mode"),
            ("ffmpeg version 8.0 Copyright", "-fps_mode"),
            ("ffmpeg version N-117563-g5b5a5d5 Copyright", "-fps_mode"),
            ("", "-fps_mode"),
        ] {
            assert_eq!(sync_option(line), [option, "passthrough"], "{line}");
        }
    }

    /// A frame of another size is refused from the headers, naming it and the first frame;
    /// the frames are not decoded (a frame whose body is broken but whose header is of another
    /// size gives the size error, not a decoding one).
    #[test]
    fn a_frame_of_another_size_is_refused_before_decoding() {
        let dir = tempfile::tempdir().unwrap();
        for f in 1..=4u32 {
            let (w, h) = if f == 3 { (20, 16) } else { (24, 16) };
            image::RgbImage::from_pixel(w, h, image::Rgb([10, 20, 30]))
                .save(dir.path().join(format!("{f}.png")))
                .unwrap();
        }
        // Frame 3's body cut short: decoding it would fail, its header still reads.
        let third = dir.path().join("3.png");
        let bytes = std::fs::read(&third).unwrap();
        std::fs::write(&third, &bytes[..bytes.len() - 20]).unwrap();
        match load_video(dir.path(), [0.0; 3], 24.0, 0) {
            Err(VideoInputError::SizeMismatch {
                label,
                size,
                first,
                first_size,
            }) => {
                assert!(
                    label.contains("3.png") && first.contains("1.png"),
                    "{label} {first}"
                );
                assert_eq!((size, first_size), ((20, 16), (24, 16)));
            }
            other => panic!("expected the size error, got {other:?}"),
        }
    }
}
