//! `clipgaussian-2d` from file to file with the tiny random-weight CLIP and VGG: fit, then
//! stylize (with a fitted model and with the fit inside the run), resume bit-identically, and
//! refuse bad inputs with a clear error and nothing written; stylize on the GPU (lavapipe in
//! CI) close to the cpu, resume a GPU run on the cpu, and refuse a device that is not there.

use std::path::{Path, PathBuf};
use std::process::Command;

use base_mirage::model_file::FittedTo;
use gs_core::ply::read_ply;
use gs_core::GaussianSet;
use gs_stylize::test_support::{
    cpu_selftest_table, fails, fit_json_psnr, path_str as s, succeeds as run, tiny_style_flags,
};
use gs_wgpu::backend::ALLOW_SOFTWARE_GPU;
use gs_wgpu::{AdapterChoice, GpuContext};
use style_loss::test_models::{write_tiny_models, TinyModelFiles};
use tempfile::TempDir;

const W: u32 = 40;
const H: u32 = 32;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_clipgaussian-2d"))
}

/// A `W x H` RGBA picture with a transparent corner, written as PNG.
fn write_picture(dir: &Path) -> PathBuf {
    let img = image::RgbaImage::from_fn(W, H, |x, y| {
        let a = if x < 6 && y < 6 { 0 } else { 255 };
        image::Rgba([(x * 6) as u8, (y * 7) as u8, 200 - (x * 3) as u8, a])
    });
    let path = dir.join("picture.png");
    img.save(&path).unwrap();
    path
}

/// `stylize` arguments with the tiny models and small patches, `steps` steps, no progress.
fn stylize_args(cmd: &mut Command, models: &TinyModelFiles, steps: u64) {
    shown_stylize_args(cmd, models, steps);
    cmd.arg("--quiet");
}

/// [`stylize_args`] with the progress shown.
fn shown_stylize_args(cmd: &mut Command, models: &TinyModelFiles, steps: u64) {
    cmd.args(["stylize", "--steps", &steps.to_string()]);
    tiny_style_flags(cmd, models);
    cmd.args([
        "--set",
        "checkpoint_every=3",
        "--set",
        "learning_rates.sh_dc=0.05",
    ]);
}

fn png_size(path: &Path) -> (u32, u32) {
    image::image_dimensions(path).unwrap()
}

#[test]
fn fit_then_stylize_from_file_to_file() {
    let dir = TempDir::new().unwrap();
    let models = write_tiny_models(dir.path());
    let picture = write_picture(dir.path());
    let fit_dir = dir.path().join("fit");
    let out = run(bin()
        .args([
            "fit",
            "--quiet",
            "--picture",
            s(&picture),
            "--out",
            s(&fit_dir),
        ])
        .args(["--gaussians", "400", "--steps", "60", "--sh-degree", "1"])
        .args(["--background", "white"]));
    let text = String::from_utf8_lossy(&out.stdout);
    let psnr = fit_json_psnr(&fit_dir, 60);
    assert!(text.contains(&format!("PSNR {psnr:.2} dB")), "{text}");
    let base = read_ply(&fit_dir.join("model.ply")).unwrap();
    assert_eq!((base.gaussians.len(), base.gaussians.sh_degree()), (400, 1));
    assert_eq!(png_size(&fit_dir.join("fitted.png")), (W, H));
    // Export: the flat Gaussians as they render, in the format the name says; a name of no
    // format is refused naming --format.
    let spz = dir.path().join("picture.spz");
    run(bin().args([
        "export",
        "--model",
        s(&fit_dir.join("model.ply")),
        "--out",
        s(&spz),
    ]));
    let exported = gs_core::splats::read_splats(&spz).unwrap().gaussians;
    assert_eq!((exported.len(), exported.sh_degree()), (400, 1));
    let model = base_mirage::model_file::read_model(&fit_dir.join("model.ply")).unwrap();
    let rendered = gs_stylize::export::gaussians_at(&model.model, 0.0).unwrap();
    let worst = exported
        .means
        .iter()
        .zip(&rendered.means)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(
        worst <= 0.5 / 4096.0 + 1e-6,
        "the Gaussians as they render: {worst}"
    );
    let e = fails(bin().args([
        "export",
        "--model",
        s(&fit_dir.join("model.ply")),
        "--out",
        s(&dir.path().join("picture.xyz")),
    ]));
    assert!(e.contains("picture.xyz") && e.contains("--format"), "{e}");

    let jpeg = dir.path().join("picture.jpg");
    image::DynamicImage::ImageRgba8(image::open(&picture).unwrap().to_rgba8())
        .to_rgb8()
        .save(&jpeg)
        .unwrap();
    let jpeg_fit = dir.path().join("jpeg-fit");
    run(bin()
        .args([
            "fit",
            "--quiet",
            "--picture",
            s(&jpeg),
            "--out",
            s(&jpeg_fit),
        ])
        .args(["--gaussians", "100", "--steps", "5"]));
    assert_eq!(png_size(&jpeg_fit.join("fitted.png")), (W, H), "JPEG in");

    let sty = dir.path().join("stylized");
    let mut cmd = bin();
    stylize_args(&mut cmd, &models, 6);
    run(cmd
        .args([
            "--picture",
            s(&picture),
            "--model",
            s(&fit_dir.join("model.ply")),
        ])
        .args(["--out", s(&sty), "--set", "background=white"]));
    assert_eq!(
        png_size(&sty.join("stylized.png")),
        (W, H),
        "the original size"
    );
    assert_eq!(png_size(&sty.join("preview.png")), (2 * W, H));
    assert_eq!(png_size(&sty.join("losses.png")).0, 640);
    let stylized = read_ply(&sty.join("model.ply")).unwrap();
    assert_eq!(stylized.gaussians.len(), 400, "the count never changes");
    // The viewer: the fitted and the stylized Gaussians, the picture's camera and its mirror,
    // over the run's background.
    let scene = gs_stylize::viewer::read_scene(&sty.join("viewer.html")).unwrap();
    assert_eq!(scene["count"], 400);
    assert_eq!(scene["models"].as_array().unwrap().len(), 2);
    assert_eq!(scene["cameras"][1]["name"], "mirror");
    assert_eq!(scene["cameras"][0]["width"], W);
    assert_eq!(scene["background"], serde_json::json!([1.0, 1.0, 1.0]));
    assert_ne!(
        stylized.gaussians.sh_dc, base.gaussians.sh_dc,
        "colours changed"
    );
    let losses: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(sty.join("losses.json")).unwrap()).unwrap();
    assert_eq!(losses.as_array().unwrap().len(), 6);
    assert!(
        !sty.join("base.ply").exists(),
        "no fit when a model is given"
    );
    let config: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(sty.join("config.json")).unwrap()).unwrap();
    assert_eq!(config["lambda_background"], 0.0);
    // The dotted override set one group's rate and kept the others'.
    assert_eq!(config["learning_rates"]["sh_dc"], 0.05);
    assert_eq!(config["learning_rates"]["sh_rest"], 0.000125);
    assert_eq!(config["background"], serde_json::json!([1.0, 1.0, 1.0]));
}

