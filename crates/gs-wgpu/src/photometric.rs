//! The photometric loss of a fit on the GPU, where the render lives: `(1 - lambda) L1 +
//! lambda (1 - SSIM)` against a target kept on the device, with dL/dimage written there for the
//! backward pass and only the loss's partial sums read back (a few floats per 256 values), the
//! twin of gs-core's `PhotometricObjective` as `ClampedObjective` and the training step hand it
//! on (shaders/photometric.wgsl and the four kernels after it: the row and column passes of the
//! SSIM blur, then of its back-propagation).

use gs_core::image_loss::{ssim_window, PhotometricForm, PhotometricSums};
use gs_core::render_clamp::RenderClamp;
use gs_core::Image;
use std::sync::{Arc, Weak};

use super::buffers::{read, storage, storage_from, uniform};
use super::device::{GpuContext, GpuError};
use super::forward::GpuRendered;
use super::shaders::KernelId;

/// Threads of a workgroup of the photometric kernels (each workgroup writes one set of partial
/// sums).
const WORKGROUP: u32 = 256;

/// Bytes per pixel of the loss's planes on the device: the five blurred moments, SSIM, its three
/// partials and dL/dRGB, three channels of f32 each.
pub(crate) const PHOTOMETRIC_PIXEL_BYTES: u64 = 10 * 12;

/// The uniform of the photometric kernels (`Photometric` of shaders/photometric.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct PhotometricUniform {
    /// Width, height, 1 when the render is clamped, values.
    size: [u32; 4],
    /// The SSIM window, padded to 12.
    window: [[f32; 4]; 3],
    /// lambda, 1 / values, the factor of dL/dimage, unused.
    weights: [f32; 4],
}

/// A photometric objective's targets on one device, one buffer per view (HWC), kept in the
/// objective's [`gs_core::image_loss::DeviceSlot`].
pub(crate) struct GpuTargets {
    /// The context they were uploaded to (compared by address; never upgraded).
    ctx: Weak<GpuContext>,
    images: Vec<(u32, u32, wgpu::Buffer)>,
}

impl GpuTargets {
    /// The targets of `form` on `ctx`: those its slot keeps when they are on `ctx`, else
    /// uploaded (the slot's earlier content freed first) and kept there.
    pub(crate) fn of(
        ctx: &Arc<GpuContext>,
        form: &PhotometricForm<'_>,
    ) -> Result<Arc<Self>, GpuError> {
        let mut slot = form.device.lock();
        let kept = slot.as_ref().and_then(|b| b.downcast_ref::<Arc<Self>>());
        if let Some(targets) = kept {
            let here = std::ptr::eq(targets.ctx.as_ptr(), Arc::as_ptr(ctx));
            if here && targets.images.len() == form.targets.len() {
                return Ok(Arc::clone(targets));
            }
        }
        *slot = None;
        let images = form
            .targets
            .iter()
            .map(|t| Ok((t.width, t.height, upload_target(ctx, t)?)))
            .collect::<Result<_, GpuError>>()?;
        let targets = Arc::new(Self {
            ctx: Arc::downgrade(ctx),
            images,
        });
        *slot = Some(Box::new(Arc::clone(&targets)));
        Ok(targets)
    }

    /// The target of view `view`: its width, height and values.
    pub(crate) fn get(&self, view: usize) -> Option<&(u32, u32, wgpu::Buffer)> {
        self.images.get(view)
    }

    /// Bytes the targets hold on the device.
    pub(crate) fn bytes(&self) -> u64 {
        self.images.iter().map(|(_, _, b)| b.size()).sum()
    }
}

/// What the device computed of the photometric loss of one render.
pub struct GpuPhotometric {
    /// The loss's means, for [`gs_core::train::Objective::device_value`].
    pub sums: PhotometricSums,
    /// dL/dimage, HWC, times the factor asked for.
    pub grad: wgpu::Buffer,
    /// Values of dL/dimage that are NaN or infinite (a training step stops on any).
    pub non_finite_grads: u64,
}

