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
use crate::outputs::{create_folder, into_new_folder};
use crate::progress::Progress;
use crate::writable::{check_output_file, check_output_folder};

/// Flags of `export`, the same in every binary.
#[derive(clap::Args, Debug)]
pub struct ExportArgs {
    /// The model to export (the file the binary's other commands take as --model).
    #[arg(long)]
    pub model: PathBuf,
    /// Where to write: a file whose name ends in .ply, .compressed.ply, .splat, .spz, .glb or
    /// .sog, or a SOG folder's meta.json (its pictures written beside it) (the ending picks the
    /// format unless --format is given); a folder when several frames or times are exported,
    /// one file each (00000.ply, 00001.ply, ...).
    #[arg(long)]
    pub out: PathBuf,
    /// The format: ply (INRIA, exact), compressed-ply (SuperSplat), splat (antimatter15,
    /// degree-0 colour only), spz (Niantic, version 4), spz-v2 (for older SPZ readers), glb
    /// (glTF with KHR_gaussian_splatting) or sog (PlayCanvas SOG). Default: from the ending of
    /// --out; ply for a folder.
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
                     .spz, .glb, .sog, meta.json); give --format",
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
        let format = self.folder_format();
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

/// `--format`'s values: the names of [`SplatFormat::ALL`], listed in `--help`.
fn format_parser() -> impl clap::builder::TypedValueParser<Value = SplatFormat> {
    use clap::builder::TypedValueParser;
    clap::builder::PossibleValuesParser::new(SplatFormat::ALL.map(SplatFormat::name))
        .map(|name| SplatFormat::from_name(&name).expect("a name of SplatFormat::ALL"))
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
