//! MiraGe model files (INRIA PLY of flat Gaussians): reading one checks that it holds a 2D
//! model, writing one records the picture it was fitted to, and [`check_fits_picture`] checks
//! a model against the picture of a run.
//!
//! How a model relates to its picture: the front camera frames a rectangle of the plane `y = 0`
//! whose half width is `d tan(FOV_X / 2)` whatever the picture's size, and whose half height
//! follows from the picture's aspect ratio ([`crate::mirror::plane_half_size`]). So a model
//! covers every picture of the same aspect ratio and camera distance: at another resolution it
//! is trained and rendered at the new one, with Gaussians sized for the old one (legitimate,
//! with a warning). A picture of another aspect ratio (or another camera distance) would see
//! the model cropped or padded: an error naming both sizes.
//!
//! The record is a header comment, `clipgaussian-2d picture WxH distance D`. A file without it
//! (MiraGe's own, or an older one) is checked by the aspect ratio of the rectangle its
//! Gaussians cover. A 2D model has the flat axis MiraGe stores (`scale_0 = ln 1e-8`) on every
//! Gaussian, and its Gaussians lie near the plane; a 3D scene's PLY has neither and is refused.

use std::path::Path;

use gs_core::ply::{read_ply, write_ply, PlyFormat, PlyGaussians};

use crate::flat::{FlatGaussians, FLAT_SCALE};
use crate::mirror::plane_half_size;
use crate::stylize::{PictureFailure, PictureStylizeError};

/// The start of the header comment that records the picture.
const RECORD_PREFIX: &str = "clipgaussian-2d picture";

/// Two aspect ratios (width / height) closer than this, relative, are the same.
const SAME_ASPECT: f64 = 0.01;

/// For a model without a record: the aspect ratio of its Gaussians' rectangle may be off by
/// this much, relative (fitting moves the border Gaussians a little; 3 % was measured).
const INFERRED_ASPECT: f64 = 0.1;

/// Fewer Gaussians than this say too little about the rectangle they cover.
const MIN_GAUSSIANS_TO_INFER: usize = 64;

/// The picture a model was fitted to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FittedTo {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// The camera distance of the fit, world units.
    pub distance: f64,
}

impl FittedTo {
    /// The header comment that records it.
    fn comment(&self) -> String {
        format!(
            "{RECORD_PREFIX} {}x{} distance {}",
            self.width, self.height, self.distance
        )
    }

    /// The record in `comment`, if it is one with a size and a distance.
    fn parse(comment: &str) -> Option<Self> {
        let rest = comment.strip_prefix(RECORD_PREFIX)?;
        let mut words = rest.split_whitespace();
        let (w, h) = words.next()?.split_once('x')?;
        let distance = match (words.next(), words.next()) {
            (Some("distance"), Some(d)) => d.parse().ok()?,
            _ => return None,
        };
        let record = Self {
            width: w.parse().ok()?,
            height: h.parse().ok()?,
            distance,
        };
        // A hand-edited record of no size or distance says nothing (its aspect would be NaN).
        let usable =
            record.width > 0 && record.height > 0 && distance > 0.0 && distance.is_finite();
        usable.then_some(record)
    }
}

/// A model read from a file, with the picture it was fitted to when the file records it.
#[derive(Clone, Debug)]
pub struct ModelFile {
    /// The model.
    pub model: FlatGaussians,
    /// The picture it was fitted to (none in files that do not record it).
    pub fitted_to: Option<FittedTo>,
}

/// The error of a model file that is not what it must be.
fn refused(path: &Path, reason: String) -> PictureStylizeError {
    PictureStylizeError::ModelMismatch {
        path: path.to_path_buf(),
        reason,
    }
}

/// Reads a MiraGe model file, refusing one that does not hold a 2D model (see the module
/// documentation).
pub fn read_model(path: &Path) -> Result<ModelFile, PictureStylizeError> {
    let ply = read_ply(path).map_err(|source| {
        PictureStylizeError::Own(PictureFailure::Model {
            path: path.to_path_buf(),
            source,
        })
    })?;
    check_flat(&ply).map_err(|reason| refused(path, reason))?;
    let fitted_to = ply.comments.iter().find_map(|c| FittedTo::parse(c));
    Ok(ModelFile {
        model: FlatGaussians::new(ply.gaussians),
        fitted_to,
    })
}

