//! Splat formats against `@playcanvas/splat-transform` 3.7.0 (fixtures in `fixtures/splats`,
//! written by `scripts/make_splat_fixtures.sh`): our readers read its files as it reads them
//! (its `*.decoded.ply`), our writers write what it writes, and a round trip keeps every value
//! within the format's quantisation.

use std::path::{Path, PathBuf};

use gs_core::ply::{read_ply, PlyGaussians};
use gs_core::splats::{read_splats, write_splats, SplatFileError, SplatFormat};
use gs_core::GaussianSet;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/splats")
        .join(name)
}

/// The largest difference of `a` and `b`; a value finite on one side only is a difference of
/// infinity, equal infinities none.
fn worst(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| match (x.is_finite(), y.is_finite()) {
            (true, true) => (x - y).abs(),
            (false, false) if x == y => 0.0,
            _ => f32::INFINITY,
        })
        .fold(0.0, f32::max)
}

/// The largest difference of the rotations of `a` and `b`, each quaternion normalised and
/// compared up to sign.
fn worst_rotation(a: &GaussianSet, b: &GaussianSet) -> f32 {
    let unit = |q: &[f32]| {
        let n = q.iter().map(|v| v * v).sum::<f32>().sqrt();
        [q[0] / n, q[1] / n, q[2] / n, q[3] / n]
    };
    a.quats
        .chunks_exact(4)
        .zip(b.quats.chunks_exact(4))
        .map(|(p, q)| {
            let (p, q) = (unit(p), unit(q));
            let same = (0..4).map(|k| (p[k] - q[k]).abs()).fold(0.0, f32::max);
            let flipped = (0..4).map(|k| (p[k] + q[k]).abs()).fold(0.0, f32::max);
            same.min(flipped)
        })
        .fold(0.0, f32::max)
}

/// Every array of `got` within `tolerance` of `want`'s (rotations up to sign).
fn assert_close(what: &str, got: &GaussianSet, want: &GaussianSet, tolerance: [f32; 6]) {
    assert_eq!(got.len(), want.len(), "{what}: count");
    assert_eq!(got.sh_degree(), want.sh_degree(), "{what}: degree");
    let checks = [
        ("means", worst(&got.means, &want.means)),
        ("log_scales", worst(&got.log_scales, &want.log_scales)),
        ("rotations", worst_rotation(got, want)),
        (
            "opacities",
            worst(&got.opacity_logits, &want.opacity_logits),
        ),
        ("sh_dc", worst(&got.sh_dc, &want.sh_dc)),
        ("sh_rest", worst(&got.sh_rest, &want.sh_rest)),
    ];
    for ((name, error), tol) in checks.into_iter().zip(tolerance) {
        assert!(error <= tol, "{what}: {name} differ by {error} (> {tol})");
    }
}

/// The files of every format splat-transform reads and we read, with its reading beside.
const READ_BY_BOTH: [&str; 7] = [
    "source.compressed.ply",
    "source.splat",
    "unit.splat",
    "source.v2.spz",
    "source.v3.spz",
    "source.v4.spz",
    "source.sog",
];

#[test]
fn every_file_reads_as_splat_transform_reads_it() {
    for name in READ_BY_BOTH {
        let ours = read_splats(&fixture(name)).unwrap();
        let theirs = read_ply(&fixture(&format!("{name}.decoded.ply"))).unwrap();
        assert!(!ours.normals && ours.extras.is_empty(), "{name}");
        // The same formulas in f64 on both sides, stored in f32; SPZ 2's derived w,
        // `sqrt(1 - x² - y² - z²)`, is computed in f32 by Niantic's library (a few ulp where
        // w is small).
        assert_close(
            name,
            &ours.gaussians,
            &theirs.gaussians,
            [1e-6, 1e-6, 2e-6, 1e-5, 1e-6, 1e-6],
        );
    }
}

/// `source.ply` written by us in `format`, then read back by us.
fn round_trip(format: SplatFormat, source: &str) -> (Vec<u8>, GaussianSet) {
    let dir = tempfile::tempdir().unwrap();
    let ply = read_ply(&fixture(source)).unwrap();
    let path = dir.path().join(format!("out{}", format.extension()));
    write_splats(&path, &ply, format).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let back = read_splats(&path).unwrap().gaussians;
    (bytes, back)
}

