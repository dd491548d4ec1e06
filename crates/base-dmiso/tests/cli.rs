//! `clipgaussian-4d` from file to file with the tiny random-weight CLIP and VGG: fit a
//! generated D-NeRF scene, stylize it (with the fitted model, with the fit inside the run and
//! resumed, and with a model in the authors' layout), keep the cores, sub-Gaussians and network
//! shapes, train the network with the Gaussians, interpolate, render, eval; refuse bad inputs
//! with a clear error and nothing written.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use base_dmiso::model::group;
use base_dmiso::model_file;
use base_dmiso::stylize::DynamicSceneStylizeConfig;
use base_dmiso::Dmiso;
use candle_core::Device;
use gs_core::dataset::Background;
use gs_stylize::test_support::{
    cpu_selftest_table, fails, fit_json_psnr, path_str as s, succeeds as run, tiny_style_flags,
};
use style_loss::test_models::{write_tiny_models, TinyModelFiles};

const SIZE: u32 = 32;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_clipgaussian-4d"))
}

fn scene(dir: &Path) -> PathBuf {
    let data = dir.join("scene");
    common::write_scene(&data, 8, 3, SIZE);
    data
}

/// The tiny fit's settings as `fit` flags.
const FIT: [&str; 14] = [
    "--gaussians",
    "200",
    "--steps",
    "40",
    "--warm-up",
    "10",
    "--subs-from",
    "25",
    "--sub-cores",
    "50",
    "--subs-per-core",
    "3",
    "--deform-width",
    "16",
];

fn load(path: &Path) -> Dmiso {
    model_file::load(path, &Device::Cpu).unwrap()
}

fn stylize_args(cmd: &mut Command, models: &TinyModelFiles, steps: u64) {
    cmd.args(["stylize", "--quiet", "--steps", &steps.to_string()]);
    tiny_style_flags(cmd, models);
    cmd.args(["--set", "sweep_frames=5"])
        .args(["--set", "checkpoint_every=2", "--device", "cpu"]);
}

fn count_pngs(dir: &Path) -> usize {
    std::fs::read_dir(dir)
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .path()
                .extension()
                .is_some_and(|x| x == "png")
        })
        .count()
}

