//! Image losses with their gradients: L1 and SSIM as 3DGS computes them (11x11 Gaussian window,
//! sigma 1.5, zero padding, per channel, averaged over every pixel and channel).

use std::any::Any;
use std::sync::{Arc, Mutex, MutexGuard};

use rayon::prelude::*;

use crate::image::Image;
use crate::real::Real;
use crate::render_clamp::RenderClamp;
use crate::train::{Objective, ObjectiveValue};
use crate::GsError;

/// Side of the SSIM window, pixels.
pub const SSIM_WINDOW: usize = 11;
/// Standard deviation of the SSIM window, pixels.
pub const SSIM_SIGMA: f64 = 1.5;
const SSIM_C1: f64 = 0.01 * 0.01;
const SSIM_C2: f64 = 0.03 * 0.03;

/// A loss value and its gradient with respect to the first image (same layout as the image).
#[derive(Clone, Debug, PartialEq)]
pub struct LossGrad<T: Real = f32> {
    /// The loss.
    pub loss: T,
    /// dL/d(image).
    pub grad: Vec<T>,
}

/// Mean absolute difference of two equally long images and its gradient with respect to `a`
/// (`sign(a - b) / n`, 0 where they are equal).
///
/// # Panics
/// If the lengths differ.
pub fn l1<T: Real>(a: &[T], b: &[T]) -> LossGrad<T> {
    assert_eq!(a.len(), b.len(), "images of different sizes");
    let inv_n = T::ONE / T::from_f64(a.len().max(1) as f64);
    let loss = a
        .iter()
        .zip(b)
        .fold(T::ZERO, |s, (x, y)| s + (*x - *y).abs())
        * inv_n;
    let grad = a
        .iter()
        .zip(b)
        .map(|(x, y)| {
            if x > y {
                inv_n
            } else if x < y {
                -inv_n
            } else {
                T::ZERO
            }
        })
        .collect();
    LossGrad { loss, grad }
}

/// The SSIM window's weights: a Gaussian of sigma [`SSIM_SIGMA`] over [`SSIM_WINDOW`] taps,
/// normalised to sum 1 (in f64, then rounded to `T`).
pub fn ssim_window<T: Real>() -> [T; SSIM_WINDOW] {
    let half = (SSIM_WINDOW / 2) as f64;
    let raw: [f64; SSIM_WINDOW] = std::array::from_fn(|i| {
        (-((i as f64 - half).powi(2)) / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp()
    });
    let sum: f64 = raw.iter().sum();
    raw.map(|v| T::from_f64(v / sum))
}

/// Separable Gaussian blur of a `w` x `h` plane with zero padding ("same" size). The window is
/// symmetric, so this is also its own transpose.
///
/// Both passes run tap by tap over whole rows (loops the compiler vectorizes); every output
/// still sums its taps from zero in increasing tap order, so the result is that of the plain
/// per-pixel loop, bit for bit.
fn blur<T: Real>(plane: &[T], w: usize, h: usize, k: &[T; SSIM_WINDOW]) -> Vec<T> {
    let r = SSIM_WINDOW / 2;
    let mut tmp = vec![T::ZERO; w * h];
    tmp.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let src = &plane[y * w..(y + 1) * w];
        for (t, &wgt) in k.iter().enumerate() {
            // Output x reads src[x + t - r]: x in [r - t, w + r - t) stays inside the row.
            let lo = r.saturating_sub(t);
            let hi = (w + r).saturating_sub(t).min(w);
            if lo >= hi {
                continue;
            }
            let from = lo + t - r;
            for (o, v) in row[lo..hi].iter_mut().zip(&src[from..from + (hi - lo)]) {
                *o += wgt * *v;
            }
        }
    });
    let mut out = vec![T::ZERO; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let lo = y.saturating_sub(r);
        let hi = (y + r).min(h - 1);
        for yy in lo..=hi {
            let wgt = k[yy + r - y];
            for (o, v) in row.iter_mut().zip(&tmp[yy * w..(yy + 1) * w]) {
                *o += wgt * *v;
            }
        }
    });
    out
}

