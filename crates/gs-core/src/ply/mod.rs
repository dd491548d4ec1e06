//! INRIA 3DGS PLY files: read and write Gaussian sets with the properties of
//! `gaussian_model.py`'s `save_ply`.
//!
//! The header's `comment` lines are kept ([`PlyGaussians::comments`]) and written back; a tool
//! may record there what the Gaussians alone do not say (e.g. the picture a 2D model was fitted
//! to).
//!
//! One `vertex` element with the properties `x y z nx ny nz f_dc_0..2 f_rest_* opacity
//! scale_0..2 rot_0..3` in any order, each `float` or `double`:
//! - the SH degree (0 to 3) follows from the number of `f_rest_*` properties (0, 9, 24, 45);
//! - `f_rest_*` is channel-major on disk (all R coefficients, then G, then B), gs-core's
//!   `sh_rest` coefficient-major (`[N, K-1, 3]`);
//! - `rot_*` is the quaternion `(w, x, y, z)`, `scale_*` log-scales, `opacity` a logit.
//!
//! Every other property (the normals, extras some tools add) is kept as an [`ExtraProperty`]
//! and written back, so `write(read(file))` reproduces every value; a binary file written by
//! INRIA 3DGS is reproduced byte for byte. Bodies may be `binary_little_endian`,
//! `binary_big_endian` or `ascii`. Non-finite values are refused on reading and writing.

mod ascii;
mod binary;
mod columns;
pub mod elements;
mod header;
mod layout;
mod scalar;

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::GaussianSet;

use layout::Layout;
pub use layout::NORMAL_NAMES;
pub use scalar::ScalarType;

/// Body encoding of a PLY file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlyFormat {
    /// `binary_little_endian` (what INRIA 3DGS writes).
    BinaryLittleEndian,
    /// `binary_big_endian`.
    BinaryBigEndian,
    /// `ascii`: one vertex per line; floats written in the shortest form that reads back exactly.
    Ascii,
}

impl PlyFormat {
    /// The name in the header's `format` line.
    pub fn name(self) -> &'static str {
        match self {
            Self::BinaryLittleEndian => "binary_little_endian",
            Self::BinaryBigEndian => "binary_big_endian",
            Self::Ascii => "ascii",
        }
    }
}

/// A vertex property the Gaussians do not use, kept so that it is written back.
#[derive(Clone, Debug, PartialEq)]
pub struct ExtraProperty {
    /// Property name.
    pub name: String,
    /// Type in the file (kept on writing).
    pub ty: ScalarType,
    /// One value per vertex (every PLY scalar is exact in an `f64`).
    pub values: Vec<f64>,
}

/// The content of an INRIA PLY file: the Gaussians and the properties they do not use.
#[derive(Clone, Debug, PartialEq)]
pub struct PlyGaussians {
    /// The Gaussians (SH degree from the file).
    pub gaussians: GaussianSet,
    /// Other vertex properties in file order, normals included.
    pub extras: Vec<ExtraProperty>,
    /// The text of the header's `comment` lines, in file order (one line each).
    pub comments: Vec<String>,
    /// Whether the file has the INRIA normals `nx ny nz`: written from `extras` when they hold
    /// them, else as zeros (what INRIA writes); a file read without them (Mip-Splatting,
    /// SuperSplat exports) is written back without them.
    pub normals: bool,
}

impl PlyGaussians {
    /// Gaussians with no extra property (written with zero normals, as INRIA does).
    pub fn new(gaussians: GaussianSet) -> Self {
        Self {
            gaussians,
            extras: Vec::new(),
            comments: Vec::new(),
            normals: true,
        }
    }

    /// Gaussians with no extra property and no normals (written without them): what a format
    /// other than INRIA's PLY holds, or a model's forward gives.
    pub fn without_normals(gaussians: GaussianSet) -> Self {
        Self {
            normals: false,
            ..Self::new(gaussians)
        }
    }

    /// Names of the extra properties that are neither Gaussian parameters nor the INRIA normals
    /// (`nx ny nz`): what a caller may want to tell the user was kept but not used.
    pub fn unknown_properties(&self) -> Vec<&str> {
        self.extras
            .iter()
            .map(|e| e.name.as_str())
            .filter(|n| !NORMAL_NAMES.contains(n))
            .collect()
    }
}

