//! INRIA PLY reading and writing: round trips of every SH degree and encoding, extra
//! properties, the on-disk f_rest order, hand-written files and every error.

use std::path::Path;

use gs_core::ply::{
    read_ply, write_ply, ExtraProperty, PlyErrorKind, PlyFormat, PlyGaussians, ScalarType,
};
use gs_core::GaussianSet;
use rand::{Rng, SeedableRng};
use tempfile::TempDir;

/// A fresh temporary folder whose name starts with `name`, removed when dropped.
fn temp_dir(name: &str) -> TempDir {
    tempfile::Builder::new()
        .prefix(name)
        .tempdir()
        .expect("create a temporary folder")
}

/// `n` Gaussians of SH degree `degree` with every parameter drawn from a seeded generator.
fn random_set(n: usize, degree: usize, seed: u64) -> GaussianSet {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut set = GaussianSet::zeros(n, degree);
    for array in set.arrays_mut() {
        for v in array.iter_mut() {
            *v = rng.random_range(-3.0f32..3.0);
        }
    }
    set
}

const FORMATS: [PlyFormat; 3] = [
    PlyFormat::BinaryLittleEndian,
    PlyFormat::BinaryBigEndian,
    PlyFormat::Ascii,
];

fn zero_normals(n: usize) -> Vec<ExtraProperty> {
    ["nx", "ny", "nz"]
        .iter()
        .map(|name| ExtraProperty {
            name: name.to_string(),
            ty: ScalarType::Float32,
            values: vec![0.0; n],
        })
        .collect()
}

#[test]
fn every_degree_and_format_round_trips_exactly() {
    let dir = temp_dir("ply-round-trip");
    for degree in 0..=3 {
        let set = random_set(37, degree, degree as u64);
        for format in FORMATS {
            let path = dir.path().join(format!("d{degree}-{}.ply", format.name()));
            write_ply(&path, &PlyGaussians::new(set.clone()), format).unwrap();
            let back = read_ply(&path).unwrap();
            assert_eq!(back.gaussians.sh_degree(), degree);
            assert_eq!(back.gaussians, set, "degree {degree} {format:?}");
            // INRIA writes zero normals; they come back as extras, not as unknown properties.
            assert_eq!(back.extras, zero_normals(37));
            assert!(back.unknown_properties().is_empty());
        }
    }
}

/// A file without normals (Mip-Splatting's, SuperSplat's exports) is written back without
/// them: nothing is added to what the input had.
#[test]
fn a_file_without_normals_is_written_back_without_them() {
    let dir = temp_dir("ply-no-normals");
    let set = random_set(9, 1, 4);
    let mut ply = PlyGaussians::new(set.clone());
    ply.normals = false;
    let path = dir.path().join("plain.ply");
    write_ply(&path, &ply, PlyFormat::BinaryLittleEndian).unwrap();
    let text = String::from_utf8_lossy(&std::fs::read(&path).unwrap()).into_owned();
    assert!(!text.contains("property float nx"), "{text}");
    let back = read_ply(&path).unwrap();
    assert!(!back.normals && back.extras.is_empty());
    assert_eq!(back.gaussians, set);
    let again = dir.path().join("again.ply");
    write_ply(&again, &back, PlyFormat::BinaryLittleEndian).unwrap();
    assert_eq!(
        std::fs::read(&again).unwrap(),
        std::fs::read(&path).unwrap()
    );
}

