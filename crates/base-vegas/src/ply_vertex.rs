//! The rows of a VeGaS model file as typed elements for `ply-rs-bw`: a vertex's values by
//! name in a fixed order, and the one row of time logits. A file of n Gaussians is read and
//! written through n small arrays, not n maps from property names to values (about 20 times
//! the memory and 15 times the time).

use ply_rs_bw::ply::ScalarType;
use ply_rs_bw::ply::{ElementDef, Property, PropertyAccess, PropertyAccessResult, PropertyType};

use crate::frame::{FLAT_SCALE, POLY_LEN};

/// Values of a vertex, in order: `x y z scale_0 scale_2 rot_0 m_0 sigma_0 w1_0..w1_{P-1}
/// opacity f_dc_0..2` (`P` = [`POLY_LEN`]).
pub(crate) const VALUES: usize = 8 + POLY_LEN + 4;

/// Index of `opacity` in [`VegasVertex::values`].
pub(crate) const OPACITY: usize = 8 + POLY_LEN;

/// The name of value `k` of [`VegasVertex::values`].
pub(crate) fn name(k: usize) -> String {
    const FIRST: [&str; 8] = [
        "x", "y", "z", "scale_0", "scale_2", "rot_0", "m_0", "sigma_0",
    ];
    match k {
        k if k < 8 => FIRST[k].to_string(),
        k if k < OPACITY => format!("w1_{}", k - 8),
        OPACITY => "opacity".to_string(),
        k => format!("f_dc_{}", k - OPACITY - 1),
    }
}

/// The index of the value named `name`; `None` for a property this reader does not take.
fn slot(name: &str) -> Option<usize> {
    let fixed = match name {
        "x" => Some(0),
        "y" => Some(1),
        "z" => Some(2),
        "scale_0" => Some(3),
        "scale_2" => Some(4),
        "rot_0" => Some(5),
        "m_0" => Some(6),
        "sigma_0" => Some(7),
        "opacity" => Some(OPACITY),
        "f_dc_0" => Some(OPACITY + 1),
        "f_dc_1" => Some(OPACITY + 2),
        "f_dc_2" => Some(OPACITY + 3),
        _ => None,
    };
    fixed.or_else(|| {
        let k: usize = name.strip_prefix("w1_")?.parse().ok()?;
        (k < POLY_LEN && name == format!("w1_{k}")).then_some(8 + k)
    })
}

/// Checks a `vertex` element's properties before its rows are read: a motion polynomial of
/// this build's degree, every value present, each `float` or `double`.
pub(crate) fn check_properties(element: &ElementDef) -> Result<(), String> {
    let degree = element
        .properties
        .keys()
        .filter(|k| k.starts_with("w1_"))
        .count();
    if degree != 0 && degree != POLY_LEN {
        return Err(format!(
            "{degree} w1_* properties: a motion polynomial of degree {}, but this build reads \
             degree {} ({POLY_LEN} values)",
            degree / 2,
            POLY_LEN / 2
        ));
    }
    for k in 0..VALUES {
        let name = name(k);
        match element.properties.get(&name).map(|p| &p.data_type) {
            None => {
                return Err(format!(
                    "no property {name}: not a VeGaS model (VeGaS writes x, y, z, f_dc_*, \
                     opacity, scale_*, rot_0, m_0, sigma_0, w1_0..w1_{})",
                    POLY_LEN - 1
                ))
            }
            Some(PropertyType::Scalar(ScalarType::Float | ScalarType::Double)) => {}
            Some(other) => {
                return Err(format!("property {name} is {other:?}, not float or double"))
            }
        }
    }
    Ok(())
}

/// A vertex's values (see [`VALUES`]); properties it does not take are skipped.
#[derive(Clone, Debug)]
pub(crate) struct VegasVertex {
    /// The values, in the order of [`name`].
    pub values: [f32; VALUES],
}

impl PropertyAccess for VegasVertex {
    fn new() -> Self {
        Self {
            values: [0.0; VALUES],
        }
    }

    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        let Some(k) = slot(name) else {
            return PropertyAccessResult::Ignored;
        };
        self.values[k] = match property {
            Property::Float(v) => v,
            Property::Double(v) => v as f32,
            _ => return PropertyAccessResult::UnsupportedType,
        };
        PropertyAccessResult::Set
    }
}

impl VegasVertex {
    /// The value VeGaS writes as property `name`: one of [`VALUES`], or the ones it writes and
    /// never reads (`nx ny nz` 0, `scale_1` the flat scale's log).
    fn written(&self, name: &str) -> Option<f32> {
        match name {
            "nx" | "ny" | "nz" => Some(0.0),
            "scale_1" => Some(FLAT_SCALE.ln() as f32),
            _ => slot(name).map(|k| self.values[k]),
        }
    }
}

/// A row of a VeGaS model file, as written: a vertex, or the `time` element's one row of
/// logits (`time_func_0..`).
#[derive(Clone, Debug)]
pub(crate) enum ModelRow {
    /// A Gaussian.
    Vertex(VegasVertex),
    /// The time logits.
    Time(Vec<f32>),
}

impl PropertyAccess for ModelRow {
    fn new() -> Self {
        Self::Vertex(VegasVertex::new())
    }

    fn get_float(&self, name: &str) -> Option<f32> {
        match self {
            Self::Vertex(vertex) => vertex.written(name),
            Self::Time(logits) => {
                let k: usize = name.strip_prefix("time_func_")?.parse().ok()?;
                logits.get(k).copied()
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_value_has_its_own_name_and_slot() {
        for k in 0..VALUES {
            assert_eq!(slot(&name(k)), Some(k), "{}", name(k));
        }
        for other in ["nx", "scale_1", "w1_14", "w1_01", "f_dc_3", "w1_"] {
            assert_eq!(slot(other), None, "{other}");
        }
    }

    #[test]
    fn rows_give_what_vegas_writes() {
        let mut vertex = VegasVertex::new();
        vertex.values[OPACITY] = 0.25;
        let row = ModelRow::Vertex(vertex);
        assert_eq!(row.get_float("opacity"), Some(0.25));
        assert_eq!(row.get_float("nx"), Some(0.0));
        assert_eq!(row.get_float("scale_1"), Some(FLAT_SCALE.ln() as f32));
        assert_eq!(row.get_float("time_func_0"), None);
        let time = ModelRow::Time(vec![0.5, -1.0]);
        assert_eq!(time.get_float("time_func_1"), Some(-1.0));
        assert_eq!(time.get_float("time_func_2"), None);
        assert_eq!(time.get_float("x"), None);
    }
}
