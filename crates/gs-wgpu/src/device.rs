//! The GPU device: adapter choice, the adapter's limits and features, compiled kernels, and
//! dispatch grids that respect the per-dimension workgroup limit.

use std::path::Path;
use std::sync::{Arc, Mutex, Once};

use super::shaders::{CompileOptions, Kernel, KernelId, KernelSource, Kernels, ParameterBinding};

/// Items (Gaussians, values) of a per-item kernel are run in chunks of a multiple of this
/// many: one workgroup, and a binding offset aligned for every adapter (256 items of at
/// least 4 bytes are 1024 bytes, past the largest offset alignment WebGPU allows).
pub(crate) const ITEM_ALIGN: u32 = 256;

/// One binding of a per-item kernel ([`GpuContext::run_kernel`]): the kernels run over their
/// items in chunks small enough for the adapter's binding limit, each chunk seeing its own
/// items from index 0.
#[derive(Clone, Copy, Debug)]
pub enum Binding<'a> {
    /// Bound whole in every chunk: uniforms, and storage not indexed by item.
    Whole(&'a wgpu::Buffer),
    /// A storage buffer of this many bytes per item, bound one chunk of items at a time:
    /// item `first + i` of the run is element `i` of the chunk's binding (a record of zero
    /// bytes binds the buffer whole; the kernel must not read it).
    PerItem(&'a wgpu::Buffer, u64),
}

/// The chunk uniform of a per-item kernel (`Chunk` of shaders/chunk.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct ChunkUniform {
    first: u32,
    count: u32,
    unused: [u32; 2],
}

/// Which adapters may be used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AdapterChoice {
    /// Real GPUs only (discrete, integrated or virtualised); software rasterizers are refused.
    Hardware,
    /// A real GPU when there is one, else a software device (Mesa's lavapipe): for tests and CI.
    AllowSoftware,
}

/// Errors of the wgpu backend.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No adapter of the kind asked for.
    #[error(
        "no {wanted} GPU adapter found (adapters seen: {seen}); on Linux install a Vulkan \
         driver (Debian: mesa-vulkan-drivers, which includes the lavapipe software device)"
    )]
    NoAdapter {
        /// What was asked for.
        wanted: &'static str,
        /// Every adapter found, by name and type.
        seen: String,
    },
    /// The adapter refused to create a device.
    #[error("GPU adapter {adapter}: {message}")]
    Device {
        /// The adapter.
        adapter: String,
        /// The error it gave.
        message: String,
    },
    /// A scene or image too large for the device.
    #[error(
        "{what} needs {needed} bytes of GPU memory, more than {adapter} allows ({limit} bytes)"
    )]
    TooLarge {
        /// What was being allocated.
        what: String,
        /// Bytes needed.
        needed: u64,
        /// The device's limit.
        limit: u64,
        /// The adapter.
        adapter: String,
    },
    /// The device ran out of memory.
    #[error(
        "{what} needs {needed} bytes of GPU memory and {adapter} has no more{}",
        run_needs(*.run)
    )]
    OutOfMemory {
        /// What was being allocated.
        what: String,
        /// Bytes needed.
        needed: u64,
        /// The adapter.
        adapter: String,
        /// What the whole run needs at least, bytes ([`super::training_bytes`]), when known.
        run: Option<u64>,
    },
}

impl GpuError {
    /// This error with `run`, the bytes the whole run needs, when it is [`GpuError::OutOfMemory`].
    pub fn with_run_needs(self, run: u64) -> Self {
        match self {
            GpuError::OutOfMemory {
                what,
                needed,
                adapter,
                ..
            } => GpuError::OutOfMemory {
                what,
                needed,
                adapter,
                run: Some(run),
            },
            other => other,
        }
    }
}

