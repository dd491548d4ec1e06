//! The 3D stylization run end to end on a tiny scene the test writes to disk (a random Gaussian
//! set as an ascii PLY with an extra property, and RGBA renders of it in the NeRF-synthetic
//! layout), with the tiny CLIP / VGG-19 fixtures of style-loss: outputs, falling loss, exact
//! resume (also after a stop request, as Ctrl-C makes), configuration files, and bad inputs
//! that are named and leave nothing behind.

mod common;
mod scene;

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use base_3dgs::dataset::nerf_synthetic::{self, Split};
use base_3dgs::dataset::{Background, LoadOptions};
use base_3dgs::evaluation::{evaluate_folders, evaluate_run, ClipFiles, Style, TEST_VIEWS_DIR};
use base_3dgs::stylize::config::BackgroundPixels;
use base_3dgs::stylize::{
    run, Override, RunOptions, SceneStylizeConfig, SceneStylizeError, StyleSettings, StylizeError,
};
use candle_core::{Device, Tensor};
use common::TempDir;
use gs_core::camera::Camera;
use gs_core::dataset::GroundTruth;
use gs_core::ply::{read_ply, write_ply, PlyFormat, PlyGaussians};
use gs_core::raster::render;
use gs_core::render_clamp::clamp_unit;
use gs_core::GaussianSet;
use gs_stylize::checkpoint;
use gs_stylize::outputs::{StepLosses, CONFIG_JSON, LOSSES_JSON, LOSSES_PNG};
use gs_stylize::rates::gaussian_stylization;
use gs_wgpu::backend::DeviceChoice;
use scene::{
    c2w, fixture, random_set, write_colmap_scene, write_scene, write_tiny_clip, FOV_X, SIZE, VIEWS,
};
use style_loss::image_layout::hwc_to_tensor;
use style_loss::{
    style_rng, ClipConfig, ClipModel, ClipTokenizer, LossWeights, PatchSettings, StyleDirection,
    StyleLoss, Vgg19Features, Vgg19Widths, DEFAULT_SOURCE_PROMPT,
};

/// A scene, tiny models, and a configuration that runs on them.
struct Setup {
    dir: TempDir,
    config: SceneStylizeConfig,
}

