//! COLMAP loading: sparse models written by the test in the text and binary layouts of
//! COLMAP's `read_write_model.py`, cameras, projection, downscaling, extent and errors.

mod common;

use std::path::Path;

use base_3dgs::dataset::colmap::{self, read_sparse_model};
use base_3dgs::dataset::{Background, DatasetError, LoadOptions};
use common::TempDir;
use gs_stylize::test_support::copy_dir;

const W: u32 = 16;
const H: u32 = 12;

struct Cam {
    id: i32,
    model: &'static str,
    model_id: i32,
    params: Vec<f64>,
}

struct Img {
    id: i32,
    q: [f64; 4],
    t: [f64; 3],
    camera: i32,
    name: &'static str,
}

/// Two cameras (PINHOLE, SIMPLE_PINHOLE) and three images listed out of name order, the
/// first at the origin looking along +z, the others translated.
fn model() -> (Vec<Cam>, Vec<Img>) {
    let cams = vec![
        Cam {
            id: 1,
            model: "PINHOLE",
            model_id: 1,
            params: vec![20.0, 18.0, 8.0, 6.0],
        },
        Cam {
            id: 7,
            model: "SIMPLE_PINHOLE",
            model_id: 0,
            params: vec![15.0, 7.5, 6.5],
        },
    ];
    let s = std::f64::consts::FRAC_1_SQRT_2;
    let imgs = vec![
        Img {
            id: 3,
            q: [1.0, 0.0, 0.0, 0.0],
            t: [0.0, 0.0, 2.0],
            camera: 1,
            name: "b.png",
        },
        Img {
            id: 1,
            q: [1.0, 0.0, 0.0, 0.0],
            t: [-1.0, 0.0, 2.0],
            camera: 7,
            name: "a.png",
        },
        Img {
            id: 2,
            q: [s, 0.0, s, 0.0],
            t: [0.0, -3.0, 2.0],
            camera: 1,
            name: "c.png",
        },
    ];
    (cams, imgs)
}

const POINTS: [([f64; 3], [u8; 3]); 2] = [
    ([0.5, -0.25, 3.0], [255, 0, 10]),
    ([1.0, 2.0, 3.0], [1, 2, 3]),
];

fn write_text(dir: &Path, cams: &[Cam], imgs: &[Img]) {
    std::fs::create_dir_all(dir).unwrap();
    let mut s =
        String::from("# Camera list with one line of data per camera:\n# Number of cameras: 2\n");
    for c in cams {
        let params: Vec<String> = c.params.iter().map(|p| p.to_string()).collect();
        s += &format!("{} {} {W} {H} {}\n", c.id, c.model, params.join(" "));
    }
    std::fs::write(dir.join("cameras.txt"), s).unwrap();
    let mut s = String::from("# Image list with two lines of data per image:\n\n");
    for (k, i) in imgs.iter().enumerate() {
        s += &format!(
            "{} {} {} {} {} {} {} {} {} {}\n",
            i.id, i.q[0], i.q[1], i.q[2], i.q[3], i.t[0], i.t[1], i.t[2], i.camera, i.name
        );
        // The 2D points line; empty for the second image, as COLMAP writes it.
        s += if k == 1 {
            "\n"
        } else {
            "1.5 2.5 -1 3.0 4.0 1\n"
        };
    }
    std::fs::write(dir.join("images.txt"), s).unwrap();
    let mut s = String::from("# 3D point list\n");
    for (k, (p, c)) in POINTS.iter().enumerate() {
        s += &format!(
            "{} {} {} {} {} {} {} 0.5 1 0 3 0\n",
            k + 1,
            p[0],
            p[1],
            p[2],
            c[0],
            c[1],
            c[2]
        );
    }
    std::fs::write(dir.join("points3D.txt"), s).unwrap();
}

