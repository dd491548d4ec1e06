//! What a new modality implements, and nothing more: a model (`BaseModel`, and `GpuModel`
//! with the provided host construction) and its run's configuration (`drive::Modality`). This
//! one is as small as a modality gets: Gaussians whose geometry is fixed and whose one
//! parameter group is their colour, seen by two cameras, fitted to two pictures. The shared
//! driver fits it, keeps the fit, stylizes it, checkpoints, resumes and writes the run's files,
//! as it does for the four real modalities.

use std::borrow::Cow;
use std::path::{Path, PathBuf};

use gs_core::adam::{AdamHyper, GroupConfig, LrSchedule};
use gs_core::gaussians::GaussianGrads;
use gs_core::image_loss::PhotometricObjective;
use gs_core::model::{BaseModel, Forward, Group, ModelError, View};
use gs_core::raster::{render, GradMask};
use gs_core::render_clamp::RenderClamp;
use gs_core::sampler::ViewSampler;
use gs_core::train::TrainConfig;
use gs_core::{Camera, GaussianSet, Image};
use gs_stylize::drive::{self, Modality, OnStep};
use gs_stylize::outputs::{CONFIG_JSON, FIT_JSON, LOSSES_JSON, LOSSES_PNG};
use gs_stylize::test_support::replay_settings;
use gs_stylize::{
    Batches, PreparedRun, RunOptions, StyleSettings, StylizeError, StylizeJob, StylizeOutcome,
};
use gs_wgpu::backend::Trainer;
use gs_wgpu::GpuModel;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// The model: fixed Gaussians, their degree-0 colours the one parameter group.
#[derive(Clone, Debug, PartialEq)]
struct Coloured {
    geometry: GaussianSet,
    colours: Vec<f32>,
}

impl BaseModel for Coloured {
    type Tape = ();

    fn groups(&self) -> Vec<Group<'_>> {
        vec![Group::new("colours", &self.colours)]
    }

    fn groups_mut(&mut self) -> Vec<&mut [f32]> {
        vec![&mut self.colours]
    }

    fn grad_mask(&self, trained: &[bool]) -> GradMask {
        GradMask {
            sh_dc: trained[0],
            sh_rest: false,
            ..GradMask::COLORS
        }
    }

    fn forward(&self, _view: &View) -> Result<Forward<'_, ()>, ModelError> {
        let mut set = self.geometry.clone();
        set.sh_dc.copy_from_slice(&self.colours);
        Ok(Forward::untaped(Cow::Owned(set)))
    }

    fn backward(
        &self,
        _view: &View,
        _tape: (),
        grads: &GaussianGrads,
        trained: &[bool],
        out: &mut [Vec<f32>],
    ) -> Result<(), ModelError> {
        if trained[0] {
            out[0]
                .iter_mut()
                .zip(&grads.sh_dc)
                .for_each(|(o, g)| *o += g);
        }
        Ok(())
    }
}

/// Trains and renders on a GPU too, built on the host and uploaded.
impl GpuModel for Coloured {}

/// The run's configuration: the shared settings and the modality's own fields.
#[derive(Clone, Debug, Serialize)]
struct ColouredConfig {
    #[serde(flatten)]
    style: StyleSettings,
    out: PathBuf,
    model: Option<PathBuf>,
    fit_steps: u64,
}

/// What the run loads: the two pictures its views see.
struct Pictures {
    views: Vec<View>,
    images: Vec<Image>,
}

const SIDE: u32 = 40;
const BACKGROUND: [f32; 3] = [1.0; 3];

/// Two cameras looking at the origin from either side.
fn views() -> Vec<View> {
    [[0.0, 0.0, -3.0], [2.0, -0.5, -2.5]]
        .into_iter()
        .map(|eye| {
            let camera = Camera::look_at(eye, [0.0; 3], [0.0, -1.0, 0.0], 0.9, SIDE, SIDE);
            View::still(camera.expect("a valid camera"))
        })
        .collect()
}

