//! PlayCanvas's SOG (version 2), as `@playcanvas/splat-transform` and SuperSplat write it: a
//! `meta.json` and lossless WebP pictures (one texel a Gaussian, row by row), either as files
//! beside `meta.json` or bundled in one zip file (`.sog`). Read and written.
//!
//! - positions: `means_l` and `means_u` hold the low and high byte of a 16-bit fraction of
//!   each axis between `means.mins` and `means.maxs`, of `sign(x) ln(|x| + 1)`;
//! - rotations: `quats`, "smallest three" (three bytes of `(v sqrt 2 + 1) / 2`, the fourth
//!   `252 + ` the index, in `(w, x, y, z)`, of the largest component, taken positive);
//! - scales: `scales`, three bytes indexing the 256 log-scales of `scales.codebook`;
//! - colour: `sh0`, three bytes indexing `sh0.codebook` (`f_dc`) and the opacity's 8-bit
//!   level (its logit kept within `[1e-6, 1 - 1e-6]`, as splat-transform reads it);
//! - SH above degree 0 (`shN`, when present): `shN_labels` holds a 16-bit palette entry a
//!   Gaussian; `shN_centroids` holds, 64 entries a row, each entry's coefficients as bytes
//!   indexing `shN.codebook`, one texel a coefficient with the channels in R, G, B.
//!
//! Values are as held in 3DGS's PLY frame (splat-transform writes SOG in it). An invalid
//! rotation tag reads as no rotation and a palette entry past `shN.count` as no SH, as
//! splat-transform reads them. Version 1 files (no `version`) are refused.
//!
//! Writing quantises as splat-transform 3.7 does (positions truncated to 16 bits, rotation
//! bytes truncated, the scale and colour codebooks by its `quantize1d`, opacity levels
//! truncated), with two differences: the Gaussians keep their order (splat-transform sorts
//! them in Morton order, which compresses better; ours keeps a model and its stylized copy
//! the same Gaussians, as `interpolate` needs), and the SH palette is a deterministic k-means
//! ([`codebook::palette`]) of as many entries as splat-transform's (`1024 x 2^floor(log2(N /
//! 1024))`, at most 65536) where splat-transform seeds its k-means at random.

use std::io::Read;
use std::path::Path;

use serde::Deserialize;

use super::codebook::{self, Codebook};
use super::DecodeError;
use crate::GaussianSet;

/// The file a SOG folder's pictures are listed in, and the bundle's entry of it.
pub const META_JSON: &str = "meta.json";

#[derive(Deserialize)]
struct Means {
    mins: [f64; 3],
    maxs: [f64; 3],
    files: Vec<String>,
}

#[derive(Deserialize)]
struct Coded {
    codebook: Vec<f64>,
    files: Vec<String>,
}

#[derive(Deserialize)]
struct Files {
    files: Vec<String>,
}

#[derive(Deserialize)]
struct Palette {
    count: usize,
    bands: usize,
    codebook: Vec<f64>,
    files: Vec<String>,
}

#[derive(Deserialize)]
struct Meta {
    version: Option<u32>,
    count: usize,
    means: Means,
    scales: Coded,
    quats: Files,
    sh0: Coded,
    #[serde(rename = "shN")]
    sh_n: Option<Palette>,
}

/// A decoded picture: RGBA bytes, row by row.
struct Texture {
    width: usize,
    height: usize,
    rgba: Vec<u8>,
}

impl Texture {
    /// The texel `i` (row by row).
    fn texel(&self, i: usize) -> [u8; 4] {
        let at = 4 * i;
        [
            self.rgba[at],
            self.rgba[at + 1],
            self.rgba[at + 2],
            self.rgba[at + 3],
        ]
    }
}

/// Decodes the WebP `bytes` of the picture `name`, at most `max_pixels` pixels.
fn webp(name: &str, bytes: &[u8], max_pixels: u64) -> Result<Texture, String> {
    let bad = |e: String| format!("{name}: {e}");
    let mut reader =
        image::ImageReader::with_format(std::io::Cursor::new(bytes), image::ImageFormat::WebP);
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(max_pixels.saturating_mul(8).max(1 << 16));
    reader.limits(limits);
    let picture = reader.decode().map_err(|e| bad(e.to_string()))?.to_rgba8();
    Ok(Texture {
        width: picture.width() as usize,
        height: picture.height() as usize,
        rgba: picture.into_raw(),
    })
}

