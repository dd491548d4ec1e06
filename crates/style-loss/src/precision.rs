//! The floating-point formats CLIP ([`ClipPrecision`]) and VGG ([`VggPrecision`]) run in; how
//! their `auto` chooses is the `auto_precision` module's.

use std::fmt;
use std::str::FromStr;

use candle_core::DType;
use serde::{Deserialize, Serialize};

use crate::auto_precision::AutoChoice;

/// Environment variable that forces `auto`: `0` to f32 products, `1` to bf16 products, on every
/// CPU (for comparing runs, and for testing either path on any CPU).
pub const CPU_BF16_ENV: &str = "CLIPGAUSSIAN_CPU_BF16";

/// The format of CLIP's products and activations. The image, the embeddings CLIP returns and the
/// image gradient are f32 in every format; layer norms and softmax compute in f32.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ClipPrecision {
    /// IEEE single precision throughout (the default).
    #[default]
    F32,
    /// IEEE half precision for the weights, embeddings and activations, as OpenAI's fp16 CLIP
    /// that the authors load on CUDA.
    F16,
    /// bfloat16 (f32's range, 8 bits of mantissa) for the linear layers' products only: the
    /// weights are held in bf16, each product rounds its input to bf16, sums in f32 and rounds
    /// its output to bf16, widened back to f32; the activations, attention and embeddings stay
    /// f32. With AVX-512 BF16 the products ran 1.2 to 2 times the f32 rate on an AMD Zen 4,
    /// and under it on an Intel Sapphire Rapids.
    Bf16,
    /// `bf16` where its products time at least 1.1 times as fast as f32 on this CPU, f32
    /// everywhere else (GPUs included); see `auto_precision`.
    Auto,
}

impl ClipPrecision {
    /// The format the model runs in: `Auto` becomes what `auto` chose; the others stay.
    pub fn resolve(self, auto: &AutoChoice) -> ClipPrecision {
        match self {
            Self::Auto => auto.clip(),
            other => other,
        }
    }

    /// The format of the linear layers' weight matrices.
    pub fn matrix_dtype(self) -> DType {
        match self {
            Self::F32 | Self::Auto => DType::F32,
            Self::F16 => DType::F16,
            Self::Bf16 => DType::BF16,
        }
    }

    /// The format of the activations, embeddings and biases.
    pub fn activation_dtype(self) -> DType {
        match self {
            Self::F16 => DType::F16,
            Self::F32 | Self::Bf16 | Self::Auto => DType::F32,
        }
    }
}

/// The format of VGG's convolution products. Activations, bias and ReLU are f32 in each.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum VggPrecision {
    /// f32 products; on the CPU the forward sums (the render's and the ground truth's alike)
    /// are exact before the ReLU decides, as the f32 PyTorch network decides; the backward on
    /// the layers of 64 channels and more (all but the first) by Winograd's F(2x2, 3x3) (the
    /// default).
    #[default]
    F32,
    /// On the layers of 256 channels and more, the backward's products (the adjoint
    /// convolutions on the gradient) in bf16: gradient and kernels rounded to bf16, f32 sums,
    /// each output rounded to bf16; the forward stays f32, by Winograd's F(2x2, 3x3) rather
    /// than summed exactly. Narrower layers stay f32 both ways (their backward as with `F32`).
    /// The CPU only.
    Bf16,
    /// `bf16` where its backward times at least 1.1 times as fast as f32 on this CPU, f32
    /// everywhere else; see `auto_precision`.
    Auto,
}

impl VggPrecision {
    /// The format the network runs in: `Auto` becomes what `auto` chose; the others stay.
    pub fn resolve(self, auto: &AutoChoice) -> VggPrecision {
        match self {
            Self::Auto => auto.vgg(),
            other => other,
        }
    }
}

