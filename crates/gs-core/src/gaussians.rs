//! The Gaussian set: structure-of-arrays parameters of a fixed number of 3D Gaussians.

use crate::fallible::{filled, OutOfMemory};
use crate::real::{cast_slice, Real};

/// Number of SH coefficients per colour channel for a degree: `(degree + 1)^2`.
pub const fn sh_coeff_count(degree: usize) -> usize {
    (degree + 1) * (degree + 1)
}

/// Values per Gaussian of each parameter array of a set of SH degree `sh_degree`, in the order
/// of [`PARAM_NAMES`]: means 3, log-scales 3, quaternions 4, opacity 1, DC 3, the rest
/// `3 ((degree + 1)^2 - 1)`.
pub const fn row_widths(sh_degree: usize) -> [usize; 6] {
    [3, 3, 4, 1, 3, 3 * (sh_coeff_count(sh_degree) - 1)]
}

/// Highest spherical-harmonics degree the rasterizer evaluates.
pub const MAX_SH_DEGREE: usize = 3;

/// Parameters of `len` Gaussians, each in a flat array (structure of arrays), in the
/// conventions of gsplat / INRIA 3DGS:
///
/// - `means`: world positions, `[N, 3]`.
/// - `log_scales`: natural logarithms of the three axis scales (world units), `[N, 3]`.
/// - `quats`: rotations as quaternions `(w, x, y, z)`, `[N, 4]`; normalized when used, so any
///   non-zero length is allowed.
/// - `opacity_logits`: opacity before the sigmoid, `[N]`.
/// - `sh_dc`: the degree-0 SH coefficient per colour channel, `[N, 3]`.
/// - `sh_rest`: the SH coefficients of degree 1..=`sh_degree`, `[N, K-1, 3]` with
///   `K = (sh_degree+1)^2` (coefficient-major, channel-minor); empty at degree 0, so no memory or
///   work is spent on degrees a scene does not have.
///
/// The count is fixed at construction: nothing adds or removes Gaussians. The same type holds
/// gradients (see [`GaussianGrads`]).
#[derive(Clone, Debug, PartialEq)]
pub struct GaussianSet<T: Real = f32> {
    len: usize,
    sh_degree: usize,
    /// World positions, `[N, 3]`.
    pub means: Vec<T>,
    /// Log axis scales, `[N, 3]`.
    pub log_scales: Vec<T>,
    /// Quaternions `(w, x, y, z)`, `[N, 4]`.
    pub quats: Vec<T>,
    /// Opacity logits, `[N]`.
    pub opacity_logits: Vec<T>,
    /// Degree-0 SH coefficients, `[N, 3]`.
    pub sh_dc: Vec<T>,
    /// Higher-degree SH coefficients, `[N, K-1, 3]`.
    pub sh_rest: Vec<T>,
}

/// Gradients of a loss with respect to every parameter of a [`GaussianSet`], in its layout.
pub type GaussianGrads<T = f32> = GaussianSet<T>;

impl<T: Real> GaussianSet<T> {
    /// `len` Gaussians of SH degree `sh_degree` (at most [`MAX_SH_DEGREE`]) with every parameter
    /// zero except the identity quaternion.
    ///
    /// # Panics
    /// If `sh_degree > MAX_SH_DEGREE`.
    pub fn zeros(len: usize, sh_degree: usize) -> Self {
        Self::try_zeros(len, sh_degree).unwrap_or_else(|e| {
            let layout =
                std::alloc::Layout::array::<u8>(e.bytes).unwrap_or(std::alloc::Layout::new::<u8>());
            std::alloc::handle_alloc_error(layout)
        })
    }

    /// [`zeros`](Self::zeros), or an error when the machine cannot give the memory (for sets
    /// sized by a file).
    pub fn try_zeros(len: usize, sh_degree: usize) -> Result<Self, OutOfMemory> {
        assert!(
            sh_degree <= MAX_SH_DEGREE,
            "SH degree {sh_degree} is above the supported {MAX_SH_DEGREE}"
        );
        const WHAT: &str = "the Gaussians' arrays";
        let zeros = |n: usize| filled(n, T::ZERO, WHAT);
        let mut quats = zeros(len.saturating_mul(4))?;
        for q in quats.chunks_exact_mut(4) {
            q[0] = T::ONE;
        }
        Ok(Self {
            len,
            sh_degree,
            means: zeros(len.saturating_mul(3))?,
            log_scales: zeros(len.saturating_mul(3))?,
            quats,
            opacity_logits: zeros(len)?,
            sh_dc: zeros(len.saturating_mul(3))?,
            sh_rest: zeros(len.saturating_mul((sh_coeff_count(sh_degree) - 1) * 3))?,
        })
    }

