//! INRIA 3DGS's `cameras.json`, which its `train.py` (and gsplat's and most 3DGS trainers'
//! INRIA-layout outputs) writes beside `point_cloud/`: the training cameras of a scene, with
//! no pictures. A JSON array of one object per camera:
//!
//! ```json
//! [{"id": 0, "img_name": "r_0", "width": 800, "height": 800,
//!   "position": [0.0, 4.0, 1.0], "rotation": [[1, 0, 0], [0, 0, -1], [0, 1, 0]],
//!   "fy": 1111.1, "fx": 1111.1}]
//! ```
//!
//! `rotation` is the camera-to-world rotation, row by row, and `position` the camera centre in
//! the world (INRIA's `camera_to_JSON` writes the inverse of the world-to-camera transform,
//! in OpenCV axes: x right, y down, z forward); `fx`, `fy` are in pixels at `width` x `height`,
//! the principal point at the centre unless a fork's `cx`, `cy` say otherwise. Other fields
//! (`id`, forks' extras) are ignored.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{training_camera, DatasetError, DatasetView, LoadOptions};
use crate::model::View;
use crate::Camera;

/// The file's name in an INRIA output folder.
pub const FILE_NAME: &str = "cameras.json";

/// One camera as the file holds it, in the order INRIA's `camera_to_JSON` writes the fields.
#[derive(Deserialize, Serialize)]
struct Entry {
    #[serde(default)]
    id: usize,
    img_name: String,
    width: u32,
    height: u32,
    position: [f64; 3],
    rotation: [[f64; 3]; 3],
    fy: f64,
    fx: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    cx: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    cy: Option<f64>,
}

impl Entry {
    /// The camera the entry describes, as stored (before any downscaling).
    fn camera(&self) -> Result<Camera, crate::GsError> {
        let r = &self.rotation;
        let p = self.position;
        let mut c2w = [[0.0; 4]; 4];
        for i in 0..3 {
            c2w[i][..3].copy_from_slice(&r[i]);
            c2w[i][3] = p[i];
        }
        c2w[3][3] = 1.0;
        crate::camera::check_rigid(&c2w)?;
        // World to camera: R^T, and -R^T p.
        let rotation = [0, 1, 2].map(|i| [0, 1, 2].map(|j| r[j][i]));
        let translation = [0, 1, 2].map(|i| -(0..3).map(|j| rotation[i][j] * p[j]).sum::<f64>());
        let (w, h) = (f64::from(self.width), f64::from(self.height));
        Camera::new(
            rotation,
            translation,
            [
                self.fx,
                self.fy,
                self.cx.unwrap_or(w / 2.0),
                self.cy.unwrap_or(h / 2.0),
            ],
            self.width,
            self.height,
        )
    }
}

