//! One core of D-MiSo at one time: its triangle deformed by the network's outputs, and the frame
//! its sub-Gaussians live in (D-MiSo's `calc_vertices` and `_prepare_scaling_rot`), with the
//! exact backward. Computed in f64.
//!
//! Deformation, from the canonical triangle `(v1, v2, v3)` and the network's `dv1, dv2, dv3`
//! and quaternion `r` (`R` the rotation of `r / |r|`):
//! `v1' = v1 + dv1`, `vj' = vj + dv1 + dvj * e_j / |e_j|` with `e_j = R (vj - v1)`
//! (element-wise product). Without deformation (D-MiSo's warm-up) the triangle is canonical.
//!
//! Frame, with `a = v2' - v1'`, `b = v3' - v1'`, `eps = 1e-8`:
//! `r1 = c / (|c| + eps)` with `c = a/|a| x b/|b|`, `r2 = a / (|a| + eps)`,
//! `r3 = w / (|w| + eps)` with `w = b - (b.r1) r1 - (b.r2) r2`; scales
//! `S = [1e-8, |a| + eps, |b.r3|]`; the rotation is the quaternion of the matrix of columns
//! `r1, r2, r3` ([`matrix_to_quaternion`]), normalized. The sub-Gaussians are placed along
//! `n = (a x b) / |a x b|`, `a / |a|` and `b / |b|`.

use gs_core::mat::{
    dot, normalize3, normalize3_backward, quat_to_rotation, quat_to_rotation_backward, M3, V3,
};

/// D-MiSo's epsilon of the frame and the flat axis's scale.
pub const FRAME_EPS: f64 = 1e-8;

/// Smallest length a quaternion is divided by (torch's `F.normalize` eps).
pub const QUAT_EPS: f64 = 1e-12;

/// Smallest `|b.r3|` whose logarithm is taken: a degenerate (flat) triangle's second scale,
/// where D-MiSo's `log(0)` would give `-inf`.
pub const MIN_SCALE: f64 = 1e-30;

/// The network's outputs for one core: `dv1, dv2, dv3` and the quaternion `r` (w, x, y, z).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Deformation {
    /// Translation of the whole triangle.
    pub dv1: V3<f64>,
    /// Displacement of the second vertex along its rotated edge direction (per axis).
    pub dv2: V3<f64>,
    /// Displacement of the third vertex along its rotated edge direction (per axis).
    pub dv3: V3<f64>,
    /// The rotation of the edges, unnormalized (w, x, y, z).
    pub rot: [f64; 4],
}

impl Deformation {
    /// From the network's 13 outputs `[dv1, dv2, dv3, rot]`.
    pub fn from_slice(d: &[f32]) -> Self {
        let v = |i: usize| [d[i] as f64, d[i + 1] as f64, d[i + 2] as f64];
        Self {
            dv1: v(0),
            dv2: v(3),
            dv3: v(6),
            rot: [d[9] as f64, d[10] as f64, d[11] as f64, d[12] as f64],
        }
    }

    /// As the network's 13 outputs.
    pub fn to_array(&self) -> [f64; 13] {
        let mut out = [0.0; 13];
        out[..3].copy_from_slice(&self.dv1);
        out[3..6].copy_from_slice(&self.dv2);
        out[6..9].copy_from_slice(&self.dv3);
        out[9..].copy_from_slice(&self.rot);
        out
    }
}

/// What the sub-Gaussians of a core are built from.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Frame {
    /// The deformed first vertex, the sub-Gaussians' origin.
    pub origin: V3<f64>,
    /// `(a x b) / |a x b|`.
    pub normal: V3<f64>,
    /// `a / |a|`.
    pub a_dir: V3<f64>,
    /// `b / |b|`.
    pub b_dir: V3<f64>,
    /// `ln(|a| + eps)` and `ln |b.r3|`: the logarithms of the frame's second and third scales.
    pub log_scales: [f64; 2],
    /// The frame's rotation, normalized (w, x, y, z).
    pub quat: [f64; 4],
}