/// `sign(x) ln(|x| + 1)`: positions are stored of it.
fn to_log(x: f64) -> f64 {
    x.signum() * (x.abs() + 1.0).ln()
}

/// `x` from `sign(x) ln(|x| + 1)`.
fn from_log(v: f64) -> f64 {
    v.signum() * (v.abs().exp() - 1.0)
}

/// The Gaussians of a SOG whose `meta.json` text is `meta`, its pictures given by `load`
/// (the bytes of a file named in it).
fn decode(
    meta: &[u8],
    mut load: impl FnMut(&str) -> Result<Vec<u8>, String>,
) -> Result<GaussianSet, DecodeError> {
    let meta: Meta = serde_json::from_slice(meta).map_err(|e| format!("{META_JSON}: {e}"))?;
    match meta.version {
        Some(2) => {}
        None => {
            return Err(
                "SOG version 1 (no `version` in meta.json) is not read: convert it \
                        with a current @playcanvas/splat-transform"
                    .into(),
            )
        }
        Some(v) => return Err(format!("SOG version {v}: only version 2 is read").into()),
    }
    let n = meta.count;
    let degree = match meta.sh_n.as_ref().map(|p| p.bands) {
        None | Some(0) => 0,
        Some(b @ 1..=3) => b,
        Some(b) => return Err(format!("shN.bands {b}: SH bands 1 to 3 are read").into()),
    };
    // A picture holds a texel a Gaussian (a few rows of slack), and no more than a picture
    // read may have.
    let max_pixels = (n as u64)
        .saturating_add(1 << 20)
        .min(crate::image::MAX_PICTURE_PIXELS);
    let mut picture = |files: &[String], k: usize, what: &str| -> Result<Texture, String> {
        let name = files
            .get(k)
            .ok_or_else(|| format!("{META_JSON}: {what} names no picture {k}"))?;
        let texture = webp(name, &load(name)?, max_pixels)?;
        if texture.width * texture.height < n {
            return Err(format!(
                "{name}: {}x{} texels for {n} Gaussians",
                texture.width, texture.height
            ));
        }
        Ok(texture)
    };
    for (what, len) in [
        ("scales.codebook", meta.scales.codebook.len()),
        ("sh0.codebook", meta.sh0.codebook.len()),
    ] {
        if len < 256 && n > 0 {
            return Err(format!("{META_JSON}: {what} has {len} entries, not 256").into());
        }
    }
    let (lo, hi) = (
        picture(&meta.means.files, 0, "means")?,
        picture(&meta.means.files, 1, "means")?,
    );
    let quats = picture(&meta.quats.files, 0, "quats")?;
    let scales = picture(&meta.scales.files, 0, "scales")?;
    let sh0 = picture(&meta.sh0.files, 0, "sh0")?;
    // Allocated once the pictures have shown the count is real.
    let mut set = GaussianSet::try_zeros(n, degree)?;
    let (m0, m1) = (meta.means.mins, meta.means.maxs);
    const INDEX: [[usize; 3]; 4] = [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]];
    for i in 0..n {
        let (l, h) = (lo.texel(i), hi.texel(i));
        for k in 0..3 {
            let fraction = f64::from(u16::from(l[k]) | u16::from(h[k]) << 8) / 65535.0;
            let range = match m1[k] - m0[k] {
                0.0 => 1.0,
                r => r,
            };
            set.means[3 * i + k] = from_log(m0[k] + range * fraction) as f32;
        }
        let q = quats.texel(i);
        let mut wxyz = [1.0f64, 0.0, 0.0, 0.0];
        if (252..=255).contains(&q[3]) {
            let largest = usize::from(q[3] - 252);
            let mut sum = 0.0;
            for (j, &slot) in INDEX[largest].iter().enumerate() {
                let v = (f64::from(q[j]) / 255.0 * 2.0 - 1.0) / std::f64::consts::SQRT_2;
                wxyz[slot] = v;
                sum += v * v;
            }
            wxyz[largest] = (1.0 - sum).max(0.0).sqrt();
        }
        for k in 0..4 {
            set.quats[4 * i + k] = wxyz[k] as f32;
        }
        let s = scales.texel(i);
        let c = sh0.texel(i);
        for k in 0..3 {
            set.log_scales[3 * i + k] = meta.scales.codebook[usize::from(s[k])] as f32;
            set.sh_dc[3 * i + k] = meta.sh0.codebook[usize::from(c[k])] as f32;
        }
        let p = (f64::from(c[3]) / 255.0).clamp(1e-6, 1.0 - 1e-6);
        set.opacity_logits[i] = (p / (1.0 - p)).ln() as f32;
    }
    if let Some(palette) = meta.sh_n.as_ref().filter(|_| degree > 0) {
        let coefficients = (degree + 1) * (degree + 1) - 1;
        if palette.codebook.len() < 256 {
            return Err(format!(
                "{META_JSON}: shN.codebook has {} entries, not 256",
                palette.codebook.len()
            )
            .into());
        }
        let labels = picture(&palette.files, 1, "shN")?;
        let name = palette.files.first().map_or("", String::as_str);
        // At most 65536 palette entries of up to 15 coefficients.
        let centroids = webp(name, &load(name)?, 65536 * 15)?;
        if centroids.width != 64 * coefficients {
            return Err(format!(
                "{name}: {} texels wide, {} expected for {degree} SH bands",
                centroids.width,
                64 * coefficients
            )
            .into());
        }
        for i in 0..n {
            let t = labels.texel(i);
            let label = usize::from(t[0]) | usize::from(t[1]) << 8;
            if label >= palette.count {
                continue;
            }
            let (row, column) = (label / 64, (label % 64) * coefficients);
            if row >= centroids.height {
                continue;
            }
            for j in 0..coefficients {
                let texel = centroids.texel(row * centroids.width + column + j);
                for ch in 0..3 {
                    set.sh_rest[3 * (coefficients * i + j) + ch] =
                        palette.codebook[usize::from(texel[ch])] as f32;
                }
            }
        }
    }
    super::check_finite(&set)?;
    Ok(set)
}

