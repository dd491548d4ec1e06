//! The forward pass on the GPU: projection and SH colour, depth sort, tile binning, sort by
//! tile, compositing. Same outputs as [`gs_core::raster::render`].

use super::buffers::{read, storage, storage_per_item, uniform, GpuGaussians};
use super::device::{Binding, GpuContext, GpuError};
use super::scan::{prefix_sum, PassUniform};
use super::shaders::KernelId;
use super::sort::radix_sort;
use gs_core::camera::Camera;
use gs_core::image::Image;
use gs_core::raster::project::CameraT;
use gs_core::raster::TILE_SIZE;

/// Threads of the per-Gaussian and per-item kernels.
pub(crate) const WORKGROUP: u32 = 256;

/// Bytes of one splat (`Splat` of shaders/helpers.wgsl).
pub(crate) const SPLAT_BYTES: u64 = 64;

/// Parts a splat array and the splat gradients may be split into (`SPLAT_PARTS` of
/// shaders/helpers.wgsl): kernels that read splats by Gaussian index bind this many.
pub(crate) const SPLAT_PARTS: u32 = 4;

/// Splats per part of a split splat array on `ctx` (the most one binding holds), or an error
/// when `n` splats need more than [`SPLAT_PARTS`] parts.
pub(crate) fn splat_part_len(ctx: &GpuContext, n: u32) -> Result<u32, GpuError> {
    let part_len = ctx.items_per_binding("splats", SPLAT_BYTES)?;
    if u64::from(n) > u64::from(SPLAT_PARTS) * u64::from(part_len) {
        return Err(GpuError::TooLarge {
            what: format!(
                "the splats of {n} Gaussians, bound as at most {SPLAT_PARTS} parts of \
                 {part_len} splats,"
            ),
            needed: SPLAT_BYTES * u64::from(n),
            limit: SPLAT_BYTES * u64::from(SPLAT_PARTS) * u64::from(part_len),
            adapter: ctx.adapter_name().into(),
        });
    }
    Ok(part_len)
}

/// The [`SPLAT_PARTS`] bindings of an array of `n` records of `record` bytes split into parts
/// of `part_len` records; a part past the records binds `filler(part)` instead.
pub(crate) fn part_bindings<'a>(
    array: &'a wgpu::Buffer,
    record: u64,
    n: u32,
    part_len: u32,
    filler: impl Fn(usize) -> &'a wgpu::Buffer,
) -> Vec<wgpu::BufferBinding<'a>> {
    (0..SPLAT_PARTS)
        .map(|p| {
            let first = p * part_len;
            if first >= n {
                return filler(p as usize).as_entire_buffer_binding();
            }
            let count = part_len.min(n - first);
            wgpu::BufferBinding {
                buffer: array,
                offset: u64::from(first) * record,
                size: std::num::NonZeroU64::new(u64::from(count) * record),
            }
        })
        .collect()
}

/// The uniform every rasterizer kernel reads (`View` of shaders/helpers.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct ViewUniform {
    rot: [[f32; 4]; 3],
    centre: [f32; 4],
    intrinsics: [f32; 4],
    lim: [f32; 4],
    background: [f32; 4],
    /// Width, height, tiles per row, tile rows.
    pub size: [u32; 4],
    /// Gaussian count, SH degree, SH coefficients per channel minus one, gradient flags.
    pub scene: [u32; 4],
    /// Splats per part of a split splat array, then padding.
    pub parts: [u32; 4],
}

impl ViewUniform {
    fn new(camera: &Camera, background: [f32; 3], gaussians: &GpuGaussians, part_len: u32) -> Self {
        let cam = CameraT::<f32>::new(camera);
        let (tiles_x, tiles_y) = tiles(camera);
        let rot = std::array::from_fn(|r| {
            [
                cam.rotation[r][0],
                cam.rotation[r][1],
                cam.rotation[r][2],
                cam.translation[r],
            ]
        });
        let degree = gaussians.sh_degree() as u32;
        Self {
            rot,
            centre: [cam.centre[0], cam.centre[1], cam.centre[2], 0.0],
            intrinsics: [cam.fx, cam.fy, cam.cx, cam.cy],
            lim: cam.lim,
            background: [background[0], background[1], background[2], 0.0],
            size: [camera.width, camera.height, tiles_x, tiles_y],
            scene: [
                gaussians.len() as u32,
                degree,
                (degree + 1) * (degree + 1) - 1,
                0,
            ],
            parts: [part_len, 0, 0, 0],
        }
    }
}

