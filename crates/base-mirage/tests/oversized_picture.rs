//! A picture too large for this machine is refused from its header, before it is decoded:
//! the stored size counts, not only the size it would be shrunk to.

use base_mirage::stylize::{run, PictureStylizeConfig};
use gs_stylize::test_support::replay_settings;
use gs_stylize::{RunOptions, StyleSettings};
use style_loss::test_models::write_tiny_models;

/// CRC-32 (ISO-HDLC, PNG's) of `bytes`.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// A PNG chunk: length, type, data, CRC of type and data.
fn chunk(kind: &[u8; 4], data: &[u8]) -> Vec<u8> {
    let mut out = (data.len() as u32).to_be_bytes().to_vec();
    let mut body = kind.to_vec();
    body.extend_from_slice(data);
    out.extend_from_slice(&body);
    out.extend_from_slice(&crc32(&body).to_be_bytes());
    out
}

/// A PNG whose header says `width x height` 8-bit RGB, with a body of a few bytes: what a
/// decompression bomb looks like to a reader of headers.
fn png_claiming(width: u32, height: u32) -> Vec<u8> {
    let mut ihdr = width.to_be_bytes().to_vec();
    ihdr.extend_from_slice(&height.to_be_bytes());
    ihdr.extend_from_slice(&[8, 2, 0, 0, 0]);
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    png.extend(chunk(b"IHDR", &ihdr));
    // An empty zlib stream: the body ends long before the rows the header promises.
    png.extend(chunk(
        b"IDAT",
        &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01],
    ));
    png.extend(chunk(b"IEND", &[]));
    png
}

#[test]
fn a_picture_too_large_to_decode_is_refused_before_it_is_decoded() {
    if gs_stylize::memory_estimate::machine_memory().is_none() {
        eprintln!("SKIPPED: this system does not say how much memory it has (/proc/meminfo)");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let tiny = write_tiny_models(dir.path());
    let picture = dir.path().join("bomb.png");
    std::fs::write(&picture, png_claiming(200_000, 200_000)).unwrap();
    let out = dir.path().join("out");
    let config = PictureStylizeConfig {
        picture: Some(picture),
        out: Some(out.clone()),
        style: replay_settings(StyleSettings::paper_2d(), &tiny, 0, 3),
        ..PictureStylizeConfig::default()
    };
    let err = run(&config, &RunOptions::default())
        .unwrap_err()
        .to_string();
    // 4e10 stored pixels: 800 GB to decode, more than any machine this runs on.
    assert!(
        err.contains("this run needs about 8") && err.contains("decoding 800.0 GB"),
        "{err}"
    );
    assert!(
        err.contains("stored size counts while it is decoded"),
        "{err}"
    );
    assert!(!out.exists(), "nothing is written");
}
