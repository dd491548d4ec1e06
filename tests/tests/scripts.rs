//! The scripts for a GPU machine, parsed and dry-run (nothing is fetched, built or timed):
//! `scripts/build_cuda.sh` picks the compute capability as documented (`CUDA_COMPUTE_CAP` when
//! set, else the GPU `nvidia-smi` reports, else 8.0, PTX that runs on every GPU from Ampere on;
//! a malformed value is refused) and CUDA 13 or, on request, 12; `scripts/gpu_check.sh` lists
//! every part it would run, and, run on fake binaries, stops a hung part and reports the others.

use std::path::{Path, PathBuf};
use std::process::Command;

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scripts/build_cuda.sh")
}

/// Writes an executable `dir/name` whose text is `body`.
fn fake_program(dir: &Path, name: &str, body: &str) {
    let path = dir.join(name);
    std::fs::write(&path, body).unwrap();
    let mut permissions = std::fs::metadata(&path).unwrap().permissions();
    std::os::unix::fs::PermissionsExt::set_mode(&mut permissions, 0o755);
    std::fs::set_permissions(&path, permissions).unwrap();
}

/// A folder holding an `nvidia-smi` that prints `compute_cap` (or fails when `None`).
fn fake_nvidia_smi(dir: &Path, compute_cap: Option<&str>) {
    let body = match compute_cap {
        Some(cap) => format!("#!/bin/sh\necho {cap}\n"),
        None => "#!/bin/sh\necho 'NVIDIA-SMI has failed' >&2\nexit 9\n".to_string(),
    };
    fake_program(dir, "nvidia-smi", &body);
}

/// The dry run's status and output, `nvidia-smi` faked in front of the system's.
fn dry_run(compute_cap_env: Option<&str>, smi: Option<&str>) -> (bool, String) {
    let dir = tempfile::tempdir().unwrap();
    fake_nvidia_smi(dir.path(), smi);
    let path = format!(
        "{}:{}",
        dir.path().display(),
        std::env::var("PATH").unwrap()
    );
    let mut cmd = Command::new("bash");
    cmd.arg(script()).arg("--dry-run").env("PATH", path);
    match compute_cap_env {
        Some(cap) => cmd.env("CUDA_COMPUTE_CAP", cap),
        None => cmd.env_remove("CUDA_COMPUTE_CAP"),
    };
    let out = cmd.output().unwrap();
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    (out.status.success(), text)
}

#[test]
fn the_cuda_build_script_parses_and_picks_the_compute_capability() {
    let syntax = Command::new("bash")
        .arg("-n")
        .arg(script())
        .status()
        .unwrap();
    assert!(syntax.success());
    let (ok, text) = dry_run(None, None);
    assert!(
        ok && text.contains("compute capability 80 (no GPU found"),
        "{text}"
    );
    assert!(text.contains("dry run"), "{text}");
    let (ok, text) = dry_run(None, Some("8.6"));
    assert!(
        ok && text.contains("compute capability 86 (the GPU"),
        "{text}"
    );
    let (ok, text) = dry_run(Some("89"), Some("8.6"));
    assert!(
        ok && text.contains("compute capability 89 (CUDA_COMPUTE_CAP)"),
        "{text}"
    );
    let (ok, text) = dry_run(Some("8.9"), None);
    assert!(!ok && text.contains("as digits"), "{text}");
}

/// A folder laid out as a CUDA toolkit whose `nvcc` reports `release`.
fn fake_toolkit(dir: &Path, release: &str) {
    std::fs::create_dir_all(dir.join("bin")).unwrap();
    let nvcc = dir.join("bin/nvcc");
    let body =
        format!("#!/bin/sh\necho 'Cuda compilation tools, release {release}, V{release}.1'\n");
    std::fs::write(&nvcc, body).unwrap();
    let mut permissions = std::fs::metadata(&nvcc).unwrap().permissions();
    std::os::unix::fs::PermissionsExt::set_mode(&mut permissions, 0o755);
    std::fs::set_permissions(&nvcc, permissions).unwrap();
}