#[test]
fn stylize_fits_first_and_resumes_bit_identically() {
    let dir = TempDir::new().unwrap();
    let models = write_tiny_models(dir.path());
    let picture = write_picture(dir.path());
    let command = |out: &Path, steps: u64, resume: bool| {
        let mut cmd = bin();
        stylize_args(&mut cmd, &models, steps);
        cmd.args(["--device", "cpu"]);
        cmd.args(["--picture", s(&picture), "--out", s(out)]).args([
            "--gaussians",
            "300",
            "--fit-steps",
            "40",
        ]);
        if resume {
            cmd.arg("--resume");
        }
        cmd
    };
    let stylize_to = |out: &Path, steps: u64, resume: bool| {
        run(&mut command(out, steps, resume));
    };
    let whole = dir.path().join("whole");
    stylize_to(&whole, 6, false);
    let fitted = read_ply(&whole.join("base.ply")).unwrap();
    assert_eq!(fitted.gaussians.len(), 300);

    let parts = dir.path().join("parts");
    stylize_to(&parts, 3, false);
    // A checkpoint written before `vgg_precision` existed resumes as f32, its value then.
    let state_path = parts.join("checkpoint").join("state.json");
    let mut state: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&state_path).unwrap()).unwrap();
    let config = state["config"].as_object_mut().unwrap();
    assert_eq!(config.remove("vgg_precision"), Some("f32".into()));
    std::fs::write(&state_path, serde_json::to_string(&state).unwrap()).unwrap();
    stylize_to(&parts, 6, true);
    assert_eq!(
        std::fs::read(whole.join("model.ply")).unwrap(),
        std::fs::read(parts.join("model.ply")).unwrap(),
        "a run resumed at step 3 ends where an uninterrupted one does"
    );
    let model = std::fs::read(parts.join("model.ply")).unwrap();

    // The run resumed to its end is finished: resuming it again at the same step count has
    // nothing to do and says so, and the same command without --resume runs afresh.
    let err = fails(&mut command(&parts, 6, true));
    assert!(
        err.contains("finished all its 6 steps") && err.contains("--steps"),
        "{err}"
    );
    assert_eq!(std::fs::read(parts.join("model.ply")).unwrap(), model);
    stylize_to(&parts, 6, false);
    assert_eq!(
        std::fs::read(parts.join("model.ply")).unwrap(),
        model,
        "a new run in a finished run's folder starts from the fit again"
    );
}

/// Runs `stylize` into `out` with `extra` arguments, expects a failure whose message contains
/// every one of `expected`, and checks that `out` was not created.
fn refused(dir: &TempDir, extra: &[&str], expected: &[&str]) {
    let models = write_tiny_models(dir.path());
    let out = dir.path().join("out");
    let mut cmd = bin();
    stylize_args(&mut cmd, &models, 2);
    let err = fails(cmd.args(["--out", s(&out)]).args(extra));
    for e in expected {
        assert!(err.contains(e), "expected {e:?} in: {err}");
    }
    assert!(!out.exists(), "nothing written for {extra:?}");
}

