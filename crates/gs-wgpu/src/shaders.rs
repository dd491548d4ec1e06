//! The WGSL kernels, compiled into the crate from the repository's `shaders/`, the tiny
//! import mechanism they share helpers with, and kernels other crates bring ([`KernelSource`]).
//!
//! Every kernel file has one compute entry point, `main`. A line `//#import NAME.wgsl` is
//! replaced by the text of `shaders/NAME.wgsl` (imports nest; a file imported twice is
//! included once). One name is virtual: `accumulate.wgsl` stands for
//! `accumulate_float_atomic.wgsl` on devices with f32 atomic add and for
//! `accumulate_cas.wgsl` (a compare-exchange loop) on the others.

/// Every WGSL file, by name.
const FILES: &[(&str, &str)] = &[
    (
        "helpers.wgsl",
        include_str!("../../../shaders/helpers.wgsl"),
    ),
    ("sh.wgsl", include_str!("../../../shaders/sh.wgsl")),
    ("chunk.wgsl", include_str!("../../../shaders/chunk.wgsl")),
    (
        "splat_parts.wgsl",
        include_str!("../../../shaders/splat_parts.wgsl"),
    ),
    (
        "project.wgsl",
        include_str!("../../../shaders/project.wgsl"),
    ),
    (
        "accumulate_float_atomic.wgsl",
        include_str!("../../../shaders/accumulate_float_atomic.wgsl"),
    ),
    (
        "accumulate_parts.wgsl",
        include_str!("../../../shaders/accumulate_parts.wgsl"),
    ),
    (
        "accumulate_cas.wgsl",
        include_str!("../../../shaders/accumulate_cas.wgsl"),
    ),
    (
        "project_forward.wgsl",
        include_str!("../../../shaders/project_forward.wgsl"),
    ),
    (
        "bin_counts.wgsl",
        include_str!("../../../shaders/bin_counts.wgsl"),
    ),
    (
        "bin_tiles.wgsl",
        include_str!("../../../shaders/bin_tiles.wgsl"),
    ),
    (
        "prefix_sum_blocks.wgsl",
        include_str!("../../../shaders/prefix_sum_blocks.wgsl"),
    ),
    (
        "prefix_sum_add.wgsl",
        include_str!("../../../shaders/prefix_sum_add.wgsl"),
    ),
    (
        "radix_sort_count.wgsl",
        include_str!("../../../shaders/radix_sort_count.wgsl"),
    ),
    (
        "radix_sort_scatter.wgsl",
        include_str!("../../../shaders/radix_sort_scatter.wgsl"),
    ),
    (
        "tile_ranges.wgsl",
        include_str!("../../../shaders/tile_ranges.wgsl"),
    ),
    (
        "composite_forward.wgsl",
        include_str!("../../../shaders/composite_forward.wgsl"),
    ),
    (
        "composite_backward.wgsl",
        include_str!("../../../shaders/composite_backward.wgsl"),
    ),
    (
        "project_backward.wgsl",
        include_str!("../../../shaders/project_backward.wgsl"),
    ),
    (
        "adam_step.wgsl",
        include_str!("../../../shaders/adam_step.wgsl"),
    ),
    (
        "check_finite.wgsl",
        include_str!("../../../shaders/check_finite.wgsl"),
    ),
    (
        "screen_stats.wgsl",
        include_str!("../../../shaders/screen_stats.wgsl"),
    ),
    (
        "add_into.wgsl",
        include_str!("../../../shaders/add_into.wgsl"),
    ),
    (
        "photometric.wgsl",
        include_str!("../../../shaders/photometric.wgsl"),
    ),
    (
        "ssim_rows.wgsl",
        include_str!("../../../shaders/ssim_rows.wgsl"),
    ),
    (
        "ssim_cols.wgsl",
        include_str!("../../../shaders/ssim_cols.wgsl"),
    ),
    (
        "ssim_grad_rows.wgsl",
        include_str!("../../../shaders/ssim_grad_rows.wgsl"),
    ),
    (
        "photometric_grad.wgsl",
        include_str!("../../../shaders/photometric_grad.wgsl"),
    ),
];

const IMPORT: &str = "//#import ";

fn file(name: &str) -> &'static str {
    FILES
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, text)| *text)
        .unwrap_or_else(|| panic!("no shader file {name}"))
}

/// The text of kernel file `name` with its imports resolved.
pub(crate) fn source(name: &str, float_atomics: bool) -> String {
    expand(name, file(name), float_atomics)
}

