//! A 3D run given only the model: no dataset, the views from an INRIA `cameras.json` (beside
//! the model as INRIA lays out its outputs, or given) or from an orbit made from the model, and
//! the model's own renders as the ground truth.

mod common;
// The scene's dataset writers are the other tests'.
#[allow(dead_code)]
mod scene;

use std::path::{Path, PathBuf};

use base_3dgs::stylize::{run, RunOptions, SceneStylizeConfig, StyleSettings};
use common::TempDir;
use gs_core::dataset::inria_cameras;
use gs_core::dataset::LoadOptions;
use gs_core::orbit::OrbitKind;
use gs_core::ply::{read_ply, write_ply, PlyFormat, PlyGaussians};
use gs_core::raster::render;
use gs_core::splats::{read_splats, write_splats, SplatFormat};
use gs_core::Camera;
use gs_stylize::model_views::ModelViews;
use gs_stylize::rates::gaussian_stylization;
use gs_wgpu::backend::DeviceChoice;
use scene::{c2w, fixture, random_set, write_tiny_clip, FOV_X, SIZE, VIEWS};

/// A configuration that stylizes `model` alone with the tiny models, 6 steps, into `dir/out`.
fn config(dir: &Path, model: PathBuf) -> SceneStylizeConfig {
    let (clip_config, clip_weights) = write_tiny_clip(dir);
    SceneStylizeConfig {
        model: Some(model),
        out: Some(dir.join("out")),
        views: ModelViews {
            orbit_views: 5,
            width: SIZE,
            height: 40,
            ..ModelViews::default()
        },
        style: StyleSettings {
            style_prompt: Some("fire".into()),
            steps: 6,
            seed: 2,
            device: DeviceChoice::Cpu,
            patch_size: 32,
            num_patches: 2,
            checkpoint_every: 0,
            clip_config: Some(clip_config),
            clip_weights: Some(clip_weights),
            tokenizer: Some(fixture("tokenizer/tokenizer.json")),
            vgg_weights: Some(fixture("tiny_vgg19.safetensors")),
            vgg_widths: [4, 8, 16, 32, 32],
            ..StyleSettings::paper_3d()
        },
        learning_rates: gaussian_stylization(0.05),
        ..SceneStylizeConfig::default()
    }
}

/// INRIA's `camera_to_JSON` of the scene's NeRF cameras: the camera-to-world rotation in
/// OpenCV axes (Blender's with y and z turned, as INRIA's NeRF loader does) and the centre.
fn inria_cameras_json() -> String {
    let fx = f64::from(SIZE) / (2.0 * (FOV_X / 2.0).tan());
    let entries: Vec<serde_json::Value> = (0..VIEWS)
        .map(|k| {
            let m = c2w(k);
            let rotation: Vec<[f64; 3]> = (0..3).map(|i| [m[i][0], -m[i][1], -m[i][2]]).collect();
            serde_json::json!({
                "id": k, "img_name": format!("r_{k}"), "width": SIZE, "height": SIZE,
                "position": [m[0][3], m[1][3], m[2][3]], "rotation": rotation,
                "fy": fx, "fx": fx,
            })
        })
        .collect();
    serde_json::to_string_pretty(&entries).unwrap()
}

/// A run's losses at its first step: the content term is 0, its target being the very render
/// the step starts from.
fn first_content(out: &Path) -> f32 {
    let losses: Vec<gs_stylize::outputs::StepLosses> = serde_json::from_str(
        &std::fs::read_to_string(out.join(gs_stylize::outputs::LOSSES_JSON)).unwrap(),
    )
    .unwrap();
    losses[0].terms["content"]
}

#[test]
fn inria_cameras_json_reads_as_the_nerf_cameras_it_was_written_from() {
    let dir = TempDir::new("alone-inria-read");
    let path = dir.path().join(inria_cameras::FILE_NAME);
    std::fs::write(&path, inria_cameras_json()).unwrap();
    let views = inria_cameras::read(&path, &LoadOptions::default()).unwrap();
    assert_eq!(views.len(), VIEWS);
    let set = random_set();
    for (k, view) in views.iter().enumerate() {
        let nerf = Camera::from_nerf(c2w(k), FOV_X, SIZE, SIZE).unwrap();
        let a = render(&set, &view.view.camera, [0.0; 3]).image.data;
        let b = render(&set, &nerf, [0.0; 3]).image.data;
        let worst = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max);
        assert!(worst < 1e-4, "view {k}: {worst}");
        assert!(a.iter().any(|v| *v > 0.05), "view {k} sees the scene");
    }
}

