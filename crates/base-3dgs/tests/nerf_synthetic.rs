//! NeRF-synthetic loading: cameras, alpha compositing, masks, downscaling, extent and errors,
//! on a tiny scene written by the test.

mod common;

use std::path::Path;

use base_3dgs::dataset::nerf_synthetic::{self, Split, TrainSplits};
use base_3dgs::dataset::{scene_extent, Background, DatasetError, ImageProgress, LoadOptions};
use common::TempDir;
use gs_core::levels::composite_8bit;

const W: u32 = 8;
const H: u32 = 6;

/// A W x H RGBA image: pixel (0,0) red but fully transparent, (1,0) opaque (51,102,153),
/// (2,0) red at alpha 128, every other pixel opaque grey 200.
fn write_rgba(path: &Path, width: u32, height: u32) {
    let mut img = image::RgbaImage::from_pixel(width, height, image::Rgba([200, 200, 200, 255]));
    img.put_pixel(0, 0, image::Rgba([255, 0, 0, 0]));
    img.put_pixel(1, 0, image::Rgba([51, 102, 153, 255]));
    img.put_pixel(2, 0, image::Rgba([255, 0, 0, 128]));
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    img.save(path).unwrap();
}

/// camera_angle_x with a focal length equal to the width: 2 atan(1/2).
fn fov_x() -> f64 {
    2.0 * 0.5f64.atan()
}