#[test]
fn extra_properties_are_preserved_and_reported() {
    let dir = temp_dir("ply-extras");
    let n = 11;
    let mut rng = rand::rngs::StdRng::seed_from_u64(7);
    let mut extra =
        |name: &str, ty, values: &mut dyn FnMut(&mut rand::rngs::StdRng) -> f64| ExtraProperty {
            name: name.into(),
            ty,
            values: (0..n).map(|_| values(&mut rng)).collect(),
        };
    let extras = vec![
        extra("nx", ScalarType::Float32, &mut |r| {
            r.random_range(-1.0f32..1.0) as f64
        }),
        extra("ny", ScalarType::Float32, &mut |_| 0.5),
        extra("nz", ScalarType::Float32, &mut |_| -0.25),
        extra("red", ScalarType::UInt8, &mut |r| {
            r.random_range(0..=255) as f64
        }),
        extra("weight", ScalarType::Float64, &mut |r| {
            r.random_range(-1e6..1e6)
        }),
        extra("label", ScalarType::Int32, &mut |r| {
            r.random_range(-100_000..100_000) as f64
        }),
        extra("tag", ScalarType::Int16, &mut |r| {
            r.random_range(-300..300) as f64
        }),
    ];
    let ply = PlyGaussians {
        gaussians: random_set(n, 2, 3),
        extras,
        comments: vec![
            "made by a test".into(),
            String::new(),
            "picture 40x32".into(),
        ],
        normals: true,
    };
    for format in FORMATS {
        let path = dir.path().join(format!("extras-{}.ply", format.name()));
        write_ply(&path, &ply, format).unwrap();
        let back = read_ply(&path).unwrap();
        assert_eq!(back, ply, "{format:?}");
        assert_eq!(back.unknown_properties(), ["red", "weight", "label", "tag"]);
    }
    let mut two_lines = ply.clone();
    two_lines.comments.push("one\ntwo".into());
    let e = write_ply(&dir.path().join("bad.ply"), &two_lines, PlyFormat::Ascii).unwrap_err();
    assert!(e.to_string().contains("one line"), "{e}");
}

