//! D-MiSo's deformation network (D-NeRF's `DeformNetwork` for synthetic scenes), run in candle
//! on its device with an explicit backward.
//!
//! Input per core: the triangle encoding (63 values, [`crate::encoding::triangle_encoding`],
//! of the canonical vertices, detached) and the time embedding `timenet(PE(t))` with
//! `timenet = Linear(13, W) - ReLU - Linear(W, 30)`; `x0 = [h1, t_emb]` (93 values). The trunk
//! is 8 `Linear` layers of width `W`, each followed by a ReLU; after layer 4 the input is
//! concatenated again (`[x0, h]`, so layer 5 takes `93 + W`). Four heads without activation:
//! `dv1 (3), dv2 (3), dv3 (3), rot (4)`, concatenated as the 13 outputs of a core.
//!
//! The weights are one flat `f32` parameter group in the order of the PyTorch `state_dict`
//! ([`NetShape::tensors`]), copied to the device in one transfer when they changed since the
//! last call ([`ResidentWeights`]: once per optimizer step, not once per view); the gradients
//! come back in one. The backward follows PyTorch's
//! ReLU convention: no gradient where the pre-activation is exactly 0.

use candle_core::{DType, Device, Tensor};
use style_loss::matmul::checked_matmul;
use style_loss::transfers::{record_read, record_upload};

use crate::encoding::{TIME_ENCODING, VERTEX_ENCODING};

/// Trunk depth of D-NeRF's network.
pub const DEPTH: usize = 8;

/// The trunk layer after which the input is concatenated again (`D / 2`).
pub const SKIP: usize = DEPTH / 2;

/// Width of the time embedding.
pub const TIME_EMBEDDING: usize = 30;

/// Outputs per core: `dv1, dv2, dv3, rot`.
pub const OUTPUTS: usize = 13;

/// Width of the network input `[h1, t_emb]`.
pub const INPUT: usize = VERTEX_ENCODING + TIME_EMBEDDING;

/// Names of the output heads in the `state_dict`, in output order, with their widths.
pub const HEADS: [(&str, usize); 4] = [
    ("gaussian_warp", 3),
    ("gaussian_v2", 3),
    ("gaussian_v3", 3),
    ("gaussian_rot", 4),
];

/// The network's size: its width `W` (D-MiSo's `deform_width`, 256 by default).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NetShape {
    /// Width of the trunk and of the time network's hidden layer.
    pub width: usize,
}

impl NetShape {
    /// D-MiSo's default width, 256.
    pub const DEFAULT: Self = Self { width: 256 };

    /// Every tensor of the network in `state_dict` order: name and shape (`[out, in]` for
    /// weights, `[out]` for biases).
    pub fn tensors(&self) -> Vec<(String, Vec<usize>)> {
        let w = self.width;
        let mut out = Vec::new();
        let mut linear = |name: String, inputs: usize, outputs: usize| {
            out.push((format!("{name}.weight"), vec![outputs, inputs]));
            out.push((format!("{name}.bias"), vec![outputs]));
        };
        linear("timenet.0".into(), TIME_ENCODING, w);
        linear("timenet.2".into(), w, TIME_EMBEDDING);
        for i in 0..DEPTH {
            let inputs = match i {
                0 => INPUT,
                i if i == SKIP + 1 => w + INPUT,
                _ => w,
            };
            linear(format!("linear.{i}"), inputs, w);
        }
        for (name, n) in HEADS {
            linear(name.to_string(), w, n);
        }
        out
    }

    /// Values in the flat parameter group.
    pub fn len(&self) -> usize {
        self.tensors()
            .iter()
            .map(|(_, s)| s.iter().product::<usize>())
            .sum()
    }

    /// Always false: a network has weights.
    pub fn is_empty(&self) -> bool {
        false
    }
}

/// The network's weights on a device, one tensor per `state_dict` entry.
#[derive(Clone, Debug)]
struct Weights {
    tensors: Vec<Tensor>,
}

impl Weights {
    /// The weights of `flat` on `device`, uploaded in one transfer and viewed per tensor.
    fn load(shape: &NetShape, flat: &[f32], device: &Device) -> candle_core::Result<Self> {
        let all = Tensor::from_slice(flat, flat.len(), device)?;
        record_upload(std::mem::size_of_val(flat));
        let mut offset = 0;
        let mut tensors = Vec::new();
        for (_, dims) in shape.tensors() {
            let n: usize = dims.iter().product();
            tensors.push(all.narrow(0, offset, n)?.reshape(dims.as_slice())?);
            offset += n;
        }
        Ok(Self { tensors })
    }

