//! The VeGaS model reader against mutations of a model in the authors' layout, through
//! gs-core's fuzz harness: no panic, no allocation over its bound, errors naming the file.

#[path = "../../gs-core/tests/fuzz/mod.rs"]
mod fuzz;

use std::path::Path;

use fuzz::{fuzz, Counting};

#[global_allocator]
static ALLOCATOR: Counting = Counting;

#[test]
fn the_vegas_reader_survives_mutated_files() {
    let valid =
        std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/vegas_model.ply"))
            .unwrap();
    let refused = fuzz("vegas_model.ply", &valid, 11, |path| {
        base_vegas::model_file::read_model(path)
            .map(|_| ())
            .map_err(|e| e.to_string())
    });
    assert!(refused > 0);
}
