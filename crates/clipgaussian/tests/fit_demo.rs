//! The main job end to end: `clipgaussian fit-demo` on a tiny setting writes its pictures and
//! rejects impossible options with a clear message.

use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_clipgaussian"))
}

#[test]
fn fit_demo_writes_before_after_pictures() {
    let out = std::env::temp_dir().join(format!("cg-fit-demo-{}", std::process::id()));
    let status = bin()
        .args([
            "fit-demo",
            "--steps",
            "150",
            "--gaussians",
            "300",
            "--views",
            "3",
            "--size",
            "32",
        ])
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        status.status.success(),
        "{}",
        String::from_utf8_lossy(&status.stderr)
    );
    let stdout = String::from_utf8_lossy(&status.stdout);
    // "mean PSNR over 3 views A dB -> B dB": the fit must improve it.
    let line = stdout
        .lines()
        .find(|l| l.contains("PSNR"))
        .expect("a PSNR line");
    let psnr: Vec<f64> = line
        .split_whitespace()
        .filter_map(|w| w.parse::<f64>().ok())
        .collect();
    assert!(psnr.len() >= 4, "{stdout}");
    let (before, after) = (psnr[psnr.len() - 2], psnr[psnr.len() - 1]);
    assert!(after > before + 2.0, "PSNR {before} -> {after}: {stdout}");
    // Three views: three rows of target | before | after, 32 pixels each.
    let views = image::open(out.join("views.png")).unwrap();
    assert_eq!((views.width(), views.height()), (96, 96));
    let after = image::open(out.join("after.png")).unwrap();
    assert_eq!((after.width(), after.height()), (32, 32));
    assert!(std::fs::read_dir(&out).unwrap().all(|e| !e
        .unwrap()
        .file_name()
        .to_string_lossy()
        .ends_with(".tmp")));
    std::fs::remove_dir_all(&out).unwrap();
}

#[test]
fn fit_demo_rejects_a_tiny_image_by_name() {
    let o = bin().args(["fit-demo", "--size", "8"]).output().unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--size"), "{err}");
}
