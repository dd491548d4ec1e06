//! What the tests of the modality crates share (feature `test-support`): running a binary and
//! asserting that it succeeded or failed, the `stylize` flags of the tiny random-weight models
//! (`style_loss::test_models`), and the draws and errors of the replays of the authors' loops.

use std::path::Path;

use crate::model_kind::Binary;
use std::process::{Command, Output};

use style_loss::test_models::TinyModelFiles;

/// Runs `cmd`, asserting that it succeeds (the message shows its stderr); its output.
///
/// # Panics
/// If the program cannot be started or fails.
pub fn succeeds(cmd: &mut Command) -> Output {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("{cmd:?} did not start: {e}"));
    assert!(
        out.status.success(),
        "{:?} failed:\n{}",
        cmd,
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// Runs `cmd`, asserting that it fails; its stderr.
///
/// # Panics
/// If the program cannot be started or succeeds.
pub fn fails(cmd: &mut Command) -> String {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("{cmd:?} did not start: {e}"));
    assert!(!out.status.success(), "{cmd:?} should fail");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Checks that every `stylize` flag of a binary sets the configuration field it is named for:
/// `overrides_of` turns a command line (`stylize`, then the flags) into the binary's overrides;
/// the line is `own_flags` (the modality's flags with a value each), then every shared flag
/// with a value; the configuration `C` they make must hold `own_fields` and the shared flags'
/// values.
///
/// # Panics
/// If the configuration does not resolve or a field differs.
pub fn assert_flags_set<C>(
    own_flags: &[&str],
    own_fields: &[(&str, serde_json::Value)],
    overrides_of: impl FnOnce(Vec<&str>) -> Vec<crate::Override>,
) where
    C: serde::Serialize + serde::de::DeserializeOwned + Default,
{
    use serde_json::json;
    let shared_flags = [
        "--style-image",
        "s.png",
        "--source-prompt",
        "a cat",
        "--steps",
        "5",
        "--clip-config",
        "c.json",
        "--clip-weights",
        "c.safetensors",
        "--tokenizer",
        "t.json",
        "--vgg-weights",
        "v.safetensors",
        "--device",
        "cpu",
    ];
    let shared_fields = [
        ("style_image", json!("s.png")),
        ("style_prompt", json!(null)),
        ("source_prompt", json!("a cat")),
        ("steps", json!(5)),
        ("clip_config", json!("c.json")),
        ("clip_weights", json!("c.safetensors")),
        ("tokenizer", json!("t.json")),
        ("vgg_weights", json!("v.safetensors")),
        ("device", json!("cpu")),
    ];
    let line: Vec<&str> = std::iter::once("stylize")
        .chain(own_flags.iter().copied())
        .chain(shared_flags)
        .collect();
    let overrides = overrides_of(line);
    let config: C =
        crate::resolve_config(None, &overrides).expect("the flags make a configuration");
    let json = serde_json::to_value(&config).expect("configs serialize");
    for (field, want) in own_fields.iter().chain(&shared_fields) {
        assert_eq!(&json[*field], want, "{field}");
    }
}

/// The `fit.json` a `fit` into `out` wrote, checked: `steps` steps, a positive time and a
/// finite PSNR; returns the PSNR, dB.
///
/// # Panics
/// If the file is missing, does not parse, or fails a check.
pub fn fit_json_psnr(out: &Path, steps: u64) -> f64 {
    let text = std::fs::read_to_string(out.join(crate::outputs::FIT_JSON)).expect("fit.json");
    let report: crate::outputs::FitReport = serde_json::from_str(&text).expect("a fit report");
    assert_eq!(report.steps, steps, "{text}");
    assert!(report.seconds > 0.0, "{text}");
    let psnr = report.psnr_db.expect("the fit's PSNR");
    assert!(psnr.is_finite(), "{text}");
    psnr
}

/// Copies the folder `from` (recursively) to `to`.
///
/// # Panics
/// When a file cannot be read or written.
pub fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).unwrap();
        }
    }
}