    /// Weight and bias of linear layer `index` in [`NetShape::tensors`] order (timenet.0 is 0,
    /// timenet.2 is 1, linear.i is 2 + i, the heads follow).
    fn layer(&self, index: usize) -> (&Tensor, &Tensor) {
        (&self.tensors[2 * index], &self.tensors[2 * index + 1])
    }
}

/// The network's weights kept on its device between calls: uploaded again only when the host
/// values differ (bit for bit) from the ones uploaded last, or the device changed. The views
/// of one optimizer step share one upload, and a frozen network is uploaded once.
#[derive(Debug, Default)]
pub struct ResidentWeights {
    /// The host values last uploaded, their device and their tensors there.
    last: std::sync::Mutex<Option<(Vec<f32>, Device, Weights)>>,
}

impl Clone for ResidentWeights {
    /// A clone starts empty: its first call uploads.
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl ResidentWeights {
    /// The weights `flat` on `device`: the resident tensors when they hold these values, else
    /// a fresh upload that becomes resident.
    fn get(&self, shape: &NetShape, flat: &[f32], device: &Device) -> candle_core::Result<Weights> {
        let mut last = self
            .last
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        if let Some((values, on, weights)) = last.as_ref() {
            let same = values.len() == flat.len()
                && values
                    .iter()
                    .zip(flat)
                    .all(|(a, b)| a.to_bits() == b.to_bits());
            if same && on.same_device(device) {
                return Ok(weights.clone());
            }
        }
        let weights = Weights::load(shape, flat, device)?;
        *last = Some((flat.to_vec(), device.clone(), weights.clone()));
        Ok(weights)
    }
}

/// Index of trunk layer `i` among the linear layers.
const fn trunk(i: usize) -> usize {
    2 + i
}

/// Index of head `k` among the linear layers.
const fn head(k: usize) -> usize {
    2 + DEPTH + k
}

/// What the backward needs of one forward: the inputs of every layer and the
/// pre-activations of the ReLUs.
pub struct NetTape {
    weights: Weights,
    time: Tensor,
    time_hidden: Tensor,
    x0: Tensor,
    trunk_inputs: Vec<Tensor>,
    trunk_pre: Vec<Tensor>,
    last: Tensor,
}

/// `x W^T + b`.
fn linear(x: &Tensor, w: &Tensor, b: &Tensor) -> candle_core::Result<Tensor> {
    checked_matmul(x, &w.t()?)?.broadcast_add(b)
}

/// The network's outputs `[G, 13]` for `encodings` (`[G, 63]`, row-major) at the time
/// encoding `time` (13 values), and the tape of the call. The weights `weights` go to the
/// device through `resident`.
pub fn forward(
    shape: &NetShape,
    weights: &[f32],
    resident: &ResidentWeights,
    encodings: &[f32],
    time: &[f32; TIME_ENCODING],
    device: &Device,
) -> candle_core::Result<(Vec<f32>, NetTape)> {
    let cores = encodings.len() / VERTEX_ENCODING;
    let weights = resident.get(shape, weights, device)?;
    let h1 = Tensor::from_slice(encodings, (cores, VERTEX_ENCODING), device)?;
    let time = Tensor::from_slice(time.as_slice(), (1, TIME_ENCODING), device)?;
    record_upload(std::mem::size_of_val(encodings));
    record_upload(4 * TIME_ENCODING);
    let (w, b) = weights.layer(0);
    let time_hidden = linear(&time, w, b)?;
    let (w, b) = weights.layer(1);
    let t_emb = linear(&time_hidden.relu()?, w, b)?;
    let x0 = Tensor::cat(&[&h1, &t_emb.broadcast_as((cores, TIME_EMBEDDING))?], 1)?;
    let mut h = x0.clone();
    let mut trunk_inputs = Vec::with_capacity(DEPTH);
    let mut trunk_pre = Vec::with_capacity(DEPTH);
    for i in 0..DEPTH {
        let (w, b) = weights.layer(trunk(i));
        let z = linear(&h, w, b)?;
        trunk_inputs.push(h);
        h = z.relu()?;
        trunk_pre.push(z);
        if i == SKIP {
            h = Tensor::cat(&[&x0, &h], 1)?;
        }
    }
    let heads = (0..HEADS.len())
        .map(|k| {
            let (w, b) = weights.layer(head(k));
            linear(&h, w, b)
        })
        .collect::<candle_core::Result<Vec<_>>>()?;
    let out = Tensor::cat(&heads, 1)?;
    let values = out.flatten_all()?.to_vec1::<f32>()?;
    record_read(std::mem::size_of_val(values.as_slice()));
    Ok((
        values,
        NetTape {
            weights,
            time,
            time_hidden,
            x0,
            trunk_inputs,
            trunk_pre,
            last: h,
        },
    ))
}

/// `g` where `z > 0`, else 0 (PyTorch's `threshold_backward`: no gradient at 0).
fn relu_backward(g: &Tensor, z: &Tensor) -> candle_core::Result<Tensor> {
    g.mul(&z.gt(0.0)?.to_dtype(DType::F32)?)
}

/// The gradient of every weight (flat, [`NetShape::tensors`] order), given the gradient
/// `grad_out` (`[G, 13]`) of a loss with respect to the outputs of the forward of `tape`.
pub fn backward(tape: NetTape, grad_out: &[f32]) -> candle_core::Result<Vec<f32>> {
    let device = tape.x0.device().clone();
    let cores = tape.x0.dim(0)?;
    let g_out = Tensor::from_slice(grad_out, (cores, OUTPUTS), &device)?;
    record_upload(std::mem::size_of_val(grad_out));
    let layers = 2 + DEPTH + HEADS.len();
    let mut grads: Vec<Option<(Tensor, Tensor)>> = (0..layers).map(|_| None).collect();
    // The heads.
    let mut g_h: Option<Tensor> = None;
    let mut start = 0;
    for (k, (_, n)) in HEADS.iter().enumerate() {
        // A column slice of the `[G, 13]` gradient: made dense, as cuBLAS reads no other.
        let g = g_out.narrow(1, start, *n)?.contiguous()?;
        start += n;
        let (w, _) = tape.weights.layer(head(k));
        grads[head(k)] = Some((checked_matmul(&g.t()?, &tape.last)?, g.sum(0)?));
        let g_in = checked_matmul(&g, w)?;
        g_h = Some(match g_h {
            Some(s) => s.add(&g_in)?,
            None => g_in,
        });
    }
    let mut g_h = g_h.expect("four heads");
    let mut g_x0: Option<Tensor> = None;
    for i in (0..DEPTH).rev() {
        if i == SKIP {
            g_x0 = Some(g_h.narrow(1, 0, INPUT)?);
            let width = g_h.dim(1)? - INPUT;
            g_h = g_h.narrow(1, INPUT, width)?;
        }
        let g_z = relu_backward(&g_h, &tape.trunk_pre[i])?;
        let (w, _) = tape.weights.layer(trunk(i));
        grads[trunk(i)] = Some((
            checked_matmul(&g_z.t()?, &tape.trunk_inputs[i])?,
            g_z.sum(0)?,
        ));
        g_h = checked_matmul(&g_z, w)?;
    }
    let g_x0 = g_h.add(&g_x0.expect("the skip layer"))?;
    // The time embedding is broadcast to every core: its gradient is the sum over cores.
    let g_t_emb = g_x0
        .narrow(1, VERTEX_ENCODING, TIME_EMBEDDING)?
        .sum_keepdim(0)?;
    let hidden = tape.time_hidden.relu()?;
    let (w, _) = tape.weights.layer(1);
    grads[1] = Some((checked_matmul(&g_t_emb.t()?, &hidden)?, g_t_emb.sum(0)?));
    let g_hidden = relu_backward(&checked_matmul(&g_t_emb, w)?, &tape.time_hidden)?;
    grads[0] = Some((
        checked_matmul(&g_hidden.t()?, &tape.time)?,
        g_hidden.sum(0)?,
    ));
    // Every gradient in `state_dict` order, read back in one transfer.
    let mut parts = Vec::with_capacity(2 * layers);
    for g in grads {
        let (gw, gb) = g.expect("every layer has a gradient");
        parts.push(gw.flatten_all()?);
        parts.push(gb.flatten_all()?);
    }
    let flat = Tensor::cat(&parts, 0)?.to_vec1::<f32>()?;
    record_read(std::mem::size_of_val(flat.as_slice()));
    Ok(flat)
}

/// A network of `shape` as PyTorch initialises it, encodings of `cores` cores and a gradient of
/// their outputs, all uniform in `[-1, 1)` from `seed`: `(weights, encodings, output gradient)`.
fn seeded_inputs(shape: &NetShape, cores: usize, seed: u64) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let weights = crate::init::default_network(shape, &mut rng);
    let mut uniform =
        |n: usize| -> Vec<f32> { (0..n).map(|_| rng.random_range(-1.0..1.0)).collect() };
    let encodings = uniform(cores * VERTEX_ENCODING);
    let probe = uniform(cores * OUTPUTS);
    (weights, encodings, probe)
}