/// Gradients with respect to a [`Frame`]'s fields.
pub type FrameGrads = Frame;

/// Gradients of a core's inputs.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CoreGrads {
    /// The canonical vertices.
    pub vertices: [V3<f64>; 3],
    /// The network's outputs (zero without deformation).
    pub deformation: Deformation,
}

/// The deformed triangle of `vertices` (`None`: undeformed).
pub fn deform(vertices: &[V3<f64>; 3], d: Option<&Deformation>) -> [V3<f64>; 3] {
    let Some(d) = d else {
        return *vertices;
    };
    let r = quat_to_rotation(normalize_quat(d.rot).0);
    let [v1, v2, v3] = *vertices;
    let p1 = add(v1, d.dv1);
    let moved = |v: V3<f64>, dv: V3<f64>| {
        let (u, _) = normalize3(rotate(&r, sub(v, v1)));
        [
            v[0] + d.dv1[0] + u[0] * dv[0],
            v[1] + d.dv1[1] + u[1] * dv[1],
            v[2] + d.dv1[2] + u[2] * dv[2],
        ]
    };
    [p1, moved(v2, d.dv2), moved(v3, d.dv3)]
}

/// The frame of the triangle `p` (deformed).
pub fn frame(p: &[V3<f64>; 3]) -> Frame {
    FrameState::new(p).frame()
}

/// The frame of a deformed triangle with the intermediate values its backward needs, computed
/// once for both ([`FrameState::frame`], [`FrameState::backward`]).
pub struct FrameState {
    origin: V3<f64>,
    a: V3<f64>,
    b: V3<f64>,
    la: f64,
    lb: f64,
    a_dir: V3<f64>,
    b_dir: V3<f64>,
    c: V3<f64>,
    lc: f64,
    r1: V3<f64>,
    r2: V3<f64>,
    w: V3<f64>,
    lw: f64,
    r3: V3<f64>,
    s3: f64,
    lm: f64,
    normal: V3<f64>,
    /// The rotation matrix of columns `r1, r2, r3`.
    columns: M3<f64>,
    raw_norm: f64,
    quat: [f64; 4],
}

impl FrameState {
    /// The frame of the triangle `p` (deformed) and its intermediates.
    pub fn new(p: &[V3<f64>; 3]) -> Self {
        let a = sub(p[1], p[0]);
        let b = sub(p[2], p[0]);
        let (a_dir, la) = normalize3(a);
        let (b_dir, lb) = normalize3(b);
        let c = cross(a_dir, b_dir);
        let lc = norm(c);
        let r1 = scale(c, 1.0 / (lc + FRAME_EPS));
        let r2 = scale(a, 1.0 / (la + FRAME_EPS));
        let (br1, br2) = (dot(&b, &r1), dot(&b, &r2));
        let w = [
            b[0] - br1 * r1[0] - br2 * r2[0],
            b[1] - br1 * r1[1] - br2 * r2[1],
            b[2] - br1 * r1[2] - br2 * r2[2],
        ];
        let lw = norm(w);
        let r3 = scale(w, 1.0 / (lw + FRAME_EPS));
        let s3 = dot(&b, &r3);
        let (normal, lm) = normalize3(cross(a, b));
        let columns = [
            [r1[0], r2[0], r3[0]],
            [r1[1], r2[1], r3[1]],
            [r1[2], r2[2], r3[2]],
        ];
        let (quat, raw_norm) = normalize_quat(matrix_to_quaternion(&columns).0);
        Self {
            origin: p[0],
            a,
            b,
            la,
            lb,
            a_dir,
            b_dir,
            c,
            lc,
            r1,
            r2,
            w,
            lw,
            r3,
            s3,
            lm,
            normal,
            columns,
            raw_norm,
            quat,
        }
    }