#[test]
fn bad_inputs_are_named_and_leave_nothing() {
    let dir = TempDir::new().unwrap();
    let garbage = dir.path().join("garbage.png");
    std::fs::write(&garbage, b"not a picture").unwrap();
    refused(&dir, &["--picture", s(&garbage)], &["garbage.png"]);

    let missing = dir.path().join("missing.jpg");
    refused(&dir, &["--picture", s(&missing)], &["missing.jpg"]);

    let tiny = dir.path().join("one.png");
    image::RgbImage::new(1, 1).save(&tiny).unwrap();
    refused(&dir, &["--picture", s(&tiny)], &["one.png", "1x1"]);

    let picture = write_picture(dir.path());
    refused(
        &dir,
        &["--picture", s(&picture), "--set", "patch_size=64"],
        &["patch_size", "64", "40x32"],
    );
    refused(
        &dir,
        &["--picture", s(&picture), "--set", "bogus_field=1"],
        &["bogus_field"],
    );
    refused(
        &dir,
        &["--picture", s(&picture), "--set", "steps=abc"],
        &["steps"],
    );
    refused(
        &dir,
        &["--picture", s(&picture), "--frobnicate"],
        &["--frobnicate"],
    );
    refused(
        &dir,
        &["--picture", s(&picture), "--model", s(&garbage)],
        &["garbage.png"],
    );
    refused(
        &dir,
        &[
            "--picture",
            s(&picture),
            "--set",
            &format!("style_image={}", s(&garbage)),
            "--set",
            "style_prompt=null",
        ],
        &["style image", "garbage.png"],
    );
    refused(
        &dir,
        &["--picture", s(&picture), "--resume"],
        &["no checkpoint", "without --resume"],
    );
    // VGG weights that do not load with the widths asked for: refused before the fit writes.
    refused(
        &dir,
        &[
            "--picture",
            s(&picture),
            "--set",
            "vgg_widths=[8,8,16,32,32]",
        ],
        &["vgg", "shape"],
    );
    refused(
        &dir,
        &[
            "--picture",
            s(&picture),
            "--set",
            &format!("clip_weights={}", s(&missing)),
        ],
        &["missing.jpg"],
    );
}

#[test]
fn a_failed_fit_leaves_no_folder() {
    let dir = TempDir::new().unwrap();
    let picture = write_picture(dir.path());
    let out = dir.path().join("fit");
    let err = fails(
        bin()
            .args(["fit", "--quiet", "--picture", s(&picture), "--out", s(&out)])
            .args(["--gaussians", "0"]),
    );
    assert!(err.contains("gaussians"), "{err}");
    assert!(!out.exists(), "the folder this run made is gone");
}

#[test]
fn the_configuration_file_holds_the_paper_defaults() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/2d.json");
    let from_file: base_mirage::stylize::PictureStylizeConfig =
        gs_stylize::resolve_config(Some(&path), &[]).unwrap();
    assert_eq!(
        from_file,
        base_mirage::stylize::PictureStylizeConfig::default()
    );
    assert_eq!(from_file.style.lambda_background, 0.0);
    assert_eq!(
        from_file.learning_rates.get("sh_dc"),
        Some(&gs_stylize::rates::GroupRate::Constant(0.0025))
    );
    assert_eq!(
        from_file.style.style_prompt.as_deref(),
        Some("Starry Night by Vincent van Gogh")
    );
    let preview = path.with_file_name("2d-preview.json");
    let quick: base_mirage::stylize::PictureStylizeConfig =
        gs_stylize::resolve_config(Some(&preview), &[]).unwrap();
    quick.style.validate().unwrap();
    assert!(quick.style.steps < from_file.style.steps);
    assert_eq!(quick.style.style_prompt, from_file.style.style_prompt);
    // The paper's file runs in f32; the preview takes bf16 products where the CPU has them.
    assert_eq!(
        from_file.style.clip_precision,
        style_loss::ClipPrecision::F32
    );
    assert_eq!(from_file.style.vgg_precision, style_loss::VggPrecision::F32);
    assert_eq!(quick.style.clip_precision, style_loss::ClipPrecision::Auto);
    assert_eq!(quick.style.vgg_precision, style_loss::VggPrecision::Auto);
}

/// The L2 distance between two parameter sets, over every array.
fn distance(a: &GaussianSet, b: &GaussianSet) -> f64 {
    a.arrays()
        .iter()
        .zip(b.arrays())
        .flat_map(|(x, y)| x.iter().zip(y.iter()))
        .map(|(x, y)| (f64::from(*x) - f64::from(*y)).powi(2))
        .sum::<f64>()
        .sqrt()
}

#[test]
fn stylize_on_the_gpu_ends_close_to_the_cpu_and_resumes_on_the_cpu() {
    if !gs_wgpu::test_adapter_exists() {
        return;
    }
    let dir = TempDir::new().unwrap();
    let models = write_tiny_models(dir.path());
    let picture = write_picture(dir.path());
    let fit_dir = dir.path().join("fit");
    run(bin()
        .args([
            "fit",
            "--quiet",
            "--device",
            "cpu",
            "--picture",
            s(&picture),
        ])
        .args(["--out", s(&fit_dir), "--gaussians", "300", "--steps", "40"])
        .args(["--sh-degree", "1"]));
    let base_ply = fit_dir.join("model.ply");
    let stylize_to = |out: &Path, device: &str, steps: u64, resume: bool| {
        let mut cmd = bin();
        stylize_args(&mut cmd, &models, steps);
        cmd.args(["--device", device, "--picture", s(&picture)])
            .args(["--model", s(&base_ply), "--out", s(out)])
            .env(ALLOW_SOFTWARE_GPU, "1");
        if resume {
            cmd.arg("--resume");
        }
        String::from_utf8_lossy(&run(&mut cmd).stdout).into_owned()
    };
    let model = |out: &Path| read_ply(&out.join("model.ply")).unwrap().gaussians;
    let on_cpu = dir.path().join("cpu");
    let printed = stylize_to(&on_cpu, "cpu", 6, false);
    assert!(printed.contains("device: cpu (rayon, "), "{printed}");
    // The models' loading is said after the device, naming the files.
    let loading = printed.find("loading CLIP (").expect("a loading line");
    assert!(loading > printed.find("device: cpu").unwrap(), "{printed}");
    let clip_name = models.clip_weights.file_name().unwrap().to_string_lossy();
    assert!(printed[loading..].contains(&*clip_name), "{printed}");
    let on_gpu = dir.path().join("gpu");
    let printed = stylize_to(&on_gpu, "gpu", 6, false);
    assert!(printed.contains("device: gpu: "), "{printed}");

    let base = read_ply(&base_ply).unwrap().gaussians;
    let moved = distance(&model(&on_cpu), &base);
    let apart = distance(&model(&on_gpu), &model(&on_cpu));
    eprintln!("stylization moved the parameters by {moved:e}; gpu and cpu ended {apart:e} apart");
    assert!(moved > 0.1, "the stylization changed the model: {moved}");
    assert!(
        apart < 0.02 * moved,
        "gpu {apart:e} from cpu, moved {moved:e}"
    );

    let mixed = dir.path().join("mixed");
    stylize_to(&mixed, "gpu", 3, false);
    stylize_to(&mixed, "cpu", 6, true);
    let apart = distance(&model(&mixed), &model(&on_cpu));
    assert!(
        apart < 0.02 * moved,
        "resumed on the cpu: {apart:e} from cpu, moved {moved:e}"
    );
}

