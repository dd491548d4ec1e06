//! Every gs-core reader against mutations of small valid files (truncations, bit flips, edited
//! digits, huge and negative numbers written into headers): no panic, no allocation beyond a
//! bound (a counting allocator watches the peak), and an error that names the file whenever
//! the file is refused. Seeded and bounded, so it runs in seconds; `FUZZ_CASES` raises the
//! count of cases per reader for a longer run.

mod fuzz;

use std::path::{Path, PathBuf};

use fuzz::{fuzz, Counting};

#[global_allocator]
static ALLOCATOR: Counting = Counting;

fn fixture(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(path)
}

fn splats_reader(path: &Path) -> Result<(), String> {
    gs_core::splats::read_splats(path)
        .map(|_| ())
        .map_err(|e| e.to_string())
}

#[test]
fn splat_readers_survive_mutated_files() {
    for (name, seed) in [
        ("source.ply", 1),
        ("source.compressed.ply", 2),
        ("source.splat", 3),
        ("source.v2.spz", 4),
        ("source.v3.spz", 5),
        ("source.v4.spz", 6),
        ("source.glb", 7),
        ("source.sog", 8),
    ] {
        let valid = std::fs::read(fixture(&format!("splats/{name}"))).unwrap();
        let refused = fuzz(name, &valid, seed, splats_reader);
        assert!(refused > 0, "{name}: some mutations are refused");
    }
}

#[test]
fn colmap_readers_survive_mutated_files() {
    let dir = tempfile::tempdir().unwrap();
    let sparse = dir.path().join("model");
    std::fs::create_dir_all(&sparse).unwrap();
    std::fs::write(
        sparse.join("cameras.txt"),
        "1 PINHOLE 8 6 10 10 4 3\n2 SIMPLE_RADIAL 8 6 9 4 3 0.01\n",
    )
    .unwrap();
    std::fs::write(
        sparse.join("images.txt"),
        "1 1 0 0 0 0 0 3 1 a.png\n1.5 2.5 -1\n2 0.7 0.7 0 0 1 0 3 2 b.png\n\n",
    )
    .unwrap();
    std::fs::write(
        sparse.join("points3D.txt"),
        "1 0.1 0.2 0.3 200 100 50 0.5 1 0\n",
    )
    .unwrap();
    for file in ["cameras.txt", "images.txt", "points3D.txt"] {
        let valid = std::fs::read(sparse.join(file)).unwrap();
        let originals: Vec<(String, Vec<u8>)> = ["cameras.txt", "images.txt", "points3D.txt"]
            .iter()
            .map(|f| (f.to_string(), std::fs::read(sparse.join(f)).unwrap()))
            .collect();
        fuzz(file, &valid, file.len() as u64, |path| {
            let folder = path.parent().unwrap();
            for (f, bytes) in &originals {
                if f != file {
                    std::fs::write(folder.join(f), bytes).unwrap();
                }
            }
            gs_core::dataset::colmap::read_sparse_model(folder)
                .map(|_| ())
                .map_err(|e| e.to_string())
        });
    }
}