/// The Gaussians of a bundled `.sog` (a zip holding `meta.json` and its pictures).
pub fn decode_bundle(bytes: &[u8]) -> Result<GaussianSet, DecodeError> {
    let mut zip = zip::ZipArchive::new(std::io::Cursor::new(bytes))
        .map_err(|e| format!("not a SOG bundle (a zip file): {e}"))?;
    let mut entry = |name: &str| -> Result<Vec<u8>, String> {
        let mut file = zip
            .by_name(name)
            .map_err(|e| format!("the bundle's {name}: {e}"))?;
        let mut bytes = Vec::new();
        // An entry says its size; no more than the bundle could hold is read.
        let limit = bytes_limit(file.size());
        file.by_ref()
            .take(limit)
            .read_to_end(&mut bytes)
            .map_err(|e| format!("the bundle's {name}: {e}"))?;
        Ok(bytes)
    };
    let meta = entry(META_JSON)?;
    decode(&meta, entry)
}

/// The bytes read of an entry: its stated size, within 1 GiB.
fn bytes_limit(size: u64) -> u64 {
    size.min(1 << 30)
}

/// The Gaussians of a SOG folder's `meta.json` at `path`, its pictures beside it.
pub fn decode_folder(path: &Path) -> Result<GaussianSet, DecodeError> {
    let folder = path.parent().unwrap_or(Path::new("."));
    let meta = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    decode(&meta, |name| {
        // Only a file beside meta.json: no folders, no way out of it.
        if name.contains(['/', '\\']) || name == ".." {
            return Err(format!("{META_JSON}: {name:?} is not a file beside it"));
        }
        let file = folder.join(name);
        std::fs::read(&file).map_err(|e| format!("{}: {e}", file.display()))
    })
}

/// The widest side of a WebP picture, in texels.
const MAX_SIDE: usize = 16383;

/// The pictures of a SOG and its `meta.json`: `(file name, bytes)`, `meta.json` last.
pub type SogFiles = Vec<(String, Vec<u8>)>;