/// Mean SSIM of two `width` x `height` RGB images (HWC) and its gradient with respect to `a`.
/// Images without pixels count as identical (SSIM 1).
///
/// # Panics
/// If either image does not hold `width * height * 3` values.
pub fn ssim<T: Real>(a: &[T], b: &[T], width: usize, height: usize) -> LossGrad<T> {
    let n = width * height;
    assert_eq!(a.len(), 3 * n, "first image has the wrong size");
    assert_eq!(b.len(), 3 * n, "second image has the wrong size");
    if n == 0 {
        return LossGrad {
            loss: T::ONE,
            grad: Vec::new(),
        };
    }
    let k = ssim_window::<T>();
    let (c1, c2) = (T::from_f64(SSIM_C1), T::from_f64(SSIM_C2));
    let two = T::from_f64(2.0);
    let inv_count = T::ONE / T::from_f64((3 * n).max(1) as f64);
    let mut total = 0.0f64;
    let mut grad = vec![T::ZERO; 3 * n];
    for ch in 0..3 {
        let x: Vec<T> = (0..n).map(|i| a[3 * i + ch]).collect();
        let y: Vec<T> = (0..n).map(|i| b[3 * i + ch]).collect();
        let prod = |p: &[T], q: &[T]| p.iter().zip(q).map(|(u, v)| *u * *v).collect::<Vec<T>>();
        let mu_x = blur(&x, width, height, &k);
        let mu_y = blur(&y, width, height, &k);
        let m_xx = blur(&prod(&x, &x), width, height, &k);
        let m_yy = blur(&prod(&y, &y), width, height, &k);
        let m_xy = blur(&prod(&x, &y), width, height, &k);
        // Per-pixel SSIM and its partials with respect to mu_x, m_xx and m_xy, scaled by the
        // weight of the mean.
        let mut s_map = vec![T::ZERO; n];
        let mut d_mu = vec![T::ZERO; n];
        let mut d_xx = vec![T::ZERO; n];
        let mut d_xy = vec![T::ZERO; n];
        (
            s_map.par_chunks_mut(width),
            d_mu.par_chunks_mut(width),
            d_xx.par_chunks_mut(width),
            d_xy.par_chunks_mut(width),
        )
            .into_par_iter()
            .enumerate()
            .for_each(|(row, (s_row, d_mu, d_xx, d_xy))| {
                for (j, s_out) in s_row.iter_mut().enumerate() {
                    let i = row * width + j;
                    let (mx, my) = (mu_x[i], mu_y[i]);
                    let a1 = two * mx * my + c1;
                    let a2 = two * (m_xy[i] - mx * my) + c2;
                    let b1 = mx * mx + my * my + c1;
                    let b2 = (m_xx[i] - mx * mx) + (m_yy[i] - my * my) + c2;
                    let den = b1 * b2;
                    let s = a1 * a2 / den;
                    *s_out = s;
                    d_mu[j] = inv_count
                        * ((two * my * a2 - two * my * a1) / den
                            - s * (two * mx * b2 - two * mx * b1) / den);
                    d_xx[j] = -inv_count * s / b2;
                    d_xy[j] = inv_count * two * a1 / den;
                }
            });
        // Summed in pixel order, channel after channel, as one thread would.
        for s in &s_map {
            total += s.to_f64();
        }
        let g_mu = blur(&d_mu, width, height, &k);
        let g_xx = blur(&d_xx, width, height, &k);
        let g_xy = blur(&d_xy, width, height, &k);
        for i in 0..n {
            grad[3 * i + ch] = g_mu[i] + two * x[i] * g_xx[i] + y[i] * g_xy[i];
        }
    }
    LossGrad {
        loss: T::from_f64(total) * inv_count,
        grad,
    }
}