/// `path` as a command-line argument.
///
/// # Panics
/// If the path is not UTF-8.
pub fn path_str(path: &Path) -> &str {
    path.to_str().expect("a UTF-8 path")
}

/// Adds the `stylize` flags of the tiny models in `models` to `cmd`: their files, VGG's tiny
/// widths, three patches of 16 pixels and the prompt "a red fire".
pub fn tiny_style_flags(cmd: &mut Command, models: &TinyModelFiles) {
    cmd.args(["--clip-config", path_str(&models.clip_config)])
        .args(["--clip-weights", path_str(&models.clip_weights)])
        .args(["--tokenizer", path_str(&models.tokenizer)])
        .args(["--vgg-weights", path_str(&models.vgg_weights)])
        .args(["--set", "vgg_widths=[4,8,16,32,32]"])
        .args(["--set", "patch_size=16", "--set", "num_patches=3"])
        .args(["--style-prompt", "a red fire"]);
}

/// The settings of a replayed run: `preset` with the style prompt "fire", `seed`, `steps`
/// updates on the cpu, 4 patches of 32 pixels, no checkpoints, and the tiny models of `models`.
pub fn replay_settings(
    preset: crate::StyleSettings,
    models: &TinyModelFiles,
    seed: u64,
    steps: u64,
) -> crate::StyleSettings {
    crate::StyleSettings {
        style_prompt: Some("fire".into()),
        steps,
        seed,
        device: gs_wgpu::backend::DeviceChoice::Cpu,
        patch_size: 32,
        num_patches: 4,
        checkpoint_every: 0,
        clip_config: Some(models.clip_config.clone()),
        clip_weights: Some(models.clip_weights.clone()),
        tokenizer: Some(models.tokenizer.clone()),
        vgg_weights: Some(models.vgg_weights.clone()),
        vgg_widths: models.vgg_widths.0,
        ..preset
    }
}

/// Writes `draws` (from [`replay_draws`]) as the replay fixture's `draws.json` in `folder`
/// (created when absent).
///
/// # Panics
/// If the folder or the file cannot be written.
pub fn save_replay_draws(folder: &Path, draws: &serde_json::Value) {
    std::fs::create_dir_all(folder).expect("create the fixture folder");
    let text = serde_json::to_string_pretty(draws).expect("draws serialize");
    std::fs::write(folder.join("draws.json"), text + "\n").expect("write draws.json");
}

/// Runs `binary selftest --device cpu`, asserting that it succeeds and that no part differs;
/// its table.
///
/// # Panics
/// If the binary cannot be started, fails, or reports a mismatch.
pub fn cpu_selftest_table(binary: &Path) -> String {
    let out = succeeds(Command::new(binary).args(["selftest", "--device", "cpu"]));
    let table = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(!table.contains("MISMATCH"), "{table}");
    table
}

