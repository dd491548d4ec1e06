//! bf16 matrix products on the CPU through gemmkit, whose AVX-512 BF16 kernel (`vdpbf16ps`)
//! multiplies pairs of bf16 values and accumulates in f32, at up to twice the rate of an f32
//! product (1.2x on 64-wide products, 1.8-2x on CLIP's and VGG's wide ones);
//! without those instructions gemmkit widens to f32 itself. Each output is rounded once to bf16,
//! as a bf16 product on the GPU is.

use std::sync::Arc;

use candle_core::{CpuStorage, CustomOp2, Layout, Shape, Tensor};
use gemmkit::{gemm_batched, MatMut, MatRef, Parallelism};
use half::bf16;
use rayon::prelude::*;

use crate::cpu_elements::elements;

/// `v` rounded to the nearest bf16, ties to even, NaN kept quiet: `half`'s `bf16::from_f32`
/// without branches, so that loops over slices vectorize.
#[inline]
pub(crate) fn round_to_bf16(v: f32) -> bf16 {
    let x = v.to_bits();
    let rounded = x.wrapping_add(0x7FFF + ((x >> 16) & 1)) >> 16;
    let quiet_nan = (x >> 16) | 0x40;
    bf16::from_bits(if v.is_nan() { quiet_nan } else { rounded } as u16)
}

/// `x · w + bias` of a linear layer on the CPU, with `x` f32 `[rows, in]` (contiguous), `w` bf16
/// `[in, out]` and `bias` f32 `[out]`: bit for bit what `x.to_dtype(bf16)`, the bf16 product,
/// `to_dtype(f32)` and `broadcast_add(bias)` give, in one pass over `x` and one over the output.
/// No gradient (the linear layer attaches its own).
pub(crate) fn bf16_linear_cpu(
    x: &Tensor,
    w: &Tensor,
    bias: Option<&Tensor>,
) -> candle_core::Result<Tensor> {
    let bias = bias.map(|b| b.to_vec1::<f32>()).transpose()?.map(Arc::from);
    x.apply_op2_no_bwd(w, &Bf16Linear { bias })
}

/// The candle op of [`bf16_linear_cpu`] (CPU only).
struct Bf16Linear {
    bias: Option<Arc<[f32]>>,
}

impl CustomOp2 for Bf16Linear {
    fn name(&self) -> &'static str {
        "bf16-linear"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let x = elements(s1, l1)?;
        let CpuStorage::BF16(w) = s2 else {
            candle_core::bail!("bf16 linear: the weights are not bf16")
        };
        let (rows, inner) = l1.shape().dims2()?;
        let (w_inner, out) = l2.shape().dims2()?;
        if w_inner != inner || self.bias.as_ref().is_some_and(|b| b.len() != out) {
            candle_core::bail!("bf16 linear: input {l1:?}, weights {l2:?}, bias of {out} expected")
        }
        let rounded: Vec<bf16> = x.par_iter().map(|&v| round_to_bf16(v)).collect();
        let product = bf16_matmul(
            &rounded,
            &Layout::contiguous((rows, inner)),
            w,
            l2,
            (1, rows, out, inner),
        );
        let mut y = vec![0f32; rows * out];
        y.par_chunks_mut(out.max(1))
            .zip(product.par_chunks(out.max(1)))
            .for_each(|(y, p)| match &self.bias {
                Some(bias) => {
                    for ((y, p), b) in y.iter_mut().zip(p).zip(bias.iter()) {
                        *y = p.to_f32() + b;
                    }
                }
                None => {
                    for (y, p) in y.iter_mut().zip(p) {
                        *y = p.to_f32();
                    }
                }
            });
        Ok((CpuStorage::F32(y), Shape::from((rows, out))))
    }
}

