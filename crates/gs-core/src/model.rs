//! The `BaseModel` trait: how a modality (3DGS, MiraGe, VeGaS, D-MiSo) turns its parameters
//! into renderable Gaussians for a view and takes back their gradient.
//!
//! One view's construction is a fallible forward, which returns the Gaussians and a tape (what
//! the backward of the same step needs: D-MiSo's network graph; `()` for most models), and a
//! fallible backward that consumes the tape. The GPU twins of both are gs-wgpu's `GpuModel`
//! (provided: the Gaussians built on the host and uploaded, their gradient brought back), so
//! every model trains on either device; a model overrides them with its own kernels where
//! measurement says they pay.

use std::borrow::Cow;

use crate::adam::{GroupConfig, LrSchedule};
use crate::camera::Camera;
use crate::gaussians::{GaussianGrads, GaussianSet, PARAM_NAMES};
use crate::raster::GradMask;

/// A model's failure to build or differentiate a view's Gaussians (a network call that
/// failed, a view out of its range); it keeps its source.
pub type ModelError = Box<dyn std::error::Error + Send + Sync + 'static>;

/// One training view: a camera and, for dynamic modalities, a time.
#[derive(Clone, Debug, PartialEq)]
pub struct View {
    /// The camera.
    pub camera: Camera,
    /// Normalized time in `[0, 1]` (video frames, dynamic scenes); 0 for static scenes.
    pub time: f64,
}

impl View {
    /// A view of a static scene.
    pub fn still(camera: Camera) -> Self {
        Self { camera, time: 0.0 }
    }
}

/// What [`BaseModel::forward`] returns: the Gaussians of a view and the tape its backward
/// consumes.
#[derive(Debug)]
pub struct Forward<'a, T> {
    /// The Gaussians to render (borrowed when they are the parameters themselves).
    pub gaussians: Cow<'a, GaussianSet>,
    /// What the backward of the same step needs.
    pub tape: T,
}

impl<'a> Forward<'a, ()> {
    /// Gaussians that need no tape.
    pub fn untaped(gaussians: Cow<'a, GaussianSet>) -> Self {
        Self {
            gaussians,
            tape: (),
        }
    }
}

/// One parameter group of a model: its name (how configurations, checkpoints and optimizer
/// state find it) and its values.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Group<'a> {
    /// The group's name, unique within its model (e.g. `"means"`).
    pub name: &'a str,
    /// Its values, in the model's layout.
    pub values: &'a [f32],
}

impl<'a> Group<'a> {
    /// Group `name` holding `values`.
    pub fn new(name: &'a str, values: &'a [f32]) -> Self {
        Self { name, values }
    }
}

/// A model whose parameters (theta) produce the Gaussians rendered for each view.
///
/// Parameters are exposed as named groups of `f32` values ([`BaseModel::groups`], the one list
/// of names and lengths), each trained by its own Adam group, matched to it by name;
/// gradients come back in the same group order and layout. One step is
/// [`BaseModel::forward`] -> render -> loss -> rasterizer backward -> [`BaseModel::backward`]
/// (or their GPU twins, gs-wgpu's `GpuModel`) -> Adam.
pub trait BaseModel {
    /// What a view's forward keeps for its backward (`()` when nothing).
    type Tape;

    /// The parameter groups, named, in a fixed order: the model's one description of them.
    fn groups(&self) -> Vec<Group<'_>>;

    /// The values of the parameter groups as mutable slices, in [`BaseModel::groups`] order.
    fn groups_mut(&mut self) -> Vec<&mut [f32]>;

    /// Names of the parameter groups, in [`BaseModel::groups`] order.
    fn group_names(&self) -> Vec<String> {
        self.groups().iter().map(|g| g.name.to_string()).collect()
    }

    /// Lengths of the parameter groups, in [`BaseModel::groups`] order.
    fn group_lens(&self) -> Vec<usize> {
        self.groups().iter().map(|g| g.values.len()).collect()
    }

