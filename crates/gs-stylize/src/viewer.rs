//! `viewer.html`: one file that shows Gaussians in a browser with no network and no server
//! (WebGL2, the projection, SH colour and compositing of gs-core's rasterizer, the depth sort
//! in a worker), with orbit, pan and zoom, the run's cameras to jump between, and a style
//! slider from the base model (0) to the stylized one (1) that blends every parameter as
//! `interpolate` does.
//!
//! The page (`viewer/viewer.html`, our own code) reads its scene from a JSON block: the
//! Gaussians as little-endian `f32` arrays in base64, the cameras, the background. Opened with
//! `#camera=K&t=T&clean` it draws camera K at slider T at the camera's own size, without its
//! panel (what the tests screenshot).

use std::path::{Path, PathBuf};

use crate::StylizeError;

mod compact;

use gs_core::{Camera, GaussianSet};
use serde_json::json;

/// The page, with `/*SCENE*/` where the scene's JSON goes.
const PAGE: &str = include_str!("viewer/viewer.html");

/// The file name every run writes its viewer to.
pub const VIEWER_HTML: &str = "viewer.html";

/// What a viewer shows.
pub struct ViewerScene<'a> {
    /// The page's title line (the run, the style).
    pub title: String,
    /// The Gaussians, still or animated.
    pub shown: Shown<'a>,
    /// Cameras to jump between, with their names; the first is shown first.
    pub cameras: Vec<(String, Camera)>,
    /// The colour behind the Gaussians, linear RGB in `[0, 1]`.
    pub background: [f32; 3],
}

/// The Gaussians of a page.
pub enum Shown<'a> {
    /// The same Gaussians at every time: the base model (slider 0) and, for the slider, the
    /// same Gaussians stylized (slider 1).
    Still {
        /// The base model's Gaussians.
        base: &'a GaussianSet,
        /// The stylized model's.
        stylized: Option<&'a GaussianSet>,
    },
    /// Gaussians that change with time (a video's frames), made in the page.
    Animated(Box<Animation>),
}

/// An animated scene: models' parameter groups and the modality's script that makes a frame's
/// Gaussians from them (the page blends two models' groups linearly first, as `interpolate`
/// blends two models of one modality).
pub struct Animation {
    /// JavaScript defining `frameAt(groups, frame)`: from a model's groups (by name, as
    /// `Float32Array`s) the Gaussians of frame `frame` as `{means, quats, log_scales,
    /// opacity_logits, sh}` `Float32Array`s of all `count` Gaussians in [`GaussianSet`]'s layout
    /// (`sh` all coefficients of a Gaussian together), those not drawn with a zero quaternion.
    pub script: &'static str,
    /// Each model's groups, `(name, values)`: the base model's, then the stylized one's.
    pub models: Vec<Vec<(String, Vec<f32>)>>,
    /// Frames of the time slider (`frameAt`'s `frame` is `0..frames`).
    pub frames: usize,
    /// Gaussians of a frame (drawn or not).
    pub count: usize,
    /// SH degree of a frame's Gaussians.
    pub degree: usize,
    /// The frame the pivot is found in, as gs-core Gaussians (those drawn).
    pub first: GaussianSet,
}

/// The page's script of [`Animation::snapshots`].
const SNAPSHOT_SCRIPT: &str = include_str!("viewer/snapshots.js");

