//! The settings every stylization shares ([`StyleSettings`]) and how a modality's configuration
//! is read: a flat JSON object (`configs/3d.json`) over the modality's defaults, edited by
//! `field=value` overrides ([`Override`]; `field.key=value` sets one key of an object field,
//! as `learning_rates.sh_dc=0.02`), unknown fields refused and type errors named
//! ([`resolve_config`]).
//!
//! A modality's configuration is a struct of its own fields plus
//! `#[serde(flatten)] pub style: StyleSettings`, so its files stay flat.

use std::path::{Path, PathBuf};

use gs_wgpu::backend::DeviceChoice;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};
use style_loss::{ClipPrecision, VggPrecision};

use crate::StylizeError;

/// Optimizer updates of the paper's runs: the authors' 5000 iterations, the last of which
/// updates nothing.
pub const PAPER_UPDATES: u64 = 4999;

/// The modality-independent settings of a stylization: the style, the loss weights, the steps,
/// the patches, the checkpoints and the model files. The learning rates are the modality's own
/// (its `learning_rates`, keyed by its parameter groups' names: [`crate::rates`]). There is no
/// `Default`: each modality starts from its paper's values ([`StyleSettings::paper_3d`] for 3D
/// scenes).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StyleSettings {
    /// The style as text (exactly one of `style_prompt` and `style_image`).
    pub style_prompt: Option<String>,
    /// The style as a picture (exactly one of `style_prompt` and `style_image`).
    pub style_image: Option<PathBuf>,
    /// The source prompt the style direction starts from.
    pub source_prompt: String,
    /// Optimizer updates. The paper states 5000 steps; the authors' loops run
    /// `--iterations 5000` and step the optimizer in every iteration but the last
    /// (`if iteration < opt.iterations`), so 4999 updates: the default of every modality.
    pub steps: u64,
    /// Seed of the view order and of the patch sampling.
    pub seed: u64,
    /// Where the run computes: `cpu`, `gpu` or `auto` (a GPU for both when there is one, else
    /// the cpu). The rasterizer and Adam run on wgpu's GPU, the style loss on candle's CUDA or
    /// Metal device when the build has that feature (else on the cpu, and the run says so). A
    /// run may resume on another device.
    pub device: DeviceChoice,
    /// Weight of the directional CLIP loss.
    pub lambda_directional: f64,
    /// Weight of the patch CLIP loss.
    pub lambda_patch: f64,
    /// Weight of the VGG content loss (0 skips VGG).
    pub lambda_content: f64,
    /// Weight of the background loss, used only when every view has a mask.
    pub lambda_background: f64,
    /// Side of the square patches of the patch loss, pixels.
    pub patch_size: usize,
    /// Patches per step.
    pub num_patches: usize,
    /// Perspective distortion of the patches (torchvision's `distortion_scale`).
    pub distortion_scale: f64,
    /// Save a checkpoint every this many steps (0: never).
    pub checkpoint_every: u64,
    /// Refresh `preview.png` (the first view's picture | its render now) and `losses.png` /
    /// `losses.json` during the run every this many steps, so a long run can be watched
    /// (0: only at the end); none: every 5 % of the steps or every 60 seconds, whichever
    /// comes first.
    pub preview_every: Option<u64>,
    /// CLIP's `config.json` (`transformers` layout); none: ViT-B/32.
    pub clip_config: Option<PathBuf>,
    /// CLIP weights; none: `$CLIPGAUSSIAN_CLIP_B32_WEIGHTS`, then the Hugging Face cache.
    pub clip_weights: Option<PathBuf>,
    /// CLIP's `tokenizer.json`; none: `$CLIPGAUSSIAN_CLIP_TOKENIZER`, then the cache.
    pub tokenizer: Option<PathBuf>,
    /// VGG-19 weights; none: `$CLIPGAUSSIAN_VGG19_WEIGHTS`, then the cache.
    pub vgg_weights: Option<PathBuf>,
    /// Channel widths of the VGG-19 blocks (smaller only for test models).
    pub vgg_widths: [usize; 5],
    /// The format CLIP runs in: `f32`; `f16`, half precision throughout as the authors' fp16
    /// CLIP on CUDA; `bf16`, the linear layers' products in bf16 with f32 activations (on a
    /// CPU with AVX-512 BF16: 1.2 to 2 times the f32 rate on an AMD Zen 4, slower on an Intel
    /// Sapphire Rapids); `auto`, `bf16` where the run's own products time at least 1.1 times
    /// as fast as f32 at start, `f32` elsewhere ($CLIPGAUSSIAN_CPU_BF16 `0` or `1` forces it).
    /// The error of each against f32 is in docs/benchmarks.md.
    pub clip_precision: ClipPrecision,
    /// The format of VGG's products: `f32` (the forward summed exactly before each ReLU
    /// decides, as the f32 PyTorch network decides); `bf16`, on the layers of 256 channels and
    /// more, the backward's products in bf16 and the forward's in f32 by Winograd's F(2x2, 3x3)
    /// (the CPU only; its error against f32 is in docs/benchmarks.md);
    /// `auto`, `bf16` where a layer of each bf16 width times at least 1.1 times as fast as f32
    /// at start, `f32` elsewhere ($CLIPGAUSSIAN_CPU_BF16 forces it as for `clip_precision`).
    #[serde(default)]
    pub vgg_precision: VggPrecision,
    /// Megabytes of the views' cached ground truth (CLIP embedding and VGG features, about
    /// 21 MB a view at 854x480) held in memory; the views past it are written to
    /// `<out>/view_cache/` and read back when used (removed at the end of the run), so memory
    /// does not grow with the number of views. The values of the run do not change.
    #[serde(default = "default_view_cache_mb")]
    pub view_cache_mb: u64,
}

