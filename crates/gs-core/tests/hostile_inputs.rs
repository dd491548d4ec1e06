//! Named regressions of broken and hostile files: each is refused with an error naming the file,
//! before the work or memory it would otherwise cost.

use std::path::Path;

use gs_core::dataset::nerf_synthetic::{self, Split};
use gs_core::dataset::LoadOptions;
use gs_core::image::{decode_picture, PictureDecodeError};
use gs_core::{Camera, Image};

/// A 2x2 PNG whose header is rewritten to claim `width x height` (its checksum fixed), the
/// few bytes of a decompression bomb.
fn png_claiming(path: &Path, width: u32, height: u32) {
    let mut bytes = Vec::new();
    image::RgbImage::from_pixel(2, 2, image::Rgb([9, 9, 9]))
        .write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Png,
        )
        .unwrap();
    // Signature (8), IHDR length (4) and type (4), then width and height.
    assert_eq!(&bytes[12..16], b"IHDR");
    bytes[16..20].copy_from_slice(&width.to_be_bytes());
    bytes[20..24].copy_from_slice(&height.to_be_bytes());
    let mut crc = flate2::Crc::new();
    crc.update(&bytes[12..29]);
    bytes[29..33].copy_from_slice(&crc.sum().to_be_bytes());
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn a_picture_claiming_23000_squared_is_refused_before_decoding() {
    let dir = tempfile::tempdir().unwrap();
    let bomb = dir.path().join("bomb.png");
    png_claiming(&bomb, 23000, 23000);
    assert!(matches!(
        decode_picture(&bomb),
        Err(PictureDecodeError::TooLarge {
            width: 23000,
            height: 23000
        })
    ));
    let e = Image::load(&bomb, [0.0; 3]).unwrap_err().to_string();
    assert!(
        e.contains("bomb.png") && e.contains("23000x23000") && e.contains("downscale"),
        "{e}"
    );
    // Within the limit the same trick is an ordinary decoding error, not a 2 GB allocation.
    let small = dir.path().join("small.png");
    png_claiming(&small, 4000, 4000);
    assert!(matches!(
        decode_picture(&small),
        Err(PictureDecodeError::Image(_))
    ));
}

/// A picture with a side past 65536 pixels is refused from its header however few its pixels
/// (67108864 x 1 is within the 64-megapixel limit, and resizing it cost 120 GB); at 65536 a
/// side the header passes and the decoder then finds the data missing.
#[test]
fn a_picture_longer_than_65536_a_side_is_refused_before_decoding() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("long.png");
    for (width, height) in [
        (67_108_864, 1),
        (1, 67_108_864),
        (8_388_608, 8),
        (65_537, 2),
    ] {
        png_claiming(&path, width, height);
        match decode_picture(&path) {
            Err(PictureDecodeError::TooLong {
                width: w,
                height: h,
            }) => {
                assert_eq!((w, h), (width, height))
            }
            other => panic!("{width}x{height}: {other:?}"),
        }
        let e = Image::load(&path, [0.0; 3]).unwrap_err().to_string();
        assert!(
            e.contains("long.png")
                && e.contains(&format!("{width}x{height}"))
                && e.contains("65536 pixels a side"),
            "{e}"
        );
    }
    png_claiming(&path, 65_536, 2);
    assert!(matches!(
        decode_picture(&path),
        Err(PictureDecodeError::Image(_))
    ));
}

/// A one-frame NeRF-synthetic scene with `matrix` as its pose.
fn scene_with_pose(dir: &Path, matrix: serde_json::Value) -> String {
    image::RgbaImage::from_pixel(4, 4, image::Rgba([200, 100, 50, 255]))
        .save(dir.join("r_0.png"))
        .unwrap();
    std::fs::write(
        dir.join("transforms_train.json"),
        serde_json::json!({
            "camera_angle_x": 0.8,
            "frames": [{"file_path": "r_0", "transform_matrix": matrix}],
        })
        .to_string(),
    )
    .unwrap();
    nerf_synthetic::load(dir, Split::Train, &LoadOptions::default())
        .unwrap_err()
        .to_string()
}

