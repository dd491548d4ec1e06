//! The differentiable rasterizer (cpu backend, rayon): EWA projection, SH colour, 16x16 tile
//! binning, depth-ordered front-to-back compositing over a background colour, and the backward
//! pass to every Gaussian parameter and to the background (exact except where INRIA's backward
//! is not: at the alpha cap, at the Jacobian's clamp and in the conic's gradient, see
//! [`backward`]).
//!
//! Layouts are gsplat's; the near plane, radius, tile rectangles and the gradient at the alpha
//! cap are INRIA's rasterizer's, which every modality's authors use (see
//! `docs/conventions.md`). Gaussians whose parameters are not
//! finite, whose quaternion is zero, whose depth is at or below [`NEAR_PLANE`], whose 2D
//! covariance is degenerate or not finite, or whose tile rectangle is empty (INRIA's only
//! screen-space cull) are culled: they
//! draw nothing and receive zero gradient.

mod bin;
mod composite;
pub mod project;

use rayon::prelude::*;

use crate::camera::Camera;
use crate::gaussians::{GaussianGrads, GaussianSet};
use crate::image::Image;
use crate::real::Real;

use bin::TileBins;
use project::{CameraT, Needs, Splat, SplatGrad};

/// Side of the square screen tiles, pixels.
pub const TILE_SIZE: usize = 16;
/// Added to the diagonal of every 2D covariance (pixels^2), as gsplat's `eps2d`.
pub const EPS2D: f64 = 0.3;
/// Gaussians at camera depth `z <= NEAR_PLANE` are culled (INRIA's `in_frustum`, which every
/// modality's authors' renderer keeps; gsplat's default is 0.01).
pub const NEAR_PLANE: f64 = 0.2;
/// Added to the depth by which a centre is divided in its projection to pixels,
/// `mean2d = f x / (z + PROJECTION_EPS) + c`: INRIA's `p_w = 1 / (p_hom.w + 0.0000001)` (its
/// Jacobian divides by `z` alone).
pub const PROJECTION_EPS: f64 = 1e-7;
/// In the backward of the conic `S^-1` (`S` the 2D covariance), INRIA's
/// `denom2inv = 1 / (det(S)^2 + 0.0000001)` where the exact derivative has `1 / det(S)^2`: the
/// gradient of `S` is the exact one times `det^2 / (det^2 + CONIC_GRAD_EPS)`.
pub const CONIC_GRAD_EPS: f64 = 1e-7;
/// Gaussians at camera depth `z >= FAR_PLANE` are culled (gsplat's default far plane).
pub const FAR_PLANE: f64 = 1e10;
/// Upper clamp of a splat's alpha; the backward passes the gradient through it as INRIA's
/// rasterizer does (see [`backward`]).
pub const ALPHA_MAX: f64 = 0.99;
/// Splats with alpha below this at a pixel are skipped there.
pub const ALPHA_MIN: f64 = 1.0 / 255.0;
/// A pixel stops at the first splat that would take its transmittance below this.
pub const TRANSMITTANCE_MIN: f64 = 1e-4;

/// The result of [`render`]: the image and per-pixel alpha and depth, plus what [`backward`]
/// needs.
pub struct Rendered<T: Real = f32> {
    /// RGB composited over the background.
    pub image: Image<T>,
    /// Accumulated opacity `1 - T_final`, `[H, W]`.
    pub alpha: Vec<T>,
    /// Accumulated depth `sum_i w_i z_i` (camera z, not divided by alpha), `[H, W]`.
    pub depth: Vec<T>,
    splats: Vec<Option<Splat<T>>>,
    bins: TileBins,
    final_t: Vec<T>,
    n_contrib: Vec<u32>,
    background: [T; 3],
}

impl<T: Real> Rendered<T> {
    /// Whether Gaussian `i` survived culling (3DGS's `radii > 0`).
    pub fn is_visible(&self, i: usize) -> bool {
        self.splats.get(i).is_some_and(Option::is_some)
    }

    /// Number of Gaussians that survived culling.
    pub fn visible_count(&self) -> usize {
        self.splats.iter().filter(|s| s.is_some()).count()
    }

    /// Number of (tile, Gaussian) pairs composited.
    pub fn intersection_count(&self) -> usize {
        self.bins.ids.len()
    }
}

