//! Learning rates keyed by parameter-group name: the `learning_rates` field of every
//! modality's configuration.
//!
//! A model names its parameter groups once ([`gs_core::model::BaseModel::groups`]); the
//! configuration gives each of them, by that name, a rate:
//!
//! - a number: a constant rate (`"sh_dc": 0.01`);
//! - `"frozen"`: the group is not trained (no gradient, no optimizer state);
//! - `{"start": 1e-4, "end": 1e-6, "steps": 30000}`: an exponential decay from `start` at step
//!   0 to `end` at `steps` and after, optionally `"times_extent": true` to scale both by the
//!   scene's extent (3DGS's position rate).
//!
//! A name the model does not have, a group left out or a rate that is not finite and above 0
//! is an error naming the group and the flag that sets it (`--set learning_rates.NAME=VALUE`).
//! The table's order does not matter: the groups train in the model's order, each at its own
//! rate.

use gs_core::adam::{groups_in_model_order, GroupConfig, LrSchedule};
use serde::de::{Deserializer, Error as _, MapAccess, Visitor};
use serde::ser::{SerializeMap, Serializer};
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};

use crate::StylizeError;

/// The configuration field that holds the rates.
pub const FIELD: &str = "learning_rates";

/// CLIPGaussian's 3D stylization rates of plain Gaussians (gs-core's `PARAM_NAMES`, the
/// groups of 3DGS and MiraGe models): means `1e-4 -> 1e-6` times the scene's extent over 30,000
/// steps (3DGS's position schedule), scales 0.005, rotations 0.001, opacities 0.05, SH degree 0
/// at `feature_lr` and the higher degrees at `feature_lr / 20` (3DGS's split of the colour
/// rate). The paper's `feature_lr` is 0.01 in 3D and 0.0025 in 2D.
pub fn gaussian_stylization(feature_lr: f64) -> GroupRates {
    GroupRates::new([
        (
            "means",
            GroupRate::Decay {
                start: 1e-4,
                end: 1e-6,
                steps: 30_000,
                times_extent: true,
            },
        ),
        ("scales", GroupRate::Constant(0.005)),
        ("rotations", GroupRate::Constant(0.001)),
        ("opacities", GroupRate::Constant(0.05)),
        ("sh_dc", GroupRate::Constant(feature_lr)),
        ("sh_rest", GroupRate::Constant(feature_lr / 20.0)),
    ])
}

/// How one parameter group learns.
#[derive(Clone, Debug, PartialEq)]
pub enum GroupRate {
    /// Not trained.
    Frozen,
    /// The same rate at every step.
    Constant(f64),
    /// `start` at step 0 decaying exponentially to `end` at step `steps` and after
    /// ([`LrSchedule::Exponential`]); with `times_extent` both are multiplied by the scene's
    /// extent (world units).
    Decay {
        /// Rate at step 0.
        start: f64,
        /// Rate at step `steps` and after.
        end: f64,
        /// Length of the decay, steps.
        steps: u64,
        /// Whether `start` and `end` are in units of the scene's extent.
        times_extent: bool,
    },
}

impl GroupRate {
    /// The optimizer group `name` of this rate for a scene of size `extent`.
    fn group(&self, name: &str, extent: f64) -> GroupConfig {
        match *self {
            GroupRate::Frozen => GroupConfig::frozen(name),
            GroupRate::Constant(lr) => GroupConfig::new(name, LrSchedule::Constant(lr)),
            GroupRate::Decay {
                start,
                end,
                steps,
                times_extent,
            } => {
                let scale = if times_extent { extent } else { 1.0 };
                GroupConfig::new(
                    name,
                    LrSchedule::Exponential {
                        start: start * scale,
                        end: end * scale,
                        steps,
                    },
                )
            }
        }
    }