/// The INRIA header of degree `degree` (property order of `save_ply`).
fn inria_header(n: usize, degree: usize, format: &str) -> String {
    let rest = 3 * ((degree + 1) * (degree + 1) - 1);
    let mut names: Vec<String> = [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    names.extend((0..rest).map(|j| format!("f_rest_{j}")));
    names.push("opacity".into());
    names.extend((0..3).map(|k| format!("scale_{k}")));
    names.extend((0..4).map(|k| format!("rot_{k}")));
    let mut h = format!("ply\nformat {format} 1.0\nelement vertex {n}\n");
    for name in names {
        h.push_str(&format!("property float {name}\n"));
    }
    h + "end_header\n"
}

#[test]
fn a_hand_written_inria_file_reads_with_channel_major_f_rest_and_writes_back_byte_exact() {
    let dir = temp_dir("ply-inria");
    let path = dir.path().join("point_cloud.ply");
    // Two vertices of degree 1: 3 + 3 + 3 + 9 + 1 + 3 + 4 = 26 floats each; vertex v holds
    // 100 v + property index.
    let mut bytes = inria_header(2, 1, "binary_little_endian").into_bytes();
    for v in 0..2 {
        for p in 0..26 {
            bytes.extend_from_slice(&(100.0 * v as f32 + p as f32).to_le_bytes());
        }
    }
    std::fs::write(&path, &bytes).unwrap();
    let ply = read_ply(&path).unwrap();
    let g = &ply.gaussians;
    assert_eq!((g.len(), g.sh_degree()), (2, 1));
    assert_eq!(&g.means[3..6], &[100.0, 101.0, 102.0]);
    assert_eq!(&g.sh_dc[0..3], &[6.0, 7.0, 8.0]);
    // f_rest_j is at property 9 + j; on disk j = channel * 3 + coeff, in memory
    // sh_rest[(i * 3 + coeff) * 3 + channel].
    for coeff in 0..3 {
        for channel in 0..3 {
            let j = channel * 3 + coeff;
            assert_eq!(g.sh_rest[coeff * 3 + channel], 9.0 + j as f32);
            assert_eq!(g.sh_rest[9 + coeff * 3 + channel], 109.0 + j as f32);
        }
    }
    assert_eq!(g.opacity_logits, [18.0, 118.0]);
    assert_eq!(&g.log_scales[0..3], &[19.0, 20.0, 21.0]);
    assert_eq!(&g.quats[0..4], &[22.0, 23.0, 24.0, 25.0]);
    assert_eq!(ply.extras[0].values, [3.0, 103.0]);
    let out = dir.path().join("again.ply");
    write_ply(&out, &ply, PlyFormat::BinaryLittleEndian).unwrap();
    assert_eq!(std::fs::read(&out).unwrap(), bytes);
}

#[test]
fn f_rest_is_written_channel_major() {
    let dir = temp_dir("ply-f-rest-order");
    let mut set = GaussianSet::zeros(1, 1);
    // In memory [coeff][channel]: value 10 coeff + channel.
    for coeff in 0..3 {
        for channel in 0..3 {
            set.sh_rest[coeff * 3 + channel] = (10 * coeff + channel) as f32;
        }
    }
    let path = dir.path().join("order.ply");
    write_ply(&path, &PlyGaussians::new(set), PlyFormat::Ascii).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    let values: Vec<f32> = text
        .lines()
        .last()
        .unwrap()
        .split(' ')
        .map(|t| t.parse().unwrap())
        .collect();
    // x y z nx ny nz f_dc_0..2, then f_rest: R of coeffs 0,1,2, then G, then B.
    assert_eq!(
        &values[9..18],
        &[0.0, 10.0, 20.0, 1.0, 11.0, 21.0, 2.0, 12.0, 22.0]
    );
}

#[test]
fn property_order_and_double_types_may_vary() {
    let dir = temp_dir("ply-order");
    let path = dir.path().join("shuffled.ply");
    let names = [
        "rot_3",
        "opacity",
        "z",
        "f_dc_2",
        "scale_0",
        "rot_0",
        "x",
        "f_dc_0",
        "scale_2",
        "y",
        "rot_1",
        "f_dc_1",
        "scale_1",
        "rot_2",
        "confidence",
    ];
    let mut text = String::from("ply\nformat ascii 1.0\ncomment made by hand\nelement vertex 1\n");
    for (i, name) in names.iter().enumerate() {
        let ty = if i % 2 == 0 { "double" } else { "float32" };
        text.push_str(&format!("property {ty} {name}\n"));
    }
    text.push_str("end_header\n");
    let values: Vec<String> = (0..names.len()).map(|i| format!("{}.5", i)).collect();
    text.push_str(&values.join(" "));
    text.push('\n');
    std::fs::write(&path, text).unwrap();
    let ply = read_ply(&path).unwrap();
    let g = &ply.gaussians;
    assert_eq!(g.means, [6.5, 9.5, 2.5]);
    assert_eq!(g.quats, [5.5, 10.5, 13.5, 0.5]);
    assert_eq!(g.log_scales, [4.5, 12.5, 8.5]);
    assert_eq!(g.sh_dc, [7.5, 11.5, 3.5]);
    assert_eq!(g.opacity_logits, [1.5]);
    assert_eq!(ply.unknown_properties(), ["confidence"]);
    assert_eq!(ply.extras[0].ty, ScalarType::Float64);
    assert_eq!(ply.comments, ["made by hand"]);
}

/// Writes `text` (a whole file) and returns the error message of reading it.
fn read_error(dir: &TempDir, name: &str, bytes: &[u8]) -> (PlyErrorKind, String) {
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).unwrap();
    let e = read_ply(&path).unwrap_err();
    let message = e.to_string();
    assert!(
        message.contains(name),
        "the message names the file: {message}"
    );
    (e.kind, message)
}

fn replace_in_header(header: &str, from: &str, to: &str) -> String {
    assert!(header.contains(from));
    header.replacen(from, to, 1)
}