/// Three frames: at z = 4 looking down -z (OpenGL identity rotation), the same moved to
/// x = 2, and one at y = -4 looking along +y; `file_path` with and without ".png".
fn write_scene(root: &Path, split: &str) {
    for i in 0..3 {
        write_rgba(&root.join(format!("{split}/r_{i}.png")), W, H);
    }
    let json = serde_json::json!({
        "camera_angle_x": fov_x(),
        "frames": [
            {"file_path": format!("./{split}/r_0"), "rotation": 0.1,
             "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]},
            {"file_path": format!("./{split}/r_1.png"),
             "transform_matrix": [[1, 0, 0, 2], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]},
            {"file_path": format!("{split}/r_2"),
             "transform_matrix": [[1, 0, 0, 0], [0, 0, -1, -4], [0, 1, 0, 0], [0, 0, 0, 1]]},
        ]
    });
    std::fs::write(
        root.join(format!("transforms_{split}.json")),
        serde_json::to_string_pretty(&json).unwrap(),
    )
    .unwrap();
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-9
}

#[test]
fn a_tiny_scene_loads_with_cameras_that_project_known_points() {
    let dir = TempDir::new("nerf-load");
    write_scene(dir.path(), "train");
    let data = nerf_synthetic::load(dir.path(), Split::Train, &LoadOptions::default()).unwrap();
    assert_eq!(data.views.len(), 3);
    assert_eq!(data.images.len(), 3);
    assert!(data.image_paths[0].ends_with("train/r_0.png"));
    let cam = &data.views[0].camera;
    assert_eq!((cam.width, cam.height), (W, H));
    assert!(close(cam.fx, W as f64) && close(cam.fy, W as f64));
    // World (1, 0.5, 0) is 4 in front of the camera: u = 4 + 8 * 1/4, v = 3 - 8 * 0.5/4.
    let ([u, v], depth) = cam.project([1.0, 0.5, 0.0]).unwrap();
    assert!(
        close(u, 6.0) && close(v, 2.0) && close(depth, 4.0),
        "{u} {v} {depth}"
    );
    // The camera moved to x = 2 sees the same point left of centre.
    let ([u, v], _) = data.views[1].camera.project([1.0, 0.5, 0.0]).unwrap();
    assert!(close(u, 2.0) && close(v, 2.0), "{u} {v}");
    // The third camera at y = -4 looks along +y with world z up in the image.
    let ([u, v], depth) = data.views[2].camera.project([1.0, 0.0, 0.5]).unwrap();
    assert!(
        close(u, 6.0) && close(v, 2.0) && close(depth, 4.0),
        "{u} {v} {depth}"
    );
    assert_eq!(data.views[0].time, 0.0);
    assert!(data.points.is_none());
}

/// nerfstudio / instant-ngp files: sizes as whole floats, pixel intrinsics for the file and
/// for a frame, no `camera_angle_x`; a distorted camera is undistorted, one whose distortion
/// cannot be undone or without any focal length is refused naming the frame.
#[test]
fn nerfstudio_intrinsics_and_float_sizes_are_read() {
    let dir = TempDir::new("nerf-intrinsics");
    for i in 0..2 {
        write_rgba(&dir.path().join(format!("images/f_{i}.png")), W, H);
    }
    let pose = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]];
    let write = |json: serde_json::Value| {
        std::fs::write(
            dir.path().join("transforms_train.json"),
            serde_json::to_string(&json).unwrap(),
        )
        .unwrap();
        let loaded = nerf_synthetic::load(dir.path(), Split::Train, &LoadOptions::default());
        if let Ok(data) = &loaded {
            let options = LoadOptions::default();
            common::same_views(
                data,
                &nerf_synthetic::views(dir.path(), Split::Train, &options).unwrap(),
            );
        }
        loaded
    };
    let data = write(serde_json::json!({
        "w": 8.0, "h": 6.0, "fl_x": 7.5, "fl_y": 7.0, "cx": 4.25, "cy": 2.75,
        "frames": [
            {"file_path": "images/f_0.png", "transform_matrix": pose},
            {"file_path": "images/f_1.png", "transform_matrix": pose, "fl_x": 9.0, "cx": 3.5},
        ]
    }))
    .unwrap();
    let k = |i: usize| {
        let c = &data.views[i].camera;
        [c.fx, c.fy, c.cx, c.cy]
    };
    assert_eq!(k(0), [7.5, 7.0, 4.25, 2.75]);
    assert_eq!(k(1), [9.0, 7.0, 3.5, 2.75], "a frame's own intrinsics win");
    let undistorted = write(serde_json::json!({
        "fl_x": 7.5, "k1": -0.02, "p1": 0.001,
        "frames": [{"file_path": "images/f_0.png", "transform_matrix": pose}]
    }))
    .unwrap();
    let report = undistorted.undistorted[0].as_ref().unwrap();
    assert_eq!((report.model.as_str(), report.stored), ("OPENCV", (W, H)));
    assert_eq!(undistorted.views[0].camera.width, W - 1);
    let fisheye = write(serde_json::json!({
        "fl_x": 7.5, "k1": 0.01, "k4": 0.001, "camera_model": "OPENCV_FISHEYE",
        "frames": [{"file_path": "images/f_0.png", "transform_matrix": pose}]
    }))
    .unwrap();
    let report = fisheye.undistorted[0].as_ref().unwrap();
    assert_eq!(report.model, "OPENCV_FISHEYE");
    for (json, want) in [
        (
            serde_json::json!({"fl_x": 7.5, "k4": 0.01, "frames": [
                {"file_path": "images/f_0.png", "transform_matrix": pose}]}),
            "k4 = 0.01",
        ),
        (
            serde_json::json!({"fl_x": 7.5, "camera_model": "EQUIRECTANGULAR", "frames": [
                {"file_path": "images/f_0.png", "transform_matrix": pose}]}),
            "\"EQUIRECTANGULAR\" is not one this reader undoes",
        ),
    ] {
        let e = write(json).unwrap_err().to_string();
        assert!(e.contains("frame 0") && e.contains(want), "{e}");
    }
    let e = write(serde_json::json!({
        "frames": [{"file_path": "images/f_0.png", "transform_matrix": pose}]
    }))
    .unwrap_err()
    .to_string();
    assert!(e.contains("neither fl_x nor camera_angle_x"), "{e}");
    let e = write(serde_json::json!({
        "w": 8.5, "fl_x": 7.5,
        "frames": [{"file_path": "images/f_0.png", "transform_matrix": pose}]
    }))
    .unwrap_err()
    .to_string();
    assert!(e.contains("8.5 is not a picture size"), "{e}");
}

/// The loader tells its progress of every picture: each count once, out of the split's size.
#[test]
fn every_picture_loaded_is_reported_once() {
    use std::sync::{Arc, Mutex};
    let dir = TempDir::new("nerf-progress");
    write_scene(dir.path(), "train");
    let seen = Arc::new(Mutex::new(Vec::new()));
    let record = seen.clone();
    let options = LoadOptions {
        progress: Some(ImageProgress::new(move |done, total| {
            record.lock().unwrap().push((done, total))
        })),
        ..LoadOptions::default()
    };
    let data = nerf_synthetic::load(dir.path(), Split::Train, &options).unwrap();
    let mut seen = seen.lock().unwrap().clone();
    seen.sort_unstable();
    assert_eq!(seen, vec![(1, 3), (2, 3), (3, 3)]);
    assert_eq!(data.views.len(), 3);
}