/// The SOG files of `set` (its order kept; see the module's notes on quantisation); an error
/// names a value the format cannot hold.
pub fn encode(set: &GaussianSet) -> Result<SogFiles, String> {
    super::check_finite(set)?;
    super::check_rotations(set)?;
    let n = set.len();
    if n == 0 {
        return Err("a SOG holds at least one Gaussian; this model has none".into());
    }
    // splat-transform's layout: a near-square picture, both sides multiples of 4.
    let width = ((n as f64).sqrt() / 4.0).ceil() as usize * 4;
    let height = n.div_ceil(width).div_ceil(4) * 4;
    if width > MAX_SIDE || height > MAX_SIDE {
        return Err(format!(
            "{n} Gaussians need {width}x{height} texels, more than WebP's {MAX_SIDE} a side"
        ));
    }
    let picture = |texel: &dyn Fn(usize) -> [u8; 4]| -> Result<Vec<u8>, String> {
        let mut rgba = vec![0u8; 4 * width * height];
        for i in 0..n {
            rgba[4 * i..4 * i + 4].copy_from_slice(&texel(i));
        }
        lossless_webp(&rgba, width, height)
    };
    let mut files = SogFiles::new();

    // Positions: 16 bits of each axis's span of sign(x) ln(|x| + 1), truncated.
    let positions = LogPositions::of(&set.means);
    let fraction = |i: usize, k: usize| positions.level(set.means[3 * i + k], k);
    files.push((
        "means_l.webp".into(),
        picture(&|i| opaque([0, 1, 2].map(|k| fraction(i, k) as u8)))?,
    ));
    files.push((
        "means_u.webp".into(),
        picture(&|i| opaque([0, 1, 2].map(|k| (fraction(i, k) >> 8) as u8)))?,
    ));

    // Rotations: the unit quaternion's smallest three, the largest made positive.
    files.push((
        "quats.webp".into(),
        picture(&|i| smallest_three(&set.quats[4 * i..4 * i + 4]))?,
    ));

    // Log-scales and colours: a codebook each, pooled over the three axes or channels.
    let pooled = |values: &[f32]| -> Codebook {
        let columns: Vec<f32> = (0..3)
            .flat_map(|k| values.iter().skip(k).step_by(3).copied())
            .collect();
        codebook::scalar_codebook(&columns)
    };
    let label = |book: &Codebook, i: usize, k: usize| book.labels[k * n + i];
    let scales = pooled(&set.log_scales);
    files.push((
        "scales.webp".into(),
        picture(&|i| opaque([0, 1, 2].map(|k| label(&scales, i, k))))?,
    ));
    let colours = pooled(&set.sh_dc);
    files.push((
        "sh0.webp".into(),
        picture(&|i| {
            let alpha = super::sigmoid(f64::from(set.opacity_logits[i])) * 255.0;
            let [r, g, b] = [0, 1, 2].map(|k| label(&colours, i, k));
            [r, g, b, alpha.clamp(0.0, 255.0) as u8]
        })?,
    ));

    let sh_n = match set.sh_degree() {
        0 => None,
        degree => {
            let coefficients = (degree + 1) * (degree + 1) - 1;
            let dim = 3 * coefficients;
            // splat-transform's 1024 x 2^floor(log2(N / 1024)), capped at 65536: the largest
            // power of two not above N.
            let size = (1usize << n.ilog2()).min(65536);
            let palette = codebook::palette(&set.sh_rest, dim, size);
            let entries = palette.entries.len() / dim;
            let book = codebook::scalar_codebook(&palette.entries);
            // 64 entries a row, a texel a coefficient, the channels in R, G, B.
            let rows = entries.div_ceil(64);
            let mut rgba = vec![0u8; 4 * 64 * coefficients * rows];
            for e in 0..entries {
                for j in 0..coefficients {
                    let at = 4 * (e * coefficients + j);
                    for ch in 0..3 {
                        rgba[at + ch] = book.labels[e * dim + 3 * j + ch];
                    }
                    rgba[at + 3] = 255;
                }
            }
            files.push((
                "shN_centroids.webp".into(),
                lossless_webp(&rgba, 64 * coefficients, rows)?,
            ));
            files.push((
                "shN_labels.webp".into(),
                picture(&|i| {
                    let l = palette.labels[i];
                    [l as u8, (l >> 8) as u8, 0, 255]
                })?,
            ));
            Some(serde_json::json!({
                "count": entries,
                "bands": degree,
                "codebook": book.values,
                "files": ["shN_centroids.webp", "shN_labels.webp"],
            }))
        }
    };
    let mut meta = serde_json::json!({
        "version": 2,
        "asset": {"generator": concat!("clipgaussian ", env!("CARGO_PKG_VERSION"))},
        "count": n,
        "means": {
            "mins": positions.mins, "maxs": positions.maxs,
            "files": ["means_l.webp", "means_u.webp"],
        },
        "scales": {"codebook": scales.values, "files": ["scales.webp"]},
        "quats": {"files": ["quats.webp"]},
        "sh0": {"codebook": colours.values, "files": ["sh0.webp"]},
    });
    if let Some(sh_n) = sh_n {
        meta["shN"] = sh_n;
    }
    files.push((META_JSON.into(), meta.to_string().into_bytes()));
    Ok(files)
}

