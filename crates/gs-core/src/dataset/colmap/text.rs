//! COLMAP's text model files (`cameras.txt`, `images.txt`, `points3D.txt`); `#` starts a
//! comment line.

use std::path::Path;
use std::str::FromStr;

use super::{param_count, ColmapCamera, ColmapImage, DatasetError, PointCloud};

fn format_error(path: &Path, line: usize, message: String) -> DatasetError {
    DatasetError::Format {
        path: path.to_path_buf(),
        message: format!("line {line}: {message}"),
    }
}

/// Token `i` of a line parsed as `T`, with the field's name in the error.
fn field<T: FromStr>(tokens: &[&str], i: usize, name: &str) -> Result<T, String> {
    let token = tokens
        .get(i)
        .ok_or_else(|| format!("{name} is missing (field {})", i + 1))?;
    token
        .parse()
        .map_err(|_| format!("{name} is {token:?}, not a number of the right kind"))
}

/// The data lines: (1-based line number, whitespace-separated tokens), comments and blank
/// lines left out.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, Vec<&str>)> {
    text.lines().enumerate().filter_map(|(i, line)| {
        let t = line.trim();
        (!t.is_empty() && !t.starts_with('#')).then(|| (i + 1, t.split_whitespace().collect()))
    })
}

/// Parses `cameras.txt`: `CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`.
pub(super) fn cameras(path: &Path, text: &str) -> Result<Vec<ColmapCamera>, DatasetError> {
    let mut out: Vec<ColmapCamera> = Vec::new();
    let mut seen = std::collections::HashSet::new();
    for (line, tokens) in data_lines(text) {
        let parse = || -> Result<ColmapCamera, String> {
            let model = tokens.get(1).ok_or("MODEL is missing")?.to_string();
            let count = param_count(&model)
                .ok_or_else(|| format!("{model:?} is not a COLMAP camera model"))?;
            if tokens.len() != 4 + count {
                return Err(format!(
                    "{model} has {count} parameters, the line has {}",
                    tokens.len().saturating_sub(4)
                ));
            }
            Ok(ColmapCamera {
                id: field(&tokens, 0, "CAMERA_ID")?,
                model,
                width: field(&tokens, 2, "WIDTH")?,
                height: field(&tokens, 3, "HEIGHT")?,
                params: (4..4 + count)
                    .map(|i| field(&tokens, i, "PARAMS"))
                    .collect::<Result<_, _>>()?,
            })
        };
        let camera = parse().map_err(|m| format_error(path, line, m))?;
        if !seen.insert(camera.id) {
            return Err(format_error(
                path,
                line,
                format!("camera {} appears twice", camera.id),
            ));
        }
        out.push(camera);
    }
    Ok(out)
}

/// Parses `images.txt`: two lines per image, `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`
/// then the 2D points (possibly an empty line), which are not used.
pub(super) fn images(path: &Path, text: &str) -> Result<Vec<ColmapImage>, DatasetError> {
    let mut out = Vec::new();
    let mut lines = text.lines().enumerate();
    while let Some((i, raw)) = lines.next() {
        let t = raw.trim();
        if t.is_empty() || t.starts_with('#') {
            continue;
        }
        let tokens: Vec<&str> = t.split_whitespace().collect();
        let parse = || -> Result<ColmapImage, String> {
            let num = |k: usize, name: &str| field::<f64>(&tokens, k, name);
            if tokens.len() < 10 {
                return Err(format!("{} fields, at least 10 expected", tokens.len()));
            }
            Ok(ColmapImage {
                id: field(&tokens, 0, "IMAGE_ID")?,
                qvec: [num(1, "QW")?, num(2, "QX")?, num(3, "QY")?, num(4, "QZ")?],
                tvec: [num(5, "TX")?, num(6, "TY")?, num(7, "TZ")?],
                camera_id: field(&tokens, 8, "CAMERA_ID")?,
                name: tokens[9..].join(" "),
            })
        };
        out.push(parse().map_err(|m| format_error(path, i + 1, m))?);
        if let Some((j, points)) = lines.next() {
            check_points2d(points).map_err(|m| format_error(path, j + 1, m))?;
        }
    }
    Ok(out)
}

/// Checks that `line`, the line after an image's, is its `POINTS2D[] as (X, Y, POINT3D_ID)`
/// (empty for none): a file written without these lines would otherwise lose every other
/// image silently.
fn check_points2d(line: &str) -> Result<(), String> {
    let tokens: Vec<&str> = line.split_whitespace().collect();
    let triplets = tokens.len().is_multiple_of(3)
        && tokens.chunks_exact(3).all(|t| {
            t[0].parse::<f64>().is_ok()
                && t[1].parse::<f64>().is_ok()
                && t[2].parse::<i64>().is_ok()
        });
    if triplets {
        Ok(())
    } else {
        Err(format!(
            "{:?} is not a POINTS2D line (X Y POINT3D_ID triplets); images.txt gives every image \
             two lines, the second its 2D points (empty for none)",
            line.chars().take(60).collect::<String>()
        ))
    }
}

/// Parses `points3D.txt`: `POINT3D_ID X Y Z R G B ERROR TRACK[]`.
pub(super) fn points(path: &Path, text: &str) -> Result<PointCloud, DatasetError> {
    let mut cloud = PointCloud::default();
    for (line, tokens) in data_lines(text) {
        let parse = || -> Result<([f64; 3], [u8; 3]), String> {
            let xyz: [f64; 3] = [
                field(&tokens, 1, "X")?,
                field(&tokens, 2, "Y")?,
                field(&tokens, 3, "Z")?,
            ];
            if !xyz.iter().all(|v| v.is_finite()) {
                return Err(format!("position {xyz:?} is not finite"));
            }
            let rgb = [
                field(&tokens, 4, "R")?,
                field(&tokens, 5, "G")?,
                field(&tokens, 6, "B")?,
            ];
            Ok((xyz, rgb))
        };
        let (xyz, rgb) = parse().map_err(|m| format_error(path, line, m))?;
        cloud.positions.push(xyz);
        cloud.colors.push(rgb);
    }
    Ok(cloud)
}