/// The sizes a run checks against its memory come from the json and one header, and agree
/// with what loading gives, at full size and downscaled.
#[test]
fn training_pixels_agree_with_the_loaded_views() {
    let dir = TempDir::new("nerf-pixels");
    write_scene(dir.path(), "train");
    for downscale in [1, 2] {
        let options = LoadOptions {
            downscale,
            ..LoadOptions::default()
        };
        let (views, largest) =
            nerf_synthetic::training_pixels(dir.path(), TrainSplits::Train, &options).unwrap();
        let data = nerf_synthetic::load(dir.path(), Split::Train, &options).unwrap();
        let loaded: Vec<u64> = data
            .images
            .iter()
            .map(|i| u64::from(i.width) * u64::from(i.height))
            .collect();
        assert_eq!(views, loaded, "downscale {downscale}");
        assert_eq!(largest, u64::from(W * H));
    }
}

#[test]
fn alpha_is_composited_over_the_chosen_background_and_gives_the_mask() {
    let dir = TempDir::new("nerf-alpha");
    write_scene(dir.path(), "test");
    let a = 128.0 / 255.0;
    for (background, bg) in [(Background::White, 1.0f32), (Background::Black, 0.0)] {
        let options = LoadOptions {
            background,
            downscale: 1,
            ..LoadOptions::default()
        };
        let data = nerf_synthetic::load(dir.path(), Split::Test, &options).unwrap();
        assert_eq!(data.background, [bg; 3]);
        let img = &data.images[0];
        assert_eq!(img.pixel(0, 0), [bg; 3], "transparent red is background");
        let px = img.pixel(1, 0);
        let want = [51.0 / 255.0, 102.0 / 255.0, 153.0 / 255.0];
        assert!((0..3).all(|c| (px[c] - want[c]).abs() < 1e-6), "{px:?}");
        // Partly transparent: composited, then cut to whole 8-bit levels as 3DGS's loader
        // (gs-core's tests hold composite_8bit to the authors' numpy for every level).
        let px = img.pixel(2, 0);
        let want = composite_8bit([255, 0, 0], 128, [bg; 3]).map(|v| f32::from(v) / 255.0);
        assert_eq!(px, want);
        let float = [a + bg * (1.0 - a), bg * (1.0 - a), bg * (1.0 - a)];
        assert!(
            (0..3).all(|c| (px[c] - float[c]).abs() < 1.0 / 255.0),
            "{px:?} {float:?}"
        );
        let mask = data.masks[0].as_ref().unwrap();
        assert_eq!((mask.width, mask.height), (W, H));
        assert_eq!(mask.data[0], 1.0);
        assert_eq!(
            &mask.data[1..3],
            &[0.0, 0.0],
            "partly transparent is foreground"
        );
        assert_eq!(mask.background_count(), 1);
    }
}

#[test]
fn downscaling_halves_images_and_intrinsics() {
    let dir = TempDir::new("nerf-downscale");
    write_scene(dir.path(), "val");
    let options = LoadOptions {
        background: Background::White,
        downscale: 2,
        ..LoadOptions::default()
    };
    let data = nerf_synthetic::load(dir.path(), Split::Val, &options).unwrap();
    let cam = &data.views[0].camera;
    assert_eq!((cam.width, cam.height), (W / 2, H / 2));
    assert!(close(cam.fx, W as f64 / 2.0) && close(cam.cx, W as f64 / 4.0));
    let img = &data.images[0];
    assert_eq!((img.width, img.height), (W / 2, H / 2));
    assert_eq!(img.data.len(), (W * H / 4 * 3) as usize);
    // The bottom-right quarter is uniform grey 200 and stays so.
    let px = img.pixel(3, 2);
    assert!((px[0] - 200.0 / 255.0).abs() < 1e-3, "{px:?}");
    assert_eq!(
        data.masks[0].as_ref().unwrap().data.len(),
        (W * H / 4) as usize
    );
}

