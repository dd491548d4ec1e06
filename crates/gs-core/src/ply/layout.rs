//! The INRIA vertex layout: which property feeds which Gaussian parameter, and the conversion of
//! `f_rest_*` between the channel-major file order and gs-core's coefficient-major order.

use crate::gaussians::sh_coeff_count;

use super::scalar::{show, ScalarType};
use super::{ExtraProperty, PlyErrorKind, PlyGaussians};

/// Names of the three normal properties INRIA 3DGS writes (always zero) after the position.
pub const NORMAL_NAMES: [&str; 3] = ["nx", "ny", "nz"];

/// Where the value of one property goes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Slot {
    /// `means[3 i + k]` (`x`, `y`, `z`).
    Mean(usize),
    /// `sh_dc[3 i + c]` (`f_dc_c`).
    ShDc(usize),
    /// `sh_rest[(K-1) 3 i + offset]`, `offset = 3 coeff + channel` (`f_rest_*`).
    ShRest(usize),
    /// `opacity_logits[i]`.
    Opacity,
    /// `log_scales[3 i + k]` (`scale_k`).
    LogScale(usize),
    /// `quats[4 i + k]` (`rot_k`, w x y z).
    Quat(usize),
    /// Value `i` of extra property `e`.
    Extra(usize),
    /// Always 0: a normal written for a set that carries none (INRIA writes zero normals).
    Zero,
}

impl Slot {
    /// Checks that `value` may be stored here: finite, and a finite `f32` for a Gaussian
    /// parameter (a double too large for a float is refused, not turned into infinity).
    #[inline]
    pub fn check(self, value: f64) -> Result<(), String> {
        match self {
            Slot::Extra(_) | Slot::Zero if value.is_finite() => Ok(()),
            Slot::Extra(_) | Slot::Zero => Err(format!("value {} is not finite", show(value))),
            _ if (value as f32).is_finite() => Ok(()),
            _ if value.is_finite() => {
                Err(format!("value {} does not fit a 32-bit float", show(value)))
            }
            _ => Err(format!("value {} is not finite", show(value))),
        }
    }
}

/// One property of a vertex record.
#[derive(Clone, Debug)]
pub(crate) struct Field {
    /// Property name.
    pub name: String,
    /// Type in the file.
    pub ty: ScalarType,
    /// Destination of its values.
    pub slot: Slot,
}

impl Field {
    /// The value vertex `i` writes for this field (`rest` = SH rest values per vertex), checked
    /// to be representable in the field's type; the error names the vertex and property.
    pub fn value_to_write(
        &self,
        ply: &PlyGaussians,
        rest: usize,
        i: usize,
    ) -> Result<f64, PlyErrorKind> {
        let value = super::columns::get(ply, rest, i, self.slot);
        self.ty
            .check(value)
            .map_err(|reason| PlyErrorKind::BadValue {
                vertex: i,
                property: self.name.clone(),
                reason,
            })?;
        Ok(value)
    }
}

/// The fields of a vertex record in file order, and the SH degree they imply.
#[derive(Clone, Debug)]
pub(crate) struct Layout {
    /// The vertex properties, in file order.
    pub fields: Vec<Field>,
    /// SH degree (0..=3).
    pub degree: usize,
}

/// SH degree of a number of `f_rest_*` properties (`3 ((d+1)^2 - 1)`).
fn degree_of_rest_count(count: usize) -> Option<usize> {
    (0..=3).find(|&d| 3 * (sh_coeff_count(d) - 1) == count)
}

/// The required properties of degree `degree`, each with its slot, in INRIA order, with the
/// normals between the position and `f_dc` left out.
fn required(degree: usize) -> Vec<(String, Slot)> {
    let rest = sh_coeff_count(degree) - 1;
    let mut out: Vec<(String, Slot)> = (0..3)
        .map(|k| (["x", "y", "z"][k].to_string(), Slot::Mean(k)))
        .collect();
    out.extend((0..3).map(|c| (format!("f_dc_{c}"), Slot::ShDc(c))));
    // On disk: all R coefficients, then all G, then all B.
    out.extend((0..3 * rest).map(|j| {
        let (channel, coeff) = (j / rest, j % rest);
        (format!("f_rest_{j}"), Slot::ShRest(3 * coeff + channel))
    }));
    out.push(("opacity".to_string(), Slot::Opacity));
    out.extend((0..3).map(|k| (format!("scale_{k}"), Slot::LogScale(k))));
    out.extend((0..4).map(|k| (format!("rot_{k}"), Slot::Quat(k))));
    out
}

