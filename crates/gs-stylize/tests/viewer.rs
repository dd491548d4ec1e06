//! `viewer.html` in headless Chromium (Debian's `chromium`, software WebGL): the page's picture
//! from a fixed camera is gs-core's cpu render of it (PSNR >= 30 dB over the model's pixels),
//! at the style slider's 0 (the base model), 1 (the stylized one) and 0.5 (`interpolate`'s
//! blend), and the page makes no network request (every request goes through a proxy the test
//! holds; only Chromium's own background calls to Google's hosts may reach it).
//!
//! Without a browser the test says so and passes, unless `CLIPGAUSSIAN_REQUIRE_BROWSER_TESTS=1`
//! (CI's `.ci/run` installs Chromium and sets it).

use std::io::Read;
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use gs_core::{Camera, GaussianSet};
use gs_stylize::viewer::{write_viewer, ViewerScene};
use rand::{Rng, SeedableRng};

/// The browser to drive: `CLIPGAUSSIAN_CHROMIUM`, else the first of Chromium's names on the
/// path.
fn chromium() -> Option<PathBuf> {
    if let Some(path) = std::env::var_os("CLIPGAUSSIAN_CHROMIUM") {
        return Some(path.into());
    }
    let names = ["chromium", "chromium-browser", "google-chrome"];
    std::env::var_os("PATH").and_then(|paths| {
        std::env::split_paths(&paths)
            .flat_map(|dir| names.map(|n| dir.join(n)))
            .find(|p| p.is_file())
    })
}

/// A small scene of `n` Gaussians of SH degree 3 around the origin, from `seed`.
fn scene(n: usize, seed: u64) -> GaussianSet {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut set = GaussianSet::zeros(n, 3);
    for v in set.means.iter_mut() {
        *v = rng.random_range(-1.0..1.0);
    }
    for v in set.log_scales.iter_mut() {
        *v = rng.random_range(-3.5..-1.8);
    }
    for v in set.quats.iter_mut() {
        *v = rng.random_range(-1.0..1.0);
    }
    for v in set.opacity_logits.iter_mut() {
        *v = rng.random_range(-1.0..3.0);
    }
    for v in set.sh_dc.iter_mut() {
        *v = rng.random_range(-1.5..1.5);
    }
    for v in set.sh_rest.iter_mut() {
        *v = rng.random_range(-0.2..0.2);
    }
    set
}

/// Chromium's screenshot of `page` at `fragment`, `width x height`, with every request through
/// a proxy at `proxy` (a listener nobody else uses: any connection to it is a network request).
fn screenshot(
    browser: &Path,
    page: &Path,
    fragment: &str,
    size: (u32, u32),
    proxy: u16,
) -> image::RgbImage {
    let out = page.with_file_name(format!(
        "shot-{}.png",
        fragment.replace(['=', '&', '.'], "_")
    ));
    let status = Command::new(browser)
        .args([
            "--headless=new",
            "--no-sandbox",
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--ignore-gpu-blocklist",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--disable-extensions",
            "--hide-scrollbars",
            "--force-device-scale-factor=1",
            "--virtual-time-budget=5000",
        ])
        .arg(format!("--proxy-server=127.0.0.1:{proxy}"))
        .arg(format!("--window-size={},{}", size.0, size.1))
        .arg(format!("--screenshot={}", out.display()))
        .arg(format!("file://{}#{fragment}", page.display()))
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status()
        .unwrap();
    assert!(status.success(), "chromium: {status}");
    image::open(&out).unwrap().to_rgb8()
}

/// PSNR (dB) of `shot` against `expected` over the pixels where the model's render has alpha
/// of at least 0.05 (the background apart), and how many those are.
fn psnr_over_model(
    shot: &image::RgbImage,
    expected: &gs_core::Image,
    alpha: &[f32],
) -> (f64, usize) {
    let (mut sum, mut count) = (0.0f64, 0usize);
    for (i, &a) in alpha.iter().enumerate() {
        if a < 0.05 {
            continue;
        }
        let (x, y) = (i as u32 % expected.width, i as u32 / expected.width);
        let got = shot.get_pixel(x, y).0;
        for ch in 0..3 {
            let want = f64::from(expected.data[3 * i + ch].clamp(0.0, 1.0));
            sum += (f64::from(got[ch]) / 255.0 - want).powi(2);
        }
        count += 1;
    }
    let mse = sum / (3 * count.max(1)) as f64;
    (10.0 * (1.0 / mse.max(1e-12)).log10(), count)
}

