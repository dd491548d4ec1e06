//! The PLY header: parsing it from the start of a file and writing it.

use super::scalar::ScalarType;
use super::{PlyErrorKind, PlyFormat};

/// Longest header accepted, bytes (an INRIA degree-3 header is about 1.3 kB).
const MAX_HEADER_BYTES: usize = 1 << 20;

/// A parsed header: the body format, the vertex count and the vertex properties in file order.
#[derive(Debug)]
pub(crate) struct Header {
    /// Body encoding.
    pub format: PlyFormat,
    /// Number of vertices.
    pub vertices: usize,
    /// Property names and types, in the order of the file.
    pub properties: Vec<(String, ScalarType)>,
    /// The text of each `comment` line, in file order.
    pub comments: Vec<String>,
    /// Offset of the first body byte.
    pub body_start: usize,
    /// Number of header lines (for ascii body line numbers).
    pub lines: usize,
}

fn header_error(line: usize, text: &str, reason: impl Into<String>) -> PlyErrorKind {
    PlyErrorKind::Header {
        line,
        text: text.to_string(),
        reason: reason.into(),
    }
}

/// Parses the header at the start of `bytes`. Only one element, `vertex`, with scalar
/// properties is accepted; the text of `comment` lines is kept, `obj_info` lines are skipped.
pub(crate) fn parse(bytes: &[u8]) -> Result<Header, PlyErrorKind> {
    let mut pos = 0;
    let mut line_no = 0;
    let mut format = None;
    let mut vertices = None;
    let mut properties: Vec<(String, ScalarType)> = Vec::new();
    let mut comments = Vec::new();
    loop {
        let rest = &bytes[pos..bytes.len().min(MAX_HEADER_BYTES)];
        let Some(len) = rest.iter().position(|&b| b == b'\n') else {
            return Err(header_error(
                line_no + 1,
                "",
                "the header has no end_header line",
            ));
        };
        line_no += 1;
        let raw = &rest[..len];
        pos += len + 1;
        let text = std::str::from_utf8(raw)
            .map_err(|_| header_error(line_no, "", "the header line is not text"))?
            .trim_end_matches('\r');
        let words: Vec<&str> = text.split_whitespace().collect();
        if line_no == 1 {
            if text != "ply" {
                return Err(header_error(
                    line_no,
                    text,
                    "not a PLY file (no `ply` magic)",
                ));
            }
            continue;
        }
        match words.as_slice() {
            ["end_header"] => break,
            ["comment", ..] => {
                let rest = text
                    .trim_start()
                    .strip_prefix("comment")
                    .unwrap_or_default();
                comments.push(rest.strip_prefix([' ', '\t']).unwrap_or(rest).to_string());
            }
            ["obj_info", ..] => {}
            ["format", name, "1.0"] => {
                format = Some(match *name {
                    "binary_little_endian" => PlyFormat::BinaryLittleEndian,
                    "binary_big_endian" => PlyFormat::BinaryBigEndian,
                    "ascii" => PlyFormat::Ascii,
                    other => return Err(PlyErrorKind::UnsupportedFormat(other.to_string())),
                })
            }
            ["format", ..] => {
                return Err(header_error(line_no, text, "expected `format <kind> 1.0`"))
            }
            ["element", "vertex", count] => {
                if vertices.is_some() {
                    return Err(header_error(line_no, text, "a second vertex element"));
                }
                let n = count
                    .parse::<usize>()
                    .map_err(|_| header_error(line_no, text, "the vertex count is not a number"))?;
                vertices = Some(n);
            }
            ["element", name, ..] => {
                return Err(header_error(
                    line_no,
                    text,
                    format!("element {name:?}: only a `vertex` element is supported"),
                ))
            }
            ["property", "list", ..] => {
                return Err(header_error(
                    line_no,
                    text,
                    "list properties are not supported",
                ))
            }
            ["property", ty, name] => {
                if vertices.is_none() {
                    return Err(header_error(
                        line_no,
                        text,
                        "a property before `element vertex`",
                    ));
                }
                let ty = ScalarType::from_name(ty)
                    .ok_or_else(|| header_error(line_no, text, format!("unknown type {ty:?}")))?;
                if properties.iter().any(|(n, _)| n == name) {
                    return Err(header_error(
                        line_no,
                        text,
                        format!("property {name:?} appears twice"),
                    ));
                }
                properties.push((name.to_string(), ty));
            }
            _ => return Err(header_error(line_no, text, "unrecognised header line")),
        }
    }
    let format = format.ok_or_else(|| header_error(line_no, "end_header", "no `format` line"))?;
    let vertices =
        vertices.ok_or_else(|| header_error(line_no, "end_header", "no `element vertex` line"))?;
    Ok(Header {
        format,
        vertices,
        properties,
        comments,
        body_start: pos,
        lines: line_no,
    })
}

/// The header text of a file with `vertices` vertices and `properties`, as INRIA 3DGS writes it,
/// with a `comment` line for each of `comments` (one line each) after the `format` line.
pub(crate) fn render(
    format: PlyFormat,
    vertices: usize,
    properties: &[(String, ScalarType)],
    comments: &[String],
) -> String {
    let mut s = format!("ply\nformat {} 1.0\n", format.name());
    for comment in comments {
        s.push_str(&format!("comment {comment}\n"));
    }
    s.push_str(&format!("element vertex {vertices}\n"));
    for (name, ty) in properties {
        s.push_str(&format!("property {ty} {name}\n"));
    }
    s.push_str("end_header\n");
    s
}
