//! Named tensors of a checkpoint (a safetensors file) with shape-checked, clearly reported
//! access, or random tensors of whatever shape is asked for (tests and benchmarks).
//!
//! A safetensors file is opened by reading and checking its header only; each tensor is read
//! from the file when a model asks for it. A model reads a part of some checkpoints (VGG-19's
//! 575 MB hold 61 MB of the convolutions the content loss runs; the rest is mostly its
//! classifier), and reading the whole file first, then copying every tensor out of it, took
//! about 5 s of a run's start on a 2-core VM. Tensors of f32, f16, bf16 and f64 are taken.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use candle_core::{DType, Device, Tensor};
use safetensors::tensor::{Metadata, TensorInfo};

use crate::error::{Result, StyleLossError};

// safetensors stores little-endian values, which are read as they are (as candle's own reader
// does): a big-endian build would take every weight wrong.
#[cfg(target_endian = "big")]
compile_error!("style-loss reads safetensors weight files on little-endian hosts only");

/// The tensors of one checkpoint by name, converted to f32 on access.
#[derive(Debug)]
pub struct NamedTensors {
    source: String,
    store: Store,
}

/// Where [`NamedTensors`] takes its tensors from.
#[derive(Debug)]
enum Store {
    /// Tensors made in memory ([`NamedTensors::from_map`]).
    Loaded(HashMap<String, Tensor>),
    /// A safetensors file whose header was read and checked; tensors are read on access.
    File(SafetensorsFile),
    /// Every name exists and gets fresh random values of the requested shape.
    Random(Device),
}

/// An open safetensors file: its checked header, and where its data starts.
#[derive(Debug)]
struct SafetensorsFile {
    /// The file, for error messages.
    path: PathBuf,
    /// The file opened and checked; each read seeks to its tensor.
    file: Mutex<File>,
    /// The checked header: each tensor's format, shape and byte range in the data.
    metadata: Metadata,
    /// Byte offset of the data section (after the 8-byte length and the JSON header).
    data_start: u64,
    /// Where the tensors go.
    device: Device,
}

/// The largest JSON header taken (the safetensors crate's own limit).
const MAX_HEADER_BYTES: u64 = 100_000_000;