/// Peak signal-to-noise ratio of `a` against `b` in dB, both clamped to `[0, 1]` first (as
/// 8-bit pictures are); the mean squared error is floored at 1e-12, so equal images give 120 dB
/// rather than infinity.
///
/// # Panics
/// If the images differ in size.
pub fn psnr(a: &Image, b: &Image) -> f64 {
    assert_eq!(
        (a.width, a.height),
        (b.width, b.height),
        "PSNR of images of different sizes"
    );
    let mse = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| ((x.clamp(0.0, 1.0) - y.clamp(0.0, 1.0)) as f64).powi(2))
        .sum::<f64>()
        / a.data.len().max(1) as f64;
    psnr_of_mse(mse)
}

/// The PSNR in dB of a mean squared error of values in `[0, 1]`, floored at 1e-12 (so 120 dB at
/// most); NaN stays NaN.
pub fn psnr_of_mse(mse: f64) -> f64 {
    10.0 * (1.0 / mse.max(1e-12)).log10()
}

/// The mean [`psnr`] of `renders` against `targets` (pairs in order), dB; 0 for none.
pub fn mean_psnr(renders: &[Image], targets: &[Image]) -> f64 {
    let sum: f64 = renders.iter().zip(targets).map(|(r, t)| psnr(r, t)).sum();
    sum / targets.len().max(1) as f64
}

/// The fitting objective of 3DGS and MiraGe: `(1 - lambda) L1 + lambda (1 - SSIM)` against a
/// target image per view. A GPU trainer evaluates it on the device
/// ([`Objective::photometric`]), keeping the targets there in the objective's [`DeviceSlot`]
/// for as long as the objective lives (every trainer of a fit finds them there); they are fixed
/// at construction. A clone shares the slot: its targets are the same.
#[derive(Clone, Debug)]
pub struct PhotometricObjective {
    targets: Vec<Image>,
    lambda: f32,
    device: DeviceSlot,
}

impl PhotometricObjective {
    /// The objective against `targets` (one per view, in view order) with D-SSIM weight
    /// `lambda` (0.2 in 3DGS and MiraGe).
    pub fn new(targets: Vec<Image>, lambda: f32) -> Self {
        Self {
            targets,
            lambda,
            device: DeviceSlot::default(),
        }
    }

    /// The targets, one per view.
    pub fn targets(&self) -> &[Image] {
        &self.targets
    }

    /// The D-SSIM weight.
    pub fn lambda(&self) -> f32 {
        self.lambda
    }
}

/// What a compute device keeps of an objective between steps (a GPU's copy of its targets),
/// of a type only that device knows; dropped with the objective (and its clones).
#[derive(Clone, Default)]
pub struct DeviceSlot(Arc<Mutex<Option<Box<dyn Any + Send + Sync>>>>);

impl DeviceSlot {
    /// The slot's content, locked.
    pub fn lock(&self) -> MutexGuard<'_, Option<Box<dyn Any + Send + Sync>>> {
        // A device that panicked while filling the slot left it as it was: still usable.
        self.0
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }
}

impl std::fmt::Debug for DeviceSlot {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let filled = self.lock().is_some();
        f.debug_struct("DeviceSlot")
            .field("filled", &filled)
            .finish()
    }
}

/// A photometric objective as a device evaluates it where the render lives
/// ([`Objective::photometric`]): `(1 - lambda) L1 + lambda (1 - SSIM)` of the render as `clamp`
/// says against `targets[view]`.
#[derive(Clone, Copy, Debug)]
pub struct PhotometricForm<'a> {
    /// One target per view.
    pub targets: &'a [Image],
    /// Where the device keeps its copy of the targets.
    pub device: &'a DeviceSlot,
    /// The D-SSIM weight.
    pub lambda: f32,
    /// What the loss sees of the render.
    pub clamp: RenderClamp,
}

