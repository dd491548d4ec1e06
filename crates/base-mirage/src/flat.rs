//! MiraGe's flat Gaussians ("amorphous" setting): free 3D means and rotations, and scales
//! `clamp([1e-8, e^s1, e^s2], 1e-8, 1)`: the first local axis is held at 1e-8, so every Gaussian
//! is a flat disc, and the two in-plane scales are clamped to `[1e-8, 1]` world units.
//!
//! The parameters are a [`GaussianSet`] in the INRIA PLY layout (as MiraGe saves them:
//! `scale_0 = ln 1e-8`). The Gaussians rendered are the same set with the log-scales clamped;
//! the gradient of a clamped log-scale is zero, as torch's `clamp` gives, and the held axis
//! never receives one, so Adam leaves it exactly where it is.
//!
//! On the GPU ([`gs_wgpu::GpuModel::gpu_forward`]) the same transform runs as two small kernels,
//! `shaders/flat_gaussians_forward.wgsl` and `..._backward.wgsl`; every other array is rendered
//! from the parameter buffers themselves.

use std::borrow::Cow;

use gs_core::gaussians::GaussianGrads;
use gs_core::model::{add_identity_grads, BaseModel, Forward, Group, ModelError, View};
use gs_core::raster::GradMask;
use gs_core::{GaussianSet, Real};
use gs_wgpu::{
    zeroed_f32, Access, Binding, Buffer, GpuError, GpuForward, GpuGradients, GpuModel, GpuStep,
    KernelSource,
};

/// Index of the log-scales in [`gs_core::gaussians::PARAM_NAMES`].
const SCALES_GROUP: usize = 1;

/// The scale of the flat axis and the lower clamp of the others, world units.
pub const FLAT_SCALE: f64 = 1e-8;

/// The upper clamp of the in-plane scales, world units.
pub const MAX_SCALE: f64 = 1.0;

/// The GPU twin of [`renderable`] for the log-scales.
const FORWARD_KERNEL: KernelSource = KernelSource {
    name: "flat_gaussians_forward.wgsl",
    wgsl: include_str!("../../../shaders/flat_gaussians_forward.wgsl"),
    bindings: &[Access::Uniform, Access::Read, Access::Write],
};

/// The GPU twin of [`add_scale_grads`].
const BACKWARD_KERNEL: KernelSource = KernelSource {
    name: "flat_gaussians_backward.wgsl",
    wgsl: include_str!("../../../shaders/flat_gaussians_backward.wgsl"),
    bindings: &[Access::Uniform, Access::Read, Access::Read, Access::Write],
};

/// Bytes of one Gaussian's log-scales (three `f32`s), the record of the flat-Gaussian kernels.
const SCALE_RECORD: u64 = 12;

/// `log_scale` clamped to `[ln FLAT_SCALE, ln MAX_SCALE]`; NaN stays NaN, so the rasterizer
/// culls that Gaussian as it culls any non-finite one, rather than drawing it at a bound
/// (no NaN reaches here in training: PLY input refuses them and gradients are checked).
fn clamp_log_scale<T: Real>(log_scale: T) -> T {
    let (lo, hi) = (T::from_f64(FLAT_SCALE.ln()), T::from_f64(MAX_SCALE.ln()));
    if log_scale < lo {
        lo
    } else if log_scale > hi {
        hi
    } else {
        log_scale
    }
}

/// Whether a gradient flows through the clamp of `log_scale` (inside the bounds, inclusive).
fn passes_clamp<T: Real>(log_scale: T) -> bool {
    let (lo, hi) = (T::from_f64(FLAT_SCALE.ln()), T::from_f64(MAX_SCALE.ln()));
    log_scale >= lo && log_scale <= hi
}

/// The Gaussians MiraGe renders for the parameters `params`: the flat axis at
/// [`FLAT_SCALE`], the in-plane log-scales clamped, everything else as stored.
pub fn renderable<T: Real>(params: &GaussianSet<T>) -> GaussianSet<T> {
    let mut set = params.clone();
    for s in set.log_scales.chunks_exact_mut(3) {
        s[0] = T::from_f64(FLAT_SCALE.ln());
        s[1] = clamp_log_scale(s[1]);
        s[2] = clamp_log_scale(s[2]);
    }
    set
}

/// Adds to `out` the gradient with respect to the stored log-scales `log_scales` (`[N, 3]`),
/// given `grads`, the gradient with respect to the rendered ones: nothing on the flat axis and
/// where the clamp is active, `grads` elsewhere.
pub fn add_scale_grads<T: Real>(log_scales: &[T], grads: &[T], out: &mut [T]) {
    for ((s, g), o) in log_scales
        .chunks_exact(3)
        .zip(grads.chunks_exact(3))
        .zip(out.chunks_exact_mut(3))
    {
        for k in 1..3 {
            if passes_clamp(s[k]) {
                o[k] += g[k];
            }
        }
    }
}

/// A picture's MiraGe model: flat Gaussians whose parameters are stored as a [`GaussianSet`].
#[derive(Clone, Debug, PartialEq)]
pub struct FlatGaussians {
    params: GaussianSet,
}

