//! HWC `Vec<f32>` <-> `[1, 3, h, w]` conversions keep every value in place.

use candle_core::Device;
use style_loss::image_layout::{hwc_to_tensor, tensor_to_hwc};

#[test]
fn hwc_round_trip_and_channel_placement() {
    let (h, w) = (2, 3);
    let pixels: Vec<f32> = (0..h * w * 3).map(|v| v as f32).collect();
    let t = hwc_to_tensor(&pixels, h, w, &Device::Cpu).unwrap();
    assert_eq!(t.dims(), &[1, 3, h, w]);
    // Pixel (row 1, column 2), green channel: index (1 * 3 + 2) * 3 + 1 = 16.
    let green = t
        .get(0)
        .unwrap()
        .get(1)
        .unwrap()
        .get(1)
        .unwrap()
        .get(2)
        .unwrap();
    assert_eq!(green.to_scalar::<f32>().unwrap(), 16.0);
    assert_eq!(tensor_to_hwc(&t).unwrap(), pixels);
    assert!(hwc_to_tensor(&pixels[1..], h, w, &Device::Cpu).is_err());
}
