//! A full-size ViT-B/32 (random weights, real shapes) runs forward and backward: the real
//! tensor shapes and memory, not just the tiny fixtures.

use candle_core::{Device, Tensor, Var};
use style_loss::{ClipConfig, ClipModel, NamedTensors};

#[test]
fn vit_b32_forward_and_backward_with_real_shapes() {
    let device = Device::Cpu;
    let config = ClipConfig::vit_b_32();
    let clip = ClipModel::from_tensors(&config, &NamedTensors::random(&device), &device).unwrap();
    let image =
        Var::from_tensor(&Tensor::rand(0f32, 1f32, (1, 3, 240, 320), &device).unwrap()).unwrap();
    let embedding = clip.encode_images(image.as_tensor()).unwrap();
    assert_eq!(embedding.dims(), &[1, 512]);
    let norm = embedding
        .sqr()
        .unwrap()
        .sum_all()
        .unwrap()
        .to_scalar::<f32>()
        .unwrap();
    assert!((norm - 1.0).abs() < 1e-4, "embedding norm^2 {norm}");
    let target = Tensor::rand(-1f32, 1f32, (1, 512), &device).unwrap();
    let loss = (embedding * target).unwrap().sum_all().unwrap();
    let grads = loss.backward().unwrap();
    let grad = grads
        .get(image.as_tensor())
        .expect("gradient reaches the image");
    assert_eq!(grad.dims(), &[1, 3, 240, 320]);
    let grad_norm = grad
        .sqr()
        .unwrap()
        .sum_all()
        .unwrap()
        .to_scalar::<f32>()
        .unwrap();
    assert!(
        grad_norm.is_finite() && grad_norm > 0.0,
        "gradient norm^2 {grad_norm}"
    );

    let text = clip
        .encode_token_ids(&[vec![49406, 320, 1125, 49407]])
        .unwrap();
    assert_eq!(text.dims(), &[1, 512]);
}
