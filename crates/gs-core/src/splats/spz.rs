//! Niantic's SPZ, versions 2, 3 and 4, as Niantic's encoder writes them and
//! `@playcanvas/splat-transform` reads them.
//!
//! Versions 2 and 3 are one gzip stream holding a 16-byte header (magic `NGSP`, version,
//! count, SH degree, fractional bits, flags, a reserved byte) and then the attributes one after
//! the other; version 4 has a 32-byte plain header (the same fields, then the number of
//! streams and the offset of a table of contents), the table (compressed and plain size of
//! each stream) and one zstd stream per attribute. The attributes, in order:
//! - positions: 24-bit signed fixed point, `round(v 2^bits)` (`bits` 12 unless the scene is
//!   too large for it: the writer takes fewer so `|v| 2^bits` fits);
//! - alphas: `round(sigmoid(opacity) 255)`;
//! - colours: `round(f_dc 0.15 255 + 127.5)`;
//! - log-scales: `round((s + 10) 16)`, the range `[-10, 5.94]`;
//! - rotations: version 2 the `x, y, z` of the unit quaternion with `w >= 0`, each
//!   `round(v 127.5 + 127.5)`; versions 3 and 4 "smallest three" in 32 bits (2 bits for the
//!   largest of `(x, y, z, w)`, then each other as a sign bit and 9 bits of `|v| / sqrt(1/2)`);
//! - SH above degree 0, coefficient by coefficient with the channel innermost:
//!   `round(v 128) + 128` to a bucket of 8 (the three degree-1 coefficients) or 16 (the rest).
//!
//! Axes: SPZ stores its Gaussians in its own frame, x right, y up, z back (OpenGL's, "RUB"),
//! and Niantic's library converts from and to the caller's. Gaussians are held here in 3DGS's
//! PLY frame (x right, y down, z forward, "RDF"), so the writer turns them a half turn about x
//! into SPZ's frame and the reader turns them back, as Niantic's `ply_to_spz` / `spz_to_ply`
//! and `@playcanvas/splat-transform` 2 do: positions' y and z negated, the quaternions' y and
//! z, and each SH coefficient by its parity in y and z ([`turn_about_x`]).
//! (`@playcanvas/splat-transform` 3 writes and reads the PLY frame unconverted, against the
//! format's definition: its files come out upside down and mirrored here, and ours there.) The
//! antialiasing flag is written clear and ignored on reading.

use std::io::{Read, Write};

use super::DecodeError;
use super::{check_finite, check_rotations, opacity_of_level, sigmoid};
use crate::GaussianSet;

/// The magic number, `NGSP` little-endian.
const MAGIC: u32 = 0x5053_474e;
/// Colour quantisation scale around 0.5.
const COLOUR_SCALE: f64 = 0.15;
/// The fixed-point bits the writer uses when the scene fits.
const FRACTIONAL_BITS: u8 = 12;

/// An SPZ version this crate writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Version {
    /// Version 2: gzip, 3-byte rotations; what older readers take.
    V2,
    /// Version 3: gzip, 4-byte rotations.
    V3,
    /// Version 4: zstd streams, the current one.
    V4,
}

impl Version {
    fn number(self) -> u32 {
        match self {
            Self::V2 => 2,
            Self::V3 => 3,
            Self::V4 => 4,
        }
    }
}

/// The sign of each SH coefficient above degree 0 (degrees 1 to 4, in the order 3DGS stores
/// them) under a half turn about x, `(x, y, z) -> (x, -y, -z)`: the coefficient of a real SH
/// basis function odd in y and z together keeps its sign, odd in one of them flips.
const SH_SIGNS_ABOUT_X: [f32; 24] = [
    -1.0, -1.0, 1.0, // degree 1: y, z, x
    -1.0, 1.0, 1.0, -1.0, 1.0, // degree 2: xy, yz, 3z²-1, xz, x²-y²
    -1.0, 1.0, -1.0, -1.0, 1.0, -1.0, 1.0, // degree 3
    -1.0, 1.0, -1.0, 1.0, 1.0, -1.0, 1.0, -1.0, -1.0, // degree 4
];

