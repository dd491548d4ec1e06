//! The `export` subcommand every binary has: a model's Gaussians written in the splat formats
//! viewers open ([`gs_core::splats`]); for video and dynamic scenes the Gaussians of one frame
//! or time, or a folder of them for many.

use std::error::Error;
use std::path::{Path, PathBuf};

use gs_core::dataset::nerf_synthetic::TrainSplits;
use gs_core::dataset::LoadOptions;
use gs_core::model::{BaseModel, View};
use gs_core::orbit::RobustBounds;
use gs_core::ply::PlyGaussians;
use gs_core::splats::{write_splats, SplatFormat};
use gs_core::{Camera, GaussianSet};

use crate::model_kind::{check_model, Binary};
use crate::model_views::ModelViews;
use crate::outputs::{create_folder, into_new_folder};
use crate::progress::Progress;
use crate::viewer::{write_viewer, Shown, ViewerScene};
use crate::writable::{check_output_file, check_output_folder};

/// What `export` writes: a splat file, or a viewer page.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportFormat {
    /// A splat file of this format.
    Splats(SplatFormat),
    /// `viewer.html` (see [`crate::viewer`]).
    Html,
}

impl ExportFormat {
    /// The name on the command line: the splat format's, or `html`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Splats(format) => format.name(),
            Self::Html => "html",
        }
    }

    /// The format `--out`'s name ends in (`.html`, or a splat format's ending).
    fn from_path(path: &Path) -> Option<Self> {
        let html = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("html"));
        if html {
            return Some(Self::Html);
        }
        SplatFormat::from_path(path).map(Self::Splats)
    }
}

/// Flags of `export`, the same in every binary.
#[derive(clap::Args, Debug)]
pub struct ExportArgs {
    /// The model to export (the file the binary's other commands take as --model; `--a` is
    /// the same flag).
    #[arg(long, visible_alias = "a")]
    pub model: PathBuf,
    /// With --format html: a second model of the same Gaussians (a stylization of --model):
    /// the page's style slider goes from --model (0) to it (1).
    #[arg(long)]
    pub b: Option<PathBuf>,
    /// Where to write: a file whose name ends in .ply, .compressed.ply, .splat, .spz, .glb or
    /// .sog, or a SOG folder's meta.json (its pictures written beside it), or .html (a viewer
    /// page) (the ending picks the format unless --format is given); a folder when several
    /// frames or times are exported, one file each (00000.ply, 00001.ply, ...).
    #[arg(long)]
    pub out: PathBuf,
    /// The format: ply (INRIA, exact), compressed-ply (SuperSplat), splat (antimatter15,
    /// degree-0 colour only), spz (Niantic, version 4), spz-v2 (for older SPZ readers), glb
    /// (glTF with KHR_gaussian_splatting), sog (PlayCanvas SOG) or html (a viewer page that
    /// opens from disk in a browser). Default: from the ending of --out; ply for a folder.
    #[arg(long, value_parser = format_parser())]
    pub format: Option<ExportFormat>,
}

impl ExportArgs {
    /// The format to write one file: `--format`, else the ending of `--out`; an error naming
    /// the flag when neither says one.
    pub fn file_format(&self) -> Result<ExportFormat, Box<dyn Error>> {
        match self.format {
            Some(format) => Ok(format),
            None => ExportFormat::from_path(&self.out).ok_or_else(|| {
                format!(
                    "--out {}: the name ends in no format (.ply, .compressed.ply, .splat, .spz, \
                     .glb, .sog, meta.json, .html); give --format",
                    self.out.display()
                )
                .into()
            }),
        }
    }

    /// Whether `--out` is a viewer page.
    pub fn is_html(&self) -> bool {
        matches!(self.file_format(), Ok(ExportFormat::Html))
    }

    /// The format of a folder's files: `--format`, else INRIA PLY (a page is one file).
    fn folder_format(&self) -> Result<SplatFormat, Box<dyn Error>> {
        match self.format {
            None => Ok(SplatFormat::Ply),
            Some(ExportFormat::Splats(format)) => Ok(format),
            Some(ExportFormat::Html) => {
                Err("--format html writes one page: export one frame or time".into())
            }
        }
    }