/// Why a PLY file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum PlyErrorKind {
    /// The file could not be read or written.
    #[error("{0}")]
    Io(std::io::Error),
    /// A header line that is not valid (1-based line number).
    #[error("header line {line} {text:?}: {reason}")]
    Header {
        /// Line number, from 1.
        line: usize,
        /// The line.
        text: String,
        /// What is wrong with it.
        reason: String,
    },
    /// Arrays this machine could not reserve for the file's vertices.
    #[error("{0}")]
    OutOfMemory(#[from] crate::fallible::OutOfMemory),
    /// A `format` other than the three PLY encodings.
    #[error("format {0:?} is not supported (binary_little_endian, binary_big_endian, ascii are)")]
    UnsupportedFormat(String),
    /// A property INRIA 3DGS always writes is absent.
    #[error("required property {0:?} is missing")]
    MissingProperty(String),
    /// A Gaussian property of an integer type.
    #[error("property {name:?} is {ty}; Gaussian properties must be float or double")]
    PropertyType {
        /// Property name.
        name: String,
        /// Its type.
        ty: ScalarType,
    },
    /// A number of `f_rest_*` properties that is no SH degree.
    #[error("{0} f_rest_* properties: SH degrees 0 to 3 have 0, 9, 24 or 45")]
    ShRestCount(usize),
    /// A value that is not finite or not of its property's type, or a zero quaternion (0-based
    /// vertex index).
    #[error("vertex {vertex}, property {property:?}: {reason}")]
    BadValue {
        /// Vertex index, from 0.
        vertex: usize,
        /// Property name.
        property: String,
        /// What is wrong with the value.
        reason: String,
    },
    /// A binary body shorter than the header says.
    #[error(
        "truncated body: {vertices} vertices of {stride} bytes need {expected} bytes, found {found}"
    )]
    Truncated {
        /// Vertex count of the header.
        vertices: usize,
        /// Bytes per vertex.
        stride: usize,
        /// Bytes needed.
        expected: usize,
        /// Bytes present.
        found: usize,
    },
    /// An ascii body with fewer vertex lines than the header says.
    #[error("truncated ascii body: {found} of {expected} vertices")]
    AsciiTruncated {
        /// Vertex count of the header.
        expected: usize,
        /// Vertex lines present.
        found: usize,
    },
    /// Data after the last vertex.
    #[error("trailing data: {0}")]
    TrailingData(String),
    /// An ascii vertex line with the wrong number of values.
    #[error("line {line}: {found} values, {expected} properties")]
    AsciiFieldCount {
        /// Line number in the file, from 1.
        line: usize,
        /// Number of properties.
        expected: usize,
        /// Number of values on the line.
        found: usize,
    },
    /// An ascii value that does not parse or is not finite.
    #[error("line {line}, property {property:?}: {reason}")]
    AsciiValue {
        /// Line number in the file, from 1.
        line: usize,
        /// Property name.
        property: String,
        /// What is wrong.
        reason: String,
    },
    /// Gaussians or extras that cannot be written (wrong lengths, clashing names).
    #[error("cannot write: {0}")]
    InvalidData(String),
}

/// A PLY error and the file it concerns.
#[derive(Debug, thiserror::Error)]
#[error("{}: {kind}", path.display())]
pub struct PlyError {
    /// The file.
    pub path: PathBuf,
    /// What went wrong.
    pub kind: PlyErrorKind,
}

/// Reads an INRIA PLY file (see the module documentation).
pub fn read_ply(path: &Path) -> Result<PlyGaussians, PlyError> {
    read_ply_with_format(path).map(|(ply, _)| ply)
}

/// Reads an INRIA PLY file like [`read_ply`] and also returns the format of its body, so a
/// modified copy can be written in the same format.
pub fn read_ply_with_format(path: &Path) -> Result<(PlyGaussians, PlyFormat), PlyError> {
    let err = |kind| PlyError {
        path: path.to_path_buf(),
        kind,
    };
    let bytes = std::fs::read(path).map_err(|e| err(PlyErrorKind::Io(e)))?;
    parse(&bytes).map_err(err)
}