/// The one stride that steps from one matrix of the flattened batch to the next (0 when the
/// batch holds one matrix or broadcasts one), for layouts that `batch_strides_ok` accepts.
fn flat_batch_stride(layout: &Layout) -> isize {
    let (dims, s) = (layout.dims(), layout.stride());
    let batch = &dims[..dims.len() - 2];
    let strides = &s[..s.len() - 2];
    match (batch, strides) {
        ([d0, d1], [s0, s1]) if *d1 == 1 => {
            if *d0 == 1 {
                0
            } else {
                *s0 as isize
            }
        }
        ([_, _], [_, s1]) => *s1 as isize,
        ([d0], [s0]) if *d0 > 1 => *s0 as isize,
        _ => 0,
    }
}

/// The two last strides of an operand (rows, columns), as gemmkit reads them.
fn matrix_strides(layout: &Layout) -> (isize, isize) {
    let s = layout.stride();
    (s[s.len() - 2] as isize, s[s.len() - 1] as isize)
}

/// `lhs · rhs` for `(batch, m, n, k)` products of bf16 operands of any layout that candle's CUDA
/// backend accepts (`[.., m, k]` times `[.., k, n]`), returned dense `[batch, m, n]`.
pub(crate) fn bf16_matmul(
    lhs: &[bf16],
    lhs_layout: &Layout,
    rhs: &[bf16],
    rhs_layout: &Layout,
    (batch, m, n, k): (usize, usize, usize, usize),
) -> Vec<bf16> {
    let mut out = vec![bf16::ZERO; batch * m * n];
    if out.is_empty() {
        return out;
    }
    let (lr, lc) = matrix_strides(lhs_layout);
    let (rr, rc) = matrix_strides(rhs_layout);
    gemm_batched(
        batch,
        bf16::ONE,
        MatRef::new(&lhs[lhs_layout.start_offset()..], m, k, lr, lc),
        flat_batch_stride(lhs_layout),
        MatRef::new(&rhs[rhs_layout.start_offset()..], k, n, rr, rc),
        flat_batch_stride(rhs_layout),
        bf16::ZERO,
        MatMut::from_row_major(&mut out, m, n),
        (m * n) as isize,
        Parallelism::Rayon(0),
    );
    out
}

#[cfg(test)]
mod tests {
    use candle_core::{DType, Device, Tensor, Var};

    use crate::matmul::checked_matmul;
    use crate::nn::Linear;