#[test]
fn the_viewer_draws_what_gs_core_renders_at_every_slider_position() {
    let Some(browser) = chromium() else {
        assert!(
            std::env::var("CLIPGAUSSIAN_REQUIRE_BROWSER_TESTS").as_deref() != Ok("1"),
            "no Chromium found (install Debian's chromium, or set CLIPGAUSSIAN_CHROMIUM)"
        );
        eprintln!("skipped: no Chromium on this machine (set CLIPGAUSSIAN_CHROMIUM to run it)");
        return;
    };
    let base = scene(300, 1);
    // The stylized model: the same Gaussians moved, recoloured and resized.
    let mut stylized = scene(300, 2);
    for (s, b) in stylized.means.iter_mut().zip(&base.means) {
        *s = b + 0.1 * *s;
    }
    let background = [1.0f32, 1.0, 1.0];
    let camera =
        Camera::look_at([0.4, -0.6, -4.0], [0.0; 3], [0.0, -1.0, 0.0], 0.8, 160, 120).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let page = dir.path().join("viewer.html");
    write_viewer(
        &page,
        &ViewerScene {
            title: "test".into(),
            base: &base,
            stylized: Some(&stylized),
            cameras: vec![("view 0".into(), camera.clone())],
            background,
        },
    )
    .unwrap();
    let (port, requests, stop) = proxy();
    for t in [0.0f32, 1.0, 0.5] {
        let blended = gs_core::interpolate::interpolate(&base, &stylized, t).unwrap();
        let rendered = gs_core::raster::render(&blended, &camera, background);
        let shot = screenshot(
            &browser,
            &page,
            &format!("camera=0&t={t}&clean"),
            (160, 120),
            port,
        );
        assert_eq!(shot.dimensions(), (160, 120));
        let (psnr, pixels) = psnr_over_model(&shot, &rendered.image, &rendered.alpha);
        eprintln!("slider {t}: {psnr:.1} dB over {pixels} pixels");
        assert!(pixels > 2000, "the model covers the view: {pixels} pixels");
        assert!(psnr >= 30.0, "slider {t}: {psnr:.1} dB");
    }
    stop.store(true, Ordering::SeqCst);
    let requests = requests.lock().unwrap();
    // Chromium's own background calls (time, sign-in, its start page), not the page's.
    let own = [
        "clients2.google.com",
        "www.google.com",
        "accounts.google.com",
    ];
    let page_requests: Vec<&String> = requests
        .iter()
        .filter(|line| {
            !own.iter().any(|host| {
                line.contains(&format!(" {host}:")) || line.contains(&format!("//{host}/"))
            })
        })
        .collect();
    assert!(
        page_requests.is_empty(),
        "the page made network requests: {page_requests:?}"
    );
}

/// A proxy on 127.0.0.1 that records the first line of every request until `stop` is set: its
/// port, the lines, the stop flag.
fn proxy() -> (u16, Arc<Mutex<Vec<String>>>, Arc<AtomicBool>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    listener.set_nonblocking(true).unwrap();
    let port = listener.local_addr().unwrap().port();
    let requests = Arc::new(Mutex::new(Vec::new()));
    let stop = Arc::new(AtomicBool::new(false));
    let (seen, done) = (Arc::clone(&requests), Arc::clone(&stop));
    std::thread::spawn(move || {
        while !done.load(Ordering::SeqCst) {
            match listener.accept() {
                Ok((mut stream, _)) => {
                    stream.set_nonblocking(false).unwrap();
                    stream
                        .set_read_timeout(Some(std::time::Duration::from_secs(2)))
                        .unwrap();
                    let mut buffer = [0u8; 512];
                    let read = stream.read(&mut buffer).unwrap_or(0);
                    let text = String::from_utf8_lossy(&buffer[..read]);
                    seen.lock()
                        .unwrap()
                        .push(text.lines().next().unwrap_or("").to_string());
                }
                Err(_) => std::thread::sleep(std::time::Duration::from_millis(10)),
            }
        }
    });
    (port, requests, stop)
}