#[test]
fn fit_stylize_interpolate_render_from_file_to_file() {
    let dir = tempfile::tempdir().unwrap();
    let models = write_tiny_models(dir.path());
    let data = scene(dir.path());
    let fitted = dir.path().join("fitted");
    let out = run(bin()
        .args(["fit", "--quiet", "--device", "cpu", "--data", s(&data)])
        .args(["--out", s(&fitted)])
        .args(FIT));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("mean PSNR") && text.contains("50 cores of 3 sub-Gaussians"),
        "{text}"
    );
    fit_json_psnr(&fitted, 40);
    assert_eq!(count_pngs(&fitted.join("frames")), 3);
    for preview in ["preview.png", "preview.gif"] {
        assert!(fitted.join(preview).is_file(), "the fit writes {preview}");
    }
    let base = load(&fitted.join("model.safetensors"));
    assert_eq!(
        (base.cores(), base.subs_per_core(), base.net().width),
        (50, 3, 16)
    );
    // Export: the Gaussians at one time to a file, at three times to a folder.
    let glb = dir.path().join("t.glb");
    run(bin()
        .args(["export", "--model", s(&fitted.join("model.safetensors"))])
        .args(["--time", "0.5", "--out", s(&glb)]));
    assert_eq!(&std::fs::read(&glb).unwrap()[..4], b"glTF");
    let times = dir.path().join("times");
    run(bin()
        .args(["export", "--model", s(&fitted.join("model.safetensors"))])
        .args([
            "--times",
            "3",
            "--format",
            "compressed-ply",
            "--out",
            s(&times),
        ]));
    let sets: Vec<_> = (0..3)
        .map(|i| {
            gs_core::splats::read_splats(&times.join(format!("{i:05}.compressed.ply")))
                .unwrap()
                .gaussians
        })
        .collect();
    let gaussians = gs_stylize::export::gaussians_at(&base, 0.0).unwrap().len();
    assert!(sets.iter().all(|g| g.len() == gaussians));
    assert_ne!(sets[0].means, sets[2].means, "the Gaussians move with time");
    let e = fails(
        bin()
            .args(["export", "--model", s(&fitted.join("model.safetensors"))])
            .args(["--time", "1.5", "--out", s(&dir.path().join("x.ply"))]),
    );
    assert!(e.contains("--time 1.5") && e.contains("[0, 1]"), "{e}");
    let recorded = |p: &Path| model_file::recorded_background(p).unwrap();
    assert_eq!(
        recorded(&fitted.join("model.safetensors")),
        Some(Background::White)
    );

    let styled = dir.path().join("styled");
    let mut cmd = bin();
    stylize_args(&mut cmd, &models, 3);
    let out = run(cmd
        .args(["--data", s(&data)])
        .args(["--model", s(&fitted.join("model.safetensors"))])
        .args(["--out", s(&styled)]));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("3 test views"), "{stdout}");
    assert!(
        stdout.lines().all(|l| !l.to_lowercase().contains("error")),
        "{stdout}"
    );
    for name in [
        "preview.gif",
        "preview.png",
        "losses.json",
        "losses.png",
        "config.json",
    ] {
        assert!(styled.join(name).is_file(), "{name}");
    }
    assert_eq!(count_pngs(&styled.join("frames")), 3);
    assert_eq!(count_pngs(&styled.join("sweep")), 5);
    // The sweep's mp4 is written exactly where ffmpeg is installed (not on CI).
    let ffmpeg = Command::new("ffmpeg").arg("-version").output().is_ok();
    assert_eq!(styled.join("sweep.mp4").is_file(), ffmpeg);
    assert_eq!(stdout.contains("no mp4"), !ffmpeg, "{stdout}");
    let stylized = load(&styled.join("model.safetensors"));
    assert_eq!(
        (stylized.cores(), stylized.subs_per_core(), stylized.net()),
        (base.cores(), base.subs_per_core(), base.net())
    );
    // Everything trains together: the Gaussians, the triangles, the network, the layer.
    for g in [
        group::PSEUDOMESH,
        group::ALPHA,
        group::DC,
        group::DEFORM,
        group::TIME_NET,
    ] {
        assert_ne!(
            stylized.params().groups[g],
            base.params().groups[g],
            "group {g} moved"
        );
    }
    let losses: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(styled.join("losses.json")).unwrap())
            .unwrap();
    assert_eq!(losses.as_array().unwrap().len(), 3);
    // The viewer: the fit and its stylization at 24 times, from the training cameras.
    let scene = gs_stylize::viewer::read_scene(&styled.join("viewer.html")).unwrap();
    assert_eq!(scene["animation"]["frames"], 24);
    assert_eq!(scene["animation"]["models"].as_array().unwrap().len(), 2);
    assert!(!scene["cameras"].as_array().unwrap().is_empty());
    // And a page of the two by export: 5 times, an orbit of 16 views.
    let page = dir.path().join("scene.html");
    let said = run(bin()
        .args(["export", "--model", s(&fitted.join("model.safetensors"))])
        .args(["--b", s(&styled.join("model.safetensors"))])
        .args(["--times", "5", "--out", s(&page)]));
    let said = String::from_utf8_lossy(&said.stdout);
    assert!(
        said.contains("and their stylization, 16 camera(s)"),
        "{said}"
    );
    let scene = gs_stylize::viewer::read_scene(&page).unwrap();
    assert_eq!(scene["animation"]["frames"], 5);

    // Interpolation of the fit and its stylization: the Gaussians and the network's weights.
    let half = dir.path().join("half.safetensors");
    let said = run(bin()
        .args(["interpolate", "--a"])
        .arg(fitted.join("model.safetensors"))
        .args([
            "--b",
            s(&styled.join("model.safetensors")),
            "--t",
            "0.5",
            "--out",
            s(&half),
        ]));
    let blended = load(&half);
    let count = format!("({} Gaussians, t = 0.5)", blended.len());
    let said = String::from_utf8_lossy(&said.stdout);
    assert!(said.contains(&count), "{count} in {said}");
    for g in [group::DC, group::DEFORM] {
        let (a, b, m) = (
            &base.params().groups[g],
            &stylized.params().groups[g],
            &blended.params().groups[g],
        );
        for k in [0, a.len() / 2, a.len() - 1] {
            assert!((m[k] - 0.5 * (a[k] + b[k])).abs() < 1e-6);
        }
    }

    // Render at the dataset's views, and through time.
    let rendered = dir.path().join("rendered");
    let out = run(bin()
        .args(["render", "--device", "cpu", "--model", s(&half)])
        .args(["--data", s(&data), "--sweep", "4", "--out", s(&rendered)]));
    assert!(String::from_utf8_lossy(&out.stdout).contains("wrote 3 views"));
    assert_eq!(count_pngs(&rendered.join("frames")), 3);
    assert_eq!(count_pngs(&rendered.join("sweep")), 4);

    // The model the authors' code saved (the fixture) stylizes as well.
    let authors = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/dmiso_small");
    let theirs = dir.path().join("theirs");
    let mut cmd = bin();
    stylize_args(&mut cmd, &models, 2);
    run(cmd
        .args(["--data", s(&data), "--model", s(&authors)])
        .args(["--out", s(&theirs)]));
    let styled_theirs = load(&theirs.join("model.safetensors"));
    assert_eq!(
        recorded(&authors),
        Some(Background::White),
        "their cfg_args: white_background=True"
    );
    assert_eq!(
        recorded(&theirs.join("model.safetensors")),
        Some(Background::White)
    );
    assert_eq!(
        (
            styled_theirs.cores(),
            styled_theirs.subs_per_core(),
            styled_theirs.net().width
        ),
        (5, 3, 32)
    );
}

