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

use super::{check_finite, check_linear_scales, sigmoid};
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
