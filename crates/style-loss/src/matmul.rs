//! Matrix products checked against the operand layouts candle's CUDA backend accepts, on every
//! device.
//!
//! candle's CPU product takes operands of any strides, its CUDA product (cuBLAS) only those
//! whose two last dimensions are dense or a plain transpose of dense, with regular batch strides
//! (candle 0.11's `gemm_config`). A product that only the CPU accepts passes every CPU test and
//! fails on the first GPU step, so every product of the style loss and of the D-MiSo network goes
//! through [`checked_matmul`], which refuses such layouts on the CPU too; its gradient is made of
//! checked products of contiguous upstream gradients.

use candle_core::backend::BackendStorage;
use candle_core::{CpuStorage, CudaStorage, CustomOp2, Layout, MetalStorage, Shape, Tensor};

use crate::bf16_product::bf16_matmul;
use crate::cpu_elements::generic_path;

/// `(batch, m, n, k)` of `lhs · rhs` (`[.., m, k]` times `[.., k, n]`, the same batch dims).
fn product_dims(lhs: &Shape, rhs: &Shape) -> candle_core::Result<(usize, usize, usize, usize)> {
    let (a, b) = (lhs.dims(), rhs.dims());
    let rank = a.len();
    if rank < 2 || b.len() != rank || a[..rank - 2] != b[..rank - 2] || a[rank - 1] != b[rank - 2] {
        candle_core::bail!("matmul: shapes {lhs:?} and {rhs:?} do not multiply")
    }
    let batch = a[..rank - 2].iter().product();
    Ok((batch, a[rank - 2], b[rank - 1], a[rank - 1]))
}

/// Whether one operand `[.., rows, cols]` is dense (`N`) or a transposed dense matrix (`T`) in
/// its two last dimensions, as cuBLAS reads it (a dimension of size 1 may have any stride).
fn minor_strides_ok(layout: &Layout, rows: usize, cols: usize) -> bool {
    let s = layout.stride();
    let (m2, m1) = (s[s.len() - 2], s[s.len() - 1]);
    let dense = (m1 == 1 || cols == 1) && (m2 == cols || rows == 1);
    let transposed = (m1 == rows || cols == 1) && (m2 == 1 || rows == 1);
    dense || transposed
}

/// Whether the batch dimensions of an operand step regularly (one stride for the flattened
/// batch), as candle's CUDA product needs.
fn batch_strides_ok(layout: &Layout) -> bool {
    let (dims, s) = (layout.dims(), layout.stride());
    match (&dims[..dims.len() - 2], &s[..s.len() - 2]) {
        ([], []) | ([_], [_]) => true,
        ([d0, d1], [s0, s1]) => *s0 == s1 * d1 || *d0 == 1 || *d1 == 1,
        _ => false,
    }
}

/// Why candle's CUDA backend would refuse `lhs · rhs` with these layouts (`[.., m, k]` and
/// `[.., k, n]`), or `None` when it takes them.
pub fn cuda_layout_problem(lhs: &Layout, rhs: &Layout) -> Option<String> {
    let (_, m, n, k) = product_dims(lhs.shape(), rhs.shape()).ok()?;
    let problem = if !minor_strides_ok(lhs, m, k) {
        "the left operand is neither dense nor a transposed dense matrix"
    } else if !minor_strides_ok(rhs, k, n) {
        "the right operand is neither dense nor a transposed dense matrix"
    } else if !batch_strides_ok(lhs) || !batch_strides_ok(rhs) {
        "the batch dimensions do not step regularly"
    } else {
        return None;
    };
    Some(format!(
        "{problem} (left {:?} strides {:?}, right {:?} strides {:?}); make it contiguous",
        lhs.dims(),
        lhs.stride(),
        rhs.dims(),
        rhs.stride()
    ))
}

/// `lhs · rhs` (`[.., m, k]` times `[.., k, n]`), refused on every device when candle's CUDA
/// backend would refuse the layouts ([`cuda_layout_problem`]). Differentiable in both operands
/// (where they track a gradient), through checked products of the contiguous upstream gradient.
pub fn checked_matmul(lhs: &Tensor, rhs: &Tensor) -> candle_core::Result<Tensor> {
    lhs.apply_op2(rhs, CheckedMatmul)
}

/// The product as a candle op: checks the layouts, then runs the backend's own product.
struct CheckedMatmul;

impl CheckedMatmul {
    /// Checks the layouts, then runs `product` on the `(batch, m, n, k)` of the operands;
    /// returns its result with the output's shape.
    fn checked<S>(
        l1: &Layout,
        l2: &Layout,
        product: impl FnOnce((usize, usize, usize, usize)) -> candle_core::Result<S>,
    ) -> candle_core::Result<(S, Shape)> {
        if let Some(problem) = cuda_layout_problem(l1, l2) {
            candle_core::bail!("matmul: {problem}")
        }
        let (batch, m, n, k) = product_dims(l1.shape(), l2.shape())?;
        let dims = l1.dims();
        let shape = Shape::from(&dims[..dims.len() - 2]).extend(&[m, n]);
        Ok((product((batch, m, n, k))?, shape))
    }