/// Turns `set` a half turn about x, between 3DGS's PLY frame and SPZ's (its own inverse):
/// positions and the quaternions' vector parts get y and z negated, SH coefficients their
/// signs under the turn ([`SH_SIGNS_ABOUT_X`]).
fn turn_about_x(set: &mut GaussianSet) {
    for p in set.means.chunks_exact_mut(3) {
        p[1] = -p[1];
        p[2] = -p[2];
    }
    // (w, x, y, z): the rotation R becomes T R T with T = diag(1, -1, -1).
    for q in set.quats.chunks_exact_mut(4) {
        q[2] = -q[2];
        q[3] = -q[3];
    }
    let rest = rest_coefficients(set.sh_degree());
    if rest > 0 {
        for (k, v) in set.sh_rest.iter_mut().enumerate() {
            *v *= SH_SIGNS_ABOUT_X[(k / 3) % rest];
        }
    }
}

/// SH coefficients per channel above degree 0, by degree.
fn rest_coefficients(degree: usize) -> usize {
    (degree + 1) * (degree + 1) - 1
}

/// The fixed-point bits that hold every position of `means` in 24 signed bits.
fn fractional_bits(means: &[f32]) -> Result<u8, String> {
    let largest = means.iter().fold(0.0f64, |m, &v| m.max(f64::from(v).abs()));
    let limit = f64::from((1 << 23) - 1);
    (0..=FRACTIONAL_BITS)
        .rev()
        .find(|&b| (largest * f64::from(1u32 << b)).round() <= limit)
        .ok_or_else(|| format!("a position of size {largest} is beyond SPZ's range (8388607)"))
}

/// The attribute streams of `set`: positions, alphas, colours, scales, rotations, SH.
fn attributes(set: &GaussianSet, version: Version, bits: u8) -> Vec<Vec<u8>> {
    let n = set.len();
    let scale = f64::from(1u32 << bits);
    let mut positions = Vec::with_capacity(9 * n);
    for &v in &set.means {
        let fixed = (f64::from(v) * scale).round() as i32;
        positions.extend(&fixed.to_le_bytes()[..3]);
    }
    let alphas = set
        .opacity_logits
        .iter()
        .map(|&o| (sigmoid(f64::from(o)) * 255.0).round().clamp(0.0, 255.0) as u8)
        .collect();
    let colours = set
        .sh_dc
        .iter()
        .map(|&c| {
            (f64::from(c) * COLOUR_SCALE * 255.0 + 127.5)
                .round()
                .clamp(0.0, 255.0) as u8
        })
        .collect();
    let scales = set
        .log_scales
        .iter()
        .map(|&s| ((f64::from(s) + 10.0) * 16.0).round().clamp(0.0, 255.0) as u8)
        .collect();
    let mut rotations = Vec::with_capacity(4 * n);
    for q in set.quats.chunks_exact(4) {
        // (x, y, z, w), unit (`encode` refused zero quaternions).
        let xyzw = [q[1], q[2], q[3], q[0]].map(f64::from);
        let norm = xyzw.iter().map(|v| v * v).sum::<f64>().sqrt();
        let u = xyzw.map(|v| v / norm);
        match version {
            Version::V2 => {
                let sign = if u[3] < 0.0 { -127.5 } else { 127.5 };
                for v in &u[..3] {
                    rotations.push((v * sign + 127.5).round().clamp(0.0, 255.0) as u8);
                }
            }
            Version::V3 | Version::V4 => {
                let largest = (1..4).fold(0, |b, k| if u[k].abs() > u[b].abs() { k } else { b });
                let negative = u[largest] < 0.0;
                let mut packed = largest as u32;
                for (k, v) in u.iter().enumerate() {
                    if k != largest {
                        let sign = u32::from((*v < 0.0) != negative);
                        let magnitude = (511.0 * v.abs() / std::f64::consts::FRAC_1_SQRT_2 + 0.5)
                            .floor() as u32;
                        packed = packed << 10 | sign << 9 | magnitude.min(511);
                    }
                }
                rotations.extend(packed.to_le_bytes());
            }
        }
    }
    let mut streams = vec![positions, alphas, colours, scales, rotations];
    let rest = rest_coefficients(set.sh_degree());
    if rest > 0 {
        let mut sh = Vec::with_capacity(3 * rest * n);
        for (k, &v) in set.sh_rest.iter().enumerate() {
            let coefficient = (k / 3) % rest;
            let bucket = if coefficient < 3 { 8 } else { 16 };
            let q = (f64::from(v) * 128.0).round() as i64 + 128;
            let q = (q + bucket / 2).div_euclid(bucket) * bucket;
            sh.push(q.clamp(0, 255) as u8);
        }
        streams.push(sh);
    }
    streams
}

