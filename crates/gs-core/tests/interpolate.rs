//! Parameter-by-parameter interpolation of Gaussian sets: end points, midpoints, quaternion
//! hemispheres, extrapolation, PLY extras and every error.

use gs_core::interpolate::{interpolate, interpolate_ply, InterpolateError};
use gs_core::ply::{ExtraProperty, PlyGaussians, ScalarType};
use gs_core::GaussianSet;
use rand::{Rng, SeedableRng};

/// `n` Gaussians of SH degree `degree` with every parameter drawn from a seeded generator;
/// quaternions have positive `w`, so two such sets are not forced into opposite hemispheres.
fn random_set(n: usize, degree: usize, seed: u64) -> GaussianSet {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut set = GaussianSet::zeros(n, degree);
    for array in set.arrays_mut() {
        for v in array.iter_mut() {
            *v = rng.random_range(-3.0f32..3.0);
        }
    }
    for q in set.quats.chunks_exact_mut(4) {
        q[0] = q[0].abs() + 1.0;
    }
    set
}

fn normalized(q: &[f32]) -> Vec<f32> {
    let norm = q.iter().map(|v| v * v).sum::<f32>().sqrt();
    q.iter().map(|v| v / norm).collect()
}

fn assert_close(got: &[f32], want: &[f32], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: lengths");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!(
            (g - w).abs() <= 1e-5 * (1.0 + w.abs()),
            "{what}[{i}]: {g} vs {w}"
        );
    }
}

/// Every array but the quaternions equal, quaternions equal to `want`'s normalized up to sign.
fn assert_matches(got: &GaussianSet, want: &GaussianSet) {
    assert_eq!((got.len(), got.sh_degree()), (want.len(), want.sh_degree()));
    let names = gs_core::gaussians::PARAM_NAMES;
    for ((name, g), w) in names.iter().zip(got.arrays()).zip(want.arrays()) {
        if *name == "rotations" {
            for (gq, wq) in g.chunks_exact(4).zip(w.chunks_exact(4)) {
                // q and -q are the same rotation: the blend may land in the other hemisphere.
                let mut want = normalized(wq);
                if gq.iter().zip(&want).map(|(x, y)| x * y).sum::<f32>() < 0.0 {
                    want.iter_mut().for_each(|v| *v = -*v);
                }
                assert_close(gq, &want, name);
            }
        } else {
            assert_close(g, w, name);
        }
    }
}

#[test]
fn end_points_give_the_inputs() {
    for degree in 0..=3 {
        let a = random_set(7, degree, 1);
        let b = random_set(7, degree, 2);
        let start = interpolate(&a, &b, 0.0).unwrap();
        assert_matches(&start, &a);
        // At t = 0 the sign is a's own.
        for (q, qa) in start.quats.chunks_exact(4).zip(a.quats.chunks_exact(4)) {
            assert_close(q, &normalized(qa), "quats at t = 0");
        }
        assert_matches(&interpolate(&a, &b, 1.0).unwrap(), &b);
    }
}

#[test]
fn midpoint_is_the_mean_of_stored_values() {
    let mut a = GaussianSet::zeros(1, 1);
    let mut b = GaussianSet::zeros(1, 1);
    a.means.copy_from_slice(&[1.0, 2.0, 3.0]);
    b.means.copy_from_slice(&[3.0, -2.0, 5.0]);
    a.log_scales.copy_from_slice(&[-1.0, 0.0, 1.0]);
    b.log_scales.copy_from_slice(&[1.0, 2.0, -3.0]);
    a.opacity_logits[0] = -4.0;
    b.opacity_logits[0] = 2.0;
    a.sh_dc.copy_from_slice(&[0.5, 0.5, 0.5]);
    b.sh_dc.copy_from_slice(&[1.5, -0.5, 0.0]);
    a.sh_rest.fill(1.0);
    b.sh_rest.fill(-3.0);
    // 90 degrees about z in b: the midpoint is 45 degrees about z.
    b.quats.copy_from_slice(&[0.0, 0.0, 0.0, 1.0]);
    let mid = interpolate(&a, &b, 0.5).unwrap();
    assert_close(&mid.means, &[2.0, 0.0, 4.0], "means");
    // Log space: the midpoint scale is the geometric mean exp(0), exp(1), exp(-1).
    assert_close(&mid.log_scales, &[0.0, 1.0, -1.0], "log_scales");
    // Logit space: logit -1, not the logit of the mean opacity.
    assert_close(&mid.opacity_logits, &[-1.0], "opacity_logits");
    assert_close(&mid.sh_dc, &[1.0, 0.0, 0.25], "sh_dc");
    assert_close(&mid.sh_rest, &[-1.0; 9], "sh_rest");
    let h = std::f32::consts::FRAC_1_SQRT_2;
    assert_close(&mid.quats, &[h, 0.0, 0.0, h], "quats");
}