    /// Checks before any work that `--model` (and `--b`) are models of `binary` and that
    /// `--out` can be written, as a file (`folder` false, its format known) or as a folder.
    pub fn check(&self, binary: Binary, folder: bool) -> Result<(), Box<dyn Error>> {
        check_model(binary, "--model", &self.model)?;
        if let Some(b) = &self.b {
            check_model(binary, "--b", b)?;
        }
        if folder {
            self.folder_format()?;
            check_output_folder(&self.out)?;
        } else {
            self.file_format()?;
            check_output_file(&self.out)?;
        }
        if self.b.is_some() && !self.is_html() {
            return Err("--b: only a viewer page (--format html) shows two models".into());
        }
        Ok(())
    }

    /// The cameras of a page of `--model` whose Gaussians are `set`: the cameras.json beside
    /// the model (INRIA's layout), else 16 views of an orbit made from them with `up` upwards.
    pub fn page_cameras(
        &self,
        set: &GaussianSet,
        up: [f64; 3],
    ) -> Result<Vec<(String, Camera)>, Box<dyn Error>> {
        let bounds = RobustBounds::of(set).map_err(|e| format!("{}: {e}", self.model.display()))?;
        let views = ModelViews {
            orbit_views: 16,
            up,
            ..ModelViews::default()
        };
        let (found, _) = views.views(
            &self.model,
            &bounds,
            TrainSplits::default(),
            &LoadOptions::default(),
        )?;
        Ok(found
            .into_iter()
            .enumerate()
            .map(|(i, v)| (format!("view {i}"), v.view.camera))
            .collect())
    }

    /// Writes the viewer page of `shown` (`--model`'s Gaussians, and `--b`'s for the slider)
    /// with `cameras` over `background` to `--out`; returns the line that says so. An error of
    /// the page (models of other Gaussians) names `--model` and `--b`.
    pub fn write_page(
        &self,
        shown: Shown,
        cameras: Vec<(String, Camera)>,
        background: [f32; 3],
    ) -> Result<String, Box<dyn Error>> {
        let title = match &self.b {
            Some(b) => format!("{} to {}", self.model.display(), b.display()),
            None => self.model.display().to_string(),
        };
        let (count, two) = match &shown {
            Shown::Still { base, stylized } => (base.len(), stylized.is_some()),
            Shown::Animated(a) => (a.count, a.models.len() > 1),
        };
        let views = cameras.len();
        write_viewer(
            &self.out,
            &ViewerScene {
                title,
                shown,
                cameras,
                background,
            },
        )
        .map_err(|e| match &self.b {
            Some(b) => format!(
                "--model {} and --b {}: {e}",
                self.model.display(),
                b.display()
            ),
            None => format!("--model {}: {e}", self.model.display()),
        })?;
        Ok(format!(
            "wrote {} (a viewer of {count} Gaussians{}, {views} camera(s))",
            self.out.display(),
            if two { " and their stylization" } else { "" }
        ))
    }

    /// Writes `ply` to `--out` in its format and returns the line that says so.
    pub fn write_file(&self, ply: &PlyGaussians) -> Result<String, Box<dyn Error>> {
        let ExportFormat::Splats(format) = self.file_format()? else {
            return Err("--format html writes a viewer page (write_html), not splats".into());
        };
        write_splats(&self.out, ply, format)?;
        Ok(format!(
            "wrote {} ({} Gaussians, {})",
            self.out.display(),
            ply.gaussians.len(),
            format.name()
        ))
    }

