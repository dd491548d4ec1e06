//! How much GPU memory a training run needs: wgpu cannot say how much an adapter has free,
//! so an allocation that fails is reported with this estimate of the whole run's needs.

use super::backward::SPLAT_GRAD_BYTES;
use super::forward::SPLAT_BYTES;

/// Bytes per pixel of one view's image buffers: RGB, alpha, depth, final transmittance,
/// contributor count, and dL/dRGB.
const PIXEL_BYTES: u64 = 12 + 4 + 4 + 4 + 4 + 12;

/// Bytes per Gaussian of one view's sort and binning buffers: depth keys, order, tile counts,
/// and the radix sort's two scratch arrays.
const SORT_BYTES: u64 = 5 * 4;

/// The GPU memory, bytes, that training needs at least: parameter groups of `lens` values
/// (`trained[i]` adds Adam's two moments and a gradient for group `i`), and one view of
/// `pixels` pixels rendering `gaussians` Gaussians (splats, splat gradients, sort buffers,
/// images). The tile lists (8 bytes per tile-Gaussian pair) come on top: their size depends
/// on how much of the image each Gaussian covers; so do a fit's targets and its photometric
/// loss's planes on the device, which the trainer adds when its objective is one.
pub fn training_bytes(lens: &[usize], trained: &[bool], gaussians: usize, pixels: u64) -> u64 {
    let values: u64 = lens.iter().map(|&n| n as u64).sum();
    let trained_values = trained_values(lens, trained);
    let per_view =
        gaussians as u64 * (SPLAT_BYTES + SPLAT_GRAD_BYTES + SORT_BYTES) + pixels * PIXEL_BYTES;
    4 * values + 3 * 4 * trained_values + per_view
}

/// Values of the trained groups (`lens[i]` values, trained when `trained[i]`).
pub(crate) fn trained_values(lens: &[usize], trained: &[bool]) -> u64 {
    lens.iter()
        .zip(trained)
        .filter(|(_, &t)| t)
        .map(|(&n, _)| n as u64)
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_parameters_moments_gradients_and_one_view() {
        // 10 Gaussians of degree 0 as a GaussianSet: 3+3+4+1+3 values each, sh_rest empty;
        // scales frozen.
        let lens = [30, 30, 40, 10, 30, 0];
        let trained = [true, false, true, true, true, true];
        let pixels = 8 * 6;
        let want = 4 * 140 + 12 * 110 + 10 * (64 + 40 + 20) + 48 * 40;
        assert_eq!(training_bytes(&lens, &trained, 10, pixels), want);
        assert_eq!(training_bytes(&[], &[], 0, 0), 0);
    }
}