/// The grid of a kernel with one thread per item of `n` items.
fn grid(ctx: &GpuContext, n: u32) -> [u32; 2] {
    let (x, y) = ctx.grid(n.div_ceil(WORKGROUP));
    [x, y]
}

/// Tiles per row and tile rows of the camera's image.
fn tiles(camera: &Camera) -> (u32, u32) {
    let t = TILE_SIZE as u32;
    (camera.width.div_ceil(t), camera.height.div_ceil(t))
}

/// A render on the GPU: its outputs and what [`super::backward`] needs stay there until read.
pub struct GpuRendered {
    pub(crate) width: u32,
    pub(crate) height: u32,
    pub(crate) view: ViewUniform,
    pairs: u32,
    splats: wgpu::Buffer,
    /// Bound in place of the parts of the splat array past its end.
    filler: wgpu::Buffer,
    pub(crate) tile_ids: wgpu::Buffer,
    pub(crate) ranges: wgpu::Buffer,
    rgb: wgpu::Buffer,
    alpha: wgpu::Buffer,
    depth: wgpu::Buffer,
    pub(crate) final_t: wgpu::Buffer,
    pub(crate) n_contrib: wgpu::Buffer,
}

impl GpuRendered {
    /// Reads the RGB image back (composited over the background, HWC).
    pub fn image(&self, ctx: &GpuContext) -> Image {
        Image {
            width: self.width,
            height: self.height,
            data: read(ctx, &self.rgb, 3 * self.pixels()),
        }
    }

    /// Reads the accumulated opacity `1 - T_final` back, `[H, W]`.
    pub fn alpha(&self, ctx: &GpuContext) -> Vec<f32> {
        read(ctx, &self.alpha, self.pixels())
    }

    /// Reads the accumulated depth back, `[H, W]`.
    pub fn depth(&self, ctx: &GpuContext) -> Vec<f32> {
        read(ctx, &self.depth, self.pixels())
    }

    /// The RGB image on the device (HWC).
    pub(crate) fn rgb(&self) -> &wgpu::Buffer {
        &self.rgb
    }

    /// Number of (tile, Gaussian) pairs composited.
    pub fn intersection_count(&self) -> usize {
        self.pairs as usize
    }

    fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// The [`SPLAT_PARTS`] bindings of the splat array.
    /// The splat array, one [`SPLAT_BYTES`] record per Gaussian.
    pub(crate) fn splats(&self) -> &wgpu::Buffer {
        &self.splats
    }

    pub(crate) fn splat_bindings(&self) -> Vec<wgpu::BufferBinding<'_>> {
        splat_bindings(&self.splats, &self.filler, &self.view)
    }
}

/// The [`SPLAT_PARTS`] bindings of `splats`, split as `view` says, `filler` past the end.
fn splat_bindings<'a>(
    splats: &'a wgpu::Buffer,
    filler: &'a wgpu::Buffer,
    view: &ViewUniform,
) -> Vec<wgpu::BufferBinding<'a>> {
    part_bindings(splats, SPLAT_BYTES, view.scene[0], view.parts[0], |_| {
        filler
    })
}

