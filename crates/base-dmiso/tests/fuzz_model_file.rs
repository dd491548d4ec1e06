//! The 4D model reader against mutations of a saved model (header, metadata, tensors), through
//! gs-core's fuzz harness: no panic, no allocation over its bound, errors naming the file.

#[path = "../../gs-core/tests/fuzz/mod.rs"]
mod fuzz;

use base_dmiso::deform_net::NetShape;
use candle_core::Device;
use std::io::{Cursor, Read, Write};
use std::path::Path;

use base_dmiso::model_file::{read_authors, AuthorsFiles};
use fuzz::{fuzz, fuzz_with, mutate, Counting};
use rand::rngs::StdRng;

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

/// A copy of the authors' model folder of the `dmiso_small` fixture, and its files.
fn authors_copy() -> (tempfile::TempDir, AuthorsFiles) {
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/dmiso_small");
    let dir = tempfile::tempdir().unwrap();
    for folder in ["point_cloud", "deform", "time_net"] {
        let to = dir.path().join(folder).join("iteration_best");
        std::fs::create_dir_all(&to).unwrap();
        for entry in std::fs::read_dir(fixture.join(folder).join("iteration_best")).unwrap() {
            let entry = entry.unwrap();
            std::fs::copy(entry.path(), to.join(entry.file_name())).unwrap();
        }
    }
    let files = AuthorsFiles::find(dir.path(), Some("best")).unwrap();
    (dir, files)
}

/// The pickle (`data.pkl`) of a PyTorch zip file.
fn pickle_of(pth: &[u8]) -> Vec<u8> {
    let mut zip = zip::ZipArchive::new(Cursor::new(pth)).unwrap();
    let name = zip
        .file_names()
        .map(|n| n.unwrap().to_string())
        .find(|n| n.ends_with("/data.pkl"))
        .unwrap();
    let mut pickle = Vec::new();
    zip.by_name(&name)
        .unwrap()
        .read_to_end(&mut pickle)
        .unwrap();
    pickle
}

/// The PyTorch zip file `pth` with its pickle replaced by `pickle` (checksums made anew, so
/// the reader sees the pickle itself).
fn with_pickle(pth: &[u8], pickle: &[u8]) -> Vec<u8> {
    let mut zip = zip::ZipArchive::new(Cursor::new(pth)).unwrap();
    let mut out = zip::ZipWriter::new(Cursor::new(Vec::new()));
    let stored =
        zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    for i in 0..zip.len() {
        let mut entry = zip.by_index(i).unwrap();
        let name = entry.name().unwrap().to_string();
        let mut bytes = Vec::new();
        entry.read_to_end(&mut bytes).unwrap();
        out.start_file(&name, stored).unwrap();
        let bytes = if name.ends_with("/data.pkl") {
            pickle
        } else {
            &bytes
        };
        out.write_all(bytes).unwrap();
    }
    out.finish().unwrap().into_inner()
}

/// `read_authors` of `files` with `target` replaced by the file at `mutated`.
fn read_with(files: &AuthorsFiles, target: &Path, mutated: &Path) -> Result<(), String> {
    std::fs::copy(mutated, target).unwrap();
    read_authors(files, &Device::Cpu)
        .map(|_| ())
        .map_err(|e| e.to_string())
}

/// Mutations of each PyTorch file of the authors' layout, read through `read_authors` with
/// the other files left valid: of the whole file (a zip, so mostly refused by its
/// checksums), and of the pickle inside a zip rewritten with good checksums.
#[test]
fn the_authors_tensor_files_survive_mutations() {
    let (_dir, files) = authors_copy();
    for (target, seed) in [
        (&files.params, 21),
        (&files.deform, 22),
        (&files.time_net, 23),
    ] {
        let valid = std::fs::read(target).unwrap();
        let name = target.file_name().unwrap().to_str().unwrap();
        let read = |mutated: &Path| read_with(&files, target, mutated);
        let refused = fuzz(name, &valid, seed, read);
        assert!(refused > 0, "{name}: no mutation was refused");
        let pickle = pickle_of(&valid);
        let make = |rng: &mut StdRng| with_pickle(&valid, &mutate(&pickle, rng));
        let refused = fuzz_with(name, seed + 10, make, read);
        assert!(refused > 0, "{name}: no mutation of its pickle was refused");
        std::fs::write(target, &valid).unwrap();
    }
}

