//! `clipgaussian-video` from file to file with the tiny random-weight CLIP and VGG: fit a
//! generated clip, stylize it (with the fitted model, and with the fit inside the run), keep
//! the frame count, frame size and Gaussian count, interpolate, render, eval the temporal
//! consistency part; refuse bad inputs with a clear error and nothing written.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use base_vegas::model_file::read_model;
use gs_stylize::test_support::{
    cpu_selftest_table, fails, fit_json_psnr, path_str as s, succeeds as run, tiny_style_flags,
};
use style_loss::test_models::{write_tiny_models, TinyModelFiles};

const W: u32 = 40;
const H: u32 = 32;
const FRAMES: usize = 6;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_clipgaussian-video"))
}

/// A frames folder: a square moving across a gradient, numbered 1..=FRAMES without padding.
fn write_clip(dir: &Path) -> PathBuf {
    let frames = dir.join("clip");
    std::fs::create_dir(&frames).unwrap();
    for f in 0..FRAMES {
        let img = image::RgbImage::from_fn(W, H, |x, y| {
            let inside = (x as usize).abs_diff(8 + 4 * f) < 5 && y.abs_diff(16) < 5;
            if inside {
                image::Rgb([230, 40, 30])
            } else {
                image::Rgb([(x * 6) as u8, (y * 7) as u8, 120])
            }
        });
        img.save(frames.join(format!("{}.png", f + 1))).unwrap();
    }
    frames
}

/// `fit` of `video` into `out` on the cpu with `gaussians` and `steps`.
fn fit_video(video: &Path, out: &Path, gaussians: usize, steps: u64) -> Output {
    run(bin()
        .args([
            "fit",
            "--quiet",
            "--device",
            "cpu",
            "--video",
            s(video),
            "--out",
            s(out),
        ])
        .args([
            "--gaussians",
            &gaussians.to_string(),
            "--steps",
            &steps.to_string(),
        ]))
}

fn stylize_args(cmd: &mut Command, models: &TinyModelFiles, steps: u64) {
    cmd.args(["stylize", "--quiet", "--steps", &steps.to_string()]);
    tiny_style_flags(cmd, models);
    cmd.args(["--set", "checkpoint_every=3", "--device", "cpu"]);
}

fn frame_sizes(dir: &Path) -> Vec<(u32, u32)> {
    let mut names: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    names.sort();
    names
        .iter()
        .map(|p| image::image_dimensions(p).unwrap())
        .collect()
}