/// What a device hands back of a photometric objective for one render: the means over every
/// value (pixel and channel), summed in f64 from its partial sums.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhotometricSums {
    /// Mean `|x - y|` of the seen render `x` and the target `y`.
    pub l1: f64,
    /// Mean SSIM.
    pub ssim: f64,
    /// Mean squared difference of the render and the target, both clamped to `[0, 1]` (PSNR's).
    pub mse: f64,
}

impl PhotometricSums {
    /// The objective's value of D-SSIM weight `lambda`: its loss and terms as
    /// [`PhotometricObjective::evaluate`] gives them (dL/dimage stays on the device: empty).
    pub fn value(&self, lambda: f32) -> ObjectiveValue {
        photometric_value(self.l1 as f32, self.ssim as f32, lambda, Vec::new())
    }
}

/// The photometric objective's value from its mean L1 and mean SSIM: `(1 - lambda) l1 +
/// lambda (1 - ssim)`, its two weighted terms, and `grad`.
fn photometric_value(l1: f32, ssim: f32, lambda: f32, grad: Vec<f32>) -> ObjectiveValue {
    let w1 = 1.0 - lambda;
    let d_ssim = 1.0 - ssim;
    ObjectiveValue {
        loss: w1 * l1 + lambda * d_ssim,
        terms: vec![
            ("l1".to_string(), w1 * l1),
            ("d_ssim".to_string(), lambda * d_ssim),
        ],
        grad,
    }
}

/// A [`PhotometricObjective`] that also logs each render it is given: `(view, PSNR in dB)` in
/// the order of evaluation (for a fit of one view a step, entry `k` is step `k + 1`'s render,
/// before its update).
#[derive(Clone, Debug)]
pub struct PsnrLog {
    /// The objective.
    pub inner: PhotometricObjective,
    /// The log.
    pub log: Vec<(usize, f64)>,
}

impl Objective for PsnrLog {
    type Error = GsError;

    fn evaluate(&mut self, view: usize, image: &Image) -> Result<ObjectiveValue, GsError> {
        let value = self.inner.evaluate(view, image)?;
        self.log
            .push((view, psnr(image, &self.inner.targets[view])));
        Ok(value)
    }

    fn photometric(&self) -> Option<PhotometricForm<'_>> {
        self.inner.photometric()
    }

    fn device_value(&mut self, view: usize, sums: &PhotometricSums) -> ObjectiveValue {
        self.log.push((view, psnr_of_mse(sums.mse)));
        self.inner.device_value(view, sums)
    }
}

/// Checks the settings every photometric fit shares (MiraGe's, VeGaS's): at least one Gaussian
/// and one step, a D-SSIM weight in `[0, 1]`, background channels in `[0, 1]`; the error starts
/// with the field (`gaussians: must be at least 1`).
pub fn check_fit_settings(
    gaussians: usize,
    steps: u64,
    lambda_dssim: f32,
    background: [f32; 3],
) -> Result<(), String> {
    if gaussians == 0 {
        return Err("gaussians: must be at least 1".into());
    }
    if steps == 0 {
        return Err("steps: must be at least 1".into());
    }
    if !(lambda_dssim.is_finite() && (0.0..=1.0).contains(&lambda_dssim)) {
        return Err(format!("lambda_dssim: {lambda_dssim} must be in [0, 1]"));
    }
    if background.iter().any(|c| !(0.0..=1.0).contains(c)) {
        return Err(format!(
            "background: {background:?} must have channels in [0, 1]"
        ));
    }
    Ok(())
}

impl Objective for PhotometricObjective {
    type Error = GsError;

