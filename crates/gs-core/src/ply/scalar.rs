//! PLY scalar property types: sizes, names, binary and text encodings.

use std::fmt;

/// The scalar type of a PLY property. Every value of every type is held exactly in an `f64`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScalarType {
    /// `char` / `int8`.
    Int8,
    /// `uchar` / `uint8`.
    UInt8,
    /// `short` / `int16`.
    Int16,
    /// `ushort` / `uint16`.
    UInt16,
    /// `int` / `int32`.
    Int32,
    /// `uint` / `uint32`.
    UInt32,
    /// `float` / `float32`.
    Float32,
    /// `double` / `float64`.
    Float64,
}

impl ScalarType {
    /// The type of a header type name (both the classic and the sized spellings).
    pub fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::Int8,
            "uchar" | "uint8" => Self::UInt8,
            "short" | "int16" => Self::Int16,
            "ushort" | "uint16" => Self::UInt16,
            "int" | "int32" => Self::Int32,
            "uint" | "uint32" => Self::UInt32,
            "float" | "float32" => Self::Float32,
            "double" | "float64" => Self::Float64,
            _ => return None,
        })
    }

    /// The classic header name, as INRIA 3DGS (plyfile) writes it.
    pub fn name(self) -> &'static str {
        match self {
            Self::Int8 => "char",
            Self::UInt8 => "uchar",
            Self::Int16 => "short",
            Self::UInt16 => "ushort",
            Self::Int32 => "int",
            Self::UInt32 => "uint",
            Self::Float32 => "float",
            Self::Float64 => "double",
        }
    }

    /// Size of one value in a binary body, bytes.
    pub fn size(self) -> usize {
        match self {
            Self::Int8 | Self::UInt8 => 1,
            Self::Int16 | Self::UInt16 => 2,
            Self::Int32 | Self::UInt32 | Self::Float32 => 4,
            Self::Float64 => 8,
        }
    }

    /// True for `float` and `double`.
    pub fn is_float(self) -> bool {
        matches!(self, Self::Float32 | Self::Float64)
    }

    /// The value stored in `b` (at least [`ScalarType::size`] bytes).
    #[inline]
    pub(crate) fn decode(self, b: &[u8], big_endian: bool) -> f64 {
        macro_rules! get {
            ($t:ty, $n:literal) => {{
                let a: [u8; $n] = b[..$n].try_into().expect("slice has the type's size");
                if big_endian {
                    <$t>::from_be_bytes(a) as f64
                } else {
                    <$t>::from_le_bytes(a) as f64
                }
            }};
        }
        match self {
            Self::Int8 => get!(i8, 1),
            Self::UInt8 => get!(u8, 1),
            Self::Int16 => get!(i16, 2),
            Self::UInt16 => get!(u16, 2),
            Self::Int32 => get!(i32, 4),
            Self::UInt32 => get!(u32, 4),
            Self::Float32 => get!(f32, 4),
            Self::Float64 => get!(f64, 8),
        }
    }

    /// Writes `v` into `out` ([`ScalarType::size`] bytes). `v` must have passed
    /// [`ScalarType::check`].
    #[inline]
    pub(crate) fn encode(self, v: f64, big_endian: bool, out: &mut [u8]) {
        macro_rules! put {
            ($x:expr) => {{
                let x = $x;
                out.copy_from_slice(&if big_endian {
                    x.to_be_bytes()
                } else {
                    x.to_le_bytes()
                })
            }};
        }
        match self {
            Self::Int8 => put!(v as i8),
            Self::UInt8 => put!(v as u8),
            Self::Int16 => put!(v as i16),
            Self::UInt16 => put!(v as u16),
            Self::Int32 => put!(v as i32),
            Self::UInt32 => put!(v as u32),
            Self::Float32 => put!(v as f32),
            Self::Float64 => put!(v),
        }
    }

    /// Checks that `v` is a value of this type: finite (and a finite `f32` for `float`), or an
    /// integer within range.
    pub(crate) fn check(self, v: f64) -> Result<(), String> {
        let (lo, hi) = match self {
            Self::Float32 => {
                return if (v as f32).is_finite() {
                    Ok(())
                } else {
                    Err(format!("value {} is not a finite float", show(v)))
                };
            }
            Self::Float64 => {
                return if v.is_finite() {
                    Ok(())
                } else {
                    Err(format!("value {} is not finite", show(v)))
                };
            }
            Self::Int8 => (i8::MIN as f64, i8::MAX as f64),
            Self::UInt8 => (0.0, u8::MAX as f64),
            Self::Int16 => (i16::MIN as f64, i16::MAX as f64),
            Self::UInt16 => (0.0, u16::MAX as f64),
            Self::Int32 => (i32::MIN as f64, i32::MAX as f64),
            Self::UInt32 => (0.0, u32::MAX as f64),
        };
        if v.fract() == 0.0 && v >= lo && v <= hi {
            Ok(())
        } else {
            Err(format!("value {} is not a {}", show(v), self.name()))
        }
    }

    /// Parses one ascii token of this type.
    pub(crate) fn parse_ascii(self, token: &str) -> Result<f64, String> {
        let v = match self {
            Self::Float32 => token
                .parse::<f32>()
                .map(f64::from)
                .map_err(|e| e.to_string()),
            Self::Float64 => token.parse::<f64>().map_err(|e| e.to_string()),
            _ => token
                .parse::<i64>()
                .map(|i| i as f64)
                .map_err(|e| e.to_string()),
        }
        .map_err(|e| format!("{token:?} is not a {}: {e}", self.name()))?;
        self.check(v)?;
        Ok(v)
    }

    /// Appends `v` as ascii text that parses back to the same value.
    pub(crate) fn format_ascii(self, v: f64, out: &mut String) {
        use std::fmt::Write;
        let _ = match self {
            Self::Float32 => write!(out, "{}", v as f32),
            Self::Float64 => write!(out, "{v}"),
            _ => write!(out, "{}", v as i64),
        };
    }
}

/// A value for a message: plain decimals for ordinary magnitudes, scientific notation for very
/// large or small ones.
pub(crate) fn show(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-6..1e16).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

impl fmt::Display for ScalarType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}
