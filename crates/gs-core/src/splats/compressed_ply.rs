//! SuperSplat's compressed PLY (`.compressed.ply`), as `@playcanvas/splat-transform` writes
//! and reads it. A binary little-endian PLY of three elements:
//! - `chunk` (one per 256 Gaussians): 18 floats, the chunk's `min_x..max_z` of the positions,
//!   `min_scale_x..max_scale_z` of the log-scales (each bound clamped to `[-20, 20]`) and
//!   `min_r..max_b` of the colours `0.5 + C0 f_dc`;
//! - `vertex`: four `uint`s: position and log-scale as 11-10-11 bits within the chunk's bounds;
//!   the rotation as "smallest three" (2 bits for the largest of `(w, x, y, z)`, made positive,
//!   then the other three, each `q sqrt(1/2) + 1/2` in 10 bits); colour 8-8-8 within the
//!   bounds and `sigmoid(opacity)` in 8 bits;
//! - `sh` (when the degree is above 0): one `uchar` per `f_rest_*` (INRIA's channel-major
//!   order), `trunc((v / 8 + 1/2) 256)`: the range `[-4, 4]` in steps of 1/32.
//!
//! The writer sorts the Gaussians in Morton order first (10 bits an axis over the bounding box,
//! finer within runs of more than 256 equal codes), as splat-transform does, so the file order
//! is not the input's. A bound pair closer than 1e-5 stores 0.

use super::DecodeError;
use super::{check_finite, check_rotations, opacity_of_level, sigmoid};
use crate::ply::elements::{check_body_length, parse_elements};
use crate::sh::C0;
use crate::GaussianSet;

/// Gaussians a chunk holds.
const CHUNK: usize = 256;

/// The chunk properties, in file order.
const CHUNK_PROPERTIES: [&str; 18] = [
    "min_x",
    "min_y",
    "min_z",
    "max_x",
    "max_y",
    "max_z",
    "min_scale_x",
    "min_scale_y",
    "min_scale_z",
    "max_scale_x",
    "max_scale_y",
    "max_scale_z",
    "min_r",
    "min_g",
    "min_b",
    "max_r",
    "max_g",
    "max_b",
];

/// The vertex properties, in file order.
const VERTEX_PROPERTIES: [&str; 4] = [
    "packed_position",
    "packed_rotation",
    "packed_scale",
    "packed_color",
];

/// The bound of a chunk's log-scales the format's writers keep to (SuperSplat's and
/// splat-transform's clamp).
const LOG_SCALE_BOUND: f64 = 20.0;

/// Refuses chunk `c`'s `bounds` (in [`CHUNK_PROPERTIES`] order; the colour range only where
/// `colour` says the file has one) where a writer could not have written them: a bound not
/// finite, a minimum above its maximum, or a log-scale bound outside `[-20, 20]`. Decoded, such
/// a chunk's Gaussians would vanish from renders without a word.
fn check_chunk_bounds(c: usize, bounds: &[f64; 18], colour: bool) -> Result<(), String> {
    let used = if colour { 18 } else { 12 };
    for k in 0..used {
        let v = bounds[k];
        if !v.is_finite() {
            return Err(format!("chunk {c}: {} is {v}", CHUNK_PROPERTIES[k]));
        }
        if (6..12).contains(&k) && v.abs() > LOG_SCALE_BOUND {
            return Err(format!(
                "chunk {c}: {} is {v}, outside the [-20, 20] log-scales the format holds",
                CHUNK_PROPERTIES[k]
            ));
        }
    }
    for lo in [0, 1, 2, 6, 7, 8, 12, 13, 14]
        .into_iter()
        .filter(|&k| k < used)
    {
        if bounds[lo] > bounds[lo + 3] {
            return Err(format!(
                "chunk {c}: {} {} is above {} {}",
                CHUNK_PROPERTIES[lo],
                bounds[lo],
                CHUNK_PROPERTIES[lo + 3],
                bounds[lo + 3]
            ));
        }
    }
    Ok(())
}

/// Whether `bytes` is a PLY file with a `chunk` element (the compressed layout).
pub fn is_compressed(bytes: &[u8]) -> bool {
    let head = &bytes[..bytes.len().min(4096)];
    let text = String::from_utf8_lossy(head);
    text.starts_with("ply")
        && text
            .lines()
            .take_while(|l| l.trim() != "end_header")
            .any(|l| l.split_whitespace().take(2).eq(["element", "chunk"]))
}

