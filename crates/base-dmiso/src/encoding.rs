//! D-MiSo's positional encodings (NeRF's): the input itself, then for each frequency
//! `2^0, 2^1, ...` the sine and the cosine of the input times it (no factor pi), interleaved
//! per frequency: `[x, sin x, cos x, sin 2x, cos 2x, ...]`. Computed in f32, as PyTorch does.

/// Frequencies of the vertex encoding (63 values for a point).
pub const VERTEX_FREQUENCIES: usize = 10;

/// Frequencies of the time encoding of synthetic (D-NeRF) scenes (13 values).
pub const TIME_FREQUENCIES: usize = 6;

/// Length of a point's vertex encoding.
pub const VERTEX_ENCODING: usize = 3 * (1 + 2 * VERTEX_FREQUENCIES);

/// Length of the time encoding.
pub const TIME_ENCODING: usize = 1 + 2 * TIME_FREQUENCIES;

/// Appends the encoding of `x` (any length) with `frequencies` frequencies to `out`.
pub fn encode(x: &[f32], frequencies: usize, out: &mut Vec<f32>) {
    out.extend_from_slice(x);
    for k in 0..frequencies {
        let f = (1u32 << k) as f32;
        out.extend(x.iter().map(|&v| (v * f).sin()));
        out.extend(x.iter().map(|&v| (v * f).cos()));
    }
}

/// The time encoding of `t` (13 values).
pub fn time_encoding(t: f32) -> [f32; TIME_ENCODING] {
    let mut out = Vec::with_capacity(TIME_ENCODING);
    encode(&[t], TIME_FREQUENCIES, &mut out);
    out.try_into().expect("13 values")
}

/// The network input of one triangle: the element-wise product of its three vertices'
/// encodings (63 values), appended to `out`.
pub fn triangle_encoding(vertices: &[f32], out: &mut Vec<f32>) {
    let mut e = Vec::with_capacity(3 * VERTEX_ENCODING);
    for v in vertices.chunks_exact(3) {
        encode(v, VERTEX_FREQUENCIES, &mut e);
    }
    let (e1, rest) = e.split_at(VERTEX_ENCODING);
    let (e2, e3) = rest.split_at(VERTEX_ENCODING);
    out.extend((0..VERTEX_ENCODING).map(|i| e1[i] * e2[i] * e3[i]));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encodings_interleave_sine_and_cosine_per_frequency() {
        let t = time_encoding(0.3);
        assert_eq!(t[0], 0.3);
        assert_eq!(t[1], 0.3f32.sin());
        assert_eq!(t[2], 0.3f32.cos());
        assert_eq!(t[11], (0.3f32 * 32.0).sin());
        assert_eq!(t[12], (0.3f32 * 32.0).cos());
        let mut v = Vec::new();
        encode(&[0.1, 0.2, 0.3], VERTEX_FREQUENCIES, &mut v);
        assert_eq!(v.len(), VERTEX_ENCODING);
        assert_eq!(&v[3..6], &[0.1f32.sin(), 0.2f32.sin(), 0.3f32.sin()]);
        assert_eq!(v[62], (0.3f32 * 512.0).cos());
        let mut p = Vec::new();
        triangle_encoding(&[0.1, 0.2, 0.3, 1.0, 1.0, 1.0, 2.0, 2.0, 2.0], &mut p);
        assert_eq!(p[..3], [0.2, 0.4, 0.6]);
        assert_eq!(p.len(), VERTEX_ENCODING);
    }
}