    fn evaluate(&mut self, view: usize, image: &Image) -> Result<ObjectiveValue, GsError> {
        let target = &self.targets[view];
        if (target.width, target.height) != (image.width, image.height) {
            return Err(GsError::SizeMismatch {
                view,
                render_w: image.width,
                render_h: image.height,
                target_w: target.width,
                target_h: target.height,
            });
        }
        let (w, h) = (image.width as usize, image.height as usize);
        let l = l1(&image.data, &target.data);
        let s = ssim(&image.data, &target.data, w, h);
        let w1 = 1.0 - self.lambda;
        let grad = l
            .grad
            .iter()
            .zip(&s.grad)
            .map(|(g1, gs)| w1 * g1 - self.lambda * gs)
            .collect();
        Ok(photometric_value(l.loss, s.loss, self.lambda, grad))
    }

    fn photometric(&self) -> Option<PhotometricForm<'_>> {
        Some(PhotometricForm {
            targets: &self.targets,
            device: &self.device,
            lambda: self.lambda,
            clamp: RenderClamp::Off,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn noise(seed: u64, n: usize) -> Vec<f64> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..n).map(|_| rng.random_range(0.0..1.0)).collect()
    }

    #[test]
    fn psnr_of_a_known_error() {
        let a = Image::filled(4, 2, [0.5, 0.5, 0.5]);
        let b = Image::filled(4, 2, [0.6, 0.5, 0.5]);
        // MSE = 0.01 / 3.
        let expected = 10.0 * (3.0f64 / 0.01).log10();
        assert!((psnr(&a, &b) - expected).abs() < 1e-4, "{}", psnr(&a, &b));
        assert_eq!(psnr(&a, &a), 120.0);
    }

    #[test]
    fn ssim_of_an_image_with_itself_is_one() {
        let a = noise(1, 3 * 20 * 13);
        let s = ssim(&a, &a, 20, 13);
        assert!((s.loss - 1.0).abs() < 1e-12);
        assert!(s.grad.iter().all(|g| g.abs() < 1e-12));
    }

    #[test]
    fn ssim_gradient_matches_finite_differences() {
        let (w, h) = (17, 12);
        let a = noise(2, 3 * w * h);
        let b = noise(3, 3 * w * h);
        let s = ssim(&a, &b, w, h);
        let eps = 1e-6;
        for idx in [0, 5, 100, 3 * w * h / 2, 3 * w * h - 1] {
            let mut p = a.clone();
            p[idx] += eps;
            let mut m = a.clone();
            m[idx] -= eps;
            let fd = (ssim(&p, &b, w, h).loss - ssim(&m, &b, w, h).loss) / (2.0 * eps);
            assert!(
                (fd - s.grad[idx]).abs() < 1e-7 * (1.0 + fd.abs() * 1e3),
                "{idx}: {fd} vs {}",
                s.grad[idx]
            );
        }
    }