/// The default of [`StyleSettings::view_cache_mb`]: 2 GB, about 100 views at 854x480.
pub const DEFAULT_VIEW_CACHE_MB: u64 = 2048;

fn default_view_cache_mb() -> u64 {
    DEFAULT_VIEW_CACHE_MB
}

impl StyleSettings {
    /// The paper's 3D settings (the paper; docs/fidelity.md), no style yet: lambdas 5 / 90 / 0.8 / 1000 (the
    /// background term only applies to datasets with masks), 4999 updates (the authors' 5000
    /// iterations), 64 patches of 128 x 128, a checkpoint every 500 steps.
    pub fn paper_3d() -> Self {
        Self {
            style_prompt: None,
            style_image: None,
            source_prompt: style_loss::DEFAULT_SOURCE_PROMPT.to_string(),
            steps: PAPER_UPDATES,
            seed: 0,
            device: DeviceChoice::Auto,
            lambda_directional: 5.0,
            lambda_patch: 90.0,
            lambda_content: 0.8,
            lambda_background: 1000.0,
            patch_size: 128,
            num_patches: 64,
            distortion_scale: 0.5,
            checkpoint_every: 500,
            preview_every: None,
            clip_config: None,
            clip_weights: None,
            tokenizer: None,
            vgg_weights: None,
            vgg_widths: [64, 128, 256, 512, 512],
            clip_precision: ClipPrecision::F32,
            vgg_precision: VggPrecision::F32,
            view_cache_mb: DEFAULT_VIEW_CACHE_MB,
        }
    }

    /// The paper's 2D (MiraGe) settings (the paper; docs/fidelity.md), no style yet: those of
    /// [`StyleSettings::paper_3d`] with lambda_background 0.
    pub fn paper_2d() -> Self {
        Self {
            lambda_background: 0.0,
            ..Self::paper_3d()
        }
    }

    /// The paper's 4D (D-MiSo) settings (the paper; docs/fidelity.md), no style yet: lambdas 5 / 90 / 0.8 / 0
    /// (500 where the background must stay).
    pub fn paper_4d() -> Self {
        Self {
            lambda_background: 0.0,
            ..Self::paper_3d()
        }
    }

    /// The paper's video (VeGaS) settings (the paper; docs/fidelity.md), no style yet: lambdas 5 / 90 / 0.5 / 0.
    pub fn paper_video() -> Self {
        Self {
            lambda_content: 0.5,
            lambda_background: 0.0,
            ..Self::paper_3d()
        }
    }

    /// The style in a few words, for titles: the prompt in quotes, or the style picture's file
    /// name.
    pub fn label(&self) -> String {
        match (&self.style_prompt, &self.style_image) {
            (Some(prompt), _) => format!("\"{prompt}\""),
            (None, Some(image)) => image.file_name().map_or_else(
                || image.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            ),
            (None, None) => "no style".into(),
        }
    }

