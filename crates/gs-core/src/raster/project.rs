//! Per-Gaussian projection (EWA splatting, gsplat conventions) and its exact backward.

use crate::camera::Camera;
use crate::gaussians::GaussianSet;
use crate::mat::{self, M3, V3};
use crate::real::Real;
use crate::sh;

use super::bin::tile_rect;
use super::{ALPHA_MIN, CONIC_GRAD_EPS, EPS2D, FAR_PLANE, NEAR_PLANE, PROJECTION_EPS, TILE_SIZE};

/// The camera, cast once to the working precision.
#[derive(Clone, Copy, Debug)]
pub struct CameraT<T: Real> {
    /// World-to-camera rotation (OpenCV axes), row-major.
    pub rotation: M3<T>,
    /// World-to-camera translation.
    pub translation: V3<T>,
    /// The camera's centre in world coordinates.
    pub centre: V3<T>,
    /// Focal length along x, pixels.
    pub fx: T,
    /// Focal length along y, pixels.
    pub fy: T,
    /// Principal point x, pixels.
    pub cx: T,
    /// Principal point y, pixels.
    pub cy: T,
    /// Clamp limits of `x/z` and `y/z` in the Jacobian: `[-neg_x, pos_x]`, `[-neg_y, pos_y]`.
    pub lim: [T; 4],
    /// Image width, pixels.
    pub width: T,
    /// Image height, pixels.
    pub height: T,
    /// Tiles per row and per column.
    pub tiles: [usize; 2],
}

impl<T: Real> CameraT<T> {
    /// `cam` in the working precision, with its Jacobian clamp limits (1.3 times the half
    /// field of view past each border, as gsplat and INRIA).
    pub fn new(cam: &Camera) -> Self {
        let c = T::from_f64;
        let tan_x = 0.5 * cam.width as f64 / cam.fx;
        let tan_y = 0.5 * cam.height as f64 / cam.fy;
        let lim = [
            (cam.width as f64 - cam.cx) / cam.fx + 0.3 * tan_x,
            cam.cx / cam.fx + 0.3 * tan_x,
            (cam.height as f64 - cam.cy) / cam.fy + 0.3 * tan_y,
            cam.cy / cam.fy + 0.3 * tan_y,
        ];
        let centre = cam.centre();
        Self {
            rotation: cam.rotation.map(|r| r.map(c)),
            translation: cam.translation.map(c),
            centre: centre.map(c),
            fx: c(cam.fx),
            fy: c(cam.fy),
            cx: c(cam.cx),
            cy: c(cam.cy),
            lim: lim.map(c),
            width: c(cam.width as f64),
            height: c(cam.height as f64),
            tiles: [
                (cam.width as usize).div_ceil(TILE_SIZE),
                (cam.height as usize).div_ceil(TILE_SIZE),
            ],
        }
    }
}

/// A projected Gaussian: what compositing needs.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Splat<T: Real> {
    /// Centre in pixels.
    pub mean2d: [T; 2],
    /// Inverse of the 2D covariance (with `EPS2D`), upper triangle `[a, b, c]`.
    pub conic: [T; 3],
    /// Camera-space depth `z`.
    pub depth: T,
    /// Opacity after the sigmoid.
    pub opacity: T,
    /// RGB after SH evaluation, `+0.5` and clamping at 0.
    pub color: [T; 3],
    /// Square screen-space radius (3 sigma), pixels; 0 when culled.
    pub radius: T,
    /// A pre-filter: at pixels where the Mahalanobis term `sigma` exceeds this, alpha is surely
    /// below `ALPHA_MIN` (`ln(opacity / ALPHA_MIN)` plus a margin), so `exp` is not evaluated.
    pub sigma_cut: T,
    /// Half-extents in x and y (pixels) of the ellipse `sigma <= sigma_cut`: outside the box
    /// `mean2d +- extent` the splat contributes nothing.
    pub extent: [T; 2],
}

/// The Mahalanobis term `sigma = 0.5 (a dx^2 + c dy^2) + b dx dy` of the conic `(a, b, c)` at the
/// offset `(dx, dy) = mean2d - pixel centre`. Binning and tests evaluate it here; compositing
/// through [`mahalanobis_in_row`] with the row's term computed once. One order of operations.
#[inline(always)]
pub(crate) fn mahalanobis<T: Real>(conic: [T; 3], dx: T, dy: T) -> T {
    mahalanobis_in_row(conic, dx, dy, conic[2] * dy * dy)
}