impl FromStr for VggPrecision {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "f32" => Ok(Self::F32),
            "bf16" => Ok(Self::Bf16),
            "auto" => Ok(Self::Auto),
            other => Err(format!("precision {other:?} is not one of f32, bf16, auto")),
        }
    }
}

impl fmt::Display for VggPrecision {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::F32 => "f32",
            Self::Bf16 => "bf16",
            Self::Auto => "auto",
        })
    }
}

/// Whether this CPU has the AVX-512 BF16 dot product (`vdpbf16ps`) that bf16 products run on
/// (Intel from Cooper Lake, AMD from Zen 4; every CPU with AMX has it too).
pub fn cpu_multiplies_bf16() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512bf16")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

impl FromStr for ClipPrecision {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "f32" => Ok(Self::F32),
            "f16" => Ok(Self::F16),
            "bf16" => Ok(Self::Bf16),
            "auto" => Ok(Self::Auto),
            other => Err(format!(
                "precision {other:?} is not one of f32, f16, bf16, auto"
            )),
        }
    }
}

impl fmt::Display for ClipPrecision {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::F32 => "f32",
            Self::F16 => "f16",
            Self::Bf16 => "bf16",
            Self::Auto => "auto",
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every value's name parses back, is its JSON string and reads back from JSON; `unknown`
    /// is refused with an error that lists the names `listed`.
    fn assert_names_round_trip<P>(values: &[P], unknown: &str, listed: &str)
    where
        P: Copy + PartialEq + fmt::Debug + fmt::Display + FromStr<Err = String>,
        P: Serialize + serde::de::DeserializeOwned,
    {
        for &p in values {
            assert_eq!(p.to_string().parse::<P>(), Ok(p));
            let json = serde_json::to_string(&p).unwrap();
            assert_eq!(json, format!("\"{p}\""));
            assert_eq!(serde_json::from_str::<P>(&json).unwrap(), p);
        }
        assert!(unknown.parse::<P>().unwrap_err().contains(listed));
        assert!(serde_json::from_str::<P>(&format!("\"{unknown}\"")).is_err());
    }

    #[test]
    fn names_round_trip_and_unknown_names_are_refused() {
        assert_names_round_trip(
            &[
                ClipPrecision::F32,
                ClipPrecision::F16,
                ClipPrecision::Bf16,
                ClipPrecision::Auto,
            ],
            "fp16",
            "f32, f16, bf16, auto",
        );
        assert_eq!(ClipPrecision::default().matrix_dtype(), DType::F32);
        assert_names_round_trip(
            &[VggPrecision::F32, VggPrecision::Bf16, VggPrecision::Auto],
            "f16",
            "f32, bf16, auto",
        );
        assert_eq!(VggPrecision::default(), VggPrecision::F32);
    }

    #[test]
    fn auto_becomes_what_was_chosen_and_the_others_stay() {
        for (choice, clip, vgg) in [
            (
                AutoChoice::Forced(true),
                ClipPrecision::Bf16,
                VggPrecision::Bf16,
            ),
            (
                AutoChoice::NoInstructions,
                ClipPrecision::F32,
                VggPrecision::F32,
            ),
        ] {
            assert_eq!(ClipPrecision::Auto.resolve(&choice), clip);
            assert_eq!(VggPrecision::Auto.resolve(&choice), vgg);
            for fixed in [ClipPrecision::F32, ClipPrecision::F16, ClipPrecision::Bf16] {
                assert_eq!(fixed.resolve(&choice), fixed);
            }
            for fixed in [VggPrecision::F32, VggPrecision::Bf16] {
                assert_eq!(fixed.resolve(&choice), fixed);
            }
        }
        // bf16 holds the matrices in bf16 and the activations in f32; f16 is half throughout.
        assert_eq!(ClipPrecision::Bf16.matrix_dtype(), DType::BF16);
        assert_eq!(ClipPrecision::Bf16.activation_dtype(), DType::F32);
        assert_eq!(ClipPrecision::F16.activation_dtype(), DType::F16);
    }
}