    #[test]
    fn blur_is_the_normalized_2d_gaussian_window() {
        let k = ssim_window::<f64>();
        assert!((k.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        assert!((k[5] / k[6] - (1.0f64 / (2.0 * 1.5 * 1.5)).exp()).abs() < 1e-12);
        // At the centre of an 11x11 plane the blur is the full 2D weighted sum.
        let (w, h) = (11, 11);
        let x = noise(4, w * h);
        let direct: f64 = (0..w * h).map(|i| k[i / w] * k[i % w] * x[i]).sum();
        assert!((blur(&x, w, h, &k)[5 * w + 5] - direct).abs() < 1e-12);
        // At a corner, zero padding drops the taps outside.
        let corner: f64 = (0..w * h)
            .filter(|i| i / w <= 5 && i % w <= 5)
            .map(|i| k[i / w + 5] * k[i % w + 5] * x[i])
            .sum();
        assert!((blur(&x, w, h, &k)[0] - corner).abs() < 1e-12);
    }

    /// The blur as a per-pixel loop: each output sums its taps from zero in increasing order,
    /// along the rows and then along the columns.
    fn blur_per_pixel(plane: &[f32], w: usize, h: usize, k: &[f32; SSIM_WINDOW]) -> Vec<f32> {
        let r = SSIM_WINDOW as isize / 2;
        let (wi, hi) = (w as isize, h as isize);
        // Output (x, y) sums k[t] src[(x, y) + (t - r) step].
        let pass = |src: &[f32], (step_x, step_y): (isize, isize)| {
            let mut out = vec![0f32; w * h];
            for y in 0..hi {
                for x in 0..wi {
                    let mut s = 0f32;
                    for (t, &wgt) in k.iter().enumerate() {
                        let (xx, yy) =
                            (x + (t as isize - r) * step_x, y + (t as isize - r) * step_y);
                        if (0..wi).contains(&xx) && (0..hi).contains(&yy) {
                            s += wgt * src[(yy * wi + xx) as usize];
                        }
                    }
                    out[(y * wi + x) as usize] = s;
                }
            }
            out
        };
        pass(&pass(plane, (1, 0)), (0, 1))
    }

    #[test]
    fn blur_is_the_per_pixel_loop_bit_for_bit_at_any_size() {
        let k = ssim_window::<f32>();
        for (i, &(w, h)) in [(1, 1), (1, 9), (7, 1), (5, 3), (11, 11), (12, 4), (40, 23)]
            .iter()
            .enumerate()
        {
            let x: Vec<f32> = noise(10 + i as u64, w * h)
                .iter()
                .map(|&v| v as f32 - 0.3)
                .collect();
            let ours = blur(&x, w, h, &k);
            let reference = blur_per_pixel(&x, w, h, &k);
            for (p, (a, b)) in ours.iter().zip(&reference).enumerate() {
                assert_eq!(a.to_bits(), b.to_bits(), "{w}x{h}, pixel {p}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn ssim_of_constant_images_in_the_interior() {
        // Far from the border, constant images give (2 ab + C1) / (a^2 + b^2 + C1).
        let (w, h) = (40, 40);
        let a = vec![0.5f64; 3 * w * h];
        let b = vec![0.25f64; 3 * w * h];
        let s = ssim(&a, &b, w, h);
        let interior = (2.0 * 0.5 * 0.25 + SSIM_C1) / (0.25 + 0.0625 + SSIM_C1);
        // The border ring lowers the mean; the interior (30x30 of 40x40) dominates it.
        assert!(
            s.loss < interior && s.loss > 0.56 * interior,
            "{} vs {interior}",
            s.loss
        );
    }

    #[test]
    fn l1_and_its_gradient() {
        let l = l1(&[0.5f64, 0.2, 0.7], &[0.1, 0.2, 0.9]);
        assert!((l.loss - 0.2).abs() < 1e-12);
        assert_eq!(l.grad, vec![1.0 / 3.0, 0.0, -1.0 / 3.0]);
    }

    #[test]
    fn photometric_objective_weights_both_terms_and_checks_sizes() {
        let (w, h) = (8u32, 8u32);
        let img = |seed| Image {
            width: w,
            height: h,
            data: noise(seed, 3 * 64).iter().map(|v| *v as f32).collect(),
        };
        let (a, b) = (img(6), img(7));
        let mut obj = PhotometricObjective::new(vec![b.clone()], 0.2);
        let v = obj.evaluate(0, &a).unwrap();
        let l = l1(&a.data, &b.data);
        let s = ssim(&a.data, &b.data, 8, 8);
        assert!((v.loss - (0.8 * l.loss + 0.2 * (1.0 - s.loss))).abs() < 1e-6);
        let g: Vec<f32> = l
            .grad
            .iter()
            .zip(&s.grad)
            .map(|(x, y)| 0.8 * x - 0.2 * y)
            .collect();
        assert_eq!(v.grad, g);
        let small = Image::filled(4, 8, [0.0; 3]);
        let e = obj.evaluate(0, &small).unwrap_err().to_string();
        assert!(e.contains("4x8") && e.contains("8x8"), "{e}");
    }
}
