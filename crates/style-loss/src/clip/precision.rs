//! The floating-point format CLIP runs in ([`ClipPrecision`]).

use std::fmt;
use std::str::FromStr;

use candle_core::DType;
use serde::{Deserialize, Serialize};

/// The format of CLIP's weight matrices, embeddings and activations. Layer norms and softmax
/// compute in f32 whatever it is, as OpenAI's fp16 CLIP does; the image, the embeddings CLIP
/// returns and the image gradient are f32. The authors run CLIP in fp16 on the GPU.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ClipPrecision {
    /// IEEE single precision (the default).
    #[default]
    F32,
    /// IEEE half precision, as the authors' CLIP on CUDA.
    F16,
    /// bfloat16: f32's range with 8 bits of mantissa.
    Bf16,
}

impl ClipPrecision {
    /// The candle dtype of this format.
    pub fn dtype(self) -> DType {
        match self {
            Self::F32 => DType::F32,
            Self::F16 => DType::F16,
            Self::Bf16 => DType::BF16,
        }
    }
}

impl FromStr for ClipPrecision {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "f32" => Ok(Self::F32),
            "f16" => Ok(Self::F16),
            "bf16" => Ok(Self::Bf16),
            other => Err(format!("precision {other:?} is not one of f32, f16, bf16")),
        }
    }
}

impl fmt::Display for ClipPrecision {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::F32 => "f32",
            Self::F16 => "f16",
            Self::Bf16 => "bf16",
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_unknown_names_are_refused() {
        for p in [ClipPrecision::F32, ClipPrecision::F16, ClipPrecision::Bf16] {
            assert_eq!(p.to_string().parse::<ClipPrecision>(), Ok(p));
            let json = serde_json::to_string(&p).unwrap();
            assert_eq!(json, format!("\"{p}\""));
            assert_eq!(serde_json::from_str::<ClipPrecision>(&json).unwrap(), p);
        }
        assert!("fp16"
            .parse::<ClipPrecision>()
            .unwrap_err()
            .contains("f32, f16, bf16"));
        assert_eq!(ClipPrecision::default().dtype(), DType::F32);
    }
}
