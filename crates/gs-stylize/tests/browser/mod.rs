//! Headless Chromium for the viewer's tests (included by path from the crates that write
//! pages): the browser, a page's screenshot, its PSNR against gs-core's render, and a proxy
//! that sees every network request.

#![allow(dead_code)]

use std::io::Read;
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

/// The browser, or `None` (after saying so) where there is none and the browser tests are not
/// required (`CLIPGAUSSIAN_REQUIRE_BROWSER_TESTS=1`, which CI sets, makes that a failure).
pub fn chromium_or_skip() -> Option<PathBuf> {
    let found = chromium();
    if found.is_none() {
        assert!(
            std::env::var("CLIPGAUSSIAN_REQUIRE_BROWSER_TESTS").as_deref() != Ok("1"),
            "no Chromium found (install Debian's chromium, or set CLIPGAUSSIAN_CHROMIUM)"
        );
        eprintln!("skipped: no Chromium on this machine (set CLIPGAUSSIAN_CHROMIUM to run it)");
    }
    found
}

/// The browser to drive: `CLIPGAUSSIAN_CHROMIUM`, else the first of Chromium's names on the
/// path.
pub fn chromium() -> Option<PathBuf> {
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

/// Chromium's screenshot of `page` at `fragment`, `width x height`, with every request through
/// a proxy at `proxy` (a listener nobody else uses: any connection to it is a network request).
pub fn screenshot(
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
pub fn psnr_over_model(
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

/// The requests a page made: every one but Chromium's own background calls (time, sign-in,
/// sync, its start page), which go to hosts under `google.com` (a page's assets would come from
/// other hosts, `googleapis.com` and `gstatic.com` included). A connection that sent no request
/// (Chromium opens some ahead of any request, then closes them) is none.
pub fn page_requests(requests: &Mutex<Vec<String>>) -> Vec<String> {
    requests
        .lock()
        .unwrap()
        .iter()
        .filter(|line| {
            let Some(target) = line.split_whitespace().nth(1) else {
                return false;
            };
            let host = target
                .trim_start_matches("http://")
                .trim_start_matches("https://")
                .split(['/', ':'])
                .next()
                .unwrap_or("");
            !(host == "google.com" || host.ends_with(".google.com"))
        })
        .cloned()
        .collect()
}

/// A proxy on 127.0.0.1 that records the first line of every request until `stop` is set: its
/// port, the lines, the stop flag.
pub fn proxy() -> (u16, Arc<Mutex<Vec<String>>>, Arc<AtomicBool>) {
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
