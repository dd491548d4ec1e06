//! Times the content term's pieces one by one at VGG-19's shapes for an 800x800 image: each
//! 3x3 convolution (candle's `conv2d`), the ReLU and its gradient mask, the 2x2 max pool with
//! PyTorch's tie rule (`torch_ties::max_pool_2x2`, forward and forward + backward) beside
//! candle's own `max_pool2d`, and the whole network forward and forward + backward (random
//! weights). Each figure is the mean of 5 runs after one warm-up, the device synchronized
//! around them.
//!
//! Run: `cargo run --release -p style-loss --example vgg_op_timing`; with `--features cuda` and
//! `STYLE_LOSS_DEVICE=cuda`, on the GPU (what `scripts/gpu_check.sh` runs).

use std::time::Instant;

use candle_core::{Device, Tensor, Var};
use style_loss::torch_ties::max_pool_2x2;
use style_loss::{NamedTensors, Vgg19Features, Vgg19Widths, VggPrecision};

/// Prints `| label | mean ms |` of `runs` calls of `f` after a warm-up call.
fn time<T>(
    device: &Device,
    label: &str,
    runs: usize,
    mut f: impl FnMut() -> candle_core::Result<T>,
) -> candle_core::Result<()> {
    f()?;
    device.synchronize()?;
    let start = Instant::now();
    for _ in 0..runs {
        f()?;
    }
    device.synchronize()?;
    let ms = 1000.0 * start.elapsed().as_secs_f64() / runs as f64;
    println!("| {label} | {ms:.3} |");
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let device = match std::env::var("STYLE_LOSS_DEVICE").as_deref() {
        Ok("cuda") => Device::new_cuda(0)?,
        Ok("metal") => Device::new_metal(0)?,
        _ => Device::Cpu,
    };
    let runs = 5;
    println!("device: {device:?}\n\n| op | ms |\n|---|---|");
    for (c_in, c_out, side) in [
        (3, 64, 800),
        (64, 64, 800),
        (64, 128, 400),
        (128, 128, 400),
        (128, 256, 200),
        (256, 256, 200),
        (256, 512, 100),
        (512, 512, 100),
        (512, 512, 50),
    ] {
        let x = Tensor::rand(0f32, 1f32, (1, c_in, side, side), &device)?;
        let w = Tensor::rand(-0.1f32, 0.1f32, (c_out, c_in, 3, 3), &device)?;
        let y = x.conv2d(&w, 1, 1, 1, 1)?;
        time(
            &device,
            &format!("conv2d {c_in} -> {c_out} at {side}"),
            runs,
            || x.conv2d(&w, 1, 1, 1, 1),
        )?;
        time(&device, &format!("relu, {c_out} at {side}"), runs, || {
            y.relu()
        })?;
        time(
            &device,
            &format!("relu's gradient mask, {c_out} at {side}"),
            runs,
            || &y * y.gt(0.0)?.to_dtype(y.dtype())?,
        )?;
    }
    for (c, side) in [(64, 800), (128, 400), (256, 200), (512, 100)] {
        let x = Var::from_tensor(&Tensor::rand(0f32, 1f32, (1, c, side, side), &device)?)?;
        time(
            &device,
            &format!("max_pool_2x2, {c} at {side}"),
            runs,
            || max_pool_2x2(x.as_tensor()),
        )?;
        time(
            &device,
            &format!("max_pool_2x2 and its backward, {c} at {side}"),
            runs,
            || max_pool_2x2(x.as_tensor())?.sum_all()?.backward(),
        )?;
        time(
            &device,
            &format!("candle's max_pool2d, {c} at {side}"),
            runs,
            || x.as_tensor().max_pool2d(2),
        )?;
    }
    let vgg = Vgg19Features::from_tensors_with_precision(
        &NamedTensors::random(&device),
        Vgg19Widths::default(),
        VggPrecision::F32,
    )?;
    let image = Var::from_tensor(&Tensor::rand(0f32, 1f32, (1, 3, 800, 800), &device)?)?;
    let forward = || {
        vgg.forward(image.as_tensor())
            .map_err(candle_core::Error::wrap)
    };
    time(
        &device,
        "VGG-19 to conv5_2, forward, 800x800",
        runs,
        forward,
    )?;
    time(
        &device,
        "VGG-19 to conv5_2, forward and backward, 800x800",
        runs,
        || {
            let f = forward()?;
            (f.relu4_2.sum_all()? + f.relu5_2.sum_all()?)?.backward()
        },
    )?;
    Ok(())
}
