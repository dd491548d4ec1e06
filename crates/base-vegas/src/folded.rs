//! VeGaS's model of a video behind [`BaseModel`]: folded Gaussians ([`FoldedParams`]) and the
//! global time function ([`crate::time`]), each frame rendered as the 3D Gaussians of
//! [`build_frame`] at that frame's learned time.
//!
//! A view names its frame by its time: frame `f` of `F` is the view time `f / (F - 1)`
//! ([`view_time`]); the model renders it at the learned time `t_f`, so the time logits are
//! trained through every frame.

use std::borrow::Cow;

use gs_core::gaussians::GaussianGrads;
use gs_core::model::{BaseModel, Forward, Group, ModelError, View};
use gs_core::raster::GradMask;
use gs_wgpu::GpuModel;

use crate::frame::{add_frame_grads, build_frame, FoldedParams, FrameTape, POLY_LEN};
use crate::time::{add_time_grads, frame_time};

/// The parameter groups, in order (VeGaS's names where it has them).
pub const GROUP_NAMES: [&str; 9] = [
    "xyz", "scaling", "rotation", "m", "sigma", "w", "opacity", "f_dc", "time",
];

/// Group indices in [`GROUP_NAMES`].
mod group {
    pub const XYZ: usize = 0;
    pub const SCALING: usize = 1;
    pub const ROTATION: usize = 2;
    pub const M: usize = 3;
    pub const SIGMA: usize = 4;
    pub const W: usize = 5;
    pub const OPACITY: usize = 6;
    pub const F_DC: usize = 7;
    pub const TIME: usize = 8;
}

/// The view time that names frame `frame` of `frames` (`0` for a single frame).
pub fn view_time(frame: usize, frames: usize) -> f64 {
    if frames <= 1 {
        0.0
    } else {
        frame as f64 / (frames - 1) as f64
    }
}

/// The frame of `frames` that the view time `time` names, or an error when it names none.
pub fn frame_of(time: f64, frames: usize) -> Result<usize, String> {
    let scaled = time * frames.saturating_sub(1) as f64;
    let frame = scaled.round();
    if !(0.0..=1.0).contains(&time) || (scaled - frame).abs() > 1e-6 {
        return Err(format!(
            "view time {time} names no frame of {frames} (frame f is time f / {})",
            frames.saturating_sub(1).max(1)
        ));
    }
    Ok(frame as usize)
}

/// A video's VeGaS model: folded Gaussians and the time logits of its `F` frames.
#[derive(Clone, Debug, PartialEq)]
pub struct FoldedGaussians {
    params: FoldedParams,
    time_logits: Vec<f32>,
}

impl FoldedGaussians {
    /// The model of `params` for a video of `time_logits.len() + 1` frames; an error names the
    /// first array whose length does not fit the Gaussian count.
    pub fn new(params: FoldedParams, time_logits: Vec<f32>) -> Result<Self, String> {
        let n = params.len();
        let lens = [
            ("xyz", params.xyz.len(), 3 * n),
            ("log_scales", params.log_scales.len(), 2 * n),
            ("rotation", params.rotation.len(), n),
            ("sigma", params.sigma.len(), n),
            ("w", params.w.len(), POLY_LEN * n),
            ("opacity_logits", params.opacity_logits.len(), n),
            ("sh_dc", params.sh_dc.len(), 3 * n),
        ];
        if let Some((name, len, want)) = lens.into_iter().find(|(_, len, want)| len != want) {
            return Err(format!(
                "{name} has {len} values; {n} Gaussians need {want}"
            ));
        }
        Ok(Self {
            params,
            time_logits,
        })
    }

    /// The folded Gaussians.
    pub fn params(&self) -> &FoldedParams {
        &self.params
    }

    /// The time logits (`F - 1` values).
    pub fn time_logits(&self) -> &[f32] {
        &self.time_logits
    }

    /// The number of frames `F`.
    pub fn frames(&self) -> usize {
        self.time_logits.len() + 1
    }

    /// The learned time of frame `frame`.
    pub fn time_of(&self, frame: usize) -> f32 {
        frame_time(&self.time_logits, frame)
    }

    /// The frame a view shows.
    fn frame(&self, view: &View) -> Result<usize, ModelError> {
        Ok(frame_of(view.time, self.frames())?)
    }
}

impl BaseModel for FoldedGaussians {
    type Tape = FrameTape;