    /// The frame.
    pub fn frame(&self) -> Frame {
        Frame {
            origin: self.origin,
            normal: self.normal,
            a_dir: self.a_dir,
            b_dir: self.b_dir,
            log_scales: [
                (self.la + FRAME_EPS).ln(),
                self.s3.abs().max(MIN_SCALE).ln(),
            ],
            quat: self.quat,
        }
    }

    /// Gradient with respect to the deformed triangle of a loss whose gradient with respect
    /// to its frame is `g`.
    pub fn backward(&self, g: &FrameGrads) -> [V3<f64>; 3] {
        let f = self;
        let g_raw = normalize_quat_backward(f.quat, f.raw_norm, g.quat);
        let g_m = matrix_to_quaternion_backward(&f.columns, g_raw);
        let mut g_r1 = [g_m[0][0], g_m[1][0], g_m[2][0]];
        let mut g_r2 = [g_m[0][1], g_m[1][1], g_m[2][1]];
        let mut g_r3 = [g_m[0][2], g_m[1][2], g_m[2][2]];
        let mut g_a = [0.0; 3];
        let mut g_b = [0.0; 3];
        // ln|b.r3| (clamped: no gradient below MIN_SCALE).
        if f.s3.abs() > MIN_SCALE {
            let g_s3 = g.log_scales[1] / f.s3;
            axpy(&mut g_b, g_s3, f.r3);
            axpy(&mut g_r3, g_s3, f.b);
        }
        // ln(|a| + eps).
        let g_la = g.log_scales[0] / (f.la + FRAME_EPS);
        // r3 = w / (|w| + eps).
        let g_w = eps_normalize_backward(f.w, f.lw, g_r3);
        // w = b - (b.r1) r1 - (b.r2) r2.
        let (br1, br2) = (dot(&f.b, &f.r1), dot(&f.b, &f.r2));
        let (wr1, wr2) = (dot(&g_w, &f.r1), dot(&g_w, &f.r2));
        for k in 0..3 {
            g_b[k] += g_w[k] - f.r1[k] * wr1 - f.r2[k] * wr2;
            g_r1[k] -= br1 * g_w[k] + wr1 * f.b[k];
            g_r2[k] -= br2 * g_w[k] + wr2 * f.b[k];
        }
        // r2 = a / (|a| + eps).
        add_into(&mut g_a, eps_normalize_backward(f.a, f.la, g_r2));
        // r1 = c / (|c| + eps), c = a_dir x b_dir.
        let g_c = eps_normalize_backward(f.c, f.lc, g_r1);
        let mut g_a_dir = g.a_dir;
        let mut g_b_dir = g.b_dir;
        add_into(&mut g_a_dir, cross(f.b_dir, g_c));
        add_into(&mut g_b_dir, cross(g_c, f.a_dir));
        add_into(&mut g_a, normalize3_backward(f.a_dir, f.la, g_a_dir));
        add_into(&mut g_b, normalize3_backward(f.b_dir, f.lb, g_b_dir));
        axpy(&mut g_a, if f.la > 0.0 { g_la } else { 0.0 }, f.a_dir);
        // normal = m / |m|, m = a x b.
        let g_mm = normalize3_backward(f.normal, f.lm, g.normal);
        add_into(&mut g_a, cross(f.b, g_mm));
        add_into(&mut g_b, cross(g_mm, f.a));
        let mut g_p = [[0.0; 3]; 3];
        for k in 0..3 {
            g_p[0][k] = g.origin[k] - g_a[k] - g_b[k];
            g_p[1][k] = g_a[k];
            g_p[2][k] = g_b[k];
        }
        g_p
    }
}

/// Gradient with respect to the deformed triangle `p` of a loss whose gradient with respect
/// to [`frame`]`(p)` is `g`.
pub fn frame_backward(p: &[V3<f64>; 3], g: &FrameGrads) -> [V3<f64>; 3] {
    FrameState::new(p).backward(g)
}

