//! Real spherical harmonics up to degree 3 with the constants and sign conventions of INRIA 3DGS
//! and gsplat, and their gradient with respect to the view direction.

use crate::real::Real;

/// Degree-0 constant `1 / (2 sqrt(pi))`.
pub const C0: f64 = 0.28209479177387814;
/// Degree-1 constant.
pub const C1: f64 = 0.4886025119029199;
/// Degree-2 constants.
pub const C2: [f64; 5] = [
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
];
/// Degree-3 constants.
pub const C3: [f64; 7] = [
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
];

/// The first `(degree+1)^2` SH basis values at the unit direction `d`, and, when `with_grad`,
/// their gradients with respect to `d` (the coordinates treated as independent).
pub fn basis<T: Real>(degree: usize, d: [T; 3], with_grad: bool) -> ([T; 16], [[T; 3]; 16]) {
    let c = T::from_f64;
    let [x, y, z] = d;
    let z0 = T::ZERO;
    let mut b = [z0; 16];
    let mut g = [[z0; 3]; 16];
    b[0] = c(C0);
    if degree == 0 {
        return (b, g);
    }
    let c1 = c(C1);
    b[1] = -c1 * y;
    b[2] = c1 * z;
    b[3] = -c1 * x;
    if with_grad {
        g[1] = [z0, -c1, z0];
        g[2] = [z0, z0, c1];
        g[3] = [-c1, z0, z0];
    }
    if degree == 1 {
        return (b, g);
    }
    let (xx, yy, zz) = (x * x, y * y, z * z);
    let two = c(2.0);
    b[4] = c(C2[0]) * x * y;
    b[5] = c(C2[1]) * y * z;
    b[6] = c(C2[2]) * (two * zz - xx - yy);
    b[7] = c(C2[3]) * x * z;
    b[8] = c(C2[4]) * (xx - yy);
    if with_grad {
        g[4] = [c(C2[0]) * y, c(C2[0]) * x, z0];
        g[5] = [z0, c(C2[1]) * z, c(C2[1]) * y];
        g[6] = [-two * c(C2[2]) * x, -two * c(C2[2]) * y, c(4.0 * C2[2]) * z];
        g[7] = [c(C2[3]) * z, z0, c(C2[3]) * x];
        g[8] = [two * c(C2[4]) * x, -two * c(C2[4]) * y, z0];
    }
    if degree == 2 {
        return (b, g);
    }
    let three = c(3.0);
    let four = c(4.0);
    b[9] = c(C3[0]) * y * (three * xx - yy);
    b[10] = c(C3[1]) * x * y * z;
    b[11] = c(C3[2]) * y * (four * zz - xx - yy);
    b[12] = c(C3[3]) * z * (two * zz - three * xx - three * yy);
    b[13] = c(C3[4]) * x * (four * zz - xx - yy);
    b[14] = c(C3[5]) * z * (xx - yy);
    b[15] = c(C3[6]) * x * (xx - three * yy);
    if with_grad {
        g[9] = [
            c(C3[0]) * c(6.0) * x * y,
            c(C3[0]) * (three * xx - three * yy),
            z0,
        ];
        g[10] = [c(C3[1]) * y * z, c(C3[1]) * x * z, c(C3[1]) * x * y];
        g[11] = [
            -two * c(C3[2]) * x * y,
            c(C3[2]) * (four * zz - xx - three * yy),
            c(C3[2]) * c(8.0) * y * z,
        ];
        g[12] = [
            -c(6.0) * c(C3[3]) * x * z,
            -c(6.0) * c(C3[3]) * y * z,
            c(C3[3]) * (c(6.0) * zz - three * xx - three * yy),
        ];
        g[13] = [
            c(C3[4]) * (four * zz - three * xx - yy),
            -two * c(C3[4]) * x * y,
            c(C3[4]) * c(8.0) * x * z,
        ];
        g[14] = [
            two * c(C3[5]) * x * z,
            -two * c(C3[5]) * y * z,
            c(C3[5]) * (xx - yy),
        ];
        g[15] = [
            c(C3[6]) * (three * xx - three * yy),
            -c(6.0) * c(C3[6]) * x * y,
            z0,
        ];
    }
    (b, g)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn basis_gradient_matches_finite_differences() {
        let d = [0.3f64, -0.5, 0.81];
        let (_, g) = basis(3, d, true);
        let h = 1e-6;
        for axis in 0..3 {
            let mut p = d;
            let mut m = d;
            p[axis] += h;
            m[axis] -= h;
            let (bp, _) = basis(3, p, false);
            let (bm, _) = basis(3, m, false);
            for k in 0..16 {
                let fd = (bp[k] - bm[k]) / (2.0 * h);
                assert!((fd - g[k][axis]).abs() < 1e-8, "k={k} axis={axis}");
            }
        }
    }

    #[test]
    fn basis_is_orthonormal_on_the_sphere() {
        // Monte-Carlo-free check: a Fibonacci sphere quadrature of b_i b_j approximates
        // delta_ij / (4 pi) * 4 pi = delta_ij.
        let n = 20000;
        let mut gram = [[0.0f64; 16]; 16];
        for i in 0..n {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let phi = i as f64 * std::f64::consts::PI * (3.0 - 5f64.sqrt());
            let (b, _) = basis(3, [r * phi.cos(), r * phi.sin(), z], false);
            for a in 0..16 {
                for c in 0..16 {
                    gram[a][c] += b[a] * b[c] * 4.0 * std::f64::consts::PI / n as f64;
                }
            }
        }
        for (a, row) in gram.iter().enumerate() {
            for (c, v) in row.iter().enumerate() {
                let want = if a == c { 1.0 } else { 0.0 };
                assert!((v - want).abs() < 2e-3, "gram[{a}][{c}] = {v}");
            }
        }
    }
}