/// The bytes after a PLY header.
fn body(bytes: &[u8]) -> &[u8] {
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap();
    &bytes[end + 11..]
}

#[test]
fn compressed_ply_is_written_as_splat_transform_writes_it() {
    let (ours, back) = round_trip(SplatFormat::CompressedPly, "source.ply");
    let theirs = std::fs::read(fixture("source.compressed.ply")).unwrap();
    assert_eq!(
        body(&ours),
        body(&theirs),
        "the same Morton order and packing"
    );
    // Read back, it is splat-transform's reading of its own file, in the same (Morton) order.
    let decoded = read_ply(&fixture("source.compressed.ply.decoded.ply")).unwrap();
    assert_close(
        "compressed",
        &back,
        &decoded.gaussians,
        [1e-6, 1e-6, 1e-6, 1e-5, 1e-6, 1e-6],
    );
}

#[test]
fn splat_is_written_as_splat_transform_writes_it() {
    let (ours, back) = round_trip(SplatFormat::Splat, "unit.ply");
    assert_eq!(ours, std::fs::read(fixture("unit.splat")).unwrap());
    assert_eq!(back.sh_degree(), 0, "no view dependence");
}

/// Decompressed SPZ attribute bytes: byte positions where ours and theirs differ, and by how
/// much at most (Niantic's encoder rounds in `f32`, ours in `f64`: a tie may fall either way).
fn spz_differences(ours: &GaussianSet, theirs: &GaussianSet) -> f32 {
    let mut error = 0.0f32;
    for (a, b) in [
        (&ours.means, &theirs.means),
        (&ours.log_scales, &theirs.log_scales),
        (&ours.sh_dc, &theirs.sh_dc),
        (&ours.sh_rest, &theirs.sh_rest),
    ] {
        error = error.max(worst(a, b));
    }
    error
}

#[test]
fn spz_is_written_as_niantics_encoder_writes_it() {
    for (format, name) in [
        (SplatFormat::SpzV2, "source.v2.spz"),
        (SplatFormat::Spz, "source.v4.spz"),
    ] {
        let (_, back) = round_trip(format, "source.ply");
        let theirs = read_splats(&fixture(name)).unwrap().gaussians;
        // At most one quantisation level apart anywhere, at ties (f32 rounding in Niantic's).
        let step = spz_differences(&back, &theirs);
        assert!(step <= 1.0 / 128.0 + 1e-6, "{name}: {step}");
        let rotation = worst_rotation(&back, &theirs);
        assert!(rotation < 3e-3, "{name}: rotations {rotation}");
        assert!(
            worst(&back.opacity_logits, &theirs.opacity_logits) < 0.05,
            "{name}"
        );
    }
}