/// [`mahalanobis`] given `c_dy2 = conic[2] * dy * dy`, the term every pixel of a row shares
/// (computed once per row by the compositing loops); the same operations in the same order.
#[inline(always)]
pub(crate) fn mahalanobis_in_row<T: Real>(conic: [T; 3], dx: T, dy: T, c_dy2: T) -> T {
    T::from_f64(0.5) * (conic[0] * dx * dx + c_dy2) + conic[1] * dx * dy
}

/// Gradients of a loss with respect to one splat's compositing inputs.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct SplatGrad<T: Real> {
    pub mean2d: [T; 2],
    pub conic: [T; 3],
    pub opacity: T,
    pub color: [T; 3],
    pub depth: T,
}

impl<T: Real> SplatGrad<T> {
    pub fn add(&mut self, o: &Self) {
        for k in 0..2 {
            self.mean2d[k] += o.mean2d[k];
        }
        for k in 0..3 {
            self.conic[k] += o.conic[k];
            self.color[k] += o.color[k];
        }
        self.opacity += o.opacity;
        self.depth += o.depth;
    }
}

/// Intermediate values of one projection, kept for the backward pass.
struct Forward<T: Real> {
    p_cam: V3<T>,
    qn: [T; 4],
    q_norm: T,
    rot: M3<T>,
    scale: V3<T>,
    /// `rot * diag(scale)`.
    m: M3<T>,
    cov_cam: M3<T>,
    jac: [[T; 3]; 2],
    clamped: [bool; 2],
    u: [T; 2],
    conic: [T; 3],
    splat: Splat<T>,
    dir: V3<T>,
    dir_norm: T,
    basis: [T; 16],
    basis_grad: [[T; 3]; 16],
    color_active: [bool; 3],
}

fn all_finite<T: Real>(v: &[T]) -> bool {
    v.iter().all(|x| x.is_finite())
}

