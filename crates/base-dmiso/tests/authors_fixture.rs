//! The model the authors' code would save (written by scripts/make_dmiso_fixture.py in their
//! exact layout, with PyTorch's values and autograd gradients in float64): loaded through
//! candle's PyTorch reader, it builds the same sub-Gaussians, renders the same image, and its
//! backward gives PyTorch's gradient of every parameter group.

mod common;

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use base_dmiso::model::group;
use base_dmiso::model_file::{read_authors, AuthorsFiles, DmisoFileError};
use base_dmiso::{Dmiso, GROUP_NAMES};
use candle_core::Device;
use gs_core::gaussians::GaussianSet;
use gs_core::model::{BaseModel, View};
use gs_core::Camera;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

fn expected(name: &str) -> HashMap<String, Vec<f32>> {
    let bytes = std::fs::read(fixture(name).join("expected.safetensors")).unwrap();
    let tensors = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    tensors
        .tensors()
        .into_iter()
        .map(|(name, view)| {
            let values = view
                .data()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            (name, values)
        })
        .collect()
}

fn load(name: &str) -> Dmiso {
    let files = AuthorsFiles::find(&fixture(name), None).unwrap();
    read_authors(&files, &Device::Cpu).unwrap()
}

/// Largest difference relative to the largest magnitude of `want`.
fn relative(want: &[f32], got: &[f32]) -> f32 {
    assert_eq!(want.len(), got.len());
    let scale = want.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-12);
    want.iter()
        .zip(got)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max)
        / scale
}

const FIXTURES: [&str; 2] = ["dmiso_small", "dmiso_zero_bias"];

#[test]
fn the_authors_layout_loads_and_builds_pytorchs_sub_gaussians() {
    for name in FIXTURES {
        let want = expected(name);
        let model = load(name);
        assert_eq!(model.len() * 16 * 3, want["sh_dc"].len() * 16);
        let view = View {
            camera: Camera::look_at([0.0, -0.5, -4.0], [0.0; 3], [0.0, -1.0, 0.0], 0.8, 48, 40)
                .unwrap(),
            time: want["time"][0] as f64,
        };
        let deform = model.deformations(view.time).unwrap();
        let e = relative(&want["deform_out"], &deform);
        assert!(e < 1e-5, "{name}: network outputs differ by {e}");
        let built = model.forward(&view).unwrap().gaussians.into_owned();
        for (what, got, tol) in [
            ("means", &built.means, 1e-5),
            ("log_scales", &built.log_scales, 1e-5),
            ("quats", &built.quats, 1e-5),
            ("opacity_logits", &built.opacity_logits, 0.0),
            ("sh_dc", &built.sh_dc, 0.0),
            ("sh_rest", &built.sh_rest, 0.0),
        ] {
            let e = relative(&want[what], got);
            assert!(e <= tol, "{name}: {what} differ by {e}");
        }
        // The fixture's Gaussians render as ours.
        let theirs = GaussianSet::from_arrays(
            want["means"].clone(),
            want["log_scales"].clone(),
            want["quats"].clone(),
            want["opacity_logits"].clone(),
            &interleave_sh(&want["sh_dc"], &want["sh_rest"]),
        )
        .unwrap();
        let a = gs_core::raster::render(&built, &view.camera, [1.0; 3]).image;
        let b = gs_core::raster::render(&theirs, &view.camera, [1.0; 3]).image;
        let e = relative(&b.data, &a.data);
        assert!(e < 1e-4, "{name}: renders differ by {e}");
        assert!(
            b.data.iter().any(|&v| v < 0.9),
            "{name}: the Gaussians are in view"
        );
    }
}

/// `[N, 16, 3]` SH from the DC `[N, 3]` and the rest `[N, 15, 3]`.
fn interleave_sh(dc: &[f32], rest: &[f32]) -> Vec<f32> {
    dc.chunks_exact(3)
        .zip(rest.chunks_exact(45))
        .flat_map(|(d, r)| d.iter().chain(r).copied())
        .collect()
}