/// What each format keeps of the values, stated: the round trip of `source.ply` stays within
/// it.
#[test]
fn round_trips_stay_within_each_formats_quantisation() {
    let source = read_ply(&fixture("source.ply")).unwrap().gaussians;
    let unit = read_ply(&fixture("unit.ply")).unwrap().gaussians;
    // PLY: exact.
    let (_, back) = round_trip(SplatFormat::Ply, "source.ply");
    assert_eq!(back, source);
    // SPZ: positions 1/4096; log-scales 1/32 (1/16 steps); rotations ~3e-3 (v3/v4), 0.05 (v2,
    // whose w is derived from 8-bit x, y, z and is poorly conditioned where small); opacities within half an 8-bit level of the sigmoid; colour half of 1/(0.15 255);
    // SH half a bucket of 16/128 after rounding to 1/128: 8.5/128.
    for (format, rotation) in [(SplatFormat::Spz, 3e-3), (SplatFormat::SpzV2, 0.05)] {
        let (_, back) = round_trip(format, "source.ply");
        assert_close(
            format.name(),
            &back,
            &source,
            [
                0.5 / 4096.0 + 1e-6,
                1.0 / 32.0 + 1e-6,
                rotation,
                f32::INFINITY,
                0.5 / (0.15 * 255.0) + 1e-5,
                8.5 / 128.0 + 1e-6,
            ],
        );
        let sigmoid = |x: f32| 1.0 / (1.0 + (-x).exp());
        let alpha = back
            .opacity_logits
            .iter()
            .zip(&source.opacity_logits)
            .map(|(a, b)| (sigmoid(*a) - sigmoid(*b)).abs())
            .fold(0.0, f32::max);
        assert!(
            alpha <= 0.5 / 255.0 + 1e-6,
            "{}: alpha {alpha}",
            format.name()
        );
    }
    // SOG: positions 16 bits of the span of sign(x) ln(|x| + 1), truncated (here a span of
    // 2.2, so 3.4e-5 before the exp, times e^1.1 at most after it); rotation bytes truncated
    // (2 / (255 sqrt 2) a component, more on the derived largest); log-scales and colours by
    // their 256-entry codebooks (here within 0.02); the SH palette (32 entries for 50
    // Gaussians of random values, which do not cluster) no further from the source than
    // splat-transform's.
    let (_, back) = round_trip(SplatFormat::Sog, "source.ply");
    assert_close(
        "sog",
        &back,
        &source,
        [1.1e-4, 0.02, 0.012, f32::INFINITY, 0.02, f32::INFINITY],
    );
    let rms = |a: &[f32], b: &[f32]| {
        let sum: f32 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
        (sum / a.len() as f32).sqrt()
    };
    let theirs = read_ply(&fixture("source.sog.decoded.ply"))
        .unwrap()
        .gaussians;
    let (ours, theirs) = (
        rms(&back.sh_rest, &source.sh_rest),
        rms(&theirs.sh_rest, &matched(&source, &theirs).sh_rest),
    );
    eprintln!("SH rms ours {ours} theirs {theirs}");
    assert!(
        ours <= 1.1 * theirs,
        "SH palette: rms {ours}, splat-transform's {theirs}"
    );
    // .splat: degree 0; colour and alpha truncated to 1/255 of the sigmoid and of 0.5 + C0 f_dc.
    let (_, back) = round_trip(SplatFormat::Splat, "unit.ply");
    assert_eq!(back.means, unit.means);
    let dc = worst(&back.sh_dc, &unit.sh_dc);
    assert!(dc <= 1.0 / (255.0 * 0.282_094_8) + 1e-5, "{dc}");
    assert!(worst(&back.log_scales, &unit.log_scales) < 1e-6);
}

/// splat-transform's `.glb` reads back as its source PLY (in the PLY frame: the half turn
/// undone), and ours round-trips within `f32` arithmetic (the colour is its float attribute,
/// the opacity its logit of the stored sigmoid).
#[test]
fn glb_reads_back_as_the_ply_it_was_written_from() {
    let source = read_ply(&fixture("source.ply")).unwrap().gaussians;
    let theirs = read_splats(&fixture("source.glb")).unwrap().gaussians;
    let (_, ours) = round_trip(SplatFormat::Glb, "source.ply");
    for (name, back) in [("theirs", &theirs), ("ours", &ours)] {
        assert_eq!(back.len(), source.len(), "{name}");
        assert_eq!(back.sh_degree(), source.sh_degree(), "{name}");
        assert_close(name, back, &source, [1e-6, 1e-5, 1e-5, 1e-4, 1e-6, 1e-6]);
    }
}

/// A SOG folder (`meta.json` and its pictures beside it) reads as the bundle does; a version 1
/// meta, a missing picture, a picture name that leaves the folder, and a bundle without its
/// meta.json are refused naming the file.
#[test]
fn sog_reads_from_a_folder_as_from_its_bundle() {
    let dir = tempfile::tempdir().unwrap();
    let bundle = std::fs::read(fixture("source.sog")).unwrap();
    let mut zip = zip::ZipArchive::new(std::io::Cursor::new(&bundle)).unwrap();
    for i in 0..zip.len() {
        let mut entry = zip.by_index(i).unwrap();
        let mut bytes = Vec::new();
        std::io::Read::read_to_end(&mut entry, &mut bytes).unwrap();
        std::fs::write(dir.path().join(entry.name()), bytes).unwrap();
    }
    let meta = dir.path().join("meta.json");
    let from_folder = read_splats(&meta).unwrap().gaussians;
    let from_bundle = read_splats(&fixture("source.sog")).unwrap().gaussians;
    assert_eq!(from_folder, from_bundle);
    assert_eq!((from_bundle.len(), from_bundle.sh_degree()), (50, 3));

    let text = std::fs::read_to_string(&meta).unwrap();
    let refused = |edited: String, said: &str| {
        std::fs::write(&meta, edited).unwrap();
        let e = read_splats(&meta).unwrap_err().to_string();
        assert!(
            e.contains("meta.json") && e.contains(said),
            "{said:?} not in {e}"
        );
    };
    refused(text.replace("\"version\":2,", ""), "version 1");
    refused(text.replace("quats.webp", "missing.webp"), "missing.webp");
    refused(
        text.replace("quats.webp", "../quats.webp"),
        "not a file beside it",
    );
    refused(
        text.replace("\"count\":50", "\"count\":5000000"),
        "texels for 5000000",
    );
    let bad = dir.path().join("bad.sog");
    std::fs::write(&bad, b"PK\x05\x06").unwrap();
    let e = read_splats(&bad).unwrap_err().to_string();
    assert!(e.contains("bad.sog") && e.contains("zip"), "{e}");
}