/// `text` (the file `name`) with its imports of gs-core's shader files resolved.
fn expand(name: &str, text: &str, float_atomics: bool) -> String {
    fn resolve(text: &str, float_atomics: bool, done: &mut Vec<String>, out: &mut String) {
        for line in text.lines() {
            match line.trim().strip_prefix(IMPORT) {
                Some(import) => {
                    let real = match import.trim() {
                        "accumulate.wgsl" if float_atomics => "accumulate_float_atomic.wgsl",
                        "accumulate.wgsl" => "accumulate_cas.wgsl",
                        other => other,
                    };
                    if !done.iter().any(|d| d == real) {
                        done.push(real.to_string());
                        resolve(file(real), float_atomics, done, out);
                    }
                }
                None => {
                    out.push_str(line);
                    out.push('\n');
                }
            }
        }
    }
    let mut out = String::new();
    resolve(text, float_atomics, &mut vec![name.to_string()], &mut out);
    out
}

/// How a kernel sees one of its bindings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    /// A uniform buffer.
    Uniform,
    /// A read-only storage buffer.
    Read,
    /// A read-write storage buffer.
    Write,
}

use Access::{Read as R, Uniform as U, Write as W};

/// How kernels bind their parameter blocks (the [`Access::Uniform`] bindings: the view, pass,
/// chunk and Adam-step structs); the same layout either way.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ParameterBinding {
    /// As uniform buffers (`var<uniform>`): hardware adapters.
    Uniform,
    /// As read-only storage buffers (`var<storage, read>`): software adapters. Mesa's lavapipe
    /// (22.3) keeps memory for every dispatch of a kernel that reads uniforms, about 0.4 MB per
    /// render and 1.3 MB per training step of a small scene, until the device closes; bound as
    /// storage, nothing grows.
    Storage,
}

impl ParameterBinding {
    /// The usage of a buffer bound this way.
    pub(crate) fn usage(self) -> wgpu::BufferUsages {
        match self {
            Self::Uniform => wgpu::BufferUsages::UNIFORM,
            Self::Storage => wgpu::BufferUsages::STORAGE,
        }
    }

    /// `text` with its parameter blocks declared this way.
    fn declare(self, text: &str) -> String {
        match self {
            Self::Uniform => text.to_string(),
            Self::Storage => text.replace("var<uniform>", "var<storage, read>"),
        }
    }

    /// The binding type of a buffer of access `access`.
    fn binding_type(self, access: Access) -> wgpu::BufferBindingType {
        match (access, self) {
            (Access::Uniform, Self::Uniform) => wgpu::BufferBindingType::Uniform,
            (Access::Uniform, Self::Storage) | (Access::Read, _) => {
                wgpu::BufferBindingType::Storage { read_only: true }
            }
            (Access::Write, _) => wgpu::BufferBindingType::Storage { read_only: false },
        }
    }
}

/// What a context compiles its kernels for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct CompileOptions {
    /// Accumulate with native f32 atomic add (else a compare-exchange loop).
    pub(crate) float_atomics: bool,
    /// How parameter blocks are bound.
    pub(crate) parameters: ParameterBinding,
}

/// A per-item compute kernel that a crate other than gs-core brings (e.g. a base model's
/// per-view construction of its Gaussians): WGSL with one entry point `main`, whose
/// `//#import` lines name gs-core's shader files, run with
/// [`super::GpuContext::run_kernel`]. Bindings are `@group(0) @binding(0..)` in the order of
/// `bindings`. The kernel imports `chunk.wgsl` and runs over the items of one chunk:
/// `chunk_item(...)` is the item's index within the chunk (also its index into every
/// per-item binding), valid below `chunk.count`; `chunk.first` is the chunk's first item.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct KernelSource {
    /// The file name, e.g. `flat_gaussians_forward.wgsl` (names the kernel in errors and caches).
    pub name: &'static str,
    /// The WGSL text.
    pub wgsl: &'static str,
    /// How the kernel sees each binding, in order.
    pub bindings: &'static [Access],
}

/// The kernels, each named after its cpu twin (see the file's header).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum KernelId {
    ProjectForward,
    BinCounts,
    BinTiles,
    PrefixSumBlocks,
    PrefixSumAdd,
    RadixSortCount,
    RadixSortScatter,
    TileRanges,
    CompositeForward,
    CompositeBackward,
    ProjectBackward,
    AdamStep,
    CheckFinite,
    AddInto,
    ScreenStats,
    SsimRows,
    SsimCols,
    SsimGradRows,
    PhotometricGrad,
}

