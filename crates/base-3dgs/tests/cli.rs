//! The `render`, `interpolate` and `eval` subcommands of `clipgaussian-3d` on the tiny scene:
//! what they write, and errors that are named and leave no output behind.

mod common;
mod scene;

use gs_stylize::test_support::cpu_selftest_table;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::TempDir;
use gs_core::ply::{read_ply, write_ply, PlyFormat, PlyGaussians};
use gs_core::raster::render;
use gs_core::Camera;
use scene::{
    c2w, fixture, random_set, write_colmap_scene, write_scene, write_tiny_clip, FOV_X, SIZE, VIEWS,
};

/// Runs `clipgaussian-3d` with `args`.
fn cli(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_clipgaussian-3d"))
        .args(args)
        .output()
        .unwrap()
}

/// Runs `clipgaussian-3d` with `args` and expects success.
fn succeeds(args: &[&str]) -> String {
    let out = cli(args);
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Runs `clipgaussian-3d` with `args`, expects a failure whose message contains every one of
/// `words`, and checks that `output` was not created.
fn fails(args: &[&str], words: &[&str], output: &Path) {
    let out = cli(args);
    assert!(!out.status.success(), "{args:?} succeeded");
    let stderr = String::from_utf8_lossy(&out.stderr);
    for w in words {
        assert!(stderr.contains(w), "{w:?} not in {stderr:?}");
    }
    assert!(
        !output.exists(),
        "{stderr}: {} was created",
        output.display()
    );
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn png(path: &Path) -> image::RgbImage {
    image::open(path).unwrap().to_rgb8()
}

#[test]
fn render_from_a_dataset_writes_one_picture_per_view_as_gs_core_renders_it() {
    let dir = TempDir::new("cli-render-data");
    let (ply, data) = write_scene(dir.path());
    let out = dir.path().join("renders");
    succeeds(&[
        "render",
        "--ply",
        s(&ply),
        "--data",
        s(&data),
        "--out",
        s(&out),
        "--background",
        "white",
    ]);
    let set = read_ply(&ply).unwrap().gaussians;
    let mut names: Vec<String> = std::fs::read_dir(out.join("frames"))
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    let expected: Vec<String> = (0..VIEWS).map(|k| format!("r_{k}.png")).collect();
    assert_eq!(names, expected);
    for k in 0..VIEWS {
        let written = png(&out.join("frames").join(format!("r_{k}.png")));
        assert_eq!(written.dimensions(), (SIZE, SIZE));
        let camera = Camera::from_nerf(c2w(k), FOV_X, SIZE, SIZE).unwrap();
        assert!(written == render(&set, &camera, [1.0; 3]).image.to_rgb8());
    }

    let half = dir.path().join("half");
    succeeds(&[
        "render",
        "--ply",
        s(&ply),
        "--data",
        s(&data),
        "-r",
        "2",
        "--out",
        s(&half),
    ]);
    assert_eq!(
        png(&half.join("frames/r_0.png")).dimensions(),
        (SIZE / 2, SIZE / 2)
    );

    let missing = dir.path().join("missing");
    fails(
        &[
            "render",
            "--ply",
            s(&ply),
            "--data",
            s(&data),
            "--split",
            "test",
            "--out",
            s(&missing),
        ],
        &["transforms_test.json"],
        &missing,
    );
    fails(
        &[
            "render",
            "--ply",
            s(&dir.path().join("none.ply")),
            "--data",
            s(&data),
            "--out",
            s(&missing),
        ],
        &["none.ply"],
        &missing,
    );
    fails(
        &[
            "render",
            "--ply",
            s(&ply),
            "--data",
            s(dir.path()),
            "--out",
            s(&missing),
        ],
        &["neither", "sparse"],
        &missing,
    );
}

#[test]
fn render_from_a_colmap_dataset_names_pictures_after_its_images() {
    let dir = TempDir::new("cli-render-colmap");
    let (ply, _) = write_scene(dir.path());
    let data = write_colmap_scene(dir.path());
    let out = dir.path().join("renders");
    succeeds(&[
        "render",
        "--ply",
        s(&ply),
        "--data",
        s(&data),
        "--out",
        s(&out),
    ]);
    let set = read_ply(&ply).unwrap().gaussians;
    for k in 0..VIEWS {
        let written = png(&out.join("frames").join(format!("r_{k}.png")));
        let camera = Camera::from_nerf(c2w(k), FOV_X, SIZE, SIZE).unwrap();
        // Over black by default, as stylize renders.
        let want = render(&set, &camera, [0.0; 3]).image.to_rgb8();
        // The COLMAP poses went through a quaternion: allow one 8-bit step of difference.
        let worst = written
            .as_raw()
            .iter()
            .zip(want.as_raw())
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap();
        assert!(worst <= 1, "view {k}: off by {worst}");
    }
}

#[test]
fn render_from_a_camera_file_writes_render_png() {
    let dir = TempDir::new("cli-render-camera");
    let (ply, _) = write_scene(dir.path());
    let camera = Camera::from_nerf(c2w(1), FOV_X, SIZE, SIZE).unwrap();
    let (r, t) = (camera.rotation, camera.translation);
    let file = |last_row: [f64; 4]| {
        serde_json::json!({
            "width": SIZE, "height": SIZE,
            "fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy,
            "world_to_camera": [
                [r[0][0], r[0][1], r[0][2], t[0]],
                [r[1][0], r[1][1], r[1][2], t[1]],
                [r[2][0], r[2][1], r[2][2], t[2]],
                last_row,
            ],
        })
        .to_string()
    };
    let json = dir.path().join("camera.json");
    std::fs::write(&json, file([0.0, 0.0, 0.0, 1.0])).unwrap();
    let out = dir.path().join("one");
    succeeds(&[
        "render",
        "--ply",
        s(&ply),
        "--camera",
        s(&json),
        "--out",
        s(&out),
    ]);
    let set = read_ply(&ply).unwrap().gaussians;
    assert!(png(&out.join("frames/render.png")) == render(&set, &camera, [0.0; 3]).image.to_rgb8());

    let bad = dir.path().join("bad.json");
    std::fs::write(&bad, file([0.0, 0.0, 1.0, 1.0])).unwrap();
    let missing = dir.path().join("missing");
    fails(
        &[
            "render",
            "--ply",
            s(&ply),
            "--camera",
            s(&bad),
            "--out",
            s(&missing),
        ],
        &["bad.json", "last row"],
        &missing,
    );
    let help = succeeds(&["render", "--help"]);
    assert!(
        help.contains("world_to_camera") && help.contains("OpenCV"),
        "{help}"
    );
}

#[test]
fn interpolate_at_zero_is_a_and_mismatched_counts_are_named() {
    let dir = TempDir::new("cli-interpolate");
    let (a, _) = write_scene(dir.path());
    let mut other = random_set();
    other.means.iter_mut().for_each(|v| *v += 0.25);
    other.sh_dc.iter_mut().for_each(|v| *v = -*v);
    let b = dir.path().join("b.ply");
    write_ply(&b, &PlyGaussians::new(other), PlyFormat::BinaryLittleEndian).unwrap();
    let out = dir.path().join("mix.ply");
    succeeds(&[
        "interpolate",
        "--a",
        s(&a),
        "--b",
        s(&b),
        "--t",
        "0",
        "--out",
        s(&out),
    ]);
    let input = read_ply(&a).unwrap();
    let mixed = read_ply(&out).unwrap();
    assert!(std::fs::read(&out)
        .unwrap()
        .starts_with(b"ply\nformat ascii"));
    assert_eq!(mixed.extras, input.extras);
    let (x, y) = (&mixed.gaussians, &input.gaussians);
    assert_eq!(
        (
            &x.means,
            &x.log_scales,
            &x.opacity_logits,
            &x.sh_dc,
            &x.sh_rest
        ),
        (
            &y.means,
            &y.log_scales,
            &y.opacity_logits,
            &y.sh_dc,
            &y.sh_rest
        )
    );
    for (q, p) in x.quats.chunks(4).zip(y.quats.chunks(4)) {
        let n = p.iter().map(|v| v * v).sum::<f32>().sqrt();
        for (u, v) in q.iter().zip(p) {
            assert!((u - v / n).abs() < 1e-6, "{q:?} vs {p:?}");
        }
    }

    let small = gs_core::GaussianSet::zeros(5, 1);
    assert_eq!(small.len(), 5);
    let c = dir.path().join("small.ply");
    write_ply(&c, &PlyGaussians::new(small), PlyFormat::Ascii).unwrap();
    let missing = dir.path().join("missing.ply");
    fails(
        &[
            "interpolate",
            "--a",
            s(&a),
            "--b",
            s(&c),
            "--t",
            "0.5",
            "--out",
            s(&missing),
        ],
        &["80", "5", "small.ply"],
        &missing,
    );
    fails(
        &[
            "interpolate",
            "--a",
            s(&a),
            "--b",
            s(&b),
            "--t",
            "NaN",
            "--out",
            s(&missing),
        ],
        &["NaN"],
        &missing,
    );
}

/// `interpolate` reads every splat format the scene readers know and writes the one its
/// `--out` ends in: two SPZ files blended at t = 1 give B again, as an SPZ file.
#[test]
fn interpolate_reads_and_writes_splat_formats() {
    use gs_core::splats::{read_splats, write_splats, SplatFormat};
    let dir = TempDir::new("cli-interpolate-spz");
    let mut other = random_set();
    other.means.iter_mut().for_each(|v| *v += 0.25);
    let (a, b) = (dir.path().join("a.spz"), dir.path().join("b.spz"));
    write_splats(&a, &PlyGaussians::new(random_set()), SplatFormat::Spz).unwrap();
    write_splats(&b, &PlyGaussians::new(other), SplatFormat::Spz).unwrap();
    let out = dir.path().join("mix.spz");
    let said = succeeds(&[
        "interpolate",
        "--a",
        s(&a),
        "--b",
        s(&b),
        "--t",
        "1",
        "--out",
        s(&out),
    ]);
    assert!(said.contains("80 Gaussians, t = 1"), "{said}");
    let bytes = std::fs::read(&out).unwrap();
    assert!(!bytes.starts_with(b"ply"), "an SPZ file, not a PLY");
    let (mixed, expected) = (read_splats(&out).unwrap(), read_splats(&b).unwrap());
    assert_eq!(mixed.gaussians.len(), expected.gaussians.len());
    for (x, y) in mixed.gaussians.means.iter().zip(&expected.gaussians.means) {
        // SPZ's positions are fixed point at 1/4096 of a unit (12 fraction bits).
        assert!((x - y).abs() <= 1.0 / 4096.0, "{x} vs {y}");
    }
}

/// The `eval` arguments for `renders` against `gt` with the tiny CLIP in `dir`, writing `out`.
fn eval_args(clip: &(PathBuf, PathBuf), renders: &Path, gt: &Path, out: &Path) -> Vec<String> {
    let tokenizer = fixture("tokenizer/tokenizer.json");
    [
        "eval",
        "--renders",
        s(renders),
        "--gt",
        s(gt),
        "--style-prompt",
        "fire",
        "--clip-config",
        s(&clip.0),
        "--clip-weights",
        s(&clip.1),
        "--tokenizer",
        s(&tokenizer),
        "--out",
        s(out),
    ]
    .iter()
    .map(|a| a.to_string())
    .collect()
}

#[test]
fn eval_scores_matching_folders_and_names_the_unmatched_pictures() {
    let dir = TempDir::new("cli-eval");
    let (ply, data) = write_scene(dir.path());
    let clip = write_tiny_clip(dir.path());
    let out = dir.path().join("renders");
    succeeds(&[
        "render",
        "--ply",
        s(&ply),
        "--data",
        s(&data),
        "--out",
        s(&out),
    ]);
    let renders = out.join("frames");
    let gt = data.join("train");
    std::fs::write(gt.join("notes.txt"), "not a picture").unwrap();

    let metrics = dir.path().join("metrics.json");
    let args = eval_args(&clip, &renders, &gt, &metrics);
    let stdout = succeeds(&args.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(
        stdout.contains("CLIP-S") && stdout.contains("CLIP-F"),
        "{stdout}"
    );
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&metrics).unwrap()).unwrap();
    assert_eq!(m["views"], VIEWS);
    for key in ["clip_s", "clip_sim", "clip_cons", "clip_f"] {
        assert!(m[key].as_f64().unwrap().is_finite(), "{key}: {m}");
    }

    let same = dir.path().join("same.json");
    let args = eval_args(&clip, &renders, &renders, &same);
    succeeds(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&same).unwrap()).unwrap();
    assert!((m["clip_f"].as_f64().unwrap() - 100.0).abs() < 1e-9, "{m}");
    assert_eq!(m["clip_sim"].as_f64().unwrap(), 0.0, "{m}");

    std::fs::rename(renders.join("r_1.png"), renders.join("extra.png")).unwrap();
    let missing = dir.path().join("missing.json");
    let args = eval_args(&clip, &renders, &gt, &missing);
    fails(
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
        &[
            format!(
                "{} and {} hold different pictures",
                renders.display(),
                gt.display()
            )
            .as_str(),
            "only in the renders: [extra.png]",
            "only in the ground truths: [r_1.png]",
        ],
        &missing,
    );
    std::fs::rename(renders.join("extra.png"), renders.join("r_1.png")).unwrap();
    let small = image::open(renders.join("r_2.png"))
        .unwrap()
        .thumbnail(4, 4);
    small.save(renders.join("r_2.png")).unwrap();
    let args = eval_args(&clip, &renders, &gt, &missing);
    fails(
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
        &["r_2.png: the render is 4x4 but its ground truth", "-r"],
        &missing,
    );
    let empty = dir.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let args = eval_args(&clip, &empty, &empty, &missing);
    fails(
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
        &["no picture", "empty"],
        &missing,
    );
    // An empty renders folder against a full one says it is empty, naming it.
    let args = eval_args(&clip, &empty, &gt, &missing);
    fails(
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
        &["no picture", "empty"],
        &missing,
    );
    // A style picture that does not decode is named as the style image.
    let garbage = dir.path().join("garbage.png");
    std::fs::write(&garbage, b"not a picture").unwrap();
    let mut args = eval_args(&clip, &renders, &renders, &missing);
    let prompt = args.iter().position(|a| a == "--style-prompt").unwrap();
    args.splice(
        prompt..prompt + 2,
        ["--style-image".into(), s(&garbage).into()],
    );
    fails(
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
        &["style image: ", "garbage.png"],
        &missing,
    );
    let a_file = renders.join("r_2.png");
    let args = eval_args(&clip, &a_file, &gt, &missing);
    fails(
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
        &["r_2.png: a file, not a folder of pictures"],
        &missing,
    );
}

