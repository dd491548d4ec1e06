//! The device a run asks for (`--device cpu|gpu|auto`), as a choice; opening it is the
//! GPU backend's (gs-wgpu's `OpenDevice`).

use std::fmt;
use std::str::FromStr;

/// The device asked for: `cpu`, `gpu` or `auto`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DeviceChoice {
    /// The cpu backend (rayon).
    Cpu,
    /// A real GPU through wgpu; an error when there is none.
    Gpu,
    /// A real GPU when there is one, else the cpu.
    #[default]
    Auto,
}

impl FromStr for DeviceChoice {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "cpu" => Ok(Self::Cpu),
            "gpu" => Ok(Self::Gpu),
            "auto" => Ok(Self::Auto),
            other => Err(format!("device {other:?} is not one of cpu, gpu, auto")),
        }
    }
}

impl fmt::Display for DeviceChoice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Cpu => "cpu",
            Self::Gpu => "gpu",
            Self::Auto => "auto",
        })
    }
}

/// Its name (`"cpu"`, `"gpu"`, `"auto"`), as configuration files and flags write it.
impl serde::Serialize for DeviceChoice {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

/// From its name; another name is refused listing the three.
impl<'de> serde::Deserialize<'de> for DeviceChoice {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        <String as serde::Deserialize>::deserialize(d)?
            .parse()
            .map_err(serde::de::Error::custom)
    }
}