/// A compressed PLY whose chunk bounds no writer could have written (not finite, a log-scale
/// past the format's [-20, 20], a minimum above its maximum) is refused naming the chunk and
/// the bound; decoded, that chunk's Gaussians would vanish from renders without a word.
#[test]
fn compressed_ply_chunk_bounds_are_checked() {
    let dir = tempfile::tempdir().unwrap();
    let valid = std::fs::read(fixture("source.compressed.ply")).unwrap();
    let start = valid.len() - body(&valid).len();
    // Chunk 0's 18 float bounds open the body: min_x..max_z, min_scale_x..max_scale_z,
    // min_r..max_b.
    for (k, value, said) in [
        (0, f32::NAN, "chunk 0: min_x is NaN"),
        (4, f32::INFINITY, "chunk 0: max_y is inf"),
        (14, f32::NEG_INFINITY, "chunk 0: min_b is -inf"),
        (
            6,
            1e30,
            "chunk 0: min_scale_x is 1000000015047466200000000000000",
        ),
        (11, -20.5, "max_scale_z is -20.5, outside the [-20, 20]"),
        (2, 1e6, "chunk 0: min_z 1000000 is above max_z"),
    ] {
        let mut bytes = valid.clone();
        bytes[start + 4 * k..start + 4 * k + 4].copy_from_slice(&value.to_le_bytes());
        let path = dir.path().join("hostile.compressed.ply");
        std::fs::write(&path, &bytes).unwrap();
        let e = read_splats(&path).unwrap_err().to_string();
        assert!(
            e.contains("hostile.compressed.ply") && e.contains(said),
            "{said}: {e}"
        );
    }
    // At the limits the file reads: log-scale bounds of exactly -20 and 20.
    let mut bytes = valid.clone();
    bytes[start + 24..start + 28].copy_from_slice(&(-20.0f32).to_le_bytes());
    bytes[start + 36..start + 40].copy_from_slice(&20.0f32.to_le_bytes());
    let path = dir.path().join("edge.compressed.ply");
    std::fs::write(&path, &bytes).unwrap();
    read_splats(&path).unwrap();
}

/// The `meta.json` of a `.sog` bundle's bytes.
fn sog_meta(bundle: &[u8]) -> serde_json::Value {
    let mut zip = zip::ZipArchive::new(std::io::Cursor::new(bundle)).unwrap();
    let mut text = String::new();
    std::io::Read::read_to_string(&mut zip.by_name("meta.json").unwrap(), &mut text).unwrap();
    serde_json::from_str(&text).unwrap()
}

/// `set`'s Gaussians in the order of `order`'s, matched by position (each of `order`'s to
/// the nearest of `set`'s).
fn matched(set: &GaussianSet, order: &GaussianSet) -> GaussianSet {
    fn at(s: &GaussianSet, i: usize) -> &[f32] {
        &s.means[3 * i..3 * i + 3]
    }
    let pick: Vec<usize> = (0..order.len())
        .map(|j| {
            let distance = |i: usize| -> f32 {
                at(set, i)
                    .iter()
                    .zip(at(order, j))
                    .map(|(a, b)| (a - b) * (a - b))
                    .sum()
            };
            (0..set.len())
                .min_by(|&a, &b| distance(a).total_cmp(&distance(b)))
                .unwrap()
        })
        .collect();
    gathered(set, &pick)
}

