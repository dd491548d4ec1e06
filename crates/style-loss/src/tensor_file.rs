//! Named tensors of a checkpoint (a safetensors file) with shape-checked, clearly reported
//! access, or random tensors of whatever shape is asked for (tests and benchmarks).

use std::collections::HashMap;
use std::path::Path;

use candle_core::{DType, Device, Tensor};

use crate::error::{Result, StyleLossError};

/// The tensors of one checkpoint by name, converted to f32 on access.
#[derive(Debug)]
pub struct NamedTensors {
    source: String,
    store: Store,
}

#[derive(Debug)]
enum Store {
    Loaded(HashMap<String, Tensor>),
    /// Every name exists and gets fresh random values of the requested shape.
    Random(Device),
}

impl NamedTensors {
    /// Reads a safetensors file onto `device`.
    pub fn load_safetensors(path: &Path, device: &Device) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|source| StyleLossError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let tensors = candle_core::safetensors::load_buffer(&bytes, device).map_err(|e| {
            StyleLossError::Parse {
                path: path.to_path_buf(),
                message: e.to_string(),
            }
        })?;
        Ok(Self {
            source: path.display().to_string(),
            store: Store::Loaded(tensors),
        })
    }

    /// Wraps tensors that were made in memory; `source` names them in error messages.
    pub fn from_map(source: impl Into<String>, tensors: HashMap<String, Tensor>) -> Self {
        Self {
            source: source.into(),
            store: Store::Loaded(tensors),
        }
    }

    /// Random weights for any model, on `device`, for shape tests, timing and self-checks:
    /// drawn on the host from a stream seeded by the tensor's name, so every device gets the
    /// same values.
    ///
    /// A tensor of two or more dimensions is uniform with variance `1 / fan_in` (fan_in = the
    /// product of all but the first dimension); a vector whose name ends in `.weight` (a norm
    /// gain) is uniform in [0.9, 1.1]; any other vector is uniform in [-0.1, 0.1].
    pub fn random(device: &Device) -> Self {
        Self {
            source: "random weights".into(),
            store: Store::Random(device.clone()),
        }
    }

    /// Where the tensors came from (a path, or the description given to [`Self::from_map`]).
    pub fn source(&self) -> &str {
        &self.source
    }

    /// The tensor `name` as f32, which must have shape `expected`.
    pub fn get(&self, name: &str, expected: &[usize]) -> Result<Tensor> {
        let tensors = match &self.store {
            Store::Loaded(tensors) => tensors,
            Store::Random(device) => return Ok(random_tensor(name, expected, device)?),
        };
        let tensor = tensors
            .get(name)
            .ok_or_else(|| StyleLossError::MissingTensor {
                source_name: self.source.clone(),
                tensor: name.to_string(),
            })?
            .to_dtype(DType::F32)?;
        if tensor.dims() != expected {
            return Err(StyleLossError::TensorShape {
                source_name: self.source.clone(),
                tensor: name.to_string(),
                found: tensor.dims().to_vec(),
                expected: expected.to_vec(),
            });
        }
        Ok(tensor)
    }
}

/// See [`NamedTensors::random`].
fn random_tensor(name: &str, shape: &[usize], device: &Device) -> candle_core::Result<Tensor> {
    use rand::{Rng, SeedableRng};
    let (lo, hi) = match shape {
        [_] if name.ends_with(".weight") => (0.9f32, 1.1f32),
        [_] | [] => (-0.1, 0.1),
        [_, rest @ ..] => {
            let fan_in = rest.iter().product::<usize>().max(1) as f32;
            let bound = (3.0 / fan_in).sqrt();
            (-bound, bound)
        }
    };
    // FNV-1a of the name: the same stream for the same tensor on every device and run.
    let seed = name.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    });
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let count = shape.iter().product::<usize>();
    let values: Vec<f32> = (0..count).map(|_| rng.random_range(lo..hi)).collect();
    Tensor::from_vec(values, shape, device)
}