#[test]
fn header_errors_name_the_line_or_property() {
    let dir = temp_dir("ply-header-errors");
    let good = inria_header(1, 0, "ascii");
    let body = "0 0 0 0 0 0 0 0 0 0 0 0 0 1 0 0 0\n";
    let cases = [
        ("missing.ply", replace_in_header(&good, "property float opacity\n", ""), "\"opacity\""),
        ("magic.ply", good.replacen("ply\n", "plx\n", 1), "ply"),
        ("format.ply", replace_in_header(&good, "ascii", "binary_middle_endian"), "binary_middle_endian"),
        ("type.ply", replace_in_header(&good, "float x", "half x"), "\"half\""),
        ("int.ply", replace_in_header(&good, "float opacity", "uchar opacity"), "\"opacity\" is uchar"),
        (
            "list.ply",
            replace_in_header(&good, "end_header", "property list uchar int idx\nend_header"),
            "list",
        ),
        (
            "face.ply",
            replace_in_header(&good, "end_header", "element face 3\nend_header"),
            "\"face\"",
        ),
        ("twice.ply", replace_in_header(&good, "float y\n", "float y\nproperty float y\n"), "twice"),
        ("rest.ply", replace_in_header(&good, "end_header", "property float f_rest_0\nproperty float f_rest_1\nproperty float f_rest_2\nproperty float f_rest_3\nproperty float f_rest_4\nend_header"), "5 f_rest"),
        ("noend.ply", good.replace("end_header\n", ""), "header line 21"),
    ];
    for (name, header, expected) in cases {
        let (_, message) = read_error(&dir, name, (header + body).as_bytes());
        assert!(message.contains(expected), "{name}: {message}");
    }
    let (_, message) = read_error(&dir, "eof.ply", good.replace("end_header\n", "").as_bytes());
    assert!(message.contains("no end_header"), "{message}");
}

#[test]
fn a_degree_with_a_missing_f_rest_name_is_named() {
    let dir = temp_dir("ply-rest-name");
    let header = inria_header(1, 1, "binary_little_endian").replace("f_rest_4\n", "f_rest_40\n");
    let mut bytes = header.into_bytes();
    bytes.extend(std::iter::repeat_n(0u8, 26 * 4));
    let (kind, message) = read_error(&dir, "rest-name.ply", &bytes);
    assert!(
        matches!(kind, PlyErrorKind::MissingProperty(p) if p == "f_rest_4"),
        "{message}"
    );
}

#[test]
fn non_finite_values_name_the_vertex_and_property() {
    let dir = temp_dir("ply-nan");
    let mut bytes = inria_header(3, 0, "binary_little_endian").into_bytes();
    for v in 0..3 {
        for p in 0..17 {
            // Vertex 2, scale_1 (property 11) is NaN.
            let x = if v == 2 && p == 11 { f32::NAN } else { 0.5 };
            bytes.extend_from_slice(&x.to_le_bytes());
        }
    }
    let (kind, message) = read_error(&dir, "nan.ply", &bytes);
    assert!(
        matches!(&kind, PlyErrorKind::BadValue { vertex: 2, property, .. } if property == "scale_1"),
        "{message}"
    );
    assert!(message.contains("NaN"), "{message}");

    let text = inria_header(2, 0, "ascii")
        + "0 0 0 0 0 0 0 0 0 0 0 0 0 1 0 0 0\n0 0 0 0 0 0 0 0 0 inf 0 0 0 1 0 0 0\n";
    let (kind, message) = read_error(&dir, "inf.ply", text.as_bytes());
    // The header has 3 + 17 + 1 = 21 lines; the second vertex is line 23.
    assert!(
        matches!(&kind, PlyErrorKind::AsciiValue { line: 23, property, .. } if property == "opacity"),
        "{message}"
    );

    // A double too large for a float is refused too.
    let text = inria_header(1, 0, "ascii").replace("float z", "double z")
        + "0 0 1e300 0 0 0 0 0 0 0 0 0 0 1 0 0 0\n";
    let (_, message) = read_error(&dir, "huge.ply", text.as_bytes());
    assert!(
        message.contains("\"z\"") && message.contains("1e300"),
        "{message}"
    );
}