/// Writes flat Gaussians as a MiraGe PLY (binary little-endian, `scale_0 = ln 1e-8`) that
/// records `fitted_to`.
pub fn write_model(
    path: &Path,
    model: &FlatGaussians,
    fitted_to: &FittedTo,
) -> Result<(), PictureStylizeError> {
    let mut ply = PlyGaussians::new(model.params().clone());
    ply.comments.push(fitted_to.comment());
    write_ply(path, &ply, PlyFormat::BinaryLittleEndian).map_err(|source| {
        PictureStylizeError::Own(PictureFailure::Model {
            path: path.to_path_buf(),
            source,
        })
    })
}

/// Checks that the Gaussians of `ply` are those of a 2D model: every one with the flat axis,
/// none farther from the plane `y = 0` than the half width of the picture's rectangle at
/// camera distance 1. The error says what is wrong.
fn check_flat(ply: &PlyGaussians) -> Result<(), String> {
    let g = &ply.gaussians;
    let flat = (FLAT_SCALE.ln()) as f32;
    let round = g
        .log_scales
        .chunks_exact(3)
        .map(|s| s[0])
        .filter(|s0| (s0 - flat).abs() > 1e-3)
        .collect::<Vec<f32>>();
    let depth = g
        .means
        .chunks_exact(3)
        .map(|m| m[1].abs())
        .fold(0.0f32, f32::max);
    let (half_width, _) = plane_half_size(1, 1, 1.0);
    let mut problems = Vec::new();
    if !round.is_empty() {
        let (lo, hi) = round
            .iter()
            .fold((f32::MAX, f32::MIN), |(lo, hi), &s| (lo.min(s), hi.max(s)));
        problems.push(format!(
            "{} of its {} Gaussians have no flat axis (scale_0 from {lo:.2} to {hi:.2}; a 2D \
             model stores ln 1e-8 = {flat:.2})",
            round.len(),
            g.len()
        ));
    }
    if f64::from(depth) > half_width {
        problems.push(format!(
            "its Gaussians lie up to {depth:.2} off the picture plane y = 0 (a 2D model's stay \
             well within {half_width:.2})"
        ));
    }
    if problems.is_empty() {
        Ok(())
    } else {
        Err(format!(
            "not a 2D model: {}. It looks like a 3D scene (use clipgaussian-3d for those); a \
             2D model is the model.ply of clipgaussian-2d fit or stylize",
            problems.join("; ")
        ))
    }
}

/// Checks the model read from `path` against a run's picture of `width x height` pixels
/// (named `label`) at camera distance `distance` (see the module documentation). Returns a
/// warning to show when only the resolution differs.
pub fn check_fits_picture(
    path: &Path,
    file: &ModelFile,
    width: u32,
    height: u32,
    distance: f64,
    label: &str,
) -> Result<Option<String>, PictureStylizeError> {
    let aspect = |w: f64, h: f64| w / h;
    let picture = aspect(f64::from(width), f64::from(height));
    let differs = |a: f64, tolerance: f64| (a / picture - 1.0).abs() > tolerance;
    match &file.fitted_to {
        Some(f) => {
            let (fw, fh) = (f.width, f.height);
            if differs(aspect(f64::from(fw), f64::from(fh)), SAME_ASPECT) {
                return Err(refused(
                    path,
                    format!(
                        "it was fitted to a {fw}x{fh} picture and {label} is {width}x{height}, \
                         another aspect ratio ({:.3} against {picture:.3}): the model covers \
                         another rectangle of the picture plane; fit this picture instead \
                         (leave out --model)",
                        aspect(f64::from(fw), f64::from(fh))
                    ),
                ));
            }
            if (f.distance - distance).abs() > 1e-9 * distance.max(1.0) {
                return Err(refused(
                    path,
                    format!(
                        "it was fitted with the cameras at distance {} and this run puts them \
                         at {distance}; set distance to {} (--set distance={})",
                        f.distance, f.distance, f.distance
                    ),
                ));
            }
            Ok(((fw, fh) != (width, height)).then(|| {
                format!(
                    "model {} was fitted to a {fw}x{fh} picture and {label} is \
                     {width}x{height} (the same aspect ratio): it is trained and rendered at \
                     {width}x{height} with Gaussians sized for {fw}x{fh}",
                    path.display()
                )
            }))
        }
        None => {
            let Some(covered) = covered_aspect(file.model.params().means.as_slice()) else {
                return Ok(None);
            };
            if differs(covered, INFERRED_ASPECT) {
                let (hw, hh) = plane_half_size(width, height, distance);
                return Err(refused(
                    path,
                    format!(
                        "its Gaussians cover a rectangle of aspect ratio about {covered:.2} \
                         (width / height) and {label} is {width}x{height} ({picture:.2}, a \
                         rectangle of {:.3} x {:.3} at distance {distance}): it was fitted to \
                         a picture of another shape; fit this picture instead (leave out \
                         --model)",
                        2.0 * hw,
                        2.0 * hh
                    ),
                ));
            }
            Ok(None)
        }
    }
}