/// Renders `gaussians` through `camera` over `background`, as [`gs_core::raster::render`] does.
/// Waits for the GPU once, to size the tile lists; the outputs stay on the GPU.
///
/// # Panics
/// If the camera is invalid ([`Camera::validate`]) or the scene has more than `u32::MAX`
/// Gaussians.
pub fn render(
    ctx: &GpuContext,
    gaussians: &GpuGaussians,
    camera: &Camera,
    background: [f32; 3],
) -> Result<GpuRendered, GpuError> {
    if let Err(e) = camera.validate() {
        panic!("{e}");
    }
    let n = u32::try_from(gaussians.len()).expect("at most u32::MAX Gaussians");
    let view = ViewUniform::new(camera, background, gaussians, splat_part_len(ctx, n)?);
    let view_buf = uniform(ctx, &view);
    let (tiles_x, tiles_y) = tiles(camera);
    let n_tiles = tiles_x * tiles_y;
    let bytes = |count: u32, size: u64| size * u64::from(count);

    let splats = storage_per_item(ctx, "splats", bytes(n, SPLAT_BYTES))?;
    let filler = storage(ctx, "unused splat part", 0)?;
    let counts = storage(ctx, "tile counts", bytes(n, 4))?;
    let mut pairs = 0;
    let mut order = storage(ctx, "depth order", bytes(n, 4))?;
    if n > 0 {
        let depth_keys = storage(ctx, "depth keys", bytes(n, 4))?;
        let mut encoder = ctx.encoder();
        let mut bindings = vec![Binding::Whole(&view_buf)];
        bindings.extend(gaussians.per_item_bindings());
        bindings.extend([
            Binding::PerItem(&splats, SPLAT_BYTES),
            Binding::PerItem(&depth_keys, 4),
            Binding::PerItem(&order, 4),
        ]);
        ctx.dispatch_items(&mut encoder, KernelId::ProjectForward, &bindings, n)?;
        (_, order) = radix_sort(ctx, &mut encoder, depth_keys, order, n, 32)?;
        let mut bindings = vec![view_buf.as_entire_buffer_binding()];
        bindings.extend(splat_bindings(&splats, &filler, &view));
        bindings.extend([
            order.as_entire_buffer_binding(),
            counts.as_entire_buffer_binding(),
        ]);
        ctx.dispatch_ranges(&mut encoder, KernelId::BinCounts, &bindings, grid(ctx, n));
        let total = prefix_sum(ctx, &mut encoder, &counts, n)?;
        ctx.submit(encoder);
        pairs = read::<u32>(ctx, &total, 1)[0];
    }

    let mut encoder = ctx.encoder();
    let mut tile_keys = storage(ctx, "tile keys", bytes(pairs, 4))?;
    let mut tile_ids = storage(ctx, "tile lists", bytes(pairs, 4))?;
    let ranges = storage(ctx, "tile ranges", bytes(n_tiles, 8))?;
    if pairs > 0 {
        let mut bindings = vec![view_buf.as_entire_buffer_binding()];
        bindings.extend(splat_bindings(&splats, &filler, &view));
        bindings
            .extend([&order, &counts, &tile_keys, &tile_ids].map(|b| b.as_entire_buffer_binding()));
        ctx.dispatch_ranges(&mut encoder, KernelId::BinTiles, &bindings, grid(ctx, n));
        let tile_bits = u32::BITS - (n_tiles - 1).leading_zeros();
        (tile_keys, tile_ids) =
            radix_sort(ctx, &mut encoder, tile_keys, tile_ids, pairs, tile_bits)?;
        let params = uniform(ctx, &PassUniform::new(pairs, 0));
        ctx.dispatch(
            &mut encoder,
            KernelId::TileRanges,
            &[&params, &tile_keys, &ranges],
            pairs.div_ceil(WORKGROUP),
        );
    }
    let pixels = camera.width * camera.height;
    let rgb = storage(ctx, "image", bytes(pixels, 12))?;
    let alpha = storage(ctx, "alpha", bytes(pixels, 4))?;
    let depth = storage(ctx, "depth", bytes(pixels, 4))?;
    let final_t = storage(ctx, "final transmittance", bytes(pixels, 4))?;
    let n_contrib = storage(ctx, "contributor counts", bytes(pixels, 4))?;
    let mut bindings = vec![view_buf.as_entire_buffer_binding()];
    bindings.extend(splat_bindings(&splats, &filler, &view));
    bindings.extend(
        [
            &tile_ids, &ranges, &rgb, &alpha, &depth, &final_t, &n_contrib,
        ]
        .map(|b| b.as_entire_buffer_binding()),
    );
    ctx.dispatch_ranges(
        &mut encoder,
        KernelId::CompositeForward,
        &bindings,
        [tiles_x, tiles_y],
    );
    ctx.submit(encoder);
    Ok(GpuRendered {
        width: camera.width,
        height: camera.height,
        view,
        pairs,
        splats,
        filler,
        tile_ids,
        ranges,
        rgb,
        alpha,
        depth,
        final_t,
        n_contrib,
    })
}
