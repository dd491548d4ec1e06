//! Ascii bodies: one vertex per line, values separated by spaces.

use super::columns;
use super::layout::Layout;
use super::{PlyErrorKind, PlyGaussians};

/// Parses `body`, whose first line is line `first_line` of the file, into `set` and `extras`.
/// Blank lines are skipped; anything but blank lines after the last vertex is an error.
pub(crate) fn read_body(
    body: &[u8],
    first_line: usize,
    layout: &Layout,
    set: &mut crate::GaussianSet,
    extras: &mut [Vec<f64>],
) -> Result<(), PlyErrorKind> {
    let n = set.len();
    let mut runs = columns::split(set, extras, n.max(1));
    let mut vertex = 0;
    for (k, raw) in body.split(|&b| b == b'\n').enumerate() {
        let line = first_line + k;
        let text = std::str::from_utf8(raw).map_err(|_| PlyErrorKind::AsciiValue {
            line,
            property: String::new(),
            reason: "the line is not text".into(),
        })?;
        if text.trim().is_empty() {
            continue;
        }
        let Some(cols) = runs.first_mut().filter(|_| vertex < n) else {
            return Err(PlyErrorKind::TrailingData(format!(
                "line {line} follows the last of {n} vertices"
            )));
        };
        let tokens: Vec<&str> = text.split_whitespace().collect();
        if tokens.len() != layout.fields.len() {
            return Err(PlyErrorKind::AsciiFieldCount {
                line,
                expected: layout.fields.len(),
                found: tokens.len(),
            });
        }
        for (field, token) in layout.fields.iter().zip(tokens) {
            let bad = |reason: String| PlyErrorKind::AsciiValue {
                line,
                property: field.name.clone(),
                reason,
            };
            let value = field.ty.parse_ascii(token).map_err(bad)?;
            field.slot.check(value).map_err(bad)?;
            cols.set(vertex, field.slot, value);
        }
        vertex += 1;
    }
    if vertex < n {
        return Err(PlyErrorKind::AsciiTruncated {
            expected: n,
            found: vertex,
        });
    }
    Ok(())
}

/// Formats every vertex of `ply` in `layout` (values checked against their types).
pub(crate) fn write_body(ply: &PlyGaussians, layout: &Layout) -> Result<String, PlyErrorKind> {
    let rest = 3 * (ply.gaussians.sh_coeffs() - 1);
    let mut out = String::new();
    for i in 0..ply.gaussians.len() {
        for (f, field) in layout.fields.iter().enumerate() {
            let value = field.value_to_write(ply, rest, i)?;
            if f > 0 {
                out.push(' ');
            }
            field.ty.format_ascii(value, &mut out);
        }
        out.push('\n');
    }
    Ok(out)
}