/// INRIA's layout: `<run>/point_cloud/iteration_7/point_cloud.ply` and `<run>/cameras.json`.
/// The run takes those cameras (its first preview is the model seen from the first of them),
/// keeps the count and the PLY's extras, and its first content loss is 0.
#[test]
fn a_model_in_inria_layout_trains_on_the_cameras_beside_it() {
    let dir = TempDir::new("alone-inria-run");
    let iteration = dir.path().join("point_cloud/iteration_7");
    std::fs::create_dir_all(&iteration).unwrap();
    let model = iteration.join("point_cloud.ply");
    write_ply(
        &model,
        &PlyGaussians::new(random_set()),
        PlyFormat::BinaryLittleEndian,
    )
    .unwrap();
    std::fs::write(
        dir.path().join(inria_cameras::FILE_NAME),
        inria_cameras_json(),
    )
    .unwrap();
    let config = config(dir.path(), model);
    let summary = run(&config, &RunOptions::default()).unwrap();
    assert_eq!(summary.gaussians.len(), random_set().len());
    let out = config.out.clone().unwrap();
    assert_eq!(first_content(&out), 0.0);
    assert_first_view_is_r_0(&out);
}

/// The "before" half of the run's preview in `out` is the model seen by the scene's first NeRF
/// camera, `r_0`: the run trained on those cameras.
fn assert_first_view_is_r_0(out: &Path) {
    let preview = image::open(out.join("preview.png")).unwrap().to_rgb8();
    assert_eq!((preview.width(), preview.height()), (2 * SIZE, SIZE));
    let nerf = Camera::from_nerf(c2w(0), FOV_X, SIZE, SIZE).unwrap();
    let expected = render(&random_set(), &nerf, [0.0; 3]).image;
    let mut worst = 0.0f32;
    for y in 0..SIZE {
        for x in 0..SIZE {
            let p = preview.get_pixel(x, y);
            for c in 0..3 {
                let want = expected.data[3 * (y * SIZE + x) as usize + c].clamp(0.0, 1.0);
                worst = worst.max((f32::from(p[c]) / 255.0 - want).abs());
            }
        }
    }
    assert!(
        worst <= 1.0 / 255.0,
        "the 'before' half is camera r_0's view: {worst}"
    );
}

/// `--cameras` naming a NeRF-synthetic folder (or its transforms file) takes its cameras,
/// the run training on them; the pictures are not decoded, but where the json gives no size a
/// picture's header is needed, and a missing one is named before any output.
#[test]
fn cameras_from_a_nerf_folder_are_taken_naming_a_missing_picture() {
    let dir = TempDir::new("alone-nerf-cameras");
    let (model, data) = scene::write_scene(dir.path());
    let with = |cameras: PathBuf, out: &str| {
        let mut c = config(dir.path(), model.clone());
        c.views.cameras = Some(cameras);
        c.out = Some(dir.path().join(out));
        c
    };
    for (out, cameras) in [
        ("folder", data.clone()),
        ("file", data.join("transforms_train.json")),
    ] {
        let config = with(cameras, out);
        let summary = run(&config, &RunOptions::default()).unwrap();
        assert_eq!(summary.gaussians.len(), random_set().len());
        assert_first_view_is_r_0(config.out.as_ref().unwrap());
    }
    std::fs::remove_file(data.join("train/r_0.png")).unwrap();
    fails_cleanly(&with(data.clone(), "missing"), &["r_0.png", "not found"]);
}

/// An SPZ file alone: an orbit made from it, the stylized scene written as PLY and as SPZ.
#[test]
fn an_spz_file_alone_is_stylized_from_an_orbit() {
    let dir = TempDir::new("alone-spz");
    let model = dir.path().join("scene.spz");
    write_splats(&model, &PlyGaussians::new(random_set()), SplatFormat::Spz).unwrap();
    let config = config(dir.path(), model.clone());
    let summary = run(&config, &RunOptions::default()).unwrap();
    let out = config.out.clone().unwrap();
    let input = read_splats(&model).unwrap().gaussians;
    let ply = read_ply(&out.join("model.ply")).unwrap().gaussians;
    assert_eq!(ply, summary.gaussians);
    assert_ne!(ply, input, "the parameters moved");
    let spz = read_splats(&out.join("model.spz")).unwrap().gaussians;
    assert_eq!(spz.len(), input.len());
    assert_eq!(first_content(&out), 0.0);
    let preview = image::open(out.join("preview.png")).unwrap();
    assert_eq!((preview.width(), preview.height()), (2 * SIZE, 40));
    // The inside orbit runs as well.
    let mut inside = config;
    inside.views.orbit = Some(OrbitKind::Inside);
    inside.out = Some(dir.path().join("inside"));
    let summary = run(&inside, &RunOptions::default()).unwrap();
    assert_eq!(summary.gaussians.len(), input.len());
}

fn fails_cleanly(config: &SceneStylizeConfig, words: &[&str]) {
    let message = run(config, &RunOptions::default()).unwrap_err().to_string();
    for w in words {
        assert!(message.contains(w), "{w:?} not in {message:?}");
    }
    assert!(
        !config.out.as_ref().unwrap().exists(),
        "{message}: output made"
    );
}