/// The sentence of [`GpuError::OutOfMemory`] on what the whole run needs.
fn run_needs(run: Option<u64>) -> String {
    match run {
        Some(bytes) => format!(
            "; this run needs at least {:.2} GiB ({bytes} bytes) of GPU memory, plus its tile \
             lists: use fewer Gaussians, a smaller image, or --device cpu",
            bytes as f64 / f64::from(1u32 << 30)
        ),
        None => String::new(),
    }
}

/// Options of a [`GpuContext`]; the defaults suit every use but tests of the fallbacks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GpuOptions {
    /// Accumulate gradients with f32 atomic add where the adapter has it; false forces the
    /// compare-exchange loop.
    pub float_atomics: bool,
    /// A lower limit on workgroups per dispatch dimension than the adapter's, to exercise
    /// split dispatches on small scenes.
    pub max_workgroups_per_dimension: Option<u32>,
    /// A lower limit on the bytes one storage binding may hold than the adapter's, to
    /// exercise chunked kernels and split splat arrays on small scenes.
    pub max_binding_bytes: Option<u64>,
    /// How kernels bind their parameter blocks; `None`: as read-only storage on a software
    /// adapter (see [`ParameterBinding::Storage`]), as uniforms on every other.
    pub parameter_binding: Option<ParameterBinding>,
}

impl Default for GpuOptions {
    fn default() -> Self {
        Self {
            float_atomics: true,
            max_workgroups_per_dimension: None,
            max_binding_bytes: None,
            parameter_binding: None,
        }
    }
}

/// Storage buffers the widest kernel binds (composite_backward: four splat parts, four
/// gradient parts, the background's gradient and seven more), and its view when parameter
/// blocks are bound as storage.
const STORAGE_BUFFERS_NEEDED: u32 = 16;

/// A wgpu device with the rasterizer's kernels compiled for it.
pub struct GpuContext {
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    compile: CompileOptions,
    max_workgroups: u32,
    max_binding: u64,
    max_buffer: u64,
    kernels: Kernels,
    /// Kernels of other crates ([`GpuContext::run_kernel`]), compiled on first use.
    extra_kernels: Mutex<Vec<(&'static str, Arc<Kernel>)>>,
}

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_tuple("GpuContext").field(&self.describe()).finish()
    }
}

/// True for a software rasterizer's adapter (e.g. lavapipe).
fn is_software(info: &wgpu::AdapterInfo) -> bool {
    info.device_type == wgpu::DeviceType::Cpu
}

/// Preference of an adapter type: lower is better; `None` when the choice excludes it.
fn rank(kind: wgpu::DeviceType, choice: AdapterChoice) -> Option<u8> {
    match kind {
        wgpu::DeviceType::DiscreteGpu => Some(0),
        wgpu::DeviceType::IntegratedGpu => Some(1),
        wgpu::DeviceType::VirtualGpu => Some(2),
        wgpu::DeviceType::Other => Some(3),
        wgpu::DeviceType::Cpu => (choice == AdapterChoice::AllowSoftware).then_some(4),
    }
}

/// The variable that picks the adapter among the best-ranked ones by its index in the order
/// the drivers list them (`0`, `1`, ...): how `clipgaussian batch run --gpus` gives each job its
/// own GPU (with `CUDA_VISIBLE_DEVICES` for candle's device, both in PCI bus order).
pub const ADAPTER_VARIABLE: &str = "CLIPGAUSSIAN_GPU_ADAPTER";

/// The index of the adapter to open among adapters of ranks `ranks` (`None`: not allowed):
/// the first of the best rank, or the `wanted`-th of the best rank (see [`ADAPTER_VARIABLE`]);
/// `None` when no adapter is allowed; an error for a `wanted` that is not one of them.
fn pick(ranks: &[Option<u8>], wanted: Option<&str>) -> Result<Option<usize>, String> {
    let Some(best) = ranks.iter().flatten().min() else {
        return Ok(None);
    };
    let best: Vec<usize> = (0..ranks.len())
        .filter(|&k| ranks[k] == Some(*best))
        .collect();
    match wanted {
        None => Ok(Some(best[0])),
        Some(text) => match text.trim().parse::<usize>() {
            Ok(n) if n < best.len() => Ok(Some(best[n])),
            _ => Err(format!(
                "{ADAPTER_VARIABLE}={text} names none of the {} adapters of the best kind \
                 (0 to {})",
                best.len(),
                best.len() - 1
            )),
        },
    }
}