/// The random draws of a stylization run with `settings` on `views` views of `height x width`:
/// the view and the patch crops and warps of each of its `settings.steps` updates, and its text
/// direction (from `settings.style_prompt` with its model files), as the JSON a replay of the
/// run in another framework reads (`draws.json` of the replay fixtures). Fields: `steps` (`[{view,
/// patches: [{top, left, corners}]}]`), `style_direction`, and the inputs they depend on.
///
/// # Panics
/// If the settings have no prompt or their model files cannot be read (a broken test setup).
pub fn replay_draws(
    settings: &crate::StyleSettings,
    views: usize,
    height: usize,
    width: usize,
) -> serde_json::Value {
    use gs_core::sampler::{BatchOrder, ViewSampler};
    use serde_json::json;
    use style_loss::{
        style_rng, ClipConfig, ClipModel, ClipTokenizer, PatchSettings, StyleDirection,
    };

    let mut sampler = ViewSampler::batches(views, 1, BatchOrder::Shuffled, settings.seed);
    let mut rng = style_rng(
        settings
            .seed
            .wrapping_add(crate::stylize::PATCH_SEED_OFFSET),
    );
    let patches = PatchSettings {
        patch_size: settings.patch_size,
        num_patches: settings.num_patches,
        distortion_scale: settings.distortion_scale,
    };
    let steps: Vec<serde_json::Value> = (0..settings.steps)
        .map(|_| {
            let view = sampler.next_batch().views[0];
            let drawn: Vec<serde_json::Value> = patches
                .sample(&mut rng, height, width)
                .expect("the patches fit the views")
                .iter()
                .map(|p| json!({"top": p.top, "left": p.left, "corners": p.corners}))
                .collect();
            json!({"view": view, "patches": drawn})
        })
        .collect();
    let file = |f: &Option<std::path::PathBuf>| f.clone().expect("the tiny model files are set");
    let config = ClipConfig::from_json_file(&file(&settings.clip_config)).expect("CLIP config");
    let clip = ClipModel::load_with_precision(
        &config,
        &file(&settings.clip_weights),
        &candle_core::Device::Cpu,
        settings.clip_precision,
    )
    .expect("CLIP weights");
    let tokenizer = ClipTokenizer::from_file(&file(&settings.tokenizer)).expect("tokenizer");
    let prompt = settings.style_prompt.as_deref().expect("a style prompt");
    let direction = StyleDirection::from_text(&clip, &tokenizer, prompt, &settings.source_prompt)
        .expect("the text direction")
        .as_tensor()
        .to_vec1::<f32>()
        .expect("a vector");
    json!({
        "seed": settings.seed, "views": views, "width": width, "height": height,
        "patch_size": settings.patch_size, "num_patches": settings.num_patches,
        "updates": settings.steps, "prompt": prompt, "source_prompt": settings.source_prompt,
        "style_direction": direction, "steps": steps,
    })
}

/// Asserts that the replay fixture's `draws.json` at `path` holds the draws `ours` (from
/// [`replay_draws`]): the same views and patches, the text direction within 1e-6. `regenerate`
/// says how to write the fixture again when they changed.
///
/// # Panics
/// When they differ, or the file cannot be read.
pub fn assert_replay_draws(path: &Path, ours: &serde_json::Value, regenerate: &str) {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let recorded: serde_json::Value = serde_json::from_str(&text).expect("draws.json is JSON");
    assert_eq!(
        ours["steps"], recorded["steps"],
        "the run's view order or patch draws changed: {regenerate}"
    );
    let values = |v: &serde_json::Value| -> Vec<f64> {
        v.as_array()
            .expect("a direction")
            .iter()
            .map(|x| x.as_f64().expect("a number"))
            .collect()
    };
    let (a, b) = (
        values(&ours["style_direction"]),
        values(&recorded["style_direction"]),
    );
    assert!(
        a.len() == b.len() && a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-6),
        "the run's text direction changed: {regenerate}"
    );
}

/// `|ours - reference| / |reference - start|`: how far a parameter group of our run ends from a
/// replay's, relative to the update the replay made.
///
/// # Panics
/// If the lengths differ or the replay did not move the group.
pub fn update_error(start: &[f32], ours: &[f32], reference: &[f64]) -> f64 {
    assert!(start.len() == ours.len() && ours.len() == reference.len());
    let norm = |v: &mut dyn Iterator<Item = f64>| v.map(|x| x * x).sum::<f64>().sqrt();
    let diff = norm(&mut ours.iter().zip(reference).map(|(&o, r)| f64::from(o) - r));
    let update = norm(&mut reference.iter().zip(start).map(|(r, &s)| r - f64::from(s)));
    assert!(update > 0.0, "the replay did not move this group");
    diff / update
}

