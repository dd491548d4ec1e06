//! The `render --camera` reader against mutations of a camera file, through gs-core's fuzz
//! harness: no panic, no allocation over its bound, errors naming the file.

#[path = "../../gs-core/tests/fuzz/mod.rs"]
mod fuzz;

use fuzz::{fuzz, Counting};

#[global_allocator]
static ALLOCATOR: Counting = Counting;

#[test]
fn the_camera_file_reader_survives_mutated_files() {
    let valid = serde_json::json!({
        "width": 64, "height": 48, "fx": 60.0, "fy": 60.0, "cx": 32.0, "cy": 24.0,
        "world_to_camera": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]],
    })
    .to_string();
    let refused = fuzz("camera.json", valid.as_bytes(), 13, |path| {
        base_3dgs::render_views::camera_from_file(path)
            .map(|_| ())
            .map_err(|e| e.to_string())
    });
    assert!(refused > 0);
}
