//! VeGaS model files: one written in the authors' layout (by `scripts/make_vegas_fixture.py`
//! with plyfile, as VeGaS's `save_ply`) loads with every value in place; ours read back
//! exactly; broken files are refused with the file and the reason.

use std::path::{Path, PathBuf};

use base_vegas::init::initial_model;
use base_vegas::model_file::{read_header, read_model, write_model, VideoRecord};
use gs_core::model::BaseModel;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

fn floats(v: &serde_json::Value) -> Vec<f32> {
    fn flat(v: &serde_json::Value, out: &mut Vec<f32>) {
        match v {
            serde_json::Value::Array(items) => items.iter().for_each(|i| flat(i, out)),
            other => out.push(other.as_f64().unwrap() as f32),
        }
    }
    let mut out = Vec::new();
    flat(v, &mut out);
    out
}

#[test]
fn a_model_in_the_authors_layout_loads_with_every_value_in_place() {
    let (model, record) = read_model(&fixture("vegas_model.ply")).unwrap();
    let expected: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fixture("vegas_model.json")).unwrap())
            .unwrap();
    let p = model.params();
    assert_eq!(p.len(), 7);
    assert_eq!(model.frames(), 5);
    assert_eq!(record, None, "VeGaS writes no record");
    assert_eq!(
        read_header(&fixture("vegas_model.ply")).unwrap(),
        (5, None),
        "the header alone says as much"
    );
    assert_eq!(p.xyz, floats(&expected["xyz"]));
    assert_eq!(p.sh_dc, floats(&expected["f_dc"]));
    assert_eq!(p.opacity_logits, floats(&expected["opacity"]));
    assert_eq!(p.log_scales, floats(&expected["scale_0_2"]));
    assert_eq!(p.rotation, floats(&expected["rot"]));
    assert_eq!(p.m, floats(&expected["m"]));
    assert_eq!(p.sigma, floats(&expected["sigma"]));
    assert_eq!(p.w, floats(&expected["w1"]));
    assert_eq!(
        model.time_logits(),
        floats(&expected["time_func"]).as_slice()
    );
}

#[test]
fn our_model_files_read_back_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("model.ply");
    let mut model = initial_model(50, 9, 0.4, 0.3, 2);
    for (k, g) in model.groups_mut().into_iter().enumerate() {
        for (i, v) in g.iter_mut().enumerate() {
            *v += 1e-3 * ((k * 31 + i) % 17) as f32;
        }
    }
    let record = VideoRecord {
        width: 96,
        height: 64,
        fps: 29.97,
        distance: 1.5,
    };
    write_model(&path, &model, Some(record)).unwrap();
    let (back, back_record) = read_model(&path).unwrap();
    assert_eq!(back, model);
    assert_eq!(back_record, Some(record));
    assert_eq!(read_header(&path).unwrap(), (9, Some(record)));
    // A header cut before its end is refused.
    let cut = dir.path().join("cut.ply");
    let bytes = std::fs::read(&path).unwrap();
    let end = bytes.windows(10).position(|w| w == b"end_header").unwrap();
    std::fs::write(&cut, &bytes[..end]).unwrap();
    let e = read_header(&cut).unwrap_err().to_string();
    assert!(e.contains("cut.ply") && e.contains("end_header"), "{e}");
    std::fs::remove_file(&cut).unwrap();
    let leftovers: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(leftovers.len(), 1, "no temporary file left");
    // A record whose frames no camera can have (a side past 65536 pixels), or whose numbers
    // are not positive, is refused by both readers naming the file and the comment.
    for (record, said) in [
        ("96x64 fps 29.97 distance 1.5", None),
        ("70000x2 fps 24 distance 1", Some("its frames")),
        ("96x64 fps -1 distance 1", Some("each positive")),
        ("96x64 fps 24", Some("each positive")),
    ] {
        let was = b"96x64 fps 29.97 distance 1.5";
        let at = bytes.windows(was.len()).position(|w| w == was).unwrap();
        let edited = [&bytes[..at], record.as_bytes(), &bytes[at + was.len()..]].concat();
        let odd = dir.path().join("record.ply");
        std::fs::write(&odd, edited).unwrap();
        for e in [
            read_model(&odd).err().map(|e| e.to_string()),
            read_header(&odd).err().map(|e| e.to_string()),
        ] {
            match said {
                None => assert_eq!(e, None),
                Some(said) => {
                    let e = e.unwrap_or_else(|| panic!("{record} accepted"));
                    assert!(e.contains("record.ply") && e.contains(said), "{e}");
                }
            }
        }
    }
}

