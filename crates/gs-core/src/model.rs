//! The `BaseModel` trait: how a modality (3DGS, MiraGe, VeGaS, D-MiSo) turns its parameters
//! into renderable Gaussians for a view and takes back their gradient.

use std::borrow::Cow;

use crate::camera::Camera;
use crate::gaussians::{GaussianGrads, GaussianSet, PARAM_NAMES};
use crate::raster::GradMask;

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

/// A model whose parameters (theta) produce the Gaussians rendered for each view.
///
/// Parameters are exposed as named groups of `f32` values, each trained by its own Adam group;
/// gradients come back in the same group order and layout.
pub trait BaseModel {
    /// Names of the parameter groups, in a fixed order.
    fn group_names(&self) -> Vec<String>;

    /// The parameter groups as mutable slices, in [`BaseModel::group_names`] order.
    fn groups_mut(&mut self) -> Vec<&mut [f32]>;

    /// Lengths of the parameter groups, in [`BaseModel::group_names`] order.
    fn group_lens(&self) -> Vec<usize>;

    /// The Gaussians to render for `view` (borrowed when they are the parameters themselves).
    fn gaussians(&self, view: &View) -> Cow<'_, GaussianSet>;

    /// Adds to `out` (one buffer per group, already sized) the gradient of the loss with respect
    /// to every group, given its gradient `grads` with respect to the Gaussians of `view`.
    /// Groups for which `trained[i]` is false may be skipped.
    fn backward(&self, view: &View, grads: &GaussianGrads, trained: &[bool], out: &mut [Vec<f32>]);

    /// Which Gaussian arrays need a gradient when only the groups with `trained[i]` are trained.
    fn grad_mask(&self, trained: &[bool]) -> GradMask;
}

/// Plain 3D Gaussians are their own renderable set: theta is the identity.
impl BaseModel for GaussianSet {
    fn group_names(&self) -> Vec<String> {
        PARAM_NAMES.iter().map(|s| s.to_string()).collect()
    }

    fn groups_mut(&mut self) -> Vec<&mut [f32]> {
        self.arrays_mut()
            .into_iter()
            .map(|v| v.as_mut_slice())
            .collect()
    }

    fn group_lens(&self) -> Vec<usize> {
        self.arrays().iter().map(|a| a.len()).collect()
    }

    fn gaussians(&self, _view: &View) -> Cow<'_, GaussianSet> {
        Cow::Borrowed(self)
    }

    fn backward(
        &self,
        _view: &View,
        grads: &GaussianGrads,
        trained: &[bool],
        out: &mut [Vec<f32>],
    ) {
        for ((src, dst), &t) in grads.arrays().iter().zip(out.iter_mut()).zip(trained) {
            if t {
                for (d, s) in dst.iter_mut().zip(src.iter()) {
                    *d += *s;
                }
            }
        }
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
}
