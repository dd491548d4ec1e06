//! Splat files beyond INRIA's PLY, read and written for viewers and other pipelines:
//! SuperSplat's compressed PLY ([`compressed_ply`]), Niantic's SPZ ([`spz`]), antimatter15's
//! `.splat` ([`splat_format`]), glTF binary with `KHR_gaussian_splatting` ([`gltf`]) and
//! PlayCanvas's SOG ([`sog`]: a `.sog` bundle or a folder's `meta.json`), every one both ways.
//!
//! [`read_splats`] and [`write_splats`] pick the format from the file name
//! ([`SplatFormat::from_path`]); a `.ply` is read as compressed when its header has a `chunk`
//! element. Every format but INRIA's PLY quantises: what each keeps is stated in its module and
//! checked against `@playcanvas/splat-transform`'s files. Coordinates are written as they are
//! held (3DGS's: x right, y down, z forward) in PLY, compressed PLY and `.splat`; SPZ is turned
//! into its own frame (y up, z back) as Niantic's library does, and glTF is y-up (the scene
//! turned half a turn about z) as splat-transform writes it; both are turned back on reading.

pub mod codebook;
pub mod compressed_ply;
pub mod gltf;
pub mod sog;
pub mod splat_format;
pub mod spz;

use std::path::{Path, PathBuf};

use crate::ply::{read_ply_with_format, write_ply, PlyError, PlyFormat, PlyGaussians};
use crate::GaussianSet;

/// A splat file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SplatFormat {
    /// INRIA 3DGS PLY (`.ply`): every value exact.
    Ply,
    /// SuperSplat's compressed PLY (`.compressed.ply`).
    CompressedPly,
    /// antimatter15's `.splat`: 32 bytes a Gaussian, no view dependence.
    Splat,
    /// Niantic's SPZ (`.spz`), version 4 (the current one: zstd streams).
    Spz,
    /// Niantic's SPZ version 2 (gzip), which older readers take (`.spz` with `--format
    /// spz-v2`).
    SpzV2,
    /// glTF binary with `KHR_gaussian_splatting` (`.glb`).
    Glb,
    /// PlayCanvas's SOG: a `.sog` bundle, or a folder's `meta.json` with its pictures beside.
    Sog,
}

impl SplatFormat {
    /// Every format, in the order of [`SplatFormat::name`]s a command lists.
    pub const ALL: [Self; 7] = [
        Self::Ply,
        Self::CompressedPly,
        Self::Splat,
        Self::Spz,
        Self::SpzV2,
        Self::Glb,
        Self::Sog,
    ];

    /// The format's name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::Ply => "ply",
            Self::CompressedPly => "compressed-ply",
            Self::Splat => "splat",
            Self::Spz => "spz",
            Self::SpzV2 => "spz-v2",
            Self::Glb => "glb",
            Self::Sog => "sog",
        }
    }

    /// The file name ending the format's files take.
    pub fn extension(self) -> &'static str {
        match self {
            Self::Ply => ".ply",
            Self::CompressedPly => ".compressed.ply",
            Self::Splat => ".splat",
            Self::Spz | Self::SpzV2 => ".spz",
            Self::Glb => ".glb",
            Self::Sog => ".sog",
        }
    }

    /// The format of a file named `path` by its ending (`.compressed.ply` before `.ply`; SPZ
    /// files are written in version 4 and read in any; a file named `meta.json` is a SOG
    /// folder's), `None` for an unknown ending.
    pub fn from_path(path: &Path) -> Option<Self> {
        if is_sog_folder(path) {
            return Some(Self::Sog);
        }
        let name = path.file_name()?.to_str()?.to_ascii_lowercase();
        [
            Self::CompressedPly,
            Self::Ply,
            Self::Splat,
            Self::Spz,
            Self::Glb,
            Self::Sog,
        ]
        .into_iter()
        .find(|f| name.ends_with(f.extension()))
    }

    /// The format named `name` (see [`SplatFormat::name`]).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|f| f.name() == name)
    }
}