/// Gradients of the canonical vertices and of the network's outputs, given the gradient `g_p`
/// with respect to the deformed triangle [`deform`]`(vertices, d)`.
pub fn deform_backward(
    vertices: &[V3<f64>; 3],
    d: Option<&Deformation>,
    g_p: &[V3<f64>; 3],
) -> CoreGrads {
    let Some(d) = d else {
        return CoreGrads {
            vertices: *g_p,
            deformation: Deformation::default(),
        };
    };
    let (q, q_norm) = normalize_quat(d.rot);
    let r = quat_to_rotation(q);
    let [v1, ..] = *vertices;
    let mut g_v = *g_p;
    let mut g_r = [[0.0; 3]; 3];
    let mut g_d = Deformation::default();
    for k in 0..3 {
        g_d.dv1[k] = g_p[0][k] + g_p[1][k] + g_p[2][k];
    }
    for (j, dv, g_dv) in [(1, d.dv2, &mut g_d.dv2), (2, d.dv3, &mut g_d.dv3)] {
        let f = sub(vertices[j], v1);
        let e = rotate(&r, f);
        let (u, le) = normalize3(e);
        let g_u = [g_p[j][0] * dv[0], g_p[j][1] * dv[1], g_p[j][2] * dv[2]];
        *g_dv = [g_p[j][0] * u[0], g_p[j][1] * u[1], g_p[j][2] * u[2]];
        let g_e = normalize3_backward(u, le, g_u);
        // e = R f: dR += g_e f^T, df = R^T g_e.
        for row in 0..3 {
            for col in 0..3 {
                g_r[row][col] += g_e[row] * f[col];
            }
        }
        let g_f = rotate_t(&r, g_e);
        for k in 0..3 {
            g_v[j][k] += g_f[k];
            g_v[0][k] -= g_f[k];
        }
    }
    let g_q = quat_to_rotation_backward(q, &g_r);
    g_d.rot = normalize_quat_backward(q, q_norm, g_q);
    CoreGrads {
        vertices: g_v,
        deformation: g_d,
    }
}

/// The quaternion (w, x, y, z) of the rotation matrix `m` as pytorch3d's
/// `matrix_to_quaternion` computes it (D-MiSo's `rot_to_quat_batch`): four candidates, each
/// divided by `2 max(q_abs_i, 0.1)`, the one of the largest `q_abs_i` kept (the first on ties),
/// then negated when its `w` is negative. Also returns the index of the candidate.
pub fn matrix_to_quaternion(m: &M3<f64>) -> ([f64; 4], usize) {
    let x = diagonal_terms(m);
    let q_abs = x.map(|v| if v > 0.0 { v.sqrt() } else { 0.0 });
    let i = argmax_first(&q_abs);
    let row = candidate_row(m, &q_abs, i);
    let denominator = 2.0 * q_abs[i].max(0.1);
    let mut q = row.map(|v| v / denominator);
    if q[0] < 0.0 {
        q = q.map(|v| -v);
    }
    (q, i)
}

