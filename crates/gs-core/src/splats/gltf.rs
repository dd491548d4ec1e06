//! glTF binary (`.glb`) with `KHR_gaussian_splatting`: one point primitive whose attributes
//! are the Gaussians, every value a `float` but the colour:
//! - `POSITION` (`VEC3`, with its bounds);
//! - `COLOR_0`: `0.5 + C0 f_dc` and `sigmoid(opacity)` as normalised `u8 x 4`, rounded;
//! - `KHR_gaussian_splatting:ROTATION`: the quaternion in glTF's `(x, y, z, w)` order, as held;
//! - `KHR_gaussian_splatting:SCALE`: linear scales (`exp` of the log-scales);
//! - `KHR_gaussian_splatting:OPACITY`: after the sigmoid;
//! - `KHR_gaussian_splatting:SH_DEGREE_l_COEF_c`: each SH coefficient as an RGB `VEC3`.
//!
//! glTF's `y` is up where 3DGS's is down: the scene is turned half a turn about `z` (`x` and `y`
//! negated, the rotations and SH coefficients with them), as `@playcanvas/splat-transform`
//! writes it, so viewers show it upright.
//!
//! [`decode`] reads such a file back (ours, splat-transform's, any writer's of the extension
//! with `float` attributes, or normalised bytes for the colour): it takes the first primitive
//! with `KHR_gaussian_splatting`, turns it back, takes logs of the scales and logits of the
//! opacities (kept within `[1e-6, 1 - 1e-6]`, so an opacity of 1 stays finite), and the degree-0
//! colour from `SH_DEGREE_0_COEF_0`, else from `COLOR_0`.

use super::{check_finite, check_linear_scales, sigmoid, DecodeError};
use crate::sh::C0;
use crate::GaussianSet;

/// glTF component types.
const FLOAT: u32 = 5126;
const UNSIGNED_BYTE: u32 = 5121;
/// glTF buffer view target of vertex attributes.
const ARRAY_BUFFER: u32 = 34962;

/// The sign each SH coefficient above degree 0 takes under a half turn about `z`
/// (`(x, y, z) -> (-x, -y, z)`), in 3DGS's coefficient order.
const HALF_TURN_SH_SIGNS: [f32; 15] = [
    -1.0, 1.0, -1.0, // degree 1: y, z, x
    1.0, -1.0, 1.0, -1.0, 1.0, // degree 2
    -1.0, 1.0, -1.0, 1.0, -1.0, 1.0, -1.0, // degree 3
];

/// The number of components of a glTF accessor type.
fn components(kind: &str) -> Option<usize> {
    match kind {
        "SCALAR" => Some(1),
        "VEC3" => Some(3),
        "VEC4" => Some(4),
        _ => None,
    }
}

/// One attribute: its name, bytes, component type, type and count.
struct Attribute {
    name: String,
    bytes: Vec<u8>,
    component: u32,
    kind: &'static str,
    normalized: bool,
}

fn floats(values: impl IntoIterator<Item = f32>) -> Vec<u8> {
    values.into_iter().flat_map(f32::to_le_bytes).collect()
}