impl FlatGaussians {
    /// The model of the parameters `params` (e.g. read from a MiraGe or 3DGS PLY); the flat
    /// axis is set to `ln FLAT_SCALE`, as MiraGe ignores whatever is stored there.
    pub fn new(mut params: GaussianSet) -> Self {
        for s in params.log_scales.chunks_exact_mut(3) {
            s[0] = FLAT_SCALE.ln() as f32;
        }
        Self { params }
    }

    /// The stored parameters (INRIA PLY layout).
    pub fn params(&self) -> &GaussianSet {
        &self.params
    }

    /// The stored parameters, consuming the model.
    pub fn into_params(self) -> GaussianSet {
        self.params
    }

    /// The Gaussians rendered (the same for every view).
    pub fn renderable(&self) -> GaussianSet {
        renderable(&self.params)
    }
}

impl BaseModel for FlatGaussians {
    type Tape = ();

    fn groups(&self) -> Vec<Group<'_>> {
        self.params.groups()
    }

    fn groups_mut(&mut self) -> Vec<&mut [f32]> {
        self.params.groups_mut()
    }

    fn grad_mask(&self, trained: &[bool]) -> GradMask {
        self.params.grad_mask(trained)
    }

    fn forward(&self, _view: &View) -> Result<Forward<'_, ()>, ModelError> {
        Ok(Forward::untaped(Cow::Owned(self.renderable())))
    }

    fn backward(
        &self,
        _view: &View,
        _tape: (),
        grads: &GaussianGrads,
        trained: &[bool],
        out: &mut [Vec<f32>],
    ) -> Result<(), ModelError> {
        add_identity_grads(grads, trained, out, Some(SCALES_GROUP));
        if trained[SCALES_GROUP] {
            add_scale_grads(
                &self.params.log_scales,
                &grads.log_scales,
                &mut out[SCALES_GROUP],
            );
        }
        Ok(())
    }
}

/// The GPU twins with kernels of their own: the stored log-scales are clamped on the GPU
/// (`shaders/flat_gaussians_*.wgsl`), everything else is handed on as it is.
impl GpuModel for FlatGaussians {
    fn gpu_forward(
        &mut self,
        gpu: &mut GpuStep<'_>,
        _view: &View,
    ) -> Result<GpuForward<()>, ModelError> {
        let n = self.kernel_items();
        let uniform = self.clamp_uniform(gpu)?;
        let scales = gpu.scratch.buffer(
            "flat rendered log-scales",
            u64::from(n) * SCALE_RECORD,
            || zeroed_f32(gpu.ctx, "flat rendered log-scales", 3 * n as usize),
        )?;
        let stored = &gpu.params.buffers()[SCALES_GROUP];
        gpu.ctx.run_kernel(
            &FORWARD_KERNEL,
            &[
                Binding::Whole(&uniform),
                Binding::PerItem(stored, SCALE_RECORD),
                Binding::PerItem(&scales, SCALE_RECORD),
            ],
            n,
        )?;
        let mut gaussians = gpu.params.as_gaussians(self.params.sh_degree());
        gaussians.replace_array(SCALES_GROUP, scales);
        Ok(GpuForward::untaped(gaussians))
    }

    fn gpu_backward(
        &mut self,
        gpu: &mut GpuStep<'_>,
        _view: &View,
        _tape: (),
        grads: GpuGradients,
        trained: &[bool],
    ) -> Result<Vec<Option<Buffer>>, ModelError> {
        let mut out = grads.into_trained(trained);
        if let Some(rendered) = out[SCALES_GROUP].take() {
            let n = self.kernel_items();
            let uniform = self.clamp_uniform(gpu)?;
            let stored_grads = gpu.scratch.buffer(
                "flat log-scale gradients",
                u64::from(n) * SCALE_RECORD,
                || zeroed_f32(gpu.ctx, "flat log-scale gradients", 3 * n as usize),
            )?;
            gpu.ctx.run_kernel(
                &BACKWARD_KERNEL,
                &[
                    Binding::Whole(&uniform),
                    Binding::PerItem(&gpu.params.buffers()[SCALES_GROUP], SCALE_RECORD),
                    Binding::PerItem(&rendered, SCALE_RECORD),
                    Binding::PerItem(&stored_grads, SCALE_RECORD),
                ],
                n,
            )?;
            out[SCALES_GROUP] = Some(stored_grads);
        }
        Ok(out)
    }
}

impl FlatGaussians {
    /// The number of Gaussians, the item count of the flat-Gaussian kernels.
    fn kernel_items(&self) -> u32 {
        u32::try_from(self.params.len()).expect("at most u32::MAX Gaussians")
    }

    /// The uniform of the flat-Gaussian kernels (`Clamp`: the clamp bounds), made once.
    fn clamp_uniform(&self, gpu: &mut GpuStep<'_>) -> Result<Buffer, GpuError> {
        let lo = FLAT_SCALE.ln() as f32;
        let hi = MAX_SCALE.ln() as f32;
        let ctx = gpu.ctx;
        gpu.scratch.buffer("flat clamp bounds", 16, || {
            Ok(ctx.uniform_words([lo.to_bits(), hi.to_bits(), 0, 0]))
        })
    }
}
