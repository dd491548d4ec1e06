//! GPU buffers: storage and uniform buffers, read-back, and the Gaussian parameters kept on
//! the GPU across steps.

use wgpu::util::DeviceExt;

use super::device::{Binding, GpuContext, GpuError};
use gs_core::gaussians::{GaussianSet, PARAM_NAMES};

/// Smallest buffer created: bindings cannot be empty, and the largest element (a splat) is 64
/// bytes.
const MIN_BYTES: u64 = 64;

/// A zeroed storage buffer of `bytes` bytes (at least [`MIN_BYTES`]) that kernels bind whole,
/// or an error naming `what` when it exceeds the device's binding limit or the device is out
/// of memory.
pub(crate) fn storage(ctx: &GpuContext, what: &str, bytes: u64) -> Result<wgpu::Buffer, GpuError> {
    allocate(ctx, what, bytes, ctx.max_binding())
}

/// A zeroed storage buffer of `bytes` bytes of per-item records (Gaussians, values), which
/// kernels bind one chunk or part at a time: only the adapter's buffer-size limit applies.
pub(crate) fn storage_per_item(
    ctx: &GpuContext,
    what: &str,
    bytes: u64,
) -> Result<wgpu::Buffer, GpuError> {
    allocate(ctx, what, bytes, ctx.max_buffer())
}

fn allocate(
    ctx: &GpuContext,
    what: &str,
    bytes: u64,
    limit: u64,
) -> Result<wgpu::Buffer, GpuError> {
    let size = bytes.max(MIN_BYTES).next_multiple_of(4);
    if size > limit {
        return Err(GpuError::TooLarge {
            what: what.into(),
            needed: size,
            limit,
            adapter: ctx.adapter_name().into(),
        });
    }
    let scope = ctx.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
    let buffer = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(what),
        size,
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    match pollster::block_on(scope.pop()) {
        None => Ok(buffer),
        Some(_) => Err(GpuError::OutOfMemory {
            what: what.into(),
            needed: size,
            adapter: ctx.adapter_name().into(),
            run: None,
        }),
    }
}

/// A storage buffer that kernels bind whole ([`storage`]) holding `data`.
pub(crate) fn storage_from<T: bytemuck::Pod>(
    ctx: &GpuContext,
    what: &str,
    data: &[T],
) -> Result<wgpu::Buffer, GpuError> {
    let buffer = storage(ctx, what, std::mem::size_of_val(data) as u64)?;
    write(ctx, &buffer, data);
    Ok(buffer)
}

/// A per-item storage buffer ([`storage_per_item`]) holding `data`.
pub(crate) fn per_item_from<T: bytemuck::Pod>(
    ctx: &GpuContext,
    what: &str,
    data: &[T],
) -> Result<wgpu::Buffer, GpuError> {
    let buffer = storage_per_item(ctx, what, std::mem::size_of_val(data) as u64)?;
    write(ctx, &buffer, data);
    Ok(buffer)
}

/// Queues `data` to be written at the start of `buffer`.
fn write<T: bytemuck::Pod>(ctx: &GpuContext, buffer: &wgpu::Buffer, data: &[T]) {
    if !data.is_empty() {
        ctx.queue
            .write_buffer(buffer, 0, bytemuck::cast_slice(data));
    }
}

/// A parameter block holding `value`, for a binding of [`crate::Access::Uniform`] (a uniform
/// buffer, or read-only storage: [`crate::ParameterBinding`]).
pub(crate) fn uniform<T: bytemuck::Pod>(ctx: &GpuContext, value: &T) -> wgpu::Buffer {
    ctx.device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: None,
            contents: bytemuck::bytes_of(value),
            usage: ctx.parameter_binding().usage(),
        })
}

/// Waits for the queue and reads the first `count` values of `buffer`.
pub(crate) fn read<T: bytemuck::Pod>(
    ctx: &GpuContext,
    buffer: &wgpu::Buffer,
    count: usize,
) -> Vec<T> {
    let bytes = (count * std::mem::size_of::<T>()) as u64;
    if bytes == 0 {
        return Vec::new();
    }
    let staging = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("read-back"),
        size: bytes.next_multiple_of(4),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = ctx.encoder();
    encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, staging.size());
    ctx.submit(encoder);
    let slice = staging.slice(..);
    slice.map_async(wgpu::MapMode::Read, |r| {
        r.expect("mapping a read-back buffer");
    });
    ctx.device
        .poll(wgpu::PollType::wait_indefinitely())
        .expect("waiting for the GPU");
    let view = slice.get_mapped_range().expect("mapped read-back buffer");
    let out = bytemuck::cast_slice::<u8, T>(&view[..bytes as usize]).to_vec();
    drop(view);
    staging.unmap();
    out
}

