//! The files of a run: the loss log, the resolved configuration, before/after pictures. Every
//! file is written through [`gs_core::fs`] (a temporary name, an fsync and a rename), so a
//! reader never sees half a file.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use gs_core::model::View;
use gs_core::train::StepReport;
use gs_core::Image;
use gs_wgpu::backend::Backend;
use gs_wgpu::GpuModel;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::StylizeError;

/// The per-step losses in the output folder.
pub const LOSSES_JSON: &str = "losses.json";
/// The plot of the total loss in the output folder.
pub const LOSSES_PNG: &str = "losses.png";
/// The resolved configuration in the output folder.
pub const CONFIG_JSON: &str = "config.json";
/// What the fit of the base model did, when the run fitted it ([`FitReport`]).
pub const FIT_JSON: &str = "fit.json";
/// The folder of the views' cached ground truth past `view_cache_mb`, there only while a run
/// is going on.
pub const VIEW_CACHE_DIR: &str = "view_cache";

/// What a run's fit of its base model did (`fit.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FitReport {
    /// Steps of the fit.
    pub steps: u64,
    /// Its wall time, seconds.
    pub seconds: f64,
    /// The fitted model's mean PSNR over the training views, dB, where the modality measures
    /// it.
    pub psnr_db: Option<f64>,
    /// Gaussians of the fitted model (absent from files written before it was recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gaussians: Option<usize>,
    /// The fitted model's mean PSNR over the held-out test views, dB, when the fit held some
    /// out.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub test_psnr_db: Option<f64>,
}

/// The losses of one step.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StepLosses {
    /// The step, 1-based.
    pub step: u64,
    /// The view it used.
    pub view: usize,
    /// The total loss.
    pub total: f32,
    /// Every weighted term by name (`directional`, `patch`, `content`, `background`).
    pub terms: BTreeMap<String, f32>,
}

impl StepLosses {
    /// The losses of a training step's report.
    pub fn from_report(report: &StepReport) -> Self {
        Self {
            step: report.step,
            view: report.view,
            total: report.value.loss,
            terms: report.value.terms.iter().cloned().collect(),
        }
    }
}

/// The before/after picture every modality writes: the original and the stylized result side
/// by side (the first preview view in 3D, the first frame in video and 4D, the picture in 2D).
pub const PREVIEW_PNG: &str = "preview.png";
/// The plot of a fit's PSNR against the step, in an output folder.
pub const FIT_PSNR_PNG: &str = "fit_psnr.png";

/// The name of the before/after picture of the `k`-th preview view, view `view`: [`PREVIEW_PNG`]
/// for the first, `preview_view{view:03}.png` for the others.
pub fn preview_name(k: usize, view: usize) -> String {
    if k == 0 {
        PREVIEW_PNG.to_string()
    } else {
        format!("preview_view{view:03}.png")
    }
}