impl KernelId {
    const ALL: [KernelId; 19] = [
        KernelId::ProjectForward,
        KernelId::BinCounts,
        KernelId::BinTiles,
        KernelId::PrefixSumBlocks,
        KernelId::PrefixSumAdd,
        KernelId::RadixSortCount,
        KernelId::RadixSortScatter,
        KernelId::TileRanges,
        KernelId::CompositeForward,
        KernelId::CompositeBackward,
        KernelId::ProjectBackward,
        KernelId::AdamStep,
        KernelId::CheckFinite,
        KernelId::AddInto,
        KernelId::ScreenStats,
        KernelId::SsimRows,
        KernelId::SsimCols,
        KernelId::SsimGradRows,
        KernelId::PhotometricGrad,
    ];

    /// True for per-item kernels, run in chunks with a `Chunk` uniform (shaders/chunk.wgsl).
    fn per_item(self) -> bool {
        matches!(
            self,
            KernelId::ProjectForward
                | KernelId::ProjectBackward
                | KernelId::AdamStep
                | KernelId::CheckFinite
                | KernelId::AddInto
                | KernelId::ScreenStats
        )
    }

    /// The kernel's file and its bindings `0..` in order.
    fn spec(self) -> (&'static str, &'static [Access]) {
        match self {
            KernelId::ProjectForward => ("project_forward.wgsl", &[U, R, R, R, R, R, R, W, W, W]),
            KernelId::BinCounts => ("bin_counts.wgsl", &[U, R, R, R, R, R, W]),
            KernelId::BinTiles => ("bin_tiles.wgsl", &[U, R, R, R, R, R, R, W, W]),
            KernelId::PrefixSumBlocks => ("prefix_sum_blocks.wgsl", &[U, W, W]),
            KernelId::PrefixSumAdd => ("prefix_sum_add.wgsl", &[U, W, R]),
            KernelId::RadixSortCount => ("radix_sort_count.wgsl", &[U, R, W]),
            KernelId::RadixSortScatter => ("radix_sort_scatter.wgsl", &[U, R, R, R, W, W]),
            KernelId::TileRanges => ("tile_ranges.wgsl", &[U, R, W]),
            KernelId::CompositeForward => (
                "composite_forward.wgsl",
                &[U, R, R, R, R, R, R, W, W, W, W, W],
            ),
            KernelId::CompositeBackward => (
                "composite_backward.wgsl",
                &[U, R, R, R, R, R, R, R, R, R, R, R, W, W, W, W, W],
            ),
            KernelId::ProjectBackward => (
                "project_backward.wgsl",
                &[U, R, R, R, R, R, R, R, W, W, W, W, W, W],
            ),
            KernelId::AdamStep => ("adam_step.wgsl", &[U, W, R, W, W]),
            KernelId::CheckFinite => ("check_finite.wgsl", &[R, W]),
            KernelId::AddInto => ("add_into.wgsl", &[R, W]),
            KernelId::ScreenStats => ("screen_stats.wgsl", &[U, R, R, W, W]),
            KernelId::SsimRows => ("ssim_rows.wgsl", &[U, R, R, W, W, W, W, W]),
            KernelId::SsimCols => ("ssim_cols.wgsl", &[U, R, R, R, R, R, W, W, W, W]),
            KernelId::SsimGradRows => ("ssim_grad_rows.wgsl", &[U, R, R, R, W, W, W]),
            KernelId::PhotometricGrad => ("photometric_grad.wgsl", &[U, R, R, R, R, R, R, W, W]),
        }
    }
}

/// A compiled kernel and the layout of its bindings.
pub(crate) struct Kernel {
    name: &'static str,
    layout: wgpu::BindGroupLayout,
    /// The layout of group 1, the `Chunk` uniform, for per-item kernels.
    chunk_layout: Option<wgpu::BindGroupLayout>,
    pipeline: wgpu::ComputePipeline,
}

/// The layout of bindings `0..` of the given accesses, in order, parameter blocks bound as
/// `parameters`.
fn group_layout(
    device: &wgpu::Device,
    name: &str,
    access: &[Access],
    parameters: ParameterBinding,
) -> wgpu::BindGroupLayout {
    let entries: Vec<wgpu::BindGroupLayoutEntry> = access
        .iter()
        .enumerate()
        .map(|(i, a)| wgpu::BindGroupLayoutEntry {
            binding: i as u32,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: parameters.binding_type(*a),
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        })
        .collect();
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some(name),
        entries: &entries,
    })
}

impl Kernel {
    fn new(device: &wgpu::Device, id: KernelId, options: CompileOptions) -> Self {
        let (name, access) = id.spec();
        let text = source(name, options.float_atomics);
        Self::compile(device, name, &text, access, id.per_item(), options)
    }