/// The Gaussians (rows of `width` values of the group called `what`) that one side moved and
/// the other left exactly where they started, each named in a line ("Gaussian 7's colour
/// moved by the authors' loop, left in place by ours"): a Gaussian one rasterizer draws and the
/// other leaves out. Adam leaves a parameter whose gradients were all zero exactly in place, on
/// both sides.
///
/// # Panics
/// If the lengths differ or are not a multiple of `width`.
pub fn moved_by_one_side(
    start: &[f32],
    ours: &[f32],
    reference: &[f64],
    width: usize,
    what: &str,
) -> Vec<String> {
    assert!(start.len() == ours.len() && ours.len() == reference.len());
    assert_eq!(start.len() % width, 0, "rows of {width}");
    start
        .chunks_exact(width)
        .zip(ours.chunks_exact(width))
        .zip(reference.chunks_exact(width))
        .enumerate()
        .filter_map(|(i, ((s, o), r))| {
            let ours_moved = o.iter().zip(s).any(|(o, s)| o != s);
            let replay_moved = r.iter().zip(s).any(|(&r, &s)| r != f64::from(s));
            let (moved, left) = if replay_moved {
                ("the authors' loop", "ours")
            } else {
                ("ours", "the authors' loop")
            };
            (ours_moved != replay_moved)
                .then(|| format!("Gaussian {i}'s {what} moved by {moved}, left in place by {left}"))
        })
        .collect()
}

/// One small file of each model kind the binaries open, in `dir` (headers only: enough to be
/// recognized by [`crate::model_kind`], not to load): the binary that opens it, and its path.
fn model_of_each_binary(dir: &Path) -> Vec<(Binary, std::path::PathBuf)> {
    let ply = |extra: &str| {
        format!(
            "ply\nformat binary_little_endian 1.0\n{extra}element vertex 1\nproperty float x\n\
             end_header\n"
        )
        .into_bytes()
    };
    let header = r#"{"__metadata__":{"format":"clipgaussian-dmiso"}}"#;
    let mut safetensors = (header.len() as u64).to_le_bytes().to_vec();
    safetensors.extend(header.as_bytes());
    let files = [
        (
            Binary::Picture,
            "picture.ply",
            ply("comment clipgaussian-2d picture 8x8 distance 1\n"),
        ),
        (Binary::Scene, "scene.ply", ply("")),
        (
            Binary::Video,
            "video.ply",
            ply("element time 1\nproperty float time_func_0\n"),
        ),
        (Binary::DynamicScene, "dynamic.safetensors", safetensors),
    ];
    files
        .into_iter()
        .map(|(binary, name, bytes)| {
            let path = dir.join(name);
            std::fs::write(&path, bytes).expect("a model file in the test folder");
            (binary, path)
        })
        .collect()
}

/// Runs `run` (the binary `binary` given a model file) on a model of every other binary (a
/// plain Gaussian PLY is left out for 2D, which reads MiraGe's own) and asserts that each run
/// fails naming the binary that opens it.
fn assert_foreign_models_refused(
    binary: Binary,
    dir: &Path,
    run: impl Fn(&Path) -> std::process::Output,
) {
    for (opens, path) in model_of_each_binary(dir) {
        if opens == binary || (binary == Binary::Picture && opens == Binary::Scene) {
            continue;
        }
        let out = run(&path);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{}: accepted", path.display());
        assert!(
            stderr.contains(&format!("use {}", opens.name())),
            "{}: {stderr}",
            path.display()
        );
    }
}

/// Asserts that the binary `exe` (which is `binary`) refuses a model of every other binary
/// (written in the empty folder `dir`), naming the binary that opens it, in `render`
/// (`--model`, with `render_args` besides), `stylize` (the model given with `stylize_flag`)
/// and `interpolate` (`--a`, `--b`), and writes nothing.
///
/// # Panics
/// When a run succeeds, its error does not name the right binary, or an output appears.
pub fn assert_every_command_refuses_foreign_models(
    binary: Binary,
    exe: &Path,
    dir: &Path,
    stylize_flag: &str,
    render_args: &[&str],
) {
    let out = dir.join("out");
    let out_arg = path_str(&out);
    let run = |args: &[&str]| {
        Command::new(exe)
            .args(args)
            .output()
            .unwrap_or_else(|e| panic!("{} did not start: {e}", exe.display()))
    };
    assert_foreign_models_refused(binary, dir, |model| {
        let mut args = vec!["render", "--model", path_str(model)];
        args.extend_from_slice(render_args);
        args.extend(["--out", out_arg]);
        run(&args)
    });
    assert_foreign_models_refused(binary, dir, |model| {
        run(&["stylize", stylize_flag, path_str(model), "--out", out_arg])
    });
    let blend = out.join("blend");
    assert_foreign_models_refused(binary, dir, |model| {
        let model = path_str(model);
        let args = [
            "--a",
            model,
            "--b",
            model,
            "--t",
            "0.5",
            "--out",
            path_str(&blend),
        ];
        run(&[&["interpolate"][..], &args].concat())
    });
    assert!(!out.exists(), "{}: nothing is written", exe.display());
}

