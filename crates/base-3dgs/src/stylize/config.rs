//! The run configuration of a 3D stylization: a flat JSON file (`configs/3d.json`) of the 3D
//! fields and the shared [`StyleSettings`], edited by `field=value` overrides, with unknown
//! fields refused ([`gs_stylize::resolve_config`]), then checked.

use std::path::{Path, PathBuf};

use gs_stylize::{resolve_config, Override, StyleSettings, StylizeError};
use serde::{Deserialize, Serialize};

/// Everything a 3D stylization run needs. The defaults are the paper's
/// ([`StyleSettings::paper_3d`]), rendering over white at full resolution.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StylizeConfig {
    /// The trained 3DGS scene (INRIA PLY).
    pub ply: Option<PathBuf>,
    /// The dataset folder: NeRF-synthetic when it has `transforms_train.json`, else COLMAP.
    pub data: Option<PathBuf>,
    /// The output folder.
    pub out: Option<PathBuf>,
    /// Resolution divisor of the dataset images (3DGS's `-r`).
    pub resolution: u32,
    /// Composite transparent pixels over white (else black) and render over it.
    pub white_background: bool,
    /// Views rendered before and after into the preview pictures.
    pub preview_views: Vec<usize>,
    /// The settings every modality shares (style, weights, rates, patches, models).
    #[serde(flatten)]
    pub style: StyleSettings,
}

impl Default for StylizeConfig {
    fn default() -> Self {
        Self {
            ply: None,
            data: None,
            out: None,
            resolution: 1,
            white_background: true,
            preview_views: vec![0],
            style: StyleSettings::paper_3d(),
        }
    }
}

impl StylizeConfig {
    /// The configuration in `file` (the defaults when `None`, and for the fields it leaves out)
    /// with `overrides` applied in order, then checked with [`StylizeConfig::validate`].
    /// Unknown fields and values of the wrong type are errors naming the field.
    pub fn resolve(file: Option<&Path>, overrides: &[Override]) -> Result<Self, StylizeError> {
        let config: Self = resolve_config(file, overrides)?;
        config.validate()?;
        Ok(config)
    }

    /// Checks what deserializing cannot: the required paths, the shared settings
    /// ([`StyleSettings::validate`]) and the resolution divisor.
    pub fn validate(&self) -> Result<(), StylizeError> {
        let bad = |field: &str, why: &str| Err(StylizeError::Config(format!("{field}: {why}")));
        for (field, value) in [("ply", &self.ply), ("data", &self.data), ("out", &self.out)] {
            if value.is_none() {
                return bad(field, "is required");
            }
        }
        self.style.validate()?;
        if self.resolution == 0 {
            return bad(
                "resolution",
                "must be at least 1 (1 keeps the images as they are)",
            );
        }
        Ok(())
    }

    /// The required `ply` path ([`StylizeConfig::validate`] checked it is set).
    pub fn ply_path(&self) -> &Path {
        self.ply.as_deref().expect("validated: ply is set")
    }

    /// The required `data` path.
    pub fn data_path(&self) -> &Path {
        self.data.as_deref().expect("validated: data is set")
    }

    /// The required `out` path.
    pub fn out_path(&self) -> &Path {
        self.out.as_deref().expect("validated: out is set")
    }
}