impl ModelFile {
    /// The size of the picture the model records, when it records one of no more pixels than
    /// a picture read may have ([`gs_core::image::MAX_PICTURE_PIXELS`]).
    pub fn picture_size(&self) -> Option<(u32, u32)> {
        let f = self.fitted_to?;
        (u64::from(f.width) * u64::from(f.height) <= gs_core::image::MAX_PICTURE_PIXELS)
            .then_some((f.width, f.height))
    }
}

/// The aspect ratio (x extent / z extent) of the rectangle the means `[N, 3]` cover, from
/// their 0.5 % and 99.5 % quantiles; `None` for too few Gaussians or a degenerate extent.
fn covered_aspect(means: &[f32]) -> Option<f64> {
    let n = means.len() / 3;
    if n < MIN_GAUSSIANS_TO_INFER {
        return None;
    }
    let extent = |axis: usize| {
        let mut v: Vec<f32> = means.chunks_exact(3).map(|m| m[axis]).collect();
        v.sort_by(f32::total_cmp);
        let at = |q: f64| f64::from(v[(q * (n - 1) as f64).round() as usize]);
        at(0.995) - at(0.005)
    };
    let (x, z) = (extent(0), extent(2));
    (x > 0.0 && z > 0.0).then(|| x / z)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::init::initial_gaussians;

    #[test]
    fn the_record_round_trips_and_other_comments_are_ignored() {
        let f = FittedTo {
            width: 40,
            height: 32,
            distance: 1.5,
        };
        assert_eq!(FittedTo::parse(&f.comment()), Some(f));
        assert_eq!(FittedTo::parse("made by hand"), None);
        for empty in ["0x0", "40x0", "0x30"] {
            let comment = format!("{RECORD_PREFIX}{empty} distance 1");
            assert_eq!(FittedTo::parse(&comment), None, "{comment}");
        }
        let nowhere = format!("{RECORD_PREFIX}40x30 distance 0");
        assert_eq!(FittedTo::parse(&nowhere), None);
    }

    #[test]
    fn models_are_checked_against_the_picture_by_aspect_ratio() {
        let (hw, hh) = plane_half_size(160, 90, 1.0);
        let model = initial_gaussians(500, 0, hw, hh, 1);
        let path = Path::new("m.ply");
        let recorded = |width, height| ModelFile {
            model: model.clone(),
            fitted_to: Some(FittedTo {
                width,
                height,
                distance: 1.0,
            }),
        };
        let check = |file: &ModelFile, w, h| check_fits_picture(path, file, w, h, 1.0, "p.png");
        assert_eq!(check(&recorded(160, 90), 160, 90).unwrap(), None);
        let warning = check(&recorded(160, 90), 320, 180).unwrap().unwrap();
        assert!(
            warning.contains("160x90") && warning.contains("320x180"),
            "{warning}"
        );
        let e = check(&recorded(160, 90), 90, 90).unwrap_err().to_string();
        assert!(e.contains("160x90") && e.contains("90x90"), "{e}");
        let e = check_fits_picture(path, &recorded(160, 90), 160, 90, 2.0, "p.png")
            .unwrap_err()
            .to_string();
        assert!(e.contains("distance"), "{e}");

        let unrecorded = ModelFile {
            model: model.clone(),
            fitted_to: None,
        };
        assert_eq!(check(&unrecorded, 320, 180).unwrap(), None);
        let e = check(&unrecorded, 100, 100).unwrap_err().to_string();
        assert!(e.contains("about 1.7") && e.contains("100x100"), "{e}");
    }
}