/// The flags a subcommand has in every binary that has it: one product, one set of names.
pub const SHARED_FLAGS: &[(&str, &[&str])] = &[
    (
        "stylize",
        &[
            "--config",
            "--model",
            "--out",
            "--style-prompt",
            "--style-image",
            "--source-prompt",
            "--steps",
            "--max-width",
            "--background",
            "--clip-config",
            "--clip-weights",
            "--tokenizer",
            "--vgg-weights",
            "--device",
            "--set",
            "--resume",
            "--quiet",
        ],
    ),
    (
        "fit",
        &[
            "--out",
            "--gaussians",
            "--steps",
            "--seed",
            "--max-width",
            "--background",
            "--device",
            "--quiet",
        ],
    ),
    ("render", &["--model", "--out", "--background", "--device"]),
    ("interpolate", &["--a", "--b", "--t", "--out"]),
    ("export", &["--model", "--out", "--format"]),
    (
        "eval",
        &[
            "--renders",
            "--gt",
            "--style-prompt",
            "--style-image",
            "--source-prompt",
            "--clip-config",
            "--clip-weights",
            "--tokenizer",
            "--background",
            "--out",
        ],
    ),
    ("selftest", &["--device"]),
];

/// The flags `stylize` has where the modality fits its own base model first (2D, video, 4D).
pub const STYLIZE_FIT_FLAGS: &[&str] = &["--gaussians", "--fit-steps"];

/// Asserts that the binary at `binary` has every subcommand of [`SHARED_FLAGS`] (`fit` only
/// when it `fits` its own base model) with every flag listed for it (from its `--help`),
/// `stylize` also [`STYLIZE_FIT_FLAGS`] when it fits, that each `--device` takes
/// `cpu, gpu, auto` and each `--background` `white`, `black` or `R,G,B`, and that `eval`
/// writes `metrics.json` by default.
///
/// # Panics
/// When a subcommand or a flag is missing, or a `--device` takes other values.
pub fn assert_shared_flags(binary: &Path, fits: bool) {
    for &(sub, shared) in SHARED_FLAGS.iter().filter(|(sub, _)| fits || *sub != "fit") {
        let mut flags = shared.to_vec();
        if fits && sub == "stylize" {
            flags.extend(STYLIZE_FIT_FLAGS);
        }
        let help = succeeds(Command::new(binary).args([sub, "--help"]));
        let help = String::from_utf8_lossy(&help.stdout);
        for flag in &flags {
            let listed = help
                .lines()
                .any(|l| l.trim_start().split([' ', ',', '=']).any(|w| w == *flag));
            assert!(listed, "{} {sub}: no {flag} in\n{help}", binary.display());
        }
        if sub == "eval" {
            assert!(
                help.contains("[default: metrics.json]"),
                "{} eval writes metrics.json by default:\n{help}",
                binary.display()
            );
        }
        for (flag, wrong, refusal) in [
            ("--background", "grey", "is not white, black or R,G,B"),
            ("--device", "tpu", "cpu, gpu, auto"),
        ] {
            if flags.contains(&flag) {
                let err = fails(Command::new(binary).args([sub, flag, wrong]));
                assert!(
                    err.contains(refusal),
                    "{} {sub} {flag} {wrong} is refused with {refusal:?}: {err}",
                    binary.display()
                );
            }
        }
    }
}