#[test]
fn fit_stylize_interpolate_render_from_file_to_file() {
    let dir = tempfile::tempdir().unwrap();
    let models = write_tiny_models(dir.path());
    let clip = write_clip(dir.path());
    let fitted = dir.path().join("fitted");
    let out = fit_video(&clip, &fitted, 300, 60);
    let text = String::from_utf8_lossy(&out.stdout);
    let psnr = fit_json_psnr(&fitted, 60);
    assert!(
        text.contains(&format!("mean PSNR {psnr:.2} dB")) && text.contains("6 frames of 40x32"),
        "{text}"
    );
    assert_eq!(frame_sizes(&fitted.join("frames")), vec![(W, H); FRAMES]);
    assert!(fitted.join("preview.gif").is_file());
    // The first frame, original | fitted, as every modality's preview.png.
    assert_eq!(
        image::image_dimensions(fitted.join("preview.png")).unwrap(),
        (2 * W, H)
    );

    let styled = dir.path().join("styled");
    let mut cmd = bin();
    stylize_args(&mut cmd, &models, 4);
    let out = run(cmd
        .args(["--video", s(&clip), "--model", s(&fitted.join("model.ply"))])
        .args(["--out", s(&styled)]));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("wrote 6 frames (40x32)"), "{stdout}");
    assert!(
        stdout.lines().all(|l| !l.to_lowercase().contains("error")),
        "{stdout}"
    );
    assert_eq!(frame_sizes(&styled.join("frames")), vec![(W, H); FRAMES]);
    for name in [
        "preview.gif",
        "preview.png",
        "model.ply",
        "viewer.html",
        "losses.json",
        "losses.png",
        "config.json",
    ] {
        assert!(styled.join(name).is_file(), "{name}");
    }
    // The viewer plays the fit (slider 0) and the stylized model (1) frame by frame.
    let scene = gs_stylize::viewer::read_scene(&styled.join("viewer.html")).unwrap();
    assert_eq!(scene["animation"]["frames"], FRAMES);
    assert_eq!(scene["animation"]["models"].as_array().unwrap().len(), 2);
    assert_eq!(scene["cameras"][0]["width"], W);
    let (base, _) = read_model(&fitted.join("model.ply")).unwrap();
    let (stylized, record) = read_model(&styled.join("model.ply")).unwrap();
    assert_eq!(
        stylized.params().len(),
        base.params().len(),
        "the Gaussian count is kept"
    );
    assert_eq!(stylized.frames(), FRAMES);
    // Export: one frame to a file of the format its name says, every frame to a folder.
    let one = dir.path().join("frame2.splat");
    run(bin()
        .args(["export", "--model", s(&styled.join("model.ply"))])
        .args(["--frame", "2", "--out", s(&one)]));
    let frame2 = gs_core::splats::read_splats(&one).unwrap().gaussians;
    let at = |f: usize| {
        gs_stylize::export::gaussians_at(&stylized, base_vegas::folded::view_time(f, FRAMES))
            .unwrap()
    };
    assert_eq!(frame2.len(), at(2).len());
    assert_eq!(frame2.means, at(2).means, ".splat keeps positions exactly");
    assert_ne!(frame2.means, at(0).means, "the frame's own Gaussians");
    let every = dir.path().join("every");
    run(bin()
        .args(["export", "--model", s(&styled.join("model.ply"))])
        .args(["--all-frames", "--format", "spz", "--out", s(&every)]));
    for f in 0..FRAMES {
        let path = every.join(format!("{f:05}.spz"));
        let set = gs_core::splats::read_splats(&path).unwrap().gaussians;
        assert_eq!(set.len(), at(f).len(), "{}", path.display());
    }
    // A page of the fit and its stylization; a page of every frame is one page, not a folder.
    let page = dir.path().join("video.html");
    let said = run(bin()
        .args(["export", "--model", s(&fitted.join("model.ply"))])
        .args(["--b", s(&styled.join("model.ply")), "--out", s(&page)]));
    let said = String::from_utf8_lossy(&said.stdout);
    assert!(said.contains("and their stylization"), "{said}");
    let scene = gs_stylize::viewer::read_scene(&page).unwrap();
    assert_eq!(scene["animation"]["models"].as_array().unwrap().len(), 2);
    let e = fails(
        bin()
            .args(["export", "--model", s(&styled.join("model.ply"))])
            .args([
                "--all-frames",
                "--format",
                "html",
                "--out",
                s(&dir.path().join("pages")),
            ]),
    );
    assert!(e.contains("--format html writes one page"), "{e}");
    let e = fails(
        bin()
            .args(["export", "--model", s(&styled.join("model.ply"))])
            .args(["--frame", "6", "--out", s(&dir.path().join("x.ply"))]),
    );
    assert!(
        e.contains("--frame 6") && e.contains("frames 0 to 5"),
        "{e}"
    );
    assert_eq!(record.map(|r| (r.width, r.height)), Some((W, H)));
    // Colours only: everything but the SH DC is the fit's.
    assert_eq!(stylized.params().xyz, base.params().xyz);
    assert_eq!(stylized.params().m, base.params().m);
    assert_eq!(stylized.time_logits(), base.time_logits());
    assert_ne!(stylized.params().sh_dc, base.params().sh_dc);

    let mix = dir.path().join("mix.ply");
    let said = run(bin()
        .args(["interpolate", "--a", s(&fitted.join("model.ply"))])
        .args([
            "--b",
            s(&styled.join("model.ply")),
            "--t",
            "0.5",
            "--out",
            s(&mix),
        ]));
    let (mixed, _) = read_model(&mix).unwrap();
    let count = format!("({} Gaussians, t = 0.5)", mixed.params().len());
    let said = String::from_utf8_lossy(&said.stdout);
    assert!(said.contains(&count), "{count} in {said}");
    let (a, b) = (base.params().sh_dc[0], stylized.params().sh_dc[0]);
    assert!((mixed.params().sh_dc[0] - 0.5 * (a + b)).abs() < 1e-6);

    let rendered = dir.path().join("rendered");
    run(bin().args([
        "render",
        "--device",
        "cpu",
        "--model",
        s(&mix),
        "--out",
        s(&rendered),
    ]));
    assert_eq!(frame_sizes(&rendered.join("frames")), vec![(W, H); FRAMES]);

    // The fit inside the run, then a resume that continues it to 6 steps.
    let inside = dir.path().join("inside");
    let mut cmd = bin();
    stylize_args(&mut cmd, &models, 3);
    run(cmd.args(["--video", s(&clip), "--out", s(&inside)]).args([
        "--gaussians",
        "200",
        "--fit-steps",
        "20",
    ]));
    assert!(inside.join("base.ply").is_file());
    let mut cmd = bin();
    stylize_args(&mut cmd, &models, 6);
    let resumed = run(cmd
        .args(["--video", s(&clip), "--out", s(&inside), "--resume"])
        .args(["--gaussians", "200", "--fit-steps", "20"]));
    let said = String::from_utf8_lossy(&resumed.stdout);
    assert!(said.contains("resuming from step 3 of 6 ("), "{said}");
    let losses: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(inside.join("losses.json")).unwrap())
            .unwrap();
    assert_eq!(losses.as_array().unwrap().len(), 6);
    // The same run without the interruption ends with the same bytes.
    let whole = dir.path().join("whole");
    let mut cmd = bin();
    stylize_args(&mut cmd, &models, 6);
    run(cmd.args(["--video", s(&clip), "--out", s(&whole)]).args([
        "--gaussians",
        "200",
        "--fit-steps",
        "20",
    ]));
    assert_eq!(
        std::fs::read(whole.join("model.ply")).unwrap(),
        std::fs::read(inside.join("model.ply")).unwrap(),
        "a run resumed at step 3 ends where an uninterrupted one does"
    );
}

