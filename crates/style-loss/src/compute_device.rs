//! The candle device the style loss runs on: the CPU, or a GPU through candle's CUDA (feature
//! `cuda`) or Metal (feature `metal`) backend. Only the image and its gradient cross between
//! this device and the rasterizer's, once each per step ([`crate::StyleObjective`]).

use candle_core::Device;
use gs_core::backend::DeviceChoice;

/// A GPU for the style loss: `Ok(None)` when this build has neither the `cuda` nor the `metal`
/// feature, an error when it has one and the device does not open (no driver, no GPU).
pub fn open_gpu() -> Result<Option<Device>, String> {
    open_built_gpu()
}

#[cfg(feature = "cuda")]
fn open_built_gpu() -> Result<Option<Device>, String> {
    Device::new_cuda(0)
        .map(Some)
        .map_err(|e| format!("CUDA device 0 does not open: {e}"))
}

#[cfg(all(feature = "metal", not(feature = "cuda")))]
fn open_built_gpu() -> Result<Option<Device>, String> {
    Device::new_metal(0)
        .map(Some)
        .map_err(|e| format!("Metal device 0 does not open: {e}"))
}

#[cfg(not(any(feature = "cuda", feature = "metal")))]
fn open_built_gpu() -> Result<Option<Device>, String> {
    Ok(None)
}

/// The device of the style loss for `choice`, and a note for the run's device line: `cpu` the
/// cpu (no GPU is opened); `auto` a GPU when this build has one (the `cuda` or `metal` feature)
/// and it opens, else the cpu; `gpu` that GPU, an error when the build has one that does not
/// open, and the cpu with a note saying why when the build has none (the rasterizer still runs
/// on wgpu).
pub fn open_for(choice: DeviceChoice) -> Result<(Device, String), String> {
    if choice == DeviceChoice::Cpu {
        return Ok((Device::Cpu, String::new()));
    }
    let cpu = |note: &str| (Device::Cpu, note.to_string());
    match (choice, open_gpu()) {
        (_, Ok(Some(gpu))) => Ok((gpu, String::new())),
        (DeviceChoice::Gpu, Ok(None)) => Ok(cpu(
            " (this build has neither the cuda nor the metal feature: scripts/build_cuda.sh \
             builds one with cuda)",
        )),
        (DeviceChoice::Gpu, Err(why)) => Err(format!(
            "--device gpu: the style loss: {why}; use --device auto or cpu to run it on the cpu"
        )),
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
}