/// Keeps Mesa's implicit Vulkan layer `VK_LAYER_MESA_device_select` from printing
/// `error: XDG_RUNTIME_DIR is invalid or not set in the environment.` on every run of a
/// machine without a desktop session (a server, a container, ssh): when the Vulkan instance is
/// created and its adapters enumerated, the layer calls libwayland-client's
/// `wl_display_connect` to find the display's GPU, and libwayland prints that line when
/// `XDG_RUNTIME_DIR` is unset or not a folder. The layer only reorders the adapters, and
/// [`GpuContext::with_options`] ranks and chooses the adapter itself, so when there is no
/// runtime folder (hence no Wayland display to ask) and the user has not set it either way,
/// the layer is turned off for this process with its own switch, `NODEVICE_SELECT=1`.
///
/// This runs once, before the first instance of the process is created; the variable is set
/// only on platforms where Mesa's Vulkan drivers run.
fn quiet_mesa_device_select() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        if cfg!(any(target_os = "macos", target_os = "ios", windows)) {
            return;
        }
        let runtime_dir = std::env::var_os("XDG_RUNTIME_DIR")
            .is_some_and(|dir| !dir.is_empty() && Path::new(&dir).is_dir());
        if !runtime_dir && std::env::var_os("NODEVICE_SELECT").is_none() {
            std::env::set_var("NODEVICE_SELECT", "1");
        }
    });
}

impl GpuContext {
    /// Opens the best adapter `choice` allows, with f32 atomics where the adapter has them.
    pub fn new(choice: AdapterChoice) -> Result<Self, GpuError> {
        Self::with_options(choice, GpuOptions::default())
    }

