//! The candle device the style loss runs on: the CPU, or a GPU through candle's CUDA (feature
//! `cuda`) or Metal (feature `metal`) backend. Only the image and its gradient cross between
//! this device and the rasterizer's, once each per step ([`crate::StyleObjective`]).

use candle_core::Device;

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
        if !built_with_gpu() {
            assert!(matches!(open_gpu(), Ok(None)));
        }
    }
}
