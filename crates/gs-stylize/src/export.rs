//! The `export` subcommand every binary has: a model's Gaussians written in the splat formats
//! viewers open ([`gs_core::splats`]); for video and dynamic scenes the Gaussians of one frame
//! or time, or a folder of them for many.

use std::error::Error;
use std::path::PathBuf;

use gs_core::model::{BaseModel, View};
use gs_core::ply::PlyGaussians;
use gs_core::splats::{write_splats, SplatFormat};
use gs_core::{Camera, GaussianSet};

use crate::model_kind::{check_model, Binary};
use crate::outputs::create_folder;
use crate::writable::{check_output_file, check_output_folder};

/// Flags of `export`, the same in every binary.
#[derive(clap::Args, Debug)]
pub struct ExportArgs {
    /// The model to export (the file the binary's other commands take as --model).
    #[arg(long)]
    pub model: PathBuf,
    /// Where to write: a file whose name ends in .ply, .compressed.ply, .splat, .spz or .glb
    /// (the ending picks the format unless --format is given); a folder when several frames or
    /// times are exported, one file each (00000.ply, 00001.ply, ...).
    #[arg(long)]
    pub out: PathBuf,
    /// The format: ply (INRIA, exact), compressed-ply (SuperSplat), splat (antimatter15,
    /// degree-0 colour only), spz (Niantic, version 4), spz-v2 (for older SPZ readers) or glb
    /// (glTF with KHR_gaussian_splatting). Default: from the ending of --out; ply for a folder.
    #[arg(long, value_parser = format_parser())]
    pub format: Option<SplatFormat>,
}

impl ExportArgs {
    /// The format to write one file: `--format`, else the ending of `--out`; an error naming
    /// the flag when neither says one.
    pub fn file_format(&self) -> Result<SplatFormat, Box<dyn Error>> {
        match self.format {
            Some(format) => Ok(format),
            None => SplatFormat::from_path(&self.out).ok_or_else(|| {
                format!(
                    "--out {}: the name ends in no splat format (.ply, .compressed.ply, .splat, \
                     .spz, .glb); give --format",
                    self.out.display()
                )
                .into()
            }),
        }
    }

    /// The format of a folder's files: `--format`, else INRIA PLY.
    fn folder_format(&self) -> SplatFormat {
        self.format.unwrap_or(SplatFormat::Ply)
    }

    /// Checks before any work that `--model` is a model of `binary` and that `--out` can be
    /// written, as a file (`folder` false, its format known) or as a folder.
    pub fn check(&self, binary: Binary, folder: bool) -> Result<(), Box<dyn Error>> {
        check_model(binary, "--model", &self.model)?;
        if folder {
            check_output_folder(&self.out)?;
        } else {
            self.file_format()?;
            check_output_file(&self.out)?;
        }
        Ok(())
    }

    /// Writes `ply` to `--out` in its format and returns the line that says so.
    pub fn write_file(&self, ply: &PlyGaussians) -> Result<String, Box<dyn Error>> {
        let format = self.file_format()?;
        write_splats(&self.out, ply, format)?;
        Ok(format!(
            "wrote {} ({} Gaussians, {})",
            self.out.display(),
            ply.gaussians.len(),
            format.name()
        ))
    }

    /// Writes Gaussians a model's forward made (`sets`): each into the folder `--out` when
    /// `folder` ([`ExportArgs::write_folder`]), else the first to the file `--out`; returns the
    /// line that says so.
    pub fn write_sets(
        &self,
        mut sets: Vec<GaussianSet>,
        folder: bool,
    ) -> Result<String, Box<dyn Error>> {
        if folder {
            return self.write_folder(&sets);
        }
        let set = sets.drain(..).next().ok_or("no Gaussians to export")?;
        self.write_file(&PlyGaussians::without_normals(set))
    }

    /// Writes each of `sets` into the folder `--out` (created when absent) as `00000<ext>`,
    /// `00001<ext>`, ... and returns the line that says so.
    pub fn write_folder(&self, sets: &[GaussianSet]) -> Result<String, Box<dyn Error>> {
        let format = self.folder_format();
        create_folder(&self.out)?;
        for (i, set) in sets.iter().enumerate() {
            let path = self.out.join(format!("{i:05}{}", format.extension()));
            write_splats(&path, &PlyGaussians::without_normals(set.clone()), format)?;
        }
        Ok(format!(
            "wrote {} files ({} each, {}) to {}",
            sets.len(),
            sets.first()
                .map_or("no Gaussians".into(), |s| format!("{} Gaussians", s.len())),
            format.name(),
            self.out.display()
        ))
    }
}

/// `--format`'s values: the names of [`SplatFormat::ALL`], listed in `--help`.
fn format_parser() -> impl clap::builder::TypedValueParser<Value = SplatFormat> {
    use clap::builder::TypedValueParser;
    clap::builder::PossibleValuesParser::new(SplatFormat::ALL.map(SplatFormat::name))
        .map(|name| SplatFormat::from_name(&name).expect("a name of SplatFormat::ALL"))
}

/// The Gaussians `model` renders at each of `times` (its forward at a view of that time; the
/// camera of the view is one a model's forward may not look at).
pub fn gaussians_at<M: BaseModel>(model: &M, times: &[f64]) -> Result<Vec<GaussianSet>, String> {
    let camera = Camera::look_at([0.0, 0.0, -1.0], [0.0; 3], [0.0, -1.0, 0.0], 1.0, 1, 1)
        .map_err(|e| e.to_string())?;
    times
        .iter()
        .map(|&time| {
            let view = View {
                camera: camera.clone(),
                time,
            };
            model
                .forward(&view)
                .map(|f| f.gaussians.into_owned())
                .map_err(|e| format!("the Gaussians at time {time}: {e}"))
        })
        .collect()
}