/// The `selftest` part of the network: forward and backward of a seeded network of width 32 on
/// seven cores, on `device` against the cpu (the largest output or gradient difference,
/// relative to the cpu's largest value).
pub fn self_check(device: &Device) -> Result<gs_stylize::selftest::Check, String> {
    let shape = NetShape { width: 32 };
    let (weights, enc, probe) = seeded_inputs(&shape, 7, 9);
    let time = [0.4f32; TIME_ENCODING];
    let run = |device: &Device| -> candle_core::Result<Vec<f32>> {
        let (mut out, tape) = forward(
            &shape,
            &weights,
            &ResidentWeights::default(),
            &enc,
            &time,
            device,
        )?;
        out.extend(backward(tape, &probe)?);
        Ok(out)
    };
    let start = std::time::Instant::now();
    let ours = run(device).map_err(|e| format!("the deformation network: {e}"))?;
    let seconds = start.elapsed().as_secs_f64();
    let cpu = run(&Device::Cpu).map_err(|e| format!("the deformation network: {e}"))?;
    Ok(gs_stylize::selftest::Check {
        part: "deformation network and its backward".into(),
        device: format!("{} vs cpu", style_loss::compute_device::describe(device)),
        error: gs_stylize::selftest::relative_max_error(&ours, &cpu),
        tolerance: 1e-4,
        seconds,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Forward and backward run every product through `checked_matmul`, which refuses the
    /// layouts candle's CUDA backend refuses (the heads' gradients are column slices of the
    /// `[G, 13]` gradient: made dense, else this fails as a CUDA step would). The values are the
    /// authors' (`tests/authors_fixture.rs` compares both passes with PyTorch).
    #[test]
    fn cuda_layout_network_forward_and_backward() {
        let shape = NetShape { width: 16 };
        let cores = 7;
        let (weights, enc, probe) = seeded_inputs(&shape, cores, 5);
        let time = [0.3f32; TIME_ENCODING];
        let before = style_loss::transfers::snapshot();
        let (out, tape) = forward(
            &shape,
            &weights,
            &ResidentWeights::default(),
            &enc,
            &time,
            &Device::Cpu,
        )
        .unwrap();
        assert_eq!(out.len(), cores * OUTPUTS);
        let grad = backward(tape, &probe).unwrap();
        // Weights, encodings, time and the output gradient up; outputs and gradients back.
        let moved = style_loss::transfers::snapshot() - before;
        assert_eq!((moved.uploads, moved.reads), (4, 2));
        assert_eq!(
            moved.read_bytes,
            4 * (cores * OUTPUTS + weights.len()) as u64
        );
        assert_eq!(grad.len(), weights.len());
        assert!(grad.iter().all(|g| g.is_finite()));
        // Every head's weights get a gradient (its slice of the upstream gradient reached it).
        let mut offset = 0;
        for (name, dims) in shape.tensors() {
            let n: usize = dims.iter().product();
            if name.starts_with("gaussian_") {
                assert!(grad[offset..offset + n].iter().any(|&g| g != 0.0), "{name}");
            }
            offset += n;
        }
    }

    /// The weights stay on the device between calls: a second forward at the same values
    /// uploads only its encodings and time, a changed value (one bit of one weight) uploads the
    /// weights again, and the outputs follow the values.
    #[test]
    fn weights_stay_resident_until_they_change() {
        let shape = NetShape { width: 8 };
        let (mut weights, enc, _) = seeded_inputs(&shape, 3, 9);
        let time = [0.1f32; TIME_ENCODING];
        let resident = ResidentWeights::default();
        let run = |weights: &[f32]| {
            let before = style_loss::transfers::snapshot();
            let (out, _) = forward(&shape, weights, &resident, &enc, &time, &Device::Cpu).unwrap();
            (out, style_loss::transfers::snapshot() - before)
        };
        let weight_bytes = 4 * weights.len() as u64;
        let (first, moved) = run(&weights);
        assert_eq!(moved.uploads, 3);
        let inputs = moved.uploaded_bytes - weight_bytes;
        let (again, moved) = run(&weights);
        assert_eq!((moved.uploads, moved.uploaded_bytes), (2, inputs));
        assert_eq!(first, again);
        // The last bias of the rotation head: one output column moves.
        let last = weights.len() - 1;
        weights[last] = f32::from_bits(weights[last].to_bits() + 1);
        let (changed, moved) = run(&weights);
        assert_eq!(
            (moved.uploads, moved.uploaded_bytes),
            (3, inputs + weight_bytes)
        );
        assert_ne!(first, changed);
        assert_eq!(run(&weights).1.uploads, 2);
    }
}