#[test]
fn the_cuda_build_script_builds_cuda_12_with_an_installed_toolkit() {
    let run = |args: &[&str], cuda_home: Option<&Path>| {
        let mut cmd = Command::new("bash");
        cmd.arg(script())
            .args(args)
            .env_remove("CARGO_TARGET_DIR")
            .env_remove("CUDA_PATH")
            .env("CUDA_COMPUTE_CAP", "86");
        match cuda_home {
            Some(home) => cmd.env("CUDA_HOME", home),
            None => cmd.env_remove("CUDA_HOME"),
        };
        let out = cmd.output().unwrap();
        let text = String::from_utf8_lossy(&out.stdout).into_owned()
            + &String::from_utf8_lossy(&out.stderr);
        (out.status.code(), text)
    };
    let dir = tempfile::tempdir().unwrap();
    let (twelve, twelve_four, thirteen) = (
        dir.path().join("12.0"),
        dir.path().join("12.4"),
        dir.path().join("13.0"),
    );
    fake_toolkit(&twelve, "12.0");
    fake_toolkit(&twelve_four, "12.4");
    fake_toolkit(&thirteen, "13.0");
    let (code, text) = run(&["--cuda", "12", "--dry-run"], Some(&twelve));
    assert_eq!(code, Some(0), "{text}");
    assert!(text.contains("CUDA 12.0, compute capability 86"), "{text}");
    assert!(
        text.contains("installed toolkit into target/cuda12"),
        "{text}"
    );
    assert!(!text.contains("note:"), "{text}");
    let (code, text) = run(&["--cuda", "12", "--dry-run"], Some(&twelve_four));
    assert_eq!(code, Some(0), "{text}");
    assert!(text.contains("drivers of CUDA 12.4 or newer"), "{text}");
    let (code, text) = run(&["--dry-run"], Some(&twelve));
    assert_eq!(code, Some(0), "{text}");
    assert!(
        text.contains("CUDA 13.0") && text.contains("build into target/cuda\n"),
        "{text}"
    );
    let (code, text) = run(&["--cuda", "11", "--dry-run"], None);
    assert_eq!(code, Some(2), "{text}");
    assert!(
        text.contains("give 13 (NVIDIA driver 580 or newer) or 12"),
        "{text}"
    );
    // Without a CUDA 12 toolkit (a CUDA 13 one is not taken), when this machine has none in
    // the usual places either.
    let installed = ["/usr/local/cuda", "/opt/cuda"]
        .iter()
        .any(|p| Path::new(p).exists())
        || std::fs::read_dir("/usr/local")
            .map(|d| {
                d.flatten()
                    .any(|e| e.file_name().to_string_lossy().starts_with("cuda-12"))
            })
            .unwrap_or(false);
    if !installed {
        let (code, text) = run(&["--cuda", "12", "--dry-run"], Some(&thirteen));
        assert_eq!(code, Some(2), "{text}");
        assert!(
            text.contains("PyPI has no CUDA 12 nvcc") && text.contains("set CUDA_HOME"),
            "{text}"
        );
    }
}