    /// As [`GpuContext::new`] with explicit options.
    pub fn with_options(choice: AdapterChoice, options: GpuOptions) -> Result<Self, GpuError> {
        quiet_mesa_device_select();
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends: wgpu::Backends::VULKAN | wgpu::Backends::METAL | wgpu::Backends::DX12,
            ..wgpu::InstanceDescriptor::new_without_display_handle()
        });
        let adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all()));
        let seen = adapters
            .iter()
            .map(|a| {
                let i = a.get_info();
                format!("{} ({:?}, {:?})", i.name, i.device_type, i.backend)
            })
            .collect::<Vec<_>>()
            .join(", ");
        let ranks: Vec<Option<u8>> = adapters
            .iter()
            .map(|a| rank(a.get_info().device_type, choice))
            .collect();
        let wanted = std::env::var(ADAPTER_VARIABLE).ok();
        let chosen = pick(&ranks, wanted.as_deref()).map_err(|message| GpuError::Device {
            adapter: seen.clone(),
            message,
        })?;
        let adapter = chosen
            .map(|k| adapters.into_iter().nth(k).expect("an index of the list"))
            .ok_or_else(|| GpuError::NoAdapter {
                wanted: match choice {
                    AdapterChoice::Hardware => "hardware",
                    AdapterChoice::AllowSoftware => "hardware or software",
                },
                seen: if seen.is_empty() { "none".into() } else { seen },
            })?;
        let info = adapter.get_info();
        let limits = adapter.limits();
        let device_err = |message: String| GpuError::Device {
            adapter: info.name.clone(),
            message,
        };
        let parameters = options.parameter_binding.unwrap_or(if is_software(&info) {
            ParameterBinding::Storage
        } else {
            ParameterBinding::Uniform
        });
        let needed = STORAGE_BUFFERS_NEEDED + u32::from(parameters == ParameterBinding::Storage);
        if limits.max_storage_buffers_per_shader_stage < needed {
            return Err(device_err(format!(
                "binds at most {} storage buffers per shader stage, the rasterizer needs {needed}",
                limits.max_storage_buffers_per_shader_stage
            )));
        }
        let float_atomics = options.float_atomics
            && adapter
                .features()
                .contains(wgpu::Features::SHADER_FLOAT32_ATOMIC);
        let features = if float_atomics {
            wgpu::Features::SHADER_FLOAT32_ATOMIC
        } else {
            wgpu::Features::empty()
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("gs-core"),
            required_features: features,
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| device_err(e.to_string()))?;
        let compile = CompileOptions {
            float_atomics,
            parameters,
        };
        let kernels = Kernels::new(&device, compile);
        Ok(Self {
            device,
            queue,
            max_workgroups: options
                .max_workgroups_per_dimension
                .map_or(limits.max_compute_workgroups_per_dimension, |m| {
                    m.clamp(1, limits.max_compute_workgroups_per_dimension)
                }),
            max_binding: options
                .max_binding_bytes
                .unwrap_or(u64::MAX)
                .min(limits.max_storage_buffer_binding_size)
                .min(limits.max_buffer_size),
            max_buffer: limits.max_buffer_size,
            info,
            compile,
            kernels,
            extra_kernels: Mutex::new(Vec::new()),
        })
    }

    /// The adapter's name, type and backend, e.g. for the `--device` report.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {:?}{})",
            self.info.name,
            self.info.device_type,
            self.info.backend,
            if self.compile.float_atomics {
                ", f32 atomics"
            } else {
                ", compare-exchange accumulation"
            }
        )
    }

    /// True when the adapter is a software rasterizer (e.g. lavapipe).
    pub fn is_software(&self) -> bool {
        is_software(&self.info)
    }

    /// True when the backward pass accumulates with native f32 atomic add.
    pub fn float_atomics(&self) -> bool {
        self.compile.float_atomics
    }

    /// How the kernels bind their parameter blocks.
    pub fn parameter_binding(&self) -> ParameterBinding {
        self.compile.parameters
    }

    pub(crate) fn kernel(&self, id: KernelId) -> &Kernel {
        self.kernels.get(id)
    }

    /// The most bytes one storage binding may hold.
    pub(crate) fn max_binding(&self) -> u64 {
        self.max_binding
    }

    /// The largest buffer the adapter can create, bytes.
    pub(crate) fn max_buffer(&self) -> u64 {
        self.max_buffer
    }

    /// The largest multiple of [`ITEM_ALIGN`] items of `record` bytes each that one binding
    /// holds, or an error naming `what` when not even [`ITEM_ALIGN`] of them fit.
    pub(crate) fn items_per_binding(&self, what: &str, record: u64) -> Result<u32, GpuError> {
        let items = self.max_binding / record.max(1);
        let items = items - items % u64::from(ITEM_ALIGN);
        if items == 0 {
            return Err(GpuError::TooLarge {
                what: format!("{what} ({ITEM_ALIGN} items of {record} bytes)"),
                needed: u64::from(ITEM_ALIGN) * record,
                limit: self.max_binding,
                adapter: self.info.name.clone(),
            });
        }
        Ok(u32::try_from(items).unwrap_or(u32::MAX - ITEM_ALIGN + 1))
    }

    /// The adapter's name alone, e.g. `NVIDIA GeForce RTX 4090`.
    pub fn adapter_name(&self) -> &str {
        &self.info.name
    }

    /// A grid of `workgroups` workgroups, split over y past the per-dimension limit (kernels
    /// skip the padding past their item count).
    pub(crate) fn grid(&self, workgroups: u32) -> (u32, u32) {
        if workgroups <= self.max_workgroups {
            (workgroups.max(1), 1)
        } else {
            (
                self.max_workgroups,
                workgroups.div_ceil(self.max_workgroups),
            )
        }
    }

    /// Records `kernel` over `workgroups` workgroups (a 1D count, split as [`Self::grid`]).
    pub(crate) fn dispatch(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        id: KernelId,
        buffers: &[&wgpu::Buffer],
        workgroups: u32,
    ) {
        let (x, y) = self.grid(workgroups);
        self.dispatch_2d(encoder, id, buffers, [x, y]);
    }

    /// Records `kernel` over an explicit `[x, y]` grid of workgroups.
    pub(crate) fn dispatch_2d(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        id: KernelId,
        buffers: &[&wgpu::Buffer],
        grid: [u32; 2],
    ) {
        let bindings: Vec<_> = buffers
            .iter()
            .map(|b| b.as_entire_buffer_binding())
            .collect();
        self.dispatch_ranges(encoder, id, &bindings, grid);
    }

    /// Records `kernel` over an explicit `[x, y]` grid of workgroups, its bindings given as
    /// buffer ranges (the parts of a split array).
    pub(crate) fn dispatch_ranges(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        id: KernelId,
        bindings: &[wgpu::BufferBinding<'_>],
        grid: [u32; 2],
    ) {
        let kernel = self.kernel(id);
        let bind = kernel.bind(&self.device, bindings);
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(kernel.name()),
            timestamp_writes: None,
        });
        pass.set_pipeline(kernel.pipeline());
        pass.set_bind_group(0, &bind, &[]);
        pass.dispatch_workgroups(grid[0], grid[1], 1);
    }

    /// Records per-item kernel `id` over `items` items, in chunks (see [`Binding`]).
    pub(crate) fn dispatch_items(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        id: KernelId,
        bindings: &[Binding<'_>],
        items: u32,
    ) -> Result<(), GpuError> {
        self.record_items(encoder, self.kernel(id), bindings, items)
    }

    /// Records `kernel` over `items` items: one dispatch a chunk of as many items as the
    /// binding limit allows for the widest per-item record, each with its own sub-ranges and
    /// chunk uniform.
    fn record_items(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        kernel: &Kernel,
        bindings: &[Binding<'_>],
        items: u32,
    ) -> Result<(), GpuError> {
        if items == 0 {
            return Ok(());
        }
        let record = bindings
            .iter()
            .map(|b| match b {
                Binding::PerItem(_, bytes) => *bytes,
                Binding::Whole(_) => 0,
            })
            .max()
            .unwrap_or(0);
        let chunk = self.items_per_binding(kernel.name(), record)?;
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(kernel.name()),
            timestamp_writes: None,
        });
        pass.set_pipeline(kernel.pipeline());
        let mut first = 0;
        while first < items {
            let count = chunk.min(items - first);
            let ranges: Vec<wgpu::BufferBinding<'_>> = bindings
                .iter()
                .map(|b| match *b {
                    Binding::PerItem(buffer, bytes) if bytes > 0 => wgpu::BufferBinding {
                        buffer,
                        offset: u64::from(first) * bytes,
                        size: std::num::NonZeroU64::new(u64::from(count) * bytes),
                    },
                    Binding::PerItem(buffer, _) | Binding::Whole(buffer) => {
                        buffer.as_entire_buffer_binding()
                    }
                })
                .collect();
            let chunk_uniform = super::buffers::uniform(
                self,
                &ChunkUniform {
                    first,
                    count,
                    unused: [0; 2],
                },
            );
            pass.set_bind_group(0, &kernel.bind(&self.device, &ranges), &[]);
            pass.set_bind_group(1, &kernel.bind_chunk(&self.device, &chunk_uniform), &[]);
            let (x, y) = self.grid(count.div_ceil(ITEM_ALIGN));
            pass.dispatch_workgroups(x, y, 1);
            first += count;
        }
        Ok(())
    }

    /// Runs per-item kernel `kernel` over `items` items (Gaussians, values) with `bindings`, one
    /// per binding in order, in chunks as the adapter's binding limit requires (see
    /// [`Binding`] and [`KernelSource`]); compiles it on first use.
    ///
    /// # Panics
    /// If the number of bindings is not the kernel's.
    pub fn run_kernel(
        &self,
        kernel: &KernelSource,
        bindings: &[Binding<'_>],
        items: u32,
    ) -> Result<(), GpuError> {
        assert_eq!(
            bindings.len(),
            kernel.bindings.len(),
            "{}: one buffer per binding",
            kernel.name
        );
        let compiled = {
            let mut cache = self.extra_kernels.lock().expect("kernel cache");
            match cache.iter().find(|(name, _)| *name == kernel.name) {
                Some((_, k)) => Arc::clone(k),
                None => {
                    let k = Arc::new(Kernel::extra(&self.device, kernel, self.compile));
                    cache.push((kernel.name, Arc::clone(&k)));
                    k
                }
            }
        };
        let mut encoder = self.encoder();
        self.record_items(&mut encoder, &compiled, bindings, items)?;
        self.submit(encoder);
        Ok(())
    }

    /// A 16-byte uniform buffer of four words (`u32`s; `f32`s as their bits), for the
    /// parameters of a [`KernelSource`].
    pub fn uniform_words(&self, words: [u32; 4]) -> wgpu::Buffer {
        super::buffers::uniform(self, &words)
    }

    /// Blocks until the GPU has finished all submitted work (for timings).
    pub fn wait(&self) {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .expect("waiting for the GPU");
    }

    /// A new command encoder.
    pub(crate) fn encoder(&self) -> wgpu::CommandEncoder {
        self.device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None })
    }

    /// Submits `encoder`'s commands.
    pub(crate) fn submit(&self, encoder: wgpu::CommandEncoder) {
        self.queue.submit([encoder.finish()]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_adapter_variable_picks_among_the_best_ranked_in_their_order() {
        // Two discrete GPUs (rank 0) around an integrated one, then a software one refused.
        let ranks = [Some(0), Some(1), Some(0), None];
        assert_eq!(pick(&ranks, None), Ok(Some(0)));
        assert_eq!(pick(&ranks, Some("0")), Ok(Some(0)));
        assert_eq!(pick(&ranks, Some("1")), Ok(Some(2)));
        let e = pick(&ranks, Some("2")).unwrap_err();
        assert!(
            e.contains("CLIPGAUSSIAN_GPU_ADAPTER=2") && e.contains("0 to 1"),
            "{e}"
        );
        assert!(pick(&ranks, Some("GPU-1234")).is_err());
        assert_eq!(pick(&[None, None], None), Ok(None));
    }

    #[test]
    fn out_of_memory_names_what_the_run_needs() {
        let e = GpuError::OutOfMemory {
            what: "splats".into(),
            needed: 64,
            adapter: "test".into(),
            run: None,
        };
        assert_eq!(
            e.to_string(),
            "splats needs 64 bytes of GPU memory and test has no more"
        );
        let message = e.with_run_needs(3 << 30).to_string();
        assert!(
            message.contains("at least 3.00 GiB (3221225472 bytes)"),
            "{message}"
        );
        let other = GpuError::Device {
            adapter: "test".into(),
            message: "lost".into(),
        };
        assert_eq!(
            other.with_run_needs(1).to_string(),
            "GPU adapter test: lost"
        );
    }

    #[test]
    fn software_adapters_only_when_allowed() {
        assert_eq!(rank(wgpu::DeviceType::Cpu, AdapterChoice::Hardware), None);
        assert!(rank(wgpu::DeviceType::Cpu, AdapterChoice::AllowSoftware).is_some());
        assert!(
            rank(wgpu::DeviceType::DiscreteGpu, AdapterChoice::AllowSoftware)
                < rank(wgpu::DeviceType::Cpu, AdapterChoice::AllowSoftware)
        );
    }
}