/// 24 random Gaussians around the origin, grey.
fn geometry() -> GaussianSet {
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let mut set = GaussianSet::zeros(24, 0);
    set.means
        .iter_mut()
        .for_each(|m| *m = rng.random_range(-0.6..0.6));
    set.log_scales.fill(-2.0);
    set.opacity_logits.fill(2.0);
    set
}

/// A colour for each Gaussian, drawn with `seed`.
fn colours(seed: u64) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..24 * 3).map(|_| rng.random_range(-1.0..1.0)).collect()
}

impl Modality for ColouredConfig {
    type Model = Coloured;
    type Inputs = Pictures;
    type Fit = Coloured;
    type Outputs = Coloured;
    type Error = StylizeError;

    const BASE_MODEL: &'static str = "base.json";
    const FITTED: &'static str = "the pictures";

    fn settings(&self) -> &StyleSettings {
        &self.style
    }

    fn out(&self) -> Result<&Path, StylizeError> {
        Ok(&self.out)
    }

    fn check(&self) -> Result<(), StylizeError> {
        Ok(())
    }

    fn given_model(&self) -> Option<&Path> {
        self.model.as_deref()
    }

    /// Renders of the scene with colours of seed 1: what a user's pictures would be.
    fn load_inputs(
        &self,
        _run: &PreparedRun,
        _model: Option<&Path>,
    ) -> Result<Pictures, StylizeError> {
        let mut scene = geometry();
        scene.sh_dc = colours(1);
        let views = views();
        let images = views
            .iter()
            .map(|v| render(&scene, &v.camera, BACKGROUND).image)
            .collect();
        Ok(Pictures { views, images })
    }

    fn read_model(
        &self,
        _inputs: &Pictures,
        path: &Path,
        _own_fit: bool,
        _run: &PreparedRun,
    ) -> Result<Coloured, StylizeError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| StylizeError::Input(format!("{}: {e}", path.display())))?;
        let colours = serde_json::from_str(&text)
            .map_err(|e| StylizeError::Input(format!("{}: {e}", path.display())))?;
        Ok(Coloured {
            geometry: geometry(),
            colours,
        })
    }

    fn fit_steps(&self) -> u64 {
        self.fit_steps
    }

    /// L1 + D-SSIM towards the pictures from colours of seed 2, on the run's device.
    fn fit(
        &self,
        inputs: &Pictures,
        run: &PreparedRun,
        on_step: OnStep<'_>,
    ) -> Result<Coloured, StylizeError> {
        let model = Coloured {
            geometry: geometry(),
            colours: colours(2),
        };
        let mut trainer = Trainer::new(run.backend(), model, fit_groups(), AdamHyper::default())?;
        let mut objective = PhotometricObjective::new(inputs.images.clone(), 0.2);
        let config = TrainConfig {
            steps: self.fit_steps,
            background: BACKGROUND,
        };
        let mut sampler = ViewSampler::new(inputs.views.len(), 0);
        trainer
            .train(
                &inputs.views,
                &mut objective,
                &mut sampler,
                &config,
                on_step,
            )
            .map_err(|e| StylizeError::Input(e.to_string()))?;
        Ok(trainer.into_model())
    }

    fn keep_fit(
        &self,
        _inputs: &Pictures,
        fit: Coloured,
        path: &Path,
    ) -> Result<Coloured, StylizeError> {
        let text = serde_json::to_string(&fit.colours).expect("numbers serialize");
        std::fs::write(path, text)
            .map_err(|e| StylizeError::Input(format!("{}: {e}", path.display())))?;
        Ok(fit)
    }

    fn job(
        &self,
        inputs: &mut Pictures,
        model: Coloured,
        _run: &PreparedRun,
    ) -> Result<StylizeJob<Coloured>, StylizeError> {
        Ok(StylizeJob {
            model,
            groups: vec![GroupConfig::new("colours", LrSchedule::Constant(0.02))],
            views: inputs.views.clone(),
            images: inputs.images.clone(),
            labels: vec!["front".into(), "side".into()],
            masks: None,
            background: BACKGROUND,
            batches: Batches::ONE,
            render_clamp: RenderClamp::Off,
        })
    }

    fn write_outputs(
        &self,
        _inputs: Pictures,
        outcome: StylizeOutcome<Coloured>,
        run: &PreparedRun,
    ) -> Result<Coloured, StylizeError> {
        let model = outcome.model;
        let front = &views()[0];
        let mut set = model.geometry.clone();
        set.sh_dc.copy_from_slice(&model.colours);
        let stylized = render(&set, &front.camera, BACKGROUND).image;
        stylized.save_png(&run.out().join("stylized.png"))?;
        Ok(model)
    }
}

