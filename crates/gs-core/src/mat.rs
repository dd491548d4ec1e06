//! Row-major 3x3 and 2x2 matrix helpers on plain arrays, generic over [`Real`].

use crate::real::Real;

/// A 3-vector.
pub type V3<T> = [T; 3];
/// A row-major 3x3 matrix: `m[row][col]`.
pub type M3<T> = [[T; 3]; 3];

/// `a * b`.
#[inline]
pub fn mul<T: Real>(a: &M3<T>, b: &M3<T>) -> M3<T> {
    let mut r = [[T::ZERO; 3]; 3];
    for (i, row) in r.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
        }
    }
    r
}

/// `aᵀ`.
#[inline]
pub fn transpose<T: Real>(a: &M3<T>) -> M3<T> {
    [
        [a[0][0], a[1][0], a[2][0]],
        [a[0][1], a[1][1], a[2][1]],
        [a[0][2], a[1][2], a[2][2]],
    ]
}

/// `a * v`.
#[inline]
pub fn mul_vec<T: Real>(a: &M3<T>, v: &V3<T>) -> V3<T> {
    [
        a[0][0] * v[0] + a[0][1] * v[1] + a[0][2] * v[2],
        a[1][0] * v[0] + a[1][1] * v[1] + a[1][2] * v[2],
        a[2][0] * v[0] + a[2][1] * v[1] + a[2][2] * v[2],
    ]
}

/// `aᵀ * v`.
#[inline]
pub fn mul_t_vec<T: Real>(a: &M3<T>, v: &V3<T>) -> V3<T> {
    [
        a[0][0] * v[0] + a[1][0] * v[1] + a[2][0] * v[2],
        a[0][1] * v[0] + a[1][1] * v[1] + a[2][1] * v[2],
        a[0][2] * v[0] + a[1][2] * v[1] + a[2][2] * v[2],
    ]
}

/// Element-wise `a + b`.
#[inline]
pub fn add<T: Real>(a: &M3<T>, b: &M3<T>) -> M3<T> {
    let mut r = *a;
    for i in 0..3 {
        for j in 0..3 {
            r[i][j] += b[i][j];
        }
    }
    r
}

/// Dot product.
#[inline]
pub fn dot<T: Real>(a: &V3<T>, b: &V3<T>) -> T {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Rotation matrix of the unit quaternion `(w, x, y, z)` (the caller normalizes).
#[inline]
pub fn quat_to_rotation<T: Real>(q: [T; 4]) -> M3<T> {
    let [w, x, y, z] = q;
    let one = T::ONE;
    let two = T::from_f64(2.0);
    [
        [
            one - two * (y * y + z * z),
            two * (x * y - w * z),
            two * (x * z + w * y),
        ],
        [
            two * (x * y + w * z),
            one - two * (x * x + z * z),
            two * (y * z - w * x),
        ],
        [
            two * (x * z - w * y),
            two * (y * z + w * x),
            one - two * (x * x + y * y),
        ],
    ]
}

/// Gradient of a loss with respect to the unit quaternion `(w, x, y, z)`, given its gradient
/// `g` with respect to the rotation matrix [`quat_to_rotation`] builds from it.
#[inline]
pub fn quat_to_rotation_backward<T: Real>(q: [T; 4], g: &M3<T>) -> [T; 4] {
    let [w, x, y, z] = q;
    let two = T::from_f64(2.0);
    let gw = two * (x * (g[2][1] - g[1][2]) + y * (g[0][2] - g[2][0]) + z * (g[1][0] - g[0][1]));
    let gx = two
        * (-two * x * (g[1][1] + g[2][2])
            + y * (g[1][0] + g[0][1])
            + z * (g[2][0] + g[0][2])
            + w * (g[2][1] - g[1][2]));
    let gy = two
        * (-two * y * (g[0][0] + g[2][2])
            + x * (g[1][0] + g[0][1])
            + z * (g[2][1] + g[1][2])
            + w * (g[0][2] - g[2][0]));
    let gz = two
        * (-two * z * (g[0][0] + g[1][1])
            + x * (g[2][0] + g[0][2])
            + y * (g[2][1] + g[1][2])
            + w * (g[1][0] - g[0][1]));
    [gw, gx, gy, gz]
}

/// `v / |v|` and `|v|`; the zero vector gives itself and a zero length.
#[inline]
pub fn normalize3<T: Real>(v: V3<T>) -> (V3<T>, T) {
    let n = dot(&v, &v).sqrt();
    if n > T::ZERO {
        ([v[0] / n, v[1] / n, v[2] / n], n)
    } else {
        (v, T::ZERO)
    }
}

/// Gradient with respect to `v` of a loss whose gradient with respect to `v / |v|` is `g`,
/// where `d = v / |v|` and `n = |v|` (zero for a zero-length `v`, which gets no gradient).
#[inline]
pub fn normalize3_backward<T: Real>(d: V3<T>, n: T, g: V3<T>) -> V3<T> {
    if n <= T::ZERO {
        return [T::ZERO; 3];
    }
    let dg = dot(&d, &g);
    [
        (g[0] - d[0] * dg) / n,
        (g[1] - d[1] * dg) / n,
        (g[2] - d[2] * dg) / n,
    ]
}