impl Setup {
    fn new(name: &str) -> Self {
        let dir = TempDir::new(name);
        let (ply, data) = write_scene(dir.path());
        let (clip_config, clip_weights) = write_tiny_clip(dir.path());
        let config = SceneStylizeConfig {
            model: Some(ply),
            data: Some(data),
            out: Some(dir.path().join("out")),
            preview_views: vec![0, 2],
            // The scene's pictures are renders over black with alpha: composited over white,
            // their background differs from the transparent pixels' stored black.
            background: [1.0; 3],
            ground_truth: GroundTruth::Composited,
            object: true,
            style: StyleSettings {
                style_prompt: Some("fire".into()),
                steps: 20,
                seed: 4,
                // Exact resume is a cpu property: GPU atomics sum in any order.
                device: DeviceChoice::Cpu,
                patch_size: 32,
                num_patches: 4,
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
        };
        Self { dir, config }
    }

    fn with(&self, edit: impl FnOnce(&mut SceneStylizeConfig)) -> SceneStylizeConfig {
        let mut c = self.config.clone();
        edit(&mut c);
        c
    }

    /// A red style picture in the temporary folder.
    fn style_image(&self) -> PathBuf {
        let path = self.dir.path().join("red.png");
        image::RgbImage::from_pixel(40, 30, image::Rgb([230, 25, 25]))
            .save(&path)
            .unwrap();
        path
    }
}

fn quiet() -> RunOptions {
    RunOptions::default()
}

fn resume() -> RunOptions {
    RunOptions {
        resume: true,
        ..RunOptions::default()
    }
}

/// The total and the (unweighted) directional loss of `config` summed over every view of its
/// dataset with the same patches each time, so the losses before and after stylization compare.
fn fixed_loss(config: &SceneStylizeConfig, gaussians: &GaussianSet) -> (f64, f64) {
    let device = Device::Cpu;
    let background = Background::from_rgb(config.background);
    let options = LoadOptions {
        background,
        ground_truth: config.ground_truth,
        downscale: 1,
        ..LoadOptions::default()
    };
    let data = nerf_synthetic::load(config.data.as_ref().unwrap(), Split::Train, &options).unwrap();
    let clip_config =
        ClipConfig::from_json_file(config.style.clip_config.as_ref().unwrap()).unwrap();
    let clip = ClipModel::load(
        &clip_config,
        config.style.clip_weights.as_ref().unwrap(),
        &device,
    )
    .unwrap();
    let tokenizer = ClipTokenizer::from_file(config.style.tokenizer.as_ref().unwrap()).unwrap();
    let direction =
        StyleDirection::from_text(&clip, &tokenizer, "fire", DEFAULT_SOURCE_PROMPT).unwrap();
    let vgg = Vgg19Features::load(
        config.style.vgg_weights.as_ref().unwrap(),
        Vgg19Widths(config.style.vgg_widths),
        &device,
    )
    .unwrap();
    let weights = LossWeights {
        directional: config.style.lambda_directional,
        patch: config.style.lambda_patch,
        content: config.style.lambda_content,
        background: config.style.lambda_background,
    };
    let patches = PatchSettings {
        patch_size: config.style.patch_size,
        num_patches: config.style.num_patches,
        distortion_scale: config.style.distortion_scale,
    };
    let loss = StyleLoss::new(clip, Some(vgg), direction, weights, patches).unwrap();
    let mut rng = style_rng(99);
    let s = SIZE as usize;
    (0..VIEWS)
        .map(|v| {
            let gt = hwc_to_tensor(&data.images[v].data, s, s, &device).unwrap();
            let mask = data.masks[v].as_ref().unwrap();
            let mask = Tensor::from_slice(&mask.data, (s, s), &device).unwrap();
            let cache = loss.cache_view(&gt, Some(&mask)).unwrap();
            // The loss sees the render clamped to [0, 1], as in the run.
            let img = clamp_unit(&render(gaussians, &data.views[v].camera, background.rgb()).image);
            let x = hwc_to_tensor(&img.data, s, s, &device).unwrap();
            let patches = loss.sample_patches(&mut rng, s, s).unwrap();
            let o = loss
                .loss_and_grad_with_patches(&x, &cache, &patches)
                .unwrap();
            (o.total, o.terms.directional)
        })
        .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1))
}