/// The SPZ bytes of `set` in `version`; an error names a value that cannot be written.
pub fn encode(set: &GaussianSet, version: Version) -> Result<Vec<u8>, String> {
    check_finite(set)?;
    check_rotations(set)?;
    let n = u32::try_from(set.len()).map_err(|_| "more Gaussians than SPZ counts (2^32)")?;
    let bits = fractional_bits(&set.means)?;
    let mut turned = set.clone();
    turn_about_x(&mut turned);
    let streams = attributes(&turned, version, bits);
    let degree = set.sh_degree() as u8;
    match version {
        Version::V2 | Version::V3 => {
            let mut plain = Vec::new();
            plain.extend(MAGIC.to_le_bytes());
            plain.extend(version.number().to_le_bytes());
            plain.extend(n.to_le_bytes());
            plain.extend([degree, bits, 0, 0]);
            for s in &streams {
                plain.extend(s);
            }
            let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
            gz.write_all(&plain).map_err(|e| e.to_string())?;
            gz.finish().map_err(|e| e.to_string())
        }
        Version::V4 => {
            let mut out = Vec::new();
            out.extend(MAGIC.to_le_bytes());
            out.extend(4u32.to_le_bytes());
            out.extend(n.to_le_bytes());
            out.extend([degree, bits, 0, streams.len() as u8]);
            out.extend(32u32.to_le_bytes());
            out.extend([0u8; 12]);
            let compressed: Vec<Vec<u8>> = streams
                .iter()
                .map(|s| {
                    ruzstd::encoding::compress_to_vec(
                        &s[..],
                        ruzstd::encoding::CompressionLevel::Fastest,
                    )
                })
                .collect();
            for (c, s) in compressed.iter().zip(&streams) {
                out.extend((c.len() as u64).to_le_bytes());
                out.extend((s.len() as u64).to_le_bytes());
            }
            for c in compressed {
                out.extend(c);
            }
            Ok(out)
        }
    }
}

/// A little-endian `u32` at `at`.
fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?))
}

/// The header fields every version has: version, count, SH degree, fractional bits.
fn header(b: &[u8]) -> Result<(u32, usize, usize, u8), String> {
    if u32_at(b, 0) != Some(MAGIC) {
        return Err("not an SPZ file (no NGSP magic)".into());
    }
    let version = u32_at(b, 4).ok_or("the header is cut short")?;
    let n = u32_at(b, 8).ok_or("the header is cut short")? as usize;
    let degree = usize::from(*b.get(12).ok_or("the header is cut short")?);
    let bits = *b.get(13).ok_or("the header is cut short")?;
    if degree > 3 {
        return Err(format!("SH degree {degree}; 0 to 3 are read"));
    }
    if bits > 23 {
        return Err(format!(
            "{bits} fractional bits; at most 23 fit 24-bit positions"
        ));
    }
    Ok((version, n, degree, bits))
}

/// The Gaussians of SPZ bytes (versions 2, 3 and 4).
pub fn decode(bytes: &[u8]) -> Result<GaussianSet, DecodeError> {
    if bytes.starts_with(&[0x1f, 0x8b]) {
        // The header first, then no more than the attributes it announces: a small file whose
        // stream unpacks to far more is refused without holding it.
        let mut stream = flate2::read::GzDecoder::new(bytes);
        let mut head = [0u8; 16];
        stream
            .read_exact(&mut head)
            .map_err(|e| format!("the gzip stream: {e}"))?;
        let (version, n, degree, bits) = header(&head)?;
        if !(2..=3).contains(&version) {
            return Err(format!("version {version} in a gzip stream; 2 and 3 are gzip").into());
        }
        let sizes = stream_sizes(n, degree, version);
        let total: usize = sizes.iter().sum();
        let mut plain = Vec::new();
        stream
            .take(total as u64 + 1)
            .read_to_end(&mut plain)
            .map_err(|e| format!("the gzip stream: {e}"))?;
        if plain.len() != total {
            return Err(format!(
                "{} bytes of attributes for {n} Gaussians of degree {degree}; {total} expected",
                plain.len()
            )
            .into());
        }
        let mut streams = Vec::new();
        let mut at = 0;
        for size in sizes {
            streams.push(&plain[at..at + size]);
            at += size;
        }
        return assemble(&streams, n, degree, bits, version);
    }
    let (version, n, degree, bits) = header(bytes)?;
    if version != 4 {
        return Err(format!("version {version} without gzip; only version 4 is plain").into());
    }
    let count = usize::from(*bytes.get(15).ok_or("the header is cut short")?);
    let toc = u32_at(bytes, 16).ok_or("the header is cut short")? as usize;
    let sizes = stream_sizes(n, degree, version);
    if count != sizes.len() {
        return Err(format!(
            "{count} streams; {} expected for degree {degree}",
            sizes.len()
        )
        .into());
    }
    let mut at = toc
        .checked_add(16 * count)
        .filter(|&end| end <= bytes.len())
        .ok_or("the table of streams runs past the end")?;
    let mut plain = Vec::new();
    for (k, want) in sizes.iter().enumerate() {
        let entry = toc + 16 * k;
        let packed = u64::from_le_bytes(bytes[entry..entry + 8].try_into().unwrap()) as usize;
        let size = u64::from_le_bytes(bytes[entry + 8..entry + 16].try_into().unwrap()) as usize;
        if size != *want {
            return Err(format!("stream {k} holds {size} bytes; {want} expected").into());
        }
        let end = at
            .checked_add(packed)
            .filter(|&e| e <= bytes.len())
            .ok_or_else(|| format!("stream {k} runs past the end"))?;
        let mut out = Vec::new();
        ruzstd::decoding::StreamingDecoder::new(&bytes[at..end])
            .map_err(|e| format!("stream {k}: {e}"))?
            .take(size as u64 + 1)
            .read_to_end(&mut out)
            .map_err(|e| format!("stream {k}: {e}"))?;
        if out.len() != size {
            return Err(
                format!("stream {k} unpacks to {} bytes; {size} expected", out.len()).into(),
            );
        }
        plain.push(out);
        at = end;
    }
    let streams: Vec<&[u8]> = plain.iter().map(Vec::as_slice).collect();
    assemble(&streams, n, degree, bits, version)
}