fn write_binary(dir: &Path, cams: &[Cam], imgs: &[Img]) {
    std::fs::create_dir_all(dir).unwrap();
    let mut b = Vec::new();
    b.extend((cams.len() as u64).to_le_bytes());
    for c in cams {
        b.extend(c.id.to_le_bytes());
        b.extend(c.model_id.to_le_bytes());
        b.extend((W as u64).to_le_bytes());
        b.extend((H as u64).to_le_bytes());
        c.params.iter().for_each(|p| b.extend(p.to_le_bytes()));
    }
    std::fs::write(dir.join("cameras.bin"), b).unwrap();
    let mut b = Vec::new();
    b.extend((imgs.len() as u64).to_le_bytes());
    for i in imgs {
        b.extend(i.id.to_le_bytes());
        i.q.iter()
            .chain(&i.t)
            .for_each(|v| b.extend(v.to_le_bytes()));
        b.extend(i.camera.to_le_bytes());
        b.extend(i.name.as_bytes());
        b.push(0);
        b.extend(2u64.to_le_bytes());
        for (x, y, id) in [(1.5f64, 2.5f64, -1i64), (3.0, 4.0, 1)] {
            b.extend(x.to_le_bytes());
            b.extend(y.to_le_bytes());
            b.extend(id.to_le_bytes());
        }
    }
    std::fs::write(dir.join("images.bin"), b).unwrap();
    let mut b = Vec::new();
    b.extend((POINTS.len() as u64).to_le_bytes());
    for (k, (p, c)) in POINTS.iter().enumerate() {
        b.extend((k as u64 + 1).to_le_bytes());
        p.iter().for_each(|v| b.extend(v.to_le_bytes()));
        b.extend(c);
        b.extend(0.5f64.to_le_bytes());
        b.extend(1u64.to_le_bytes());
        b.extend(3i32.to_le_bytes());
        b.extend(0i32.to_le_bytes());
    }
    std::fs::write(dir.join("points3D.bin"), b).unwrap();
}

fn write_images(dir: &Path, width: u32, height: u32) {
    std::fs::create_dir_all(dir).unwrap();
    for name in ["a.png", "b.png", "c.png"] {
        let img = image::RgbImage::from_fn(width, height, |x, y| {
            image::Rgb([(10 * x) as u8, (10 * y) as u8, 77])
        });
        img.save(dir.join(name)).unwrap();
    }
}

/// A scene with the text model (`binary` false) or the binary one, and its images.
fn scene(name: &str, binary: bool) -> TempDir {
    let dir = TempDir::new(name);
    let (cams, imgs) = model();
    let sparse = dir.path().join("sparse/0");
    if binary {
        write_binary(&sparse, &cams, &imgs);
    } else {
        write_text(&sparse, &cams, &imgs);
    }
    write_images(&dir.path().join("images"), W, H);
    dir
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-9
}

#[test]
fn text_and_binary_models_load_to_the_same_scene() {
    let txt = scene("colmap-txt", false);
    let bin = scene("colmap-bin", true);
    let a = read_sparse_model(&txt.path().join("sparse/0")).unwrap();
    let b = read_sparse_model(&bin.path().join("sparse/0")).unwrap();
    assert_eq!(a.cameras, b.cameras);
    assert_eq!(a.images, b.images);
    assert_eq!(a.points, b.points);
    assert_eq!(a.cameras[1].params, [15.0, 7.5, 6.5]);
    assert_eq!(a.images[1].name, "a.png");
    assert_eq!(a.points.colors[0], [255, 0, 10]);

    let options = LoadOptions::default();
    let da = colmap::load(txt.path(), &options).unwrap();
    let db = colmap::load(bin.path(), &options).unwrap();
    assert_eq!(da.views, db.views);
    assert_eq!(da.images, db.images);
    assert_eq!(da.points, db.points);
    // Sorted by image name, as 3DGS does.
    let names: Vec<_> = da
        .image_paths
        .iter()
        .map(|p| p.file_name().unwrap().to_owned())
        .collect();
    assert_eq!(names, ["a.png", "b.png", "c.png"]);
    assert_eq!(
        da.images[0].pixel(3, 2),
        [30.0 / 255.0, 20.0 / 255.0, 77.0 / 255.0]
    );
    assert!(da.masks.iter().all(Option::is_none), "no alpha, no mask");
}

