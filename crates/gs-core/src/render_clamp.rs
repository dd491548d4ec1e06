//! The render as the loss sees it: as rasterized, or clamped to `[0, 1]` with PyTorch's
//! gradient rule, as INRIA 3DGS's `render()` (the renderer of CLIPGaussian's 3D code) returns
//! it. Whether a modality clamps follows its authors' renderer, so the choice is the modality's
//! and the training loop is the same for all.
//!
//! The clamp runs on the host image the objective receives, which is where both backends hand
//! the render to the loss, so the cpu and the wgpu path clamp the same values the same way; a
//! photometric objective on a GPU ([`crate::train::Objective::photometric`]) is clamped by the
//! same rule in the device's kernel.

use crate::image::Image;
use crate::image_loss::{PhotometricForm, PhotometricSums};
use crate::train::{Objective, ObjectiveValue};

/// What the loss sees of a render.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum RenderClamp {
    /// The rasterizer's output as it is (values above 1 where colours add up): VeGaS's and
    /// D-MiSo's `render()`.
    #[default]
    Off,
    /// `clamp(render, 0, 1)`: INRIA 3DGS's `render()` at the commit CLIPGaussian pins. The
    /// gradient passes where `0 <= x <= 1` (both ends included) and is zero elsewhere, also
    /// where the render is NaN, as `torch.clamp`'s backward.
    Unit,
}

/// `image` with every value clamped to `[0, 1]` (NaN stays NaN, as `torch.clamp`).
pub fn clamp_unit(image: &Image) -> Image {
    Image {
        width: image.width,
        height: image.height,
        data: image.data.iter().map(|&x| x.clamp(0.0, 1.0)).collect(),
    }
}

/// Back-propagates dL/d(clamped) through the clamp of [`clamp_unit`]: `grad` becomes
/// dL/d(raw), zero where `raw` lies outside `[0, 1]` or is NaN.
///
/// # Panics
/// If `grad` and `raw` differ in length.
pub fn clamp_unit_backward(raw: &Image, grad: &mut [f32]) {
    assert_eq!(
        raw.data.len(),
        grad.len(),
        "one gradient value per render value"
    );
    for (g, &x) in grad.iter_mut().zip(&raw.data) {
        if !(0.0..=1.0).contains(&x) {
            *g = 0.0;
        }
    }
}

/// `objective` evaluated on the render as [`RenderClamp`] says: a borrowed wrapper, so that the
/// objective's own state (its random stream) stays with its owner between training calls.
#[derive(Debug)]
pub struct ClampedObjective<'a, O> {
    objective: &'a mut O,
    clamp: RenderClamp,
}

impl<'a, O: Objective> ClampedObjective<'a, O> {
    /// `objective` seeing renders as `clamp` says.
    pub fn new(objective: &'a mut O, clamp: RenderClamp) -> Self {
        Self { objective, clamp }
    }
}

impl<O: Objective> Objective for ClampedObjective<'_, O> {
    type Error = O::Error;

    fn evaluate(&mut self, view: usize, image: &Image) -> Result<ObjectiveValue, Self::Error> {
        match self.clamp {
            RenderClamp::Off => self.objective.evaluate(view, image),
            RenderClamp::Unit => {
                let mut value = self.objective.evaluate(view, &clamp_unit(image))?;
                clamp_unit_backward(image, &mut value.grad);
                Ok(value)
            }
        }
    }

    /// The inner objective's form, seeing the render as this clamp says (an inner clamp stays
    /// when this one is off).
    fn photometric(&self) -> Option<PhotometricForm<'_>> {
        let form = self.objective.photometric()?;
        Some(match self.clamp {
            RenderClamp::Off => form,
            RenderClamp::Unit => PhotometricForm {
                clamp: RenderClamp::Unit,
                ..form
            },
        })
    }

    fn device_value(&mut self, view: usize, sums: &PhotometricSums) -> ObjectiveValue {
        self.objective.device_value(view, sums)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// L = sum of the image: records the values it saw, dL/dimage is all ones.
    struct Sum {
        seen: Vec<f32>,
    }

    impl Objective for Sum {
        type Error = std::convert::Infallible;
        fn evaluate(&mut self, _view: usize, image: &Image) -> Result<ObjectiveValue, Self::Error> {
            self.seen = image.data.clone();
            Ok(ObjectiveValue {
                loss: image.data.iter().sum(),
                terms: Vec::new(),
                grad: vec![1.0; image.data.len()],
            })
        }
    }

    fn image(data: Vec<f32>) -> Image {
        Image {
            width: data.len() as u32 / 3,
            height: 1,
            data,
        }
    }

    #[test]
    fn the_loss_sees_clamped_values_and_the_gradient_passes_at_both_ends_only_inside() {
        let raw = image(vec![-0.5, 0.0, 0.3, 1.0, 1.0 + f32::EPSILON, 2.5]);
        let mut sum = Sum { seen: Vec::new() };
        let value = ClampedObjective::new(&mut sum, RenderClamp::Unit)
            .evaluate(0, &raw)
            .unwrap();
        assert_eq!(sum.seen, vec![0.0, 0.0, 0.3, 1.0, 1.0, 1.0]);
        assert!((value.loss - 3.3).abs() < 1e-6, "{}", value.loss);
        // torch.clamp's backward: the gradient passes where min <= x <= max.
        assert_eq!(value.grad, vec![0.0, 1.0, 1.0, 1.0, 0.0, 0.0]);
    }

    #[test]
    fn a_nan_render_stays_nan_for_the_loss_and_gets_no_gradient() {
        let raw = image(vec![f32::NAN, 0.5, 0.5]);
        let mut sum = Sum { seen: Vec::new() };
        let value = ClampedObjective::new(&mut sum, RenderClamp::Unit)
            .evaluate(0, &raw)
            .unwrap();
        assert!(sum.seen[0].is_nan());
        assert_eq!(value.grad, vec![0.0, 1.0, 1.0]);
    }

    #[test]
    fn off_hands_the_render_over_unchanged() {
        let raw = image(vec![-0.5, 0.3, 2.5]);
        let mut sum = Sum { seen: Vec::new() };
        let value = ClampedObjective::new(&mut sum, RenderClamp::Off)
            .evaluate(0, &raw)
            .unwrap();
        assert_eq!(sum.seen, raw.data);
        assert_eq!(value.grad, vec![1.0; 3]);
    }
}