fn parse(bytes: &[u8]) -> Result<(PlyGaussians, PlyFormat), PlyErrorKind> {
    let header = header::parse(bytes)?;
    let (layout, extra_types) = Layout::from_properties(&header.properties)?;
    let body = &bytes[header.body_start..];
    let n = header.vertices;
    let big_endian = match header.format {
        PlyFormat::Ascii => {
            if n > body.len() {
                return Err(PlyErrorKind::AsciiTruncated {
                    expected: n,
                    found: body.iter().filter(|&&b| b == b'\n').count(),
                });
            }
            None
        }
        PlyFormat::BinaryLittleEndian => Some(false),
        PlyFormat::BinaryBigEndian => Some(true),
    };
    if big_endian.is_some() {
        binary::check_length(body.len(), n, layout.stride())?;
    }
    let mut gaussians = GaussianSet::try_zeros(n, layout.degree)?;
    let mut extras: Vec<Vec<f64>> = extra_types
        .iter()
        .map(|_| crate::fallible::filled(n, 0.0, "the extra properties' values"))
        .collect::<Result<_, _>>()?;
    match big_endian {
        Some(be) => binary::read_body(body, &layout, be, &mut gaussians, &mut extras)?,
        None => ascii::read_body(body, header.lines + 1, &layout, &mut gaussians, &mut extras)?,
    }
    if let Some(vertex) = gaussians.zero_rotation() {
        return Err(PlyErrorKind::BadValue {
            vertex,
            property: "rot_0..rot_3".into(),
            reason: "the quaternion is zero: a rotation has a direction (such a Gaussian renders \
                     as nothing, or as NaN)"
                .into(),
        });
    }
    let extras: Vec<ExtraProperty> = extra_types
        .into_iter()
        .zip(extras)
        .map(|((name, ty), values)| ExtraProperty { name, ty, values })
        .collect();
    let normals = extras
        .iter()
        .any(|e| NORMAL_NAMES.contains(&e.name.as_str()));
    let ply = PlyGaussians {
        gaussians,
        extras,
        comments: header.comments,
        normals,
    };
    Ok((ply, header.format))
}

/// Checks what [`Layout::for_writing`] relies on: array lengths, extra names and lengths.
fn validate(ply: &PlyGaussians) -> Result<(), PlyErrorKind> {
    ply.gaussians
        .check_shapes()
        .map_err(PlyErrorKind::InvalidData)?;
    let n = ply.gaussians.len();
    for (i, e) in ply.extras.iter().enumerate() {
        let bad = |why: String| {
            Err(PlyErrorKind::InvalidData(format!(
                "extra {:?}: {why}",
                e.name
            )))
        };
        if e.name.is_empty() || e.name.contains(char::is_whitespace) {
            return bad("a property name must be one word".into());
        }
        if layout::is_gaussian_property(&e.name) {
            return bad("the name of a Gaussian property".into());
        }
        if ply.extras[..i].iter().any(|o| o.name == e.name) {
            return bad("the name appears twice".into());
        }
        if e.values.len() != n {
            return bad(format!("{} values for {n} Gaussians", e.values.len()));
        }
    }
    if let Some(c) = ply.comments.iter().find(|c| c.contains(['\n', '\r'])) {
        return Err(PlyErrorKind::InvalidData(format!(
            "comment {c:?}: a comment must be one line"
        )));
    }
    Ok(())
}

/// Writes `ply` in `format`, properties in INRIA order (see [`PlyGaussians::new`] for normals,
/// extras after the Gaussian properties). The file is written under a temporary name beside
/// `path` (`<name>.tmp`), fsynced and renamed ([`crate::fs::write_atomic_with`]), so a failure
/// leaves nothing partial at `path`.
pub fn write_ply(path: &Path, ply: &PlyGaussians, format: PlyFormat) -> Result<(), PlyError> {
    let err = |kind| PlyError {
        path: path.to_path_buf(),
        kind,
    };
    validate(ply).map_err(err)?;
    let layout = Layout::for_writing(ply);
    let body = match format {
        PlyFormat::Ascii => ascii::write_body(ply, &layout).map(String::into_bytes),
        PlyFormat::BinaryLittleEndian => binary::write_body(ply, &layout, false),
        PlyFormat::BinaryBigEndian => binary::write_body(ply, &layout, true),
    }
    .map_err(err)?;
    let head = header::render(
        format,
        ply.gaussians.len(),
        &layout.properties(),
        &ply.comments,
    );
    crate::fs::write_atomic_with(path, |w| {
        w.write_all(head.as_bytes())?;
        w.write_all(&body)
    })
    .map_err(|e| err(PlyErrorKind::Io(e)))
}