fn forward<T: Real>(
    g: &GaussianSet<T>,
    i: usize,
    cam: &CameraT<T>,
    with_grad: bool,
) -> Option<Forward<T>> {
    if !g.is_valid(i) {
        return None;
    }
    let c = T::from_f64;
    let mean = [g.means[3 * i], g.means[3 * i + 1], g.means[3 * i + 2]];
    let pr = mat::mul_vec(&cam.rotation, &mean);
    let p_cam = [
        pr[0] + cam.translation[0],
        pr[1] + cam.translation[1],
        pr[2] + cam.translation[2],
    ];
    let z = p_cam[2];
    if !(z > c(NEAR_PLANE)) || !(z < c(FAR_PLANE)) || !all_finite(&p_cam) {
        return None;
    }

    let q = [
        g.quats[4 * i],
        g.quats[4 * i + 1],
        g.quats[4 * i + 2],
        g.quats[4 * i + 3],
    ];
    let q_norm = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    if !(q_norm > T::ZERO) || !q_norm.is_finite() {
        return None;
    }
    let qn = q.map(|v| v / q_norm);
    let rot = mat::quat_to_rotation(qn);
    let scale = [
        g.log_scales[3 * i].exp(),
        g.log_scales[3 * i + 1].exp(),
        g.log_scales[3 * i + 2].exp(),
    ];
    let m = rot.map(|row| [row[0] * scale[0], row[1] * scale[1], row[2] * scale[2]]);
    let cov = mat::mul(&m, &mat::transpose(&m));
    let cov_cam = mat::mul(
        &mat::mul(&cam.rotation, &cov),
        &mat::transpose(&cam.rotation),
    );

    let ux_raw = p_cam[0] / z;
    let uy_raw = p_cam[1] / z;
    let ux = ux_raw.clamp(-cam.lim[1], cam.lim[0]);
    let uy = uy_raw.clamp(-cam.lim[3], cam.lim[2]);
    let clamped = [ux != ux_raw, uy != uy_raw];
    let jac = [
        [cam.fx / z, T::ZERO, -cam.fx * ux / z],
        [T::ZERO, cam.fy / z, -cam.fy * uy / z],
    ];
    // cov2d = J cov_cam J^T + eps2d I
    let mut jc = [[T::ZERO; 3]; 2];
    for r in 0..2 {
        for k in 0..3 {
            jc[r][k] =
                jac[r][0] * cov_cam[0][k] + jac[r][1] * cov_cam[1][k] + jac[r][2] * cov_cam[2][k];
        }
    }
    let dotj = |a: &[T; 3], b: &[T; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let a = dotj(&jc[0], &jac[0]) + c(EPS2D);
    let b = dotj(&jc[0], &jac[1]);
    let cc = dotj(&jc[1], &jac[1]) + c(EPS2D);
    let det = a * cc - b * b;
    if !(det > T::ZERO) || !det.is_finite() {
        return None;
    }
    let conic = [cc / det, -b / det, a / det];
    let mid = c(0.5) * (a + cc);
    // INRIA's floor of 0.1 under the root (gsplat's is 0.01): it sets the radius, and so the
    // tiles a splat is drawn in.
    let lambda = mid + (mid * mid - det).max(c(0.1)).sqrt();
    let radius = (c(3.0) * lambda.sqrt()).ceil();
    let z_proj = z + c(PROJECTION_EPS);
    let mean2d = [
        cam.fx * p_cam[0] / z_proj + cam.cx,
        cam.fy * p_cam[1] / z_proj + cam.cy,
    ];
    if !all_finite(&conic) || !all_finite(&mean2d) || !radius.is_finite() {
        return None;
    }
    // INRIA's only screen-space cull: an empty tile rectangle. A splat whose centre lies past
    // the last column or row by more than its radius is still drawn when its rectangle keeps
    // the last tile, which extends past the picture unless the side is a multiple of 16.
    let [x0, x1, y0, y1] = tile_rect(mean2d, radius, cam.tiles);
    if x0 == x1 || y0 == y1 {
        return None;
    }

    let opacity = g.opacity_logits[i].sigmoid();
    let sigma_cut = sigma_cut(opacity);
    // sigma = 0.5 d^T Q d <= cut spans sqrt(2 cut (Q^-1)_xx) in x and sqrt(2 cut (Q^-1)_yy) in y.
    // Q is the stored (rounded) conic the loops evaluate, so Q^-1 is taken from it in f64; the
    // 2D covariance's diagonal bounds it too where rounding leaves Q barely positive definite.
    // A 1 % and one-pixel margin covers the rest of the rounding.
    let extent = {
        let [qa, qb, qc] = conic.map(|v| v.to_f64());
        let det_q = qa * qc - qb * qb;
        let (mut ex, mut ey) = (a.to_f64(), cc.to_f64());
        if det_q > 0.0 {
            ex = ex.max(qc / det_q);
            ey = ey.max(qa / det_q);
        }
        let reach = (2.0 * sigma_cut.to_f64().max(0.0)).sqrt() * 1.01;
        [c(reach * ex.sqrt() + 1.0), c(reach * ey.sqrt() + 1.0)]
    };
    let (dir, dir_norm) = mat::normalize3([
        mean[0] - cam.centre[0],
        mean[1] - cam.centre[1],
        mean[2] - cam.centre[2],
    ]);
    let degree = g.sh_degree();
    let (basis, basis_grad) = sh::basis(degree, dir, with_grad && degree > 0);
    let k_rest = g.sh_coeffs() - 1;
    let rest = &g.sh_rest[3 * k_rest * i..3 * k_rest * (i + 1)];
    let mut color = [T::ZERO; 3];
    let mut color_active = [false; 3];
    for ch in 0..3 {
        let mut v = basis[0] * g.sh_dc[3 * i + ch] + c(0.5);
        for k in 0..k_rest {
            v += basis[k + 1] * rest[3 * k + ch];
        }
        // INRIA's `clamped` is `result < 0`: at exactly 0 the gradient passes (as PyTorch's
        // `clamp_min` of the authors' precomputed colours).
        color_active[ch] = v >= T::ZERO;
        color[ch] = v.max(T::ZERO);
    }

    Some(Forward {
        p_cam,
        qn,
        q_norm,
        rot,
        scale,
        m,
        cov_cam,
        jac,
        clamped,
        u: [ux, uy],
        conic,
        splat: Splat {
            mean2d,
            conic,
            depth: z,
            opacity,
            color,
            radius,
            sigma_cut,
            extent,
        },
        dir,
        dir_norm,
        basis,
        basis_grad,
        color_active,
    })
}

/// [`Splat::sigma_cut`] of a splat of `opacity`: `ln(opacity / ALPHA_MIN)` and a margin, or
/// -1 (no pixel) below `ALPHA_MIN`. At opacity exactly 1/255 it is the margin alone: the splat
/// still reaches alpha 1/255 where sigma is 0, which INRIA's skip (`alpha < 1/255`) keeps.
fn sigma_cut<T: Real>(opacity: T) -> T {
    let alpha_min = T::from_f64(ALPHA_MIN);
    if opacity >= alpha_min {
        (opacity / alpha_min).ln() + T::from_f64(1e-3)
    } else {
        -T::ONE
    }
}

/// Projects Gaussian `i`; `None` when it is culled (invalid parameters, depth at or below the
/// near plane, degenerate covariance, or an empty tile rectangle).
pub(crate) fn project<T: Real>(g: &GaussianSet<T>, i: usize, cam: &CameraT<T>) -> Option<Splat<T>> {
    forward(g, i, cam, false).map(|f| f.splat)
}

/// Which parameter arrays need a gradient.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Needs {
    pub geometry: bool,
    pub opacity: bool,
    pub sh_dc: bool,
    pub sh_rest: bool,
}

