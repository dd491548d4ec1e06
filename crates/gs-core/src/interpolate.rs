//! Parameter-by-parameter interpolation of two Gaussian sets with the same Gaussians (e.g. two
//! stylizations of one base model): `(1 - t) a + t b` for every stored parameter.
//!
//! Conventions:
//! - Parameters are blended as stored, so opacities blend in logit space and scales in log
//!   space (the blend of `sigmoid`/`exp` is not the `sigmoid`/`exp` of the blend).
//! - Quaternions `(w, x, y, z)` are blended then normalized. `q` and `-q` are the same rotation,
//!   so when `dot(q_a, q_b) < 0` the blend uses `-q_b` and takes the short way; at `t = 1` the
//!   result is then `-q_b / |q_b|`, the same rotation as `q_b`. A blend of zero length (both
//!   inputs zero, or an extrapolation through zero) stays zero, which the rasterizer culls as it
//!   culls a zero quaternion of the inputs.
//! - Any finite `t` is allowed: `t` outside `[0, 1]` extrapolates (exaggerates or reverses the
//!   difference between the sets), which is sometimes wanted. NaN or infinite `t` is an error.

use crate::model::BaseModel;
use crate::ply::PlyGaussians;
use crate::GaussianSet;

/// Why two sets cannot be interpolated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum InterpolateError {
    /// The sets hold different numbers of Gaussians.
    #[error("cannot interpolate {a} Gaussians with {b} Gaussians: the counts differ")]
    CountMismatch {
        /// Count of the first set.
        a: usize,
        /// Count of the second set.
        b: usize,
    },
    /// The sets have different spherical-harmonics degrees.
    #[error("cannot interpolate SH degree {a} with SH degree {b}: the degrees differ")]
    ShDegreeMismatch {
        /// Degree of the first set.
        a: usize,
        /// Degree of the second set.
        b: usize,
    },
    /// An array of a set does not have the length its count and degree call for.
    #[error("set `{set}` is malformed: {reason}")]
    Malformed {
        /// `"a"` or `"b"`.
        set: &'static str,
        /// Which array and which lengths.
        reason: String,
    },
    /// The interpolation parameter is NaN or infinite.
    #[error("interpolation parameter t = {t} is not finite")]
    NonFiniteT {
        /// The offending value.
        t: f32,
    },
}

/// `(1 - t) a + t b` for every parameter (see the module documentation for quaternions, logits,
/// log-scales and extrapolation): `t = 0` gives `a`, `t = 1` gives `b` (quaternions normalized).
pub fn interpolate(
    a: &GaussianSet,
    b: &GaussianSet,
    t: f32,
) -> Result<GaussianSet, InterpolateError> {
    if !t.is_finite() {
        return Err(InterpolateError::NonFiniteT { t });
    }
    if a.len() != b.len() {
        return Err(InterpolateError::CountMismatch {
            a: a.len(),
            b: b.len(),
        });
    }
    if a.sh_degree() != b.sh_degree() {
        return Err(InterpolateError::ShDegreeMismatch {
            a: a.sh_degree(),
            b: b.sh_degree(),
        });
    }
    for (set, name) in [(a, "a"), (b, "b")] {
        set.check_shapes()
            .map_err(|reason| InterpolateError::Malformed { set: name, reason })?;
    }
    let lerp = |x: f32, y: f32| (1.0 - t) * x + t * y;
    let mut out = a.clone();
    // Every array, quaternions included; these are then redone with the hemisphere flip.
    for (dst, src) in out.arrays_mut().into_iter().zip(b.arrays()) {
        dst.iter_mut().zip(src).for_each(|(x, &y)| *x = lerp(*x, y));
    }
    for ((q, qa), qb) in out
        .quats
        .chunks_exact_mut(4)
        .zip(a.quats.chunks_exact(4))
        .zip(b.quats.chunks_exact(4))
    {
        let dot: f32 = qa.iter().zip(qb).map(|(x, y)| x * y).sum();
        let sign = if dot < 0.0 { -1.0 } else { 1.0 };
        for ((v, &x), &y) in q.iter_mut().zip(qa).zip(qb) {
            *v = lerp(x, sign * y);
        }
        let norm = q.iter().map(|v| v * v).sum::<f32>().sqrt();
        if norm > 0.0 {
            q.iter_mut().for_each(|v| *v /= norm);
        }
    }
    Ok(out)
}

/// `(1 - t) a + t b` of every parameter group of two models of one modality with groups of the
/// same names and lengths (e.g. two stylizations of one fitted VeGaS or D-MiSo model: logits,
/// logs, quaternion inputs and network weights are blended as stored), or an error naming the
/// first group that differs.
pub fn blend_groups<M: BaseModel + Clone>(a: &M, b: &M, t: f32) -> Result<M, String> {
    if !t.is_finite() {
        return Err(format!("the interpolation parameter t = {t} is not finite"));
    }
    let (names, lens) = (a.group_names(), a.group_lens());
    if names != b.group_names() {
        return Err(format!(
            "groups {} against {}",
            names.join(", "),
            b.group_names().join(", ")
        ));
    }
    for ((name, n), m) in names.iter().zip(&lens).zip(b.group_lens()) {
        if *n != m {
            return Err(format!("{name}: {n} values against {m}"));
        }
    }
    let mut out = a.clone();
    let mut b = b.clone();
    for (x, y) in out.groups_mut().into_iter().zip(b.groups_mut()) {
        for (v, w) in x.iter_mut().zip(y.iter()) {
            *v = (1.0 - t) * *v + t * w;
        }
    }
    Ok(out)
}

/// [`interpolate`] of the Gaussians of two PLY files; the extra properties (normals and any
/// other vertex property) and the header comments are those of `a`, unchanged.
pub fn interpolate_ply(
    a: &PlyGaussians,
    b: &PlyGaussians,
    t: f32,
) -> Result<PlyGaussians, InterpolateError> {
    Ok(PlyGaussians {
        gaussians: interpolate(&a.gaussians, &b.gaussians, t)?,
        extras: a.extras.clone(),
        comments: a.comments.clone(),
        normals: a.normals,
    })
}