#[test]
fn bad_inputs_are_refused_with_clear_errors_and_nothing_written() {
    let dir = tempfile::tempdir().unwrap();
    let models = write_tiny_models(dir.path());
    let clip = write_clip(dir.path());
    let out = dir.path().join("out");
    let refused = |extra: &[&str]| {
        let mut cmd = bin();
        stylize_args(&mut cmd, &models, 2);
        let err = fails(cmd.args(["--out", s(&out)]).args(extra));
        assert!(!out.exists(), "nothing written for {extra:?}: {err}");
        assert!(err.starts_with("error: "), "{err}");
        err
    };
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let e = refused(&["--video", s(&empty)]);
    assert!(
        e.contains("empty") && e.contains("no PNG or JPEG frames"),
        "{e}"
    );
    let e = refused(&["--video", s(&dir.path().join("missing"))]);
    assert!(e.contains("missing") && e.contains("no such file"), "{e}");
    let e = refused(&["--video", s(&clip), "--set", "patch_size=64"]);
    assert!(e.contains("patch_size 64") && e.contains("1.png"), "{e}");
    let e = refused(&["--video", s(&clip), "--set", "bogus=1"]);
    assert!(e.contains("bogus"), "{e}");
    let e = refused(&[]);
    assert!(e.contains("video: is required"), "{e}");

    // A model of another video (3 frames) is refused before any training.
    let other = dir.path().join("other");
    std::fs::create_dir(&other).unwrap();
    for f in 0..3 {
        image::RgbImage::from_pixel(W, H, image::Rgb([10, 20, 30 * f]))
            .save(other.join(format!("{f}.png")))
            .unwrap();
    }
    let other_fit = dir.path().join("other_fit");
    fit_video(&other, &other_fit, 50, 5);
    let e = refused(&[
        "--video",
        s(&clip),
        "--model",
        s(&other_fit.join("model.ply")),
    ]);
    assert!(e.contains("holds 3 frames, the video 6"), "{e}");

    // A clip whose frames differ in size.
    let mixed = dir.path().join("mixed");
    std::fs::create_dir(&mixed).unwrap();
    image::RgbImage::new(W, H)
        .save(mixed.join("0.png"))
        .unwrap();
    image::RgbImage::new(W + 2, H)
        .save(mixed.join("1.png"))
        .unwrap();
    let e = fails(bin().args(["fit", "--quiet", "--video", s(&mixed), "--out", s(&out)]));
    assert!(e.contains("1.png is 42x32"), "{e}");
    assert!(!out.exists());
}