/// The fit's one Adam group.
fn fit_groups() -> Vec<GroupConfig> {
    vec![GroupConfig::new("colours", LrSchedule::Constant(0.05))]
}

#[test]
fn a_minimal_modality_fits_stylizes_checkpoints_and_resumes_through_the_shared_driver() {
    let dir = tempfile::tempdir().unwrap();
    let models = style_loss::test_models::write_tiny_models(dir.path());
    let mut style = replay_settings(StyleSettings::paper_3d(), &models, 3, 4);
    style.patch_size = 16;
    style.num_patches = 2;
    style.checkpoint_every = 2;
    let out = dir.path().join("run");
    let config = ColouredConfig {
        style,
        out: out.clone(),
        model: None,
        fit_steps: 30,
    };

    // Fit, keep the fit, stylize 4 steps, write the run's files and the modality's own.
    let stylized = drive::run(&config, &RunOptions::default()).unwrap();
    for file in [
        CONFIG_JSON,
        FIT_JSON,
        LOSSES_JSON,
        LOSSES_PNG,
        "base.json",
        "stylized.png",
    ] {
        assert!(out.join(file).is_file(), "{file} written");
    }
    let base: Vec<f32> =
        serde_json::from_str(&std::fs::read_to_string(out.join("base.json")).unwrap()).unwrap();
    let fitted = colours(2);
    assert_ne!(base, fitted, "the fit moved the colours");
    let error = |c: &[f32]| -> f32 { c.iter().zip(&colours(1)).map(|(a, b)| (a - b).abs()).sum() };
    assert!(
        error(&base) < error(&fitted),
        "the fit came closer to the pictures' colours"
    );
    assert_ne!(stylized.colours, base, "the stylization moved the colours");
    assert_eq!(stylized.geometry, geometry(), "and nothing else");
    let losses: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(out.join(LOSSES_JSON)).unwrap()).unwrap();
    assert_eq!(losses.len(), 4);

    // The same run with more steps, resumed: it reads back its own fit and continues from the
    // last checkpoint, to the colours of an uninterrupted 6-step run.
    let mut longer = config.clone();
    longer.style.steps = 6;
    let resume = RunOptions {
        resume: true,
        ..RunOptions::default()
    };
    let resumed = drive::run(&longer, &resume).unwrap();
    let all: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(out.join(LOSSES_JSON)).unwrap()).unwrap();
    assert_eq!(all.len(), 6);
    assert_eq!(
        all[..4],
        losses[..],
        "the first 4 steps are the first run's, not run again"
    );
    let straight_out = dir.path().join("straight");
    let straight = ColouredConfig {
        out: straight_out.clone(),
        model: Some(out.join("base.json")),
        ..longer
    };
    let uninterrupted = drive::run(&straight, &RunOptions::default()).unwrap();
    assert_eq!(resumed.colours, uninterrupted.colours);
    assert!(
        !straight_out.join(FIT_JSON).exists(),
        "a given model is not fitted"
    );
}