/// Gradient with respect to `m` of a loss whose gradient with respect to
/// [`matrix_to_quaternion`]`(m)` is `g`, with pytorch3d's conventions: the
/// chosen candidate only, no gradient through `sqrt(max(0, x))` where `x <= 0`, nor through
/// the `0.1` floor.
pub fn matrix_to_quaternion_backward(m: &M3<f64>, g: [f64; 4]) -> M3<f64> {
    let x = diagonal_terms(m);
    let q_abs = x.map(|v| if v > 0.0 { v.sqrt() } else { 0.0 });
    let i = argmax_first(&q_abs);
    let row = candidate_row(m, &q_abs, i);
    let denominator = 2.0 * q_abs[i].max(0.1);
    // The sign standardization: `q = sign * row / denominator`.
    let sign = if row[0] / denominator < 0.0 {
        -1.0
    } else {
        1.0
    };
    let g = g.map(|v| v * sign);
    let g_row = g.map(|v| v / denominator);
    let mut g_m = [[0.0; 3]; 3];
    // Off-diagonal entries of the row: linear in m.
    for (j, &coefficients) in OFF_DIAGONAL[i].iter().enumerate() {
        if j == i {
            continue;
        }
        for &(r, c, s) in coefficients {
            g_m[r][c] += s * g_row[j];
        }
    }
    // The diagonal entry `q_abs_i^2 = x_i` and the denominator `2 q_abs_i`.
    let mut g_x = g_row[i];
    if q_abs[i] > 0.1 {
        let g_den = -(0..4).map(|j| g[j] * row[j]).sum::<f64>() / (denominator * denominator);
        g_x += g_den / q_abs[i];
    }
    if x[i] <= 0.0 {
        g_x = 0.0;
    }
    for (k, s) in DIAGONAL_SIGNS[i].iter().enumerate() {
        g_m[k][k] += s * g_x;
    }
    g_m
}

/// Signs of `m00, m11, m22` in `x_i = 1 +- m00 +- m11 +- m22`.
const DIAGONAL_SIGNS: [[f64; 3]; 4] = [
    [1.0, 1.0, 1.0],
    [1.0, -1.0, -1.0],
    [-1.0, 1.0, -1.0],
    [-1.0, -1.0, 1.0],
];

/// The off-diagonal entries of each candidate row, as sums of `sign * m[r][c]`.
type Terms = &'static [(usize, usize, f64)];
const OFF_DIAGONAL: [[Terms; 4]; 4] = [
    [
        &[],
        &[(2, 1, 1.0), (1, 2, -1.0)],
        &[(0, 2, 1.0), (2, 0, -1.0)],
        &[(1, 0, 1.0), (0, 1, -1.0)],
    ],
    [
        &[(2, 1, 1.0), (1, 2, -1.0)],
        &[],
        &[(1, 0, 1.0), (0, 1, 1.0)],
        &[(0, 2, 1.0), (2, 0, 1.0)],
    ],
    [
        &[(0, 2, 1.0), (2, 0, -1.0)],
        &[(1, 0, 1.0), (0, 1, 1.0)],
        &[],
        &[(1, 2, 1.0), (2, 1, 1.0)],
    ],
    [
        &[(1, 0, 1.0), (0, 1, -1.0)],
        &[(2, 0, 1.0), (0, 2, 1.0)],
        &[(2, 1, 1.0), (1, 2, 1.0)],
        &[],
    ],
];

fn diagonal_terms(m: &M3<f64>) -> [f64; 4] {
    DIAGONAL_SIGNS.map(|s| 1.0 + s[0] * m[0][0] + s[1] * m[1][1] + s[2] * m[2][2])
}

fn candidate_row(m: &M3<f64>, q_abs: &[f64; 4], i: usize) -> [f64; 4] {
    let mut row = [0.0; 4];
    for (j, terms) in OFF_DIAGONAL[i].iter().enumerate() {
        row[j] = if j == i {
            q_abs[i] * q_abs[i]
        } else {
            terms.iter().map(|&(r, c, s)| s * m[r][c]).sum()
        };
    }
    row
}

fn argmax_first(v: &[f64; 4]) -> usize {
    let mut best = 0;
    for i in 1..4 {
        if v[i] > v[best] {
            best = i;
        }
    }
    best
}

/// `q / max(|q|, 1e-12)` and `|q|`.
pub fn normalize_quat(q: [f64; 4]) -> ([f64; 4], f64) {
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    let d = n.max(QUAT_EPS);
    (q.map(|v| v / d), n)
}