/// The `.glb` bytes of `set`; an error names a value that cannot be written.
pub fn encode(set: &GaussianSet) -> Result<Vec<u8>, String> {
    check_finite(set)?;
    check_linear_scales(set)?;
    let n = set.len();
    let turned: Vec<[f32; 3]> = set
        .means
        .chunks_exact(3)
        .map(|m| [-m[0], -m[1], m[2]])
        .collect();
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for m in &turned {
        for k in 0..3 {
            lo[k] = lo[k].min(m[k]);
            hi[k] = hi[k].max(m[k]);
        }
    }
    let level = |v: f64| (v * 255.0).round().clamp(0.0, 255.0) as u8;
    let mut colour = Vec::with_capacity(4 * n);
    for i in 0..n {
        for k in 0..3 {
            colour.push(level(f64::from(set.sh_dc[3 * i + k]) * C0 + 0.5));
        }
        colour.push(level(sigmoid(f64::from(set.opacity_logits[i]))));
    }
    // The half turn: q' = (0, 0, 0, 1) q, (w, x, y, z) -> (-z, -y, x, w); stored (x, y, z, w).
    let rotation = set
        .quats
        .chunks_exact(4)
        .flat_map(|q| [-q[2], q[1], q[0], -q[3]]);
    let mut attributes = vec![
        Attribute {
            name: "POSITION".into(),
            bytes: floats(turned.iter().flatten().copied()),
            component: FLOAT,
            kind: "VEC3",
            normalized: false,
        },
        Attribute {
            name: "COLOR_0".into(),
            bytes: colour,
            component: UNSIGNED_BYTE,
            kind: "VEC4",
            normalized: true,
        },
        Attribute {
            name: "KHR_gaussian_splatting:ROTATION".into(),
            bytes: floats(rotation),
            component: FLOAT,
            kind: "VEC4",
            normalized: false,
        },
        Attribute {
            name: "KHR_gaussian_splatting:SCALE".into(),
            bytes: floats(set.log_scales.iter().map(|&s| f64::from(s).exp() as f32)),
            component: FLOAT,
            kind: "VEC3",
            normalized: false,
        },
        Attribute {
            name: "KHR_gaussian_splatting:OPACITY".into(),
            bytes: floats(
                set.opacity_logits
                    .iter()
                    .map(|&o| sigmoid(f64::from(o)) as f32),
            ),
            component: FLOAT,
            kind: "SCALAR",
            normalized: false,
        },
        Attribute {
            name: "KHR_gaussian_splatting:SH_DEGREE_0_COEF_0".into(),
            bytes: floats(set.sh_dc.iter().copied()),
            component: FLOAT,
            kind: "VEC3",
            normalized: false,
        },
    ];
    let rest = set.sh_coeffs() - 1;
    let mut coefficient = 0;
    for degree in 1..=set.sh_degree() {
        for c in 0..2 * degree + 1 {
            let sign = HALF_TURN_SH_SIGNS[coefficient];
            let values = (0..n).flat_map(|i| {
                let at = 3 * (rest * i + coefficient);
                [0, 1, 2].map(|ch| sign * set.sh_rest[at + ch])
            });
            attributes.push(Attribute {
                name: format!("KHR_gaussian_splatting:SH_DEGREE_{degree}_COEF_{c}"),
                bytes: floats(values),
                component: FLOAT,
                kind: "VEC3",
                normalized: false,
            });
            coefficient += 1;
        }
    }
    let mut binary = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    let mut names = serde_json::Map::new();
    for (index, a) in attributes.iter().enumerate() {
        views.push(serde_json::json!({
            "buffer": 0,
            "byteOffset": binary.len(),
            "byteLength": a.bytes.len(),
            "target": ARRAY_BUFFER,
        }));
        let mut accessor = serde_json::json!({
            "bufferView": index,
            "byteOffset": 0,
            "componentType": a.component,
            "count": n,
            "type": a.kind,
        });
        if a.normalized {
            accessor["normalized"] = true.into();
        }
        if a.name == "POSITION" && n > 0 {
            accessor["min"] = serde_json::json!(lo);
            accessor["max"] = serde_json::json!(hi);
        }
        accessors.push(accessor);
        names.insert(a.name.clone(), index.into());
        binary.extend(&a.bytes);
        binary.resize(binary.len().next_multiple_of(4), 0);
    }
    let gltf = serde_json::json!({
        "asset": {"version": "2.0", "generator": "clipgaussian"},
        "extensionsUsed": ["KHR_gaussian_splatting"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "buffers": [{"byteLength": binary.len()}],
        "bufferViews": views,
        "accessors": accessors,
        "meshes": [{"primitives": [{
            "attributes": names,
            "mode": 0,
            "extensions": {"KHR_gaussian_splatting": {
                "kernel": "ellipse",
                "colorSpace": "srgb_rec709_display",
                "sortingMethod": "cameraDistance",
                "projection": "perspective",
            }},
        }]}],
    });
    let mut json = serde_json::to_vec(&gltf).map_err(|e| e.to_string())?;
    json.resize(json.len().next_multiple_of(4), b' ');
    let total = 12 + 8 + json.len() + 8 + binary.len();
    let total = u32::try_from(total).map_err(|_| "the file would pass glTF's 4 GB limit")?;
    let mut out = Vec::with_capacity(total as usize);
    out.extend(b"glTF");
    out.extend(2u32.to_le_bytes());
    out.extend(total.to_le_bytes());
    out.extend((json.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(json);
    out.extend((binary.len() as u32).to_le_bytes());
    out.extend(b"BIN\0");
    out.extend(binary);
    Ok(out)
}

/// The JSON and binary chunks of `.glb` bytes.
fn chunks(bytes: &[u8]) -> Result<(serde_json::Value, &[u8]), String> {
    let u32_at = |at: usize| -> Option<usize> {
        Some(u32::from_le_bytes(bytes.get(at..at + 4)?.try_into().ok()?) as usize)
    };
    if bytes.get(..4) != Some(b"glTF") {
        return Err("not a glTF binary: it does not start with `glTF`".into());
    }
    if u32_at(4) != Some(2) {
        return Err(format!(
            "glTF version {:?}: only version 2 is read",
            u32_at(4)
        ));
    }
    let json_len = u32_at(12).ok_or("the file ends inside its header")?;
    if bytes.get(16..20) != Some(b"JSON") {
        return Err("the first chunk is not the JSON chunk".into());
    }
    let json_end = 20usize
        .checked_add(json_len)
        .filter(|&e| e <= bytes.len())
        .ok_or("the JSON chunk runs past the end of the file")?;
    let json: serde_json::Value =
        serde_json::from_slice(&bytes[20..json_end]).map_err(|e| format!("its JSON: {e}"))?;
    let bin = match u32_at(json_end) {
        Some(len) => {
            if bytes.get(json_end + 4..json_end + 8) != Some(b"BIN\0") {
                return Err("the second chunk is not the binary chunk".into());
            }
            let start = json_end + 8;
            let end = start
                .checked_add(len)
                .filter(|&e| e <= bytes.len())
                .ok_or("the binary chunk runs past the end of the file")?;
            &bytes[start..end]
        }
        None => &[][..],
    };
    Ok((json, bin))
}

/// The values of accessor `index` of `gltf` in `bin` as `f64`, `count` elements of `width`
/// components each; `float` components, or `unsigned byte` / `unsigned short` ones when
/// normalised (mapped to `[0, 1]`).
fn accessor(
    gltf: &serde_json::Value,
    bin: &[u8],
    name: &str,
    index: &serde_json::Value,
    count: usize,
    width: usize,
) -> Result<Vec<f64>, String> {
    let bad = |why: String| format!("attribute {name}: {why}");
    let a = index
        .as_u64()
        .and_then(|i| gltf["accessors"].get(i as usize))
        .ok_or_else(|| bad(format!("accessor {index} does not exist")))?;
    let kind = a["type"].as_str().unwrap_or("");
    if components(kind) != Some(width) {
        return Err(bad(format!("type {kind:?}, expected {width} component(s)")));
    }
    if a["count"].as_u64() != Some(count as u64) {
        return Err(bad(format!("{} elements, expected {count}", a["count"])));
    }
    let size = match (a["componentType"].as_u64(), a["normalized"].as_bool()) {
        (Some(c), _) if c == u64::from(FLOAT) => 4,
        (Some(c), Some(true)) if c == u64::from(UNSIGNED_BYTE) => 1,
        (Some(5123), Some(true)) => 2,
        (c, _) => return Err(bad(format!("component type {c:?} is not read"))),
    };
    let view = a["bufferView"]
        .as_u64()
        .and_then(|v| gltf["bufferViews"].get(v as usize))
        .ok_or_else(|| bad("no buffer view (sparse accessors are not read)".into()))?;
    if view["buffer"].as_u64().unwrap_or(0) != 0 {
        return Err(bad("its data is in an external buffer".into()));
    }
    let offset = view["byteOffset"].as_u64().unwrap_or(0) + a["byteOffset"].as_u64().unwrap_or(0);
    let element = size * width;
    let stride = view["byteStride"].as_u64().map_or(element, |s| s as usize);
    if stride < element {
        return Err(bad(format!(
            "byte stride {stride} is less than an element, {element}"
        )));
    }
    let end = (count.saturating_sub(1) as u128) * stride as u128 + element as u128 + offset as u128;
    let view_end = view["byteOffset"].as_u64().unwrap_or(0) as u128
        + view["byteLength"].as_u64().unwrap_or(0) as u128;
    if count > 0 && (end > bin.len() as u128 || end > view_end) {
        return Err(bad("its data runs past its buffer view or the file".into()));
    }
    let mut values = crate::fallible::filled(count * width, 0.0f64, "a glTF attribute")
        .map_err(|e| bad(e.to_string()))?;
    for i in 0..count {
        let at = offset as usize + i * stride;
        for k in 0..width {
            let b = &bin[at + k * size..at + (k + 1) * size];
            values[i * width + k] = match size {
                4 => f64::from(f32::from_le_bytes(b.try_into().unwrap())),
                2 => f64::from(u16::from_le_bytes(b.try_into().unwrap())) / 65535.0,
                _ => f64::from(b[0]) / 255.0,
            };
        }
    }
    Ok(values)
}

/// The Gaussians of `.glb` bytes (see the module documentation).
pub fn decode(bytes: &[u8]) -> Result<GaussianSet, DecodeError> {
    let (gltf, bin) = chunks(bytes)?;
    let primitive = gltf["meshes"]
        .as_array()
        .into_iter()
        .flatten()
        .flat_map(|m| m["primitives"].as_array().into_iter().flatten())
        .find(|p| p["extensions"].get("KHR_gaussian_splatting").is_some())
        .ok_or("no mesh primitive with KHR_gaussian_splatting: not a Gaussian splat file")?;
    let attributes = primitive["attributes"]
        .as_object()
        .ok_or("the primitive has no attributes")?;
    let count = attributes
        .get("POSITION")
        .and_then(|i| i.as_u64())
        .and_then(|i| gltf["accessors"].get(i as usize))
        .and_then(|a| a["count"].as_u64())
        .ok_or("the primitive has no POSITION accessor")? as usize;
    let read = |name: &str, width: usize| -> Result<Option<Vec<f64>>, String> {
        attributes
            .get(name)
            .map(|index| accessor(&gltf, bin, name, index, count, width))
            .transpose()
    };
    let need = |name: &str, width: usize| -> Result<Vec<f64>, String> {
        read(name, width)?.ok_or_else(|| format!("the attribute {name} is missing"))
    };
    const EXT: &str = "KHR_gaussian_splatting:";
    let degree = (1..=3)
        .take_while(|d| attributes.contains_key(&format!("{EXT}SH_DEGREE_{d}_COEF_0")))
        .count();
    let position = need("POSITION", 3)?;
    let mut set = GaussianSet::try_zeros(count, degree)?;
    for (i, p) in position.chunks_exact(3).enumerate() {
        set.means[3 * i..3 * i + 3].copy_from_slice(&[-p[0] as f32, -p[1] as f32, p[2] as f32]);
    }
    let rotation = need(&format!("{EXT}ROTATION"), 4)?;
    for (i, r) in rotation.chunks_exact(4).enumerate() {
        // Stored (x', y', z', w') of the turned q' = k q; q = -k q' = (z', y', -x', -w').
        set.quats[4 * i..4 * i + 4].copy_from_slice(&[
            r[2] as f32,
            r[1] as f32,
            -r[0] as f32,
            -r[3] as f32,
        ]);
    }
    let scale = need(&format!("{EXT}SCALE"), 3)?;
    for (v, s) in set.log_scales.iter_mut().zip(&scale) {
        *v = s.ln() as f32;
    }
    let opacity = match read(&format!("{EXT}OPACITY"), 1)? {
        Some(o) => o,
        None => need("COLOR_0", 4)?.chunks_exact(4).map(|c| c[3]).collect(),
    };
    for (v, o) in set.opacity_logits.iter_mut().zip(&opacity) {
        let p = o.clamp(1e-6, 1.0 - 1e-6);
        *v = (p / (1.0 - p)).ln() as f32;
    }
    match read(&format!("{EXT}SH_DEGREE_0_COEF_0"), 3)? {
        Some(dc) => set
            .sh_dc
            .iter_mut()
            .zip(&dc)
            .for_each(|(v, c)| *v = *c as f32),
        None => {
            let colour = need("COLOR_0", 4)?;
            for (i, c) in colour.chunks_exact(4).enumerate() {
                for k in 0..3 {
                    set.sh_dc[3 * i + k] = ((c[k] - 0.5) / C0) as f32;
                }
            }
        }
    }
    let rest = set.sh_coeffs() - 1;
    let mut coefficient = 0;
    for d in 1..=degree {
        for c in 0..2 * d + 1 {
            let values = need(&format!("{EXT}SH_DEGREE_{d}_COEF_{c}"), 3)?;
            let sign = HALF_TURN_SH_SIGNS[coefficient];
            for i in 0..count {
                for ch in 0..3 {
                    set.sh_rest[3 * (rest * i + coefficient) + ch] =
                        sign * values[3 * i + ch] as f32;
                }
            }
            coefficient += 1;
        }
    }
    check_finite(&set)?;
    Ok(set)
}