#[test]
fn a_run_from_files_writes_every_output_and_lowers_the_loss() {
    let setup = Setup::new("stylize-run");
    let out = setup.config.out.clone().unwrap();
    let summary = run(&setup.config, &quiet()).unwrap();

    let input = read_ply(setup.config.model.as_ref().unwrap()).unwrap();
    let stylized = read_ply(&summary.stylized_ply).unwrap();
    assert_eq!(stylized.gaussians.len(), input.gaussians.len());
    assert_eq!(stylized.gaussians, summary.gaussians);
    assert_eq!(stylized.extras, input.extras, "extras are carried over");
    assert_ne!(stylized.gaussians, input.gaussians, "the parameters moved");
    let header = std::fs::read(&summary.stylized_ply).unwrap();
    assert!(
        header.starts_with(b"ply\nformat ascii"),
        "same format as the input"
    );

    let losses: Vec<StepLosses> =
        serde_json::from_str(&std::fs::read_to_string(out.join(LOSSES_JSON)).unwrap()).unwrap();
    assert_eq!(losses, summary.losses);
    assert_eq!(losses.len(), 20);
    for (i, l) in losses.iter().enumerate() {
        assert_eq!(l.step, i as u64 + 1);
        let names: Vec<&str> = l.terms.keys().map(String::as_str).collect();
        assert_eq!(names, ["background", "content", "directional", "patch"]);
        let sum: f32 = l.terms.values().sum();
        assert!((sum - l.total).abs() <= 1e-4 * l.total.abs().max(1.0));
    }
    let before = fixed_loss(&setup.config, &input.gaussians);
    let after = fixed_loss(&setup.config, &stylized.gaussians);
    // The patch term (weight 90) dominates and moves slowly with a random tiny CLIP; the
    // directional term shows the pull towards the style clearly.
    assert!(
        after.0 < 0.98 * before.0,
        "total loss {before:?} -> {after:?}"
    );
    assert!(
        after.1 < 0.8 * before.1,
        "directional loss {before:?} -> {after:?}"
    );

    let plot = image::open(out.join(LOSSES_PNG)).unwrap();
    assert!(plot.width() > 100 && plot.height() > 100);
    // The first preview view is preview.png, as every modality's; the others are named.
    for name in ["preview.png", "preview_view002.png"] {
        let preview = image::open(out.join(name)).unwrap();
        assert_eq!((preview.width(), preview.height()), (2 * SIZE, SIZE));
    }
    assert!(!out.join("preview_view000.png").exists());
    // The viewer holds both models (the slider's ends) and every training camera.
    let scene = gs_stylize::viewer::read_scene(&out.join("viewer.html")).unwrap();
    let stylized_ply = gs_core::ply::read_ply(&out.join("model.ply")).unwrap();
    assert_eq!(scene["count"], stylized_ply.gaussians.len());
    assert_eq!(scene["models"].as_array().unwrap().len(), 2);
    assert!(scene["cameras"].as_array().unwrap().len() >= 3);
    let written: SceneStylizeConfig =
        serde_json::from_str(&std::fs::read_to_string(out.join(CONFIG_JSON)).unwrap()).unwrap();
    assert_eq!(written, setup.config);
    let leftovers: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .filter(|n| n.ends_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");

    // Scored on a test split (the training pictures again): the renders of the stylized scene
    // are written, and the metrics are `eval`'s of that folder against the test pictures.
    let data = setup.config.data.clone().unwrap();
    let transforms = std::fs::read_to_string(data.join("transforms_train.json")).unwrap();
    std::fs::write(
        data.join("transforms_test.json"),
        transforms.replace("./train/", "./test/"),
    )
    .unwrap();
    std::fs::create_dir_all(data.join("test")).unwrap();
    for k in 0..VIEWS {
        let name = format!("r_{k}.png");
        std::fs::copy(
            data.join("train").join(&name),
            data.join("test").join(&name),
        )
        .unwrap();
    }
    let style = &setup.config.style;
    let clip = ClipFiles {
        config: style.clip_config.clone(),
        weights: style.clip_weights.clone(),
        tokenizer: style.tokenizer.clone(),
    };
    let metrics = evaluate_run(&setup.config, clip.clone()).unwrap();
    assert_eq!(metrics.views, VIEWS);
    assert!(metrics.clip_cons.is_some_and(f64::is_finite), "{metrics:?}");
    // The ground truths as the run loads them (composited and cut to 8 bits, as 3DGS's loader
    // does), written losslessly as PNG.
    let options = LoadOptions {
        background: Background::from_rgb(setup.config.background),
        ground_truth: setup.config.ground_truth,
        ..LoadOptions::default()
    };
    let test = nerf_synthetic::load(&data, Split::Test, &options).unwrap();
    let truths = setup.dir.path().join("truths");
    std::fs::create_dir_all(&truths).unwrap();
    for (k, image) in test.images.iter().enumerate() {
        image.save_png(&truths.join(format!("r_{k}.png"))).unwrap();
    }
    let renders = out.join(TEST_VIEWS_DIR);
    let expected = evaluate_folders(
        &renders,
        &truths,
        &Style::Prompt("fire".into()),
        DEFAULT_SOURCE_PROMPT,
        &clip,
        setup.config.background,
    )
    .unwrap();
    assert_eq!(metrics, expected);
    let camera = Camera::from_nerf(c2w(1), FOV_X, SIZE, SIZE).unwrap();
    let expected = setup.dir.path().join("view1.png");
    render(&stylized.gaussians, &camera, setup.config.background)
        .image
        .save_png(&expected)
        .unwrap();
    assert_eq!(
        image::open(renders.join("r_1.png")).unwrap().to_rgb8(),
        image::open(&expected).unwrap().to_rgb8(),
        "the stylized scene from test view 1"
    );
}

#[test]
fn a_run_from_a_colmap_layout_keeps_the_count_and_its_cameras_match_the_nerf_twin() {
    let setup = Setup::new("stylize-colmap");
    let data = write_colmap_scene(setup.dir.path());
    // The COLMAP scene's cameras are the NeRF scene's: the loaded views project alike.
    let colmap = base_3dgs::dataset::colmap::load(&data, &LoadOptions::default()).unwrap();
    let nerf = nerf_synthetic::load(
        setup.config.data.as_ref().unwrap(),
        Split::Train,
        &LoadOptions::default(),
    )
    .unwrap();
    assert_eq!(colmap.views.len(), VIEWS);
    for (c, n) in colmap.views.iter().zip(&nerf.views) {
        let (a, _) = c.camera.project([0.2, -0.1, 0.3]).unwrap();
        let (b, _) = n.camera.project([0.2, -0.1, 0.3]).unwrap();
        assert!(
            (a[0] - b[0]).abs() < 1e-3 && (a[1] - b[1]).abs() < 1e-3,
            "{a:?} vs {b:?}"
        );
    }
    let config = setup.with(|c| {
        c.data = Some(data);
        c.style.steps = 6;
        c.preview_views = vec![1];
        c.background_mask = BackgroundPixels::Alpha;
    });
    let summary = run(&config, &quiet()).unwrap();
    let stylized = read_ply(&summary.stylized_ply).unwrap();
    assert_eq!(stylized.gaussians.len(), random_set().len());
    assert_eq!(summary.losses.len(), 6);
    assert!(summary.losses.iter().all(|l| l.total.is_finite()));
    // No alpha in a COLMAP scene: no background term under the alpha rule.
    assert!(!summary.losses[0].terms.contains_key("background"));
}

#[test]
fn a_run_with_the_authors_3d_defaults_has_a_background_term_only_for_an_object() {
    let setup = Setup::new("stylize-defaults");
    let defaults = SceneStylizeConfig::default();
    let config = |object: bool, out: &str| {
        setup.with(|c| {
            c.background = defaults.background;
            c.ground_truth = defaults.ground_truth;
            c.background_mask = defaults.background_mask;
            c.object = object;
            c.out = Some(setup.dir.path().join(out));
            c.style.steps = 3;
        })
    };
    assert!(!defaults.object && defaults.background == [0.0; 3]);
    let scene = run(&config(false, "scene"), &quiet()).unwrap();
    assert!(scene.losses.iter().all(|l| l.total.is_finite()));
    assert!(!scene.losses[0].terms.contains_key("background"));
    // The scene's transparent pixels are stored black: the colour rule marks them over black
    // (the render there is the same scene over black, so the term is small).
    let object = run(&config(true, "object"), &quiet()).unwrap();
    assert!(object.losses.iter().all(|l| l
        .terms
        .get("background")
        .is_some_and(|b| b.is_finite() && *b >= 0.0)));
}

#[test]
fn resuming_from_step_10_ends_where_an_uninterrupted_run_ends() {
    let setup = Setup::new("stylize-resume");
    let image = setup.style_image();
    let styled = |out: &str, steps: u64, every: u64| {
        setup.with(|c| {
            c.style.style_prompt = None;
            c.style.style_image = Some(image.clone());
            c.out = Some(setup.dir.path().join(out));
            c.style.steps = steps;
            c.style.checkpoint_every = every;
        })
    };
    let whole = run(&styled("whole", 20, 0), &quiet()).unwrap();
    assert!(!setup.dir.path().join("whole/checkpoint").exists());

    let first = run(&styled("parts", 10, 10), &quiet()).unwrap();
    assert_eq!(first.losses[..], whole.losses[..10]);
    assert!(first.gaussians != whole.gaussians);
    let parts_out = styled("parts", 20, 10).out.unwrap();
    assert_eq!(checkpoint::finished_step(&parts_out), Some(10));
    // A finished run has nothing to resume at its own step count; it continues with more.
    let e = run(&styled("parts", 10, 10), &resume())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("finished all its 10 steps") && e.contains("raise --steps above 10"),
        "{e}"
    );
    let other_seed = setup.with(|c| {
        *c = styled("parts", 20, 10);
        c.style.seed = 5;
    });
    let e = run(&other_seed, &resume()).unwrap_err().to_string();
    assert!(e.contains("seed") && e.contains("checkpoint"), "{e}");

    let e = run(&styled("parts", 5, 10), &resume())
        .unwrap_err()
        .to_string();
    assert!(e.contains("finished all its 10 steps"), "{e}");

    // A save interrupted between its two renames leaves the checkpoint parked in
    // `checkpoint.old`; resuming finds it there.
    std::fs::rename(
        checkpoint::checkpoint_dir(&parts_out),
        parts_out.join("checkpoint.old"),
    )
    .unwrap();
    let resumed = run(&styled("parts", 20, 10), &resume()).unwrap();
    assert!(
        resumed.gaussians == whole.gaussians,
        "the resumed run ends with other parameters"
    );
    assert_eq!(resumed.losses, whole.losses);
    let on_disk = read_ply(&resumed.stylized_ply).unwrap();
    assert!(on_disk.gaussians == whole.gaussians);

    let e = run(&styled("never-run", 20, 10), &resume())
        .unwrap_err()
        .to_string();
    assert!(e.contains("no checkpoint"), "{e}");

    // A stop request (Ctrl-C) ends the run after the current step with a checkpoint of it;
    // resuming finishes exactly like the uninterrupted run.
    let stopping = RunOptions {
        stop: Arc::new(AtomicBool::new(true)),
        ..RunOptions::default()
    };
    let stopped = styled("stopped", 20, 0);
    let out = stopped.out.clone().unwrap();
    let e = run(&stopped, &stopping).unwrap_err();
    assert!(
        matches!(
            e,
            SceneStylizeError::Stylize(StylizeError::Interrupted { step: 1, .. })
        ),
        "{e}"
    );
    assert!(e.to_string().contains("--resume"), "{e}");
    assert_eq!(checkpoint::load(&out).unwrap().step, 1);
    assert!(!out.join("model.ply").exists());
    // The live preview (every 5 % of 20 steps: each step) was written before the stop: the
    // first view's picture | its render, and the losses so far.
    let preview = image::open(out.join("preview.png")).unwrap();
    assert_eq!((preview.width(), preview.height()), (2 * SIZE, SIZE));
    let so_far: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(out.join("losses.json")).unwrap()).unwrap();
    assert_eq!(so_far.len(), 1);
    assert!(out.join("losses.png").is_file());
    let e = run(&stopped, &quiet()).unwrap_err().to_string();
    assert!(
        e.contains("unfinished run") && e.contains("--resume"),
        "a fresh run must not overwrite the checkpoint of an unfinished run: {e}"
    );
    let finished = run(&stopped, &resume()).unwrap();
    assert!(finished.gaussians == whole.gaussians);
    assert_eq!(finished.losses, whole.losses);
    // Its last step is saved and marked finished, although checkpoint_every is 0; a new run in
    // the folder is then allowed and replaces it.
    assert_eq!(checkpoint::load(&out).unwrap().step, 20);
    assert_eq!(checkpoint::finished_step(&out), Some(20));
    let again = run(&stopped, &quiet()).unwrap();
    assert!(again.gaussians == whole.gaussians);
    assert!(
        !checkpoint::checkpoint_dir(&out).exists(),
        "checkpoint_every 0 keeps none"
    );
}

