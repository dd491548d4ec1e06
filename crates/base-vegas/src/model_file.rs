//! VeGaS model files: the PLY its `save_ply` writes (read with `ply-rs-bw`), so a model trained
//! by the authors' code loads, and ours loads in theirs.
//!
//! Element `vertex`, every property `float`: `x y z nx ny nz f_dc_0..2 opacity scale_0..2 rot_0
//! m_0 sigma_0 w1_0..w1_13` (VeGaS writes no `f_rest` at SH degree 0; `scale_1` is unused and
//! written as the flat scale's log; `rot_0` is the rotation logit, `sigma_0` the log width);
//! then element `time` with one row `time_func_0..time_func_{F-2}` (the raw time logits).
//! Reading takes properties by name in any order and `float` or `double`; a missing one, a
//! motion polynomial of another degree, a non-finite value or a missing `time` element is an
//! error naming the file.
//!
//! Ours also records the video and the camera distance in a header comment,
//! `clipgaussian-video frames WxH fps R distance D`, which VeGaS ignores.

use std::path::{Path, PathBuf};

use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{
    Addable, DefaultElement, ElementDef, Encoding, Ply, Property, PropertyDef, PropertyType,
    ScalarType,
};
use ply_rs_bw::writer::Writer;

use crate::folded::FoldedGaussians;
use crate::frame::{FoldedParams, POLY_LEN};
use crate::ply_vertex::{self, ModelRow, VegasVertex};

/// The start of the header comment that records the video.
const RECORD_PREFIX: &str = "clipgaussian-video frames";

/// The video a model was fitted to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VideoRecord {
    /// Frame width, pixels.
    pub width: u32,
    /// Frame height, pixels.
    pub height: u32,
    /// Frames per second.
    pub fps: f64,
    /// Distance of the cameras from the plane, world units.
    pub distance: f64,
}