/// The Gaussians `pick` of `set`, in that order.
fn gathered(set: &GaussianSet, pick: &[usize]) -> GaussianSet {
    let rest = set.sh_rest.len() / set.len().max(1);
    let gather = |values: &[f32], width: usize| -> Vec<f32> {
        pick.iter()
            .flat_map(|&i| values[width * i..width * (i + 1)].iter().copied())
            .collect()
    };
    let mut out = GaussianSet::zeros(pick.len(), set.sh_degree());
    out.means = gather(&set.means, 3);
    out.log_scales = gather(&set.log_scales, 3);
    out.quats = gather(&set.quats, 4);
    out.opacity_logits = gather(&set.opacity_logits, 1);
    out.sh_dc = gather(&set.sh_dc, 3);
    out.sh_rest = gather(&set.sh_rest, rest);
    out
}

/// Our SOG of `source.ply` quantises as splat-transform's `source.sog`: the same position
/// ranges and scale and colour codebooks, so every Gaussian reads back with splat-transform's
/// values but for the SH palette (a k-means that splat-transform seeds at random); the order
/// is ours (splat-transform's is Morton order).
#[test]
fn sog_is_written_as_splat_transform_writes_it() {
    let (bytes, ours) = round_trip(SplatFormat::Sog, "source.ply");
    let meta = sog_meta(&bytes);
    let theirs_meta = sog_meta(&std::fs::read(fixture("source.sog")).unwrap());
    for key in [
        "/means/mins",
        "/means/maxs",
        "/scales/codebook",
        "/sh0/codebook",
    ] {
        let values = |m: &serde_json::Value| -> Vec<f64> {
            m.pointer(key)
                .unwrap()
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect()
        };
        let (a, b) = (values(&meta), values(&theirs_meta));
        assert_eq!(a.len(), b.len(), "{key}");
        for (x, y) in a.iter().zip(&b) {
            assert!(
                (x - y).abs() <= 1e-6 * y.abs().max(1.0),
                "{key}: {x} against {y}"
            );
        }
    }
    assert_eq!(meta["count"], 50);
    assert_eq!(meta["shN"]["bands"], 3);
    assert_eq!(meta["shN"]["count"], theirs_meta["shN"]["count"]);
    let theirs = read_ply(&fixture("source.sog.decoded.ply"))
        .unwrap()
        .gaussians;
    let mut ours = matched(&ours, &theirs);
    // The SH palette is compared by the round trip's bound instead.
    ours.sh_rest.clone_from(&theirs.sh_rest);
    assert_close("sog", &ours, &theirs, [1e-6, 1e-6, 2e-6, 1e-5, 1e-6, 0.0]);
}

/// splat-transform reads the SOG our writer writes (`ours.sog`, written by `clipgaussian-3d
/// export` in the fixture script) as we read it, and our writer still writes those bytes.
#[test]
fn splat_transform_reads_our_sog_as_we_do() {
    let ours = read_splats(&fixture("ours.sog")).unwrap().gaussians;
    let theirs = read_ply(&fixture("ours.sog.decoded.ply"))
        .unwrap()
        .gaussians;
    assert_close(
        "ours.sog",
        &ours,
        &theirs,
        [1e-6, 1e-6, 2e-6, 1e-5, 1e-6, 1e-6],
    );
    let (bytes, _) = round_trip(SplatFormat::Sog, "source.ply");
    assert!(
        bytes == std::fs::read(fixture("ours.sog")).unwrap(),
        "the writer changed: rerun scripts/make_splat_fixtures.sh"
    );
}