/// The pickle of `model_params.pt` with the pseudomesh's shape (5, 3, 3) and strides
/// (9, 3, 1) replaced.
fn pseudomesh_as(valid: &[u8], shape: &[u8], strides: &[u8]) -> Vec<u8> {
    let mut pickle = pickle_of(valid);
    for (from, to) in [
        (&b"K\x05K\x03K\x03\x87"[..], shape),
        (b"K\x09K\x03K\x01\x87", strides),
    ] {
        let at = pickle.windows(from.len()).position(|w| w == from).unwrap();
        pickle.splice(at..at + from.len(), to.iter().copied());
    }
    with_pickle(valid, &pickle)
}

/// The pseudomesh claiming 2^31 - 1 cores over its 45 stored values (77 GB as f32) is refused
/// naming the file, without an allocation of that size; so is one whose zero stride makes 200
/// million cores of the same 9 values (7 GB, within pytorch-reader's own limit, above the
/// file's length).
#[test]
fn a_pseudomesh_larger_than_its_file_is_refused_before_allocation() {
    let (_dir, files) = authors_copy();
    let valid = std::fs::read(&files.params).unwrap();
    let huge = b"J\xff\xff\xff\x7fK\x03K\x03\x87";
    let expanded = b"J\x00\xc2\xeb\x0bK\x03K\x03\x87";
    let zero_stride = b"K\x00K\x03K\x01\x87";
    for (shape, strides) in [
        (&huge[..], &b"K\x09K\x03K\x01\x87"[..]),
        (expanded, zero_stride),
    ] {
        std::fs::write(&files.params, pseudomesh_as(&valid, shape, strides)).unwrap();
        let held = fuzz::held();
        let e = read_authors(&files, &Device::Cpu).unwrap_err().to_string();
        assert!(fuzz::peak_since(held) < fuzz::LIMIT, "{e}");
        assert!(e.contains("model_params.pt"), "{e}");
        assert!(
            e.contains("[2147483647, 3, 3]") || e.contains("[200000000, 3, 3]"),
            "{e}"
        );
    }
}

/// A `deform.pth` whose storage type was changed from floats to bytes (`FloatStorage` to
/// `ByteStorage` in its pickle) is refused naming the tensor, not read as byte values.
#[test]
fn a_storage_changed_to_bytes_is_refused_naming_the_tensor() {
    let (_dir, files) = authors_copy();
    let valid = std::fs::read(&files.time_net).unwrap();
    let pickle = pickle_of(&valid);
    let (from, to) = (b"torch\nFloatStorage", b"torch\nByteStorage");
    let at = pickle.windows(from.len()).position(|w| w == from).unwrap();
    let mut edited = pickle.clone();
    edited.splice(at..at + from.len(), to.iter().copied());
    std::fs::write(&files.time_net, with_pickle(&valid, &edited)).unwrap();
    let e = read_authors(&files, &Device::Cpu).unwrap_err().to_string();
    assert!(
        e.contains("time_net") && e.contains("deform.pth") && e.contains("stored as U8"),
        "{e}"
    );
}

/// The authors' `cfg_args` (a Python `Namespace(...)`), mutated: what the 4D binary reads of it
/// (the background and the eval flag) is read or refused naming the file, never guessed.
#[test]
fn cfg_args_survive_mutations() {
    let valid = b"Namespace(data_device='cuda', eval=False, images='images', is_blender=True, \
                  model_path='output/trex', resolution=-1, sh_degree=3, source_path='trex', \
                  white_background=True)";
    let refused = fuzz("cfg_args", valid, 31, |path| {
        let folder = path.parent().unwrap();
        base_dmiso::model_file::recorded_background(folder)
            .and_then(|_| base_dmiso::model_file::recorded_eval(folder))
            .map(|_| ())
            .map_err(|e| e.to_string())
    });
    assert!(refused > 0, "a flipped True or False is refused");
}