/// The byte size of each attribute stream of `n` Gaussians.
fn stream_sizes(n: usize, degree: usize, version: u32) -> Vec<usize> {
    let rotation = if version == 2 { 3 } else { 4 };
    let mut sizes = vec![9 * n, n, 3 * n, 3 * n, rotation * n];
    if degree > 0 {
        sizes.push(3 * rest_coefficients(degree) * n);
    }
    sizes
}

/// The Gaussians of the attribute streams.
fn assemble(
    streams: &[&[u8]],
    n: usize,
    degree: usize,
    bits: u8,
    version: u32,
) -> Result<GaussianSet, DecodeError> {
    let mut set = GaussianSet::try_zeros(n, degree)?;
    let scale = f64::from(1u32 << bits);
    for (k, b) in streams[0].chunks_exact(3).enumerate() {
        let fixed = i32::from_le_bytes([b[0], b[1], b[2], if b[2] & 0x80 != 0 { 0xff } else { 0 }]);
        set.means[k] = (f64::from(fixed) / scale) as f32;
    }
    for (i, &a) in streams[1].iter().enumerate() {
        set.opacity_logits[i] = opacity_of_level(u32::from(a)) as f32;
    }
    for (k, &c) in streams[2].iter().enumerate() {
        set.sh_dc[k] = ((f64::from(c) / 255.0 - 0.5) / COLOUR_SCALE) as f32;
    }
    for (k, &s) in streams[3].iter().enumerate() {
        set.log_scales[k] = (f64::from(s) / 16.0 - 10.0) as f32;
    }
    let stride = if version == 2 { 3 } else { 4 };
    for (i, r) in streams[4].chunks_exact(stride).enumerate() {
        let mut xyzw = [0.0f64; 4];
        if version == 2 {
            for k in 0..3 {
                xyzw[k] = f64::from(r[k]) / 127.5 - 1.0;
            }
            xyzw[3] = (1.0 - xyzw[..3].iter().map(|v| v * v).sum::<f64>())
                .max(0.0)
                .sqrt();
        } else {
            let mut packed = u32::from_le_bytes(r.try_into().unwrap());
            let largest = (packed >> 30) as usize;
            let mut sum = 0.0;
            for k in (0..4).rev() {
                if k != largest {
                    let magnitude = f64::from(packed & 511);
                    let negative = packed >> 9 & 1 == 1;
                    packed >>= 10;
                    let v = std::f64::consts::FRAC_1_SQRT_2 * magnitude / 511.0;
                    xyzw[k] = if negative { -v } else { v };
                    sum += v * v;
                }
            }
            xyzw[largest] = (1.0 - sum).max(0.0).sqrt();
        }
        let q = [xyzw[3], xyzw[0], xyzw[1], xyzw[2]];
        for k in 0..4 {
            set.quats[4 * i + k] = q[k] as f32;
        }
    }
    if degree > 0 {
        for (k, &v) in streams[5].iter().enumerate() {
            set.sh_rest[k] = ((f64::from(v) - 128.0) / 128.0) as f32;
        }
    }
    turn_about_x(&mut set);
    Ok(set)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::render;
    use crate::Camera;

    /// Gaussians of SH degree 3 in front of a camera at the origin looking down +z, from a
    /// fixed sequence (no two alike, every coefficient non-zero).
    fn scene(seed: f32) -> GaussianSet {
        let mut set = GaussianSet::zeros(40, 3);
        let value = |i: usize, scale: f32| (i as f32 * 0.731 + seed).sin() * scale;
        for (i, v) in set.means.iter_mut().enumerate() {
            *v = if i % 3 == 2 {
                4.0 + value(i, 1.0)
            } else {
                value(i, 1.2)
            };
        }
        for (i, v) in set.log_scales.iter_mut().enumerate() {
            *v = -2.0 + value(i + 7, 0.6);
        }
        for (i, v) in set.quats.iter_mut().enumerate() {
            *v = value(i + 3, 1.0);
        }
        for (i, v) in set.opacity_logits.iter_mut().enumerate() {
            *v = value(i + 11, 2.0);
        }
        for (i, v) in set.sh_dc.iter_mut().enumerate() {
            *v = value(i + 5, 1.0);
        }
        for (i, v) in set.sh_rest.iter_mut().enumerate() {
            *v = value(i + 13, 0.4);
        }
        set
    }

    /// The half turn is a rotation of the whole scene: the turned Gaussians seen by the turned
    /// camera are the picture the Gaussians give (positions, orientations and the colour of
    /// every view direction, each SH degree included), and two turns are none.
    #[test]
    fn the_half_turn_about_x_turns_the_scene_and_undoes_itself() {
        for seed in [0.0, 1.3, 2.9] {
            let set = scene(seed);
            let mut turned = set.clone();
            turn_about_x(&mut turned);
            for (eye, target) in [
                ([0.0, 0.0, 0.0], [0.0, 0.0, 4.0]),
                ([2.0, -1.0, 1.0], [0.0, 0.0, 4.0]),
            ] {
                let camera = Camera::look_at(eye, target, [0.0, -1.0, 0.0], 1.2, 48, 40).unwrap();
                let flip = [1.0, -1.0, -1.0];
                let mut rotation = camera.rotation;
                for row in &mut rotation {
                    for (r, f) in row.iter_mut().zip(flip) {
                        *r *= f;
                    }
                }
                let turned_camera = Camera::new(
                    rotation,
                    camera.translation,
                    [camera.fx, camera.fy, camera.cx, camera.cy],
                    camera.width,
                    camera.height,
                )
                .unwrap();
                let a = render(&set, &camera, [0.0; 3]).image.data;
                let b = render(&turned, &turned_camera, [0.0; 3]).image.data;
                let lit = a.iter().filter(|v| **v > 0.05).count();
                assert!(lit > a.len() / 10, "the Gaussians are in view ({lit} lit)");
                let worst = a
                    .iter()
                    .zip(&b)
                    .map(|(x, y)| (x - y).abs())
                    .fold(0.0, f32::max);
                assert!(
                    worst < 1e-4,
                    "seed {seed}, eye {eye:?}: pictures differ by {worst}"
                );
            }
            turn_about_x(&mut turned);
            assert_eq!(turned, set);
        }
    }

    /// A sign of the turn taken away (each SH coefficient, a quaternion or position part) is
    /// seen: the check above would fail without it.
    #[test]
    fn each_sh_sign_matters() {
        let set = scene(0.4);
        let camera = Camera::look_at(
            [1.0, 0.5, 0.0],
            [0.0, 0.0, 4.0],
            [0.0, -1.0, 0.0],
            1.2,
            32,
            32,
        )
        .unwrap();
        let base = render(&set, &camera, [0.0; 3]).image.data;
        for coefficient in 0..15 {
            let mut changed = set.clone();
            for g in 0..changed.len() {
                for c in 0..3 {
                    changed.sh_rest[(g * 15 + coefficient) * 3 + c] *= -1.0;
                }
            }
            let other = render(&changed, &camera, [0.0; 3]).image.data;
            let worst = base
                .iter()
                .zip(&other)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f32::max);
            assert!(worst > 1e-3, "coefficient {coefficient} has no effect here");
        }
    }
}