#[test]
fn a_run_that_fits_first_resumes_with_its_fit() {
    let dir = tempfile::tempdir().unwrap();
    let models = write_tiny_models(dir.path());
    let data = scene(dir.path());
    let out = dir.path().join("out");
    let fit_settings = [
        "fit_gaussians=150",
        "fit_steps=20",
        "fit_warm_up=5",
        "fit_subs_from=10",
        "fit_sub_cores=40",
        "fit_subs_per_core=2",
        "deform_width=8",
    ];
    let with_fit = |cmd: &mut Command| {
        for f in fit_settings {
            cmd.args(["--set", f]);
        }
    };
    let mut cmd = bin();
    stylize_args(&mut cmd, &models, 2);
    with_fit(&mut cmd);
    run(cmd.args([
        "--data",
        s(&data),
        "--out",
        s(&out),
        "--background",
        "black",
    ]));
    let base = load(&out.join("base.safetensors"));
    let recorded = model_file::recorded_background(&out.join("base.safetensors")).unwrap();
    assert_eq!(
        recorded,
        Some(Background::Black),
        "the fit records its background"
    );
    assert_eq!((base.cores(), base.subs_per_core()), (40, 2));
    let mut cmd = bin();
    stylize_args(&mut cmd, &models, 4);
    with_fit(&mut cmd);
    // A resumed run has the same settings: a run without --background would be refused.
    run(cmd
        .args(["--data", s(&data), "--out", s(&out), "--resume"])
        .args(["--background", "black"]));
    let recorded = model_file::recorded_background(&out.join("model.safetensors")).unwrap();
    assert_eq!(recorded, Some(Background::Black));
    assert_eq!(
        load(&out.join("base.safetensors")),
        base,
        "the fit is reused"
    );
    let losses: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("losses.json")).unwrap()).unwrap();
    assert_eq!(losses.as_array().unwrap().len(), 4);
    // The same run without the interruption ends with the same bytes.
    let whole = dir.path().join("whole");
    let mut cmd = bin();
    stylize_args(&mut cmd, &models, 4);
    with_fit(&mut cmd);
    run(cmd.args([
        "--data",
        s(&data),
        "--out",
        s(&whole),
        "--background",
        "black",
    ]));
    // (Compared as models: the file's metadata order is not fixed.)
    assert_eq!(
        load(&whole.join("model.safetensors")),
        load(&out.join("model.safetensors")),
        "a run resumed at step 2 ends where an uninterrupted one does"
    );
}

