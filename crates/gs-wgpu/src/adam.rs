//! Adam on the GPU: the update of [`gs_core::adam::Adam`], step for step, with the moments kept
//! on the GPU next to the parameters.

use super::buffers::{read, storage_per_item, uniform};
use super::device::{Binding, GpuContext, GpuError};
use super::shaders::KernelId;
use gs_core::adam::{decode_state, encode_state, AdamHyper, GroupConfig};
use gs_core::GsError;

/// The uniform of adam_step.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct AdamUniform {
    step_size: f32,
    inv_bc2_sqrt: f32,
    beta1: f32,
    beta2: f32,
    eps: f32,
    unused: [u32; 3],
}

/// First and second moments of one trained group.
struct Moments {
    len: usize,
    m: wgpu::Buffer,
    v: wgpu::Buffer,
}

/// Adam over a fixed list of parameter groups living on the GPU (PyTorch's update rule with
/// bias correction, as [`gs_core::adam::Adam`]); frozen groups get no moments and no work.
pub struct GpuAdam {
    hyper: AdamHyper,
    groups: Vec<GroupConfig>,
    moments: Vec<Option<Moments>>,
    step: u64,
}

impl GpuAdam {
    /// An optimizer for `groups` whose sizes are `lens`.
    ///
    /// # Panics
    /// If `groups` and `lens` differ in length.
    pub fn new(
        ctx: &GpuContext,
        groups: Vec<GroupConfig>,
        lens: &[usize],
        hyper: AdamHyper,
    ) -> Result<Self, GpuError> {
        assert_eq!(groups.len(), lens.len(), "one length per group");
        let mut moments = Vec::with_capacity(groups.len());
        for (g, &len) in groups.iter().zip(lens) {
            moments.push(if g.frozen {
                None
            } else {
                let bytes = 4 * len as u64;
                Some(Moments {
                    len,
                    m: storage_per_item(ctx, &format!("Adam m of {}", g.name), bytes)?,
                    v: storage_per_item(ctx, &format!("Adam v of {}", g.name), bytes)?,
                })
            });
        }
        Ok(Self {
            hyper,
            groups,
            moments,
            step: 0,
        })
    }

    /// The group configurations.
    pub fn groups(&self) -> &[GroupConfig] {
        &self.groups
    }

    /// Steps taken so far.
    pub fn step_count(&self) -> u64 {
        self.step
    }

    /// The state (step count and every moment, read back) as bytes, in the format of
    /// [`gs_core::adam::Adam::save_state`]: either optimizer resumes from the other's state.
    pub fn save_state(&self, ctx: &GpuContext) -> Vec<u8> {
        let moments: Vec<Option<(Vec<f32>, Vec<f32>)>> = (0..self.groups.len())
            .map(|i| self.moments(ctx, i))
            .collect();
        encode_state(
            self.step,
            &self.groups,
            moments
                .iter()
                .map(|m| m.as_ref().map(|(m, v)| (m.as_slice(), v.as_slice()))),
        )
    }

    /// Restores state saved by [`GpuAdam::save_state`] or [`gs_core::adam::Adam::save_state`]
    /// into an optimizer with the same groups (names, sizes and frozen flags); anything else is
    /// an error that names the difference, and changes nothing.
    pub fn restore_state(&mut self, ctx: &GpuContext, bytes: &[u8]) -> Result<(), GsError> {
        let lens: Vec<Option<usize>> = self
            .moments
            .iter()
            .map(|m| m.as_ref().map(|m| m.len))
            .collect();
        let (step, saved) = decode_state(bytes, &self.groups, &lens)?;
        for (mine, saved) in self.moments.iter().zip(saved) {
            if let (Some(mine), Some((m, v))) = (mine, saved) {
                if mine.len > 0 {
                    ctx.queue.write_buffer(&mine.m, 0, bytemuck::cast_slice(&m));
                    ctx.queue.write_buffer(&mine.v, 0, bytemuck::cast_slice(&v));
                }
            }
        }
        self.step = step;
        Ok(())
    }

    /// One Adam step: `params[i]` is group `i`'s buffer, `grads[i]` its gradient (`None` is
    /// allowed for frozen and empty groups only). Fails only when the adapter cannot bind
    /// even one chunk of values.
    ///
    /// # Panics
    /// If the number of groups differs from construction or a trained group has no gradient.
    pub fn step(
        &mut self,
        ctx: &GpuContext,
        params: &[&wgpu::Buffer],
        grads: &[Option<&wgpu::Buffer>],
    ) -> Result<(), GpuError> {
        assert_eq!(
            params.len(),
            self.groups.len(),
            "one parameter buffer per group"
        );
        assert_eq!(
            grads.len(),
            self.groups.len(),
            "one gradient slot per group"
        );
        let t = self.step + 1;
        let AdamHyper { beta1, beta2, eps } = self.hyper;
        let bc1 = 1.0 - beta1.powf(t as f64);
        let bc2 = 1.0 - beta2.powf(t as f64);
        let mut encoder = ctx.encoder();
        for (i, mom) in self.moments.iter().enumerate() {
            let Some(mom) = mom else {
                continue;
            };
            let group = &self.groups[i];
            if mom.len == 0 {
                continue;
            }
            let grad =
                grads[i].unwrap_or_else(|| panic!("trained group {} has no gradient", group.name));
            let lr = group.lr_for_update(t);
            let params_uniform = uniform(
                ctx,
                &AdamUniform {
                    step_size: (lr / bc1) as f32,
                    inv_bc2_sqrt: (1.0 / bc2.sqrt()) as f32,
                    beta1: beta1 as f32,
                    beta2: beta2 as f32,
                    eps: group.eps_or(eps) as f32,
                    unused: [0; 3],
                },
            );
            let len = u32::try_from(mom.len).expect("at most u32::MAX values a group");
            ctx.dispatch_items(
                &mut encoder,
                KernelId::AdamStep,
                &[
                    Binding::Whole(&params_uniform),
                    Binding::PerItem(params[i], 4),
                    Binding::PerItem(grad, 4),
                    Binding::PerItem(&mom.m, 4),
                    Binding::PerItem(&mom.v, 4),
                ],
                len,
            )?;
        }
        ctx.submit(encoder);
        self.step = t;
        Ok(())
    }

    /// Reads group `i`'s first and second moments back (`None` for a frozen group).
    pub fn moments(&self, ctx: &GpuContext, i: usize) -> Option<(Vec<f32>, Vec<f32>)> {
        self.moments[i]
            .as_ref()
            .map(|m| (read(ctx, &m.m, m.len), read(ctx, &m.v, m.len)))
    }
}