#[test]
fn a_gpu_run_without_a_desktop_session_prints_no_error_line() {
    // Without XDG_RUNTIME_DIR, Mesa's Vulkan layer VK_LAYER_MESA_device_select made
    // libwayland print `error: XDG_RUNTIME_DIR is invalid or not set in the environment.`
    // while the adapters were enumerated, on runs that then succeeded.
    if !gs_wgpu::test_adapter_exists() {
        return;
    }
    let dir = TempDir::new("cli-no-session");
    let (ply, data) = write_scene(dir.path());
    let out = dir.path().join("renders");
    let run = Command::new(env!("CARGO_BIN_EXE_clipgaussian-3d"))
        .args([
            "render",
            "--ply",
            s(&ply),
            "--data",
            s(&data),
            "--out",
            s(&out),
        ])
        .args(["--device", "gpu"])
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("NODEVICE_SELECT")
        .env(gs_wgpu::backend::ALLOW_SOFTWARE_GPU, "1")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{stderr}");
    assert!(
        String::from_utf8_lossy(&run.stdout).contains("device: gpu: "),
        "the run opened the GPU"
    );
    let errors: Vec<&str> = stderr.lines().filter(|l| l.starts_with("error:")).collect();
    assert!(errors.is_empty(), "a successful run printed {errors:?}");
    assert!(out.join("frames/r_0.png").is_file());
}

