//! Binary bodies: fixed-stride records decoded and encoded in parallel runs of vertices.

use rayon::prelude::*;

use super::columns::{self, ColumnsMut};
use super::layout::{Layout, Slot};
use super::{PlyErrorKind, PlyGaussians};

/// Vertices per parallel run.
const RUN: usize = 8192;

/// Checks that a body of `len` bytes holds exactly `vertices` records of `stride` bytes.
pub(crate) fn check_length(len: usize, vertices: usize, stride: usize) -> Result<(), PlyErrorKind> {
    let truncated = |expected| PlyErrorKind::Truncated {
        vertices,
        stride,
        expected,
        found: len,
    };
    let expected = vertices
        .checked_mul(stride)
        .ok_or_else(|| truncated(usize::MAX))?;
    match len.cmp(&expected) {
        std::cmp::Ordering::Less => Err(truncated(expected)),
        std::cmp::Ordering::Greater => Err(PlyErrorKind::TrailingData(format!(
            "{} bytes after the last of {vertices} vertices",
            len - expected
        ))),
        std::cmp::Ordering::Equal => Ok(()),
    }
}

/// The first value refused: vertex, field index, reason.
type BadValue = (usize, usize, String);

/// Decodes a run of records; returns the first refused value.
fn decode_run(
    records: &[u8],
    stride: usize,
    first: usize,
    fields: &[(usize, super::ScalarType, Slot)],
    big_endian: bool,
    cols: &mut ColumnsMut<'_>,
) -> Result<(), BadValue> {
    for (v, rec) in records.chunks_exact(stride).enumerate() {
        for (f, &(offset, ty, slot)) in fields.iter().enumerate() {
            let value = ty.decode(&rec[offset..], big_endian);
            slot.check(value).map_err(|reason| (first + v, f, reason))?;
            cols.set(v, slot, value);
        }
    }
    Ok(())
}

/// Decodes `body` (already length-checked) into `set` and `extras`.
pub(crate) fn read_body(
    body: &[u8],
    layout: &Layout,
    big_endian: bool,
    set: &mut crate::GaussianSet,
    extras: &mut [Vec<f64>],
) -> Result<(), PlyErrorKind> {
    let stride = layout.stride();
    let mut offset = 0;
    let fields: Vec<_> = layout
        .fields
        .iter()
        .map(|f| {
            let o = offset;
            offset += f.ty.size();
            (o, f.ty, f.slot)
        })
        .collect();
    let runs = columns::split(set, extras, RUN);
    let results: Vec<Result<(), BadValue>> = body
        .par_chunks(RUN * stride.max(1))
        .zip(runs.into_par_iter())
        .enumerate()
        .map(|(r, (records, mut cols))| {
            decode_run(records, stride, r * RUN, &fields, big_endian, &mut cols)
        })
        .collect();
    match results.into_iter().find_map(Result::err) {
        Some((vertex, f, reason)) => Err(PlyErrorKind::BadValue {
            vertex,
            property: layout.fields[f].name.clone(),
            reason,
        }),
        None => Ok(()),
    }
}

/// Encodes every vertex of `ply` in `layout` (values checked against their types).
pub(crate) fn write_body(
    ply: &PlyGaussians,
    layout: &Layout,
    big_endian: bool,
) -> Result<Vec<u8>, PlyErrorKind> {
    let stride = layout.stride();
    let n = ply.gaussians.len();
    let rest = 3 * (ply.gaussians.sh_coeffs() - 1);
    let mut body = vec![0u8; n * stride];
    let results: Vec<Result<(), PlyErrorKind>> = body
        .par_chunks_mut(RUN * stride.max(1))
        .enumerate()
        .map(|(r, out)| {
            for (v, rec) in out.chunks_exact_mut(stride).enumerate() {
                let i = r * RUN + v;
                let mut offset = 0;
                for field in &layout.fields {
                    let value = field.value_to_write(ply, rest, i)?;
                    let size = field.ty.size();
                    field
                        .ty
                        .encode(value, big_endian, &mut rec[offset..offset + size]);
                    offset += size;
                }
            }
            Ok(())
        })
        .collect();
    results.into_iter().collect::<Result<(), _>>()?;
    Ok(body)
}
