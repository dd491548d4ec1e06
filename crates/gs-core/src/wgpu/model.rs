//! The GPU side of a base model: its parameter groups resident on the GPU ([`GpuParams`]) and
//! the per-view construction of the rendered Gaussians from them ([`GpuBaseModel`]), the twin
//! of [`BaseModel::gaussians`] and [`BaseModel::backward`].

use super::backward::GpuGradients;
use super::buffers::{per_item_from, read, GpuGaussians};
use super::device::{GpuContext, GpuError};
use crate::gaussians::GaussianSet;
use crate::model::{BaseModel, View};

/// A model's parameter groups on the GPU, one buffer per group in
/// [`BaseModel::group_names`] order: uploaded once, read back on request (checkpoints,
/// outputs).
pub struct GpuParams {
    buffers: Vec<wgpu::Buffer>,
    lens: Vec<usize>,
}

impl GpuParams {
    /// Uploads the parameter groups of `model` (mutable access is how [`BaseModel`] lends
    /// them; nothing is changed).
    pub fn upload<M: BaseModel>(ctx: &GpuContext, model: &mut M) -> Result<Self, GpuError> {
        let names = model.group_names();
        let mut buffers = Vec::with_capacity(names.len());
        let mut lens = Vec::with_capacity(names.len());
        for (name, values) in names.iter().zip(model.groups_mut()) {
            buffers.push(per_item_from(ctx, &format!("parameters {name}"), values)?);
            lens.push(values.len());
        }
        Ok(Self { buffers, lens })
    }

    /// Reads every group back, in group order.
    pub fn download(&self, ctx: &GpuContext) -> Vec<Vec<f32>> {
        self.buffers
            .iter()
            .zip(&self.lens)
            .map(|(b, &n)| read(ctx, b, n))
            .collect()
    }

    /// Copies the values on the GPU into `model`'s groups.
    ///
    /// # Panics
    /// If `model` is not the model uploaded (its group sizes differ).
    pub fn download_into<M: BaseModel>(&self, ctx: &GpuContext, model: &mut M) {
        for (dst, values) in model.groups_mut().into_iter().zip(self.download(ctx)) {
            dst.copy_from_slice(&values);
        }
    }

    /// The group buffers, in group order.
    pub fn buffers(&self) -> &[wgpu::Buffer] {
        &self.buffers
    }

    /// The number of values of each group.
    pub fn lens(&self) -> &[usize] {
        &self.lens
    }
}

/// A base model that builds its rendered Gaussians on the GPU: the twin of
/// [`BaseModel::gaussians`] and [`BaseModel::backward`] over parameters in [`GpuParams`], so a
/// training step moves only the image and dL/dimage between host and GPU. The model itself
/// (`&self`) gives the structure (counts, SH degree); its values on the host may be stale.
pub trait GpuBaseModel: BaseModel {
    /// The Gaussians to render for `view`, from `params` (this model's groups, uploaded). They
    /// may share `params`' buffers: nothing is copied where a group is rendered as it is.
    fn gpu_gaussians(
        &self,
        ctx: &GpuContext,
        params: &GpuParams,
        view: &View,
    ) -> Result<GpuGaussians, GpuError>;

    /// The gradient of the loss with respect to every group (`None` where `trained[i]` is false,
    /// and allowed for empty groups), given `grads`, its gradient with respect to the Gaussians
    /// of `view` (which may be handed on without a copy).
    fn gpu_backward(
        &self,
        ctx: &GpuContext,
        params: &GpuParams,
        view: &View,
        grads: GpuGradients,
        trained: &[bool],
    ) -> Result<Vec<Option<wgpu::Buffer>>, GpuError>;
}

/// Plain 3D Gaussians render their parameters as they are: no kernel, no copy.
impl GpuBaseModel for GaussianSet {
    fn gpu_gaussians(
        &self,
        _ctx: &GpuContext,
        params: &GpuParams,
        _view: &View,
    ) -> Result<GpuGaussians, GpuError> {
        let arrays: [wgpu::Buffer; 6] = params
            .buffers()
            .to_vec()
            .try_into()
            .expect("six parameter groups");
        Ok(GpuGaussians::from_buffers(
            self.len(),
            self.sh_degree(),
            arrays,
        ))
    }

    fn gpu_backward(
        &self,
        _ctx: &GpuContext,
        _params: &GpuParams,
        _view: &View,
        grads: GpuGradients,
        trained: &[bool],
    ) -> Result<Vec<Option<wgpu::Buffer>>, GpuError> {
        Ok(grads
            .into_buffers()
            .into_iter()
            .zip(trained)
            .map(|(g, &t)| g.filter(|_| t))
            .collect())
    }
}