/// Gradient with respect to `q` of a loss whose gradient with respect to `u = q / max(|q|,
/// eps)` is `g` (`n = |q|`).
pub fn normalize_quat_backward(u: [f64; 4], n: f64, g: [f64; 4]) -> [f64; 4] {
    if n <= QUAT_EPS {
        return g.map(|v| v / QUAT_EPS);
    }
    let ug: f64 = (0..4).map(|k| u[k] * g[k]).sum();
    [0, 1, 2, 3].map(|k| (g[k] - u[k] * ug) / n)
}

/// Gradient of `v / (|v| + eps)` with respect to `v` (`n = |v|`), given `g`.
fn eps_normalize_backward(v: V3<f64>, n: f64, g: V3<f64>) -> V3<f64> {
    let d = n + FRAME_EPS;
    if n <= 0.0 {
        return scale(g, 1.0 / d);
    }
    let vg = dot(&v, &g);
    [0, 1, 2].map(|k| g[k] / d - v[k] * vg / (d * d * n))
}

/// Hamilton product `p q` (w, x, y, z).
pub fn quat_mul(p: [f64; 4], q: [f64; 4]) -> [f64; 4] {
    let [w1, x1, y1, z1] = p;
    let [w2, x2, y2, z2] = q;
    [
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ]
}

/// Gradients of `p` and `q` given the gradient `g` of `p q`: `g conj(q)` and `conj(p) g`.
pub fn quat_mul_backward(p: [f64; 4], q: [f64; 4], g: [f64; 4]) -> ([f64; 4], [f64; 4]) {
    let conj = |v: [f64; 4]| [v[0], -v[1], -v[2], -v[3]];
    (quat_mul(g, conj(q)), quat_mul(conj(p), g))
}