#[test]
fn a_model_or_cameras_that_show_nothing_are_refused_naming_them() {
    let dir = TempDir::new("alone-bad");
    let model = dir.path().join("scene.ply");
    write_ply(
        &model,
        &PlyGaussians::new(random_set()),
        PlyFormat::BinaryLittleEndian,
    )
    .unwrap();
    let base = config(dir.path(), model.clone());

    // Cameras that all look away from the scene: each moved far out, facing the way it did.
    let mut away: Vec<serde_json::Value> = serde_json::from_str(&inria_cameras_json()).unwrap();
    for e in &mut away {
        e["position"] = serde_json::json!([100.0, 100.0, 100.0]);
    }
    let away_path = dir.path().join("away.json");
    std::fs::write(&away_path, serde_json::to_string(&away).unwrap()).unwrap();
    let with_cameras = |path: PathBuf| {
        let mut c = base.clone();
        c.views.cameras = Some(path);
        c
    };
    fails_cleanly(
        &with_cameras(away_path.clone()),
        &[
            "scene.ply",
            "none of the 4 view(s)",
            "away.json",
            "--cameras",
        ],
    );

    // A model of no visible Gaussian (a PLY holds only finite values).
    let mut broken = random_set();
    broken.opacity_logits.fill(-1e30);
    let nan = dir.path().join("clear.ply");
    write_ply(
        &nan,
        &PlyGaussians::new(broken),
        PlyFormat::BinaryLittleEndian,
    )
    .unwrap();
    fails_cleanly(
        &config(dir.path(), nan),
        &["clear.ply", "none of the 80 Gaussians"],
    );

    // Cameras that are not there, or not cameras.
    fails_cleanly(
        &with_cameras(dir.path().join("missing.json")),
        &["missing.json", "not found"],
    );
    let text = dir.path().join("notes.txt");
    std::fs::write(&text, "hello").unwrap();
    fails_cleanly(&with_cameras(text), &["notes.txt", "INRIA cameras.json"]);
    // A camera of the file that is no camera is named by its entry.
    let skewed = inria_cameras_json().replacen("\"fx\": ", "\"fx\": -", 1);
    let skewed_path = dir.path().join(inria_cameras::FILE_NAME);
    std::fs::write(&skewed_path, skewed).unwrap();
    fails_cleanly(
        &with_cameras(skewed_path),
        &["cameras.json", "camera 0 (img_name \"r_0\")"],
    );

    // Data and cameras, or data and an orbit, together.
    let mut with_orbit = base.clone();
    with_orbit.views.orbit = Some(OrbitKind::Object);
    for mut edit in [with_cameras(away_path.clone()), with_orbit] {
        edit.data = Some(dir.path().to_path_buf());
        fails_cleanly(&edit, &["--data"]);
    }
}

/// `clipgaussian-3d stylize --model scene.spz --style-prompt fire --out o`, the weights aside:
/// the run says where its cameras came from and writes the scene in both formats.
#[test]
fn the_binary_stylizes_a_splat_file_alone() {
    let dir = TempDir::new("alone-cli");
    let model = dir.path().join("scene.spz");
    write_splats(&model, &PlyGaussians::new(random_set()), SplatFormat::Spz).unwrap();
    let c = config(dir.path(), model.clone());
    let out = dir.path().join("cli-out");
    let path = |p: &Option<PathBuf>| p.as_ref().unwrap().display().to_string();
    let ok = std::process::Command::new(env!("CARGO_BIN_EXE_clipgaussian-3d"))
        .arg("stylize")
        .args(["--model", &model.display().to_string()])
        .args([
            "--style-prompt",
            "fire",
            "--out",
            &out.display().to_string(),
        ])
        .args([
            "--steps",
            "2",
            "--orbit-views",
            "3",
            "--width",
            "40",
            "--height",
            "32",
        ])
        .args(["--clip-config", &path(&c.style.clip_config)])
        .args(["--clip-weights", &path(&c.style.clip_weights)])
        .args(["--tokenizer", &path(&c.style.tokenizer)])
        .args(["--vgg-weights", &path(&c.style.vgg_weights)])
        .args([
            "--set",
            "vgg_widths=[4,8,16,32,32]",
            "--set",
            "patch_size=32",
        ])
        .args(["--set", "num_patches=2", "--device", "cpu"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&ok.stderr);
    assert!(ok.status.success(), "{stderr}");
    assert!(
        stderr.contains("cameras: 3 view(s) of an object orbit (chosen"),
        "{stderr}"
    );
    assert!(!stderr.to_lowercase().contains("error"), "{stderr}");
    assert_eq!(
        read_splats(&out.join("model.spz")).unwrap().gaussians.len(),
        80
    );
    assert_eq!(
        read_ply(&out.join("model.ply")).unwrap().gaussians.len(),
        80
    );
}
