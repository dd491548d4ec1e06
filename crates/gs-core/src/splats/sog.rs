//! PlayCanvas's SOG (version 2), as `@playcanvas/splat-transform` and SuperSplat write it: a
//! `meta.json` and lossless WebP pictures (one texel a Gaussian, row by row), either as files
//! beside `meta.json` or bundled in one zip file (`.sog`). Read here, not written.
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

use std::io::Read;
use std::path::Path;

use serde::Deserialize;

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