/// Why a model file cannot be read or written.
#[derive(Debug, thiserror::Error)]
pub enum VegasFileError {
    /// The file cannot be opened, encoded or written.
    #[error("model {}: {what}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What failed (`cannot open`, `cannot encode`, `cannot write`).
        what: &'static str,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A file that is not a readable PLY file.
    #[error("model {}: not a readable PLY file: {source}", path.display())]
    Unreadable {
        /// The file.
        path: PathBuf,
        /// The PLY parser's error.
        source: ply_rs_bw::parser::ParseError,
    },
    /// A file that reads but is not a VeGaS model (missing or bad values).
    #[error("model {}: {message}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

/// The vertex properties, in VeGaS's order.
fn vertex_properties() -> Vec<String> {
    let mut names: Vec<String> = [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    names.extend(
        [
            "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "m_0", "sigma_0",
        ]
        .iter()
        .map(|s| s.to_string()),
    );
    names.extend((0..POLY_LEN).map(|k| format!("w1_{k}")));
    names
}

/// Writes `model` (and the video it holds, when given) to `path` as VeGaS's PLY, through a
/// temporary name.
pub fn write_model(
    path: &Path,
    model: &FoldedGaussians,
    video: Option<VideoRecord>,
) -> Result<(), VegasFileError> {
    let io = |what: &'static str| {
        move |source: std::io::Error| VegasFileError::Io {
            path: path.to_path_buf(),
            what,
            source,
        }
    };
    let p = model.params();
    let mut ply = Ply::<ModelRow>::new();
    ply.header.encoding = Encoding::BinaryLittleEndian;
    if let Some(v) = video {
        ply.header.comments.push(format!(
            "{RECORD_PREFIX} {}x{} fps {} distance {}",
            v.width, v.height, v.fps, v.distance
        ));
    }
    let float = PropertyType::Scalar(ScalarType::Float);
    let mut vertex = ElementDef::new("vertex".into());
    for name in vertex_properties() {
        vertex.properties.add(PropertyDef::new(name, float.clone()));
    }
    ply.header.elements.add(vertex);
    let mut time = ElementDef::new("time".into());
    for k in 0..model.time_logits().len() {
        time.properties
            .add(PropertyDef::new(format!("time_func_{k}"), float.clone()));
    }
    ply.header.elements.add(time);
    let rows: Vec<ModelRow> = (0..p.len())
        .map(|i| {
            let mut values = [0.0; ply_vertex::VALUES];
            values[0..3].copy_from_slice(&p.xyz[3 * i..3 * i + 3]);
            values[3..5].copy_from_slice(&p.log_scales[2 * i..2 * i + 2]);
            values[5] = p.rotation[i];
            values[6] = p.m[i];
            values[7] = p.sigma[i];
            values[8..ply_vertex::OPACITY].copy_from_slice(&p.w[POLY_LEN * i..POLY_LEN * (i + 1)]);
            values[ply_vertex::OPACITY] = p.opacity_logits[i];
            values[ply_vertex::OPACITY + 1..].copy_from_slice(&p.sh_dc[3 * i..3 * i + 3]);
            ModelRow::Vertex(VegasVertex { values })
        })
        .collect();
    ply.payload.insert("vertex".into(), rows);
    ply.payload.insert(
        "time".into(),
        vec![ModelRow::Time(model.time_logits().to_vec())],
    );
    let mut bytes = Vec::new();
    Writer::new()
        .write_ply(&mut bytes, &mut ply)
        .map_err(io("cannot encode"))?;
    gs_core::fs::write_atomic(path, &bytes).map_err(io("cannot write"))
}

/// Reads a VeGaS model and, when the file records it, its video.
pub fn read_model(path: &Path) -> Result<(FoldedGaussians, Option<VideoRecord>), VegasFileError> {
    let fail = |message: String| VegasFileError::Format {
        path: path.to_path_buf(),
        message,
    };
    let io = |what: &'static str| {
        move |source: std::io::Error| VegasFileError::Io {
            path: path.to_path_buf(),
            what,
            source,
        }
    };
    let bytes = std::fs::read(path).map_err(io("cannot open"))?;
    // The strict reading of the header and the body's length first: a count that is off, a
    // second property of one name, bytes past the end, another format version.
    let header = gs_core::ply::elements::parse_elements(&bytes).map_err(&fail)?;
    gs_core::ply::elements::check_body_length(&header, &bytes).map_err(&fail)?;
    let unreadable = |source| VegasFileError::Unreadable {
        path: path.to_path_buf(),
        source,
    };
    let mut reader = Reader::new(std::io::Cursor::new(&bytes[..]));
    let parser = Parser::<VegasVertex>::new();
    let ply_header = parser.read_header(&mut reader).map_err(unreadable)?;
    let vertex = ply_header
        .elements
        .get("vertex")
        .ok_or_else(|| fail("no `vertex` element".into()))?;
    ply_vertex::check_properties(vertex).map_err(&fail)?;
    // Elements are read in the header's order; any other than these two is read and dropped.
    let (mut vertices, mut time_rows) = (None, None);
    for (name, element) in &ply_header.elements {
        if name == "vertex" {
            vertices = Some(
                parser
                    .read_payload_for_element(&mut reader, element, &ply_header)
                    .map_err(unreadable)?,
            );
        } else {
            let rows = Parser::<DefaultElement>::new()
                .read_payload_for_element(&mut reader, element, &ply_header)
                .map_err(unreadable)?;
            if name == "time" {
                time_rows = Some(rows);
            }
        }
    }
    let vertices = vertices.unwrap_or_default();
    let mut p = FoldedParams::with_capacity(vertices.len());
    for (i, vertex) in vertices.iter().enumerate() {
        let v = &vertex.values;
        if let Some(k) = v.iter().position(|v| !v.is_finite()) {
            return Err(fail(format!(
                "{} of vertex {i} is {}",
                ply_vertex::name(k),
                v[k]
            )));
        }
        p.xyz.extend(&v[0..3]);
        p.log_scales.extend(&v[3..5]);
        p.rotation.push(v[5]);
        p.m.push(v[6]);
        p.sigma.push(v[7]);
        p.w.extend(&v[8..ply_vertex::OPACITY]);
        p.opacity_logits.push(v[ply_vertex::OPACITY]);
        p.sh_dc.extend(&v[ply_vertex::OPACITY + 1..]);
    }
    drop(vertices);
    let time_rows = time_rows
        .ok_or_else(|| fail("no `time` element (VeGaS saves the time logits there)".into()))?;
    let time_row = match time_rows.as_slice() {
        [row] => row,
        rows => {
            return Err(fail(format!(
                "the `time` element has {} rows, not 1",
                rows.len()
            )))
        }
    };
    let logits = (0..time_row.len())
        .map(|k| {
            let name = format!("time_func_{k}");
            let v = match time_row.get(&name) {
                Some(Property::Float(v)) => *v,
                Some(Property::Double(v)) => *v as f32,
                Some(other) => {
                    return Err(fail(format!(
                        "property {name} is {other:?}, not float or double"
                    )))
                }
                None => return Err(fail(format!("no property {name} in the `time` element"))),
            };
            if !v.is_finite() {
                return Err(fail(format!("{name} of the time element is {v}")));
            }
            Ok(v)
        })
        .collect::<Result<Vec<f32>, _>>()?;
    let record = ply_header
        .comments
        .iter()
        .find_map(|c| parse_record(c))
        .transpose()
        .map_err(&fail)?;
    let model = FoldedGaussians::new(p, logits).map_err(fail)?;
    Ok((model, record))
}