/// Why a splat file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum SplatFileError {
    /// An INRIA PLY file's error.
    #[error(transparent)]
    Ply(#[from] PlyError),
    /// The file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// Content that is not what the format allows.
    #[error("{}: {message}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong and where.
        message: String,
    },
    /// Arrays this machine could not give memory to, for the file's Gaussians.
    #[error("{}: {source}", path.display())]
    OutOfMemory {
        /// The file.
        path: PathBuf,
        /// What could not be reserved.
        source: crate::fallible::OutOfMemory,
    },
}

/// Why a splat file's bytes did not decode: content the format does not allow, or arrays this
/// machine could not give memory to.
#[derive(Debug, thiserror::Error)]
pub enum DecodeError {
    /// What is wrong and where.
    #[error("{0}")]
    Format(String),
    /// The Gaussians' arrays.
    #[error(transparent)]
    OutOfMemory(#[from] crate::fallible::OutOfMemory),
}

impl From<String> for DecodeError {
    fn from(message: String) -> Self {
        Self::Format(message)
    }
}

impl From<&str> for DecodeError {
    fn from(message: &str) -> Self {
        Self::Format(message.to_string())
    }
}

/// Reads the splat file `path` in the format its name says (a `.ply` with a `chunk` element as
/// compressed; a `.sog` or a `meta.json` as SOG; a name of no known ending as INRIA PLY when it
/// starts as a PLY, else refused).
/// Formats other than INRIA's PLY give Gaussians without extras or normals.
pub fn read_splats(path: &Path) -> Result<PlyGaussians, SplatFileError> {
    read_splats_with_format(path).map(|(ply, _)| ply)
}

/// [`read_splats`], with the body format of an INRIA PLY (binary little-endian for every other
/// format), so a modified copy can be written as the input was.
pub fn read_splats_with_format(path: &Path) -> Result<(PlyGaussians, PlyFormat), SplatFileError> {
    let format = match SplatFormat::from_path(path) {
        Some(format) => format,
        None if head(path)?.starts_with(b"ply") => SplatFormat::Ply,
        None => {
            return Err(SplatFileError::Format {
                path: path.to_path_buf(),
                message: "not a splat file this reader knows: the name ends in none of .ply, \
                          .compressed.ply, .splat, .spz, .glb, .sog (nor is it a SOG folder's \
                          meta.json), and the file does not start as a PLY"
                    .into(),
            })
        }
    };
    let read = || {
        std::fs::read(path).map_err(|source| SplatFileError::Io {
            path: path.to_path_buf(),
            source,
        })
    };
    let format_error = |e: DecodeError| decode_error(path, e);
    let gaussians = match format {
        SplatFormat::Ply | SplatFormat::CompressedPly => {
            if !compressed_ply::is_compressed(&head(path)?) {
                return Ok(read_ply_with_format(path)?);
            }
            compressed_ply::decode(&read()?).map_err(format_error)?
        }
        SplatFormat::Splat => splat_format::decode(&read()?).map_err(format_error)?,
        SplatFormat::Spz | SplatFormat::SpzV2 => spz::decode(&read()?).map_err(format_error)?,
        SplatFormat::Glb => gltf::decode(&read()?).map_err(format_error)?,
        SplatFormat::Sog if is_sog_folder(path) => {
            sog::decode_folder(path).map_err(format_error)?
        }
        SplatFormat::Sog => sog::decode_bundle(&read()?).map_err(format_error)?,
    };
    Ok((
        PlyGaussians::without_normals(gaussians),
        PlyFormat::BinaryLittleEndian,
    ))
}

/// Whether `path` names a SOG folder's `meta.json`.
fn is_sog_folder(path: &Path) -> bool {
    path.file_name().is_some_and(|n| n == sog::META_JSON)
}

/// A decoder's error as the file's.
fn decode_error(path: &Path, e: DecodeError) -> SplatFileError {
    match e {
        DecodeError::Format(message) => SplatFileError::Format {
            path: path.to_path_buf(),
            message,
        },
        DecodeError::OutOfMemory(source) => SplatFileError::OutOfMemory {
            path: path.to_path_buf(),
            source,
        },
    }
}

/// The first 4 KiB of `path` (a PLY header fits), to tell a compressed PLY from an INRIA one
/// without reading the whole file.
fn head(path: &Path) -> Result<Vec<u8>, SplatFileError> {
    crate::fs::read_head(path, 4096).map_err(|source| SplatFileError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Writes `ply` to `path` in `format` (through a temporary name, renamed when complete; a SOG
/// folder's pictures first, its `meta.json` last). Formats other than INRIA's PLY keep only the
/// Gaussians.
pub fn write_splats(
    path: &Path,
    ply: &PlyGaussians,
    format: SplatFormat,
) -> Result<(), SplatFileError> {
    let set = &ply.gaussians;
    let bytes = match format {
        SplatFormat::Ply => return Ok(write_ply(path, ply, PlyFormat::BinaryLittleEndian)?),
        SplatFormat::CompressedPly => compressed_ply::encode(set),
        SplatFormat::Splat => splat_format::encode(set),
        SplatFormat::Spz => spz::encode(set, spz::Version::V4),
        SplatFormat::SpzV2 => spz::encode(set, spz::Version::V2),
        SplatFormat::Glb => gltf::encode(set),
        SplatFormat::Sog if is_sog_folder(path) => {
            let files = sog::encode(set).map_err(|message| SplatFileError::Format {
                path: path.to_path_buf(),
                message,
            })?;
            let folder = path.parent().unwrap_or(Path::new(""));
            for (name, bytes) in &files {
                let file = folder.join(name);
                crate::fs::write_atomic(&file, bytes)
                    .map_err(|source| SplatFileError::Io { path: file, source })?;
            }
            return Ok(());
        }
        SplatFormat::Sog => sog::encode(set).and_then(|files| sog::bundle(&files)),
    }
    .map_err(|message| SplatFileError::Format {
        path: path.to_path_buf(),
        message,
    })?;
    crate::fs::write_atomic(path, &bytes).map_err(|source| SplatFileError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// `1 / (1 + e^-x)`.
pub(crate) fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

/// The opacity logit of an 8-bit alpha level: `logit(level / 255)`, the fraction kept within
/// `[1e-6, 1 - 1e-6]` as splat-transform's `.splat` and SPZ readers keep it, so levels 0 and
/// 255 give finite logits (about -13.8 and 13.8).
pub(crate) fn opacity_of_level(level: u32) -> f64 {
    let p = (f64::from(level) / 255.0).clamp(1e-6, 1.0 - 1e-6);
    (p / (1.0 - p)).ln()
}

/// A Gaussian whose quaternion is zero, named by index: what the formats that store unit
/// rotations (compressed PLY, SPZ, `.splat`) refuse, since it has no direction to store.
pub(crate) fn check_rotations(set: &GaussianSet) -> Result<(), String> {
    match set.zero_rotation() {
        Some(i) => Err(format!(
            "the rotation of Gaussian {i} is zero: a rotation has a direction"
        )),
        None => Ok(()),
    }
}

/// A log-scale whose linear scale (`exp`) is not a finite `f32`, named by index: what the
/// formats of linear scales (`.splat`, glTF) refuse.
pub(crate) fn check_linear_scales(set: &GaussianSet) -> Result<(), String> {
    match set
        .log_scales
        .iter()
        .position(|&s| !(f64::from(s).exp() as f32).is_finite())
    {
        Some(i) => Err(format!(
            "scales[{i}] is {}: the exp of this log-scale does not fit a float",
            set.log_scales[i]
        )),
        None => Ok(()),
    }
}

/// A non-finite value among the Gaussians, named by array ([`crate::gaussians::PARAM_NAMES`])
/// and index: what an encoder refuses (a quantised format would write nonsense for it).
pub(crate) fn check_finite(set: &GaussianSet) -> Result<(), String> {
    for (name, values) in crate::gaussians::PARAM_NAMES.iter().zip(set.arrays()) {
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(format!("{name}[{i}] is {}", values[i]));
        }
    }
    Ok(())
}
