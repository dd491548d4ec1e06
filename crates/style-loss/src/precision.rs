//! The floating-point formats CLIP ([`ClipPrecision`]) and VGG ([`VggPrecision`]) run in, and
//! the choice their `auto` makes: bf16 products where the CPU multiplies bf16 natively.

use std::fmt;
use std::str::FromStr;

use candle_core::{DType, Device};
use serde::{Deserialize, Serialize};

/// Environment variable that, set to `0`, keeps `auto` at f32 on every CPU
/// (for comparing runs, and for testing the fallback on a CPU that has the instructions).
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
    /// f32. On a CPU with AVX-512 BF16 the products run 1.5 to 1.8 times the f32 rate.
    Bf16,
    /// `bf16` on a CPU with the AVX-512 BF16 dot product, f32 everywhere else (GPUs included);
    /// see [`ClipPrecision::resolve`].
    Auto,
}

impl ClipPrecision {
    /// The format the model runs in on `device`: `Auto` becomes `Bf16` where [`auto_takes_bf16`],
    /// `F32` elsewhere; the others stay.
    pub fn resolve(self, device: &Device) -> ClipPrecision {
        self.resolve_with(auto_takes_bf16(device))
    }

    /// [`ClipPrecision::resolve`] given whether bf16 products are native here.
    pub fn resolve_with(self, native_bf16: bool) -> ClipPrecision {
        match self {
            Self::Auto if native_bf16 => Self::Bf16,
            Self::Auto => Self::F32,
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

/// Whether `auto` takes bf16 products on `device`: a CPU that [`cpu_multiplies_bf16`], unless
/// `CLIPGAUSSIAN_CPU_BF16` is `0`, `false`, `off` or `no`.
pub fn auto_takes_bf16(device: &Device) -> bool {
    let enabled = std::env::var(CPU_BF16_ENV)
        .map_or(true, |v| !matches!(v.trim(), "0" | "false" | "off" | "no"));
    device.is_cpu() && enabled && cpu_multiplies_bf16()
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
    /// `bf16` on a CPU with the AVX-512 BF16 dot product, f32 everywhere else.
    Auto,
}

impl VggPrecision {
    /// The format on `device`: `Auto` becomes `Bf16` where [`auto_takes_bf16`], `F32`
    /// elsewhere; the others stay.
    pub fn resolve(self, device: &Device) -> VggPrecision {
        match self {
            Self::Auto if auto_takes_bf16(device) => Self::Bf16,
            Self::Auto => Self::F32,
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
    fn auto_takes_bf16_only_where_the_cpu_multiplies_it() {
        assert_eq!(ClipPrecision::Auto.resolve_with(true), ClipPrecision::Bf16);
        assert_eq!(ClipPrecision::Auto.resolve_with(false), ClipPrecision::F32);
        for fixed in [ClipPrecision::F32, ClipPrecision::F16, ClipPrecision::Bf16] {
            assert_eq!(fixed.resolve_with(true), fixed);
            assert_eq!(fixed.resolve_with(false), fixed);
        }
        // CLIP's and VGG's auto choose alike (the switch is tested through clipgaussian-2d).
        assert_eq!(
            ClipPrecision::Auto.resolve(&Device::Cpu) == ClipPrecision::Bf16,
            VggPrecision::Auto.resolve(&Device::Cpu) == VggPrecision::Bf16
        );
        // bf16 holds the matrices in bf16 and the activations in f32; f16 is half throughout.
        assert_eq!(ClipPrecision::Bf16.matrix_dtype(), DType::BF16);
        assert_eq!(ClipPrecision::Bf16.activation_dtype(), DType::F32);
        assert_eq!(ClipPrecision::F16.activation_dtype(), DType::F16);
    }
}