/// The frame count and the recorded video of the VeGaS model at `path`, from its header
/// alone (the frames are the `time` element's properties plus one): what a run checks before
/// it reads the whole model. A header that does not parse is an error; [`read_model`] checks
/// the rest.
pub fn read_header(path: &Path) -> Result<(usize, Option<VideoRecord>), VegasFileError> {
    use std::io::BufRead;
    let fail = |message: String| VegasFileError::Format {
        path: path.to_path_buf(),
        message,
    };
    let file = std::fs::File::open(path).map_err(|source| VegasFileError::Io {
        path: path.to_path_buf(),
        what: "cannot open",
        source,
    })?;
    let mut header = Vec::new();
    // A header of 20,000 frames' time properties is under 1 MB; 16 MB bounds a hostile one.
    let mut lines = std::io::Read::take(std::io::BufReader::new(file), 1 << 24);
    while !header.ends_with(b"end_header\n") {
        let read = lines
            .read_until(b'\n', &mut header)
            .map_err(|source| VegasFileError::Io {
                path: path.to_path_buf(),
                what: "cannot open",
                source,
            })?;
        if read == 0 {
            return Err(fail("no end_header line".into()));
        }
    }
    let elements = gs_core::ply::elements::parse_elements(&header).map_err(&fail)?;
    let time = elements
        .elements
        .iter()
        .find(|e| e.name == "time")
        .ok_or_else(|| fail("no `time` element (VeGaS saves the time logits there)".into()))?;
    let record = String::from_utf8_lossy(&header)
        .lines()
        .filter_map(|l| l.strip_prefix("comment "))
        .find_map(parse_record)
        .transpose()
        .map_err(&fail)?;
    Ok((time.properties.len() + 1, record))
}

/// The video of a `clipgaussian-video frames WxH fps R distance D` comment: none when the
/// comment is another; an error when it holds a size, rate or distance that is not positive,
/// or a frame size no camera can have.
fn parse_record(comment: &str) -> Option<Result<VideoRecord, String>> {
    let rest = comment.strip_prefix(RECORD_PREFIX)?.trim();
    let parsed = || -> Result<VideoRecord, String> {
        let bad = || {
            format!("{comment:?}: `{RECORD_PREFIX} WxH fps R distance D` expected, each positive")
        };
        let mut parts = rest.split_whitespace();
        let (w, h) = parts
            .next()
            .and_then(|s| s.split_once('x'))
            .ok_or_else(bad)?;
        let mut number = |key: &str| -> Result<f64, String> {
            if parts.next() != Some(key) {
                return Err(bad());
            }
            parts
                .next()
                .and_then(|v| v.parse().ok())
                .filter(|v: &f64| v.is_finite() && *v > 0.0)
                .ok_or_else(bad)
        };
        let (fps, distance) = (number("fps")?, number("distance")?);
        let record = VideoRecord {
            width: w.parse().ok().filter(|&w| w > 0).ok_or_else(bad)?,
            height: h.parse().ok().filter(|&h| h > 0).ok_or_else(bad)?,
            fps,
            distance,
        };
        gs_core::mirror_pair::plane_camera(record.width, record.height, record.distance, false)
            .map_err(|e| format!("{comment:?}: its frames: {e}"))?;
        Ok(record)
    };
    Some(parsed())
}