impl Animation {
    /// Gaussians at a few times, a snapshot a frame of the page's time slider (for a model
    /// whose Gaussians the page cannot make itself), with the same times of the stylized model
    /// for the style slider (blended linearly in the page; each quaternion first turned to the
    /// base's hemisphere, as `interpolate` does). Every snapshot must have the first's count and
    /// SH degree.
    pub fn snapshots(
        base: &[GaussianSet],
        stylized: Option<&[GaussianSet]>,
    ) -> Result<Box<Self>, String> {
        let first = base.first().ok_or("no snapshot to show")?;
        let shape = (first.len(), first.sh_degree());
        let mut all = base.iter().chain(stylized.into_iter().flatten());
        if let Some(other) = all.find(|s| (s.len(), s.sh_degree()) != shape) {
            return Err(format!(
                "snapshots of {} and {} Gaussians (SH degree {} and {}): a page's frames show \
                 the same Gaussians",
                shape.0,
                other.len(),
                shape.1,
                other.sh_degree()
            ));
        }
        if stylized.is_some_and(|s| s.len() != base.len()) {
            return Err("the stylized model has another number of snapshots".into());
        }
        let groups = |sets: &[GaussianSet], align: Option<&[GaussianSet]>| {
            let mut out: Vec<(String, Vec<f32>)> = Vec::new();
            let gather = |f: &dyn Fn(usize, &GaussianSet) -> Vec<f32>| -> Vec<f32> {
                sets.iter().enumerate().flat_map(|(k, s)| f(k, s)).collect()
            };
            out.push(("frames".into(), vec![sets.len() as f32]));
            out.push(("means".into(), gather(&|_, s| s.means.clone())));
            out.push((
                "quats".into(),
                gather(&|k, s| aligned_quats(&s.quats, align.map(|a| a[k].quats.as_slice()))),
            ));
            out.push(("log_scales".into(), gather(&|_, s| s.log_scales.clone())));
            out.push((
                "opacity_logits".into(),
                gather(&|_, s| s.opacity_logits.clone()),
            ));
            out.push(("sh".into(), gather(&|_, s| s.sh())));
            out
        };
        let mut models = vec![groups(base, None)];
        if let Some(stylized) = stylized {
            models.push(groups(stylized, Some(base)));
        }
        Ok(Box::new(Self {
            script: SNAPSHOT_SCRIPT,
            models,
            frames: base.len(),
            count: shape.0,
            degree: shape.1,
            first: first.clone(),
        }))
    }
}

/// The most Gaussians a still page holds (in the compact form above [`COMPACT_ABOVE`]: about
/// 165 bytes a Gaussian with both models, 165 MB at this size): a larger scene's run writes no
/// viewer and says so.
pub const MAX_GAUSSIANS: usize = 1_000_000;

/// Still pages of more Gaussians than this hold them in the compact form ([`compact`]); smaller
/// ones hold every value as a 32-bit float (about 630 bytes a Gaussian with both models).
pub const COMPACT_ABOVE: usize = 200_000;

/// The most Gaussians an animated page holds (its models' parameters as 32-bit floats).
pub const MAX_ANIMATED_GAUSSIANS: usize = 300_000;

/// Writes `scene`'s viewer to `path` (through a temporary name), its Gaussians in the compact
/// form when there are more than [`COMPACT_ABOVE`]; an error names what cannot be shown (no
/// camera, models of different Gaussians) or the file.
pub fn write_viewer(path: &Path, scene: &ViewerScene) -> Result<(), StylizeError> {
    let compact = match &scene.shown {
        Shown::Still { base, .. } => base.len() > COMPACT_ABOVE,
        Shown::Animated(_) => false,
    };
    write_viewer_as(path, scene, compact)
}

/// [`write_viewer`], a still scene's Gaussians in the compact form or not as `compact` says.
pub fn write_viewer_as(
    path: &Path,
    scene: &ViewerScene,
    compact: bool,
) -> Result<(), StylizeError> {
    let page = viewer_page(scene, compact).map_err(StylizeError::Input)?;
    crate::outputs::write_atomic(path, page.as_bytes())
}

/// The cameras of `views` for a viewer, named by their pictures' file names (`labels`, when
/// given one a view) or `view N`.
pub fn named_cameras(views: &[gs_core::model::View], labels: &[PathBuf]) -> Vec<(String, Camera)> {
    views
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let name = labels
                .get(i)
                .and_then(|p| p.file_name())
                .map_or_else(|| format!("view {i}"), |n| n.to_string_lossy().into_owned());
            (name, v.camera.clone())
        })
        .collect()
}