#[test]
fn help_explains_every_subcommand_and_option() {
    let out = run(bin().arg("--help"));
    let text = String::from_utf8_lossy(&out.stdout);
    for sub in ["stylize", "fit", "render", "interpolate", "eval"] {
        assert!(text.contains(sub), "{sub} in --help");
    }
    let out = run(bin().args(["eval", "--help"]));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("--renders") && text.contains("unwarped"),
        "{text}"
    );
}

#[test]
fn the_configuration_files_hold_the_paper_defaults() {
    use base_vegas::stylize::VideoStylizeConfig;
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
    let paper: VideoStylizeConfig =
        gs_stylize::resolve_config(Some(&root.join("video.json")), &[]).unwrap();
    assert_eq!(paper, VideoStylizeConfig::default());
    let s = &paper.style;
    assert_eq!(
        (
            s.lambda_directional,
            s.lambda_patch,
            s.lambda_content,
            s.lambda_background
        ),
        (5.0, 90.0, 0.5, 0.0)
    );
    assert_eq!((s.steps, s.num_patches, s.patch_size), (4999, 64, 128));
    assert_eq!(paper.learning_rates.trained(), ["f_dc"]);
    let light: VideoStylizeConfig =
        gs_stylize::resolve_config(Some(&root.join("video-light.json")), &[]).unwrap();
    let mut expected = paper.clone();
    expected
        .learning_rates
        .set("f_dc", gs_stylize::rates::GroupRate::Constant(0.002));
    expected.style.lambda_patch = 45.0;
    assert_eq!(light, expected);
}