    /// The backend's own product, checked.
    fn run<S: BackendStorage>(
        s1: &S,
        l1: &Layout,
        s2: &S,
        l2: &Layout,
    ) -> candle_core::Result<(S, Shape)> {
        Self::checked(l1, l2, |dims| s1.matmul(s2, dims, l1, l2))
    }
}

impl CustomOp2 for CheckedMatmul {
    fn name(&self) -> &'static str {
        "checked-matmul"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        match (s1, s2, generic_path()) {
            (CpuStorage::BF16(a), CpuStorage::BF16(b), false) => Self::checked(l1, l2, |dims| {
                Ok(CpuStorage::BF16(bf16_matmul(a, l1, b, l2, dims)))
            }),
            _ => Self::run(s1, l1, s2, l2),
        }
    }

    fn cuda_fwd(
        &self,
        s1: &CudaStorage,
        l1: &Layout,
        s2: &CudaStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CudaStorage, Shape)> {
        Self::run(s1, l1, s2, l2)
    }

    fn metal_fwd(
        &self,
        s1: &MetalStorage,
        l1: &Layout,
        s2: &MetalStorage,
        l2: &Layout,
    ) -> candle_core::Result<(MetalStorage, Shape)> {
        Self::run(s1, l1, s2, l2)
    }

    fn bwd(
        &self,
        lhs: &Tensor,
        rhs: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>)> {
        let grad = grad.contiguous()?;
        let lhs_grad = checked_matmul(&grad, &rhs.t()?)?;
        let rhs_grad = checked_matmul(&lhs.t()?, &grad)?;
        Ok((Some(lhs_grad), Some(rhs_grad)))
    }
}

#[cfg(test)]
mod tests {
    use candle_core::{Device, Tensor, Var};

    use super::*;

    fn matrix(rows: usize, cols: usize, seed: usize) -> Tensor {
        let v: Vec<f32> = (0..rows * cols)
            .map(|i| ((i * 7919 + seed * 31) % 97) as f32 / 97.0 - 0.5)
            .collect();
        Tensor::from_vec(v, (rows, cols), &Device::Cpu).unwrap()
    }

    #[test]
    fn cuda_layout_dense_and_transposed_operands_pass_sliced_ones_do_not() {
        let a = matrix(5, 13, 1);
        let b = matrix(4, 3, 2);
        // A column slice of a [5, 13] matrix: rows 13 apart, 4 wide. cuBLAS cannot read it.
        let slice = a.narrow(1, 2, 4).unwrap();
        let e = checked_matmul(&slice, &b).unwrap_err().to_string();
        assert!(
            e.contains("left operand") && e.contains("contiguous"),
            "{e}"
        );
        let e = checked_matmul(&b.t().unwrap(), &slice.t().unwrap())
            .unwrap_err()
            .to_string();
        assert!(e.contains("right operand"), "{e}");
        // Dense, transposed, and the sliced one made contiguous: the CPU product's values.
        let dense = slice.contiguous().unwrap();
        let ours = checked_matmul(&dense, &b).unwrap();
        let want = slice.matmul(&b).unwrap();
        assert_eq!(
            ours.to_vec2::<f32>().unwrap(),
            want.to_vec2::<f32>().unwrap()
        );
        let t = checked_matmul(&b.t().unwrap(), &dense.t().unwrap()).unwrap();
        assert_eq!(
            t.to_vec2::<f32>().unwrap(),
            want.t().unwrap().to_vec2::<f32>().unwrap()
        );
    }

    #[test]
    fn cuda_layout_gradients_are_those_of_candles_product() {
        let (a, b) = (matrix(6, 4, 3), matrix(4, 5, 4));
        let (va, vb) = (Var::from_tensor(&a).unwrap(), Var::from_tensor(&b).unwrap());
        let probe = matrix(5, 6, 5).t().unwrap();
        let ours = (checked_matmul(va.as_tensor(), vb.as_tensor()).unwrap() * &probe)
            .unwrap()
            .sum_all()
            .unwrap()
            .backward()
            .unwrap();
        let (ca, cb) = (Var::from_tensor(&a).unwrap(), Var::from_tensor(&b).unwrap());
        let theirs = (ca.as_tensor().matmul(cb.as_tensor()).unwrap() * &probe)
            .unwrap()
            .sum_all()
            .unwrap()
            .backward()
            .unwrap();
        for (mine, candle) in [(&va, &ca), (&vb, &cb)] {
            let g = ours
                .get(mine.as_tensor())
                .unwrap()
                .to_vec2::<f32>()
                .unwrap();
            let want = theirs
                .get(candle.as_tensor())
                .unwrap()
                .to_vec2::<f32>()
                .unwrap();
            for (x, y) in g.iter().flatten().zip(want.iter().flatten()) {
                assert!((x - y).abs() < 1e-6, "{x} vs {y}");
            }
        }
    }
}