/// The page of `scene`, a still scene's Gaussians in the compact form when `compact`.
pub fn viewer_page(scene: &ViewerScene, compact: bool) -> Result<String, String> {
    if scene.cameras.is_empty() {
        return Err("a viewer needs at least one camera".into());
    }
    let first = &scene.cameras[0].1;
    let mut json = json!({
        "title": scene.title,
        "cameras": scene.cameras.iter().map(|(name, c)| json!({
            "name": name, "rotation": c.rotation, "translation": c.translation,
            "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy,
            "width": c.width, "height": c.height,
        })).collect::<Vec<_>>(),
        "background": scene.background,
    });
    let mut script = "";
    match &scene.shown {
        Shown::Still { base, stylized } => {
            let mut models = vec![model_json(base, None, compact)];
            if let Some(stylized) = stylized {
                if (stylized.len(), stylized.sh_degree()) != (base.len(), base.sh_degree()) {
                    return Err(format!(
                        "the stylized model has {} Gaussians of SH degree {}, the base {} of \
                         degree {}: a viewer's slider blends the same Gaussians",
                        stylized.len(),
                        stylized.sh_degree(),
                        base.len(),
                        base.sh_degree()
                    ));
                }
                models.push(model_json(stylized, Some(&base.quats), compact));
            }
            json["count"] = base.len().into();
            json["degree"] = base.sh_degree().into();
            json["models"] = models.into();
            json["pivot_distance"] = pivot_distance(base, first).into();
        }
        Shown::Animated(animation) => {
            let shapes: Vec<Vec<(&str, usize)>> = animation
                .models
                .iter()
                .map(|m| m.iter().map(|(name, v)| (name.as_str(), v.len())).collect())
                .collect();
            if shapes.windows(2).any(|w| w[0] != w[1]) {
                return Err(
                    "the stylized model's parameter groups differ from the base's: a viewer's \
                     slider blends two models of the same Gaussians"
                        .into(),
                );
            }
            let models: Vec<serde_json::Value> = animation
                .models
                .iter()
                .map(|m| {
                    m.iter()
                        .map(|(name, values)| (name.clone(), base64_f32(values).into()))
                        .collect::<serde_json::Map<_, _>>()
                        .into()
                })
                .collect();
            json["count"] = animation.count.into();
            json["degree"] = animation.degree.into();
            json["animation"] = json!({"frames": animation.frames, "models": models});
            json["pivot_distance"] = pivot_distance(&animation.first, first).into();
            script = animation.script;
        }
    }
    // In a <script> block "</" must not appear; "<\/" is the same JSON string.
    let text = json.to_string().replace("</", "<\\/");
    if script.contains("</") {
        return Err("an animation script may not hold \"</\"".into());
    }
    Ok(PAGE
        .replacen("/*SCENE*/", &text, 1)
        .replacen("/*ANIMATION*/", script, 1))
}

/// The scene the viewer page at `path` holds (its JSON block), as [`viewer_page`] wrote it.
pub fn read_scene(path: &Path) -> Result<serde_json::Value, String> {
    let page = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let opening = "<script type=\"application/json\" id=\"scene\">";
    let start = page
        .find(opening)
        .map(|at| at + opening.len())
        .ok_or_else(|| format!("{}: not a viewer page (no scene block)", path.display()))?;
    let end = page[start..]
        .find("</script>")
        .map(|len| start + len)
        .ok_or_else(|| format!("{}: the scene block does not end", path.display()))?;
    serde_json::from_str(&page[start..end]).map_err(|e| format!("{}: {e}", path.display()))
}