#[test]
fn bad_inputs_are_refused_with_nothing_written() {
    let dir = tempfile::tempdir().unwrap();
    let models = write_tiny_models(dir.path());
    let data = scene(dir.path());
    let json = data.join("transforms_train.json");
    let original = std::fs::read_to_string(&json).unwrap();
    let out = dir.path().join("out");
    let stylize = |extra: &[&str]| {
        let mut cmd = bin();
        stylize_args(&mut cmd, &models, 2);
        cmd.args(["--data", s(&data), "--out", s(&out)]).args(extra);
        fails(&mut cmd)
    };
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/dmiso_small");
    let with_model = ["--model", s(&model)];

    // A frame without a time.
    std::fs::write(&json, original.replacen("\"time\"", "\"tiem\"", 1)).unwrap();
    let e = stylize(&with_model);
    assert!(
        e.contains("transforms_train.json") && e.contains("no \"time\""),
        "{e}"
    );
    // A time outside [0, 1].
    let mut v: serde_json::Value = serde_json::from_str(&original).unwrap();
    v["frames"][2]["time"] = serde_json::json!(1.5);
    std::fs::write(&json, v.to_string()).unwrap();
    let e = stylize(&with_model);
    assert!(
        e.contains("frame 2") && e.contains("1.5") && e.contains("[0, 1]"),
        "{e}"
    );
    std::fs::write(&json, &original).unwrap();
    // A picture of another size.
    let picture = data.join("train/r_003.png");
    let keep = std::fs::read(&picture).unwrap();
    image::RgbaImage::new(SIZE + 2, SIZE)
        .save(&picture)
        .unwrap();
    let e = stylize(&with_model);
    assert!(e.contains("r_003.png") && e.contains("34x32"), "{e}");
    std::fs::write(&picture, keep).unwrap();
    // A truncated deformation network.
    let broken = dir.path().join("broken");
    gs_stylize::test_support::copy_dir(&model, &broken);
    let pth = broken.join("deform/iteration_best/deform.pth");
    let bytes = std::fs::read(&pth).unwrap();
    std::fs::write(&pth, &bytes[..bytes.len() / 3]).unwrap();
    let e = stylize(&["--model", s(&broken)]);
    assert!(e.contains("deform.pth"), "{e}");
    // A foreign file as our model.
    let foreign = dir.path().join("foreign.safetensors");
    std::fs::write(&foreign, b"not a model").unwrap();
    let e = stylize(&["--model", s(&foreign)]);
    assert!(e.contains("foreign.safetensors"), "{e}");
    // A batch larger than the views. The authors' model records eval=True in its cfg_args: its
    // 8 train views train, as D-MiSo's loader with --eval; without it (as the authors' example
    // fit), the 3 test views join them.
    let e = stylize(&["--model", s(&model), "--batch-size", "9"]);
    assert!(
        e.contains("batch_size") && e.contains("8 training views"),
        "{e}"
    );
    let cfg = std::fs::read_to_string(model.join("cfg_args")).unwrap();
    assert!(cfg.contains("eval=True"), "{cfg}");
    let without_eval = dir.path().join("without-eval");
    gs_stylize::test_support::copy_dir(&model, &without_eval);
    std::fs::write(
        without_eval.join("cfg_args"),
        cfg.replace("eval=True", "eval=False"),
    )
    .unwrap();
    let e = stylize(&["--model", s(&without_eval), "--batch-size", "12"]);
    assert!(
        e.contains("batch_size") && e.contains("11 training views"),
        "{e}"
    );
    let e = stylize(&[
        "--model",
        s(&model),
        "--batch-size",
        "12",
        "--set",
        "train_splits=train_and_test",
    ]);
    assert!(
        e.contains("batch_size") && e.contains("11 training views"),
        "{e}"
    );
    assert!(!out.exists(), "nothing was written");
}

/// Copies the files of `from` into the new folder `to`.
fn copy_folder(from: &Path, to: &Path) {
    std::fs::create_dir(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let path = entry.unwrap().path();
        std::fs::copy(&path, to.join(path.file_name().unwrap())).unwrap();
    }
}