#[test]
fn the_backward_gives_pytorchs_gradient_of_every_group() {
    for name in FIXTURES {
        let want = expected(name);
        let model = load(name);
        let view = View {
            camera: Camera::look_at([0.0, 0.0, -4.0], [0.0; 3], [0.0, -1.0, 0.0], 0.8, 16, 16)
                .unwrap(),
            time: want["time"][0] as f64,
        };
        let forward = model.forward(&view).unwrap();
        let mut grads = GaussianSet::zero_grads(model.len(), 3);
        grads.means.copy_from_slice(&want["grad_means"]);
        grads.log_scales.copy_from_slice(&want["grad_log_scales"]);
        grads.quats.copy_from_slice(&want["grad_quats"]);
        grads
            .opacity_logits
            .copy_from_slice(&want["grad_opacity_logits"]);
        grads.sh_dc.copy_from_slice(&want["grad_sh_dc"]);
        grads.sh_rest.copy_from_slice(&want["grad_sh_rest"]);
        let trained = [true; 9];
        let mut out: Vec<Vec<f32>> = model.group_lens().iter().map(|&n| vec![0.0; n]).collect();
        model
            .backward(&view, forward.tape, &grads, &trained, &mut out)
            .unwrap();
        let mut deform_want = Vec::new();
        for (tensor, _) in model.net().tensors() {
            deform_want.extend_from_slice(&want[&format!("d_deform.{tensor}")]);
        }
        let mut time_net_want = want["d_time_net.weight"].clone();
        time_net_want.extend_from_slice(&want["d_time_net.bias"]);
        let wanted: [(usize, Vec<f32>); 9] = [
            (group::PSEUDOMESH, want["d_pseudomesh"].clone()),
            (group::ALPHA, want["d_alpha"].clone()),
            (group::SCALE, want["d_attached_scale"].clone()),
            (group::ROTATION, want["d_attached_rotation"].clone()),
            (group::OPACITY, want["d_attached_opacity"].clone()),
            (group::DC, want["d_attached_features_dc"].clone()),
            (group::REST, want["d_attached_features_rest"].clone()),
            (group::DEFORM, deform_want),
            (group::TIME_NET, time_net_want),
        ];
        for (g, values) in wanted {
            let e = relative(&values, &out[g]);
            assert!(
                e < 2e-4,
                "{name}: gradient of {} differs by {e}",
                GROUP_NAMES[g]
            );
        }
    }
}

#[test]
fn broken_or_foreign_checkpoints_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let copy = dir.path().join("model");
    gs_stylize::test_support::copy_dir(&fixture("dmiso_small"), &copy);
    let files = AuthorsFiles::find(&copy, Some("best")).unwrap();
    // Truncated deformation network.
    let bytes = std::fs::read(&files.deform).unwrap();
    std::fs::write(&files.deform, &bytes[..bytes.len() / 2]).unwrap();
    let e = read_authors(&files, &Device::Cpu).unwrap_err();
    assert!(matches!(e, DmisoFileError::Checkpoint { .. }), "{e}");
    assert!(e.to_string().contains("deform.pth"), "{e}");
    // A foreign file: the time network's checkpoint in place of the deformation network's.
    std::fs::copy(&files.time_net, &files.deform).unwrap();
    let e = read_authors(&files, &Device::Cpu).unwrap_err().to_string();
    assert!(
        e.contains("deform.pth") && e.contains("timenet.0.weight"),
        "{e}"
    );
    // A network of another shape: the zero-bias fixture's (width 16) with this model.
    std::fs::copy(
        fixture("dmiso_zero_bias").join("time_net/iteration_best/deform.pth"),
        &files.time_net,
    )
    .unwrap();
    gs_stylize::test_support::copy_dir(
        &fixture("dmiso_zero_bias").join("deform"),
        &copy.join("deform"),
    );
    let e = read_authors(&files, &Device::Cpu).unwrap();
    assert_eq!(
        e.net().width,
        16,
        "a narrower network of the right shapes loads"
    );
    // The zero-bias model's parameters with this model's PLY: two models.
    std::fs::copy(
        fixture("dmiso_zero_bias").join("point_cloud/iteration_best/model_params.pt"),
        &files.params,
    )
    .unwrap();
    let e = read_authors(&files, &Device::Cpu).unwrap_err().to_string();
    assert!(
        e.contains("point_cloud.ply") && e.contains("two models"),
        "{e}"
    );
    // No such iteration.
    let e = AuthorsFiles::find(&copy, Some("7000"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("iteration_7000"), "{e}");
}