/// `v` in `[min, max]` as a fraction (0 at or below, 1 at or above; 0 for a range under 1e-5).
fn normalize(v: f64, min: f64, max: f64) -> f64 {
    if v <= min {
        0.0
    } else if v >= max {
        1.0
    } else if max - min < 1e-5 {
        0.0
    } else {
        (v - min) / (max - min)
    }
}

/// `t` in `[0, 1]` as an unsigned `bits`-bit integer, rounded.
fn unorm(t: f64, bits: u32) -> u32 {
    let top = f64::from((1u32 << bits) - 1);
    (t * top + 0.5).floor().clamp(0.0, top) as u32
}

/// Three fractions as 11-10-11 bits.
fn pack_11_10_11(t: [f64; 3]) -> u32 {
    unorm(t[0], 11) << 21 | unorm(t[1], 10) << 11 | unorm(t[2], 11)
}

/// The smallest-three packing of quaternion `q` (`w, x, y, z`, any norm but 0).
fn pack_rotation(q: [f64; 4]) -> u32 {
    let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    let mut a = q.map(|v| v / norm);
    let largest = (1..4).fold(
        0,
        |best, i| {
            if a[i].abs() > a[best].abs() {
                i
            } else {
                best
            }
        },
    );
    if a[largest] < 0.0 {
        a = a.map(|v| -v);
    }
    let half_sqrt2 = std::f64::consts::SQRT_2 * 0.5;
    (0..4)
        .filter(|&i| i != largest)
        .fold(largest as u32, |packed, i| {
            packed << 10 | unorm(a[i] * half_sqrt2 + 0.5, 10)
        })
}

/// The order splat-transform writes Gaussians in: Morton codes of 10 bits an axis over the
/// bounding box of `indices`, sorted stably; a run of more than 256 equal codes is sorted again
/// over its own box.
fn morton_sort(means: &[f32], indices: &mut [usize]) {
    if indices.is_empty() {
        return;
    }
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for &i in indices.iter() {
        for k in 0..3 {
            let v = f64::from(means[3 * i + k]);
            lo[k] = lo[k].min(v);
            hi[k] = hi[k].max(v);
        }
    }
    let len = [0, 1, 2].map(|k| hi[k] - lo[k]);
    if len.iter().all(|&l| l == 0.0) || len.iter().any(|l| !l.is_finite()) {
        return;
    }
    let mul = len.map(|l| if l == 0.0 { 0.0 } else { 1024.0 / l });
    let spread = |v: u32| {
        let mut v = v & 0x3ff;
        v = (v ^ (v << 16)) & 0xff00_00ff;
        v = (v ^ (v << 8)) & 0x0300_f00f;
        v = (v ^ (v << 4)) & 0x030c_30c3;
        (v ^ (v << 2)) & 0x0924_9249
    };
    let code = |i: usize| {
        let cell = |k: usize| ((f64::from(means[3 * i + k]) - lo[k]) * mul[k]).min(1023.0) as u32;
        (spread(cell(2)) << 2) + (spread(cell(1)) << 1) + spread(cell(0))
    };
    let mut keyed: Vec<(u32, usize)> = indices.iter().map(|&i| (code(i), i)).collect();
    keyed.sort_by_key(|&(c, _)| c);
    for (slot, &(_, i)) in indices.iter_mut().zip(&keyed) {
        *slot = i;
    }
    let mut start = 0;
    while start < keyed.len() {
        let end = start
            + keyed[start..]
                .iter()
                .take_while(|k| k.0 == keyed[start].0)
                .count();
        if end - start > CHUNK {
            morton_sort(means, &mut indices[start..end]);
        }
        start = end;
    }
}

/// The smallest and largest of `values`.
fn bounds(values: impl Iterator<Item = f64>) -> (f64, f64) {
    values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    })
}