#[test]
fn help_configs_and_eval() {
    let out = run(bin().arg("--help"));
    let text = String::from_utf8_lossy(&out.stdout);
    for sub in ["stylize", "fit", "render", "interpolate", "eval"] {
        assert!(text.contains(sub), "{sub} in --help");
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let paper: DynamicSceneStylizeConfig =
        gs_stylize::resolve_config(Some(&root.join("configs/4d.json")), &[]).unwrap();
    assert_eq!(paper, DynamicSceneStylizeConfig::default());
    let keep: DynamicSceneStylizeConfig =
        gs_stylize::resolve_config(Some(&root.join("configs/4d-keep-background.json")), &[])
            .unwrap();
    assert_eq!(keep.style.lambda_background, 500.0);

    let dir = tempfile::tempdir().unwrap();
    let models = write_tiny_models(dir.path());
    let data = scene(dir.path());
    // The test pictures against themselves (composited over white, as eval reads them).
    let renders = dir.path().join("renders");
    std::fs::create_dir(&renders).unwrap();
    let test = gs_core::dataset::nerf_synthetic::load_with_times(
        &data,
        gs_core::dataset::nerf_synthetic::Split::Test,
        &gs_core::dataset::LoadOptions {
            background: gs_core::dataset::Background::White,
            downscale: 1,
            ..gs_core::dataset::LoadOptions::default()
        },
    )
    .unwrap();
    for (i, im) in test.images.iter().enumerate() {
        im.save_png(&renders.join(format!("{i:05}.png"))).unwrap();
    }
    let metrics = dir.path().join("metrics.json");
    let table = run(bin()
        .args(["eval", "--renders", s(&renders), "--gt", s(&data)])
        .args(["--style-prompt", "a red fire"])
        .args(["--clip-config", s(&models.clip_config)])
        .args(["--clip-weights", s(&models.clip_weights)])
        .args(["--tokenizer", s(&models.tokenizer)])
        .args(["--out", s(&metrics)]));
    let table = String::from_utf8_lossy(&table.stdout);
    for line in ["views:     3", "CLIP-S:    ", "CLIP-F:    100.0"] {
        assert!(table.contains(line), "{line} in {table}");
    }
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&metrics).unwrap()).unwrap();
    assert_eq!(m["views"], 3);
    assert!((m["clip_f"].as_f64().unwrap() - 100.0).abs() < 1e-3, "{m}");
    // A finished run's frames are scored as eval scores them (what a batch asks).
    let out = dir.path().join("run");
    std::fs::create_dir(&out).unwrap();
    copy_folder(&renders, &out.join("frames"));
    let config = base_dmiso::stylize::DynamicSceneStylizeConfig {
        data: Some(data.clone()),
        out: Some(out),
        background: Some([1.0; 3]),
        style: gs_stylize::StyleSettings {
            style_prompt: Some("a red fire".into()),
            ..base_dmiso::stylize::DynamicSceneStylizeConfig::default().style
        },
        ..base_dmiso::stylize::DynamicSceneStylizeConfig::default()
    };
    let clip = gs_stylize::evaluation::ClipFiles {
        config: Some(models.clip_config.clone()),
        weights: Some(models.clip_weights.clone()),
        tokenizer: Some(models.tokenizer.clone()),
    };
    let scored = base_dmiso::evaluation::evaluate_run(&config, clip).unwrap();
    assert_eq!(serde_json::to_value(scored).unwrap(), m);
    std::fs::remove_file(renders.join("00002.png")).unwrap();
    let eval_fails = || {
        fails(
            bin()
                .args(["eval", "--renders", s(&renders), "--data", s(&data)])
                .args(["--style-prompt", "a red fire"])
                .args(["--clip-config", s(&models.clip_config)])
                .args(["--clip-weights", s(&models.clip_weights)])
                .args(["--tokenizer", s(&models.tokenizer)]),
        )
    };
    let e = eval_fails();
    assert!(
        e.contains("holds 2 pictures") && e.contains("(missing: 00002.png)"),
        "{e}"
    );
    // A folder holding more renders than the test split has views: refused, not cut short.
    for i in [2, 3] {
        std::fs::copy(
            renders.join("00000.png"),
            renders.join(format!("{i:05}.png")),
        )
        .unwrap();
    }
    let e = eval_fails();
    assert!(
        e.contains("holds 4 pictures but the test split") && e.contains("unexpected: 00003.png"),
        "{e}"
    );
}

#[test]
fn selftest_on_the_cpu_checks_the_network_too() {
    let table = cpu_selftest_table(Path::new(env!("CARGO_BIN_EXE_clipgaussian-4d")));
    assert!(
        table.contains("| deformation network and its backward |"),
        "{table}"
    );
}

/// A model of another modality is refused naming the binary that opens it, by `render`,
/// `stylize` and `interpolate`.
#[test]
fn a_model_of_another_modality_names_its_binary() {
    let dir = tempfile::tempdir().unwrap();
    gs_stylize::test_support::assert_every_command_refuses_foreign_models(
        gs_stylize::model_kind::Binary::DynamicScene,
        std::path::Path::new(env!("CARGO_BIN_EXE_clipgaussian-4d")),
        dir.path(),
        "--model",
        &["--data", "scene"],
    );
}

