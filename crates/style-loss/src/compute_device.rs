//! The candle device the style loss runs on: the CPU, or a GPU through candle's CUDA (feature
//! `cuda`) or Metal (feature `metal`) backend. Only the image and its gradient cross between
//! this device and the rasterizer's, once each per step ([`crate::StyleObjective`]).

use candle_core::{Device, Tensor};
use gs_core::device::DeviceChoice;

use crate::matmul::checked_matmul;

/// Why the style loss's GPU cannot be used: what failed, candle's error behind it (when there
/// is one), and a note on this build or on what to do.
#[derive(Debug, thiserror::Error)]
#[error("{what}{}{note}", source.as_ref().map_or(String::new(), |e| format!(" ({e})")))]
pub struct LossDeviceError {
    /// What failed (`CUDA device 0 does not open`).
    pub what: String,
    /// candle's error.
    pub source: Option<Box<candle_core::Error>>,
    /// What this build was made for, or what to do (may be empty).
    pub note: String,
}

/// A GPU for the style loss: `Ok(None)` when this build has neither the `cuda` nor the `metal`
/// feature, an error when it has one and the device does not open (no driver, no GPU) or fails
/// its [`self_check`].
pub fn open_gpu() -> Result<Option<Device>, LossDeviceError> {
    match open_built_gpu()? {
        Some(device) => self_check(&device).map(|()| Some(device)),
        None => Ok(None),
    }
}

/// Runs a small elementwise kernel, a reduction and a matrix product on `device` and checks
/// their values. A device can open and still not run this build's kernels (built for another
/// compute capability, a driver older than the toolkit): that fails here, named, instead of in
/// the first step.
pub fn self_check(device: &Device) -> Result<(), LossDeviceError> {
    let run = || -> candle_core::Result<(f32, Vec<Vec<f32>>)> {
        let x = Tensor::arange(0f32, 6f32, device)?.reshape((2, 3))?;
        let y = Tensor::arange(0f32, 6f32, device)?.reshape((3, 2))?;
        let sum = x.affine(2.0, 1.0)?.sum_all()?.to_scalar::<f32>()?;
        Ok((sum, checked_matmul(&x, &y)?.to_vec2::<f32>()?))
    };
    let name = describe(device);
    match run() {
        Ok((sum, product)) if sum == 36.0 && product == [[10.0, 13.0], [28.0, 40.0]] => Ok(()),
        Ok((sum, product)) => Err(LossDeviceError {
            what: format!(
                "{name}: the self-check computed wrong values (sum {sum}, product {product:?})"
            ),
            source: None,
            note: build_note(),
        }),
        Err(e) => Err(LossDeviceError {
            what: format!("{name}: the kernels do not run"),
            source: Some(Box::new(e)),
            note: build_note(),
        }),
    }
}

/// What this build was made for, for the self-check's errors.
fn build_note() -> String {
    match option_env!("CUDA_COMPUTE_CAP") {
        Some(cap) if cfg!(feature = "cuda") => format!(
            "; this build's kernels are for compute capability {cap} (scripts/build_cuda.sh \
             builds for the GPU it finds) and CUDA 13, which needs an NVIDIA driver 580 or newer"
        ),
        _ => String::new(),
    }
}

#[cfg(feature = "cuda")]
fn open_built_gpu() -> Result<Option<Device>, LossDeviceError> {
    Device::new_cuda(0).map(Some).map_err(|e| LossDeviceError {
        what: "CUDA device 0 does not open".into(),
        source: Some(Box::new(e)),
        note: build_note(),
    })
}

#[cfg(all(feature = "metal", not(feature = "cuda")))]
fn open_built_gpu() -> Result<Option<Device>, LossDeviceError> {
    Device::new_metal(0).map(Some).map_err(|e| LossDeviceError {
        what: "Metal device 0 does not open".into(),
        source: Some(Box::new(e)),
        note: String::new(),
    })
}

#[cfg(not(any(feature = "cuda", feature = "metal")))]
fn open_built_gpu() -> Result<Option<Device>, LossDeviceError> {
    Ok(None)
}