#[test]
fn eval_scores_stylized_frames_against_the_video() {
    let dir = tempfile::tempdir().unwrap();
    let models = write_tiny_models(dir.path());
    let clip = write_clip(dir.path());
    let metrics = dir.path().join("metrics.json");
    let eval = |renders: &Path| {
        let mut cmd = bin();
        cmd.args(["eval", "--renders", s(renders), "--gt", s(&clip)])
            .args(["--style-prompt", "a red fire"])
            .args(["--clip-config", s(&models.clip_config)])
            .args(["--clip-weights", s(&models.clip_weights)])
            .args(["--tokenizer", s(&models.tokenizer)])
            .args(["--out", s(&metrics)]);
        cmd
    };
    // The video against itself: CLIP-F is 100, and the temporal numbers are the original's.
    let table = run(&mut eval(&clip));
    let table = String::from_utf8_lossy(&table.stdout);
    for line in [
        "views:     6",
        "CLIP-F:    100.0",
        "short-range RMSE: 0.",
        "long-range RMSE:  ",
    ] {
        assert!(table.contains(line), "{line} in {table}");
    }
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&metrics).unwrap()).unwrap();
    assert_eq!(m["views"], FRAMES);
    assert!((m["clip_f"].as_f64().unwrap() - 100.0).abs() < 1e-3, "{m}");
    assert_eq!(m["short_range_rmse"], m["original_short_range_rmse"]);
    assert!(
        m["short_range_rmse"].as_f64().unwrap() > 0.0,
        "the square moves"
    );
    assert!(
        m["long_range_rmse"].is_null(),
        "6 frames have no pair 7 apart"
    );
    for key in ["clip_s", "clip_sim", "clip_cons"] {
        assert!(m[key].as_f64().unwrap().is_finite(), "{key}: {m}");
    }
    // A finished run's frames are scored as eval scores them (what a batch asks).
    let out = dir.path().join("run");
    let frames = out.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    for entry in std::fs::read_dir(&clip).unwrap() {
        let path = entry.unwrap().path();
        std::fs::copy(&path, frames.join(path.file_name().unwrap())).unwrap();
    }
    let config = base_vegas::stylize::VideoStylizeConfig {
        video: Some(clip.clone()),
        out: Some(out),
        style: gs_stylize::StyleSettings {
            style_prompt: Some("a red fire".into()),
            ..base_vegas::stylize::VideoStylizeConfig::default().style
        },
        ..base_vegas::stylize::VideoStylizeConfig::default()
    };
    let files = gs_stylize::evaluation::ClipFiles {
        config: Some(models.clip_config.clone()),
        weights: Some(models.clip_weights.clone()),
        tokenizer: Some(models.tokenizer.clone()),
    };
    let scored = base_vegas::evaluation::evaluate_run(&config, files).unwrap();
    assert_eq!(serde_json::to_value(scored).unwrap(), m);
    // Fewer stylized frames than the video's: refused.
    let short = dir.path().join("short");
    std::fs::create_dir(&short).unwrap();
    for f in 1..=3 {
        std::fs::copy(
            clip.join(format!("{f}.png")),
            short.join(format!("{f}.png")),
        )
        .unwrap();
    }
    let e = fails(&mut eval(&short));
    assert!(e.contains("holds 3 pictures") && e.contains("has 6"), "{e}");
    // Frames of another shape (as wide, not as high): refused naming the frame.
    let cropped = dir.path().join("cropped");
    std::fs::create_dir(&cropped).unwrap();
    for f in 1..=FRAMES {
        let frame = image::open(clip.join(format!("{f}.png"))).unwrap();
        frame
            .crop_imm(0, 0, W, H / 2)
            .save(cropped.join(format!("{f}.png")))
            .unwrap();
    }
    let e = fails(&mut eval(&cropped));
    assert!(
        e.contains("frame 0: the render is 40x16 but its ground truth"),
        "{e}"
    );
}

#[test]
fn render_follows_the_record_and_refuses_what_does_not_fit_it() {
    let dir = tempfile::tempdir().unwrap();
    let clip = write_clip(dir.path());
    let fitted = dir.path().join("fitted");
    fit_video(&clip, &fitted, 100, 5);
    let model = fitted.join("model.ply");
    let out = dir.path().join("r");
    let render = |extra: &[&str]| {
        let mut cmd = bin();
        cmd.args([
            "render",
            "--device",
            "cpu",
            "--model",
            s(&model),
            "--out",
            s(&out),
        ])
        .args(extra);
        cmd
    };
    let e = fails(&mut render(&["--width", "40"]));
    assert!(e.contains("both --width and --height"), "{e}");
    let e = fails(&mut render(&["--width", "40", "--height", "40"]));
    assert!(e.contains("aspect ratio") && e.contains("40x32"), "{e}");
    let e = fails(&mut render(&["--background", "2,0,0"]));
    assert!(e.contains("channels in [0, 1]"), "{e}");
    assert!(!out.exists(), "nothing written");
    run(&mut render(&[
        "--width",
        "80",
        "--height",
        "64",
        "--background",
        "1,1,1",
    ]));
    assert_eq!(frame_sizes(&out.join("frames")), vec![(80, 64); FRAMES]);
    let e = fails(
        bin()
            .args([
                "fit",
                "--quiet",
                "--video",
                s(&clip),
                "--out",
                s(&dir.path().join("f")),
            ])
            .args(["--fps", "0"]),
    );
    assert!(e.contains("--fps 0 must be positive"), "{e}");
}