/// Every subcommand has the flags the four binaries share, under the same names.
#[test]
fn the_shared_flags_have_the_same_names_in_every_subcommand() {
    gs_stylize::test_support::assert_shared_flags(
        std::path::Path::new(env!("CARGO_BIN_EXE_clipgaussian-4d")),
        true,
    );
}

/// A fit setting out of range is refused naming the flag that sets it.
#[test]
fn fit_errors_name_their_flags() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let data = dir.path().join("scene");
    for (flags, named) in [
        (vec!["--gaussians", "0"], "--gaussians: must be at least 1"),
        (
            vec!["--batch-size", "0"],
            "--batch-size: must be at least 1",
        ),
        (
            vec!["--warm-up", "50", "--subs-from", "20"],
            "--warm-up 50 <= --subs-from 20",
        ),
    ] {
        let err = gs_stylize::test_support::fails(
            bin()
                .args([
                    "fit",
                    "--data",
                    data.to_str().unwrap(),
                    "--out",
                    out.to_str().unwrap(),
                ])
                .args(&flags),
        );
        assert!(err.contains(named), "{flags:?}: {err}");
    }
    assert!(!out.exists());
}

/// A model given without data is stylized alone: an orbit made from it at `--times` evenly
/// spaced times from 0 to 1 (the run says so), the model's own renders as the pictures, so the content term starts
/// at 0; the cores, sub-Gaussians and network keep their shapes. With neither data nor a model
/// the run is refused naming both.
#[test]
fn a_model_alone_is_stylized_against_its_own_renders() {
    let dir = tempfile::tempdir().unwrap();
    let models = write_tiny_models(dir.path());
    let data = scene(dir.path());
    let fitted = dir.path().join("fitted");
    run(bin()
        .args(["fit", "--quiet", "--device", "cpu", "--data", s(&data)])
        .args(["--out", s(&fitted)])
        .args(FIT));
    let model = fitted.join("model.safetensors");
    let styled = dir.path().join("alone");
    let mut cmd = bin();
    cmd.args(["stylize", "--steps", "3"]);
    tiny_style_flags(&mut cmd, &models);
    let out = run(cmd
        .args(["--set", "sweep_frames=3", "--device", "cpu"])
        .args(["--model", s(&model), "--out", s(&styled)])
        .args(["--orbit", "object", "--orbit-views", "4", "--times", "2"])
        .args(["--width", &SIZE.to_string(), "--height", &SIZE.to_string()]));
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(
        said.contains("cameras: 4 view(s) of an object orbit")
            && said.contains("at 2 time(s) evenly from 0 to 1"),
        "{said}"
    );
    let losses: Vec<gs_stylize::outputs::StepLosses> =
        serde_json::from_str(&std::fs::read_to_string(styled.join("losses.json")).unwrap())
            .unwrap();
    assert_eq!(losses[0].terms["content"], 0.0);
    let (base, stylized) = (load(&model), load(&styled.join("model.safetensors")));
    let shape = |m: &Dmiso| (m.cores(), m.subs_per_core(), m.net().width);
    assert_eq!(shape(&stylized), shape(&base));
    assert!(styled.join("preview.gif").is_file());

    // More times than views, or none, is refused before any render, naming the flag.
    for (times, said) in [
        ("5", "times: 5: give from 1 to the 4 views"),
        ("0", "times: 0"),
    ] {
        let refused = dir.path().join(format!("times{times}"));
        let mut cmd = bin();
        cmd.args(["stylize", "--steps", "3"]);
        tiny_style_flags(&mut cmd, &models);
        let e = fails(
            cmd.args([
                "--device",
                "cpu",
                "--model",
                s(&model),
                "--out",
                s(&refused),
            ])
            .args(["--orbit", "object", "--orbit-views", "4", "--times", times]),
        );
        assert!(e.contains(said) && e.contains("--times"), "{e}");
        assert!(!refused.exists());
    }

    let nothing = dir.path().join("nothing");
    let mut cmd = bin();
    stylize_args(&mut cmd, &models, 2);
    let e = fails(cmd.args(["--out", s(&nothing)]));
    assert!(
        e.contains("data: is required") && e.contains("--model"),
        "{e}"
    );
    assert!(!nothing.exists());
}