#[test]
fn transforms_readers_survive_mutated_files() {
    let dir = tempfile::tempdir().unwrap();
    image::RgbaImage::from_pixel(4, 3, image::Rgba([200, 100, 50, 255]))
        .save(dir.path().join("r_0.png"))
        .unwrap();
    let json = serde_json::json!({
        "camera_angle_x": 0.8, "w": 4, "h": 3, "fl_x": 5.0, "k1": 0.01,
        "frames": [{"file_path": "r_0", "time": 0.5,
            "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]}],
    })
    .to_string();
    let picture = std::fs::read(dir.path().join("r_0.png")).unwrap();
    fuzz("transforms_train.json", json.as_bytes(), 7, |path| {
        let root = path.parent().unwrap();
        std::fs::write(root.join("r_0.png"), &picture).unwrap();
        gs_core::dataset::nerf_synthetic::load_with_times(
            root,
            gs_core::dataset::nerf_synthetic::Split::Train,
            &gs_core::dataset::LoadOptions::default(),
        )
        .map(|_| ())
        .map_err(|e| e.to_string())
    });
    // The picture itself mutated, read through the json.
    fuzz("r_0.png", &picture, 8, |path| {
        let root = path.parent().unwrap();
        std::fs::write(root.join("transforms_train.json"), &json).unwrap();
        gs_core::dataset::nerf_synthetic::load(
            root,
            gs_core::dataset::nerf_synthetic::Split::Train,
            &gs_core::dataset::LoadOptions::default(),
        )
        .map(|_| ())
        .map_err(|e| e.to_string())
    });
}

/// A valid PLY too large for the memory the machine gives (here: this thread refuses requests
/// above the file's own size, and the decoded SH arrays are larger than the ascii file) is an
/// error naming the file and what could not be reserved, not an abort.
#[test]
fn a_valid_ply_larger_than_memory_is_an_error() {
    let n = 6000;
    let mut properties: Vec<String> = ["x", "y", "z", "nx", "ny", "nz"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    properties.extend((0..3).map(|k| format!("f_dc_{k}")));
    properties.extend((0..45).map(|k| format!("f_rest_{k}")));
    properties.push("opacity".into());
    properties.extend((0..3).map(|k| format!("scale_{k}")));
    properties.extend((0..4).map(|k| format!("rot_{k}")));
    let mut text = format!("ply\nformat ascii 1.0\nelement vertex {n}\n");
    for p in &properties {
        text += &format!("property float {p}\n");
    }
    text += "end_header\n";
    let row: Vec<&str> = properties
        .iter()
        .map(|p| if p == "rot_0" { "1" } else { "0" })
        .collect();
    let row = row.join(" ") + "\n";
    for _ in 0..n {
        text += &row;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("large.ply");
    std::fs::write(&path, &text).unwrap();
    assert!(
        gs_core::ply::read_ply(&path).is_ok(),
        "valid with memory to spare"
    );
    let sh_bytes = n * 45 * 4;
    assert!(sh_bytes > text.len() * 5 / 4);
    let e = fuzz::with_cap(text.len() * 9 / 8, || gs_core::ply::read_ply(&path))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("large.ply") && e.contains("need 1.1 MB, which this machine could not reserve"),
        "{e}"
    );
}

/// The same for a compressed PLY (SH in a byte a value, decoded to four): its reader's
/// refusal is the typed `OutOfMemory`, which a batch counts as worth retrying elsewhere.
#[test]
fn a_valid_compressed_ply_larger_than_memory_is_an_error() {
    use gs_core::splats::{read_splats, write_splats, SplatFileError, SplatFormat};
    let n = 4000;
    let mut set = gs_core::GaussianSet::zeros(n, 3);
    for (i, m) in set.means.iter_mut().enumerate() {
        *m = (i % 97) as f32 * 0.01;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("large.compressed.ply");
    let ply = gs_core::ply::PlyGaussians::without_normals(set);
    write_splats(&path, &ply, SplatFormat::CompressedPly).unwrap();
    let len = std::fs::metadata(&path).unwrap().len() as usize;
    assert!(read_splats(&path).is_ok(), "valid with memory to spare");
    assert!(
        n * 45 * 4 > len * 2,
        "the SH arrays are larger than the file"
    );
    let e = fuzz::with_cap(len * 5 / 4, || read_splats(&path)).unwrap_err();
    assert!(matches!(e, SplatFileError::OutOfMemory { .. }), "{e}");
    let e = e.to_string();
    assert!(
        e.contains("large.compressed.ply") && e.contains("could not reserve"),
        "{e}"
    );
}

/// Pictures of every kind a run reads (2D pictures, style pictures, dataset and video frames
/// all go through `decode_picture`), mutated: PNG, JPEG and WebP.
#[test]
fn picture_decoding_survives_mutated_files() {
    let picture = image::RgbImage::from_fn(24, 16, |x, y| {
        image::Rgb([(x * 10) as u8, (y * 15) as u8, ((x + y) * 5) as u8])
    });
    for (name, format, seed) in [
        ("p.png", image::ImageFormat::Png, 41),
        ("p.jpg", image::ImageFormat::Jpeg, 42),
        ("p.webp", image::ImageFormat::WebP, 43),
    ] {
        let mut valid = Vec::new();
        picture
            .write_to(&mut std::io::Cursor::new(&mut valid), format)
            .unwrap();
        let refused = fuzz(name, &valid, seed, |path| {
            gs_core::image::decode_picture(path)
                .map(|_| ())
                .map_err(|e| format!("{}: {e}", path.display()))
        });
        assert!(refused > 0, "{name}: some mutations are refused");
    }
}
