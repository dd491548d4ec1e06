//! Every gs-core reader against mutations of small valid files (truncations, bit flips, edited
//! digits, huge and negative numbers written into headers): no panic, no allocation beyond a
//! bound (a counting allocator watches the peak), and an error that names the file whenever
//! the file is refused. Seeded and bounded, so it runs in seconds; `FUZZ_CASES` raises the
//! count of cases per reader for a longer run.

// The counting allocator below is the one unsafe code of the tests: a `GlobalAlloc` is an unsafe
// trait, and it only passes each request on to the system allocator.
#![allow(unsafe_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::panic::AssertUnwindSafe;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use rand::{Rng, SeedableRng};

/// The system allocator, counting the bytes held and refusing (null) any single request above
/// [`LIMIT`], as a machine out of memory would, so a reader that sizes a buffer from a file
/// fails the test instead of the machine.
struct Counting;

static HELD: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);
/// The largest allocation a reader of these small files may ask for.
const LIMIT: usize = 256 << 20;

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if layout.size() > LIMIT {
            return std::ptr::null_mut();
        }
        let held = HELD.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
        PEAK.fetch_max(held, Ordering::Relaxed);
        // SAFETY: the layout is passed on unchanged to the system allocator.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        HELD.fetch_sub(layout.size(), Ordering::Relaxed);
        // SAFETY: `ptr` came from `alloc` with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

fn cases() -> usize {
    std::env::var("FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(500)
}

/// One mutation of `bytes`: a truncation, bit flips, a run of one byte, or a number in the
/// text (a header count, a json value) replaced by a huge, negative or odd one.
fn mutate(bytes: &[u8], rng: &mut impl Rng) -> Vec<u8> {
    let mut out = bytes.to_vec();
    match rng.random_range(0..5) {
        0 => out.truncate(rng.random_range(0..=bytes.len())),
        1 => {
            for _ in 0..rng.random_range(1..8) {
                let i = rng
                    .random_range(0..out.len().max(1))
                    .min(out.len().saturating_sub(1));
                if let Some(b) = out.get_mut(i) {
                    *b ^= 1 << rng.random_range(0..8);
                }
            }
        }
        2 => {
            let at = rng.random_range(0..out.len().max(1));
            let len = rng.random_range(1..64).min(out.len().saturating_sub(at));
            let value = [0u8, 0xff, 0x7f, 0x80][rng.random_range(0..4)];
            out[at..at + len].fill(value);
        }
        _ => {
            // A run of ASCII digits, replaced.
            let starts: Vec<usize> = (0..out.len())
                .filter(|&i| out[i].is_ascii_digit() && (i == 0 || !out[i - 1].is_ascii_digit()))
                .collect();
            if let Some(&start) = starts.get(rng.random_range(0..starts.len().max(1))) {
                let end = (start..out.len())
                    .find(|&i| !out[i].is_ascii_digit())
                    .unwrap_or(out.len());
                let number = [
                    "4294967295",
                    "99999999999999999999",
                    "-1",
                    "0",
                    "1e300",
                    "65537",
                ][rng.random_range(0..6)];
                out.splice(start..end, number.bytes());
            }
        }
    }
    out
}

/// Runs `read` on `cases()` mutations of `valid` written as `name` in a fresh folder: asserts
/// no panic, a peak of held memory below `LIMIT`, and errors that name the file. Returns how
/// many mutations were refused. A failing case is found again from its seed and number.
fn fuzz(name: &str, valid: &[u8], seed: u64, read: impl Fn(&Path) -> Result<(), String>) -> usize {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut refused = 0;
    for case in 0..cases() {
        let bytes = mutate(valid, &mut rng);
        std::fs::write(&path, &bytes).unwrap();
        let before = HELD.load(Ordering::Relaxed);
        PEAK.store(before, Ordering::Relaxed);
        let outcome = std::panic::catch_unwind(AssertUnwindSafe(|| read(&path)));
        let peak = PEAK.load(Ordering::Relaxed).saturating_sub(before);
        match outcome {
            Err(_) => panic!("{name} case {case} (seed {seed}): the reader panicked"),
            Ok(Err(e)) => {
                refused += 1;
                assert!(
                    e.contains(name),
                    "{name} case {case}: {e:?} does not name the file"
                );
            }
            Ok(Ok(())) => {}
        }
        assert!(
            peak < LIMIT,
            "{name} case {case}: {peak} bytes held at the peak"
        );
    }
    refused
}

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