/// The photometric loss of `rendered` against `target` (HWC, the render's size) with D-SSIM
/// weight `lambda`, the render seen as `clamp` says; dL/dimage is multiplied by `factor` (the
/// training step's `1 / divisor`). Values as gs-core's `PhotometricObjective` (wrapped in a
/// `ClampedObjective` for [`RenderClamp::Unit`]) gives them: the same arithmetic, the means
/// summed in another order (f32 within 256 values, then f64).
///
/// # Panics
/// If `target` holds fewer than the render's values.
pub fn photometric(
    ctx: &GpuContext,
    rendered: &GpuRendered,
    target: &wgpu::Buffer,
    lambda: f32,
    clamp: RenderClamp,
    factor: f32,
) -> Result<GpuPhotometric, GpuError> {
    let (width, height) = (rendered.width, rendered.height);
    let values = 3 * u64::from(width) * u64::from(height);
    assert!(
        target.size() >= 4 * values,
        "the target holds fewer values than the render"
    );
    let values = u32::try_from(values).expect("at most u32::MAX values an image");
    let window = ssim_window::<f32>();
    let mut padded = [[0.0f32; 4]; 3];
    for (k, w) in window.iter().enumerate() {
        padded[k / 4][k % 4] = *w;
    }
    let params = uniform(
        ctx,
        &PhotometricUniform {
            size: [width, height, u32::from(clamp == RenderClamp::Unit), values],
            window: padded,
            weights: [lambda, 1.0 / values.max(1) as f32, factor, 0.0],
        },
    );
    let bytes = 4 * u64::from(values);
    let plane = |what| storage(ctx, what, bytes);
    let moments = [
        plane("SSIM: blurred x")?,
        plane("SSIM: blurred y")?,
        plane("SSIM: blurred x*x")?,
        plane("SSIM: blurred y*y")?,
        plane("SSIM: blurred x*y")?,
    ];
    let ssim_map = plane("SSIM map")?;
    let partials_of_ssim = [
        plane("SSIM: partial by mu")?,
        plane("SSIM: partial by x*x")?,
        plane("SSIM: partial by x*y")?,
    ];
    let grad = plane("dL/dRGB")?;
    let workgroups = values.div_ceil(WORKGROUP);
    let (gx, gy) = ctx.grid(workgroups);
    let sums_len = 4 * gx as usize * gy as usize;
    let partials = storage(ctx, "photometric partial sums", 4 * sums_len as u64)?;

    let mut encoder = ctx.encoder();
    let [mx, my, mxx, myy, mxy] = &moments;
    let rgb = rendered.rgb();
    ctx.dispatch(
        &mut encoder,
        KernelId::SsimRows,
        &[&params, rgb, target, mx, my, mxx, myy, mxy],
        workgroups,
    );
    let [d_mu, d_xx, d_xy] = &partials_of_ssim;
    ctx.dispatch(
        &mut encoder,
        KernelId::SsimCols,
        &[&params, mx, my, mxx, myy, mxy, &ssim_map, d_mu, d_xx, d_xy],
        workgroups,
    );
    // The row pass of the partials' blur into three moment planes no longer needed.
    ctx.dispatch(
        &mut encoder,
        KernelId::SsimGradRows,
        &[&params, d_mu, d_xx, d_xy, mx, my, mxx],
        workgroups,
    );
    ctx.dispatch(
        &mut encoder,
        KernelId::PhotometricGrad,
        &[
            &params, rgb, target, &ssim_map, mx, my, mxx, &grad, &partials,
        ],
        workgroups,
    );
    ctx.submit(encoder);
    let partial: Vec<f32> = read(ctx, &partials, sums_len);
    let mut totals = [0.0f64; 4];
    for chunk in partial.chunks_exact(4) {
        for (t, p) in totals.iter_mut().zip(chunk) {
            *t += f64::from(*p);
        }
    }
    let n = f64::from(values);
    let sums = if values == 0 {
        // No pixel: identical images, as gs-core's `ssim` says.
        PhotometricSums {
            l1: 0.0,
            ssim: 1.0,
            mse: 0.0,
        }
    } else {
        PhotometricSums {
            l1: totals[0] / n,
            ssim: totals[1] / n,
            mse: totals[2] / n,
        }
    };
    Ok(GpuPhotometric {
        sums,
        grad,
        non_finite_grads: totals[3] as u64,
    })
}

/// A target image uploaded for [`photometric`], bound whole as a render's image is (an error
/// past the adapter's binding limit).
pub fn upload_target(ctx: &GpuContext, target: &Image) -> Result<wgpu::Buffer, GpuError> {
    storage_from(ctx, "target picture", &target.data)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{test_context, GpuOptions};
    use gs_core::image_loss::PhotometricObjective;
    use gs_core::train::Objective;

    #[test]
    fn targets_are_uploaded_once_per_objective_and_device() {
        let Some(first) = test_context(GpuOptions::default()) else {
            return;
        };
        let first = Arc::new(first);
        let second = Arc::new(test_context(GpuOptions::default()).expect("as the first"));
        let targets = vec![Image::filled(4, 3, [0.5; 3]), Image::filled(4, 3, [0.1; 3])];
        let objective = PhotometricObjective::new(targets.clone(), 0.2);
        let form = objective.photometric().expect("photometric");
        let kept = GpuTargets::of(&first, &form).unwrap();
        // A later trainer of the same objective (a clone too) on the same device finds them.
        assert!(Arc::ptr_eq(&kept, &GpuTargets::of(&first, &form).unwrap()));
        let clone = objective.clone();
        let clone_form = clone.photometric().expect("photometric");
        assert!(Arc::ptr_eq(
            &kept,
            &GpuTargets::of(&first, &clone_form).unwrap()
        ));
        assert_eq!(kept.bytes(), 2 * 4 * 3 * 3 * 4);
        assert_eq!(
            read::<f32>(&first, &kept.get(1).unwrap().2, 3),
            vec![0.1f32; 3]
        );
        // Another objective, or another device, has its own.
        let other = PhotometricObjective::new(targets, 0.2);
        let other_form = other.photometric().expect("photometric");
        assert!(!Arc::ptr_eq(
            &kept,
            &GpuTargets::of(&first, &other_form).unwrap()
        ));
        let moved = GpuTargets::of(&second, &form).unwrap();
        assert!(!Arc::ptr_eq(&kept, &moved));
        assert!(Arc::ptr_eq(
            &moved,
            &GpuTargets::of(&second, &form).unwrap()
        ));
    }
}