    /// The set of the arrays a pipeline holds: `means` `[N, 3]`, `log_scales` `[N, 3]`,
    /// `quats` `[N, 4]` (w, x, y, z), `opacity_logits` `[N]` and `sh` `[N, K, 3]` with
    /// `K = (degree + 1)^2` (all coefficients of a Gaussian together, channel last, as gsplat
    /// and 3DGS hold them); the degree follows from `K`. An error names the array whose
    /// length does not fit.
    pub fn from_arrays(
        means: Vec<T>,
        log_scales: Vec<T>,
        quats: Vec<T>,
        opacity_logits: Vec<T>,
        sh: &[T],
    ) -> Result<Self, String> {
        let len = opacity_logits.len();
        let per_gaussian = sh.len().checked_div(len).unwrap_or(3);
        let sh_degree = (0..=MAX_SH_DEGREE)
            .find(|&d| 3 * sh_coeff_count(d) == per_gaussian && sh.len() == per_gaussian * len)
            .ok_or_else(|| {
                format!(
                    "sh has {} values: {len} Gaussians need (degree + 1)^2 * 3 each, degree 0 to \
                     {MAX_SH_DEGREE}",
                    sh.len()
                )
            })?;
        let (mut sh_dc, mut sh_rest) = (Vec::with_capacity(3 * len), Vec::new());
        for coefficients in sh.chunks_exact(per_gaussian) {
            sh_dc.extend_from_slice(&coefficients[..3]);
            sh_rest.extend_from_slice(&coefficients[3..]);
        }
        let set = Self {
            len,
            sh_degree,
            means,
            log_scales,
            quats,
            opacity_logits,
            sh_dc,
            sh_rest,
        };
        set.check_shapes()?;
        Ok(set)
    }

    /// All SH coefficients as `[N, K, 3]` (the layout of [`GaussianSet::from_arrays`]).
    pub fn sh(&self) -> Vec<T> {
        let rest = 3 * (self.sh_coeffs() - 1);
        let mut out = Vec::with_capacity(3 * self.sh_coeffs() * self.len);
        for i in 0..self.len {
            out.extend_from_slice(&self.sh_dc[3 * i..3 * i + 3]);
            out.extend_from_slice(&self.sh_rest[rest * i..rest * (i + 1)]);
        }
        out
    }

    /// A set with every entry zero, quaternions included: the starting point of a gradient.
    pub fn zero_grads(len: usize, sh_degree: usize) -> Self {
        let mut g = Self::zeros(len, sh_degree);
        g.quats.fill(T::ZERO);
        g
    }

    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when the set holds no Gaussian.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Spherical-harmonics degree (0..=3).
    pub fn sh_degree(&self) -> usize {
        self.sh_degree
    }

    /// SH coefficients per channel, `(sh_degree+1)^2`.
    pub fn sh_coeffs(&self) -> usize {
        sh_coeff_count(self.sh_degree)
    }

    /// Checks that every array has the length the count and degree call for.
    pub fn check_shapes(&self) -> Result<(), String> {
        let n = self.len;
        let rest = (self.sh_coeffs() - 1) * 3 * n;
        let expect = [
            ("means", self.means.len(), 3 * n),
            ("log_scales", self.log_scales.len(), 3 * n),
            ("quats", self.quats.len(), 4 * n),
            ("opacity_logits", self.opacity_logits.len(), n),
            ("sh_dc", self.sh_dc.len(), 3 * n),
            ("sh_rest", self.sh_rest.len(), rest),
        ];
        for (name, got, want) in expect {
            if got != want {
                return Err(format!(
                    "{name} has {got} values, {want} expected for {n} Gaussians of SH degree {}",
                    self.sh_degree
                ));
            }
        }
        Ok(())
    }

    /// True when every parameter of Gaussian `i` is finite and its quaternion is not zero.
    /// Other Gaussians are culled by the rasterizer.
    pub fn is_valid(&self, i: usize) -> bool {
        let finite = |s: &[T]| s.iter().all(|v| v.is_finite());
        let k = self.sh_coeffs() - 1;
        let q = &self.quats[4 * i..4 * i + 4];
        finite(&self.means[3 * i..3 * i + 3])
            && finite(&self.log_scales[3 * i..3 * i + 3])
            && finite(q)
            && q.iter().any(|v| *v != T::ZERO)
            && self.opacity_logits[i].is_finite()
            && finite(&self.sh_dc[3 * i..3 * i + 3])
            && finite(&self.sh_rest[3 * k * i..3 * k * (i + 1)])
    }