/// `quats`, each turned to the hemisphere of the one of `align_to` it blends with (the same
/// rotation; `interpolate`'s rule).
fn aligned_quats(quats: &[f32], align_to: Option<&[f32]>) -> Vec<f32> {
    let mut quats = quats.to_vec();
    if let Some(other) = align_to {
        for (q, o) in quats.chunks_exact_mut(4).zip(other.chunks_exact(4)) {
            if q.iter().zip(o).map(|(a, b)| a * b).sum::<f32>() < 0.0 {
                q.iter_mut().for_each(|v| *v = -*v);
            }
        }
    }
    quats
}

/// One model's arrays for the page (as floats, or in the compact form); with `align_to`, its
/// quaternions turned as [`aligned_quats`] turns them.
fn model_json(set: &GaussianSet, align_to: Option<&[f32]>, compact: bool) -> serde_json::Value {
    let quats = aligned_quats(&set.quats, align_to);
    if compact {
        return compact::compact_json(set, &quats);
    }
    json!({
        "means": base64_f32(&set.means),
        "quats": base64_f32(&quats),
        "log_scales": base64_f32(&set.log_scales),
        "opacity_logits": base64_f32(&set.opacity_logits),
        "sh": base64_f32(&set.sh()),
    })
}

/// The median camera depth of the Gaussians' centres in `camera`: the distance the page orbits
/// at (1 when none is in front).
fn pivot_distance(set: &GaussianSet, camera: &Camera) -> f64 {
    let mut depths: Vec<f64> = set
        .means
        .chunks_exact(3)
        .map(|p| {
            let r = camera.rotation[2];
            r[0] * f64::from(p[0])
                + r[1] * f64::from(p[1])
                + r[2] * f64::from(p[2])
                + camera.translation[2]
        })
        .filter(|z| z.is_finite() && *z > 0.0)
        .collect();
    if depths.is_empty() {
        return 1.0;
    }
    depths.sort_by(f64::total_cmp);
    depths[depths.len() / 2]
}

/// `values` as little-endian bytes in standard base64 (with padding).
fn base64_f32(values: &[f32]) -> String {
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    base64(&bytes)
}

/// Standard base64 (RFC 4648, `+/`, `=` padding) of `bytes`.
fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = u32::from(b[0]) << 16 | u32::from(b[1]) << 8 | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(ALPHABET[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_is_rfc_4648() {
        // RFC 4648's test vectors.
        for (plain, encoded) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(plain.as_bytes()), encoded);
        }
        assert_eq!(base64(&[0xfb, 0xff]), "+/8=");
    }

    #[test]
    fn a_page_holds_its_scene_and_refuses_other_gaussians() {
        let set = GaussianSet::zeros(3, 1);
        let camera =
            Camera::look_at([0.0, 0.0, -3.0], [0.0; 3], [0.0, -1.0, 0.0], 1.0, 8, 6).unwrap();
        let scene = ViewerScene {
            title: "a </script> title".into(),
            shown: Shown::Still {
                base: &set,
                stylized: Some(&set),
            },
            cameras: vec![("view 0".into(), camera.clone())],
            background: [1.0, 1.0, 1.0],
        };
        let page = viewer_page(&scene, false).unwrap();
        assert!(!page.contains("/*SCENE*/"));
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("viewer.html");
        std::fs::write(&path, &page).unwrap();
        let read = read_scene(&path).unwrap();
        assert_eq!(read["title"], "a </script> title");
        assert_eq!(read["count"], 3);
        assert_eq!(read["models"][1]["means"], base64_f32(&set.means));
        assert!(page.contains("a <\\/script> title"));
        assert_eq!(page.matches("</script>").count(), 3, "only the page's own");
        let other = GaussianSet::zeros(4, 1);
        let e = viewer_page(
            &ViewerScene {
                shown: Shown::Still {
                    base: &set,
                    stylized: Some(&other),
                },
                ..scene
            },
            true,
        )
        .unwrap_err();
        assert!(e.contains("4 Gaussians") && e.contains("base 3"), "{e}");
    }
}