/// Positions stored as SOG stores them: each axis's `sign(x) ln(|x| + 1)` as a 16-bit fraction
/// of its span over the Gaussians, truncated.
#[derive(Clone, Copy, Debug)]
pub struct LogPositions {
    /// The least `sign(x) ln(|x| + 1)` of each axis.
    pub mins: [f64; 3],
    /// The greatest.
    pub maxs: [f64; 3],
}

impl LogPositions {
    /// The spans of `means` (`[N, 3]`).
    pub fn of(means: &[f32]) -> Self {
        let mut mins = [f64::INFINITY; 3];
        let mut maxs = [f64::NEG_INFINITY; 3];
        for p in means.chunks_exact(3) {
            for k in 0..3 {
                let v = to_log(f64::from(p[k]));
                mins[k] = mins[k].min(v);
                maxs[k] = maxs[k].max(v);
            }
        }
        Self { mins, maxs }
    }

    /// The 16-bit level of `x` on axis `k` (0 where the axis spans nothing).
    pub fn level(&self, x: f32, k: usize) -> u16 {
        let span = self.maxs[k] - self.mins[k];
        if span == 0.0 {
            return 0;
        }
        (65535.0 * (to_log(f64::from(x)) - self.mins[k]) / span) as u16
    }
}

/// A quaternion `(w, x, y, z)` as SOG stores it: the unit quaternion's three smallest
/// components, a byte each (`(v sqrt 2 + 1) / 2`, truncated), with the largest made positive,
/// and `252 +` the largest's index. A quaternion of no direction is four zero bytes (read as
/// no rotation).
pub fn smallest_three(q: &[f32]) -> [u8; 4] {
    const INDEX: [[usize; 3]; 4] = [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]];
    let norm = q.iter().map(|&v| f64::from(v).powi(2)).sum::<f64>().sqrt();
    if !(norm > 0.0) {
        return [0; 4];
    }
    let q = [0, 1, 2, 3].map(|k| f64::from(q[k]) / norm);
    let mut largest = 0;
    for k in 1..4 {
        if q[k].abs() > q[largest].abs() {
            largest = k;
        }
    }
    let s = q[largest].signum() * std::f64::consts::SQRT_2;
    let byte = |k: usize| (255.0 * (q[k] * s * 0.5 + 0.5)).clamp(0.0, 255.0) as u8;
    let [a, b, c] = INDEX[largest];
    [byte(a), byte(b), byte(c), 252 + largest as u8]
}

/// Three bytes and an opaque alpha, as a texel.
fn opaque([r, g, b]: [u8; 3]) -> [u8; 4] {
    [r, g, b, 255]
}

/// The lossless WebP of `rgba` (`width x height` texels, row by row), every byte kept (under
/// a zero alpha too).
fn lossless_webp(rgba: &[u8], width: usize, height: usize) -> Result<Vec<u8>, String> {
    use image::ImageEncoder;
    let mut out = Vec::new();
    image::codecs::webp::WebPEncoder::new_lossless(&mut out)
        .write_image(
            rgba,
            width as u32,
            height as u32,
            image::ExtendedColorType::Rgba8,
        )
        .map_err(|e| format!("WebP encoding: {e}"))?;
    Ok(out)
}

/// The `.sog` bundle of SOG `files`: a zip of them, stored (WebP is compressed already), with
/// no time stamp of the moment (the same model gives the same bytes).
pub fn bundle(files: &SogFiles) -> Result<Vec<u8>, String> {
    use std::io::Write;
    let mut zip = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    let options = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Stored)
        .last_modified_time(zip::DateTime::default());
    let failed = |e: &dyn std::fmt::Display| format!("writing the bundle: {e}");
    for (name, bytes) in files {
        zip.start_file(name.as_str(), options)
            .map_err(|e| failed(&e))?;
        zip.write_all(bytes).map_err(|e| failed(&e))?;
    }
    Ok(zip.finish().map_err(|e| failed(&e))?.into_inner())
}