    /// Why this rate cannot train, if it cannot: every rate finite and above 0.
    fn problem(&self) -> Option<String> {
        let bad = |lr: f64| !(lr.is_finite() && lr > 0.0);
        match *self {
            GroupRate::Frozen => None,
            GroupRate::Constant(lr) if bad(lr) => Some(format!("{lr} must be finite and > 0")),
            GroupRate::Decay { start, end, .. } if bad(start) || bad(end) => Some(format!(
                "start {start} and end {end} must be finite and > 0"
            )),
            _ => None,
        }
    }

    fn to_json(&self) -> Value {
        match *self {
            GroupRate::Frozen => json!("frozen"),
            GroupRate::Constant(lr) => json!(lr),
            GroupRate::Decay {
                start,
                end,
                steps,
                times_extent,
            } => json!({"start": start, "end": end, "steps": steps, "times_extent": times_extent}),
        }
    }

    fn from_json(value: &Value) -> Result<Self, String> {
        const EXPECTED: &str = "a number, \"frozen\" or {\"start\": .., \"end\": .., \"steps\": \
                                .., \"times_extent\": false}";
        match value {
            Value::Number(n) => n
                .as_f64()
                .map(GroupRate::Constant)
                .ok_or_else(|| format!("{n} is not a rate")),
            Value::String(s) if s == "frozen" => Ok(GroupRate::Frozen),
            Value::Object(fields) => {
                let unknown: Vec<&str> = fields
                    .keys()
                    .map(String::as_str)
                    .filter(|k| !["start", "end", "steps", "times_extent"].contains(k))
                    .collect();
                if !unknown.is_empty() {
                    return Err(format!(
                        "unknown key(s) {} in a decay; expected {EXPECTED}",
                        unknown.join(", ")
                    ));
                }
                let number = |key: &str| {
                    fields
                        .get(key)
                        .and_then(Value::as_f64)
                        .ok_or_else(|| format!("a decay needs a number `{key}`"))
                };
                let steps = fields
                    .get("steps")
                    .and_then(Value::as_u64)
                    .ok_or("a decay needs a whole number of `steps`")?;
                let times_extent = match fields.get("times_extent") {
                    None => false,
                    Some(v) => v.as_bool().ok_or("`times_extent` is true or false")?,
                };
                Ok(GroupRate::Decay {
                    start: number("start")?,
                    end: number("end")?,
                    steps,
                    times_extent,
                })
            }
            other => Err(format!("{other} is not {EXPECTED}")),
        }
    }
}

/// A modality's learning rates: one [`GroupRate`] per parameter-group name. Two tables are
/// equal when they give the same groups the same rates, in whatever order.
#[derive(Clone, Debug, Default)]
pub struct GroupRates(Vec<(String, GroupRate)>);

impl PartialEq for GroupRates {
    fn eq(&self, other: &Self) -> bool {
        self.0.len() == other.0.len()
            && self
                .0
                .iter()
                .all(|(name, rate)| other.get(name) == Some(rate))
    }
}