#[test]
fn opposite_hemisphere_quaternions_take_the_short_way() {
    let mut a = GaussianSet::zeros(1, 0);
    let mut b = GaussianSet::zeros(1, 0);
    a.quats.copy_from_slice(&[1.0, 0.0, 0.0, 0.0]);
    // -(cos 45, 0, 0, sin 45): 90 degrees about z written in the opposite hemisphere.
    let h = std::f32::consts::FRAC_1_SQRT_2;
    b.quats.copy_from_slice(&[-h, 0.0, 0.0, -h]);
    let mid = interpolate(&a, &b, 0.5).unwrap();
    // Short way: 45 degrees about z. Without the flip it would be 135 degrees.
    let (c, s) = (22.5f32.to_radians().cos(), 22.5f32.to_radians().sin());
    assert_close(&mid.quats, &[c, 0.0, 0.0, s], "quats");
    // The end point is b's rotation, written in a's hemisphere.
    let end = interpolate(&a, &b, 1.0).unwrap();
    assert_close(&end.quats, &[h, 0.0, 0.0, h], "quats at t = 1");
}

#[test]
fn extrapolation_is_allowed() {
    let mut a = GaussianSet::zeros(1, 0);
    let mut b = GaussianSet::zeros(1, 0);
    a.means.copy_from_slice(&[0.0, 1.0, 2.0]);
    b.means.copy_from_slice(&[1.0, 1.0, 0.0]);
    let out = interpolate(&a, &b, 2.0).unwrap();
    assert_close(&out.means, &[2.0, 1.0, -2.0], "means");
    let back = interpolate(&a, &b, -1.0).unwrap();
    assert_close(&back.means, &[-1.0, 1.0, 4.0], "means");
}

#[test]
fn zero_quaternions_stay_zero() {
    let mut a = GaussianSet::zeros(1, 0);
    a.quats.fill(0.0);
    let out = interpolate(&a, &a, 0.5).unwrap();
    assert_eq!(out.quats, vec![0.0; 4]);
}

#[test]
fn mismatches_name_both_numbers() {
    let err = interpolate(&random_set(3, 1, 1), &random_set(5, 1, 2), 0.5).unwrap_err();
    assert_eq!(err, InterpolateError::CountMismatch { a: 3, b: 5 });
    let text = err.to_string();
    assert!(text.contains('3') && text.contains('5'), "{text}");
    let err = interpolate(&random_set(4, 2, 1), &random_set(4, 3, 2), 0.5).unwrap_err();
    assert_eq!(err, InterpolateError::ShDegreeMismatch { a: 2, b: 3 });
    let text = err.to_string();
    assert!(text.contains('2') && text.contains('3'), "{text}");
}

#[test]
fn malformed_sets_are_refused() {
    let a = random_set(2, 0, 1);
    let mut b = random_set(2, 0, 2);
    b.means.pop();
    let text = interpolate(&a, &b, 0.5).unwrap_err().to_string();
    assert!(text.contains("`b`") && text.contains("means"), "{text}");
}

#[test]
fn non_finite_t_is_an_error() {
    let a = random_set(2, 0, 1);
    for t in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let err = interpolate(&a, &a, t).unwrap_err();
        assert!(matches!(err, InterpolateError::NonFiniteT { .. }), "{err}");
        assert!(err.to_string().contains("not finite"), "{err}");
    }
}

#[test]
fn ply_interpolation_keeps_the_extras_of_a() {
    let extra = |name: &str, v: f64| ExtraProperty {
        name: name.to_string(),
        ty: ScalarType::Float32,
        values: vec![v; 4],
    };
    let a = PlyGaussians {
        gaussians: random_set(4, 3, 1),
        extras: vec![extra("nx", 0.0), extra("confidence", 7.0)],
        comments: vec!["picture 40x32".into()],
        normals: true,
    };
    let b = PlyGaussians {
        gaussians: random_set(4, 3, 2),
        extras: vec![extra("other", -1.0)],
        comments: Vec::new(),
        normals: false,
    };
    let out = interpolate_ply(&a, &b, 0.25).unwrap();
    assert_eq!((&out.extras, &out.comments), (&a.extras, &a.comments));
    assert_eq!(
        out.gaussians,
        interpolate(&a.gaussians, &b.gaussians, 0.25).unwrap()
    );
    let short = PlyGaussians::new(random_set(2, 3, 3));
    assert!(interpolate_ply(&a, &short, 0.5).is_err());
}