#[test]
fn broken_model_files_are_refused_with_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read(fixture("vegas_model.ply")).unwrap();
    let header_end = text.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let header = String::from_utf8(text[..header_end].to_vec()).unwrap();
    let case = |name: &str, bytes: Vec<u8>| -> String {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        let e = read_model(&path).unwrap_err().to_string();
        assert!(e.contains(name), "{e}");
        e
    };
    let truncated = case("truncated.ply", text[..text.len() - 30].to_vec());
    assert!(
        truncated.contains("the body is 826 bytes; the header announces 856"),
        "{truncated}"
    );

    let renamed = header.replace("property float m_0\n", "property float q_0\n");
    let mut bytes = renamed.into_bytes();
    bytes.extend_from_slice(&text[header_end..]);
    let e = case("no_m.ply", bytes);
    assert!(
        e.contains("no property m_0") && e.contains("not a VeGaS model"),
        "{e}"
    );

    let e = case("not_ply.ply", b"hello".to_vec());
    assert!(e.contains("not a PLY file"), "{e}");

    // A NaN in the first vertex's x.
    let mut bytes = text.clone();
    bytes[header_end..header_end + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    let e = case("nan.ply", bytes);
    assert!(e.contains("x of vertex 0 is NaN"), "{e}");

    let inria = dir.path().join("scene.ply");
    let mut set = gs_core::GaussianSet::zeros(3, 0);
    set.opacity_logits[0] = 0.5;
    gs_core::ply::write_ply(
        &inria,
        &gs_core::ply::PlyGaussians::new(set),
        gs_core::ply::PlyFormat::BinaryLittleEndian,
    )
    .unwrap();
    let e = read_model(&inria).unwrap_err().to_string();
    assert!(
        e.contains("scene.ply") && e.contains("not a VeGaS model"),
        "{e}"
    );
}

/// The authors' file with its header edited: a vertex count one short (the time logits would
/// be read from vertex bytes), a count of 0 with the body kept, bytes after the body, a second
/// property of one name, format 2.0; each refused naming the file and what is wrong.
#[test]
fn files_that_do_not_hold_what_their_header_says_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let original = std::fs::read(fixture("vegas_model.ply")).unwrap();
    let end = original
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let header = String::from_utf8(original[..end].to_vec()).unwrap();
    let body = &original[end..];
    let with = |header: String, body: &[u8]| {
        let mut bytes = header.into_bytes();
        bytes.extend(body);
        bytes
    };
    let mut trailing = body.to_vec();
    trailing.extend([0u8; 4]);
    let cases = [
        (
            "short",
            with(header.replace("element vertex 7", "element vertex 6"), body),
            "header announces",
        ),
        (
            "zero",
            with(header.replace("element vertex 7", "element vertex 0"), body),
            "bytes after the last element",
        ),
        ("trailing", with(header.clone(), &trailing), "4 bytes after"),
        (
            "twice",
            with(
                header.replace(
                    "property float m_0",
                    "property float m_0\nproperty float m_0",
                ),
                body,
            ),
            "named twice",
        ),
        (
            "format",
            with(header.replace("1.0", "2.0"), body),
            "format 1.0",
        ),
    ];
    for (name, bytes, want) in cases {
        let path = dir.path().join(format!("{name}.ply"));
        std::fs::write(&path, bytes).unwrap();
        let e = read_model(&path).unwrap_err().to_string();
        assert!(
            e.contains(&format!("{name}.ply")) && e.contains(want),
            "{name}: {e}"
        );
    }
}
