//! COLMAP's binary model files, little-endian, as `read_write_model.py` defines them.

use std::path::Path;

use super::{ColmapCamera, ColmapImage, DatasetError, PointCloud, CAMERA_MODELS};

/// A cursor over a file's bytes whose errors name the file, the offset and the field.
struct Reader<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn new(path: &'a Path, bytes: &'a [u8]) -> Self {
        Self {
            path,
            bytes,
            pos: 0,
        }
    }

    fn error(&self, message: String) -> DatasetError {
        DatasetError::Format {
            path: self.path.to_path_buf(),
            message: format!("byte {}: {message}", self.pos),
        }
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], DatasetError> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.bytes.len());
        let end = end.ok_or_else(|| {
            self.error(format!(
                "truncated: {what} needs {n} bytes, {} left",
                self.bytes.len() - self.pos
            ))
        })?;
        let out = &self.bytes[self.pos..end];
        self.pos = end;
        Ok(out)
    }

    fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N], DatasetError> {
        Ok(self
            .take(N, what)?
            .try_into()
            .expect("take returns N bytes"))
    }

    fn u64(&mut self, what: &str) -> Result<u64, DatasetError> {
        Ok(u64::from_le_bytes(self.array(what)?))
    }

    fn i32(&mut self, what: &str) -> Result<i32, DatasetError> {
        Ok(i32::from_le_bytes(self.array(what)?))
    }

    fn f64(&mut self, what: &str) -> Result<f64, DatasetError> {
        Ok(f64::from_le_bytes(self.array(what)?))
    }

    fn f64s<const N: usize>(&mut self, what: &str) -> Result<[f64; N], DatasetError> {
        let mut out = [0.0; N];
        for v in &mut out {
            *v = self.f64(what)?;
        }
        Ok(out)
    }

    /// A count that must fit in memory: each counted record takes at least `min_bytes`.
    fn count(&mut self, what: &str, min_bytes: usize) -> Result<usize, DatasetError> {
        let n = self.u64(what)?;
        let left = (self.bytes.len() - self.pos) as u64;
        if n.saturating_mul(min_bytes as u64) > left {
            return Err(self.error(format!(
                "{what} is {n}, more than the {left} bytes left hold"
            )));
        }
        Ok(n as usize)
    }

    fn size(&mut self, what: &str) -> Result<u32, DatasetError> {
        let v = self.u64(what)?;
        u32::try_from(v).map_err(|_| self.error(format!("{what} {v} is too large")))
    }

    fn skip(
        &mut self,
        records: usize,
        record_bytes: usize,
        what: &str,
    ) -> Result<(), DatasetError> {
        let n = records
            .checked_mul(record_bytes)
            .ok_or_else(|| self.error(format!("{what}: {records} records is too many")))?;
        self.take(n, what).map(|_| ())
    }

    /// A NUL-terminated UTF-8 string.
    fn c_string(&mut self, what: &str) -> Result<String, DatasetError> {
        let len = self.bytes[self.pos..]
            .iter()
            .position(|&b| b == 0)
            .ok_or_else(|| self.error(format!("{what} has no terminating NUL")))?;
        let raw = self.take(len + 1, what)?;
        String::from_utf8(raw[..len].to_vec())
            .map_err(|_| self.error(format!("{what} is not UTF-8")))
    }

    fn finish(self) -> Result<(), DatasetError> {
        if self.pos == self.bytes.len() {
            Ok(())
        } else {
            Err(self.error(format!(
                "{} bytes after the last record",
                self.bytes.len() - self.pos
            )))
        }
    }
}

/// Parses `cameras.bin`: count (u64), then per camera id (i32), model id (i32), width (u64),
/// height (u64) and the model's parameters (f64).
pub(super) fn cameras(path: &Path, bytes: &[u8]) -> Result<Vec<ColmapCamera>, DatasetError> {
    let mut r = Reader::new(path, bytes);
    let n = r.count("the camera count", 24)?;
    let mut out: Vec<ColmapCamera> = Vec::with_capacity(n);
    let mut seen = std::collections::HashSet::with_capacity(n);
    for _ in 0..n {
        let id = r.i32("CAMERA_ID")? as i64;
        let model_id = r.i32("the model id")?;
        let &(model, count) = usize::try_from(model_id)
            .ok()
            .and_then(|m| CAMERA_MODELS.get(m))
            .ok_or_else(|| r.error(format!("camera {id}: model id {model_id} is unknown")))?;
        let width = r.size("WIDTH")?;
        let height = r.size("HEIGHT")?;
        let params = (0..count)
            .map(|_| r.f64("PARAMS"))
            .collect::<Result<_, _>>()?;
        if !seen.insert(id) {
            return Err(r.error(format!("camera {id} appears twice")));
        }
        out.push(ColmapCamera {
            id,
            model: model.to_string(),
            width,
            height,
            params,
        });
    }
    r.finish()?;
    Ok(out)
}

/// Parses `images.bin`: count (u64), then per image id (i32), qvec (4 f64), tvec (3 f64),
/// camera id (i32), NUL-terminated name, 2D point count (u64) and 24 bytes per 2D point.
pub(super) fn images(path: &Path, bytes: &[u8]) -> Result<Vec<ColmapImage>, DatasetError> {
    let mut r = Reader::new(path, bytes);
    let n = r.count("the image count", 73)?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let id = r.i32("IMAGE_ID")? as i64;
        let qvec = r.f64s::<4>("QVEC")?;
        let tvec = r.f64s::<3>("TVEC")?;
        let camera_id = r.i32("CAMERA_ID")? as i64;
        let name = r.c_string("NAME")?;
        let points = r.count("the 2D point count", 24)?;
        r.skip(points, 24, "POINTS2D")?;
        out.push(ColmapImage {
            id,
            qvec,
            tvec,
            camera_id,
            name,
        });
    }
    r.finish()?;
    Ok(out)
}

/// Parses `points3D.bin`: count (u64), then per point id (u64), xyz (3 f64), rgb (3 u8),
/// error (f64), track length (u64) and 8 bytes per track element.
pub(super) fn points(path: &Path, bytes: &[u8]) -> Result<PointCloud, DatasetError> {
    let mut r = Reader::new(path, bytes);
    let n = r.count("the point count", 51)?;
    let mut cloud = PointCloud {
        positions: Vec::with_capacity(n),
        colors: Vec::with_capacity(n),
    };
    for _ in 0..n {
        let id = r.u64("POINT3D_ID")?;
        let xyz = r.f64s::<3>("XYZ")?;
        if !xyz.iter().all(|v| v.is_finite()) {
            return Err(r.error(format!("point {id}: position {xyz:?} is not finite")));
        }
        let rgb = r.array::<3>("RGB")?;
        r.f64("ERROR")?;
        let track = r.count("the track length", 8)?;
        r.skip(track, 8, "TRACK")?;
        cloud.positions.push(xyz);
        cloud.colors.push(rgb);
    }
    r.finish()?;
    Ok(cloud)
}