/// A SOG written as a folder (`meta.json` named) reads as its bundle; a model of one Gaussian
/// and one of none (refused, nothing written); a transparent Gaussian keeps its colour (the
/// WebP keeps every byte under a zero alpha).
#[test]
fn sog_writes_folders_single_gaussians_and_transparent_ones() {
    let dir = tempfile::tempdir().unwrap();
    let mut ply = read_ply(&fixture("source.ply")).unwrap();
    ply.gaussians.opacity_logits[5] = -40.0;
    let bundle = dir.path().join("a.sog");
    write_splats(&bundle, &ply, SplatFormat::Sog).unwrap();
    let folder = dir.path().join("folder");
    std::fs::create_dir(&folder).unwrap();
    let meta = folder.join("meta.json");
    assert_eq!(SplatFormat::from_path(&meta), Some(SplatFormat::Sog));
    write_splats(&meta, &ply, SplatFormat::Sog).unwrap();
    let mut names: Vec<String> = std::fs::read_dir(&folder)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    assert_eq!(
        names,
        [
            "means_l.webp",
            "means_u.webp",
            "meta.json",
            "quats.webp",
            "scales.webp",
            "sh0.webp",
            "shN_centroids.webp",
            "shN_labels.webp"
        ]
    );
    let (a, b) = (
        read_splats(&bundle).unwrap().gaussians,
        read_splats(&meta).unwrap().gaussians,
    );
    assert_eq!(a, b);
    let bound = 0.05;
    let dc = worst(&a.sh_dc[15..18], &ply.gaussians.sh_dc[15..18]);
    assert!(
        dc < bound,
        "the transparent Gaussian's colour moved by {dc}"
    );
    assert!(a.opacity_logits[5] < -13.0);

    let one = PlyGaussians::new(gathered(&ply.gaussians, &[3]));
    let path = dir.path().join("one.sog");
    write_splats(&path, &one, SplatFormat::Sog).unwrap();
    let back = read_splats(&path).unwrap().gaussians;
    // One Gaussian: its span is zero, so its position is exact; its three log-scales and
    // three colours each take a codebook of three bins, where two values may share one (the
    // bins are placed half by rank: splat-transform's codebook, kept); its SH its own palette
    // entry, the entry's 45 values in a codebook of as many bins; its alpha is truncated to 8
    // bits.
    assert_close(
        "one",
        &back,
        &one.gaussians,
        [1e-6, 1.5, 0.012, f32::INFINITY, 1.5, 0.01],
    );
    let alpha = |x: f32| 1.0 / (1.0 + (-x).exp());
    let error = alpha(one.gaussians.opacity_logits[0]) - alpha(back.opacity_logits[0]);
    assert!((0.0..=1.0 / 255.0 + 1e-6).contains(&error), "alpha {error}");
    let none = PlyGaussians::new(gathered(&ply.gaussians, &[]));
    let path = dir.path().join("none.sog");
    let e = write_splats(&path, &none, SplatFormat::Sog)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("none.sog") && e.contains("at least one Gaussian"),
        "{e}"
    );
    assert!(!path.exists());
}

/// The glTF accessors of `.glb` bytes: name to (component type, bytes).
fn glb_attributes(bytes: &[u8]) -> Vec<(String, u64, Vec<u8>)> {
    assert_eq!(&bytes[..4], b"glTF");
    let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let json: serde_json::Value = serde_json::from_slice(&bytes[20..20 + json_len]).unwrap();
    let bin = &bytes[20 + json_len + 8..];
    let attributes = json["meshes"][0]["primitives"][0]["attributes"]
        .as_object()
        .unwrap();
    assert!(json["extensionsUsed"][0] == "KHR_gaussian_splatting");
    let mut out: Vec<(String, u64, Vec<u8>)> = attributes
        .iter()
        .map(|(name, index)| {
            let accessor = &json["accessors"][index.as_u64().unwrap() as usize];
            let view = &json["bufferViews"][accessor["bufferView"].as_u64().unwrap() as usize];
            let start = view["byteOffset"].as_u64().unwrap() as usize;
            let len = view["byteLength"].as_u64().unwrap() as usize;
            (
                name.clone(),
                accessor["componentType"].as_u64().unwrap(),
                bin[start..start + len].to_vec(),
            )
        })
        .collect();
    out.sort_by(|a, b| a.0.cmp(&b.0));
    out
}

#[test]
fn glb_holds_what_splat_transform_writes() {
    let (ours, _) = {
        let dir = tempfile::tempdir().unwrap();
        let ply = read_ply(&fixture("source.ply")).unwrap();
        let path = dir.path().join("out.glb");
        write_splats(&path, &ply, SplatFormat::Glb).unwrap();
        (std::fs::read(&path).unwrap(), ())
    };
    let theirs = std::fs::read(fixture("source.glb")).unwrap();
    let (ours, theirs) = (glb_attributes(&ours), glb_attributes(&theirs));
    let names: Vec<&str> = ours.iter().map(|a| a.0.as_str()).collect();
    let their_names: Vec<&str> = theirs.iter().map(|a| a.0.as_str()).collect();
    assert_eq!(names, their_names);
    assert_eq!(names.len(), 6 + 15);
    for ((name, component, a), (_, _, b)) in ours.iter().zip(&theirs) {
        assert_eq!(a.len(), b.len(), "{name}");
        if *component == 5121 {
            assert_eq!(a, b, "{name}: the colour levels");
            continue;
        }
        let values = |bytes: &[u8]| -> Vec<f32> {
            bytes
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
                .collect()
        };
        // The half turn of the quaternion is exact here; splat-transform's carries cos(pi/2).
        let error = worst(&values(a), &values(b));
        assert!(error < 1e-6, "{name}: {error}");
    }
}

