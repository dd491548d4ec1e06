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