/// Renders `gaussians` through `camera` over `background` (RGB).
///
/// # Panics
/// If the arrays of `gaussians` do not match its count and degree
/// ([`GaussianSet::check_shapes`]) or the camera is invalid ([`Camera::validate`]).
pub fn render<T: Real>(
    gaussians: &GaussianSet<T>,
    camera: &Camera,
    background: [T; 3],
) -> Rendered<T> {
    if let Err(e) = gaussians.check_shapes() {
        panic!("malformed Gaussian set: {e}");
    }
    if let Err(e) = camera.validate() {
        panic!("{e}");
    }
    let cam = CameraT::<T>::new(camera);
    let splats: Vec<Option<Splat<T>>> = (0..gaussians.len())
        .into_par_iter()
        .map(|i| project::project(gaussians, i, &cam))
        .collect();
    let bins = bin::bin(&splats, camera.width, camera.height);
    let (w, h) = (camera.width as usize, camera.height as usize);
    let out = composite::forward(&splats, &bins, w, h, background);
    Rendered {
        image: Image {
            width: camera.width,
            height: camera.height,
            data: out.rgb,
        },
        alpha: out.alpha,
        depth: out.depth,
        splats,
        bins,
        final_t: out.final_t,
        n_contrib: out.n_contrib,
        background,
    }
}

/// Gradients of a loss with respect to the rendered outputs, row-major like the outputs.
/// `alpha` and `depth` are optional; absent means zero.
#[derive(Clone, Copy, Debug)]
pub struct OutputGrads<'a, T: Real = f32> {
    /// dL/d(RGB), `[H, W, 3]`.
    pub rgb: &'a [T],
    /// dL/d(alpha), `[H, W]`.
    pub alpha: Option<&'a [T]>,
    /// dL/d(depth), `[H, W]`.
    pub depth: Option<&'a [T]>,
}

/// Which parameter arrays need a gradient; a frozen array costs no gradient work and gets zeros.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GradMask {
    /// Means.
    pub means: bool,
    /// Log-scales.
    pub scales: bool,
    /// Quaternions.
    pub rotations: bool,
    /// Opacity logits.
    pub opacities: bool,
    /// Degree-0 SH.
    pub sh_dc: bool,
    /// Higher-degree SH.
    pub sh_rest: bool,
}

impl GradMask {
    /// Every parameter array.
    pub const ALL: Self = Self {
        means: true,
        scales: true,
        rotations: true,
        opacities: true,
        sh_dc: true,
        sh_rest: true,
    };

    /// Colours only (video stylization freezes the geometry and opacity).
    pub const COLORS: Self = Self {
        means: false,
        scales: false,
        rotations: false,
        opacities: false,
        sh_dc: true,
        sh_rest: true,
    };
}

/// Gradients of a loss with respect to every Gaussian parameter and the background colour.
#[derive(Clone, Debug, PartialEq)]
pub struct Gradients<T: Real = f32> {
    /// Per-parameter gradients, in the layout of the Gaussian set.
    pub gaussians: GaussianGrads<T>,
    /// dL/d(background RGB).
    pub background: [T; 3],
}

/// The backward pass of [`render`]: given the gradients of a loss with respect to its
/// outputs, the gradients with respect to the parameters of `gaussians` (the same set that was
/// rendered, through the same `camera`) and to the background. It is the exact derivative
/// except in three places, where it is INRIA's rasterizer's (and so every modality's authors'
/// code's): where a splat's alpha is capped at [`ALPHA_MAX`] the gradient of
/// `opacity * exp(-sigma)` passes as if uncapped (the exact derivative would be zero); where
/// the Jacobian's `x/z` or `y/z` is clamped, its depth term is twice the derivative through the
/// clamp; and the conic's gradient is damped by [`CONIC_GRAD_EPS`] (`docs/conventions.md`).
///
/// # Panics
/// If `gaussians` or `camera` is not the one `rendered` came from (count or image size differ),
/// or the output gradients do not have the image's size.
pub fn backward<T: Real>(
    gaussians: &GaussianSet<T>,
    camera: &Camera,
    rendered: &Rendered<T>,
    out_grads: &OutputGrads<'_, T>,
    mask: GradMask,
) -> Gradients<T> {
    backward_with_screen_grads(gaussians, camera, rendered, out_grads, mask).0
}