#[test]
fn truncated_and_overlong_bodies_are_errors() {
    let dir = temp_dir("ply-truncated");
    let mut bytes = inria_header(4, 0, "binary_little_endian").into_bytes();
    bytes.extend(std::iter::repeat_n(0u8, 3 * 17 * 4 + 5));
    let (kind, message) = read_error(&dir, "short.ply", &bytes);
    assert!(
        matches!(
            kind,
            PlyErrorKind::Truncated {
                expected: 272,
                found: 209,
                ..
            }
        ),
        "{message}"
    );
    bytes.extend(std::iter::repeat_n(0u8, 17 * 4));
    let (kind, message) = read_error(&dir, "long.ply", &bytes);
    assert!(matches!(kind, PlyErrorKind::TrailingData(_)), "{message}");

    let text = inria_header(3, 0, "ascii") + "0 0 0 0 0 0 0 0 0 0 0 0 0 1 0 0 0\n";
    let (kind, message) = read_error(&dir, "short-ascii.ply", text.as_bytes());
    assert!(
        matches!(
            kind,
            PlyErrorKind::AsciiTruncated {
                expected: 3,
                found: 1
            }
        ),
        "{message}"
    );
    let text = inria_header(1, 0, "ascii") + "0 0 0 0 0 0 0 0 0 0 0 0 0 1 0 0\n";
    let (_, message) = read_error(&dir, "count-ascii.ply", text.as_bytes());
    assert!(
        message.contains("line 22: 16 values, 17 properties"),
        "{message}"
    );
}

#[test]
fn writing_refuses_bad_data_and_leaves_nothing_partial() {
    let dir = temp_dir("ply-write-errors");
    let path = dir.path().join("scene.ply");
    let good = PlyGaussians::new(random_set(5, 1, 1));
    write_ply(&path, &good, PlyFormat::BinaryLittleEndian).unwrap();
    let before = std::fs::read(&path).unwrap();

    let mut bad = good.clone();
    bad.gaussians.quats[4 * 3 + 2] = f32::INFINITY;
    let e = write_ply(&path, &bad, PlyFormat::BinaryLittleEndian).unwrap_err();
    assert!(
        matches!(&e.kind, PlyErrorKind::BadValue { vertex: 3, property, .. } if property == "rot_2"),
        "{e}"
    );
    let mut bad = good.clone();
    bad.extras.push(ExtraProperty {
        name: "red".into(),
        ty: ScalarType::UInt8,
        values: vec![0.0, 1.0, 256.0, 0.0, 0.0],
    });
    let e = write_ply(&path, &bad, PlyFormat::Ascii).unwrap_err();
    assert!(e.to_string().contains("vertex 2, property \"red\""), "{e}");
    let mut bad = good.clone();
    bad.extras.push(ExtraProperty {
        name: "opacity".into(),
        ty: ScalarType::Float32,
        values: vec![0.0; 5],
    });
    let e = write_ply(&path, &bad, PlyFormat::Ascii).unwrap_err();
    assert!(e.to_string().contains("\"opacity\""), "{e}");
    let mut bad = good.clone();
    bad.gaussians.sh_rest.pop();
    let e = write_ply(&path, &bad, PlyFormat::Ascii).unwrap_err();
    assert!(e.to_string().contains("sh_rest"), "{e}");

    // The earlier file is untouched and no temporary file is left.
    assert_eq!(std::fs::read(&path).unwrap(), before);
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names, ["scene.ply"]);

    let missing = dir.path().join("no-such-folder").join("x.ply");
    let e = write_ply(&missing, &good, PlyFormat::BinaryLittleEndian).unwrap_err();
    assert!(e.to_string().contains("no-such-folder"), "{e}");
    assert!(!Path::new(&missing).exists());
}