    fn groups(&self) -> Vec<Group<'_>> {
        let p = &self.params;
        let values: [&[f32]; 9] = [
            &p.xyz,
            &p.log_scales,
            &p.rotation,
            &p.m,
            &p.sigma,
            &p.w,
            &p.opacity_logits,
            &p.sh_dc,
            &self.time_logits,
        ];
        GROUP_NAMES
            .iter()
            .zip(values)
            .map(|(name, values)| Group::new(name, values))
            .collect()
    }

    fn groups_mut(&mut self) -> Vec<&mut [f32]> {
        let p = &mut self.params;
        vec![
            &mut p.xyz,
            &mut p.log_scales,
            &mut p.rotation,
            &mut p.m,
            &mut p.sigma,
            &mut p.w,
            &mut p.opacity_logits,
            &mut p.sh_dc,
            &mut self.time_logits,
        ]
    }

    fn grad_mask(&self, trained: &[bool]) -> GradMask {
        let any = |groups: &[usize]| groups.iter().any(|&g| trained.get(g) == Some(&true));
        use group::*;
        GradMask {
            means: any(&[XYZ, M, W, TIME]),
            scales: any(&[SCALING, M, SIGMA, TIME]),
            rotations: any(&[ROTATION]),
            opacities: any(&[OPACITY]),
            sh_dc: any(&[F_DC]),
            sh_rest: false,
        }
    }

    fn forward(&self, view: &View) -> Result<Forward<'_, FrameTape>, ModelError> {
        let t = self.time_of(self.frame(view)?);
        let (gaussians, tape) = build_frame(&self.params, t);
        Ok(Forward {
            gaussians: Cow::Owned(gaussians),
            tape,
        })
    }

    fn backward(
        &self,
        view: &View,
        tape: FrameTape,
        grads: &GaussianGrads,
        trained: &[bool],
        out: &mut [Vec<f32>],
    ) -> Result<(), ModelError> {
        let frame = self.frame(view)?;
        let t = self.time_of(frame);
        let p = &self.params;
        let mut acc = FoldedParams::zeros(p.len());
        let grad_t = add_frame_grads(p, t, &tape, grads, &mut acc);
        let sources: [&[f32]; 8] = [
            &acc.xyz,
            &acc.log_scales,
            &acc.rotation,
            &acc.m,
            &acc.sigma,
            &acc.w,
            &acc.opacity_logits,
            &acc.sh_dc,
        ];
        for ((src, dst), &t) in sources.iter().zip(out.iter_mut()).zip(trained) {
            if t {
                for (d, s) in dst.iter_mut().zip(src.iter()) {
                    *d += *s;
                }
            }
        }
        if trained[group::TIME] {
            add_time_grads(&self.time_logits, frame, grad_t, &mut out[group::TIME]);
        }
        Ok(())
    }
}

/// The provided GPU twins: each frame's Gaussians are built on the host and uploaded.
impl GpuModel for FoldedGaussians {}

/// `(1 - t) a + t b` for every parameter of two models of the same Gaussians and frames (e.g.
/// two stylizations of one fit; logits, logs and polynomials are blended as stored), or an
/// error naming what differs.
pub fn interpolate(
    a: &FoldedGaussians,
    b: &FoldedGaussians,
    t: f32,
) -> Result<FoldedGaussians, String> {
    if a.params.len() != b.params.len() {
        return Err(format!(
            "{} Gaussians against {}",
            a.params.len(),
            b.params.len()
        ));
    }
    if a.frames() != b.frames() {
        return Err(format!("{} frames against {}", a.frames(), b.frames()));
    }
    gs_core::interpolate::blend_groups(a, b, t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::init::initial_model;

    #[test]
    fn view_times_name_frames_and_nothing_else() {
        for frames in [2, 5, 24] {
            for f in 0..frames {
                assert_eq!(frame_of(view_time(f, frames), frames), Ok(f));
            }
        }
        assert!(frame_of(0.3, 5)
            .unwrap_err()
            .contains("names no frame of 5"));
        assert!(frame_of(1.5, 5).is_err() && frame_of(-0.25, 5).is_err());
        assert!(frame_of(f64::NAN, 5).is_err());
    }

    #[test]
    fn interpolation_blends_every_parameter_and_refuses_other_shapes() {
        let a = initial_model(20, 4, 0.5, 0.5, 1);
        let b = initial_model(20, 4, 0.5, 0.5, 2);
        assert_eq!(interpolate(&a, &b, 0.0).unwrap(), a);
        assert_eq!(interpolate(&a, &b, 1.0).unwrap(), b);
        let half = interpolate(&a, &b, 0.5).unwrap();
        assert_eq!(
            half.params().m[3],
            0.5 * (a.params().m[3] + b.params().m[3])
        );
        let e = interpolate(&a, &initial_model(21, 4, 0.5, 0.5, 2), 0.5).unwrap_err();
        assert!(e.contains("20 Gaussians against 21"), "{e}");
        let e = interpolate(&a, &initial_model(20, 5, 0.5, 0.5, 2), 0.5).unwrap_err();
        assert!(e.contains("4 frames against 5"), "{e}");
        assert!(interpolate(&a, &b, f32::NAN).is_err());
    }

    #[test]
    fn a_model_with_arrays_of_the_wrong_length_is_refused() {
        let mut p = initial_model(5, 3, 0.5, 0.5, 1).params().clone();
        p.w.pop();
        let e = FoldedGaussians::new(p, vec![1.0; 2]).unwrap_err();
        assert!(e.contains("w has 69 values; 5 Gaussians need 70"), "{e}");
    }
}