/// True for the name of a Gaussian property of any degree (`x`, `f_dc_0`, `f_rest_*`, `rot_3`,
/// ...), which an extra property may not take.
pub(crate) fn is_gaussian_property(name: &str) -> bool {
    name.starts_with("f_rest_") || required(0).iter().any(|(n, _)| n == name)
}

impl Layout {
    /// The layout of a file's properties: every required property found (float or double),
    /// every other property an extra, in file order. Returns the extras' names and types too.
    pub fn from_properties(
        properties: &[(String, ScalarType)],
    ) -> Result<(Self, Vec<(String, ScalarType)>), PlyErrorKind> {
        let rest_count = properties
            .iter()
            .filter(|(n, _)| n.starts_with("f_rest_"))
            .count();
        let degree =
            degree_of_rest_count(rest_count).ok_or(PlyErrorKind::ShRestCount(rest_count))?;
        let required = required(degree);
        for (name, _) in &required {
            if !properties.iter().any(|(n, _)| n == name) {
                return Err(PlyErrorKind::MissingProperty(name.clone()));
            }
        }
        let mut extras = Vec::new();
        let mut fields = Vec::with_capacity(properties.len());
        for (name, ty) in properties {
            let slot = match required.iter().find(|(n, _)| n == name) {
                Some((_, slot)) => {
                    if !ty.is_float() {
                        return Err(PlyErrorKind::PropertyType {
                            name: name.clone(),
                            ty: *ty,
                        });
                    }
                    *slot
                }
                None => {
                    extras.push((name.clone(), *ty));
                    Slot::Extra(extras.len() - 1)
                }
            };
            fields.push(Field {
                name: name.clone(),
                ty: *ty,
                slot,
            });
        }
        Ok((Self { fields, degree }, extras))
    }

    /// The layout written for `ply`: INRIA order (`x y z nx ny nz f_dc_* f_rest_* opacity
    /// scale_* rot_*`, all float), the normals taken from the extras when present (else written
    /// as float zeros; left out when `ply.normals` is false), then the other extras in their
    /// order.
    pub fn for_writing(ply: &PlyGaussians) -> Self {
        let degree = ply.gaussians.sh_degree();
        let field = |name: &str, ty, slot| Field {
            name: name.to_string(),
            ty,
            slot,
        };
        let extra_index = |name: &str| ply.extras.iter().position(|e| e.name == name);
        let mut fields = Vec::new();
        for (i, (name, slot)) in required(degree).into_iter().enumerate() {
            fields.push(field(&name, ScalarType::Float32, slot));
            if i == 2 && ply.normals {
                for n in NORMAL_NAMES {
                    fields.push(match extra_index(n) {
                        Some(e) => field(n, ply.extras[e].ty, Slot::Extra(e)),
                        None => field(n, ScalarType::Float32, Slot::Zero),
                    });
                }
            }
        }
        for (e, ExtraProperty { name, ty, .. }) in ply.extras.iter().enumerate() {
            if !NORMAL_NAMES.contains(&name.as_str()) {
                fields.push(field(name, *ty, Slot::Extra(e)));
            }
        }
        Self { fields, degree }
    }

    /// Bytes per vertex in a binary body.
    pub fn stride(&self) -> usize {
        self.fields.iter().map(|f| f.ty.size()).sum()
    }

    /// Names and types of the fields, in order.
    pub fn properties(&self) -> Vec<(String, ScalarType)> {
        self.fields.iter().map(|f| (f.name.clone(), f.ty)).collect()
    }
}