#[test]
fn the_config_files_are_the_paper_defaults_and_unknown_fields_are_named() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let required = [
        Override::new("model", "scene.ply"),
        Override::new("data", "data"),
        Override::new("out", "out"),
        Override::parse("style_prompt=fire").unwrap(),
    ];
    let paper =
        SceneStylizeConfig::resolve(Some(&root.join("configs/3d.json")), &required).unwrap();
    let expected = SceneStylizeConfig {
        model: Some("scene.ply".into()),
        data: Some("data".into()),
        out: Some("out".into()),
        style: StyleSettings {
            style_prompt: Some("fire".into()),
            ..StyleSettings::paper_3d()
        },
        ..SceneStylizeConfig::default()
    };
    assert_eq!(paper, expected);
    assert_eq!(
        (
            paper.style.lambda_directional,
            paper.style.lambda_patch,
            paper.style.lambda_content
        ),
        (5.0, 90.0, 0.8)
    );
    assert_eq!(
        (
            paper.style.steps,
            paper.style.patch_size,
            paper.style.num_patches
        ),
        (4999, 128, 64)
    );
    let light =
        SceneStylizeConfig::resolve(Some(&root.join("configs/3d-light.json")), &required).unwrap();
    assert_eq!(
        light,
        SceneStylizeConfig {
            style: StyleSettings {
                lambda_patch: 35.0,
                ..expected.style.clone()
            },
            learning_rates: gaussian_stylization(0.002),
            ..expected.clone()
        }
    );

    let mut edits = required.to_vec();
    edits.push(Override::parse("preview_views=[1,3]").unwrap());
    edits.push(Override::parse("steps=7").unwrap());
    let edited = SceneStylizeConfig::resolve(None, &edits).unwrap();
    assert_eq!(
        (edited.preview_views.clone(), edited.style.steps),
        (vec![1, 3], 7)
    );

    edits.push(Override::parse("lamda_patch=3").unwrap());
    let e = SceneStylizeConfig::resolve(None, &edits)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("unknown field") && e.contains("lamda_patch"),
        "{e}"
    );
    assert!(Override::parse("no-equals-sign").is_err());
}

