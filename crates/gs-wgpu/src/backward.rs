//! The backward pass on the GPU: compositing backward per tile, then projection and SH
//! backward per Gaussian. Same gradients as [`gs_core::raster::backward`]; frozen parameter
//! groups cost no work and no memory.

use super::buffers::{
    per_item_from, read, storage, storage_from, storage_per_item, uniform, GpuGaussians,
};
use super::device::{Binding, GpuContext, GpuError};
use super::forward::{part_bindings, GpuRendered, SPLAT_BYTES, SPLAT_PARTS};
use super::shaders::KernelId;
use gs_core::densify::ScreenStats;
use gs_core::gaussians::GaussianGrads;
use gs_core::raster::{GradMask, Gradients, OutputGrads};

/// Bytes of one Gaussian's gradient slots in the accumulation buffer (`SPLAT_GRADS` `f32`s of
/// helpers.wgsl).
pub(crate) const SPLAT_GRAD_BYTES: u64 = 4 * 10;

/// Flag bits of `View.scene.w` (shaders/helpers.wgsl).
mod flags {
    pub const MEANS: u32 = 1;
    pub const SCALES: u32 = 2;
    pub const QUATS: u32 = 4;
    pub const OPACITY: u32 = 8;
    pub const SH_DC: u32 = 16;
    pub const SH_REST: u32 = 32;
    pub const GRAD_ALPHA: u32 = 64;
    pub const GRAD_DEPTH: u32 = 128;
}

/// Gradients on the GPU, one buffer per trained parameter array (in the layout of the
/// Gaussian set; `None` for frozen arrays), and the background's.
pub struct GpuGradients {
    len: usize,
    sh_degree: usize,
    arrays: [Option<wgpu::Buffer>; 6],
    background: wgpu::Buffer,
}

impl GpuGradients {
    /// The gradient buffers in the order of [`gs_core::gaussians::PARAM_NAMES`] (for
    /// [`super::GpuAdam`]); `None` for frozen arrays.
    pub fn buffers(&self) -> [Option<&wgpu::Buffer>; 6] {
        self.arrays.each_ref().map(Option::as_ref)
    }

    /// The gradient buffers, consumed, as the gradients of the six groups of a model that
    /// renders its parameters as they are: `None` where `trained[i]` is false.
    pub fn into_trained(self, trained: &[bool]) -> Vec<Option<wgpu::Buffer>> {
        self.arrays
            .into_iter()
            .zip(trained)
            .map(|(g, &t)| g.filter(|_| t))
            .collect()
    }

    /// Reads every gradient back (zeros for frozen arrays).
    pub fn download(&self, ctx: &GpuContext) -> Gradients {
        let mut g = GaussianGrads::zero_grads(self.len, self.sh_degree);
        for (dst, buffer) in g.arrays_mut().into_iter().zip(&self.arrays) {
            if let Some(b) = buffer {
                let n = dst.len();
                *dst = read(ctx, b, n);
            }
        }
        Gradients {
            gaussians: g,
            background: self.background(ctx),
        }
    }

    /// Reads dL/d(background RGB) back.
    pub fn background(&self, ctx: &GpuContext) -> [f32; 3] {
        let bg: Vec<f32> = read(ctx, &self.background, 3);
        [bg[0], bg[1], bg[2]]
    }
}

/// The backward pass of [`super::render`], as [`gs_core::raster::backward`]: given the
/// gradients of a loss with respect to the outputs, the gradients of the parameters `mask`
/// asks for and of the background. `gaussians` must be the set that was rendered.
///
/// # Panics
/// If the output gradients do not have the image's size or `gaussians` is not the rendered
/// set (count differs).
pub fn backward(
    ctx: &GpuContext,
    gaussians: &GpuGaussians,
    rendered: &GpuRendered,
    out_grads: &OutputGrads<'_, f32>,
    mask: GradMask,
) -> Result<GpuGradients, GpuError> {
    backward_with_stats(ctx, gaussians, rendered, out_grads, mask, None)
}