#[test]
fn extent_is_1_1_times_the_largest_distance_to_the_mean_centre() {
    let dir = TempDir::new("nerf-extent");
    write_scene(dir.path(), "train");
    let data = nerf_synthetic::load(dir.path(), Split::Train, &LoadOptions::default()).unwrap();
    // Centres (0,0,4), (2,0,4), (0,-4,0): mean (2/3, -4/3, 8/3); the farthest is the third,
    // at sqrt(4/9 + 64/9 + 64/9) = sqrt(132)/3.
    let want = 1.1 * 132f64.sqrt() / 3.0;
    assert!(close(data.extent, want), "{} {want}", data.extent);
    assert!(close(scene_extent(&data.views), want));
    assert_eq!(scene_extent(&data.views[..1]), 0.0);
}

#[test]
fn missing_files_bad_json_and_size_mismatches_are_clear_errors() {
    let dir = TempDir::new("nerf-errors");
    write_scene(dir.path(), "train");
    let e = nerf_synthetic::load(dir.path(), Split::Test, &LoadOptions::default()).unwrap_err();
    assert!(matches!(e, DatasetError::Missing { .. }), "{e}");
    assert!(e.to_string().contains("transforms_test.json"), "{e}");

    write_rgba(&dir.path().join("train/r_1.png"), W + 1, H);
    let e = nerf_synthetic::load(dir.path(), Split::Train, &LoadOptions::default()).unwrap_err();
    let message = e.to_string();
    assert!(
        message.contains("r_1.png") && message.contains("9x6") && message.contains("8x6"),
        "{message}"
    );

    std::fs::remove_file(dir.path().join("train/r_1.png")).unwrap();
    let e = nerf_synthetic::load(dir.path(), Split::Train, &LoadOptions::default()).unwrap_err();
    assert!(
        matches!(e, DatasetError::Missing { .. }) && e.to_string().contains("r_1.png"),
        "{e}"
    );

    let json = dir.path().join("transforms_val.json");
    std::fs::write(
        &json,
        r#"{"frames": [{"file_path": "train/r_0", "transform_matrix":
            [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]}]}"#,
    )
    .unwrap();
    let e = nerf_synthetic::load(dir.path(), Split::Val, &LoadOptions::default()).unwrap_err();
    assert!(
        e.to_string().contains("camera_angle_x") && e.to_string().contains("transforms_val.json"),
        "{e}"
    );
    std::fs::write(&json, r#"{"camera_angle_x": 0.7, "frames": []}"#).unwrap();
    let e = nerf_synthetic::load(dir.path(), Split::Val, &LoadOptions::default()).unwrap_err();
    assert!(e.to_string().contains("no frames"), "{e}");
    std::fs::write(
        &json,
        r#"{"camera_angle_x": -1, "frames": [{"file_path": "train/r_0", "transform_matrix":
            [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]}]}"#,
    )
    .unwrap();
    let e = nerf_synthetic::load(dir.path(), Split::Val, &LoadOptions::default()).unwrap_err();
    assert!(e.to_string().contains("camera_angle_x is -1"), "{e}");

    let options = LoadOptions {
        background: Background::Black,
        downscale: 0,
        ..LoadOptions::default()
    };
    let e = nerf_synthetic::load(dir.path(), Split::Train, &options).unwrap_err();
    assert!(e.to_string().contains("downscale"), "{e}");
}

#[test]
fn training_views_are_the_train_then_the_test_frames_with_the_extent_of_both() {
    let dir = TempDir::new("nerf-training");
    write_scene(dir.path(), "train");
    let options = LoadOptions::default();
    let alone = nerf_synthetic::load_training(dir.path(), TrainSplits::TrainAndTest, &options);
    assert_eq!(
        alone.unwrap().views.len(),
        3,
        "no test split: the train views"
    );
    write_scene(dir.path(), "test");
    // The test cameras moved, so the extent of both differs from the train split's.
    let path = dir.path().join("transforms_test.json");
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    json["frames"][1]["transform_matrix"][0][3] = 9.into();
    std::fs::write(&path, json.to_string()).unwrap();
    let both =
        nerf_synthetic::load_training(dir.path(), TrainSplits::TrainAndTest, &options).unwrap();
    let train = nerf_synthetic::load_training(dir.path(), TrainSplits::Train, &options).unwrap();
    assert_eq!(train.views.len(), 3);
    assert_eq!(both.views.len(), 6);
    for (k, path) in both.image_paths.iter().enumerate() {
        let split = if k < 3 { "train" } else { "test" };
        assert!(
            path.ends_with(format!("{split}/r_{}.png", k % 3)),
            "{path:?}"
        );
    }
    assert_eq!(both.extent, scene_extent(&both.views));
    assert!(
        both.extent > train.extent + 1.0,
        "{} vs {}",
        both.extent,
        train.extent
    );
}

