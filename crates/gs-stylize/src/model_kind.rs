//! Which binary opens a model file, recognized from its first bytes: so that a model given to
//! the wrong binary is refused with the binary to use, not with a parser's error about an
//! element or a header length. The product's four formats:
//!
//! - `clipgaussian-2d`: a PLY with the header comment `clipgaussian-2d picture ...` (MiraGe's own
//!   PLYs, without it, are plain Gaussian PLYs that the 2D reader checks for flatness);
//! - `clipgaussian-3d`: a plain Gaussian PLY (INRIA 3DGS's layout, one `vertex` element);
//! - `clipgaussian-video`: a PLY with VeGaS's `time` element (or the comment
//!   `clipgaussian-video frames ...`);
//! - `clipgaussian-4d`: a safetensors file whose metadata `format` is `clipgaussian-dmiso`.

use std::path::Path;

/// What a model file is, as far as its first bytes tell.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ModelKind {
    /// A PLY recording the picture a 2D model was fitted to.
    Picture,
    /// A PLY of plain Gaussians: a 3D scene (or a MiraGe picture without our record).
    Gaussians,
    /// A VeGaS video model.
    Video,
    /// A D-MiSo dynamic-scene model of ours.
    DynamicScene,
    /// None of these (or unreadable): left to the binary's own reader, which names the problem.
    Unknown,
}

/// The product's binaries, by modality.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Binary {
    /// `clipgaussian-2d`.
    Picture,
    /// `clipgaussian-3d`.
    Scene,
    /// `clipgaussian-video`.
    Video,
    /// `clipgaussian-4d`.
    DynamicScene,
}

impl Binary {
    /// The binary's name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Picture => "clipgaussian-2d",
            Self::Scene => "clipgaussian-3d",
            Self::Video => "clipgaussian-video",
            Self::DynamicScene => "clipgaussian-4d",
        }
    }
}

/// How much of a file is read to recognize it: a PLY header or a safetensors length and header
/// start fit well within it.
const SNIFF_BYTES: u64 = 1 << 16;

/// Recognizes `path` from its first bytes (a folder, a missing file or anything else is
/// [`ModelKind::Unknown`]).
pub fn recognize(path: &Path) -> ModelKind {
    let Ok(head) = gs_core::fs::read_head(path, SNIFF_BYTES) else {
        return ModelKind::Unknown;
    };
    if head.starts_with(b"ply\n") || head.starts_with(b"ply\r\n") {
        return ply_kind(&head);
    }
    safetensors_kind(&head)
}

/// The kind of a PLY from its header lines (up to `end_header` or the bytes read).
fn ply_kind(head: &[u8]) -> ModelKind {
    let text = String::from_utf8_lossy(head);
    let mut kind = ModelKind::Gaussians;
    for line in text.lines().take_while(|l| l.trim() != "end_header") {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["element", "time", ..] => return ModelKind::Video,
            ["comment", "clipgaussian-video", ..] => return ModelKind::Video,
            ["comment", "clipgaussian-2d", "picture", ..] => kind = ModelKind::Picture,
            _ => {}
        }
    }
    kind
}

/// [`ModelKind::DynamicScene`] when `head` starts a safetensors file whose metadata names our
/// D-MiSo format, else unknown.
fn safetensors_kind(head: &[u8]) -> ModelKind {
    let Some(length) = head.get(..8) else {
        return ModelKind::Unknown;
    };
    let length = u64::from_le_bytes(length.try_into().unwrap_or_default()) as usize;
    let Some(header) = head.get(8..8usize.saturating_add(length)) else {
        return ModelKind::Unknown;
    };
    let Ok(header) = serde_json::from_slice::<serde_json::Value>(header) else {
        return ModelKind::Unknown;
    };
    if header["__metadata__"]["format"] == "clipgaussian-dmiso" {
        ModelKind::DynamicScene
    } else {
        ModelKind::Unknown
    }
}