    /// Writes the Gaussians `model` renders at each of `times`: when `folder`, into the folder
    /// `--out` as `00000<ext>`, `00001<ext>`, ..., each computed and written before the next
    /// (a model of many frames is never held whole; the folder is removed again when this run
    /// made it and a file fails), else the first to the file `--out`. Returns the line that
    /// says so.
    pub fn write_at<M: BaseModel>(
        &self,
        model: &M,
        times: &[f64],
        folder: bool,
    ) -> Result<String, Box<dyn Error>> {
        if !folder {
            let &time = times.first().ok_or("no time to export")?;
            return self.write_file(&PlyGaussians::without_normals(gaussians_at(model, time)?));
        }
        let format = self.folder_format()?;
        let progress = Progress::new(times.len() > 1, "export", times.len() as u64, 0);
        let written = into_new_folder(&self.out, || {
            create_folder(&self.out)?;
            times
                .iter()
                .enumerate()
                .try_fold(None, |_, (i, &time)| -> Result<_, Box<dyn Error>> {
                    let set = gaussians_at(model, time)?;
                    let count = set.len();
                    let path = self.out.join(format!("{i:05}{}", format.extension()));
                    write_splats(&path, &PlyGaussians::without_normals(set), format)?;
                    progress.update(i as u64 + 1, "");
                    Ok(Some(count))
                })
        });
        progress.finish();
        let count = written?;
        Ok(format!(
            "wrote {} files ({} each, {}) to {}",
            times.len(),
            count.map_or("no Gaussians".into(), |n| format!("{n} Gaussians")),
            format.name(),
            self.out.display()
        ))
    }
}

/// `--format`'s values: the names of [`SplatFormat::ALL`] and `html`, listed in `--help`.
fn format_parser() -> impl clap::builder::TypedValueParser<Value = ExportFormat> {
    use clap::builder::TypedValueParser;
    let names: Vec<&str> = SplatFormat::ALL
        .map(SplatFormat::name)
        .into_iter()
        .chain(["html"])
        .collect();
    clap::builder::PossibleValuesParser::new(names).map(|name| match name.as_str() {
        "html" => ExportFormat::Html,
        name => {
            ExportFormat::Splats(SplatFormat::from_name(name).expect("a name of SplatFormat::ALL"))
        }
    })
}

/// The Gaussians `model` renders at `time` (its forward at a view of that time; the camera of
/// the view is one a model's forward may not look at).
pub fn gaussians_at<M: BaseModel>(model: &M, time: f64) -> Result<GaussianSet, String> {
    let camera = Camera::look_at([0.0, 0.0, -1.0], [0.0; 3], [0.0, -1.0, 0.0], 1.0, 1, 1)
        .map_err(|e| e.to_string())?;
    model
        .forward(&View { camera, time })
        .map(|f| f.gaussians.into_owned())
        .map_err(|e| format!("the Gaussians at time {time}: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(out: PathBuf) -> ExportArgs {
        ExportArgs {
            model: PathBuf::from("model.ply"),
            b: None,
            out,
            format: None,
        }
    }

    /// A folder export writes one file per time; one whose Gaussians cannot be written removes
    /// the folder it made, and leaves a folder that was there before.
    #[test]
    fn a_folder_export_writes_each_time_and_removes_its_folder_on_failure() {
        let dir = tempfile::tempdir().unwrap();
        let mut set = GaussianSet::zeros(3, 0);
        let out = dir.path().join("frames");
        let line = args(out.clone())
            .write_at(&set, &[0.0, 0.5, 1.0], true)
            .unwrap();
        assert!(
            line.starts_with("wrote 3 files (3 Gaussians each"),
            "{line}"
        );
        for i in 0..3 {
            let read = gs_core::splats::read_splats(&out.join(format!("{i:05}.ply"))).unwrap();
            assert_eq!(read.gaussians.means, set.means);
        }
        set.means[4] = f32::NAN;
        let failed = dir.path().join("failed");
        let e = args(failed.clone())
            .write_at(&set, &[0.0, 1.0], true)
            .unwrap_err();
        assert!(e.to_string().contains("00000.ply"), "{e}");
        assert!(!failed.exists(), "the folder this run made is gone");
        let e = args(out.clone()).write_at(&set, &[0.0, 1.0], true);
        assert!(e.is_err() && out.is_dir(), "a folder that was there stays");
    }
}