/// The compressed PLY bytes of `set` (Morton order); an error names a value that cannot be
/// written.
pub fn encode(set: &GaussianSet) -> Result<Vec<u8>, String> {
    check_finite(set)?;
    check_rotations(set)?;
    let n = set.len();
    let chunks = n.div_ceil(CHUNK);
    let rest = 3 * (set.sh_coeffs() - 1);
    let mut order: Vec<usize> = (0..n).collect();
    morton_sort(&set.means, &mut order);
    let mut header = String::from("ply\nformat binary_little_endian 1.0\n");
    header += "comment Generated by clipgaussian\n";
    header += &format!("element chunk {chunks}\n");
    for p in CHUNK_PROPERTIES {
        header += &format!("property float {p}\n");
    }
    header += &format!("element vertex {n}\n");
    for p in VERTEX_PROPERTIES {
        header += &format!("property uint {p}\n");
    }
    if rest > 0 {
        header += &format!("element sh {n}\n");
        for k in 0..rest {
            header += &format!("property uchar f_rest_{k}\n");
        }
    }
    header += "end_header\n";
    let mut chunk_data = Vec::with_capacity(chunks * 18 * 4);
    let mut vertex_data = Vec::with_capacity(n * 16);
    let mut sh_data = Vec::with_capacity(n * rest);
    // The colour as splat-transform holds it: computed in f64, stored in f32.
    let colour =
        |i: usize, c: usize| f64::from((f64::from(set.sh_dc[3 * i + c]) * C0 + 0.5) as f32);
    for members in order.chunks(CHUNK) {
        let axis = |values: &dyn Fn(usize) -> f64| bounds(members.iter().map(|&i| values(i)));
        let position = [0, 1, 2].map(|k| axis(&|i| f64::from(set.means[3 * i + k])));
        let scale = [0, 1, 2].map(|k| {
            let (lo, hi) = axis(&|i| f64::from(set.log_scales[3 * i + k]));
            (lo.clamp(-20.0, 20.0), hi.clamp(-20.0, 20.0))
        });
        let rgb = [0, 1, 2].map(|c| axis(&|i| colour(i, c)));
        for bound in [position, scale, rgb] {
            for v in bound.map(|b| b.0).into_iter().chain(bound.map(|b| b.1)) {
                chunk_data.extend((v as f32).to_le_bytes());
            }
        }
        for &i in members {
            let fractions = |b: &[(f64, f64); 3], values: [f32; 3]| {
                [0, 1, 2].map(|k| normalize(f64::from(values[k]), b[k].0, b[k].1))
            };
            let m = [0, 1, 2].map(|k| set.means[3 * i + k]);
            let s = [0, 1, 2].map(|k| set.log_scales[3 * i + k]);
            let q = [0, 1, 2, 3].map(|k| f64::from(set.quats[4 * i + k]));
            let c = [0, 1, 2].map(|k| normalize(colour(i, k), rgb[k].0, rgb[k].1));
            let alpha = sigmoid(f64::from(set.opacity_logits[i]));
            let packed_colour =
                unorm(c[0], 8) << 24 | unorm(c[1], 8) << 16 | unorm(c[2], 8) << 8 | unorm(alpha, 8);
            for word in [
                pack_11_10_11(fractions(&position, m)),
                pack_rotation(q),
                pack_11_10_11(fractions(&scale, s)),
                packed_colour,
            ] {
                vertex_data.extend(word.to_le_bytes());
            }
            let coefficients = rest / 3;
            for k in 0..rest {
                let (channel, coefficient) = (k / coefficients, k % coefficients);
                let v = f64::from(set.sh_rest[rest * i + 3 * coefficient + channel]);
                sh_data.push(((v / 8.0 + 0.5) * 256.0).trunc().clamp(0.0, 255.0) as u8);
            }
        }
    }
    let mut out = header.into_bytes();
    out.extend(chunk_data);
    out.extend(vertex_data);
    out.extend(sh_data);
    Ok(out)
}