/// The cameras of the INRIA `cameras.json` at `path`, in the file's order, each at its
/// training size as `options` says (downscaled, or shrunk to `max_width`); each view's
/// picture is its `img_name` (no folder, no extension: the file has no pictures). An error
/// names the file and, for a camera that is not one, its entry and image.
pub fn read(path: &Path, options: &LoadOptions) -> Result<Vec<DatasetView>, DatasetError> {
    let text = std::fs::read_to_string(path).map_err(|source| DatasetError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let entries: Vec<Entry> = serde_json::from_str(&text).map_err(|source| DatasetError::Json {
        path: path.to_path_buf(),
        source,
    })?;
    if entries.is_empty() {
        return Err(DatasetError::Format {
            path: path.to_path_buf(),
            message: "holds no cameras".into(),
        });
    }
    entries
        .iter()
        .enumerate()
        .map(|(i, entry)| {
            let context = format!(
                "{}: camera {i} (img_name {:?})",
                path.display(),
                entry.img_name
            );
            let camera = entry
                .camera()
                .and_then(|full| training_camera(&full, options))
                .map_err(|source| DatasetError::Camera { context, source })?;
            Ok(DatasetView {
                view: View::still(camera),
                picture: PathBuf::from(&entry.img_name),
            })
        })
        .collect()
}

/// The `cameras.json` of the INRIA output folder a model is in, when there is one: in the
/// model's folder when the model is one (D-MiSo's output), else beside the file, or two
/// folders up (`<run>/point_cloud/iteration_N/point_cloud.ply` with `<run>/cameras.json`).
pub fn beside(model: &Path) -> Option<PathBuf> {
    if model.is_dir() {
        return Some(model.join(FILE_NAME)).filter(|p| p.is_file());
    }
    let folder = model.parent()?;
    [Some(folder), folder.parent().and_then(Path::parent)]
        .into_iter()
        .flatten()
        .map(|f| f.join(FILE_NAME))
        .find(|p| p.is_file())
}

/// Writes `cameras` (each with its picture's name, no folder or extension) as INRIA's
/// `cameras.json` to `path` (through a temporary name, then renamed). A principal point off
/// the picture's centre, which INRIA's format cannot say, is written as forks write it
/// (`cx`, `cy`), which [`read`] takes.
pub fn write(path: &Path, cameras: &[(&Camera, String)]) -> std::io::Result<()> {
    let entries: Vec<Entry> = cameras
        .iter()
        .enumerate()
        .map(|(id, (camera, name))| {
            let r = camera.rotation;
            Entry {
                id,
                img_name: name.clone(),
                width: camera.width,
                height: camera.height,
                position: camera.centre(),
                // Camera to world: the transpose of the world-to-camera rotation.
                rotation: [0, 1, 2].map(|i| [0, 1, 2].map(|j| r[j][i])),
                fy: camera.fy,
                fx: camera.fx,
                cx: (camera.cx != f64::from(camera.width) / 2.0).then_some(camera.cx),
                cy: (camera.cy != f64::from(camera.height) / 2.0).then_some(camera.cy),
            }
        })
        .collect();
    let text = serde_json::to_string(&entries).map_err(std::io::Error::other)?;
    crate::fs::write_atomic(path, text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, text: &str) -> PathBuf {
        let path = dir.join(FILE_NAME);
        std::fs::write(&path, text).unwrap();
        path
    }

    /// An entry as INRIA's `camera_to_JSON` writes it, for a camera at `centre` whose
    /// camera-to-world rotation is `r`.
    fn entry(name: &str, centre: [f64; 3], r: [[f64; 3]; 3]) -> String {
        format!(
            r#"{{"id": 0, "img_name": "{name}", "width": 40, "height": 30, "position": {centre:?},
               "rotation": {r:?}, "fy": 50.0, "fx": 52.0}}"#
        )
    }

    #[test]
    fn written_cameras_read_back_as_they_were() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(FILE_NAME);
        let a = Camera::look_at([0.3, 4.0, 1.0], [0.0; 3], [0.0, 0.0, 1.0], 0.9, 40, 30).unwrap();
        let mut b = Camera::look_at(
            [-2.0, 1.0, 0.5],
            [0.1, 0.2, 0.0],
            [0.0, 0.0, 1.0],
            1.1,
            33,
            21,
        )
        .unwrap();
        b.cx = 15.25;
        super::write(&path, &[(&a, "r_0".into()), (&b, "r_1".into())]).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(
            text.contains("\"img_name\":\"r_0\"") && text.contains("\"cx\":15.25"),
            "{text}"
        );
        assert_eq!(
            text.matches("\"cx\"").count(),
            1,
            "a centred point is not written"
        );
        let read = read(
            &path,
            &LoadOptions {
                max_width: 0,
                ..LoadOptions::default()
            },
        )
        .unwrap();
        for (view, (camera, name)) in read.iter().zip([(&a, "r_0"), (&b, "r_1")]) {
            let c = &view.view.camera;
            assert_eq!(view.picture, PathBuf::from(name));
            for i in 0..3 {
                assert!((c.translation[i] - camera.translation[i]).abs() < 1e-12);
                for j in 0..3 {
                    assert!((c.rotation[i][j] - camera.rotation[i][j]).abs() < 1e-12);
                }
            }
            assert_eq!(
                (c.fx, c.fy, c.cx, c.cy),
                (camera.fx, camera.fy, camera.cx, camera.cy)
            );
            assert_eq!((c.width, c.height), (camera.width, camera.height));
        }
    }

    #[test]
    fn the_pose_is_the_inverse_of_the_stored_camera_to_world() {
        let dir = tempfile::tempdir().unwrap();
        // Looking down -y from (0, 4, 0): camera x = world x, camera y = world z, z = -y.
        let r = [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]];
        let path = write(
            dir.path(),
            &format!("[{}]", entry("r_0", [0.0, 4.0, 0.0], r)),
        );
        let views = read(&path, &LoadOptions::default()).unwrap();
        let camera = &views[0].view.camera;
        assert_eq!(views[0].picture, PathBuf::from("r_0"));
        let c = camera.centre();
        assert!((c[0]).abs() < 1e-12 && (c[1] - 4.0).abs() < 1e-12 && c[2].abs() < 1e-12);
        // The world origin is 4 ahead, at the principal point; world +x is to the right.
        let ([x, y], depth) = camera.project([0.0, 0.0, 0.0]).unwrap();
        assert!((depth - 4.0).abs() < 1e-12 && (x - 20.0).abs() < 1e-9 && (y - 15.0).abs() < 1e-9);
        let ([x, _], _) = camera.project([1.0, 0.0, 0.0]).unwrap();
        assert!((x - (20.0 + 52.0 / 4.0)).abs() < 1e-9, "{x}");
        // World +z is camera +y: down in the picture.
        let ([_, y], _) = camera.project([0.0, 0.0, 1.0]).unwrap();
        assert!((y - (15.0 + 50.0 / 4.0)).abs() < 1e-9, "{y}");
    }

    #[test]
    fn bad_files_and_entries_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let ok = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let skew = [[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let cases = [
            ("[]".to_string(), "no cameras"),
            ("{}".to_string(), "cameras.json"),
            (
                format!(
                    "[{}, {}]",
                    entry("a", [0.0; 3], ok),
                    entry("b", [0.0; 3], skew)
                ),
                "camera 1 (img_name \"b\")",
            ),
            (
                format!("[{}]", entry("a", [0.0; 3], ok)).replace("52.0", "-1.0"),
                "camera 0",
            ),
            (
                format!("[{}]", entry("a", [0.0; 3], ok)).replace("\"width\": 40", "\"width\": 0"),
                "camera 0",
            ),
        ];
        for (text, said) in cases {
            let path = write(dir.path(), &text);
            let e = read(&path, &LoadOptions::default())
                .unwrap_err()
                .to_string();
            assert!(
                e.contains(said) && e.contains("cameras.json"),
                "{text}: {e}"
            );
        }
    }

    #[test]
    fn the_file_is_found_where_inria_writes_it() {
        let dir = tempfile::tempdir().unwrap();
        let iteration = dir.path().join("point_cloud/iteration_30000");
        std::fs::create_dir_all(&iteration).unwrap();
        let model = iteration.join("point_cloud.ply");
        assert_eq!(beside(&model), None);
        let cameras = write(dir.path(), "[]");
        assert_eq!(beside(&model), Some(cameras));
        let flat = dir.path().join("scene.ply");
        assert_eq!(beside(&flat), Some(dir.path().join(FILE_NAME)));
        // A model folder (D-MiSo's output) holds its own.
        assert_eq!(beside(dir.path()), Some(dir.path().join(FILE_NAME)));
        assert_eq!(beside(&iteration), None);
    }
}