/// `image_undistorter` writes its model straight into `sparse/` (no `0/`): the same scene
/// loads from there; a `sparse/` holding no model is named with both places looked in.
#[test]
fn a_model_directly_in_sparse_loads_as_from_sparse_0() {
    let dir = scene("colmap-flat-sparse", false);
    let nested = colmap::load(dir.path(), &LoadOptions::default()).unwrap();
    let sparse = dir.path().join("sparse");
    for entry in std::fs::read_dir(sparse.join("0")).unwrap() {
        let path = entry.unwrap().path();
        std::fs::rename(&path, sparse.join(path.file_name().unwrap())).unwrap();
    }
    std::fs::remove_dir(sparse.join("0")).unwrap();
    let flat = colmap::load(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(flat.views, nested.views);
    assert_eq!(flat.image_paths, nested.image_paths);
    for name in ["cameras.txt", "images.txt", "points3D.txt"] {
        std::fs::remove_file(sparse.join(name)).unwrap();
    }
    let e = colmap::load(dir.path(), &LoadOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("sparse/0") && e.contains("cameras.bin"), "{e}");
}

#[test]
fn a_known_point_projects_to_the_expected_pixel() {
    let dir = scene("colmap-project", true);
    let data = colmap::load(dir.path(), &LoadOptions::default()).unwrap();
    // b.png: PINHOLE fx 20 fy 18 cx 8 cy 6, identity rotation, t = (0, 0, 2). The point
    // (0.5, -0.25, 3) is (0.5, -0.25, 5) in the camera: u = 20 * 0.1 + 8, v = 18 * -0.05 + 6.
    let ([u, v], depth) = data.views[1].camera.project([0.5, -0.25, 3.0]).unwrap();
    assert!(
        close(u, 10.0) && close(v, 5.1) && close(depth, 5.0),
        "{u} {v} {depth}"
    );
    // a.png: SIMPLE_PINHOLE f 15, t = (-1, 0, 2): the point is at (-0.5, -0.25, 5).
    let ([u, v], _) = data.views[0].camera.project([0.5, -0.25, 3.0]).unwrap();
    assert!(close(u, 7.5 - 1.5) && close(v, 6.5 - 0.75), "{u} {v}");
    // c.png: R = rotation of 90 degrees about y, which maps world (-1, 0, 0) to (0, 0, 1).
    let ([u, v], depth) = data.views[2].camera.project([-1.0, 0.0, 0.0]).unwrap();
    assert!(
        close(u, 8.0) && close(v, 6.0 - 18.0 * 3.0 / 3.0) && close(depth, 3.0),
        "{u} {v}"
    );
}

#[test]
fn extent_matches_a_hand_computation() {
    let dir = scene("colmap-extent", false);
    let data = colmap::load(dir.path(), &LoadOptions::default()).unwrap();
    // Centres -R^T t: a (1, 0, -2), b (0, 0, -2), c: R^T (0, -3, 2) = (-2, -3, 0), negated
    // (2, 3, 0). Mean (1, 1, -4/3); squared distances 13/9, 22/9 and 61/9.
    let want = 1.1 * 61f64.sqrt() / 3.0;
    assert!(close(data.extent, want), "{} {want}", data.extent);
}

#[test]
fn downscale_2_halves_intrinsics_and_image_sizes() {
    let dir = scene("colmap-downscale", true);
    let full = colmap::load(dir.path(), &LoadOptions::default()).unwrap();
    let options = LoadOptions {
        background: Background::White,
        downscale: 2,
        ..LoadOptions::default()
    };
    let check = |data: &base_3dgs::dataset::Dataset| {
        for (half, full) in data.views.iter().zip(&full.views) {
            let (h, f) = (&half.camera, &full.camera);
            assert_eq!((h.width, h.height), (W / 2, H / 2));
            assert!(close(h.fx, f.fx / 2.0) && close(h.fy, f.fy / 2.0));
            assert!(close(h.cx, f.cx / 2.0) && close(h.cy, f.cy / 2.0));
            assert_eq!(h.rotation, f.rotation);
        }
        for img in &data.images {
            assert_eq!((img.width, img.height), (W / 2, H / 2));
        }
    };
    // No images_2/: the full images are resized.
    let resized = colmap::load(dir.path(), &options).unwrap();
    check(&resized);
    common::same_views(&resized, &colmap::views(dir.path(), &options).unwrap());
    assert!(resized.image_paths[0].parent().unwrap().ends_with("images"));
    // Blue is 77 everywhere and stays so; red is a ramp that the resize averages.
    let px = resized.images[0].pixel(1, 1);
    assert!((px[2] - 77.0 / 255.0).abs() < 1e-3 && px[0] > 0.0, "{px:?}");

    // With images_2/ present, its images are used as they are.
    write_images(&dir.path().join("images_2"), W / 2, H / 2);
    let prescaled = colmap::load(dir.path(), &options).unwrap();
    check(&prescaled);
    common::same_views(&prescaled, &colmap::views(dir.path(), &options).unwrap());
    assert!(prescaled.image_paths[0]
        .parent()
        .unwrap()
        .ends_with("images_2"));
    assert_eq!(
        prescaled.images[0].pixel(3, 2),
        [30.0 / 255.0, 20.0 / 255.0, 77.0 / 255.0]
    );

    // A pre-downscaled image more than a pixel off is refused.
    write_images(&dir.path().join("images_2"), W / 2 + 2, H / 2);
    let e = colmap::load(dir.path(), &options).unwrap_err();
    assert!(
        e.to_string().contains("10x6") && e.to_string().contains("8x6"),
        "{e}"
    );
}

#[test]
fn distorted_cameras_are_undistorted_and_cropped_and_other_models_refused() {
    let dir = scene("colmap-radial", false);
    let path = dir.path().join("sparse/0/cameras.txt");
    std::fs::write(
        &path,
        format!("1 PINHOLE {W} {H} 20 18 8 6\n7 SIMPLE_RADIAL {W} {H} 15 7.5 6.5 -0.05\n"),
    )
    .unwrap();
    let data = colmap::load(dir.path(), &LoadOptions::default()).unwrap();
    common::same_views(
        &data,
        &colmap::views(dir.path(), &LoadOptions::default()).unwrap(),
    );
    // a.png is camera 7's: barrel distortion undone, its border bulges outwards, so the
    // pinhole picture of only valid pixels sees more than the same focal length would (a shorter
    // one) and loses its last column and row (OpenCV's rounding at alpha 0); b.png and c.png are
    // the pinhole camera's.
    let a = &data.views[0].camera;
    assert_eq!((a.width, a.height), (W - 1, H - 1));
    assert!(a.fx < 15.0 && a.fy < 15.0, "{} {}", a.fx, a.fy);
    assert_eq!(
        (data.images[0].width, data.images[0].height),
        (a.width, a.height)
    );
    assert_eq!(data.undistorted[0].as_ref().unwrap().model, "SIMPLE_RADIAL");
    assert!(data.undistorted[1].is_none() && data.undistorted[2].is_none());
    let b = &data.views[1].camera;
    assert_eq!([b.fx, b.fy, b.cx, b.cy], [20.0, 18.0, 8.0, 6.0]);
    let summary = data.undistortion_summary();
    assert_eq!(summary.len(), 1, "{summary:?}");
    assert!(
        summary[0].starts_with("1 view(s): SIMPLE_RADIAL 16x12 undistorted and cropped to"),
        "{summary:?}"
    );

    let bin = scene("colmap-radial-bin", true);
    let (mut cams, imgs) = model();
    cams[0].model_id = 4;
    cams[0].params = vec![20.0, 18.0, 8.0, 6.0, 0.1, 0.0, 0.01, 0.0];
    write_binary(&bin.path().join("sparse/0"), &cams, &imgs);
    let data = colmap::load(bin.path(), &LoadOptions::default()).unwrap();
    assert_eq!(data.undistorted[1].as_ref().unwrap().model, "OPENCV");

    std::fs::write(
        &path,
        format!("1 PINHOLE {W} {H} 20 18 8 6\n7 FOV {W} {H} 15 15 7.5 6.5 0.9\n"),
    )
    .unwrap();
    let e = colmap::load(dir.path(), &LoadOptions::default()).unwrap_err();
    assert!(
        matches!(
            &e,
            DatasetError::UnsupportedCameraModel { camera_id: 7, .. }
        ),
        "{e}"
    );
    let message = e.to_string();
    assert!(
        message.contains("FOV")
            && message.contains("cameras.txt")
            && message.contains("image_undistorter"),
        "{message}"
    );
}

/// The undistorted normalized point of distorted `(xd, yd)`, solved to convergence by Newton's
/// method (independent of the reader's OpenCV-style iteration).
fn undistort_exactly(lens: Lens, xd: f64, yd: f64) -> (f64, f64) {
    let (mut x, mut y) = (xd, yd);
    for _ in 0..100 {
        let h = 1e-7;
        let (fx, fy) = distort(lens, x, y);
        let (ax, ay) = distort(lens, x + h, y);
        let (bx, by) = distort(lens, x, y + h);
        let j = [
            [(ax - fx) / h, (bx - fx) / h],
            [(ay - fy) / h, (by - fy) / h],
        ];
        let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
        let (rx, ry) = (fx - xd, fy - yd);
        x -= (j[1][1] * rx - j[0][1] * ry) / det;
        y -= (j[0][0] * ry - j[1][0] * rx) / det;
    }
    (x, y)
}

#[derive(Clone, Copy)]
enum Lens {
    Radial(f64, f64),
    Fisheye([f64; 4]),
}

fn distort(lens: Lens, x: f64, y: f64) -> (f64, f64) {
    match lens {
        Lens::Radial(k1, k2) => {
            let r2 = x * x + y * y;
            let f = 1.0 + k1 * r2 + k2 * r2 * r2;
            (x * f, y * f)
        }
        Lens::Fisheye(k) => {
            let r = (x * x + y * y).sqrt();
            let t = r.atan();
            let t2 = t * t;
            let td = t * (1.0 + k[0] * t2 + k[1] * t2 * t2 + k[2] * t2.powi(3) + k[3] * t2.powi(4));
            (x * td / r, y * td / r)
        }
    }
}

/// A smooth pattern over undistorted normalized coordinates.
fn pattern(x: f64, y: f64) -> [f64; 3] {
    [
        0.5 + 0.4 * (3.0 * x + 2.0 * y).sin(),
        0.5 + 0.4 * (2.5 * y - 1.5 * x).cos(),
        0.5 + 0.3 * (4.0 * x * y).sin(),
    ]
}

/// A one-image COLMAP scene whose picture is `pattern` seen through `lens`: each stored pixel
/// holds the pattern at the undistorted point of its ray. After loading, every pixel of the
/// undistorted picture must hold the pattern at its own pinhole ray.
#[test]
fn undistorted_pictures_show_what_a_pinhole_camera_sees() {
    let (w, h) = (72u32, 54u32);
    let cases = [
        (
            "SIMPLE_RADIAL",
            "50 35.5 26.0 -0.12",
            Lens::Radial(-0.12, 0.0),
        ),
        (
            "RADIAL",
            "48 36.2 27.3 0.08 -0.02",
            Lens::Radial(0.08, -0.02),
        ),
        (
            "OPENCV_FISHEYE",
            "40 41 35.0 26.5 0.05 -0.01 0.002 0.0",
            Lens::Fisheye([0.05, -0.01, 0.002, 0.0]),
        ),
    ];
    for (model, params, lens) in cases {
        let dir = TempDir::new("colmap-undistort-content");
        let sparse = dir.path().join("sparse/0");
        std::fs::create_dir_all(&sparse).unwrap();
        std::fs::write(
            sparse.join("cameras.txt"),
            format!("1 {model} {w} {h} {params}\n"),
        )
        .unwrap();
        std::fs::write(sparse.join("images.txt"), "1 1 0 0 0 0 0 3 1 a.png\n\n").unwrap();
        std::fs::write(sparse.join("points3D.txt"), "").unwrap();
        let p: Vec<f64> = params.split(' ').map(|v| v.parse().unwrap()).collect();
        let [fx, fy, cx, cy] = if p.len() == 4 || p.len() == 5 {
            [p[0], p[0], p[1], p[2]]
        } else {
            [p[0], p[1], p[2], p[3]]
        };
        let picture = image::RgbImage::from_fn(w, h, |u, v| {
            let (x, y) =
                undistort_exactly(lens, (f64::from(u) - cx) / fx, (f64::from(v) - cy) / fy);
            image::Rgb(pattern(x, y).map(|c| (c * 255.0).round() as u8))
        });
        std::fs::create_dir_all(dir.path().join("images")).unwrap();
        picture.save(dir.path().join("images/a.png")).unwrap();
        let options = LoadOptions {
            max_width: 0,
            ..LoadOptions::default()
        };
        let data = colmap::load(dir.path(), &options).unwrap();
        let camera = &data.views[0].camera;
        let image = &data.images[0];
        assert!(camera.width < w && camera.height < h, "{model}: cropped");
        let mut worst = 0.0f64;
        for j in 0..image.height {
            for i in 0..image.width {
                let x = (f64::from(i) - camera.cx) / camera.fx;
                let y = (f64::from(j) - camera.cy) / camera.fy;
                let want = pattern(x, y);
                let got = image.pixel(i, j);
                for c in 0..3 {
                    worst = worst.max((f64::from(got[c]) - want[c]).abs());
                }
            }
        }
        // Bilinear resampling of a smooth pattern stored in 8-bit levels.
        assert!(worst < 0.02, "{model}: worst {worst}");
    }
}

#[test]
fn a_dense_folder_from_image_undistorter_is_read_when_there_is_no_sparse() {
    let dir = TempDir::new("colmap-dense");
    let dense = dir.path().join("dense");
    let (cams, imgs) = model();
    write_binary(&dense.join("sparse"), &cams, &imgs);
    write_images(&dense.join("images"), W, H);
    std::fs::create_dir_all(dense.join("stereo")).unwrap();
    assert_eq!(
        base_3dgs::dataset::Layout::detect(dir.path()),
        Some(base_3dgs::dataset::Layout::Colmap)
    );
    let data = colmap::load(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(data.views.len(), 3);
    assert!(data.image_paths[0].starts_with(&dense));
    // A scene's own sparse/ wins over dense/, and over a transforms.json written from it.
    let theirs = scene("colmap-dense-own", true);
    std::fs::write(theirs.path().join("transforms.json"), r#"{"frames": []}"#).unwrap();
    assert_eq!(
        base_3dgs::dataset::Layout::detect(theirs.path()),
        Some(base_3dgs::dataset::Layout::Colmap)
    );
    write_binary(&theirs.path().join("dense/sparse"), &cams, &imgs[..1]);
    assert_eq!(
        colmap::load(theirs.path(), &LoadOptions::default())
            .unwrap()
            .views
            .len(),
        3
    );
}

#[test]
fn malformed_models_and_mismatched_images_are_clear_errors() {
    let dir = scene("colmap-errors", false);
    let sparse = dir.path().join("sparse/0");
    write_images(&dir.path().join("images"), W, H + 1);
    let e = colmap::load(dir.path(), &LoadOptions::default()).unwrap_err();
    let message = e.to_string();
    assert!(
        message.contains("a.png") && message.contains("16x13") && message.contains("16x12"),
        "{message}"
    );

    std::fs::write(sparse.join("cameras.txt"), "1 PINHOLE 16 12 20 18 8\n").unwrap();
    let e = read_sparse_model(&sparse).unwrap_err();
    assert!(
        e.to_string()
            .contains("cameras.txt: line 1: PINHOLE has 4 parameters, the line has 3"),
        "{e}"
    );
    std::fs::write(
        sparse.join("cameras.txt"),
        "1 PINHOLE 16 twelve 20 18 8 6\n",
    )
    .unwrap();
    let e = read_sparse_model(&sparse).unwrap_err();
    assert!(e.to_string().contains("HEIGHT is \"twelve\""), "{e}");

    let bin = scene("colmap-truncated", true);
    let images = bin.path().join("sparse/0/images.bin");
    let bytes = std::fs::read(&images).unwrap();
    std::fs::write(&images, &bytes[..bytes.len() - 5]).unwrap();
    let e = read_sparse_model(&bin.path().join("sparse/0")).unwrap_err();
    assert!(
        e.to_string().contains("images.bin") && e.to_string().contains("truncated"),
        "{e}"
    );

    std::fs::remove_file(&images).unwrap();
    let e = colmap::load(bin.path(), &LoadOptions::default()).unwrap_err();
    assert!(
        matches!(e, DatasetError::Missing { .. }) && e.to_string().contains("images.txt"),
        "{e}"
    );

    let empty = TempDir::new("colmap-empty");
    let e = colmap::load(empty.path(), &LoadOptions::default()).unwrap_err();
    assert!(e.to_string().contains("sparse"), "{e}");
}

/// A scene written by pycolmap (COLMAP's own writers, text and binary, with the rigs and frames
/// files new COLMAP adds; `scripts/make_colmap_fixture.py`): SIMPLE_RADIAL, OPENCV and PINHOLE
/// cameras. Poses, points and the undistorted cameras agree with pycolmap's and OpenCV's.
#[test]
fn a_scene_written_by_pycolmap_loads_in_both_formats() {
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/colmap_pycolmap");
    let expected: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fixture.join("expected.json")).unwrap())
            .unwrap();
    let floats = |v: &serde_json::Value| -> Vec<f64> {
        v.as_array()
            .unwrap()
            .iter()
            .flat_map(|x| match x.as_array() {
                Some(row) => row.iter().map(|y| y.as_f64().unwrap()).collect(),
                None => vec![x.as_f64().unwrap()],
            })
            .collect()
    };
    for sparse in ["sparse", "sparse_bin"] {
        let dir = TempDir::new("colmap-pycolmap");
        copy_dir(&fixture.join("images"), &dir.path().join("images"));
        copy_dir(&fixture.join(sparse), &dir.path().join("sparse"));
        let options = LoadOptions {
            max_width: 0,
            ..LoadOptions::default()
        };
        let data = colmap::load(dir.path(), &options).unwrap();
        let images = expected["images"].as_array().unwrap();
        assert_eq!(data.views.len(), images.len(), "{sparse}");
        for (k, want) in images.iter().enumerate() {
            let name = want["name"].as_str().unwrap();
            assert!(
                data.image_paths[k].ends_with(name),
                "{sparse}: sorted by name"
            );
            let camera = &data.views[k].camera;
            let rotation: Vec<f64> = camera.rotation.iter().flatten().copied().collect();
            for (got, want) in rotation.iter().zip(floats(&want["rotation"])) {
                assert!((got - want).abs() < 1e-12, "{sparse} {name}: rotation");
            }
            for (got, want) in camera.translation.iter().zip(floats(&want["translation"])) {
                assert!((got - want).abs() < 1e-12, "{sparse} {name}: translation");
            }
            let colmap_camera = expected["cameras"]
                .as_array()
                .unwrap()
                .iter()
                .find(|c| c["camera_id"] == want["camera_id"])
                .unwrap();
            let (k_want, size) = match colmap_camera["undistorted"].as_object() {
                Some(u) => {
                    let roi = floats(&u["roi"]);
                    let k = floats(&u["new_k"]);
                    (
                        [k[0], k[1], k[2] - roi[0], k[3] - roi[1]],
                        (roi[2] as u32, roi[3] as u32),
                    )
                }
                None => {
                    let p = floats(&colmap_camera["params"]);
                    let size = (
                        colmap_camera["width"].as_u64().unwrap() as u32,
                        colmap_camera["height"].as_u64().unwrap() as u32,
                    );
                    ([p[0], p[1], p[2], p[3]], size)
                }
            };
            let k_got = [camera.fx, camera.fy, camera.cx, camera.cy];
            for (got, want) in k_got.iter().zip(k_want) {
                assert!(
                    (got - want).abs() < 1e-9,
                    "{sparse} {name}: {k_got:?} vs {k_want:?}"
                );
            }
            assert_eq!((camera.width, camera.height), size, "{sparse} {name}");
            assert_eq!(
                (data.images[k].width, data.images[k].height),
                size,
                "{sparse} {name}"
            );
            assert_eq!(
                data.undistorted[k].is_some(),
                colmap_camera["undistorted"].is_object()
            );
        }
        let points = data.points.as_ref().unwrap();
        let want_points = expected["points3D"].as_array().unwrap();
        assert_eq!(points.positions.len(), want_points.len());
        for (k, want) in want_points.iter().enumerate() {
            assert_eq!(points.positions[k].to_vec(), floats(&want["xyz"]));
            let rgb: Vec<u8> = floats(&want["rgb"]).iter().map(|&v| v as u8).collect();
            assert_eq!(points.colors[k].to_vec(), rgb);
        }
    }
}
