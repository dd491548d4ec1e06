//! Background colours as a user writes them: `white`, `black` or `R,G,B` with channels in
//! `[0, 1]`, the same on the command line (`--background`), in `--set background=...` and in
//! configuration files (which also take a JSON array `[r, g, b]`, the form written back).

use std::fmt;

use serde::de::{self, Deserializer, SeqAccess, Visitor};

/// Parses `white`, `black` or `R,G,B` (channels in `[0, 1]`) into linear RGB.
pub fn parse_background(text: &str) -> Result<[f32; 3], String> {
    match text.trim() {
        "white" => return Ok([1.0; 3]),
        "black" => return Ok([0.0; 3]),
        _ => {}
    }
    let parts: Vec<&str> = text.split(',').collect();
    let bad = || format!("{text:?} is not white, black or R,G,B with channels in [0, 1]");
    if parts.len() != 3 {
        return Err(bad());
    }
    let mut rgb = [0.0f32; 3];
    for (c, p) in rgb.iter_mut().zip(parts) {
        *c = p.trim().parse().map_err(|_| bad())?;
        if !(0.0..=1.0).contains(c) {
            return Err(bad());
        }
    }
    Ok(rgb)
}

/// Deserializes a background written as [`parse_background`] reads it or as an array
/// `[r, g, b]` with channels in `[0, 1]` (for `#[serde(deserialize_with = ...)]`).
pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<[f32; 3], D::Error> {
    d.deserialize_any(BackgroundVisitor)
}

/// [`deserialize`] of an optional background: `null` is none.
pub fn deserialize_optional<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f32; 3]>, D::Error> {
    d.deserialize_option(OptionalBackgroundVisitor)
}

/// The serde visitor of [`deserialize_optional`].
struct OptionalBackgroundVisitor;

impl<'de> Visitor<'de> for OptionalBackgroundVisitor {
    type Value = Option<[f32; 3]>;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("null, white, black, \"R,G,B\" or [r, g, b] with channels in [0, 1]")
    }

    fn visit_none<E: de::Error>(self) -> Result<Self::Value, E> {
        Ok(None)
    }

    fn visit_unit<E: de::Error>(self) -> Result<Self::Value, E> {
        Ok(None)
    }

    fn visit_some<D: Deserializer<'de>>(self, d: D) -> Result<Self::Value, D::Error> {
        deserialize(d).map(Some)
    }
}

/// The serde visitor of [`deserialize`].
struct BackgroundVisitor;

impl<'de> Visitor<'de> for BackgroundVisitor {
    type Value = [f32; 3];

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("white, black, \"R,G,B\" or [r, g, b] with channels in [0, 1]")
    }

    fn visit_str<E: de::Error>(self, text: &str) -> Result<[f32; 3], E> {
        parse_background(text).map_err(E::custom)
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<[f32; 3], A::Error> {
        let mut rgb = [0.0f32; 3];
        for (i, c) in rgb.iter_mut().enumerate() {
            *c = seq
                .next_element()?
                .ok_or_else(|| de::Error::invalid_length(i, &self))?;
        }
        if seq.next_element::<de::IgnoredAny>()?.is_some() {
            return Err(de::Error::invalid_length(4, &self));
        }
        if rgb.iter().any(|c| !(0.0..=1.0).contains(c)) {
            return Err(de::Error::custom(format!(
                "{rgb:?} is not a colour with channels in [0, 1]"
            )));
        }
        Ok(rgb)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(serde::Deserialize)]
    struct Holder {
        #[serde(deserialize_with = "deserialize")]
        background: [f32; 3],
    }

    fn read(json: &str) -> Result<[f32; 3], String> {
        serde_json::from_str::<Holder>(json)
            .map(|h| h.background)
            .map_err(|e| e.to_string())
    }

    #[test]
    fn names_triples_and_arrays_are_read_alike() {
        assert_eq!(read(r#"{"background": "white"}"#), Ok([1.0; 3]));
        assert_eq!(read(r#"{"background": "0.5, 0, 1"}"#), Ok([0.5, 0.0, 1.0]));
        assert_eq!(
            read(r#"{"background": [0, 0.25, 1]}"#),
            Ok([0.0, 0.25, 1.0])
        );
        let e = read(r#"{"background": "grey"}"#).unwrap_err();
        assert!(e.contains("\"grey\" is not white, black or R,G,B"), "{e}");
        assert!(read(r#"{"background": [1, 1]}"#).is_err());
        assert!(read(r#"{"background": [1, 1, 1, 1]}"#).is_err());
        let e = read(r#"{"background": [0, 1.5, 0]}"#).unwrap_err();
        assert!(e.contains("channels in [0, 1]"), "{e}");
        assert!(parse_background("1,1,2").is_err());
    }

    #[derive(serde::Deserialize)]
    struct OptionalHolder {
        #[serde(default, deserialize_with = "deserialize_optional")]
        background: Option<[f32; 3]>,
    }

    #[test]
    fn an_optional_background_is_none_when_null_or_absent() {
        let read = |json: &str| {
            serde_json::from_str::<OptionalHolder>(json)
                .map(|h| h.background)
                .map_err(|e| e.to_string())
        };
        assert_eq!(read(r#"{"background": null}"#), Ok(None));
        assert_eq!(read("{}"), Ok(None));
        assert_eq!(read(r#"{"background": "black"}"#), Ok(Some([0.0; 3])));
        assert_eq!(
            read(r#"{"background": [0.25, 0.5, 1]}"#),
            Ok(Some([0.25, 0.5, 1.0]))
        );
        assert!(read(r#"{"background": "pink"}"#).is_err());
    }
}