/// nerfstudio's and instant-ngp's single `transforms.json`: every frame trains without split
/// lists (and there is no test split); with them each split is its list, in the file's frame
/// order, a listed name with no frame refused; `aabb_scale`, `scale` and `offset` move no camera.
#[test]
fn a_single_transforms_json_gives_its_splits() {
    let dir = TempDir::new("nerfstudio-single");
    for i in 0..4 {
        write_rgba(&dir.path().join(format!("images/frame_{i:05}.png")), W, H);
    }
    let frame = |i: usize, x: f64| {
        serde_json::json!({"file_path": format!("images/frame_{i:05}.png"),
            "transform_matrix": [[1, 0, 0, x], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]})
    };
    let frames: Vec<_> = (0..4).map(|i| frame(i, i as f64)).collect();
    let write = |json: serde_json::Value| {
        std::fs::write(
            dir.path().join("transforms.json"),
            serde_json::to_string(&json).unwrap(),
        )
        .unwrap();
    };
    write(serde_json::json!({
        "fl_x": 7.0, "w": 8, "h": 6, "aabb_scale": 16, "scale": 0.33, "offset": [0.5, 0.5, 0.5],
        "frames": frames,
    }));
    assert_eq!(
        base_3dgs::dataset::Layout::detect(dir.path()),
        Some(base_3dgs::dataset::Layout::NerfSynthetic)
    );
    let options = LoadOptions::default();
    let all = nerf_synthetic::load(dir.path(), Split::Train, &options).unwrap();
    assert_eq!(all.views.len(), 4);
    assert!(
        close(all.views[2].camera.centre()[0], 2.0),
        "the file's own frame"
    );
    assert!(!nerf_synthetic::has_split(dir.path(), Split::Test).unwrap());
    let render_split = nerf_synthetic::default_render_split(dir.path()).unwrap();
    assert_eq!(
        render_split,
        Split::Train,
        "no test split: render renders the frames"
    );
    let both = nerf_synthetic::load_training(dir.path(), TrainSplits::TrainAndTest, &options);
    assert_eq!(both.unwrap().views.len(), 4);
    let e = nerf_synthetic::load(dir.path(), Split::Test, &options).unwrap_err();
    assert!(e.to_string().contains("test_filenames"), "{e}");

    write(serde_json::json!({
        "fl_x": 7.0, "frames": frames,
        "train_filenames": ["images/frame_00003.png", "./images/frame_00000.png"],
        "test_filenames": ["images/frame_00002.png"],
    }));
    let train = nerf_synthetic::load(dir.path(), Split::Train, &options).unwrap();
    let names: Vec<_> = train
        .image_paths
        .iter()
        .map(|p| p.file_name().unwrap().to_str().unwrap().to_string())
        .collect();
    assert_eq!(names, ["frame_00000.png", "frame_00003.png"]);
    assert!(nerf_synthetic::has_split(dir.path(), Split::Test).unwrap());
    assert!(!nerf_synthetic::has_split(dir.path(), Split::Val).unwrap());
    let render_split = nerf_synthetic::default_render_split(dir.path()).unwrap();
    assert_eq!(
        render_split,
        Split::Test,
        "render renders the views eval scores"
    );
    let training =
        nerf_synthetic::load_training(dir.path(), TrainSplits::TrainAndTest, &options).unwrap();
    assert_eq!(training.views.len(), 3);
    let (pixels, _) =
        nerf_synthetic::training_pixels(dir.path(), TrainSplits::TrainAndTest, &options).unwrap();
    assert_eq!(pixels, vec![u64::from(W * H); 3]);

    write(serde_json::json!({
        "fl_x": 7.0, "frames": frames, "train_filenames": ["images/frame_00009.png"],
    }));
    let e = nerf_synthetic::load(dir.path(), Split::Train, &options).unwrap_err();
    assert!(
        e.to_string().contains("transforms.json")
            && e.to_string()
                .contains("train_filenames names \"images/frame_00009.png\""),
        "{e}"
    );
}