/// Gaussian parameters resident on the GPU, one buffer per array of [`GaussianSet`] (same
/// layout), so that Adam can update each group where it lives. A clone shares the buffers.
#[derive(Clone)]
pub struct GpuGaussians {
    len: usize,
    sh_degree: usize,
    pub(crate) arrays: [wgpu::Buffer; 6],
}

impl GpuGaussians {
    /// Uploads `gaussians`.
    ///
    /// # Panics
    /// If the set is malformed ([`GaussianSet::check_shapes`]).
    pub fn upload(ctx: &GpuContext, gaussians: &GaussianSet) -> Result<Self, GpuError> {
        if let Err(e) = gaussians.check_shapes() {
            panic!("malformed Gaussian set: {e}");
        }
        let arrays = gaussians.arrays();
        let mut buffers = Vec::with_capacity(6);
        for (name, data) in PARAM_NAMES.iter().zip(arrays) {
            buffers.push(per_item_from(ctx, &format!("Gaussian {name}"), data)?);
        }
        Ok(Self {
            len: gaussians.len(),
            sh_degree: gaussians.sh_degree(),
            arrays: buffers.try_into().expect("six arrays"),
        })
    }

    /// Gaussians whose six arrays are `arrays` (the layout of [`GaussianSet`], in
    /// [`PARAM_NAMES`] order), for `len` Gaussians of SH degree `sh_degree`: the buffers are
    /// shared, not copied, so a model whose parameters are (some of) its rendered arrays builds
    /// its Gaussians at no cost.
    pub fn from_buffers(len: usize, sh_degree: usize, arrays: [wgpu::Buffer; 6]) -> Self {
        Self {
            len,
            sh_degree,
            arrays,
        }
    }

    /// Replaces array `index` ([`PARAM_NAMES`] order) with `buffer` (a model's per-view
    /// output of that array, same layout).
    pub fn replace_array(&mut self, index: usize, buffer: wgpu::Buffer) {
        self.arrays[index] = buffer;
    }

    /// Overwrites the parameters with `gaussians` (same count and degree).
    ///
    /// # Panics
    /// If the count or degree differ.
    pub fn write(&self, ctx: &GpuContext, gaussians: &GaussianSet) {
        assert_eq!(
            (gaussians.len(), gaussians.sh_degree()),
            (self.len, self.sh_degree),
            "count or SH degree changed"
        );
        for (buffer, data) in self.arrays.iter().zip(gaussians.arrays()) {
            if !data.is_empty() {
                ctx.queue
                    .write_buffer(buffer, 0, bytemuck::cast_slice(data));
            }
        }
    }

    /// Reads the parameters back.
    pub fn download(&self, ctx: &GpuContext) -> GaussianSet {
        let mut g = GaussianSet::zeros(self.len, self.sh_degree);
        for (dst, buffer) in g.arrays_mut().into_iter().zip(&self.arrays) {
            let n = dst.len();
            *dst = read(ctx, buffer, n);
        }
        g
    }

    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when there is no Gaussian.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// SH degree.
    pub fn sh_degree(&self) -> usize {
        self.sh_degree
    }

    /// Bytes of one Gaussian's record in each array, in the order of [`PARAM_NAMES`]
    /// (`sh_rest` is empty at degree 0).
    pub(crate) fn record_bytes(&self) -> [u64; 6] {
        gs_core::gaussians::row_widths(self.sh_degree).map(|floats| 4 * floats as u64)
    }

    /// The six arrays as per-item bindings of a chunked kernel, in the order of
    /// [`PARAM_NAMES`].
    pub(crate) fn per_item_bindings(&self) -> [Binding<'_>; 6] {
        let bytes = self.record_bytes();
        std::array::from_fn(|k| Binding::PerItem(&self.arrays[k], bytes[k]))
    }

    /// The parameter buffers in the order of [`PARAM_NAMES`] (for [`super::GpuAdam`]).
    pub fn buffers(&self) -> [&wgpu::Buffer; 6] {
        self.arrays.each_ref()
    }
}

/// A GPU storage buffer holding `data` (for parameter groups other than a [`GpuGaussians`]'s,
/// gradients computed elsewhere, tests).
pub fn upload_f32(ctx: &GpuContext, data: &[f32]) -> Result<wgpu::Buffer, GpuError> {
    per_item_from(ctx, "f32 data", data)
}

/// A zeroed GPU storage buffer of `count` `f32` values; `what` names it in errors.
pub fn zeroed_f32(ctx: &GpuContext, what: &str, count: usize) -> Result<wgpu::Buffer, GpuError> {
    storage_per_item(ctx, what, 4 * count as u64)
}

/// Waits for the GPU and reads the first `count` values of an `f32` buffer.
pub fn read_f32(ctx: &GpuContext, buffer: &wgpu::Buffer, count: usize) -> Vec<f32> {
    read(ctx, buffer, count)
}