#[test]
fn poses_that_are_not_rigid_are_refused_naming_the_frame() {
    let dir = tempfile::tempdir().unwrap();
    let e = scene_with_pose(dir.path(), serde_json::json!([[0.0f64; 4]; 4].to_vec()));
    assert!(
        e.contains("transforms_train.json frame 0") && e.contains("last row"),
        "{e}"
    );
    let scaled = serde_json::json!([[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 4], [0, 0, 0, 1]]);
    let e = scene_with_pose(dir.path(), scaled);
    assert!(
        e.contains("frame 0") && e.contains("not orthonormal"),
        "{e}"
    );
    let mirrored = serde_json::json!([[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]);
    let e = scene_with_pose(dir.path(), mirrored);
    assert!(e.contains("determinant"), "{e}");
}

#[test]
fn cameras_too_large_to_render_are_refused() {
    let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let camera = |w, h| Camera::new(identity, [0.0; 3], [100.0, 100.0, 50.0, 50.0], w, h);
    for (w, h) in [
        (u32::MAX, u32::MAX),
        (100_000, 100_000),
        (65_536, 65_536),
        (70_000, 2),
    ] {
        let e = camera(w, h).unwrap_err().to_string();
        assert!(
            e.contains(&format!("{w}x{h}")) && e.contains("at most 65536 pixels a side"),
            "{e}"
        );
        assert!(e.contains("GB") && e.contains("resolution divisor"), "{e}");
    }
    let e = camera(100_000, 100_000).unwrap_err().to_string();
    assert!(e.contains("needs 160.0 GB"), "{e}");
    assert!(camera(16_384, 16_384).is_ok());
    assert!(camera(65_536, 4_096).is_ok());
}

#[test]
fn colmap_images_without_their_points2d_lines_are_refused_not_halved() {
    let dir = tempfile::tempdir().unwrap();
    let sparse = dir.path().join("sparse/0");
    std::fs::create_dir_all(&sparse).unwrap();
    std::fs::write(sparse.join("cameras.txt"), "1 PINHOLE 8 6 10 10 4 3\n").unwrap();
    std::fs::write(sparse.join("points3D.txt"), "").unwrap();
    // Two images, one line each: the second would be taken as the first's 2D points.
    std::fs::write(
        sparse.join("images.txt"),
        "1 1 0 0 0 0 0 3 1 a.png\n2 1 0 0 0 1 0 3 1 b.png\n",
    )
    .unwrap();
    let e = gs_core::dataset::colmap::read_sparse_model(&sparse)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("images.txt") && e.contains("line 2") && e.contains("POINTS2D"),
        "{e}"
    );
    // With its (empty and full) points lines, the same file reads both images.
    std::fs::write(
        sparse.join("images.txt"),
        "1 1 0 0 0 0 0 3 1 a.png\n\n2 1 0 0 0 1 0 3 1 b.png\n1.5 2.5 -1 3 4 7\n",
    )
    .unwrap();
    let model = gs_core::dataset::colmap::read_sparse_model(&sparse).unwrap();
    assert_eq!(model.images.len(), 2);
    // A value error names the files the image and its camera come from.
    std::fs::write(sparse.join("images.txt"), "1 0 0 0 0 0 0 3 1 a.png\n\n").unwrap();
    std::fs::create_dir_all(dir.path().join("images")).unwrap();
    let e = gs_core::dataset::colmap::load(dir.path(), &LoadOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("images.txt") && e.contains("cameras.txt") && e.contains("\"a.png\""),
        "{e}"
    );
}

#[test]
fn a_ply_with_a_zero_quaternion_is_refused_naming_the_vertex() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("zero.ply");
    let mut set = gs_core::GaussianSet::zeros(3, 0);
    set.quats[4..8].fill(0.0);
    gs_core::ply::write_ply(
        &path,
        &gs_core::ply::PlyGaussians::new(set),
        gs_core::ply::PlyFormat::BinaryLittleEndian,
    )
    .unwrap();
    let e = gs_core::ply::read_ply(&path).unwrap_err().to_string();
    assert!(
        e.contains("zero.ply") && e.contains("vertex 1") && e.contains("quaternion is zero"),
        "{e}"
    );
}

/// 200,000 cameras with the first listed again at the end, as text and as binary: refused
/// naming the file and the camera (the check is one hash set: a pairwise check took over 20 s
/// on this many).
#[test]
fn a_camera_listed_twice_among_200000_is_refused_naming_it() {
    const CAMERAS: i32 = 200_000;
    let dir = tempfile::tempdir().unwrap();
    let text = dir.path().join("text/sparse/0");
    let binary = dir.path().join("binary/sparse/0");
    for sparse in [&text, &binary] {
        std::fs::create_dir_all(sparse).unwrap();
        std::fs::write(sparse.join("images.txt"), "").unwrap();
        std::fs::write(sparse.join("points3D.txt"), "").unwrap();
    }
    let mut lines = String::new();
    let mut bytes = (CAMERAS as u64 + 1).to_le_bytes().to_vec();
    for id in (1..=CAMERAS).chain([1]) {
        lines += &format!("{id} PINHOLE 8 6 10 10 4 3\n");
        bytes.extend(id.to_le_bytes());
        bytes.extend(1i32.to_le_bytes());
        bytes.extend(8u64.to_le_bytes());
        bytes.extend(6u64.to_le_bytes());
        for v in [10.0f64, 10.0, 4.0, 3.0] {
            bytes.extend(v.to_le_bytes());
        }
    }
    std::fs::write(text.join("cameras.txt"), lines).unwrap();
    std::fs::write(binary.join("cameras.bin"), bytes).unwrap();
    for (sparse, file) in [(&text, "cameras.txt"), (&binary, "cameras.bin")] {
        let e = gs_core::dataset::colmap::read_sparse_model(sparse)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains(file) && e.contains("camera 1 appears twice"),
            "{e}"
        );
    }
}