#[test]
fn devices_that_are_not_there_are_refused_clearly() {
    let dir = TempDir::new().unwrap();
    let model_ply = dir.path().join("model.ply");
    base_mirage::model_file::write_model(
        &model_ply,
        &base_mirage::flat::FlatGaussians::new(GaussianSet::zeros(4, 0)),
        &FittedTo {
            width: 8,
            height: 8,
            distance: 1.0,
        },
    )
    .unwrap();
    let render = |device: &str| {
        let mut cmd = bin();
        cmd.args([
            "render",
            "--model",
            s(&model_ply),
            "--width",
            "8",
            "--height",
            "8",
        ])
        .args(["--out", s(&dir.path().join("r.png")), "--device", device])
        .env_remove(ALLOW_SOFTWARE_GPU);
        cmd
    };
    let err = fails(&mut render("cuda"));
    assert!(
        err.contains("cuda") && err.contains("cpu, gpu, auto"),
        "{err}"
    );

    let hardware = GpuContext::new(AdapterChoice::Hardware).is_ok();
    let auto = String::from_utf8_lossy(&run(&mut render("auto")).stdout).into_owned();
    if hardware {
        assert!(auto.contains("device: gpu: "), "{auto}");
    } else {
        assert!(
            auto.contains("device: cpu (rayon, "),
            "auto never takes a software GPU: {auto}"
        );
        let err = fails(&mut render("gpu"));
        let software = GpuContext::new(AdapterChoice::AllowSoftware).is_ok();
        // With a software adapter only, the flag that allows it; with none, what to install.
        let hint = if software {
            ALLOW_SOFTWARE_GPU
        } else {
            "no GPU adapter"
        };
        assert!(err.contains("--device gpu") && err.contains(hint), "{err}");
    }
}

/// The lines of `text` that start with `prefix`.
fn lines_starting<'a>(text: &'a str, prefix: &str) -> Vec<&'a str> {
    text.lines().filter(|l| l.starts_with(prefix)).collect()
}