fn sub(a: V3<f64>, b: V3<f64>) -> V3<f64> {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn add(a: V3<f64>, b: V3<f64>) -> V3<f64> {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

fn scale(a: V3<f64>, s: f64) -> V3<f64> {
    [a[0] * s, a[1] * s, a[2] * s]
}

fn norm(a: V3<f64>) -> f64 {
    dot(&a, &a).sqrt()
}

/// `a x b`.
pub fn cross(a: V3<f64>, b: V3<f64>) -> V3<f64> {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn add_into(a: &mut V3<f64>, b: V3<f64>) {
    for k in 0..3 {
        a[k] += b[k];
    }
}

fn axpy(a: &mut V3<f64>, s: f64, b: V3<f64>) {
    for k in 0..3 {
        a[k] += s * b[k];
    }
}

fn rotate(r: &M3<f64>, v: V3<f64>) -> V3<f64> {
    gs_core::mat::mul_vec(r, &v)
}

fn rotate_t(r: &M3<f64>, v: V3<f64>) -> V3<f64> {
    gs_core::mat::mul_t_vec(r, &v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A fixed linear functional of a frame, and its gradient.
    fn weights(rng: &mut ChaCha8Rng) -> FrameGrads {
        let mut v = || [0, 1, 2].map(|_| rng.random_range(-1.0..1.0));
        Frame {
            origin: v(),
            normal: v(),
            a_dir: v(),
            b_dir: v(),
            log_scales: [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)],
            quat: [0, 1, 2, 3].map(|_| rng.random_range(-1.0..1.0)),
        }
    }

    fn apply(w: &FrameGrads, f: &Frame) -> f64 {
        let d = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
        d(&w.origin, &f.origin)
            + d(&w.normal, &f.normal)
            + d(&w.a_dir, &f.a_dir)
            + d(&w.b_dir, &f.b_dir)
            + d(&w.log_scales, &f.log_scales)
            + d(&w.quat, &f.quat)
    }

    fn loss(w: &FrameGrads, v: &[V3<f64>; 3], d: Option<&Deformation>) -> f64 {
        apply(w, &frame(&deform(v, d)))
    }

    /// Checks the analytic gradient of every vertex coordinate and network output against
    /// central differences.
    /// `size` is the triangle's scale: the step is `1e-6 size`; `tol` the relative tolerance.
    fn check(
        v: [V3<f64>; 3],
        d: Option<Deformation>,
        w: &FrameGrads,
        (size, tol): (f64, f64),
        what: &str,
    ) {
        let g_p = frame_backward(&deform(&v, d.as_ref()), w);
        let g = deform_backward(&v, d.as_ref(), &g_p);
        let h = 1e-6 * size;
        let close = |analytic: f64, numeric: f64, name: String| {
            let tol = tol * (1.0 + numeric.abs());
            assert!(
                (analytic - numeric).abs() < tol,
                "{what}: {name}: analytic {analytic} numeric {numeric}"
            );
        };
        for j in 0..3 {
            for k in 0..3 {
                let (mut plus, mut minus) = (v, v);
                plus[j][k] += h;
                minus[j][k] -= h;
                let numeric =
                    (loss(w, &plus, d.as_ref()) - loss(w, &minus, d.as_ref())) / (2.0 * h);
                close(g.vertices[j][k], numeric, format!("v{}[{k}]", j + 1));
            }
        }
        if let Some(d) = d {
            let analytic = g.deformation.to_array();
            for i in 0..13 {
                let shifted = |s: f64| {
                    let mut full = d.to_array();
                    full[i] += s;
                    let mut e = d;
                    e.dv1.copy_from_slice(&full[..3]);
                    e.dv2.copy_from_slice(&full[3..6]);
                    e.dv3.copy_from_slice(&full[6..9]);
                    e.rot.copy_from_slice(&full[9..]);
                    loss(w, &v, Some(&e))
                };
                // The quaternion is of order 1 whatever the triangle's size.
                let step = if i < 9 { h } else { 1e-6 };
                let numeric = (shifted(step) - shifted(-step)) / (2.0 * step);
                close(analytic[i], numeric, format!("network output {i}"));
            }
        }
    }

    fn random_triangle(rng: &mut ChaCha8Rng, size: f64) -> [V3<f64>; 3] {
        let c = [0, 1, 2].map(|_| rng.random_range(-1.0..1.0));
        [0, 1, 2].map(|_| [0, 1, 2].map(|k| c[k] + size * rng.random_range(-1.0..1.0)))
    }

    fn random_deformation(rng: &mut ChaCha8Rng, size: f64) -> Deformation {
        let mut v = || [0, 1, 2].map(|_| size * rng.random_range(-1.0..1.0));
        Deformation {
            dv1: v(),
            dv2: v(),
            dv3: v(),
            rot: [0, 1, 2, 3].map(|_| rng.random_range(-1.0..1.0)),
        }
    }

    #[test]
    fn the_frame_and_the_deformation_have_the_gradient_of_finite_differences() {
        for seed in 0..6 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let w = weights(&mut rng);
            let v = random_triangle(&mut rng, 0.4);
            check(v, None, &w, (0.4, 1e-6), &format!("seed {seed}, canonical"));
            let d = random_deformation(&mut rng, 0.1);
            check(
                v,
                Some(d),
                &w,
                (0.4, 1e-6),
                &format!("seed {seed}, deformed"),
            );
        }
    }

    #[test]
    fn small_and_thin_triangles_keep_finite_exact_gradients() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let w = weights(&mut rng);
        // A triangle of 1e-3: still far above the 1e-8 epsilons.
        let v = random_triangle(&mut rng, 1e-3);
        check(
            v,
            Some(random_deformation(&mut rng, 1e-4)),
            &w,
            (1e-3, 1e-6),
            "tiny",
        );
        // A sliver: the third vertex about 1e-3 off the first edge's line (axes in general
        // position: an axis-aligned frame ties the quaternion candidates).
        let v = [
            [0.1, 0.2, 0.3],
            [1.1, 0.5, 0.1],
            [0.6, 0.35 + 1e-3, 0.2 + 2e-3],
        ];
        // Its curvature is of order 1e6: the step is 1e-8 and the bound 1e-4.
        check(v, None, &w, (1e-2, 1e-4), "sliver");
        // Collinear and collapsed triangles: every value and gradient finite (D-MiSo's epsilons
        // give such a triangle an arbitrary frame; an exact zero third scale is clamped to
        // MIN_SCALE before its logarithm).
        for v in [
            [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]],
            [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
        ] {
            let f = frame(&v);
            let values = [f.origin, f.normal, f.a_dir, f.b_dir];
            assert!(
                values
                    .iter()
                    .flatten()
                    .chain(&f.log_scales)
                    .chain(&f.quat)
                    .all(|x| x.is_finite()),
                "{f:?}"
            );
            let g = frame_backward(&v, &w);
            assert!(g.iter().flatten().all(|x| x.is_finite()), "{g:?}");
        }
        let v = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]];
        let g = frame_backward(&v, &w);
        assert!(g.iter().flatten().all(|x| x.is_finite()), "{g:?}");
    }

    #[test]
    fn every_quaternion_candidate_is_taken_and_differentiated() {
        // Rotations by 0.3, 2.9 rad about x, y and z pick candidates 0, 1, 2 and 3.
        let mut taken = [false; 4];
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for axis in 0..3 {
            for angle in [0.3, 2.9f64] {
                let mut q = [(angle / 2.0).cos(), 0.0, 0.0, 0.0];
                q[1 + axis] = (angle / 2.0).sin();
                let m = quat_to_rotation(q);
                let (got, i) = matrix_to_quaternion(&m);
                taken[i] = true;
                for k in 0..4 {
                    assert!((got[k] - q[k]).abs() < 1e-12, "{q:?} -> {got:?}");
                }
                let g = [0, 1, 2, 3].map(|_| rng.random_range(-1.0..1.0));
                let analytic = matrix_to_quaternion_backward(&m, g);
                let h = 1e-7;
                for r in 0..3 {
                    for c in 0..3 {
                        let f = |s: f64| {
                            let mut mm = m;
                            mm[r][c] += s;
                            let q = matrix_to_quaternion(&mm).0;
                            (0..4).map(|k| q[k] * g[k]).sum::<f64>()
                        };
                        let numeric = (f(h) - f(-h)) / (2.0 * h);
                        assert!(
                            (analytic[r][c] - numeric).abs() < 1e-6,
                            "candidate {i}, m[{r}][{c}]: {} vs {numeric}",
                            analytic[r][c]
                        );
                    }
                }
            }
        }
        assert_eq!(taken, [true; 4]);
        // A negative w is flipped: the rotation by 2 pi - 0.3 gives the quaternion of 0.3.
        let m = quat_to_rotation([-(0.15f64).cos(), -(0.15f64).sin(), 0.0, 0.0]);
        assert!(matrix_to_quaternion(&m).0[0] > 0.0);
    }

    #[test]
    fn quaternion_products_have_the_gradient_of_finite_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let mut q = || [0, 1, 2, 3].map(|_| rng.random_range(-1.0..1.0));
        let (p, r, g) = (q(), q(), q());
        let (gp, gr) = quat_mul_backward(p, r, g);
        let f = |p: [f64; 4], r: [f64; 4]| {
            let m = quat_mul(p, r);
            (0..4).map(|k| m[k] * g[k]).sum::<f64>()
        };
        for k in 0..4 {
            let mut e = [0.0; 4];
            e[k] = 1e-6;
            let add = |a: [f64; 4], s: f64| [0, 1, 2, 3].map(|i| a[i] + s * e[i]);
            let np = (f(add(p, 1.0), r) - f(add(p, -1.0), r)) / 2e-6;
            let nr = (f(p, add(r, 1.0)) - f(p, add(r, -1.0))) / 2e-6;
            assert!((gp[k] - np).abs() < 1e-8 && (gr[k] - nr).abs() < 1e-8);
        }
    }
}