    /// Compiles a per-item kernel brought by another crate, its imports resolved.
    pub(crate) fn extra(
        device: &wgpu::Device,
        kernel: &KernelSource,
        options: CompileOptions,
    ) -> Self {
        let text = expand(kernel.name, kernel.wgsl, options.float_atomics);
        Self::compile(device, kernel.name, &text, kernel.bindings, true, options)
    }

    fn compile(
        device: &wgpu::Device,
        name: &'static str,
        text: &str,
        access: &[Access],
        per_item: bool,
        options: CompileOptions,
    ) -> Self {
        let parameters = options.parameters;
        let layout = group_layout(device, name, access, parameters);
        let chunk_layout =
            per_item.then(|| group_layout(device, name, &[Access::Uniform], parameters));
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(name),
            bind_group_layouts: &[Some(&layout), chunk_layout.as_ref()],
            immediate_size: 0,
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(name),
            source: wgpu::ShaderSource::Wgsl(parameters.declare(text).into()),
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(name),
            layout: Some(&pipeline_layout),
            module: &module,
            entry_point: Some("main"),
            compilation_options: Default::default(),
            cache: None,
        });
        Self {
            name,
            layout,
            chunk_layout,
            pipeline,
        }
    }

    pub(crate) fn name(&self) -> &'static str {
        self.name
    }

    pub(crate) fn pipeline(&self) -> &wgpu::ComputePipeline {
        &self.pipeline
    }

    /// A bind group of `bindings`, one per binding in order.
    ///
    /// # Panics
    /// If the number of bindings is not the kernel's.
    pub(crate) fn bind(
        &self,
        device: &wgpu::Device,
        bindings: &[wgpu::BufferBinding<'_>],
    ) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = bindings
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: wgpu::BindingResource::Buffer(b.clone()),
            })
            .collect();
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(self.name),
            layout: &self.layout,
            entries: &entries,
        })
    }

    /// The group-1 bind group of a per-item kernel: its `Chunk` uniform.
    ///
    /// # Panics
    /// If the kernel is not a per-item kernel.
    pub(crate) fn bind_chunk(
        &self,
        device: &wgpu::Device,
        chunk: &wgpu::Buffer,
    ) -> wgpu::BindGroup {
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(self.name),
            layout: self
                .chunk_layout
                .as_ref()
                .unwrap_or_else(|| panic!("{} is not a per-item kernel", self.name)),
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: chunk.as_entire_binding(),
            }],
        })
    }
}

/// Every kernel, compiled for one device.
pub(crate) struct Kernels(Vec<Kernel>);

impl Kernels {
    pub(crate) fn new(device: &wgpu::Device, options: CompileOptions) -> Self {
        Self(
            KernelId::ALL
                .iter()
                .map(|&id| Kernel::new(device, id, options))
                .collect(),
        )
    }

    pub(crate) fn get(&self, id: KernelId) -> &Kernel {
        &self.0[KernelId::ALL
            .iter()
            .position(|&k| k == id)
            .expect("every kernel is compiled")]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn imports_resolve_once_and_pick_the_accumulation_variant() {
        for id in KernelId::ALL {
            let (name, _) = id.spec();
            for atomics in [false, true] {
                let text = source(name, atomics);
                assert!(!text.contains(IMPORT), "{name}: unresolved import");
                assert!(text.contains("fn main("), "{name}: no entry point");
                assert!(
                    text.matches("const TILE_SIZE").count() <= 1,
                    "{name}: helpers imported twice"
                );
            }
        }
        let cas = source("composite_backward.wgsl", false);
        let native = source("composite_backward.wgsl", true);
        assert!(cas.contains("atomicCompareExchangeWeak") && !cas.contains("atomic<f32>"));
        assert!(native.contains("atomic<f32>") && !native.contains("atomicCompareExchangeWeak"));
    }

    #[test]
    fn parameter_blocks_are_declared_as_the_layout_binds_them() {
        // Every `var<uniform>` of a kernel is one of its `Access::Uniform` bindings (or the
        // chunk of a per-item kernel), so that bound as storage, text and layout agree.
        for id in KernelId::ALL {
            let (name, access) = id.spec();
            let text = source(name, true);
            let blocks = access.iter().filter(|&&a| a == Access::Uniform).count();
            let declared = text.matches("var<uniform>").count();
            assert_eq!(declared, blocks + usize::from(id.per_item()), "{name}");
            let storage = ParameterBinding::Storage.declare(&text);
            assert!(!storage.contains("var<uniform>"), "{name}");
            assert_eq!(
                storage.matches("var<storage, read>").count(),
                text.matches("var<storage, read>").count() + declared,
                "{name}"
            );
            assert_eq!(ParameterBinding::Uniform.declare(&text), text, "{name}");
        }
    }
}