impl NamedTensors {
    /// Opens a safetensors file whose tensors go onto `device`: reads and checks its header
    /// (every tensor's offsets and size, and that the data fill the file exactly); the tensors
    /// themselves are read by [`Self::get`], so the file must not change while this value
    /// lives.
    pub fn load_safetensors(path: &Path, device: &Device) -> Result<Self> {
        let io = |source| StyleLossError::Io {
            path: path.to_path_buf(),
            source,
        };
        let parse = |message: String| StyleLossError::Parse {
            path: path.to_path_buf(),
            message,
        };
        let mut file = File::open(path).map_err(io)?;
        let file_len = file.metadata().map_err(io)?.len();
        let mut len_bytes = [0u8; 8];
        if file_len < 8 {
            return Err(parse(format!(
                "{file_len} bytes: a safetensors file starts with an 8-byte header length"
            )));
        }
        file.read_exact(&mut len_bytes).map_err(io)?;
        let header_len = u64::from_le_bytes(len_bytes);
        if header_len > MAX_HEADER_BYTES || header_len > file_len - 8 {
            return Err(parse(format!(
                "header length {header_len} bytes, in a file of {file_len} bytes (at most \
                 {MAX_HEADER_BYTES} taken)"
            )));
        }
        let mut header = vec![0u8; header_len as usize];
        file.read_exact(&mut header).map_err(io)?;
        // The crate's own checks; where they refuse the header, the entry at fault is named if
        // there is one (the crate's messages for a size that is not its format's name none).
        let metadata: Metadata = serde_json::from_slice(&header).map_err(|e| {
            parse(
                check_entries(&header)
                    .err()
                    .unwrap_or_else(|| format!("header: {e}")),
            )
        })?;
        let data_start = 8 + header_len;
        let data_len = metadata.data_len() as u64;
        if data_start.checked_add(data_len) != Some(file_len) {
            return Err(parse(format!(
                "the header gives {data_len} bytes of tensor data after {data_start}, the file \
                 has {file_len} bytes (truncated or padded)"
            )));
        }
        Ok(Self {
            source: path.display().to_string(),
            store: Store::File(SafetensorsFile {
                path: path.to_path_buf(),
                file: Mutex::new(file),
                metadata,
                data_start,
                device: device.clone(),
            }),
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
        let missing = || StyleLossError::MissingTensor {
            source_name: self.source.clone(),
            tensor: name.to_string(),
        };
        let wrong_shape = |found: &[usize]| StyleLossError::TensorShape {
            source_name: self.source.clone(),
            tensor: name.to_string(),
            found: found.to_vec(),
            expected: expected.to_vec(),
        };
        match &self.store {
            Store::Random(device) => Ok(random_tensor(name, expected, device)?),
            Store::Loaded(tensors) => {
                let tensor = tensors.get(name).ok_or_else(missing)?;
                if tensor.dims() != expected {
                    return Err(wrong_shape(tensor.dims()));
                }
                Ok(tensor.to_dtype(DType::F32)?)
            }
            Store::File(file) => {
                let info = file.metadata.info(name).ok_or_else(missing)?;
                if info.shape != expected {
                    return Err(wrong_shape(&info.shape));
                }
                file.read(name, info)
            }
        }
    }
}

/// Checks each tensor entry of a safetensors header on its own, so that an error names the
/// tensor: its format, shape and offsets parse, and its byte range holds exactly its values.
/// Run on a header the safetensors crate refused, to say which entry is at fault; the order of
/// the ranges (back to back from 0) is the crate's check alone, whose error names the tensor.
fn check_entries(header: &[u8]) -> std::result::Result<(), String> {
    let entries: BTreeMap<String, serde_json::Value> =
        serde_json::from_slice(header).map_err(|e| format!("header: {e}"))?;
    for (name, entry) in entries {
        if name == "__metadata__" {
            continue;
        }
        let info: TensorInfo =
            serde_json::from_value(entry).map_err(|e| format!("header: tensor `{name}`: {e}"))?;
        let (start, end) = info.data_offsets;
        let bits = info
            .shape
            .iter()
            .try_fold(1usize, |n, &d| n.checked_mul(d))
            .and_then(|n| n.checked_mul(info.dtype.bitsize()));
        let needs = match bits {
            Some(bits) if bits % 8 == 0 && end >= start && bits / 8 == end - start => continue,
            Some(bits) if bits % 8 == 0 => format!("{} bytes", bits / 8),
            Some(bits) => format!("{bits} bits, no whole number of bytes"),
            None => "more bytes than can be counted".to_string(),
        };
        return Err(format!(
            "header: tensor `{name}`: {:?} of shape {:?} takes {needs}, its data offsets [{start}, \
             {end}] hold {} bytes",
            info.dtype,
            info.shape,
            end.saturating_sub(start)
        ));
    }
    Ok(())
}

impl SafetensorsFile {
    /// The tensor `name` of `info` (an entry of this file's checked header) as f32 on the
    /// device; errors name the file and the tensor.
    fn read(&self, name: &str, info: &TensorInfo) -> Result<Tensor> {
        let (start, end) = info.data_offsets;
        let (from, to) = (self.data_start + start as u64, self.data_start + end as u64);
        let io = |e: std::io::Error| StyleLossError::Io {
            path: self.path.clone(),
            source: std::io::Error::new(
                e.kind(),
                format!("tensor `{name}` (bytes {from}..{to} of the file): {e}"),
            ),
        };
        let dtype = match info.dtype {
            safetensors::Dtype::F32 => DType::F32,
            safetensors::Dtype::F16 => DType::F16,
            safetensors::Dtype::BF16 => DType::BF16,
            safetensors::Dtype::F64 => DType::F64,
            other => {
                return Err(StyleLossError::Parse {
                    path: self.path.clone(),
                    message: format!(
                        "tensor `{name}` is {other:?}; weights are taken as F32, F16, BF16 or F64"
                    ),
                })
            }
        };
        let converted = |source| StyleLossError::TensorLoad {
            path: self.path.clone(),
            tensor: name.to_string(),
            source: Box::new(source),
        };
        let mut file = self
            .file
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        file.seek(SeekFrom::Start(from)).map_err(io)?;
        let host = if dtype == DType::F32 {
            // Straight into the f32 vector (the header's check made the range 4 bytes a value).
            let mut values = vec![0f32; (end - start) / 4];
            file.read_exact(bytemuck::cast_slice_mut(&mut values))
                .map_err(io)?;
            Tensor::from_vec(values, info.shape.as_slice(), &Device::Cpu)
        } else {
            let mut bytes = vec![0u8; end - start];
            file.read_exact(&mut bytes).map_err(io)?;
            Tensor::from_raw_buffer(&bytes, dtype, &info.shape, &Device::Cpu)
                .and_then(|t| t.to_dtype(DType::F32))
        };
        host.and_then(|t| t.to_device(&self.device))
            .map_err(converted)
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Tensors of four formats, written with candle's safetensors writer.
    fn write_checkpoint(path: &Path) -> HashMap<String, Tensor> {
        let dev = Device::Cpu;
        let f32s = vec![1.5f32, -0.0, f32::MIN_POSITIVE, -3.25e7, 1e-40, 7.0];
        let tensors = HashMap::from([
            (
                "f32".to_string(),
                Tensor::from_vec(f32s, (2, 3), &dev).unwrap(),
            ),
            (
                "f16".to_string(),
                Tensor::new(&[0.5f32, -2.0, 65504.0, 1e-3], &dev)
                    .unwrap()
                    .to_dtype(DType::F16)
                    .unwrap(),
            ),
            (
                "bf16".to_string(),
                Tensor::new(&[[3.0f32, -1e30]], &dev)
                    .unwrap()
                    .to_dtype(DType::BF16)
                    .unwrap(),
            ),
            (
                "f64".to_string(),
                Tensor::new(&[0.1f64, -1e300, 2.0], &dev).unwrap(),
            ),
            (
                "empty".to_string(),
                Tensor::zeros((0, 4), DType::F32, &dev).unwrap(),
            ),
        ]);
        candle_core::safetensors::save(&tensors, path).unwrap();
        tensors
    }

    /// The tensor's values converted to f32, as bits (so that -0.0 and NaN compare exactly).
    fn values(t: &Tensor) -> Vec<u32> {
        t.flatten_all()
            .unwrap()
            .to_dtype(DType::F32)
            .unwrap()
            .to_vec1::<f32>()
            .unwrap()
            .iter()
            .map(|v| v.to_bits())
            .collect()
    }

    #[test]
    fn every_tensor_is_read_as_f32_bit_for_bit() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("model.safetensors");
        let written = write_checkpoint(&path);
        let file = NamedTensors::load_safetensors(&path, &Device::Cpu).unwrap();
        let mut names: Vec<&String> = written.keys().collect();
        names.sort();
        // In name order, then again in the reverse order: each read seeks to its own tensor.
        for name in names.iter().chain(names.iter().rev()) {
            let tensor = &written[*name];
            let read = file.get(name, tensor.dims()).unwrap();
            assert_eq!(read.dtype(), DType::F32, "{name}");
            assert_eq!(read.dims(), tensor.dims(), "{name}");
            assert_eq!(values(&read), values(tensor), "{name}");
        }
    }

    #[test]
    fn a_missing_tensor_or_a_wrong_shape_names_the_file_and_the_tensor() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("model.safetensors");
        write_checkpoint(&path);
        let file = NamedTensors::load_safetensors(&path, &Device::Cpu).unwrap();
        let missing = file.get("nope", &[1]).unwrap_err().to_string();
        assert!(
            missing.contains("model.safetensors") && missing.contains("nope"),
            "{missing}"
        );
        let shape = file.get("f16", &[2, 2]).unwrap_err().to_string();
        assert!(
            shape.contains("model.safetensors") && shape.contains("f16") && shape.contains("[4]"),
            "{shape}"
        );
    }

    /// The file's bytes with its 8-byte header length replaced by `len`.
    fn with_header_len(bytes: &[u8], len: u64) -> Vec<u8> {
        let mut out = bytes.to_vec();
        out[..8].copy_from_slice(&len.to_le_bytes());
        out
    }

    #[test]
    fn a_damaged_file_is_refused_when_opened_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        let good = dir.path().join("good.safetensors");
        write_checkpoint(&good);
        let bytes = std::fs::read(&good).unwrap();
        let header_len = u64::from_le_bytes(bytes[..8].try_into().unwrap());
        let header = &bytes[8..8 + header_len as usize];
        // The header edited (same length), the data kept.
        let edited = |from: &str, to: &str| {
            let text = String::from_utf8(header.to_vec()).unwrap();
            assert!(text.contains(from), "{from} in {text}");
            let text = text.replacen(from, to, 1);
            assert_eq!(text.len(), header.len());
            [
                &bytes[..8],
                text.as_bytes(),
                &bytes[8 + header_len as usize..],
            ]
            .concat()
        };
        let cases: Vec<(&str, Vec<u8>)> = vec![
            ("empty", vec![]),
            ("five bytes", bytes[..5].to_vec()),
            ("huge header length", with_header_len(&bytes, u64::MAX)),
            (
                "header past the end",
                with_header_len(&bytes, bytes.len() as u64),
            ),
            ("header not json", with_header_len(&bytes, 3)),
            (
                "first offset not 0",
                edited("\"data_offsets\":[0,", "\"data_offsets\":[1,"),
            ),
            // A tensor's size no longer its format's: 2-byte values over 4-byte ones.
            (
                "format and size apart",
                edited("\"f32\":{\"dtype\":\"F32\"", "\"f32\":{\"dtype\":\"F16\""),
            ),
            ("one byte short", bytes[..bytes.len() - 1].to_vec()),
            ("one byte more", [bytes.as_slice(), &[0]].concat()),
        ];
        for (what, content) in cases {
            let path = dir.path().join("damaged.safetensors");
            std::fs::write(&path, &content).unwrap();
            let err = NamedTensors::load_safetensors(&path, &Device::Cpu)
                .map(|_| ())
                .expect_err(what);
            assert!(matches!(err, StyleLossError::Parse { .. }), "{what}: {err}");
            let text = err.to_string();
            assert!(text.contains("damaged.safetensors"), "{what}: {text}");
            if what == "format and size apart" {
                // The tensor, its format and shape, and the two sizes that disagree.
                for part in ["`f32`", "F16", "[2, 3]", "12 bytes", "hold 24 bytes"] {
                    assert!(text.contains(part), "{what}: {part} in {text}");
                }
            }
        }
    }