/// COLMAP images a picture cannot be read for are refused naming images.txt and the image: a
/// name that is a folder (`.`, `sub/`), leaves the images folder (`../x.png`, `/etc/passwd`),
/// and an id given twice; an ordinary name in a subfolder reads.
#[test]
fn colmap_image_names_and_ids_are_checked() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("cameras.txt"), "1 PINHOLE 8 6 10 10 4 3\n").unwrap();
    std::fs::write(dir.path().join("points3D.txt"), "").unwrap();
    let image = |id: u32, name: &str| format!("{id} 1 0 0 0 0 0 3 1 {name}\n\n");
    for (images, said) in [
        (image(1, "."), "image 1: NAME \".\" names no picture file"),
        (
            image(2, "sub/"),
            "image 2: NAME \"sub/\" names no picture file",
        ),
        (
            image(3, "../x.png"),
            "image 3: NAME \"../x.png\" leaves the images folder",
        ),
        (
            image(4, "/etc/passwd"),
            "image 4: NAME \"/etc/passwd\" is absolute",
        ),
        (
            image(5, "a.png") + &image(5, "b.png"),
            "image 5 appears twice",
        ),
    ] {
        std::fs::write(dir.path().join("images.txt"), &images).unwrap();
        let e = gs_core::dataset::colmap::read_sparse_model(dir.path())
            .unwrap_err()
            .to_string();
        assert!(e.contains("images.txt") && e.contains(said), "{said}: {e}");
    }
    std::fs::write(dir.path().join("images.txt"), image(6, "sub/a b.png")).unwrap();
    let model = gs_core::dataset::colmap::read_sparse_model(dir.path()).unwrap();
    assert_eq!(model.images[0].name, "sub/a b.png");
}

/// A split file with `"frames": []` is no views of that split, as INRIA's loader reads it: an
/// empty test split leaves the training views (and renders default to the train split); an
/// empty train split trains on the test views where the test split trains too, and is refused
/// where only the train split trains.
#[test]
fn an_empty_split_is_no_views_where_the_other_has_some() {
    use gs_core::dataset::nerf_synthetic::{default_render_split, load_training, TrainSplits};
    use gs_core::dataset::LoadOptions;
    let dir = tempfile::tempdir().unwrap();
    image::RgbaImage::from_pixel(4, 4, image::Rgba([200, 100, 50, 255]))
        .save(dir.path().join("r_0.png"))
        .unwrap();
    let split = |frames: usize| {
        serde_json::json!({
            "camera_angle_x": 0.8,
            "frames": (0..frames).map(|_| serde_json::json!({"file_path": "r_0",
                "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]}))
                .collect::<Vec<_>>(),
        })
        .to_string()
    };
    let write = |train: usize, test: usize| {
        std::fs::write(dir.path().join("transforms_train.json"), split(train)).unwrap();
        std::fs::write(dir.path().join("transforms_test.json"), split(test)).unwrap();
    };
    let options = LoadOptions::default();
    write(1, 0);
    let views = load_training(dir.path(), TrainSplits::TrainAndTest, &options).unwrap();
    assert_eq!(views.views.len(), 1);
    assert_eq!(default_render_split(dir.path()).unwrap(), Split::Train);
    write(0, 2);
    let views = load_training(dir.path(), TrainSplits::TrainAndTest, &options).unwrap();
    assert_eq!(views.views.len(), 2);
    let e = load_training(dir.path(), TrainSplits::Train, &options)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("transforms_train.json") && e.contains("no frames"),
        "{e}"
    );
    write(0, 0);
    let e = load_training(dir.path(), TrainSplits::TrainAndTest, &options)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("transforms_train.json") && e.contains("no frames"),
        "{e}"
    );
}

/// A NeRF frame whose `file_path` is not a file inside the scene folder (absolute, with a `..`
/// part, or naming the folder itself) is refused naming the json file and the frame;
/// Blender's `./train/r_0` reads.
#[test]
fn nerf_file_paths_stay_inside_the_scene_folder() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("train")).unwrap();
    image::RgbaImage::from_pixel(4, 4, image::Rgba([200, 100, 50, 255]))
        .save(dir.path().join("train/r_0.png"))
        .unwrap();
    let write = |file_path: &str| {
        let json = serde_json::json!({
            "camera_angle_x": 0.8,
            "frames": [{"file_path": file_path,
                "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]}],
        });
        std::fs::write(dir.path().join("transforms_train.json"), json.to_string()).unwrap();
    };
    let options = gs_core::dataset::LoadOptions::default();
    for (file_path, said) in [
        ("/etc/passwd", "is absolute"),
        ("../../outside/r_0", "leaves the scene folder"),
        ("train/../../r_0", "leaves the scene folder"),
        (".", "names no file"),
    ] {
        write(file_path);
        let e = nerf_synthetic::load(dir.path(), Split::Train, &options)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("transforms_train.json") && e.contains("frame 0") && e.contains(said),
            "{file_path}: {e}"
        );
    }
    write("./train/r_0");
    assert_eq!(
        nerf_synthetic::load(dir.path(), Split::Train, &options)
            .unwrap()
            .views
            .len(),
        1
    );
}