/// 3DGS's densification statistics on the GPU (the twin of
/// [`gs_core::densify::ScreenStats`]): per Gaussian, the summed view-space gradient norm and
/// the count of views that showed it, added to by [`backward_with_stats`] on the device.
pub struct GpuScreenStats {
    len: usize,
    grad_sum: wgpu::Buffer,
    count: wgpu::Buffer,
}

impl GpuScreenStats {
    /// `stats` uploaded.
    pub fn upload(ctx: &GpuContext, stats: &ScreenStats) -> Result<Self, GpuError> {
        Ok(Self {
            len: stats.len(),
            grad_sum: per_item_from(ctx, "densification gradient sums", &stats.grad_sum)?,
            count: per_item_from(ctx, "densification view counts", &stats.count)?,
        })
    }

    /// The statistics read back.
    pub fn download(&self, ctx: &GpuContext) -> ScreenStats {
        ScreenStats {
            grad_sum: read(ctx, &self.grad_sum, self.len),
            count: read(ctx, &self.count, self.len),
        }
    }

    /// The number of Gaussians.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

/// [`backward`], adding the view's densification statistics to `stats` (one entry per
/// rendered Gaussian) on the device in the same submission: nothing is read back.
///
/// # Panics
/// As [`backward`]; and if `stats` does not have one entry per Gaussian.
pub fn backward_with_stats(
    ctx: &GpuContext,
    gaussians: &GpuGaussians,
    rendered: &GpuRendered,
    out_grads: &OutputGrads<'_, f32>,
    mask: GradMask,
    stats: Option<&GpuScreenStats>,
) -> Result<GpuGradients, GpuError> {
    let pixels = rendered.width as usize * rendered.height as usize;
    assert_eq!(
        out_grads.rgb.len(),
        3 * pixels,
        "dL/dRGB has the wrong size"
    );
    let grad_rgb = storage_from(ctx, "dL/dRGB", out_grads.rgb)?;
    let outputs = DeviceOutputGrads {
        rgb: &grad_rgb,
        alpha: out_grads.alpha,
        depth: out_grads.depth,
    };
    backward_on_device(ctx, gaussians, rendered, &outputs, mask, stats)
}

/// The gradients of a loss with respect to a render's outputs, dL/dRGB already on the device
/// (e.g. [`crate::photometric`]'s).
pub struct DeviceOutputGrads<'a> {
    /// dL/dRGB, HWC, on the device.
    pub rgb: &'a wgpu::Buffer,
    /// dL/dalpha, `[H, W]`, if the loss depends on it.
    pub alpha: Option<&'a [f32]>,
    /// dL/ddepth, `[H, W]`, if the loss depends on it.
    pub depth: Option<&'a [f32]>,
}