    /// Checks what deserializing cannot: exactly one style, non-empty prompts, at least one
    /// step, finite non-negative weights, patches when the patch loss is
    /// on, a distortion in `[0, 1]`. Errors name the field.
    pub fn validate(&self) -> Result<(), StylizeError> {
        let bad = |field: &str, why: &str| {
            Err(StylizeError::Config(format!(
                "{field}: {why} (set it with {})",
                flag_for(field)
            )))
        };
        match (&self.style_prompt, &self.style_image) {
            (Some(_), Some(_)) => {
                return Err(StylizeError::Config(
                    "style_prompt, style_image: give exactly one style (--style-prompt or \
                     --style-image), not both"
                        .into(),
                ))
            }
            (None, None) => {
                return Err(StylizeError::Config(
                    "style_prompt, style_image: a style is required: --style-prompt TEXT or \
                     --style-image PICTURE"
                        .into(),
                ))
            }
            (Some(p), None) => {
                if let Err(why) = check_prompt("style prompt", p) {
                    return bad("style_prompt", &why);
                }
            }
            _ => {}
        }
        if let Err(why) = check_prompt("source prompt", &self.source_prompt) {
            return bad("source_prompt", &why);
        }
        if self.steps == 0 {
            return bad("steps", "must be at least 1");
        }
        let weights = [
            ("lambda_directional", self.lambda_directional),
            ("lambda_patch", self.lambda_patch),
            ("lambda_content", self.lambda_content),
            ("lambda_background", self.lambda_background),
        ];
        for (field, w) in weights {
            if !(w.is_finite() && w >= 0.0) {
                return bad(field, &format!("{w} must be finite and >= 0"));
            }
        }
        if self.lambda_patch > 0.0 && (self.patch_size == 0 || self.num_patches == 0) {
            return Err(StylizeError::Config(
                "patch_size, num_patches: a patch loss needs a patch size and a number of \
                 patches above 0 (--set patch_size=128 --set num_patches=64, the paper's; or \
                 --set lambda_patch=0 for none)"
                    .into(),
            ));
        }
        if !(0.0..=1.0).contains(&self.distortion_scale) {
            return bad("distortion_scale", "must be in [0, 1]");
        }
        Ok(())
    }
}

/// Checks that a prompt has text (not only spaces); `what` names it in the error (`the style
/// prompt is empty`). Stylization ([`StyleSettings::validate`]) and evaluation refuse empty
/// prompts alike.
pub fn check_prompt(what: &str, prompt: &str) -> Result<(), String> {
    if prompt.trim().is_empty() {
        Err(format!("the {what} is empty"))
    } else {
        Ok(())
    }
}

/// One edit of the configuration: `field` set to `value`.
#[derive(Clone, Debug, PartialEq)]
pub struct Override {
    /// The field name.
    pub field: String,
    /// Its new value.
    pub value: Value,
}

impl Override {
    /// A field set to a value.
    pub fn new(field: impl Into<String>, value: impl Into<Value>) -> Self {
        Self {
            field: field.into(),
            value: value.into(),
        }
    }

    /// Parses `field=value`: the value is JSON when it parses as JSON (`5`, `null`, `[0, 2]`,
    /// `true`), else a string.
    pub fn parse(text: &str) -> Result<Self, StylizeError> {
        let Some((field, value)) = text.split_once('=') else {
            return Err(StylizeError::Config(format!(
                "override {text:?} is not of the form field=value"
            )));
        };
        let field = field.trim();
        if field.is_empty() {
            return Err(StylizeError::Config(format!(
                "override {text:?} has no field name"
            )));
        }
        let value = serde_json::from_str(value).unwrap_or_else(|_| Value::String(value.into()));
        Ok(Self::new(field, value))
    }
}

/// How a user sets configuration field `field` on the command line: its own flag where every
/// binary has one (`--steps`, `--style-prompt`, ...), else `--set field=VALUE`.
pub fn flag_for(field: &str) -> String {
    const OWN_FLAGS: [&str; 9] = [
        "style_prompt",
        "style_image",
        "source_prompt",
        "steps",
        "clip_config",
        "clip_weights",
        "tokenizer",
        "vgg_weights",
        "device",
    ];
    if OWN_FLAGS.contains(&field) {
        format!("--{}", field.replace('_', "-"))
    } else {
        format!("--set {field}=VALUE")
    }
}