    /// A tensor of a format weights do not come in, and a file cut short after it was opened:
    /// errors naming the file and the tensor, at the read.
    #[test]
    fn a_tensor_that_cannot_be_read_names_the_file_and_the_tensor() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("model.safetensors");
        let dev = Device::Cpu;
        let tensors = HashMap::from([
            (
                "bytes".to_string(),
                Tensor::new(&[1u8, 2, 3], &dev).unwrap(),
            ),
            (
                "tail".to_string(),
                Tensor::new(&[0.5f32; 64], &dev).unwrap(),
            ),
        ]);
        candle_core::safetensors::save(&tensors, &path).unwrap();
        let file = NamedTensors::load_safetensors(&path, &dev).unwrap();
        let err = file.get("bytes", &[3]).unwrap_err();
        assert!(matches!(err, StyleLossError::Parse { .. }), "{err}");
        let text = err.to_string();
        assert!(
            text.contains("model.safetensors") && text.contains("`bytes`"),
            "{text}"
        );

        let len = std::fs::metadata(&path).unwrap().len();
        std::fs::OpenOptions::new()
            .write(true)
            .open(&path)
            .unwrap()
            .set_len(len - 8)
            .unwrap();
        let err = file.get("tail", &[64]).unwrap_err();
        assert!(matches!(err, StyleLossError::Io { .. }), "{err}");
        let text = err.to_string();
        assert!(
            text.contains("model.safetensors") && text.contains("`tail`"),
            "{text}"
        );
    }

    /// Random bytes anywhere in a file: opening and reading every tensor returns errors, never
    /// a panic; a file damaged in its data alone opens and reads every tensor.
    #[test]
    fn random_damage_never_panics() {
        let dir = tempfile::tempdir().unwrap();
        let good = dir.path().join("good.safetensors");
        let written = write_checkpoint(&good);
        let bytes = std::fs::read(&good).unwrap();
        let path = dir.path().join("fuzzed.safetensors");
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let header_end = 8 + u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
        // Damaged files that opened, and those of them whose damage is in the header.
        let (mut opened, mut header_damaged) = (0, 0);
        for _ in 0..300 {
            let mut content = bytes.clone();
            let mut in_header = false;
            for _ in 0..rng.random_range(1..4) {
                // Mostly in the header, where the structure is.
                let at = if rng.random_bool(0.8) {
                    rng.random_range(0..header_end)
                } else {
                    rng.random_range(0..content.len())
                };
                content[at] = rng.random();
                in_header |= at < header_end && content[at] != bytes[at];
            }
            std::fs::write(&path, &content).unwrap();
            let opening = NamedTensors::load_safetensors(&path, &Device::Cpu);
            // Damage to the data alone leaves a file that opens and whose every tensor reads.
            assert!(
                in_header || opening.is_ok(),
                "data damage refused: {opening:?}"
            );
            let Ok(file) = opening else {
                continue;
            };
            opened += 1;
            header_damaged += usize::from(in_header);
            for (name, tensor) in &written {
                let read = file.get(name, tensor.dims());
                assert!(
                    in_header || read.is_ok(),
                    "`{name}` with data damage: {read:?}"
                );
            }
        }
        assert!(
            header_damaged > 0 && opened > header_damaged,
            "{opened} damaged files opened, {header_damaged} with a damaged header: the reads \
             were not exercised"
        );
    }
}