#[test]
fn outputs_that_cannot_be_written_are_refused_before_any_work() {
    let dir = TempDir::new("cli-outputs");
    let (ply, data) = write_scene(dir.path());
    let file = dir.path().join("notes.txt");
    std::fs::write(&file, "not a folder").unwrap();
    let notes = s(&file);
    let missing_ply = dir.path().join("none.ply");
    // The other inputs are bad too: the output is checked first.
    let out = cli(&[
        "render",
        "--ply",
        s(&missing_ply),
        "--data",
        s(&data),
        "--out",
        notes,
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success()
            && stderr.contains(&format!("output folder {notes}: it is a file"))
            && stderr.contains("must be a folder")
            && !stderr.contains("none.ply"),
        "{stderr}"
    );
    let inside = file.join("renders");
    let out = cli(&[
        "render",
        "--ply",
        s(&ply),
        "--data",
        s(&data),
        "--out",
        s(&inside),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains(&format!("{notes} is a file, so no folder can be made")),
        "{stderr}"
    );

    let clip = write_tiny_clip(dir.path());
    let metrics = file.join("metrics.json");
    let args = eval_args(&clip, &missing_ply, &data, &metrics);
    let out = cli(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains(&format!("output file {}: {notes} is a file", s(&metrics))),
        "{stderr}"
    );
    let args = eval_args(&clip, &data, &data, dir.path());
    let out = cli(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("it is a folder"), "{stderr}");

    let out = cli(&["interpolate", "--a", s(&ply), "--b", s(&ply), "--t", "0.5"]);
    assert!(!out.status.success(), "--out is required");
    let out = cli(&[
        "interpolate",
        "--a",
        s(&missing_ply),
        "--b",
        s(&ply),
        "--t",
        "0.5",
        "--out",
        s(&dir.path().join("none/mix.ply")),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("none does not exist"), "{stderr}");

    let out = cli(&[
        "stylize",
        "--ply",
        s(&missing_ply),
        "--data",
        s(&data),
        "--out",
        notes,
        "--style-prompt",
        "fire",
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains(&format!("output folder {notes}: it is a file"))
            && !stderr.contains("none.ply"),
        "{stderr}"
    );
    let mut names: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    assert!(!names.iter().any(|n| n.starts_with('.')), "{names:?}");
}

#[test]
fn eval_refuses_an_empty_prompt_and_names_the_flag_of_a_missing_model_file() {
    let dir = TempDir::new("cli-eval-inputs");
    let (_, data) = write_scene(dir.path());
    let clip = write_tiny_clip(dir.path());
    let gt = data.join("train");
    let metrics = dir.path().join("metrics.json");
    let mut args = eval_args(&clip, &gt, &gt, &metrics);
    let prompt = args.iter().position(|a| a == "fire").unwrap();
    for empty in ["", "   "] {
        args[prompt] = empty.to_string();
        fails(
            &args.iter().map(String::as_str).collect::<Vec<_>>(),
            &["error: the style prompt is empty"],
            &metrics,
        );
    }
    args[prompt] = "fire".into();
    let weights = args.iter().position(|a| a == "--clip-weights").unwrap() + 1;
    args[weights] = s(&dir.path().join("gone.safetensors")).to_string();
    fails(
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
        &[
            "1 model file(s) missing",
            "gone.safetensors",
            "pass its path with --clip-weights, set",
        ],
        &metrics,
    );
}

#[test]
fn stylize_help_says_what_it_writes_and_where_the_weights_come_from() {
    let help = succeeds(&["stylize", "--help"]);
    for text in [
        "model.ply",
        "viewer.html",
        "preview.png",
        "losses.json",
        "losses.png",
        "config.json",
        "checkpoint/",
        "default 1",
        "downloaded from the Hugging Face Hub",
    ] {
        assert!(help.contains(text), "{text:?} not in {help}");
    }
    let help = succeeds(&["eval", "--help"]);
    assert!(
        help.contains("downloaded from the Hugging Face Hub"),
        "{help}"
    );
}

#[test]
fn stylize_renders_over_black_unless_another_background_is_asked() {
    let dir = TempDir::new("cli-stylize-background");
    let (ply, data) = write_scene(dir.path());
    let (clip_config, clip_weights) = write_tiny_clip(dir.path());
    let tokenizer = fixture("tokenizer/tokenizer.json");
    let vgg = fixture("tiny_vgg19.safetensors");
    for (i, (flags, rgb)) in [
        (vec![], [0.0; 3]),
        (vec!["--background", "white"], [1.0; 3]),
        (vec!["--background", "0.25,0.5,1"], [0.25, 0.5, 1.0]),
    ]
    .into_iter()
    .enumerate()
    {
        let out = dir.path().join(format!("out-{i}"));
        let mut args = vec![
            "stylize",
            "--ply",
            s(&ply),
            "--data",
            s(&data),
            "--out",
            s(&out),
            "--style-prompt",
            "fire",
            "--steps",
            "1",
            "--device",
            "cpu",
            "--quiet",
            "--clip-config",
            s(&clip_config),
            "--clip-weights",
            s(&clip_weights),
            "--tokenizer",
            s(&tokenizer),
            "--vgg-weights",
            s(&vgg),
            "--set",
            "vgg_widths=[4,8,16,32,32]",
            "--set",
            "patch_size=16",
            "--set",
            "num_patches=2",
        ];
        args.extend(flags);
        succeeds(&args);
        let config: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("config.json")).unwrap())
                .unwrap();
        assert_eq!(config["background"], serde_json::json!(rgb));
        assert_eq!(config["ground_truth"], "file_colour");
        assert_eq!(config["steps"], 1);
    }
}

#[test]
fn selftest_on_the_cpu_prints_every_part_and_passes() {
    let table = cpu_selftest_table(Path::new(env!("CARGO_BIN_EXE_clipgaussian-3d")));
    assert!(table.contains("| loss gradient (four terms) |"), "{table}");
}

/// A model of another modality is refused naming the binary that opens it, by `render` and
/// `stylize` (through `--model` and its alias `--ply`) and by `interpolate`.
#[test]
fn a_model_of_another_modality_names_its_binary() {
    let dir = TempDir::new("cli-foreign-models");
    gs_stylize::test_support::assert_every_command_refuses_foreign_models(
        gs_stylize::model_kind::Binary::Scene,
        std::path::Path::new(env!("CARGO_BIN_EXE_clipgaussian-3d")),
        dir.path(),
        "--ply",
        &["--camera", "c.json"],
    );
}

/// Every subcommand has the flags the four binaries share, under the same names.
#[test]
fn the_shared_flags_have_the_same_names_in_every_subcommand() {
    gs_stylize::test_support::assert_shared_flags(
        std::path::Path::new(env!("CARGO_BIN_EXE_clipgaussian-3d")),
        false,
    );
}

/// `export` writes a scene in every splat format; each reads back with the Gaussians (within
/// its quantisation), and `render` takes the SPZ as its model, rendering what the PLY renders
/// within SPZ's quantisation.
#[test]
fn export_writes_every_format_and_render_reads_them() {
    let dir = TempDir::new("cli-export");
    let (ply, data) = write_scene(dir.path());
    let scene = read_ply(&ply).unwrap();
    for name in [
        "scene.ply",
        "scene.compressed.ply",
        "scene.splat",
        "scene.spz",
        "scene.glb",
    ] {
        let out = dir.path().join(name);
        let line = succeeds(&["export", "--model", s(&ply), "--out", s(&out)]);
        assert!(
            line.contains(&format!("{} Gaussians", scene.gaussians.len())),
            "{line}"
        );
        if name.ends_with(".glb") {
            assert_eq!(&std::fs::read(&out).unwrap()[..4], b"glTF");
            continue;
        }
        let back = gs_core::splats::read_splats(&out).unwrap();
        assert_eq!(back.gaussians.len(), scene.gaussians.len(), "{name}");
    }
    // The INRIA PLY export keeps every property: the same file.
    assert_eq!(
        read_ply(&dir.path().join("scene.ply")).unwrap(),
        scene,
        "an exact copy"
    );
    let v2 = dir.path().join("old.spz");
    succeeds(&[
        "export",
        "--model",
        s(&ply),
        "--format",
        "spz-v2",
        "--out",
        s(&v2),
    ]);
    assert_eq!(
        gs_core::splats::read_splats(&v2).unwrap().gaussians.len(),
        scene.gaussians.len()
    );
    let renders = dir.path().join("renders");
    let from_spz = dir.path().join("from-spz");
    succeeds(&[
        "render",
        "--ply",
        s(&ply),
        "--data",
        s(&data),
        "--out",
        s(&renders),
    ]);
    succeeds(&[
        "render",
        "--ply",
        s(&dir.path().join("scene.spz")),
        "--data",
        s(&data),
        "--out",
        s(&from_spz),
    ]);
    let first = |dir: &Path| {
        let mut names: Vec<_> = std::fs::read_dir(dir.join("frames"))
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        names.sort();
        image::open(&names[0]).unwrap().to_rgb8()
    };
    let (a, b) = (first(&renders), first(&from_spz));
    let worst = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(x, y)| x.abs_diff(*y))
        .max()
        .unwrap();
    assert!(
        worst <= 6,
        "SPZ renders what the PLY renders: {worst} levels"
    );
    fails(
        &[
            "export",
            "--model",
            s(&ply),
            "--out",
            s(&dir.path().join("scene.obj")),
        ],
        &["scene.obj", "--format"],
        &dir.path().join("scene.obj"),
    );
}

/// `export --format html` (or an .html name) writes a viewer page of the model, with `--b`
/// (its stylization) for the slider; a `--b` of other Gaussians is refused naming both files,
/// and `--b` without a page is refused; nothing is written when refused.
#[test]
fn export_writes_a_viewer_page_of_one_model_or_two() {
    let dir = TempDir::new("cli-export-html");
    let (a, _) = write_scene(dir.path());
    let mut stylized = read_ply(&a).unwrap();
    stylized.gaussians.sh_dc.iter_mut().for_each(|v| *v = -*v);
    let b = dir.path().join("b.ply");
    write_ply(&b, &stylized, PlyFormat::BinaryLittleEndian).unwrap();
    let n = stylized.gaussians.len();
    let scene_of = |page: &Path| gs_stylize::viewer::read_scene(page).unwrap();
    let one = dir.path().join("one.html");
    let line = succeeds(&["export", "--model", s(&a), "--out", s(&one)]);
    assert!(
        line.contains(&format!("a viewer of {n} Gaussians")),
        "{line}"
    );
    let scene = scene_of(&one);
    assert_eq!(scene["models"].as_array().unwrap().len(), 1);
    assert_eq!(scene["cameras"].as_array().unwrap().len(), 16);
    let two = dir.path().join("two.page");
    let line = succeeds(&[
        "export",
        "--a",
        s(&a),
        "--b",
        s(&b),
        "--format",
        "html",
        "--out",
        s(&two),
    ]);
    assert!(line.contains("and their stylization"), "{line}");
    assert_eq!(scene_of(&two)["models"].as_array().unwrap().len(), 2);

    // The same scene less its last Gaussian.
    let g = &read_ply(&a).unwrap().gaussians;
    let m = n - 1;
    let fewer = PlyGaussians::new(
        gs_core::GaussianSet::from_arrays(
            g.means[..3 * m].to_vec(),
            g.log_scales[..3 * m].to_vec(),
            g.quats[..4 * m].to_vec(),
            g.opacity_logits[..m].to_vec(),
            &g.sh()[..3 * g.sh_coeffs() * m],
        )
        .unwrap(),
    );
    let c = dir.path().join("c.ply");
    write_ply(&c, &fewer, PlyFormat::BinaryLittleEndian).unwrap();
    let refused = dir.path().join("refused.html");
    fails(
        &[
            "export",
            "--model",
            s(&a),
            "--b",
            s(&c),
            "--out",
            s(&refused),
        ],
        &[
            "--b",
            "c.ply",
            &format!("{} Gaussians", n - 1),
            "same Gaussians",
        ],
        &refused,
    );
    let not_a_page = dir.path().join("refused.spz");
    fails(
        &[
            "export",
            "--model",
            s(&a),
            "--b",
            s(&b),
            "--out",
            s(&not_a_page),
        ],
        &["--b: only a viewer page"],
        &not_a_page,
    );
}