/// With a downscale `f`, pictures come from `images_<f>/` by file name when it exists (as
/// nerfstudio's `ns-process-data` writes them), the intrinsics scaled to each file's size;
/// per-frame sizes are each frame's own.
#[test]
fn downscaled_folders_and_per_frame_sizes_are_used() {
    let dir = TempDir::new("nerfstudio-images-2");
    write_rgba(&dir.path().join("images/frame_00000.png"), 16, 12);
    write_rgba(&dir.path().join("images/frame_00001.png"), 12, 16);
    let pose = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]];
    std::fs::write(
        dir.path().join("transforms.json"),
        serde_json::json!({
            "fl_x": 14.0, "cx": 8.0, "cy": 6.0, "w": 16, "h": 12,
            "frames": [
                {"file_path": "images/frame_00000.png", "transform_matrix": pose},
                {"file_path": "images/frame_00001.png", "transform_matrix": pose,
                 "w": 12, "h": 16, "cx": 6.0, "cy": 8.0},
            ]
        })
        .to_string(),
    )
    .unwrap();
    let full = nerf_synthetic::load(dir.path(), Split::Train, &LoadOptions::default()).unwrap();
    assert_eq!(
        (full.images[1].width, full.images[1].height),
        (12, 16),
        "a frame's own size"
    );
    let options = LoadOptions {
        downscale: 2,
        ..LoadOptions::default()
    };
    let resized = nerf_synthetic::load(dir.path(), Split::Train, &options).unwrap();
    assert!(resized.image_paths[0].parent().unwrap().ends_with("images"));
    common::same_views(
        &resized,
        &nerf_synthetic::views(dir.path(), Split::Train, &options).unwrap(),
    );
    write_rgba(&dir.path().join("images_2/frame_00000.png"), 8, 6);
    write_rgba(&dir.path().join("images_2/frame_00001.png"), 7, 8);
    let prescaled = nerf_synthetic::load(dir.path(), Split::Train, &options).unwrap();
    assert!(prescaled.image_paths[0].ends_with("images_2/frame_00000.png"));
    common::same_views(
        &prescaled,
        &nerf_synthetic::views(dir.path(), Split::Train, &options).unwrap(),
    );
    let c = &prescaled.views[1].camera;
    assert_eq!((c.width, c.height), (7, 8));
    assert!(close(c.fx, 14.0 * 7.0 / 12.0) && close(c.cy, 4.0), "{c:?}");
    write_rgba(&dir.path().join("images_2/frame_00001.png"), 9, 8);
    let e = nerf_synthetic::load(dir.path(), Split::Train, &options).unwrap_err();
    assert!(e.to_string().contains("images_2/frame_00001.png"), "{e}");
}

/// Two frames whose pictures share a file name would be rendered to one file: refused naming
/// the dataset and both pictures, from the json alone (it gives the pictures' size, and the
/// pictures do not even exist: none is read). With distinct names, the same json gives its
/// cameras without pictures.
#[test]
fn views_that_would_be_rendered_to_one_file_are_named() {
    let dir = TempDir::new("nerf-same-names");
    let pose = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]];
    let cameras = |second: &str| {
        std::fs::write(
            dir.path().join("transforms_train.json"),
            serde_json::json!({
                "camera_angle_x": fov_x(),
                "w": 8,
                "h": 6,
                "frames": [
                    {"file_path": "a/r_1", "transform_matrix": pose},
                    {"file_path": second, "transform_matrix": pose},
                ]
            })
            .to_string(),
        )
        .unwrap();
        base_3dgs::render_views::dataset_cameras(dir.path(), None, &LoadOptions::default())
    };
    let found = cameras("b/r_2").unwrap();
    let names: Vec<_> = found.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["r_1.png", "r_2.png"]);
    assert_eq!((found[1].camera.width, found[1].camera.height), (8, 6));
    let e = cameras("b/r_1").unwrap_err().to_string();
    assert!(
        e.contains("a/r_1.png")
            && e.contains("b/r_1.png")
            && e.contains("both be written to r_1.png"),
        "{e}"
    );
}