#[test]
fn a_redirected_run_prints_a_progress_line_every_five_percent_and_no_error_line() {
    let dir = TempDir::new().unwrap();
    let models = write_tiny_models(dir.path());
    let picture = write_picture(dir.path());
    let mut cmd = bin();
    shown_stylize_args(&mut cmd, &models, 6);
    let out = run(cmd
        .args([
            "--picture",
            s(&picture),
            "--out",
            s(&dir.path().join("out")),
        ])
        .args(["--gaussians", "200", "--fit-steps", "40", "--device", "cpu"]));
    let stderr = String::from_utf8_lossy(&out.stderr);
    let fit = lines_starting(&stderr, "fit: step ");
    assert_eq!(fit.len(), 20, "one line every 5 % of 40 steps: {stderr}");
    assert!(
        fit[0].starts_with("fit: step 2/40 (5%), 0:00:"),
        "{}",
        fit[0]
    );
    assert!(
        fit[0].contains(" elapsed, about 0:") && fit[0].contains(" left, loss 0."),
        "{}",
        fit[0]
    );
    assert!(fit[19].starts_with("fit: step 40/40 (100%)") && fit[19].contains("done"));
    let stylize = lines_starting(&stderr, "stylize: step ");
    assert_eq!(
        stylize.len(),
        6,
        "every step is past the next 5 %: {stderr}"
    );
    assert!(
        stylize[5].starts_with("stylize: step 6/6 (100%)") && stylize[5].contains("loss "),
        "{}",
        stylize[5]
    );
    // The per-view cache says where it is before the first step (2D: the picture and its
    // mirror).
    let caching = lines_starting(&stderr, "caching views: step ");
    assert!(
        caching.len() == 2 && caching[1].starts_with("caching views: step 2/2 (100%)"),
        "{stderr}"
    );
    let first_step = stderr.find("stylize: step ").unwrap();
    assert!(stderr.find("caching views: step 1/2").unwrap() < first_step);
    assert!(lines_starting(&stderr, "error").is_empty(), "{stderr}");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(lines_starting(&stdout, "wrote ").len(), 1, "{stdout}");
    // The memory estimate comes before the work, the summary last.
    let memory = stdout
        .find("memory: about ")
        .expect("the estimate is printed");
    assert!(memory < stdout.find("done in ").unwrap(), "{stdout}");
    // The summary: printed last and written beside the outputs.
    assert!(
        stdout.contains("done in 0:0") && stdout.contains(": 6 steps, final loss "),
        "{stdout}"
    );
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("out").join("summary.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(summary["command"], "clipgaussian-2d stylize");
    assert_eq!(summary["steps"], 6);
    let outputs = summary["outputs"].as_array().unwrap();
    for name in [
        "preview.png",
        "stylized.png",
        "model.ply",
        "losses.json",
        "fit.json",
    ] {
        assert!(outputs.iter().any(|o| o == name), "{name}: {summary}");
    }
    // The run fitted its base model: the summary says how long and how well.
    assert!(
        stdout.contains("base model fitted in 0:0") && stdout.contains(" (40 steps), PSNR "),
        "{stdout}"
    );
    assert_eq!(summary["fit"]["steps"], 40);
    let psnr = summary["fit"]["psnr_db"].as_f64().unwrap();
    assert!(psnr.is_finite() && psnr > 5.0, "{summary}");
}

#[test]
fn outputs_that_cannot_be_written_are_refused_first_naming_the_path() {
    let dir = TempDir::new().unwrap();
    let file = dir.path().join("notes.txt");
    std::fs::write(&file, "not a folder").unwrap();
    let missing_picture = dir.path().join("missing.png");
    let model = dir.path().join("model.ply");
    base_mirage::model_file::write_model(
        &model,
        &base_mirage::flat::FlatGaussians::new(GaussianSet::zeros(4, 0)),
        &FittedTo {
            width: 8,
            height: 8,
            distance: 1.0,
        },
    )
    .unwrap();
    let notes = s(&file);
    let inside = file.join("sub");
    // Every other input is bad too: the output is what is checked first.
    let err = fails(bin().args(["fit", "--picture", s(&missing_picture), "--out", notes]));
    assert!(
        err.contains(&format!("output folder {notes}: it is a file"))
            && err.contains("must be a folder"),
        "{err}"
    );
    let err = fails(bin().args(["fit", "--picture", s(&missing_picture), "--out", s(&inside)]));
    assert!(
        err.contains(&format!("{notes} is a file, so no folder can be made")),
        "{err}"
    );
    let err = fails(bin().args(["stylize", "--picture", s(&missing_picture), "--out", notes]));
    assert!(
        err.contains("it is a file") && !err.contains("missing.png"),
        "{err}"
    );
    let render = |out: &Path| {
        let mut cmd = bin();
        cmd.args([
            "render",
            "--model",
            s(&model),
            "--width",
            "8",
            "--height",
            "8",
        ])
        .args(["--device", "cpu", "--out", s(out)]);
        cmd
    };
    let err = fails(&mut render(dir.path()));
    assert!(err.contains("it is a folder"), "{err}");
    let err = fails(&mut render(&inside.join("r.png")));
    assert!(
        err.contains(&format!("{notes} is a file, not a folder")),
        "{err}"
    );
    let err = fails(&mut render(&dir.path().join("none/r.png")));
    assert!(
        err.contains("the folder") && err.contains("none does not exist"),
        "{err}"
    );
    let err = fails(
        bin()
            .args(["interpolate", "--a", s(&missing_picture), "--b", s(&model)])
            .args(["--t", "0.5", "--out", s(&inside.join("mix.ply"))]),
    );
    assert!(
        err.contains(&format!("{notes} is a file, not a folder")),
        "{err}"
    );
    run(&mut render(&dir.path().join("r.png")));
    let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(names.len(), 3, "nothing else was written: {names:?}");
}

#[test]
fn configuration_files_are_checked_as_written_and_set_takes_the_flag_spellings() {
    let dir = TempDir::new().unwrap();
    let config = dir.path().join("run.json");
    std::fs::write(&config, r#"{"fit_steps": "many", "num_patches": 3}"#).unwrap();
    // --fit-steps replaces the bad value, but the file is still wrong.
    let err = refused_with(&dir, &["--config", s(&config), "--fit-steps", "2"]);
    assert!(
        err.contains("run.json: fit_steps = \"many\": invalid type"),
        "{err}"
    );
    assert_eq!(err.matches("configuration").count(), 1, "{err}");
    let err = refused_with(&dir, &["--set", "steps=abc"]);
    assert!(
        err.starts_with("error: configuration: steps = \"abc\": "),
        "{err}"
    );

    let missing = dir.path().join("missing.png");
    for spelling in ["white", "black", "0.5,0.5,1", "[1, 0, 0]"] {
        let err = refused_with(
            &dir,
            &[
                "--set",
                &format!("background={spelling}"),
                "--picture",
                s(&missing),
            ],
        );
        assert!(
            err.contains("missing.png") && !err.contains("background"),
            "{err}"
        );
    }
    let err = refused_with(&dir, &["--set", "background=grey"]);
    assert!(
        err.contains("background = \"grey\"") && err.contains("not white, black or R,G,B"),
        "{err}"
    );
}

/// Runs `stylize` with the tiny models into a folder of `dir` with `extra` arguments, expects
/// a failure that leaves no output folder, and returns stderr.
fn refused_with(dir: &TempDir, extra: &[&str]) -> String {
    let models = write_tiny_models(dir.path());
    let out = dir.path().join("refused");
    let mut cmd = bin();
    stylize_args(&mut cmd, &models, 2);
    let err = fails(cmd.args(["--out", s(&out)]).args(extra));
    assert!(!out.exists(), "nothing written for {extra:?}");
    err
}

#[test]
fn models_of_another_picture_shape_or_of_a_3d_scene_are_named() {
    let dir = TempDir::new().unwrap();
    let picture = write_picture(dir.path());
    let fit_dir = dir.path().join("fit");
    run(bin()
        .args([
            "fit",
            "--quiet",
            "--device",
            "cpu",
            "--picture",
            s(&picture),
        ])
        .args(["--out", s(&fit_dir), "--gaussians", "100", "--steps", "2"]));
    let fitted = fit_dir.join("model.ply");
    let comments = read_ply(&fitted).unwrap().comments;
    assert_eq!(
        comments,
        [format!("clipgaussian-2d picture {W}x{H} distance 1")]
    );

    let square = dir.path().join("square.png");
    image::RgbImage::from_pixel(W, W, image::Rgb([90, 20, 200]))
        .save(&square)
        .unwrap();
    let err = refused_with(&dir, &["--picture", s(&square), "--model", s(&fitted)]);
    assert!(
        err.contains(&format!("fitted to a {W}x{H} picture"))
            && err.contains(&format!("square.png is {W}x{W}")),
        "{err}"
    );

    // Twice the size, the same shape: one warning naming both sizes, and the run goes on.
    let double = dir.path().join("double.png");
    image::RgbImage::from_pixel(2 * W, 2 * H, image::Rgb([90, 20, 200]))
        .save(&double)
        .unwrap();
    let models = write_tiny_models(dir.path());
    let mut cmd = bin();
    stylize_args(&mut cmd, &models, 2);
    let out = run(cmd
        .args([
            "--device",
            "cpu",
            "--out",
            s(&dir.path().join("double-out")),
        ])
        .args(["--picture", s(&double), "--model", s(&fitted)]));
    let err = String::from_utf8_lossy(&out.stderr);
    let warnings = lines_starting(&err, "warning: ");
    assert_eq!(warnings.len(), 1, "{err}");
    assert!(
        warnings[0].contains(&format!("{W}x{H}"))
            && warnings[0].contains(&format!("{}x{}", 2 * W, 2 * H)),
        "{err}"
    );
    assert!(lines_starting(&err, "error").is_empty(), "{err}");

    let mut scene = GaussianSet::zeros(50, 0);
    for (i, v) in scene.means.iter_mut().enumerate() {
        *v = ((i * 37 % 101) as f32 / 50.0) - 1.0;
    }
    scene.log_scales.iter_mut().for_each(|v| *v = -3.0);
    let scene_ply = dir.path().join("scene.ply");
    gs_core::ply::write_ply(
        &scene_ply,
        &gs_core::ply::PlyGaussians::new(scene),
        gs_core::ply::PlyFormat::BinaryLittleEndian,
    )
    .unwrap();
    let err = refused_with(&dir, &["--picture", s(&picture), "--model", s(&scene_ply)]);
    assert!(
        err.contains("scene.ply: not a 2D model")
            && err.contains("50 of its 50 Gaussians have no flat axis")
            && err.contains("off the picture plane"),
        "{err}"
    );
    let err = fails(
        bin()
            .args(["render", "--model", s(&scene_ply), "--width", "8"])
            .args(["--height", "8", "--out", s(&dir.path().join("r.png"))]),
    );
    assert!(err.contains("scene.ply: not a 2D model"), "{err}");
}

#[test]
fn stylize_help_lists_every_file_it_writes() {
    let help = String::from_utf8_lossy(&run(bin().args(["stylize", "--help"])).stdout).into_owned();
    for file in [
        "stylized.png",
        "preview.png",
        "model.ply",
        "viewer.html",
        "base.ply",
        "original.png",
        "losses.json",
        "losses.png",
        "config.json",
        "checkpoint/",
    ] {
        assert!(help.contains(file), "{file} not in {help}");
    }
    assert!(
        help.contains("downloaded from the Hugging Face Hub"),
        "{help}"
    );
}

#[test]
fn selftest_on_the_cpu_prints_every_part_and_passes() {
    let table = cpu_selftest_table(Path::new(env!("CARGO_BIN_EXE_clipgaussian-2d")));
    assert!(table.contains("| render and its backward |"), "{table}");
}

/// A model of another modality is refused naming the binary that opens it, by `render`,
/// `stylize` and `interpolate`.
#[test]
fn a_model_of_another_modality_names_its_binary() {
    let dir = TempDir::new().unwrap();
    gs_stylize::test_support::assert_every_command_refuses_foreign_models(
        gs_stylize::model_kind::Binary::Picture,
        std::path::Path::new(env!("CARGO_BIN_EXE_clipgaussian-2d")),
        dir.path(),
        "--model",
        &["--width", "8", "--height", "8"],
    );
}

/// `render` takes the size and distance the model records; a model that records none (MiraGe's
/// own PLY) asks for the flag.
#[test]
fn render_takes_the_size_the_model_records() {
    let dir = TempDir::new().unwrap();
    let recorded = dir.path().join("recorded.ply");
    let model = base_mirage::flat::FlatGaussians::new(GaussianSet::zeros(4, 0));
    let fitted = FittedTo {
        width: 12,
        height: 7,
        distance: 1.0,
    };
    base_mirage::model_file::write_model(&recorded, &model, &fitted).unwrap();
    let png = dir.path().join("r.png");
    run(bin()
        .args(["render", "--model", s(&recorded), "--out", s(&png)])
        .args(["--device", "cpu"]));
    assert_eq!(png_size(&png), (12, 7));
    run(bin()
        .args(["render", "--model", s(&recorded), "--out", s(&png)])
        .args(["--width", "5", "--device", "cpu"]));
    assert_eq!(png_size(&png), (5, 7));

    let mut plain = read_ply(&recorded).unwrap();
    plain.comments.clear();
    let unrecorded = dir.path().join("mirage.ply");
    gs_core::ply::write_ply(
        &unrecorded,
        &plain,
        gs_core::ply::PlyFormat::BinaryLittleEndian,
    )
    .unwrap();
    let err = fails(bin().args(["render", "--model", s(&unrecorded), "--out", s(&png)]));
    assert!(
        err.contains("records no picture size") && err.contains("--width"),
        "{err}"
    );
    run(bin()
        .args(["render", "--model", s(&unrecorded), "--out", s(&png)])
        .args(["--width", "6", "--height", "4", "--device", "cpu"]));
    assert_eq!(png_size(&png), (6, 4));
}

/// `eval` scores a stylized picture against the original and writes `metrics.json`'s fields;
/// CLIP-CONS and CLIP-F, which need several views, are null; a missing picture is named.
#[test]
fn eval_scores_a_picture_against_its_original() {
    let dir = TempDir::new().unwrap();
    let models = write_tiny_models(dir.path());
    let picture = write_picture(dir.path());
    let other = dir.path().join("other.png");
    image::RgbaImage::from_fn(W, H, |x, y| {
        image::Rgba([(y * 9) as u8, 40, (x * 5) as u8, 255])
    })
    .save(&other)
    .unwrap();
    let out = dir.path().join("metrics.json");
    let printed = run(bin()
        .args(["eval", "--renders", s(&other), "--gt", s(&picture)])
        .args(["--style-prompt", "fire", "--out", s(&out)])
        .args(["--clip-config", s(&models.clip_config)])
        .args(["--clip-weights", s(&models.clip_weights)])
        .args(["--tokenizer", s(&models.tokenizer)]));
    let printed = String::from_utf8_lossy(&printed.stdout);
    assert!(
        printed.contains("CLIP-S:") && printed.contains("n/a (one view)"),
        "{printed}"
    );
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(metrics["views"], 1);
    assert!(metrics["clip_s"].as_f64().unwrap().is_finite());
    assert!(metrics["clip_sim"].as_f64().unwrap().abs() > 0.0);
    assert!(metrics["clip_cons"].is_null() && metrics["clip_f"].is_null());
    let err = fails(
        bin()
            .args([
                "eval",
                "--renders",
                s(&dir.path().join("missing.png")),
                "--gt",
                s(&picture),
            ])
            .args([
                "--style-prompt",
                "fire",
                "--out",
                s(&dir.path().join("m2.json")),
            ])
            .args(["--clip-config", s(&models.clip_config)])
            .args(["--clip-weights", s(&models.clip_weights)])
            .args(["--tokenizer", s(&models.tokenizer)]),
    );
    assert!(err.contains("missing.png"), "{err}");
    let small = dir.path().join("small.png");
    image::RgbaImage::from_pixel(W / 2, H, image::Rgba([9, 9, 9, 255]))
        .save(&small)
        .unwrap();
    let err = fails(
        bin()
            .args(["eval", "--renders", s(&small), "--gt", s(&picture)])
            .args(["--style-prompt", "fire"])
            .args(["--out", s(&dir.path().join("m3.json"))])
            .args(["--clip-config", s(&models.clip_config)])
            .args(["--clip-weights", s(&models.clip_weights)])
            .args(["--tokenizer", s(&models.tokenizer)]),
    );
    assert!(
        err.contains("small.png: the render is 20x32 but its ground truth"),
        "{err}"
    );
}

/// Every subcommand has the flags the four binaries share, under the same names.
#[test]
fn the_shared_flags_have_the_same_names_in_every_subcommand() {
    gs_stylize::test_support::assert_shared_flags(
        std::path::Path::new(env!("CARGO_BIN_EXE_clipgaussian-2d")),
        true,
    );
}

/// `clip_precision` and `vgg_precision` `auto` time bf16 against f32 and say what they chose and
/// why; `CLIPGAUSSIAN_CPU_BF16` forces either (`0`: the losses of an f32 run; `1`: bf16's), and
/// a value that is neither is refused before any output.
#[test]
fn precision_auto_says_what_it_chose_and_the_switch_forces_it() {
    let dir = TempDir::new().unwrap();
    let models = write_tiny_models(dir.path());
    let picture = write_picture(dir.path());
    let command = |name: &str, precision: &str, switch: Option<&str>| {
        // `auto` for both, or `CLIP/VGG` apart.
        let (clip, vgg) = precision.split_once('/').unwrap_or((precision, precision));
        let mut cmd = bin();
        stylize_args(&mut cmd, &models, 3);
        cmd.args(["--picture", s(&picture), "--out", s(&dir.path().join(name))])
            .args(["--gaussians", "100", "--fit-steps", "10", "--device", "cpu"])
            .args(["--set", &format!("clip_precision={clip}")])
            .args(["--set", &format!("vgg_precision={vgg}")]);
        cmd.env_remove(style_loss::clip::CPU_BF16_ENV);
        if let Some(value) = switch {
            cmd.env(style_loss::clip::CPU_BF16_ENV, value);
        }
        cmd
    };
    let stylize = |name: &str, precision: &str, switch: Option<&str>| {
        let stdout =
            String::from_utf8_lossy(&run(&mut command(name, precision, switch)).stdout).to_string();
        let losses = std::fs::read_to_string(dir.path().join(name).join("losses.json")).unwrap();
        (stdout, losses)
    };
    let (_, f32_losses) = stylize("f32", "f32", None);
    let (off, off_losses) = stylize("off", "auto", Some("0"));
    for network in ["CLIP", "VGG"] {
        let line = format!("{network} precision: f32 (auto: CLIPGAUSSIAN_CPU_BF16=0)");
        assert!(off.contains(&line), "{off}");
    }
    assert_eq!(off_losses, f32_losses, "auto forced off is the f32 run");
    let (on, on_losses) = stylize("on", "auto", Some("1"));
    assert!(
        on.contains("CLIP precision: bf16 products (auto: CLIPGAUSSIAN_CPU_BF16=1)")
            && on.contains("VGG precision: bf16 backward products (auto: CLIPGAUSSIAN_CPU_BF16=1)"),
        "{on}"
    );
    assert_ne!(on_losses, f32_losses, "bf16 products change the losses");
    // Unforced, the tiny VGG has no layer wide enough for bf16; CLIP's choice follows its
    // timing here, and the run is the f32 run or the bf16 one accordingly.
    let (auto, auto_losses) = stylize("auto", "auto", None);
    if style_loss::clip::cpu_multiplies_bf16() {
        assert!(
            auto.contains(
                "VGG precision: f32 (auto: no layer of 256 channels or more, where bf16 runs)"
            ),
            "{auto}"
        );
        if auto.contains("CLIP precision: bf16 products (auto: bf16 ") {
            assert!(auto.contains("x faster here)"), "{auto}");
            // CLIP in bf16, VGG in f32 (its forced bf16 would also sum its forward in f32,
            // not exactly, even with no layer wide enough for bf16 products).
            let (_, apart) = stylize("apart", "bf16/f32", None);
            assert_eq!(auto_losses, apart);
        } else {
            assert!(auto.contains("CLIP precision: f32 (auto: bf16 "), "{auto}");
            assert_eq!(auto_losses, f32_losses);
        }
    } else {
        for network in ["CLIP", "VGG"] {
            let line = format!("{network} precision: f32 (auto: this CPU has no AVX-512 BF16)");
            assert!(auto.contains(&line), "{auto}");
        }
        assert_eq!(auto_losses, f32_losses);
    }
    let refused = command("bad", "auto", Some("2")).output().unwrap();
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success());
    assert!(
        stderr.contains("CLIPGAUSSIAN_CPU_BF16 = 2: must be 0"),
        "{stderr}"
    );
    assert!(!dir.path().join("bad").exists(), "nothing written");
}

/// A model given without a picture is stylized alone: its picture is its own render at the
/// size it records (written as original.png), so the content term starts at 0; a model that
/// records no size is refused naming --picture, before any output.
#[test]
fn a_model_alone_is_stylized_against_its_own_render() {
    let dir = TempDir::new().unwrap();
    let models = write_tiny_models(dir.path());
    let picture = write_picture(dir.path());
    let fit_dir = dir.path().join("fit");
    run(bin()
        .args([
            "fit",
            "--quiet",
            "--picture",
            s(&picture),
            "--out",
            s(&fit_dir),
        ])
        .args(["--gaussians", "200", "--steps", "20", "--device", "cpu"]));
    let model = fit_dir.join("model.ply");
    let sty = dir.path().join("alone");
    let mut cmd = bin();
    shown_stylize_args(&mut cmd, &models, 3);
    let out = run(cmd.args(["--model", s(&model), "--out", s(&sty), "--device", "cpu"]));
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(
        said.contains(&format!("picture: the model's own render, {W}x{H}")),
        "{said}"
    );
    assert_eq!(png_size(&sty.join("original.png")), (W, H));
    assert_eq!(png_size(&sty.join("stylized.png")), (W, H));
    let fitted = image::open(fit_dir.join("fitted.png")).unwrap().to_rgb8();
    let original = image::open(sty.join("original.png")).unwrap().to_rgb8();
    assert_eq!(fitted, original, "the picture is the model's render");
    let losses: Vec<gs_stylize::outputs::StepLosses> =
        serde_json::from_str(&std::fs::read_to_string(sty.join("losses.json")).unwrap()).unwrap();
    assert_eq!(losses[0].terms["content"], 0.0);

    let mut plain = read_ply(&model).unwrap();
    plain.comments.clear();
    let unrecorded = dir.path().join("mirage.ply");
    gs_core::ply::write_ply(
        &unrecorded,
        &plain,
        gs_core::ply::PlyFormat::BinaryLittleEndian,
    )
    .unwrap();
    let refused_out = dir.path().join("refused");
    let mut cmd = bin();
    stylize_args(&mut cmd, &models, 2);
    let err = fails(cmd.args(["--model", s(&unrecorded), "--out", s(&refused_out)]));
    assert!(
        err.contains("mirage.ply")
            && err.contains("records no picture size")
            && err.contains("--picture"),
        "{err}"
    );
    assert!(!refused_out.exists());
}