/// Gradients of Gaussian `i`'s parameters, except `sh_rest`: means (3), log-scales (3),
/// quaternion (4), opacity logit (1), SH dc (3).
pub(crate) type ParamGrad<T> = [T; 14];

/// The backward of [`project`] for Gaussian `i` given the gradient `sg` of its splat. Writes the
/// `sh_rest` gradient into `rest_grad` when asked for (`[K-1, 3]` of this Gaussian).
pub(crate) fn project_backward<T: Real>(
    g: &GaussianSet<T>,
    i: usize,
    cam: &CameraT<T>,
    sg: &SplatGrad<T>,
    needs: Needs,
    rest_grad: Option<&mut [T]>,
) -> ParamGrad<T> {
    let mut out = [T::ZERO; 14];
    let Some(f) = forward(g, i, cam, needs.geometry) else {
        return out;
    };
    let c = T::from_f64;
    let o = f.splat.opacity;
    out[10] = sg.opacity * o * (T::ONE - o);

    // Colour: d colour / d raw is 1 where the clamp at 0 is inactive.
    let g_raw: [T; 3] = std::array::from_fn(|ch| {
        if f.color_active[ch] {
            sg.color[ch]
        } else {
            T::ZERO
        }
    });
    for ch in 0..3 {
        out[11 + ch] = f.basis[0] * g_raw[ch];
    }
    let k_rest = g.sh_coeffs() - 1;
    if let Some(rg) = rest_grad {
        for k in 0..k_rest {
            for ch in 0..3 {
                rg[3 * k + ch] = f.basis[k + 1] * g_raw[ch];
            }
        }
    }
    if !needs.geometry {
        return out;
    }

    let mut g_mean = [T::ZERO; 3];
    if k_rest > 0 {
        let rest = &g.sh_rest[3 * k_rest * i..3 * k_rest * (i + 1)];
        let mut g_dir = [T::ZERO; 3];
        for k in 0..k_rest {
            let w =
                rest[3 * k] * g_raw[0] + rest[3 * k + 1] * g_raw[1] + rest[3 * k + 2] * g_raw[2];
            for ax in 0..3 {
                g_dir[ax] += w * f.basis_grad[k + 1][ax];
            }
        }
        g_mean = mat::normalize3_backward(f.dir, f.dir_norm, g_dir);
    }

    // Conic -> 2D covariance: d(S^-1) = -S^-1 dS S^-1, with G the symmetric gradient of the conic,
    // times INRIA's det^2 / (det^2 + CONIC_GRAD_EPS) (det of S; `1 / det` is the conic's).
    let [ca, cb, cc] = f.conic;
    let det_conic = ca * cc - cb * cb;
    let damp = T::ONE / (T::ONE + c(CONIC_GRAD_EPS) * det_conic * det_conic);
    let gm = [
        [sg.conic[0], c(0.5) * sg.conic[1]],
        [c(0.5) * sg.conic[1], sg.conic[2]],
    ];
    let inv = [[ca, cb], [cb, cc]];
    let mut g_cov2d = [[T::ZERO; 2]; 2];
    for r in 0..2 {
        for s in 0..2 {
            let mut v = T::ZERO;
            for k in 0..2 {
                for l in 0..2 {
                    v += inv[r][k] * gm[k][l] * inv[l][s];
                }
            }
            g_cov2d[r][s] = -damp * v;
        }
    }

    // cov2d = J Sc J^T: dSc = J^T G J, dJ = 2 G J Sc (G symmetric).
    let jac = f.jac;
    let mut g_cov_cam = [[T::ZERO; 3]; 3];
    for (a, row) in g_cov_cam.iter_mut().enumerate() {
        for (b, v) in row.iter_mut().enumerate() {
            let mut s = T::ZERO;
            for r in 0..2 {
                for t in 0..2 {
                    s += jac[r][a] * g_cov2d[r][t] * jac[t][b];
                }
            }
            *v = s;
        }
    }
    let mut g_jac = [[T::ZERO; 3]; 2];
    for r in 0..2 {
        for k in 0..3 {
            let mut s = T::ZERO;
            for t in 0..2 {
                for l in 0..3 {
                    s += g_cov2d[r][t] * jac[t][l] * f.cov_cam[l][k];
                }
            }
            g_jac[r][k] = c(2.0) * s;
        }
    }

    // Jacobian and mean2d -> camera-space position.
    let [tx, ty, tz] = f.p_cam;
    let (fx, fy) = (cam.fx, cam.fy);
    let tz2 = tz * tz;
    let mut g_p = [T::ZERO; 3];
    g_p[2] += g_jac[0][0] * (-fx / tz2)
        + g_jac[1][1] * (-fy / tz2)
        + g_jac[0][2] * (fx * f.u[0] / tz2)
        + g_jac[1][2] * (fy * f.u[1] / tz2);
    let g_u = [g_jac[0][2] * (-fx / tz), g_jac[1][2] * (-fy / tz)];
    for (ax, t) in [(0usize, tx), (1, ty)] {
        if !f.clamped[ax] {
            g_p[ax] += g_u[ax] / tz;
            g_p[2] -= g_u[ax] * t / tz2;
        } else {
            // INRIA's `dL_dtz` takes `J[.][2] = -f t / tz^2` with the clamped `t = u tz` as if `t`
            // did not depend on `tz`: `2 f t / tz^3`, twice the derivative through the clamp.
            g_p[2] -= g_u[ax] * f.u[ax] / tz;
        }
    }
    // mean2d = f t / (tz + PROJECTION_EPS) + c.
    let tz_proj = tz + c(PROJECTION_EPS);
    g_p[0] += sg.mean2d[0] * fx / tz_proj;
    g_p[1] += sg.mean2d[1] * fy / tz_proj;
    g_p[2] -= (sg.mean2d[0] * fx * tx + sg.mean2d[1] * fy * ty) / (tz_proj * tz_proj);
    g_p[2] += sg.depth;
    let g_world = mat::mul_t_vec(&cam.rotation, &g_p);
    for ax in 0..3 {
        out[ax] = g_mean[ax] + g_world[ax];
    }

    // cov_cam = W cov W^T: dcov = W^T dSc W; cov = M M^T: dM = 2 dcov M; M = R diag(s).
    let w = &cam.rotation;
    let g_cov = mat::mul(&mat::mul(&mat::transpose(w), &g_cov_cam), w);
    let g_m = mat::mul(&mat::add(&g_cov, &mat::transpose(&g_cov)), &f.m);
    let mut g_rot = [[T::ZERO; 3]; 3];
    for r in 0..3 {
        for k in 0..3 {
            g_rot[r][k] = g_m[r][k] * f.scale[k];
        }
    }
    for k in 0..3 {
        let g_s = g_m[0][k] * f.rot[0][k] + g_m[1][k] * f.rot[1][k] + g_m[2][k] * f.rot[2][k];
        out[3 + k] = g_s * f.scale[k];
    }
    let g_qn = mat::quat_to_rotation_backward(f.qn, &g_rot);
    let qdot = f.qn[0] * g_qn[0] + f.qn[1] * g_qn[1] + f.qn[2] * g_qn[2] + f.qn[3] * g_qn[3];
    for k in 0..4 {
        out[6 + k] = (g_qn[k] - f.qn[k] * qdot) / f.q_norm;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check_sigma_cut<T: Real>() {
        let alpha_min = T::from_f64(ALPHA_MIN);
        // Drawn where sigma is 0 at opacity exactly 1/255, as INRIA's `alpha < 1/255` skip.
        assert!(sigma_cut(alpha_min) >= T::ZERO);
        let below = T::from_f64(ALPHA_MIN * (1.0 - 1e-6));
        assert!(below < alpha_min && sigma_cut(below) < T::ZERO);
        // Above it, every sigma with opacity exp(-sigma) >= 1/255 is within the cut.
        for opacity in [0.004, 0.1, 0.5, 0.99, 1.0] {
            let o = T::from_f64(opacity);
            let sigma = (o / alpha_min).ln();
            assert!(sigma <= sigma_cut(o));
        }
    }

    #[test]
    fn the_sigma_cut_keeps_every_pixel_inria_draws() {
        check_sigma_cut::<f32>();
        check_sigma_cut::<f64>();
    }
}