/// Runs `config`, expects an error containing every one of `words`, and checks that the output
/// folder was not created.
fn fails_cleanly(config: &SceneStylizeConfig, words: &[&str]) {
    let e: SceneStylizeError = run(config, &quiet()).unwrap_err();
    let message = e.to_string();
    for w in words {
        assert!(message.contains(w), "{w:?} not in {message:?}");
    }
    assert!(
        !config.out.as_ref().unwrap().exists(),
        "{message}: the output folder was created"
    );
}

#[test]
fn bad_inputs_are_named_and_leave_no_output() {
    let setup = Setup::new("stylize-bad");
    let root = setup.dir.path();
    let data = setup.config.data.clone().unwrap();

    fails_cleanly(
        &setup.with(|c| c.style.style_prompt = Some("  ".into())),
        &["style_prompt", "empty"],
    );
    fails_cleanly(
        &setup.with(|c| c.style.style_image = Some(root.join("red.png"))),
        &["exactly one style"],
    );
    fails_cleanly(
        &setup.with(|c| {
            c.style.style_prompt = None;
            c.style.style_image = Some(root.join("missing.png"));
        }),
        &["style image", "missing.png"],
    );
    fails_cleanly(
        &setup.with(|c| c.style.patch_size = 64),
        &["patch_size 64", "48x48", "r_0.png"],
    );
    fails_cleanly(
        &setup.with(|c| c.preview_views = vec![9]),
        &["preview_views", "9"],
    );

    let empty = root.join("empty-data");
    std::fs::create_dir_all(&empty).unwrap();
    fails_cleanly(
        &setup.with(|c| c.data = Some(empty.clone())),
        &["transforms_train.json", "empty-data"],
    );

    let colmap = root.join("colmap-data");
    std::fs::create_dir_all(colmap.join("sparse")).unwrap();
    fails_cleanly(
        &setup.with(|c| c.data = Some(colmap.clone())),
        &["colmap-data", "sparse"],
    );

    let bad_size = root.join("bad-size");
    std::fs::create_dir_all(bad_size.join("train")).unwrap();
    std::fs::copy(
        data.join("transforms_train.json"),
        bad_size.join("transforms_train.json"),
    )
    .unwrap();
    for k in 0..VIEWS {
        let name = format!("train/r_{k}.png");
        std::fs::copy(data.join(&name), bad_size.join(&name)).unwrap();
    }
    image::RgbaImage::new(SIZE + 2, SIZE)
        .save(bad_size.join("train/r_1.png"))
        .unwrap();
    fails_cleanly(
        &setup.with(|c| c.data = Some(bad_size.clone())),
        &["r_1.png", "50x48", "48x48"],
    );

    let partial = root.join("partial.ply");
    std::fs::write(
        &partial,
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
         property float z\nend_header\n0 0 0\n",
    )
    .unwrap();
    fails_cleanly(
        &setup.with(|c| c.model = Some(partial.clone())),
        &["partial.ply", "missing"],
    );

    let nan = root.join("nan.ply");
    let mut bytes = Vec::new();
    let tmp = root.join("binary.ply");
    write_ply(
        &tmp,
        &PlyGaussians::new(random_set()),
        PlyFormat::BinaryLittleEndian,
    )
    .unwrap();
    bytes.extend(std::fs::read(&tmp).unwrap());
    let body = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    bytes[body..body + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    std::fs::write(&nan, bytes).unwrap();
    fails_cleanly(
        &setup.with(|c| c.model = Some(nan.clone())),
        &["nan.ply", "not finite"],
    );

    fails_cleanly(
        &setup.with(|c| c.style.clip_weights = Some(root.join("no-clip.safetensors"))),
        &["no-clip.safetensors"],
    );
}

#[test]
fn the_binary_takes_flags_and_set_overrides() {
    let setup = Setup::new("stylize-cli");
    let c = &setup.config;
    let out = setup.dir.path().join("cli-out");
    let path = |p: &Option<PathBuf>| p.as_ref().unwrap().display().to_string();
    let args = |extra: &[&str]| {
        let mut v: Vec<String> = vec![
            "--model".into(),
            path(&c.model),
            "--data".into(),
            path(&c.data),
            "--out".into(),
            out.display().to_string(),
            "--style-prompt".into(),
            "fire".into(),
            "--steps".into(),
            "2".into(),
            "--clip-config".into(),
            path(&c.style.clip_config),
            "--clip-weights".into(),
            path(&c.style.clip_weights),
            "--tokenizer".into(),
            path(&c.style.tokenizer),
            "--vgg-weights".into(),
            path(&c.style.vgg_weights),
            "--set".into(),
            "vgg_widths=[4,8,16,32,32]".into(),
            "--set".into(),
            "patch_size=32".into(),
            "--set".into(),
            "num_patches=2".into(),
            "--quiet".into(),
        ];
        v.extend(extra.iter().map(|s| s.to_string()));
        v
    };
    let exe = env!("CARGO_BIN_EXE_clipgaussian-3d");
    let bad = std::process::Command::new(exe)
        .arg("stylize")
        .args(args(&["--set", "bogus_field=1"]))
        .output()
        .unwrap();
    assert!(!bad.status.success());
    let stderr = String::from_utf8_lossy(&bad.stderr);
    assert!(stderr.contains("bogus_field"), "{stderr}");
    assert!(!out.exists());

    let ok = std::process::Command::new(exe)
        .arg("stylize")
        .args(args(&["-r", "1"]))
        .output()
        .unwrap();
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    let written: SceneStylizeConfig =
        serde_json::from_str(&std::fs::read_to_string(out.join(CONFIG_JSON)).unwrap()).unwrap();
    assert_eq!((written.style.steps, written.style.num_patches), (2, 2));
    assert_eq!(
        read_ply(&out.join("model.ply")).unwrap().gaussians.len(),
        80
    );
}