impl GroupRates {
    /// A table of `entries` (name and rate), in their order.
    pub fn new<'a>(entries: impl IntoIterator<Item = (&'a str, GroupRate)>) -> Self {
        Self(
            entries
                .into_iter()
                .map(|(name, rate)| (name.to_string(), rate))
                .collect(),
        )
    }

    /// The rate of group `name`.
    pub fn get(&self, name: &str) -> Option<&GroupRate> {
        self.0.iter().find(|(n, _)| n == name).map(|(_, r)| r)
    }

    /// Sets the rate of group `name` (added at the end when the table has none).
    pub fn set(&mut self, name: &str, rate: GroupRate) {
        match self.0.iter_mut().find(|(n, _)| n == name) {
            Some((_, r)) => *r = rate,
            None => self.0.push((name.to_string(), rate)),
        }
    }

    /// The names of the groups that train (not [`GroupRate::Frozen`]), in table order.
    pub fn trained(&self) -> Vec<&str> {
        self.0
            .iter()
            .filter(|(_, r)| *r != GroupRate::Frozen)
            .map(|(n, _)| n.as_str())
            .collect()
    }

    /// Checks the table against a model's group names `names`: each named once, none unknown,
    /// none missing, every rate finite and above 0. The error names every group at fault and
    /// the flag that sets it.
    pub fn check(&self, names: &[&str]) -> Result<(), StylizeError> {
        let set_with = "--set learning_rates.NAME=VALUE, or a `learning_rates` object in the \
                        configuration file";
        let mut problems = Vec::new();
        let unknown: Vec<&str> = self
            .0
            .iter()
            .map(|(n, _)| n.as_str())
            .filter(|n| !names.contains(n))
            .collect();
        if !unknown.is_empty() {
            problems.push(format!(
                "no parameter group {} in this model",
                unknown.join(", ")
            ));
        }
        let missing: Vec<&str> = names
            .iter()
            .copied()
            .filter(|n| self.get(n).is_none())
            .collect();
        if !missing.is_empty() {
            problems.push(format!("no rate for {}", missing.join(", ")));
        }
        for (name, rate) in &self.0 {
            if self.0.iter().filter(|(n, _)| n == name).count() > 1 {
                problems.push(format!("{name} is given twice"));
            } else if let Some(why) = rate.problem() {
                problems.push(format!("{name}: {why}"));
            }
        }
        if problems.is_empty() {
            Ok(())
        } else {
            problems.dedup();
            Err(StylizeError::Config(format!(
                "{FIELD}: {} (the model's groups: {}; set them with {set_with})",
                problems.join("; "),
                names.join(", ")
            )))
        }
    }

    /// The optimizer groups of a model whose groups are `names`, in that order, for a scene
    /// of size `extent` (world units; it scales the decays marked `times_extent`). Errors as
    /// [`GroupRates::check`].
    pub fn optimizer_groups(
        &self,
        names: &[String],
        extent: f64,
    ) -> Result<Vec<GroupConfig>, StylizeError> {
        let borrowed: Vec<&str> = names.iter().map(String::as_str).collect();
        self.check(&borrowed)?;
        let groups = self
            .0
            .iter()
            .map(|(name, rate)| rate.group(name, extent))
            .collect();
        groups_in_model_order(groups, names)
            .map_err(|e| StylizeError::Config(format!("{FIELD}: {e}")))
    }
}

impl Serialize for GroupRates {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut map = s.serialize_map(Some(self.0.len()))?;
        for (name, rate) in &self.0 {
            map.serialize_entry(name, &rate.to_json())?;
        }
        map.end()
    }
}