/// The device of the style loss for `choice`, and a note for the run's device line: `cpu` the
/// cpu (no GPU is opened); `auto` a GPU when this build has one (the `cuda` or `metal` feature)
/// and it opens, else the cpu; `gpu` that GPU, an error when the build has one that does not
/// open, and the cpu with a note saying why when the build has none (the rasterizer still runs
/// on wgpu).
pub fn open_for(choice: DeviceChoice) -> Result<(Device, String), LossDeviceError> {
    if choice == DeviceChoice::Cpu {
        return Ok((Device::Cpu, String::new()));
    }
    choose(choice, open_gpu())
}

/// [`open_for`] given what opening the GPU gave.
fn choose(
    choice: DeviceChoice,
    opened: Result<Option<Device>, LossDeviceError>,
) -> Result<(Device, String), LossDeviceError> {
    let cpu = |note: &str| (Device::Cpu, note.to_string());
    match (choice, opened) {
        (_, Ok(Some(gpu))) => Ok((gpu, String::new())),
        (DeviceChoice::Gpu, Ok(None)) => Ok(cpu(
            " (this build has neither the cuda nor the metal feature: scripts/build_cuda.sh \
             builds one with cuda)",
        )),
        (DeviceChoice::Gpu, Err(why)) => Err(LossDeviceError {
            what: format!("--device gpu: the style loss: {}", why.what),
            note: format!(
                "{}; use --device auto or cpu to run it on the cpu",
                why.note
            ),
            source: why.source,
        }),
        (_, Ok(None)) => Ok(cpu("")),
        (_, Err(why)) => Ok(cpu(&format!(" ({why})"))),
    }
}

/// Whether this build can run the style loss on a GPU (the `cuda` or `metal` feature).
pub const fn built_with_gpu() -> bool {
    cfg!(any(feature = "cuda", feature = "metal"))
}

/// The device in a few words: `cpu`, `cuda:0`, `metal:0`.
pub fn describe(device: &Device) -> String {
    match device.location() {
        candle_core::DeviceLocation::Cpu => "cpu".into(),
        candle_core::DeviceLocation::Cuda { gpu_id } => format!("cuda:{gpu_id}"),
        candle_core::DeviceLocation::Metal { gpu_id } => format!("metal:{gpu_id}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_build_without_gpu_features_has_no_gpu_and_says_cpu() {
        assert_eq!(describe(&Device::Cpu), "cpu");
        let (device, note) = open_for(DeviceChoice::Cpu).unwrap();
        assert!(device.is_cpu() && note.is_empty());
        if !built_with_gpu() {
            assert!(matches!(open_gpu(), Ok(None)));
            let (device, note) = open_for(DeviceChoice::Gpu).unwrap();
            assert!(
                device.is_cpu() && note.contains("neither the cuda nor the metal"),
                "{note}"
            );
            let (device, note) = open_for(DeviceChoice::Auto).unwrap();
            assert!(device.is_cpu() && note.is_empty());
        }
    }

    #[test]
    fn the_self_check_passes_on_the_cpu_and_its_failure_is_named() {
        self_check(&Device::Cpu).unwrap();
        // A GPU that opened but whose kernels do not load: auto falls back saying why, gpu stops.
        let why = || LossDeviceError {
            what: "cuda:0: the kernels do not run".into(),
            source: Some(Box::new(candle_core::Error::Msg(
                "CUDA_ERROR_NO_BINARY_FOR_GPU".into(),
            ))),
            note: String::new(),
        };
        let (device, note) = choose(DeviceChoice::Auto, Err(why())).unwrap();
        assert!(
            device.is_cpu() && note.contains("CUDA_ERROR_NO_BINARY_FOR_GPU"),
            "{note}"
        );
        let e = choose(DeviceChoice::Gpu, Err(why())).unwrap_err();
        assert!(
            matches!(e.source.as_deref(), Some(candle_core::Error::Msg(m)) if m.contains("NO_BINARY")),
            "candle's error is kept as the source: {e:?}"
        );
        let e = e.to_string();
        assert!(
            e.contains("--device gpu") && e.contains("kernels do not run") && e.contains("auto"),
            "{e}"
        );
    }
}
