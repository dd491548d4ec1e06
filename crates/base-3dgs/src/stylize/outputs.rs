//! The files of a run: the loss log, the resolved configuration, before/after pictures. Every
//! file is written under a temporary name beside its final one and renamed, so a reader never
//! sees half a file.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use gs_core::Image;
use serde::{Deserialize, Serialize};

use super::StylizeError;

/// The stylized PLY in the output folder.
pub const STYLIZED_PLY: &str = "stylized.ply";
/// The per-step losses in the output folder.
pub const LOSSES_JSON: &str = "losses.json";
/// The plot of the total loss in the output folder.
pub const LOSSES_PNG: &str = "losses.png";
/// The resolved configuration in the output folder.
pub const CONFIG_JSON: &str = "config.json";

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

/// The name of the before/after picture of view `view`.
pub fn preview_name(view: usize) -> String {
    format!("preview_view{view:03}.png")
}

/// Writes `bytes` to `path` through `<path>.tmp` and a rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), StylizeError> {
    let mut tmp_name = path.file_name().unwrap_or_default().to_os_string();
    tmp_name.push(".tmp");
    let tmp = path.with_file_name(tmp_name);
    std::fs::write(&tmp, bytes)
        .and_then(|()| std::fs::rename(&tmp, path))
        .map_err(|source| {
            let _ = std::fs::remove_file(&tmp);
            StylizeError::Io {
                path: path.to_path_buf(),
                source,
            }
        })
}

/// Writes `value` as pretty JSON to `path` (atomically).
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), StylizeError> {
    let text = serde_json::to_string_pretty(value).expect("plain data serializes");
    write_atomic(path, text.as_bytes())
}

/// Reads JSON written by [`write_json`].
pub fn read_json<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<T, StylizeError> {
    let text = std::fs::read_to_string(path).map_err(|source| StylizeError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    serde_json::from_str(&text).map_err(|e| StylizeError::Io {
        path: path.to_path_buf(),
        source: std::io::Error::new(std::io::ErrorKind::InvalidData, e),
    })
}

/// Writes `before` and `after` side by side as the preview of view `view` in `dir`; returns
/// the file.
pub fn write_preview(
    dir: &Path,
    view: usize,
    before: &Image,
    after: &Image,
) -> Result<PathBuf, StylizeError> {
    let path = dir.join(preview_name(view));
    Image::side_by_side(&[before, after]).save_png(&path)?;
    Ok(path)
}