    /// Converts every parameter to another real type (e.g. to `f64` for a reference render).
    pub fn cast<U: Real>(&self) -> GaussianSet<U> {
        GaussianSet {
            len: self.len,
            sh_degree: self.sh_degree,
            means: cast_slice(&self.means),
            log_scales: cast_slice(&self.log_scales),
            quats: cast_slice(&self.quats),
            opacity_logits: cast_slice(&self.opacity_logits),
            sh_dc: cast_slice(&self.sh_dc),
            sh_rest: cast_slice(&self.sh_rest),
        }
    }

    /// The parameter arrays with their names, in the fixed order of [`PARAM_NAMES`].
    pub fn arrays(&self) -> [&[T]; 6] {
        [
            &self.means,
            &self.log_scales,
            &self.quats,
            &self.opacity_logits,
            &self.sh_dc,
            &self.sh_rest,
        ]
    }

    /// The Gaussians `rows` names, in that order (a row may repeat).
    ///
    /// # Panics
    /// If a row is out of range.
    pub fn gather(&self, rows: &[usize]) -> Self {
        let mut out = Self {
            len: rows.len(),
            sh_degree: self.sh_degree,
            means: Vec::new(),
            log_scales: Vec::new(),
            quats: Vec::new(),
            opacity_logits: Vec::new(),
            sh_dc: Vec::new(),
            sh_rest: Vec::new(),
        };
        let widths = row_widths(self.sh_degree);
        for ((to, from), w) in out.arrays_mut().into_iter().zip(self.arrays()).zip(widths) {
            to.reserve(w * rows.len());
            for &i in rows {
                to.extend_from_slice(&from[w * i..w * (i + 1)]);
            }
        }
        out
    }

    /// The first Gaussian whose quaternion is zero (a rotation of no direction: it renders as
    /// nothing, or as NaN), if any.
    pub fn zero_rotation(&self) -> Option<usize> {
        self.quats
            .chunks_exact(4)
            .position(|q| q.iter().all(|&v| v == T::ZERO))
    }

    /// Mutable parameter arrays, in the fixed order of [`PARAM_NAMES`].
    pub fn arrays_mut(&mut self) -> [&mut Vec<T>; 6] {
        [
            &mut self.means,
            &mut self.log_scales,
            &mut self.quats,
            &mut self.opacity_logits,
            &mut self.sh_dc,
            &mut self.sh_rest,
        ]
    }
}

/// Names of the parameter arrays of a [`GaussianSet`], in the order of
/// [`GaussianSet::arrays`]; also the names of the Adam parameter groups of plain Gaussians.
pub const PARAM_NAMES: [&str; 6] = [
    "means",
    "scales",
    "rotations",
    "opacities",
    "sh_dc",
    "sh_rest",
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arrays_with_sh_of_shape_n_k_3_round_trip() {
        // Two Gaussians of degree 1: K = 4 coefficients of 3 channels each.
        let sh: Vec<f32> = (0..24).map(|v| v as f32).collect();
        let set = GaussianSet::from_arrays(
            vec![0.0; 6],
            vec![-1.0; 6],
            vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
            vec![0.5, -0.5],
            &sh,
        )
        .unwrap();
        assert_eq!(set.sh_degree(), 1);
        assert_eq!(set.sh_dc, [0.0, 1.0, 2.0, 12.0, 13.0, 14.0]);
        assert_eq!(&set.sh_rest[..3], [3.0, 4.0, 5.0]);
        assert_eq!(set.sh(), sh);
    }

    #[test]
    fn arrays_of_the_wrong_length_are_named() {
        let e = GaussianSet::<f32>::from_arrays(
            vec![0.0; 6],
            vec![0.0; 6],
            vec![0.0; 8],
            vec![0.0; 2],
            &[0.0; 10],
        )
        .unwrap_err();
        assert!(e.contains("sh has 10 values"), "{e}");
        let e = GaussianSet::<f32>::from_arrays(
            vec![0.0; 5],
            vec![0.0; 6],
            vec![0.0; 8],
            vec![0.0; 2],
            &[0.0; 6],
        )
        .unwrap_err();
        assert!(e.starts_with("means has 5 values"), "{e}");
    }
}
