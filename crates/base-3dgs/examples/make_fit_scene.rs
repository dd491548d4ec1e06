//! Writes the 3D fit's test scene (`tests/fit_scene`): a NeRF-synthetic folder rendered from
//! known Gaussians.
//!
//! Run: `cargo run --release -p base-3dgs --example make_fit_scene -- OUT [GAUSSIANS TRAIN TEST
//! SIZE SEED]` (defaults 150 24 6 40 0).

#[path = "../tests/fit_scene/mod.rs"]
mod fit_scene;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(out) = args.first() else {
        eprintln!("usage: make_fit_scene OUT [GAUSSIANS TRAIN TEST SIZE SEED]");
        std::process::exit(2);
    };
    let number = |i: usize, default: u64| -> u64 {
        args.get(i).map_or(default, |s| {
            s.parse().unwrap_or_else(|_| {
                eprintln!("argument {i}: {s:?} is not a whole number");
                std::process::exit(2)
            })
        })
    };
    let scene = fit_scene::FitScene {
        gaussians: number(1, 150) as usize,
        train: number(2, 24) as usize,
        test: number(3, 6) as usize,
        size: number(4, 40) as u32,
        seed: number(5, 0),
    };
    fit_scene::write_fit_scene(std::path::Path::new(out), scene);
    println!("wrote {out}: {scene:?}");
}