    /// `[.., rows, cols]` values in [-1, 1) from a seed, f32.
    fn values(dims: &[usize], seed: u64) -> Tensor {
        let n: usize = dims.iter().product();
        let v: Vec<f32> = (0..n as u64)
            .map(|i| {
                let x = (i + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ seed.wrapping_mul(0xD1B5);
                ((x >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
            })
            .collect();
        Tensor::from_vec(v, dims, &Device::Cpu).unwrap()
    }

    /// Checks `ours` (`[batch, m, n]`) against the f64 product of the bf16 operands `a`
    /// (`[batch, m, k]`) and `b` (`[batch, k, n]`): within one bf16 rounding of the output plus
    /// the f32 accumulation's bound.
    fn assert_is_rounded_product(ours: &Tensor, a: &Tensor, b: &Tensor) {
        let widen = |t: &Tensor| -> Vec<Vec<Vec<f64>>> {
            t.to_dtype(DType::F64).unwrap().to_vec3::<f64>().unwrap()
        };
        let (a, b, ours) = (widen(a), widen(b), widen(ours));
        for ((a, b), ours) in a.iter().zip(&b).zip(&ours) {
            let k = b.len();
            for (i, row) in ours.iter().enumerate() {
                for (j, &got) in row.iter().enumerate() {
                    let exact: f64 = (0..k).map(|p| a[i][p] * b[p][j]).sum();
                    let magnitude: f64 = (0..k).map(|p| (a[i][p] * b[p][j]).abs()).sum();
                    let bound =
                        exact.abs() / 256.0 + (k + 2) as f64 * magnitude / (1u64 << 23) as f64;
                    assert!(
                        (got - exact).abs() <= bound,
                        "[{i}, {j}] of k {k}: {got} against {exact} (bound {bound})"
                    );
                }
            }
        }
    }

    #[test]
    fn rounding_to_bf16_is_halfs_on_ties_infinities_nans_and_subnormals() {
        let mut cases: Vec<f32> = vec![
            0.0,
            -0.0,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            -f32::NAN,
            f32::from_bits(0x7F80_0001), // a signalling NaN
            f32::MAX,
            f32::MIN,
            f32::MIN_POSITIVE,
            f32::from_bits(1),           // the smallest subnormal
            f32::from_bits(0x3F80_8000), // 1 + half a bf16 step: a tie, to even (1)
            f32::from_bits(0x3F81_8000), // a tie to even upwards
            f32::from_bits(0x7F7F_8000), // rounds up to infinity
        ];
        cases.extend((0..100_000u32).map(|i| f32::from_bits(i.wrapping_mul(0x9E37_79B9))));
        for v in cases {
            let (ours, theirs) = (super::round_to_bf16(v), half::bf16::from_f32(v));
            assert_eq!(
                ours.to_bits(),
                theirs.to_bits(),
                "{v:e} ({:#010x})",
                v.to_bits()
            );
        }
    }

    #[test]
    fn bf16_products_are_the_exact_product_of_the_operands_rounded_once() {
        for (m, k, n) in [
            (1, 1, 1),
            (7, 33, 17),
            (50, 64, 50),
            (3, 768, 5),
            (40, 9, 130),
        ] {
            let a = values(&[1, m, k], 1).to_dtype(DType::BF16).unwrap();
            let b = values(&[1, k, n], 2).to_dtype(DType::BF16).unwrap();
            let ours = checked_matmul(&a, &b).unwrap();
            assert_eq!(ours.dtype(), DType::BF16);
            assert_is_rounded_product(&ours, &a, &b);
            // The generic path (candle's own product, which widens to f32) rounds alike.
            let _generic = crate::GenericPath::on();
            assert_is_rounded_product(&checked_matmul(&a, &b).unwrap(), &a, &b);
        }
    }

    #[test]
    fn the_fused_cpu_linear_is_the_composed_one_bit_for_bit() {
        let (rows, inputs, outputs) = (17, 70, 24);
        // Values with ties at bf16's rounding (1 + half a step) among them.
        let mut x = values(&[rows, inputs], 21)
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap();
        for v in x.iter_mut().step_by(7) {
            *v = f32::from_bits(0x3F80_8000);
        }
        let x = Tensor::from_vec(x, (rows, inputs), &Device::Cpu).unwrap();
        let w = values(&[inputs, outputs], 22)
            .to_dtype(DType::BF16)
            .unwrap();
        let bias = values(&[outputs], 23);
        let composed = checked_matmul(&x.to_dtype(DType::BF16).unwrap(), &w)
            .unwrap()
            .to_dtype(DType::F32)
            .unwrap();
        for (bias, want) in [
            (Some(&bias), composed.broadcast_add(&bias).unwrap()),
            (None, composed.clone()),
        ] {
            let fused = super::bf16_linear_cpu(&x, &w, bias).unwrap();
            assert_eq!(
                fused.to_vec2::<f32>().unwrap(),
                want.to_vec2::<f32>().unwrap(),
                "bias {}",
                bias.is_some()
            );
        }
        // A transposed weight view reads alike.
        let w_t = w.t().unwrap().contiguous().unwrap().t().unwrap();
        assert_eq!(
            super::bf16_linear_cpu(&x, &w_t, None)
                .unwrap()
                .to_vec2::<f32>()
                .unwrap(),
            composed.to_vec2::<f32>().unwrap()
        );
    }

    #[test]
    fn bf16_products_read_broadcast_narrowed_and_single_batches() {
        let (m, k, n) = (5, 12, 7);
        let flat = |t: &Tensor| {
            let d = t.dims().to_vec();
            let rows: usize = d[..d.len() - 2].iter().product();
            t.contiguous()
                .unwrap()
                .reshape((rows, d[d.len() - 2], d[d.len() - 1]))
                .unwrap()
        };
        let bf16 = |t: Tensor| t.to_dtype(DType::BF16).unwrap();
        // One right operand broadcast over a [2, 3] batch: batch strides 0.
        let a = bf16(values(&[2, 3, m, k], 11));
        let b = bf16(values(&[k, n], 12));
        let b_all = b.broadcast_as((2, 3, k, n)).unwrap();
        assert_eq!(&b_all.stride()[..2], &[0, 0]);
        let ours = checked_matmul(&a, &b_all).unwrap();
        assert_is_rounded_product(&flat(&ours), &flat(&a), &flat(&b_all));
        // A narrowed left operand: [3, 1, m, k] out of [3, 2, m, k], at a start offset, its
        // batch stepping by the outer stride.
        let whole = bf16(values(&[3, 2, m, k], 13));
        let narrowed = whole.narrow(1, 1, 1).unwrap();
        let b3 = bf16(values(&[3, 1, k, n], 14));
        let ours = checked_matmul(&narrowed, &b3).unwrap();
        assert_is_rounded_product(&flat(&ours), &flat(&narrowed), &flat(&b3));
        // A batch of one, [1, m, k].
        let a1 = bf16(values(&[1, m, k], 15));
        let b1 = bf16(values(&[1, k, n], 16));
        assert_is_rounded_product(&checked_matmul(&a1, &b1).unwrap(), &a1, &b1);
    }

    #[test]
    fn bf16_products_read_transposed_and_batched_operands() {
        // Attention's shapes: [batch, heads, tokens, head_dim] times its transpose.
        let q = values(&[2, 3, 11, 8], 3).to_dtype(DType::BF16).unwrap();
        let k = values(&[2, 3, 11, 8], 4).to_dtype(DType::BF16).unwrap();
        let logits = checked_matmul(&q, &k.t().unwrap()).unwrap();
        assert_eq!(logits.dims(), &[2, 3, 11, 11]);
        let flat = |t: &Tensor| {
            let d = t.dims();
            t.contiguous()
                .unwrap()
                .reshape((d[0] * d[1], d[2], d[3]))
                .unwrap()
        };
        assert_is_rounded_product(&flat(&logits), &flat(&q), &flat(&k.t().unwrap()));
        // A transposed left operand, one matrix.
        let a = values(&[1, 19, 6], 5).to_dtype(DType::BF16).unwrap();
        let b = values(&[1, 19, 4], 6).to_dtype(DType::BF16).unwrap();
        let at = a.transpose(1, 2).unwrap();
        assert_is_rounded_product(&checked_matmul(&at, &b).unwrap(), &at, &b);
    }

    #[test]
    fn a_bf16_linear_layer_multiplies_in_bf16_and_keeps_f32_activations() {
        let (rows, inputs, outputs) = (13, 70, 24);
        let weight = values(&[outputs, inputs], 7).to_dtype(DType::BF16).unwrap();
        let bias = values(&[outputs], 8);
        let layer = Linear::new(weight.clone(), Some(bias.clone())).unwrap();
        let x = Var::from_tensor(&values(&[rows, inputs], 9)).unwrap();
        let y = layer.forward(x.as_tensor()).unwrap();
        assert_eq!(y.dtype(), DType::F32, "the activations stay f32");
        let probe = values(&[rows, outputs], 10);
        let grad = (&y * &probe)
            .unwrap()
            .sum_all()
            .unwrap()
            .backward()
            .unwrap()
            .get(x.as_tensor())
            .unwrap()
            .clone();
        assert_eq!(grad.dtype(), DType::F32);
        let rounded = |t: &Tensor| t.to_dtype(DType::BF16).unwrap().unsqueeze(0).unwrap();
        // The value less its f32 bias is the rounded product of the rounded input (the bias's
        // two f32 roundings are far inside the bound).
        assert_is_rounded_product(
            &y.broadcast_sub(&bias).unwrap().unsqueeze(0).unwrap(),
            &rounded(x.as_tensor()),
            &weight.t().unwrap().unsqueeze(0).unwrap(),
        );
        // The input gradient: the probe rounded to bf16 times the weight, rounded once.
        assert_is_rounded_product(
            &grad.unsqueeze(0).unwrap(),
            &rounded(&probe),
            &weight.unsqueeze(0).unwrap(),
        );
    }
}