/// The configuration `C` of `file` (`C::default()` alone when `None`) with `overrides` applied
/// in order. Fields the file leaves out keep their default. The file is checked as written,
/// before any override: an unknown field or a value of the wrong type in it is an error naming
/// the file, the field and the value, even when an override replaces that field. Then the
/// overrides are checked the same way (their errors name the field and the value). Checking
/// the values' ranges is the caller's (e.g. [`StyleSettings::validate`]).
///
/// Only top-level fields are checked against the defaults; a nested struct refuses unknown
/// fields with its own `#[serde(deny_unknown_fields)]`.
pub fn resolve_config<C>(file: Option<&Path>, overrides: &[Override]) -> Result<C, StylizeError>
where
    C: Serialize + DeserializeOwned + Default,
{
    let Value::Object(defaults) = serde_json::to_value(C::default()).expect("configs serialize")
    else {
        panic!("a configuration must serialize to a JSON object");
    };
    let mut fields = defaults.clone();
    if let Some(path) = file {
        let in_file =
            |message: String| StylizeError::Config(format!("{}: {message}", path.display()));
        let text = std::fs::read_to_string(path).map_err(|source| StylizeError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let Value::Object(given) =
            serde_json::from_str(&text).map_err(|e| in_file(e.to_string()))?
        else {
            return Err(in_file("must be a JSON object".into()));
        };
        check_fields::<C>(&fields, &given).map_err(in_file)?;
        fields.extend(given);
    }
    let mut given = Map::new();
    for o in overrides {
        set_override(&fields, &mut given, o).map_err(StylizeError::Config)?;
    }
    check_fields::<C>(&fields, &given).map_err(StylizeError::Config)?;
    fields.extend(given);
    serde_json::from_value(Value::Object(fields)).map_err(|e| StylizeError::Config(e.to_string()))
}

/// Puts override `o` into `given` (the overridden fields over `base`): a plain field is set
/// whole; `field.key...` sets one key inside the object `field` holds (in `given` when an
/// earlier override set it, else in `base`), keeping its other keys. A dotted path through a
/// field that is not an object is an error naming it; an unknown top-level field is left for
/// [`check_fields`] to name.
fn set_override(
    base: &Map<String, Value>,
    given: &mut Map<String, Value>,
    o: &Override,
) -> Result<(), String> {
    let mut path = o.field.split('.');
    let top = path.next().unwrap_or_default();
    let keys: Vec<&str> = path.collect();
    if keys.is_empty() {
        given.insert(o.field.clone(), o.value.clone());
        return Ok(());
    }
    let Some(current) = given.get(top).or_else(|| base.get(top)) else {
        given.insert(top.to_string(), Value::Null);
        return Ok(());
    };
    let mut whole = current.clone();
    let mut at = &mut whole;
    for (i, key) in keys.iter().enumerate() {
        let Value::Object(object) = at else {
            return Err(format!(
                "{} = {}: `{}` is not an object, so it has no key `{key}`",
                o.field,
                o.value,
                keys[..i]
                    .iter()
                    .fold(top.to_string(), |path, k| format!("{path}.{k}"))
            ));
        };
        at = object
            .entry(key.to_string())
            .or_insert(Value::Object(Map::new()));
    }
    *at = o.value.clone();
    given.insert(top.to_string(), whole);
    Ok(())
}

/// Checks the fields `given` over the configuration `base` (every field of `C`): each is a
/// field of `C`, and `base` with them deserializes. The error names every unknown field, or
/// else every field whose value does not deserialize, with its value.
fn check_fields<C: DeserializeOwned>(
    base: &Map<String, Value>,
    given: &Map<String, Value>,
) -> Result<(), String> {
    let unknown: Vec<&str> = given
        .keys()
        .filter(|k| !base.contains_key(*k))
        .map(String::as_str)
        .collect();
    if !unknown.is_empty() {
        let known: Vec<&str> = base.keys().map(String::as_str).collect();
        return Err(format!(
            "unknown field{} `{}`; the fields are {}",
            if unknown.len() > 1 { "s" } else { "" },
            unknown.join("`, `"),
            known.join(", ")
        ));
    }
    let mut merged = base.clone();
    merged.extend(given.clone());
    match serde_json::from_value::<C>(Value::Object(merged)) {
        Ok(_) => Ok(()),
        Err(whole) => Err(name_bad_fields::<C>(base, given).unwrap_or(whole.to_string())),
    }
}

/// `field = value: why` for every field of `given` that does not deserialize on its own over
/// `base` (serde's messages inside a `#[serde(flatten)]` field do not name the field); `None`
/// when each does.
fn name_bad_fields<C: DeserializeOwned>(
    base: &Map<String, Value>,
    given: &Map<String, Value>,
) -> Option<String> {
    let bad: Vec<String> = given
        .iter()
        .filter_map(|(field, value)| {
            let mut alone = base.clone();
            alone.insert(field.clone(), value.clone());
            serde_json::from_value::<C>(Value::Object(alone))
                .err()
                .map(|e| format!("{field} = {value}: {e}"))
        })
        .collect();
    (!bad.is_empty()).then(|| bad.join("; "))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A field out of range is refused with the flag that sets it: its own flag where every
    /// binary has one, else `--set field=VALUE`.
    #[test]
    fn errors_name_the_flag_that_fixes_them() {
        let mut settings = StyleSettings {
            style_prompt: Some("fire".into()),
            ..StyleSettings::paper_3d()
        };
        settings.steps = 0;
        let err = settings.validate().unwrap_err().to_string();
        assert!(
            err.contains("steps: must be at least 1 (set it with --steps)"),
            "{err}"
        );
        settings.steps = 10;
        settings.distortion_scale = 2.0;
        let err = settings.validate().unwrap_err().to_string();
        assert!(err.contains("--set distortion_scale=VALUE"), "{err}");
        settings.distortion_scale = 0.5;
        settings.style_prompt = None;
        let err = settings.validate().unwrap_err().to_string();
        assert!(
            err.contains("--style-prompt TEXT or --style-image PICTURE"),
            "{err}"
        );
    }

    /// A modality configuration with the 3D fields, so `configs/3d.json` reads into it.
    #[derive(Debug, PartialEq, Serialize, Deserialize)]
    struct Modality {
        model: Option<PathBuf>,
        data: Option<PathBuf>,
        out: Option<PathBuf>,
        resolution: u32,
        max_width: u32,
        background: [f32; 3],
        ground_truth: String,
        object: bool,
        background_mask: String,
        train_splits: String,
        preview_views: Vec<usize>,
        learning_rates: crate::rates::GroupRates,
        fit_gaussians: usize,
        fit_steps: u64,
        #[serde(flatten)]
        style: StyleSettings,
    }

    impl Default for Modality {
        fn default() -> Self {
            Self {
                model: None,
                data: None,
                out: None,
                resolution: 1,
                max_width: 1600,
                background: [0.0; 3],
                ground_truth: "file_colour".into(),
                object: false,
                background_mask: "ground_truth_colour".into(),
                train_splits: "train_and_test".into(),
                preview_views: vec![0],
                fit_gaussians: 100_000,
                fit_steps: 30_000,
                learning_rates: crate::rates::gaussian_stylization(0.01),
                style: StyleSettings::paper_3d(),
            }
        }
    }

    fn error(overrides: &[Override]) -> String {
        resolve_config::<Modality>(None, overrides)
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn unknown_keys_are_named_each() {
        let e = error(&[
            Override::new("lamda_patch", 3),
            Override::new("steps", 4),
            Override::new("stpes", 4),
        ]);
        assert!(e.contains("unknown fields `lamda_patch`, `stpes`"), "{e}");
        assert!(
            e.contains("lambda_patch") && e.contains("resolution"),
            "{e}"
        );
    }

    #[test]
    fn a_bad_type_names_its_field_inside_and_outside_the_flattened_settings() {
        let e = error(&[Override::parse("steps=abc").unwrap()]);
        assert!(e.starts_with("configuration: steps = \"abc\": "), "{e}");
        assert!(e.contains("invalid type") && e.contains("abc"), "{e}");
        let e = error(&[
            Override::parse("resolution=-1").unwrap(),
            Override::parse("vgg_widths=[1,2]").unwrap(),
        ]);
        assert!(
            e.contains("resolution = -1: ") && e.contains("vgg_widths = [1,2]: "),
            "{e}"
        );
    }

    /// `field.key=value` sets one key of an object field and keeps the others, also over an
    /// earlier override of the same field; a path through a non-object is refused by name.
    #[test]
    fn a_dotted_override_sets_one_key_of_an_object_field() {
        use crate::rates::GroupRate;
        let c: Modality = resolve_config(
            None,
            &[
                Override::parse("learning_rates.sh_dc=0.5").unwrap(),
                Override::parse("learning_rates.scales=frozen").unwrap(),
            ],
        )
        .unwrap();
        let mut want = crate::rates::gaussian_stylization(0.01);
        want.set("sh_dc", GroupRate::Constant(0.5));
        want.set("scales", GroupRate::Frozen);
        assert_eq!(c.learning_rates, want);
        let c: Modality = resolve_config(
            None,
            &[Override::parse("learning_rates.means.steps=10").unwrap()],
        )
        .unwrap();
        assert!(matches!(
            c.learning_rates.get("means"),
            Some(GroupRate::Decay { steps: 10, start, .. }) if *start == 1e-4
        ));
        let e = error(&[Override::parse("learning_rates.sh_dc=fast").unwrap()]);
        assert!(
            e.contains("learning_rates") && e.contains("sh_dc: \"fast\""),
            "{e}"
        );
        let e = error(&[Override::parse("steps.count=3").unwrap()]);
        assert!(e.contains("`steps` is not an object"), "{e}");
        let e = error(&[Override::parse("lerning_rates.sh_dc=3").unwrap()]);
        assert!(e.contains("unknown field `lerning_rates`"), "{e}");
    }

    #[test]
    fn overrides_apply_in_order_over_the_defaults() {
        let c: Modality = resolve_config(
            None,
            &[
                Override::parse("steps=7").unwrap(),
                Override::parse("preview_views=[1,3]").unwrap(),
                Override::parse("style_prompt=fire").unwrap(),
                Override::parse("steps=9").unwrap(),
            ],
        )
        .unwrap();
        assert_eq!((c.style.steps, c.preview_views), (9, vec![1, 3]));
        assert_eq!(c.style.style_prompt.as_deref(), Some("fire"));
        assert_eq!(c.style.lambda_patch, StyleSettings::paper_3d().lambda_patch);
        let c: Modality = resolve_config(None, &[Override::parse("device=gpu").unwrap()]).unwrap();
        assert_eq!(c.style.device, DeviceChoice::Gpu);
        let e = error(&[Override::parse("device=cuda").unwrap()]);
        assert!(
            e.contains("device = \"cuda\": ") && e.contains("cpu, gpu, auto"),
            "{e}"
        );
        assert!(Override::parse("no-equals-sign").is_err());
        assert!(Override::parse("=3").is_err());
    }

    #[test]
    fn the_flat_3d_file_round_trips_and_missing_keys_keep_their_defaults() {
        let file = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../configs/3d.json");
        let paper: Modality = resolve_config(Some(&file), &[]).unwrap();
        assert_eq!(paper, Modality::default());
        let on_disk: Value =
            serde_json::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
        assert_eq!(serde_json::to_value(&paper).unwrap(), on_disk);

        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("config.json");
        std::fs::write(&path, r#"{"steps": 12, "resolution": 2}"#).unwrap();
        let partial: Modality = resolve_config(Some(&path), &[]).unwrap();
        assert_eq!((partial.style.steps, partial.resolution), (12, 2));
        assert_eq!(partial.preview_views, vec![0]);
        std::fs::write(&path, "[1]").unwrap();
        let e = resolve_config::<Modality>(Some(&path), &[])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("config.json") && e.contains("JSON object"),
            "{e}"
        );
    }

    #[test]
    fn the_file_is_checked_as_written_even_where_an_override_replaces_a_field() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.json");
        let resolve = |text: &str, overrides: &[Override]| {
            std::fs::write(&path, text).unwrap();
            resolve_config::<Modality>(Some(&path), overrides)
                .unwrap_err()
                .to_string()
        };
        let e = resolve(r#"{"steps": "many"}"#, &[Override::new("steps", 5)]);
        assert!(
            e.starts_with("configuration: ")
                && e.contains("run.json: steps = \"many\": invalid type"),
            "{e}"
        );
        assert_eq!(e.matches("configuration").count(), 1, "{e}");
        let e = resolve(r#"{"stpes": 5}"#, &[]);
        assert!(e.contains("run.json: unknown field `stpes`"), "{e}");
        let e = resolve(
            r#"{"steps": 5}"#,
            &[Override::parse("resolution=x").unwrap()],
        );
        assert!(
            e.starts_with("configuration: resolution = \"x\": ") && !e.contains("run.json"),
            "{e}"
        );
    }

    #[test]
    fn validation_names_the_field() {
        let mut s = StyleSettings::paper_3d();
        s.style_prompt = Some("  ".into());
        let e = s.validate().unwrap_err().to_string();
        assert_eq!(
            e,
            "configuration: style_prompt: the style prompt is empty (set it with --style-prompt)"
        );
        s.style_prompt = None;
        assert!(s
            .validate()
            .unwrap_err()
            .to_string()
            .contains("a style is required"));
        s.style_prompt = Some("fire".into());
        s.validate().unwrap();
        s.lambda_content = -1.0;
        assert!(s
            .validate()
            .unwrap_err()
            .to_string()
            .contains("lambda_content: -1 must be finite and >= 0"));
    }
}