/// [`backward`], and each Gaussian's dL/d(projected centre) in pixels: the gradient 3DGS
/// accumulates for densification (its "view-space" gradient is this times `W / 2`, `H / 2`;
/// see [`crate::densify::ScreenStats`]). Zero for a Gaussian culled in this view, and for every
/// Gaussian when `mask` asks no geometry gradient (means, scales or rotations).
pub fn backward_with_screen_grads<T: Real>(
    gaussians: &GaussianSet<T>,
    camera: &Camera,
    rendered: &Rendered<T>,
    out_grads: &OutputGrads<'_, T>,
    mask: GradMask,
) -> (Gradients<T>, Vec<[T; 2]>) {
    assert_eq!(
        gaussians.len(),
        rendered.splats.len(),
        "backward needs the Gaussian set that was rendered"
    );
    assert_eq!(
        (camera.width, camera.height),
        (rendered.image.width, rendered.image.height),
        "backward needs the camera that was rendered"
    );
    let (w, h) = (camera.width as usize, camera.height as usize);
    assert_eq!(out_grads.rgb.len(), 3 * w * h, "dL/dRGB has the wrong size");
    for g in [out_grads.alpha, out_grads.depth].into_iter().flatten() {
        assert_eq!(g.len(), w * h, "dL/dalpha or dL/ddepth has the wrong size");
    }
    let n = gaussians.len();
    let degree = gaussians.sh_degree();
    let mut grads = GaussianGrads::<T>::zero_grads(n, degree);
    let needs = Needs {
        geometry: mask.means || mask.scales || mask.rotations,
        opacity: mask.opacities,
        sh_dc: mask.sh_dc,
        sh_rest: mask.sh_rest && degree > 0,
    };
    let (slots, bg_grad) = composite::backward(rendered, out_grads, needs.geometry);
    if !(needs.geometry || needs.opacity || needs.sh_dc || needs.sh_rest) {
        let gradients = Gradients {
            gaussians: grads,
            background: bg_grad,
        };
        return (gradients, vec![[T::ZERO; 2]; n]);
    }

    let mut per_gaussian = vec![SplatGrad::<T>::default(); n];
    for (slot, &gid) in slots.iter().zip(&rendered.bins.ids) {
        per_gaussian[gid as usize].add(slot);
    }

    let cam = CameraT::<T>::new(camera);
    let k_rest = gaussians.sh_coeffs() - 1;
    let mut params = vec![[T::ZERO; 14]; n];
    let one = |i: usize, p: &mut [T; 14], rest: Option<&mut [T]>| {
        if rendered.splats[i].is_some() {
            *p = project::project_backward(gaussians, i, &cam, &per_gaussian[i], needs, rest);
        }
    };
    if needs.sh_rest {
        params
            .par_iter_mut()
            .zip(grads.sh_rest.par_chunks_mut(3 * k_rest))
            .enumerate()
            .for_each(|(i, (p, r))| one(i, p, Some(r)));
    } else {
        params
            .par_iter_mut()
            .enumerate()
            .for_each(|(i, p)| one(i, p, None));
    }

    for (i, p) in params.iter().enumerate() {
        if mask.means {
            grads.means[3 * i..3 * i + 3].copy_from_slice(&p[0..3]);
        }
        if mask.scales {
            grads.log_scales[3 * i..3 * i + 3].copy_from_slice(&p[3..6]);
        }
        if mask.rotations {
            grads.quats[4 * i..4 * i + 4].copy_from_slice(&p[6..10]);
        }
        if mask.opacities {
            grads.opacity_logits[i] = p[10];
        }
        if mask.sh_dc {
            grads.sh_dc[3 * i..3 * i + 3].copy_from_slice(&p[11..14]);
        }
    }
    let gradients = Gradients {
        gaussians: grads,
        background: bg_grad,
    };
    let screen = per_gaussian.iter().map(|g| g.mean2d).collect();
    (gradients, screen)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Every pixel centre where a splat can reach alpha 1/255 lies inside its box
    /// `mean2d +- extent`, which the splat-major compositing loops rely on.
    #[test]
    fn splat_extent_contains_every_contributing_pixel() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let mut g = GaussianSet::<f64>::zeros(300, 0);
        for v in &mut g.means {
            *v = rng.random_range(-1.0..1.0);
        }
        for v in &mut g.log_scales {
            *v = rng.random_range(-5.0..-1.0);
        }
        for v in &mut g.quats {
            *v = rng.random_range(-1.0..1.0);
        }
        for v in &mut g.opacity_logits {
            *v = rng.random_range(-6.0..8.0);
        }
        let cam =
            Camera::look_at([0.3, -0.2, -3.0], [0.0; 3], [0.0, -1.0, 0.0], 1.0, 120, 90).unwrap();
        let ct = CameraT::<f64>::new(&cam);
        let mut checked = 0;
        for i in 0..g.len() {
            let Some(s) = project::project(&g, i, &ct) else {
                continue;
            };
            let [mx, my] = s.mean2d;
            for py in (my - 60.0).floor() as i64..(my + 60.0).ceil() as i64 {
                for px in (mx - 60.0).floor() as i64..(mx + 60.0).ceil() as i64 {
                    let (dx, dy) = (mx - (px as f64 + 0.5), my - (py as f64 + 0.5));
                    let sigma = project::mahalanobis(s.conic, dx, dy);
                    let alpha = (s.opacity * (-sigma).exp()).min(ALPHA_MAX);
                    if alpha >= ALPHA_MIN {
                        checked += 1;
                        assert!(
                            dx.abs() <= s.extent[0] && dy.abs() <= s.extent[1],
                            "pixel ({px},{py}) outside the box of {s:?}"
                        );
                    }
                }
            }
        }
        assert!(checked > 1000, "only {checked} contributing pixels checked");
    }
}