#[test]
fn broken_and_unknown_files_are_refused_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let cut = dir.path().join("cut.splat");
    std::fs::write(&cut, &std::fs::read(fixture("unit.splat")).unwrap()[..100]).unwrap();
    let e = read_splats(&cut).unwrap_err().to_string();
    assert!(e.contains("cut.splat") && e.contains("100 bytes"), "{e}");
    let bad = dir.path().join("bad.spz");
    std::fs::write(&bad, b"not a splat file at all").unwrap();
    let e = read_splats(&bad).unwrap_err().to_string();
    assert!(e.contains("bad.spz") && e.contains("NGSP"), "{e}");
    let mut short = std::fs::read(fixture("source.v4.spz")).unwrap();
    short.truncate(short.len() - 10);
    let path = dir.path().join("short.spz");
    std::fs::write(&path, short).unwrap();
    assert!(read_splats(&path).is_err());
    // A name of no known ending is read as INRIA PLY when it starts as one (its reader then
    // names the problem), and refused as a format this reader does not know otherwise.
    let unknown = dir.path().join("model.xyz");
    std::fs::write(&unknown, b"ply\nformat nonsense\n").unwrap();
    assert!(matches!(read_splats(&unknown), Err(SplatFileError::Ply(_))));
    let sog = dir.path().join("model.sog");
    std::fs::write(&sog, b"PK\x03\x04 a zip of pictures").unwrap();
    let e = read_splats(&sog).unwrap_err().to_string();
    assert!(
        e.contains("model.sog") && e.contains("not a SOG bundle (a zip file)"),
        "{e}"
    );
    // A .glb that is not a splat file, or is cut short, is named.
    let glb = dir.path().join("model.glb");
    for (bytes, said) in [
        (&b"glTF\x02\0\0\0"[..], "header"),
        (&b"PK\x03\x04"[..], "not a glTF binary"),
    ] {
        std::fs::write(&glb, bytes).unwrap();
        let e = read_splats(&glb).unwrap_err().to_string();
        assert!(e.contains("model.glb") && e.contains(said), "{e}");
    }
    let mut theirs = std::fs::read(fixture("source.glb")).unwrap();
    theirs.truncate(theirs.len() - 100);
    std::fs::write(&glb, &theirs).unwrap();
    let e = read_splats(&glb).unwrap_err().to_string();
    assert!(e.contains("model.glb") && e.contains("past the end"), "{e}");
    // A NaN is refused by every quantising writer, naming the array and index.
    let mut ply = PlyGaussians::new(read_ply(&fixture("source.ply")).unwrap().gaussians);
    ply.gaussians.sh_dc[7] = f32::NAN;
    for format in [
        SplatFormat::CompressedPly,
        SplatFormat::Splat,
        SplatFormat::Spz,
        SplatFormat::Glb,
        SplatFormat::Sog,
    ] {
        let path = dir.path().join(format!("nan{}", format.extension()));
        let e = write_splats(&path, &ply, format).unwrap_err().to_string();
        assert!(e.contains("sh_dc[7] is NaN"), "{}: {e}", format.name());
        assert!(!path.exists(), "nothing written");
    }
    // A zero quaternion is refused by the formats that store unit rotations.
    let mut zero = PlyGaussians::new(read_ply(&fixture("source.ply")).unwrap().gaussians);
    zero.gaussians.quats[12..16].fill(0.0);
    for format in [
        SplatFormat::CompressedPly,
        SplatFormat::Splat,
        SplatFormat::Spz,
        SplatFormat::SpzV2,
        SplatFormat::Sog,
    ] {
        let path = dir.path().join(format!("zero{}", format.extension()));
        let e = write_splats(&path, &zero, format).unwrap_err().to_string();
        assert!(
            e.contains("rotation of Gaussian 3 is zero"),
            "{}: {e}",
            format.name()
        );
        assert!(!path.exists(), "nothing written");
    }
}
