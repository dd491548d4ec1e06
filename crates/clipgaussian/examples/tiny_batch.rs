//! Writes a small batch to try `clipgaussian batch` on any machine in seconds (what
//! `scripts/slurm_smoke.sh` submits): 2 generated pictures x 2 styles (a prompt and a picture),
//! 8 steps each (or `steps`), with the tiny CLIP and VGG-19 of the tests, on the cpu; each job
//! scored with the tiny CLIP once stylized.
//!
//! Run: `cargo run -p clipgaussian --example tiny_batch -- <folder> [steps]`; it prints the
//! manifest's path.

use std::path::{Path, PathBuf};

fn picture(path: &Path, seed: u8) -> Result<(), image::ImageError> {
    image::RgbImage::from_fn(40, 32, |x, y| {
        image::Rgb([(x * 6) as u8 ^ seed, (y * 7) as u8, 200 - (x * 3) as u8])
    })
    .save(path)
}

/// Writes the tiny models, the pictures and the manifest of `steps` steps a job into `dir`;
/// returns the manifest's path (the batch's tests use it too).
pub fn write(dir: &Path, steps: u64) -> Result<PathBuf, Box<dyn std::error::Error>> {
    std::fs::create_dir_all(dir)?;
    let models = style_loss::test_models::write_tiny_models(dir);
    picture(&dir.join("cat.png"), 0)?;
    picture(&dir.join("dog.png"), 90)?;
    picture(&dir.join("starry.png"), 170)?;
    let manifest = serde_json::json!({
        "modality": "2d",
        "set": {
            "steps": steps, "fit_steps": 10, "fit_gaussians": 60, "device": "cpu",
            "checkpoint_every": 2, "clip_config": models.clip_config,
            "clip_weights": models.clip_weights, "tokenizer": models.tokenizer,
            "vgg_weights": models.vgg_weights, "vgg_widths": models.vgg_widths.0,
            "patch_size": 16, "num_patches": 2
        },
        "inputs": [{"picture": "cat.png"}, {"picture": "dog.png"}],
        "styles": [{"style_prompt": "fire"}, {"style_image": "starry.png"}],
        "eval": {
            "clip_config": models.clip_config, "clip_weights": models.clip_weights,
            "tokenizer": models.tokenizer
        }
    });
    let path = dir.join("manifest.json");
    std::fs::write(&path, serde_json::to_string_pretty(&manifest)?)?;
    Ok(path)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let folder = args.next().ok_or("usage: tiny_batch <folder> [steps]")?;
    let steps: u64 = args.next().map_or(Ok(8), |s| s.parse())?;
    println!("{}", write(Path::new(&folder), steps)?.display());
    Ok(())
}