/// [`backward_with_stats`] with dL/dRGB on the device: nothing of the image crosses to the host.
///
/// # Panics
/// As [`backward_with_stats`]; and if dL/dRGB holds fewer values than the image.
pub fn backward_on_device(
    ctx: &GpuContext,
    gaussians: &GpuGaussians,
    rendered: &GpuRendered,
    out_grads: &DeviceOutputGrads<'_>,
    mask: GradMask,
    stats: Option<&GpuScreenStats>,
) -> Result<GpuGradients, GpuError> {
    let n = gaussians.len();
    assert_eq!(
        n as u32, rendered.view.scene[0],
        "backward needs the Gaussian set that was rendered"
    );
    let pixels = rendered.width as usize * rendered.height as usize;
    assert!(
        out_grads.rgb.size() >= 12 * pixels as u64,
        "dL/dRGB has the wrong size"
    );
    for g in [out_grads.alpha, out_grads.depth].into_iter().flatten() {
        assert_eq!(g.len(), pixels, "dL/dalpha or dL/ddepth has the wrong size");
    }
    let degree = gaussians.sh_degree();
    let wanted = [
        (mask.means, flags::MEANS),
        (mask.scales, flags::SCALES),
        (mask.rotations, flags::QUATS),
        (mask.opacities, flags::OPACITY),
        (mask.sh_dc, flags::SH_DC),
        (mask.sh_rest && degree > 0, flags::SH_REST),
    ];
    let mut bits = wanted
        .iter()
        .filter(|(on, _)| *on)
        .fold(0, |acc, (_, bit)| acc | bit);
    let params_needed = bits;
    if out_grads.alpha.is_some() {
        bits |= flags::GRAD_ALPHA;
    }
    if out_grads.depth.is_some() {
        bits |= flags::GRAD_DEPTH;
    }
    let mut view = rendered.view;
    view.scene[3] = bits;
    let view_buf = uniform(ctx, &view);

    let placeholder = storage(ctx, "unused", 0)?;
    let optional = |g: Option<&[f32]>, what: &str| match g {
        Some(g) => storage_from(ctx, what, g).map(Some),
        None => Ok(None),
    };
    let grad_alpha = optional(out_grads.alpha, "dL/dalpha")?;
    let grad_depth = optional(out_grads.depth, "dL/ddepth")?;
    let accum = storage_per_item(ctx, "splat gradients", SPLAT_GRAD_BYTES * n as u64)?;
    let background = storage(ctx, "background gradient", 12)?;
    let accum_fillers = (0..SPLAT_PARTS)
        .map(|_| storage(ctx, "unused splat-gradient part", 0))
        .collect::<Result<Vec<_>, _>>()?;

    let record_bytes = gaussians.record_bytes();
    let mut arrays: [Option<wgpu::Buffer>; 6] = Default::default();
    for (k, ((on, _), bytes)) in wanted.iter().zip(record_bytes).enumerate() {
        if *on {
            let name = gs_core::gaussians::PARAM_NAMES[k];
            arrays[k] = Some(storage_per_item(
                ctx,
                &format!("gradient of {name}"),
                bytes * n as u64,
            )?);
        }
    }

    let mut encoder = ctx.encoder();
    let mut bindings = vec![view_buf.as_entire_buffer_binding()];
    bindings.extend(rendered.splat_bindings());
    bindings.extend(
        [
            &rendered.tile_ids,
            &rendered.ranges,
            &rendered.final_t,
            &rendered.n_contrib,
            out_grads.rgb,
            grad_alpha.as_ref().unwrap_or(&placeholder),
            grad_depth.as_ref().unwrap_or(&placeholder),
        ]
        .map(|b| b.as_entire_buffer_binding()),
    );
    // A part past the end binds a filler of its own: writable bindings must not alias.
    bindings.extend(part_bindings(
        &accum,
        SPLAT_GRAD_BYTES,
        n as u32,
        view.parts[0],
        |p| &accum_fillers[p],
    ));
    bindings.push(background.as_entire_buffer_binding());
    ctx.dispatch_ranges(
        &mut encoder,
        KernelId::CompositeBackward,
        &bindings,
        [view.size[2], view.size[3]],
    );
    if params_needed != 0 && n > 0 {
        let mut bindings = vec![Binding::Whole(&view_buf)];
        bindings.extend(gaussians.per_item_bindings());
        bindings.push(Binding::PerItem(&accum, SPLAT_GRAD_BYTES));
        bindings.extend(arrays.iter().zip(record_bytes).map(|(g, bytes)| match g {
            Some(b) => Binding::PerItem(b, bytes),
            None => Binding::Whole(&placeholder),
        }));
        ctx.dispatch_items(&mut encoder, KernelId::ProjectBackward, &bindings, n as u32)?;
    }
    if let Some(stats) = stats.filter(|_| n > 0) {
        assert_eq!(
            stats.len, n,
            "densification statistics of another Gaussian count"
        );
        let bindings = [
            Binding::Whole(&view_buf),
            Binding::PerItem(rendered.splats(), SPLAT_BYTES),
            Binding::PerItem(&accum, SPLAT_GRAD_BYTES),
            Binding::PerItem(&stats.grad_sum, 4),
            Binding::PerItem(&stats.count, 4),
        ];
        ctx.dispatch_items(&mut encoder, KernelId::ScreenStats, &bindings, n as u32)?;
    }
    ctx.submit(encoder);
    Ok(GpuGradients {
        len: n,
        sh_degree: degree,
        arrays,
        background,
    })
}