/// Creates the folder `path` and its parents (nothing when it exists); the error keeps the
/// file system's and names the folder.
pub fn create_folder(path: &Path) -> Result<(), StylizeError> {
    std::fs::create_dir_all(path).map_err(|source| StylizeError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Runs `write`, which creates the folder `out` or writes into it; when it fails and `out` did
/// not exist before, removes `out` with all in it, so a failed command leaves nothing behind
/// (a folder that was there before is left as it is).
pub fn into_new_folder<T, E>(out: &Path, write: impl FnOnce() -> Result<T, E>) -> Result<T, E> {
    into_new_folder_unless(out, |_| false, write)
}

/// [`into_new_folder`], except that a failed `write` whose folder `keep` says is worth keeping
/// (a stylization that saved a checkpoint to resume from) leaves it.
pub fn into_new_folder_unless<T, E>(
    out: &Path,
    keep: impl FnOnce(&Path) -> bool,
    write: impl FnOnce() -> Result<T, E>,
) -> Result<T, E> {
    // A dangling link is there (the user's), though `exists` says no.
    let made = std::fs::symlink_metadata(out).is_err();
    let result = write();
    if result.is_err() && made && !keep(out) {
        let _ = std::fs::remove_dir_all(out);
    }
    result
}

/// Writes `before` and `after` side by side to `path`.
pub fn write_pair(path: &Path, before: &Image, after: &Image) -> Result<(), StylizeError> {
    Ok(Image::side_by_side(&[before, after]).save_png(path)?)
}

/// Writes `bytes` to `path` through [`gs_core::fs::write_atomic`].
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), StylizeError> {
    gs_core::fs::write_atomic(path, bytes).map_err(|source| StylizeError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Writes `value` as pretty JSON to `path` (atomically).
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), StylizeError> {
    let text = serde_json::to_string_pretty(value).expect("plain data serializes");
    write_atomic(path, text.as_bytes())
}

/// Reads JSON written by [`write_json`].
pub fn read_json<T: DeserializeOwned>(path: &Path) -> Result<T, StylizeError> {
    let text = std::fs::read_to_string(path).map_err(|source| StylizeError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    serde_json::from_str(&text).map_err(|e| StylizeError::Io {
        path: path.to_path_buf(),
        source: std::io::Error::new(std::io::ErrorKind::InvalidData, e),
    })
}

/// Writes `before` and `after` side by side as the preview of the `k`-th preview view, view
/// `view`, in `dir` ([`preview_name`]); returns the file.
pub fn write_preview(
    dir: &Path,
    k: usize,
    view: usize,
    before: &Image,
    after: &Image,
) -> Result<PathBuf, StylizeError> {
    let path = dir.join(preview_name(k, view));
    write_pair(&path, before, after)?;
    Ok(path)
}

/// Renders `before` and `after` on `backend` from each of the views `which` over `background`
/// (through each model's own forward) and writes their previews in `dir` ([`write_preview`]);
/// returns the files.
pub fn write_previews<M: GpuModel>(
    dir: &Path,
    before: &mut M,
    after: &mut M,
    views: &[View],
    which: &[usize],
    background: [f32; 3],
    backend: &Backend,
) -> Result<Vec<PathBuf>, StylizeError> {
    let chosen: Vec<(usize, &View)> = which
        .iter()
        .map(|&v| {
            views.get(v).map(|view| (v, view)).ok_or_else(|| {
                StylizeError::Input(format!(
                    "preview view {v} does not exist (there are {})",
                    views.len()
                ))
            })
        })
        .collect::<Result<_, _>>()?;
    let render_all = |model: &mut M| -> Result<Vec<Image>, StylizeError> {
        let mut renderer = backend.model_renderer(model)?;
        chosen
            .iter()
            .map(|(_, view)| Ok(renderer.render(view, background)?))
            .collect()
    };
    let (befores, afters) = (render_all(before)?, render_all(after)?);
    chosen
        .iter()
        .zip(befores.iter().zip(&afters))
        .enumerate()
        .map(|(k, ((v, _), (b, a)))| write_preview(dir, k, *v, b, a))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_write_removes_only_the_folder_it_made_and_not_one_worth_keeping() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        let write = |out: &Path| -> Result<(), String> {
            std::fs::create_dir_all(out.join("frames")).unwrap();
            std::fs::write(out.join("frames/00000.png"), b"half").unwrap();
            Err("disk full".into())
        };
        assert!(into_new_folder(&out, || write(&out)).is_err());
        assert!(!out.exists(), "the folder this run made is gone");

        std::fs::create_dir(&out).unwrap();
        std::fs::write(out.join("mine.txt"), b"the user's").unwrap();
        assert!(into_new_folder(&out, || write(&out)).is_err());
        assert!(
            out.join("mine.txt").exists(),
            "a folder that was there stays"
        );

        let other = dir.path().join("resumable");
        let kept = into_new_folder_unless(&other, |o| o.join("frames").is_dir(), || write(&other));
        assert!(kept.is_err() && other.join("frames/00000.png").exists());
        let done = into_new_folder(&dir.path().join("fine"), || Ok::<_, String>(7));
        assert_eq!(done, Ok(7));
    }
}