/// Refuses a model that another binary opens: `flag` names where it was given. A plain
/// Gaussian PLY passes in 2D (MiraGe's own files are such; the 2D reader checks them) and 3D;
/// an unknown file passes to the binary's own reader.
pub fn check_model(binary: Binary, flag: &str, path: &Path) -> Result<(), String> {
    let (what, opens) = match recognize(path) {
        ModelKind::Picture => ("a 2D picture model", Binary::Picture),
        ModelKind::Video => ("a VeGaS video model", Binary::Video),
        ModelKind::DynamicScene => ("a D-MiSo dynamic-scene model", Binary::DynamicScene),
        ModelKind::Gaussians if matches!(binary, Binary::Picture | Binary::Scene) => return Ok(()),
        ModelKind::Gaussians => ("a PLY of plain Gaussians (a 3D scene)", Binary::Scene),
        ModelKind::Unknown => return Ok(()),
    };
    if opens == binary {
        return Ok(());
    }
    Err(format!(
        "{flag} {}: this is {what}; use {}",
        path.display(),
        opens.name()
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
        let path = dir.join(name);
        std::fs::write(&path, bytes).unwrap();
        path
    }

    fn safetensors(metadata: &str) -> Vec<u8> {
        let header = format!(r#"{{"__metadata__":{{"format":"{metadata}"}}}}"#);
        let mut bytes = (header.len() as u64).to_le_bytes().to_vec();
        bytes.extend(header.as_bytes());
        bytes
    }

    #[test]
    fn each_format_is_recognized_and_sent_to_its_binary() {
        let dir = tempfile::tempdir().unwrap();
        let plain = write(
            dir.path(),
            "scene.ply",
            b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nend_header\n",
        );
        let picture = write(
            dir.path(),
            "picture.ply",
            b"ply\nformat binary_little_endian 1.0\ncomment clipgaussian-2d picture 8x8 distance 1\nelement vertex 1\nproperty float x\nend_header\n",
        );
        let video = write(
            dir.path(),
            "video.ply",
            b"ply\r\nformat binary_little_endian 1.0\r\nelement vertex 1\r\nproperty float x\r\nelement time 1\r\nproperty float time_func_0\r\nend_header\r\n",
        );
        let dynamic = write(
            dir.path(),
            "model.safetensors",
            &safetensors("clipgaussian-dmiso"),
        );
        let other = write(dir.path(), "other.safetensors", &safetensors("something"));
        let garbage = write(dir.path(), "x.bin", b"\x00\x01");
        assert_eq!(recognize(&plain), ModelKind::Gaussians);
        assert_eq!(recognize(&picture), ModelKind::Picture);
        assert_eq!(recognize(&video), ModelKind::Video);
        assert_eq!(recognize(&dynamic), ModelKind::DynamicScene);
        assert_eq!(recognize(&other), ModelKind::Unknown);
        assert_eq!(recognize(&garbage), ModelKind::Unknown);
        assert_eq!(recognize(dir.path()), ModelKind::Unknown);

        let err = check_model(Binary::Scene, "--model", &video).unwrap_err();
        assert!(
            err.contains("VeGaS video model; use clipgaussian-video"),
            "{err}"
        );
        let err = check_model(Binary::Video, "--model", &dynamic).unwrap_err();
        assert!(err.contains("use clipgaussian-4d"), "{err}");
        let err = check_model(Binary::DynamicScene, "--a", &plain).unwrap_err();
        assert!(
            err.starts_with("--a ") && err.contains("use clipgaussian-3d"),
            "{err}"
        );
        let err = check_model(Binary::Scene, "--model", &picture).unwrap_err();
        assert!(err.contains("use clipgaussian-2d"), "{err}");
        assert!(check_model(Binary::Picture, "--model", &plain).is_ok());
        assert!(check_model(Binary::Scene, "--model", &plain).is_ok());
        assert!(check_model(Binary::Video, "--model", &video).is_ok());
        assert!(check_model(Binary::Video, "--model", &garbage).is_ok());
    }
}