    /// Which Gaussian arrays need a gradient when only the groups with `trained[i]` are trained.
    fn grad_mask(&self, trained: &[bool]) -> GradMask;

    /// The Gaussians to render for `view` and the tape of this step.
    fn forward(&self, view: &View) -> Result<Forward<'_, Self::Tape>, ModelError>;

    /// Adds to `out` (one buffer per group, already sized where `trained[i]`) the gradient of
    /// the loss with respect to every trained group, given its gradient `grads` with respect to
    /// the Gaussians [`BaseModel::forward`] built for `view` and that step's `tape`.
    fn backward(
        &self,
        view: &View,
        tape: Self::Tape,
        grads: &GaussianGrads,
        trained: &[bool],
        out: &mut [Vec<f32>],
    ) -> Result<(), ModelError>;
}

/// Adds `src` to `dst` for every trained group: the backward of groups rendered as they are.
pub fn add_identity_grads(
    grads: &GaussianGrads,
    trained: &[bool],
    out: &mut [Vec<f32>],
    skip_group: Option<usize>,
) {
    for (group, ((src, dst), &t)) in grads
        .arrays()
        .iter()
        .zip(out.iter_mut())
        .zip(trained)
        .enumerate()
    {
        if t && Some(group) != skip_group {
            for (d, s) in dst.iter_mut().zip(src.iter()) {
                *d += *s;
            }
        }
    }
}

/// Plain 3D Gaussians are their own renderable set: theta is the identity.
impl BaseModel for GaussianSet {
    type Tape = ();

    fn groups(&self) -> Vec<Group<'_>> {
        PARAM_NAMES
            .iter()
            .zip(self.arrays())
            .map(|(name, values)| Group::new(name, values))
            .collect()
    }

    fn groups_mut(&mut self) -> Vec<&mut [f32]> {
        self.arrays_mut()
            .into_iter()
            .map(|v| v.as_mut_slice())
            .collect()
    }

    fn grad_mask(&self, trained: &[bool]) -> GradMask {
        GradMask {
            means: trained[0],
            scales: trained[1],
            rotations: trained[2],
            opacities: trained[3],
            sh_dc: trained[4],
            sh_rest: trained[5],
        }
    }

    fn forward(&self, _view: &View) -> Result<Forward<'_, ()>, ModelError> {
        Ok(Forward::untaped(Cow::Borrowed(self)))
    }

    fn backward(
        &self,
        _view: &View,
        _tape: (),
        grads: &GaussianGrads,
        trained: &[bool],
        out: &mut [Vec<f32>],
    ) -> Result<(), ModelError> {
        add_identity_grads(grads, trained, out, None);
        Ok(())
    }
}

/// Learning rates of the six parameter groups of plain Gaussians ([`PARAM_NAMES`] order), with
/// 3DGS's split of the colour rate: `sh_dc` at `feature`, `sh_rest` at `feature / 20`.
#[derive(Clone, Debug, PartialEq)]
pub struct GaussianLrs {
    /// Means (world units per step).
    pub means: LrSchedule,
    /// Log-scales.
    pub scales: f64,
    /// Quaternions.
    pub rotations: f64,
    /// Opacity logits.
    pub opacities: f64,
    /// `feature_lr`: degree-0 SH; higher degrees get a twentieth.
    pub feature: f64,
}

impl GaussianLrs {
    /// The Adam groups, in [`PARAM_NAMES`] order.
    pub fn groups(&self) -> Vec<GroupConfig> {
        let schedules = [
            self.means.clone(),
            LrSchedule::Constant(self.scales),
            LrSchedule::Constant(self.rotations),
            LrSchedule::Constant(self.opacities),
            LrSchedule::Constant(self.feature),
            LrSchedule::Constant(self.feature / 20.0),
        ];
        PARAM_NAMES
            .iter()
            .zip(schedules)
            .map(|(name, schedule)| GroupConfig::new(*name, schedule))
            .collect()
    }
}