/// The Gaussians of compressed PLY bytes, in file order.
pub fn decode(bytes: &[u8]) -> Result<GaussianSet, DecodeError> {
    let header = parse_elements(bytes)?;
    if header.format != "binary_little_endian" {
        return Err(format!(
            "format {}: a compressed PLY is binary_little_endian",
            header.format
        )
        .into());
    }
    let starts = check_body_length(&header, bytes)?;
    let elements = header.elements;
    let find = |name: &str| elements.iter().position(|e| e.name == name);
    let (chunk_e, vertex_e) = match (find("chunk"), find("vertex")) {
        (Some(c), Some(v)) => (c, v),
        _ => return Err("a compressed PLY has a chunk and a vertex element".into()),
    };
    let (chunk, vertex) = (&elements[chunk_e], &elements[vertex_e]);
    let n = vertex.count;
    if chunk.count != n.div_ceil(CHUNK) {
        return Err(format!(
            "{} chunks for {n} Gaussians; {} expected",
            chunk.count,
            n.div_ceil(CHUNK)
        )
        .into());
    }
    // Every property's place, found once: the chunk bounds by name (a colour range may be
    // absent in older files: the 8-bit colour is then the colour), the packed words, the SH.
    let word_at = |e: usize, name: &str| -> Result<Option<usize>, String> {
        match elements[e].offset(name) {
            Some((offset, 4)) => Ok(Some(offset)),
            Some(_) => Err(format!(
                "{} property {name} is not 4 bytes",
                elements[e].name
            )),
            None => Ok(None),
        }
    };
    let mut bound_offsets = [0usize; 18];
    let mut has_colour_range = true;
    for (k, name) in CHUNK_PROPERTIES.iter().enumerate() {
        match word_at(chunk_e, name)? {
            Some(offset) => bound_offsets[k] = offset,
            None if k >= 12 => has_colour_range = false,
            None => return Err(format!("chunk has no float property {name}").into()),
        }
    }
    let mut word_offsets = [0usize; 4];
    for (k, name) in VERTEX_PROPERTIES.iter().enumerate() {
        word_offsets[k] =
            word_at(vertex_e, name)?.ok_or(format!("vertex has no uint property {name}"))?;
    }
    let sh = find("sh");
    let rest = match sh {
        Some(s) => {
            let count = elements[s].properties.len();
            if elements[s].count != n || ![0, 9, 24, 45].contains(&count) {
                return Err(format!(
                    "element sh: {} rows of {count} values; {n} rows of 9, 24 or 45 expected",
                    elements[s].count
                )
                .into());
            }
            count
        }
        None => 0,
    };
    let sh_offsets: Vec<usize> = match sh {
        Some(s) => (0..rest)
            .map(|k| match elements[s].offset(&format!("f_rest_{k}")) {
                Some((offset, 1)) => Ok(offset),
                _ => Err(format!("sh has no uchar property f_rest_{k}")),
            })
            .collect::<Result<_, _>>()?,
        None => Vec::new(),
    };
    let f32_at = |at: usize| f64::from(f32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()));
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    let bounds: Vec<[f64; 18]> = (0..chunk.count)
        .map(|c| {
            let row = starts[chunk_e] + c * chunk.stride();
            bound_offsets.map(|offset| f32_at(row + offset))
        })
        .collect();
    for (c, b) in bounds.iter().enumerate() {
        check_chunk_bounds(c, b, has_colour_range)?;
    }
    let degree = [0, 9, 24, 45].iter().position(|&c| c == rest).unwrap_or(0);
    let mut set = GaussianSet::try_zeros(n, degree)?;
    let unpack = |bits: u32, width: u32| {
        f64::from(bits & ((1 << width) - 1)) / f64::from((1u32 << width) - 1)
    };
    let three = |w: u32| [unpack(w >> 21, 11), unpack(w >> 11, 10), unpack(w, 11)];
    let lerp = |t: f64, lo: f64, hi: f64| lo * (1.0 - t) + hi * t;
    for i in 0..n {
        let b = &bounds[i / CHUNK];
        let row = starts[vertex_e] + i * vertex.stride();
        let [position, rotation, scale, colour] = word_offsets.map(|offset| u32_at(row + offset));
        let (p, s) = (three(position), three(scale));
        for k in 0..3 {
            set.means[3 * i + k] = lerp(p[k], b[k], b[3 + k]) as f32;
            set.log_scales[3 * i + k] = lerp(s[k], b[6 + k], b[9 + k]) as f32;
        }
        let levels = [colour >> 24, colour >> 16, colour >> 8].map(|v| f64::from(v & 255) / 255.0);
        for k in 0..3 {
            let value = if has_colour_range {
                lerp(levels[k], b[12 + k], b[15 + k])
            } else {
                levels[k]
            };
            set.sh_dc[3 * i + k] = ((value - 0.5) / C0) as f32;
        }
        set.opacity_logits[i] = opacity_of_level(colour & 255) as f32;
        let largest = (rotation >> 30) as usize;
        let mut q = [0.0f64; 4];
        let mut shift = 30;
        for (k, slot) in q.iter_mut().enumerate() {
            if k != largest {
                shift -= 10;
                *slot = (unpack(rotation >> shift, 10) - 0.5) * std::f64::consts::SQRT_2;
            }
        }
        q[largest] = (1.0 - q.iter().map(|v| v * v).sum::<f64>()).max(0.0).sqrt();
        for k in 0..4 {
            set.quats[4 * i + k] = q[k] as f32;
        }
        if let Some(s) = sh {
            let row = starts[s] + i * elements[s].stride();
            let coefficients = rest / 3;
            for (k, offset) in sh_offsets.iter().enumerate() {
                let v = match bytes[row + offset] {
                    0 => -4.0,
                    255 => 4.0,
                    b => ((f64::from(b) + 0.5) / 256.0 - 0.5) * 8.0,
                };
                let (channel, coefficient) = (k / coefficients, k % coefficients);
                set.sh_rest[rest * i + 3 * coefficient + channel] = v as f32;
            }
        }
    }
    Ok(set)
}