impl<'de> Deserialize<'de> for GroupRates {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct InOrder;
        impl<'de> Visitor<'de> for InOrder {
            type Value = GroupRates;

            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("an object of parameter-group names and their rates")
            }

            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<GroupRates, A::Error> {
                let mut entries: Vec<(String, GroupRate)> = Vec::new();
                while let Some((name, value)) = map.next_entry::<String, Value>()? {
                    if entries.iter().any(|(n, _)| *n == name) {
                        return Err(A::Error::custom(format!("{name} is given twice")));
                    }
                    let rate = GroupRate::from_json(&value)
                        .map_err(|why| A::Error::custom(format!("{name}: {why}")))?;
                    entries.push((name, rate));
                }
                Ok(GroupRates(entries))
            }
        }
        d.deserialize_map(InOrder)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const NAMES: [&str; 3] = ["means", "scales", "colours"];

    fn table() -> GroupRates {
        GroupRates::new([
            (
                "means",
                GroupRate::Decay {
                    start: 1e-4,
                    end: 1e-6,
                    steps: 100,
                    times_extent: true,
                },
            ),
            ("scales", GroupRate::Frozen),
            ("colours", GroupRate::Constant(0.01)),
        ])
    }

    fn names(list: &[&str]) -> Vec<String> {
        list.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn the_table_round_trips_through_json_in_its_order() {
        let text = serde_json::to_string(&table()).unwrap();
        assert_eq!(
            text,
            r#"{"means":{"end":1e-6,"start":0.0001,"steps":100,"times_extent":true},"scales":"frozen","colours":0.01}"#
        );
        let back: GroupRates = serde_json::from_str(&text).unwrap();
        assert_eq!(back, table());
        let short: GroupRates =
            serde_json::from_str(r#"{"means": {"start": 2, "end": 1, "steps": 3}}"#).unwrap();
        assert_eq!(
            short.get("means"),
            Some(&GroupRate::Decay {
                start: 2.0,
                end: 1.0,
                steps: 3,
                times_extent: false
            })
        );
    }

    #[test]
    fn bad_values_are_refused_naming_the_group() {
        for (text, want) in [
            (r#"{"means": "slow"}"#, "means: \"slow\" is not a number"),
            (
                r#"{"means": {"start": 1, "end": 1}}"#,
                "needs a whole number of `steps`",
            ),
            (
                r#"{"means": {"start": 1, "end": 1, "steps": 2, "rate": 3}}"#,
                "unknown key(s) rate",
            ),
            (r#"{"means": 1, "means": 2}"#, "means is given twice"),
        ] {
            let e = serde_json::from_str::<GroupRates>(text)
                .unwrap_err()
                .to_string();
            assert!(e.contains(want), "{text}: {e}");
        }
    }

    /// The groups come out in the model's order whatever the table's, each with its own rate.
    #[test]
    fn a_table_in_another_order_gives_each_group_its_own_rate() {
        let mut reversed = GroupRates::default();
        for (name, rate) in table().0.into_iter().rev() {
            reversed.set(&name, rate);
        }
        let model = names(&NAMES);
        let want = table().optimizer_groups(&model, 2.0).unwrap();
        assert_eq!(reversed.optimizer_groups(&model, 2.0).unwrap(), want);
        let by_name: Vec<&str> = want.iter().map(|g| g.name.as_str()).collect();
        assert_eq!(by_name, NAMES);
        assert!((want[0].schedule.at(0) - 2e-4).abs() < 1e-15);
        assert!((want[0].schedule.at(100) - 2e-6).abs() < 1e-15);
        assert!(want[1].frozen && !want[2].frozen);
        assert_eq!(want[2].schedule.at(7), 0.01);
        assert_eq!(table().trained(), ["means", "colours"]);
    }

    #[test]
    fn the_plain_gaussian_table_names_every_group_of_plain_gaussians() {
        let table = gaussian_stylization(0.01);
        table.check(&gs_core::gaussians::PARAM_NAMES).unwrap();
        let groups = table
            .optimizer_groups(&names(&gs_core::gaussians::PARAM_NAMES), 2.0)
            .unwrap();
        assert!((groups[0].schedule.at(0) - 2e-4).abs() < 1e-15);
        assert!((groups[0].schedule.at(30_000) - 2e-6).abs() < 1e-15);
        let constant: Vec<f64> = groups[1..].iter().map(|g| g.schedule.at(123)).collect();
        assert_eq!(constant, vec![0.005, 0.001, 0.05, 0.01, 0.0005]);
        assert!(groups.iter().all(|g| !g.frozen));
    }

    #[test]
    fn unknown_missing_and_unusable_rates_are_named_with_the_flag() {
        let mut t = table();
        t.set("colors", GroupRate::Constant(0.1));
        t.set("scales", GroupRate::Constant(0.0));
        let e = t
            .optimizer_groups(&names(&["means", "scales", "colours", "opacities"]), 1.0)
            .unwrap_err()
            .to_string();
        for part in [
            "learning_rates: no parameter group colors",
            "no rate for opacities",
            "scales: 0 must be finite and > 0",
            "--set learning_rates.NAME=VALUE",
            "the model's groups: means, scales, colours, opacities",
        ] {
            assert!(e.contains(part), "{part} in {e}");
        }
        let mut t = table();
        t.set(
            "means",
            GroupRate::Decay {
                start: f64::NAN,
                end: 1.0,
                steps: 1,
                times_extent: false,
            },
        );
        assert!(t
            .check(&NAMES)
            .unwrap_err()
            .to_string()
            .contains("means: start NaN"));
    }
}
