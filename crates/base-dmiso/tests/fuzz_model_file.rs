//! The 4D model reader against mutations of a saved model (header, metadata, tensors), through
//! gs-core's fuzz harness: no panic, no allocation over its bound, errors naming the file.

#[path = "../../gs-core/tests/fuzz/mod.rs"]
mod fuzz;

use base_dmiso::deform_net::NetShape;
use candle_core::Device;
use fuzz::{fuzz, Counting};

#[global_allocator]
static ALLOCATOR: Counting = Counting;

#[test]
fn the_4d_model_reader_survives_mutated_files() {
    let dir = tempfile::tempdir().unwrap();
    let model = base_dmiso::init::initial_model(6, NetShape { width: 4 }, 1, &Device::Cpu).unwrap();
    let path = dir.path().join("model.safetensors");
    base_dmiso::model_file::save(&model, &path, None).unwrap();
    let valid = std::fs::read(&path).unwrap();
    let refused = fuzz("model.safetensors", &valid, 12, |path| {
        base_dmiso::model_file::load(path, &Device::Cpu)
            .map(|_| ())
            .map_err(|e| e.to_string())
    });
    assert!(refused > 0);
}