#[test]
fn the_gpu_check_parses_and_its_dry_run_lists_every_part() {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scripts/gpu_check.sh");
    let syntax = Command::new("bash")
        .arg("-n")
        .arg(&script)
        .status()
        .unwrap();
    assert!(syntax.success());
    let out = Command::new("bash")
        .arg(&script)
        .args(["--dry-run", "--bin", "some/dir"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}");
    for binary in [
        "clipgaussian-2d",
        "clipgaussian-3d",
        "clipgaussian-video",
        "clipgaussian-4d",
    ] {
        assert!(
            text.contains(&format!("some/dir/{binary} selftest --device gpu")),
            "{text}"
        );
    }
    for part in [
        "step_timing 300000 gpu 3 f16 800x800",
        "STYLE_LOSS_DEVICE=cuda STYLE_LOSS_PRECISION=f16 some/dir/style_loss_timing 3",
        "time_style_loss_torch.py 16 3 cuda f16",
        "STYLE_LOSS_DEVICE=cuda some/dir/vgg_op_timing",
        "BENCHMARK_4D_DEVICE=gpu some/dir/benchmark_4d 0 stylize",
    ] {
        assert!(text.contains(part), "{part}: {text}");
    }
    let bad = Command::new("bash")
        .arg(&script)
        .arg("--nonsense")
        .output()
        .unwrap();
    assert_eq!(bad.status.code(), Some(2));
}

/// Runs `scripts/gpu_check.sh --part-timeout 1` on fake binaries (a `clipgaussian-2d` that
/// hangs, the others printing a table row), as a folder or packed as `build_cuda.sh --pack`
/// packs them; returns the exit status and the report.
fn gpu_check_on_fakes(packed: bool) -> (Option<i32>, String) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scripts/gpu_check.sh");
    let dir = tempfile::tempdir().unwrap();
    let (bin, path) = (dir.path().join("bin"), dir.path().join("path"));
    std::fs::create_dir_all(&bin).unwrap();
    std::fs::create_dir_all(&path).unwrap();
    fake_nvidia_smi(&path, Some("9.0"));
    // No torch here: the PyTorch parts are skipped, as on a machine without it. The script
    // unpacks with python3's tarfile, done here by tar.
    fake_program(
        &path,
        "python3",
        "#!/bin/sh\ncase \"$2\" in *tarfile*) exec tar -xJf \"$3\" -C \"$4\" ;; esac\nexit 1\n",
    );
    fake_program(&bin, "clipgaussian-2d", "#!/bin/sh\nexec sleep 30\n");
    for binary in ["clipgaussian-3d", "clipgaussian-video", "clipgaussian-4d"] {
        fake_program(&bin, binary, "#!/bin/sh\necho '| part | ok |'\n");
    }
    for example in [
        "step_timing",
        "style_loss_timing",
        "vgg_op_timing",
        "benchmark_4d",
    ] {
        fake_program(&bin, example, "#!/bin/sh\necho \"| $* |\"\n");
    }
    let bin_arg = if packed {
        let archive = dir.path().join("dist.tar.xz");
        let status = Command::new("tar")
            .arg("-cJf")
            .arg(&archive)
            .arg("-C")
            .arg(&bin)
            .arg(".")
            .status()
            .unwrap();
        assert!(status.success());
        std::fs::remove_dir_all(&bin).unwrap();
        archive
    } else {
        bin
    };
    let report = dir.path().join("report.md");
    let start = std::time::Instant::now();
    let out = Command::new("bash")
        .arg(&script)
        .arg("--bin")
        .arg(&bin_arg)
        .arg("--out")
        .arg(&report)
        .args(["--part-timeout", "1"])
        .env(
            "PATH",
            format!("{}:{}", path.display(), std::env::var("PATH").unwrap()),
        )
        .output()
        .unwrap();
    assert!(
        start.elapsed().as_secs() < 25,
        "the hung part was not stopped"
    );
    (out.status.code(), std::fs::read_to_string(&report).unwrap())
}

#[test]
fn the_gpu_check_stops_a_hung_part_and_runs_the_others() {
    for packed in [false, true] {
        let (code, text) = gpu_check_on_fakes(packed);
        assert_eq!(code, Some(124), "packed {packed}: {text}");
        assert!(
            text.contains("selftest --device gpu`: exit 124, stopped after 1 s"),
            "{text}"
        );
        assert_eq!(text.matches("| part | ok |").count(), 3, "{text}");
        assert!(text.contains("| 300000 gpu 3 f16 800x800 |"), "{text}");
        assert!(text.contains("| 0 stylize |"), "{text}");
        assert!(
            text.contains("python3 has no torch or transformers: skipped"),
            "{text}"
        );
    }
}