#[test]
fn selftest_on_the_cpu_prints_every_part_and_passes() {
    let table = cpu_selftest_table(Path::new(env!("CARGO_BIN_EXE_clipgaussian-video")));
    assert!(table.contains("| three Adam steps |"), "{table}");
}

/// A model of another modality is refused naming the binary that opens it, by `render`,
/// `stylize` and `interpolate`.
#[test]
fn a_model_of_another_modality_names_its_binary() {
    let dir = tempfile::tempdir().unwrap();
    gs_stylize::test_support::assert_every_command_refuses_foreign_models(
        gs_stylize::model_kind::Binary::Video,
        std::path::Path::new(env!("CARGO_BIN_EXE_clipgaussian-video")),
        dir.path(),
        "--model",
        &[],
    );
}

/// Every subcommand has the flags the four binaries share, under the same names.
#[test]
fn the_shared_flags_have_the_same_names_in_every_subcommand() {
    gs_stylize::test_support::assert_shared_flags(
        std::path::Path::new(env!("CARGO_BIN_EXE_clipgaussian-video")),
        true,
    );
}

/// A model given without a video is stylized alone: its frames are its own renders at the
/// size and rate it records, so the content term starts at 0; one that records no frame size
/// is refused naming --video, before any output.
#[test]
fn a_model_alone_is_stylized_against_its_own_frames() {
    let dir = tempfile::tempdir().unwrap();
    let models = write_tiny_models(dir.path());
    let clip = write_clip(dir.path());
    let fitted = dir.path().join("fitted");
    fit_video(&clip, &fitted, 200, 10);
    let model = fitted.join("model.ply");
    let styled = dir.path().join("alone");
    let mut cmd = bin();
    stylize_args(&mut cmd, &models, 3);
    let out = run(cmd.args(["--model", s(&model), "--out", s(&styled)]));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("wrote 6 frames (40x32)"), "{stdout}");
    assert_eq!(frame_sizes(&styled.join("frames")), vec![(W, H); FRAMES]);
    let losses: Vec<gs_stylize::outputs::StepLosses> =
        serde_json::from_str(&std::fs::read_to_string(styled.join("losses.json")).unwrap())
            .unwrap();
    assert_eq!(losses[0].terms["content"], 0.0);
    let (stylized, record) = read_model(&styled.join("model.ply")).unwrap();
    assert_eq!(stylized.frames(), FRAMES);
    assert_eq!(record.map(|r| (r.width, r.height)), Some((W, H)));

    // VeGaS's own file records no frame size: the same file without the record's comment
    // (renamed to another comment of the same length, so the header keeps its size).
    let bytes = std::fs::read(&model).unwrap();
    let at = bytes
        .windows(b"comment clipgaussian-video".len())
        .position(|w| w == b"comment clipgaussian-video")
        .unwrap();
    let mut plain = bytes.clone();
    plain[at + 8..at + 26].copy_from_slice(b"made-by-hand-video");
    let unrecorded = dir.path().join("vegas.ply");
    std::fs::write(&unrecorded, plain).unwrap();
    let refused_out = dir.path().join("refused");
    let mut cmd = bin();
    stylize_args(&mut cmd, &models, 2);
    let err = fails(cmd.args(["--model", s(&unrecorded), "--out", s(&refused_out)]));
    assert!(
        err.contains("vegas.ply")
            && err.contains("records no frame size")
            && err.contains("--video"),
        "{err}"
    );
    assert!(!refused_out.exists());
}
