//! Helpers of the unit tests that check a map's value and input gradient against another's.

use candle_core::{Tensor, Var};

/// `f(x)` and `d sum(f(x) * probe) / dx`.
pub(crate) fn value_and_grad(
    x: &Tensor,
    probe: &Tensor,
    f: impl Fn(&Tensor) -> Tensor,
) -> (Tensor, Tensor) {
    let var = Var::from_tensor(x).unwrap();
    let y = f(var.as_tensor());
    let grads = (&y * probe).unwrap().sum_all().unwrap().backward().unwrap();
    (y, grads.get(var.as_tensor()).unwrap().clone())
}

/// The largest `|v|` of `t` (f32).
pub(crate) fn max_abs(t: &Tensor) -> f32 {
    t.abs()
        .unwrap()
        .max_all()
        .unwrap()
        .to_scalar::<f32>()
        .unwrap()
}

/// Asserts the largest `|a - b|` is within `tol` of `b`'s largest magnitude (at least 1).
pub(crate) fn assert_close(a: &Tensor, b: &Tensor, tol: f32, what: &str) {
    assert_eq!(a.dims(), b.dims(), "{what}");
    let diff = max_abs(&(a - b).unwrap());
    let scale = max_abs(b);
    assert!(diff <= tol * scale.max(1.0), "{what}: {diff} of {scale}");
}
