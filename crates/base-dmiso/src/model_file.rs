//! D-MiSo models on disk: our own single file (`model.safetensors`: every tensor under the
//! name D-MiSo gives it, and the sizes in the metadata), and the folder the authors' code saves
//! (read only, [`read_authors`]).
//!
//! Tensor names and shapes, `G` cores of `K` sub-Gaussians: `pseudomesh [G, 3, 3]`,
//! `alpha [G, K, 3]`, `attached_scale [G K, 3]`, `attached_rotation [G K, 4]`,
//! `attached_opacity [G K, 1]`, `attached_features_dc [G K, 1, 3]`,
//! `attached_features_rest [G K, 15, 3]` (coefficient-major, channel last), the deformation
//! network's `state_dict` (`deform.<name>` in our file) and the time-rotation layer
//! (`time_net.weight [4, 17]`, `time_net.bias [4]`).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor};
use gs_core::dataset::Background;
use gs_stylize::background::parse_background;

use crate::deform_net::NetShape;
use crate::model::{group, Dmiso, DmisoParams};
use crate::sub_gaussian::TIME_NET_INPUT;

/// The `format` metadata of our model files.
pub const FORMAT: &str = "clipgaussian-dmiso";

/// Why a model file could not be read or written. Each names the file.
#[derive(Debug, thiserror::Error)]
pub enum DmisoFileError {
    /// A file that could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A file that is not what it should be (truncated, foreign, of other shapes).
    #[error("{}: {message}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A file that the safetensors reader or writer refused (truncated, foreign).
    #[error("{}: not a safetensors file ({source})", path.display())]
    Safetensors {
        /// The file.
        path: PathBuf,
        /// The reader's or writer's error.
        source: safetensors::SafeTensorError,
    },
    /// A PyTorch file that could not be read (a truncated, corrupt or foreign `.pth`).
    #[error("{}: not a readable PyTorch checkpoint ({message})", path.display())]
    Checkpoint {
        /// The file.
        path: PathBuf,
        /// What the reader found.
        message: String,
    },
}

/// Every tensor of a model: name, shape, group and the range of the group it fills.
fn layout(cores: usize, subs: usize, net: &NetShape) -> Vec<(String, Vec<usize>, usize, usize)> {
    let n = cores * subs;
    let mut out = vec![
        (
            "pseudomesh".to_string(),
            vec![cores, 3, 3],
            group::PSEUDOMESH,
            0,
        ),
        ("alpha".into(), vec![cores, subs, 3], group::ALPHA, 0),
        ("attached_scale".into(), vec![n, 3], group::SCALE, 0),
        ("attached_rotation".into(), vec![n, 4], group::ROTATION, 0),
        ("attached_opacity".into(), vec![n, 1], group::OPACITY, 0),
        ("attached_features_dc".into(), vec![n, 1, 3], group::DC, 0),
        (
            "attached_features_rest".into(),
            vec![n, 15, 3],
            group::REST,
            0,
        ),
    ];
    let mut offset = 0;
    for (name, shape) in net.tensors() {
        let len: usize = shape.iter().product();
        out.push((format!("deform.{name}"), shape, group::DEFORM, offset));
        offset += len;
    }
    out.push((
        "time_net.weight".into(),
        vec![4, TIME_NET_INPUT],
        group::TIME_NET,
        0,
    ));
    out.push((
        "time_net.bias".into(),
        vec![4],
        group::TIME_NET,
        4 * TIME_NET_INPUT,
    ));
    out
}

/// Writes `model` to `path` (`model.safetensors`), through a temporary name, recording the
/// background it was fitted or stylized over (`white`) when given.
pub fn save(
    model: &Dmiso,
    path: &Path,
    background: Option<Background>,
) -> Result<(), DmisoFileError> {
    let params = model.params();
    let data: Vec<(String, Vec<usize>, Vec<u8>)> =
        layout(model.cores(), model.subs_per_core(), &model.net())
            .into_iter()
            .map(|(name, shape, g, offset)| {
                let len: usize = shape.iter().product();
                let bytes = le_bytes(&params.groups[g][offset..offset + len]);
                (name, shape, bytes)
            })
            .collect();
    let tensors = data
        .iter()
        .map(|(name, shape, bytes)| {
            let view =
                safetensors::tensor::TensorView::new(safetensors::Dtype::F32, shape.clone(), bytes)
                    .expect("shape and data agree");
            (name.clone(), view)
        })
        .collect::<Vec<_>>();
    let mut metadata = HashMap::from([
        ("format".to_string(), FORMAT.to_string()),
        ("cores".into(), model.cores().to_string()),
        ("subs_per_core".into(), model.subs_per_core().to_string()),
        ("deform_width".into(), model.net().width.to_string()),
        ("deformation".into(), model.deformation.to_string()),
    ]);
    if let Some(background) = background {
        let [r, g, b] = background.rgb();
        metadata.insert("background".into(), format!("{r},{g},{b}"));
        if background != Background::Colour([r, g, b]) {
            // What readers of the white-or-black record (and D-MiSo's cfg_args) understand.
            metadata.insert(
                "white_background".into(),
                (background == Background::White).to_string(),
            );
        }
    }
    let bytes = safetensors::serialize(tensors, Some(metadata)).map_err(|source| {
        DmisoFileError::Safetensors {
            path: path.to_path_buf(),
            source,
        }
    })?;
    let bytes = with_sorted_header(bytes);
    gs_core::fs::write_atomic(path, &bytes).map_err(|source| DmisoFileError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// `file` (safetensors bytes) with every object of its json header in key order, the header's
/// length kept (its padding spaces absorb nothing: the same keys and values in another order
/// are the same number of bytes). The safetensors crate writes the metadata from a `HashMap`,
/// in another order at every run; sorted, the same model is the same bytes.
fn with_sorted_header(mut file: Vec<u8>) -> Vec<u8> {
    let Some(length) = file
        .get(..8)
        .and_then(|b| usize::try_from(u64::from_le_bytes(b.try_into().ok()?)).ok())
    else {
        return file;
    };
    let Some(Ok(mut header)) = file
        .get(8..8 + length)
        .map(serde_json::from_slice::<serde_json::Value>)
    else {
        return file;
    };
    header.sort_all_objects();
    let sorted = serde_json::to_vec(&header).expect("a json value serializes");
    if sorted.len() <= length {
        file[8..8 + sorted.len()].copy_from_slice(&sorted);
        file[8 + sorted.len()..8 + length].fill(b' ');
    }
    file
}

/// The little-endian bytes of `values`.
fn le_bytes(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// Reads a model written by [`save`], its network on `device`.
pub fn load(path: &Path, device: &Device) -> Result<Dmiso, DmisoFileError> {
    let format = |message: String| DmisoFileError::Format {
        path: path.to_path_buf(),
        message,
    };
    let bytes = std::fs::read(path).map_err(|source| DmisoFileError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let not_safetensors = |source| DmisoFileError::Safetensors {
        path: path.to_path_buf(),
        source,
    };
    let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).map_err(not_safetensors)?;
    let meta = header.metadata().clone().unwrap_or_default();
    if meta.get("format").map(String::as_str) != Some(FORMAT) {
        return Err(format(format!(
            "not a D-MiSo model of clipgaussian (metadata format is {:?}, {FORMAT:?} expected)",
            meta.get("format")
        )));
    }
    let number = |key: &str| -> Result<usize, DmisoFileError> {
        meta.get(key)
            .and_then(|v| v.parse().ok())
            .ok_or_else(|| format(format!("metadata {key} is missing or not a count")))
    };
    let (cores, subs) = (number("cores")?, number("subs_per_core")?);
    let net = NetShape {
        width: number("deform_width")?,
    };
    let deformation = match meta.get("deformation").map(String::as_str) {
        None | Some("true") => true,
        Some("false") => false,
        Some(other) => {
            return Err(format(format!(
                "metadata deformation is {other:?}; true or false expected"
            )))
        }
    };
    let tensors = safetensors::SafeTensors::deserialize(&bytes).map_err(not_safetensors)?;
    let mut found = HashMap::new();
    for (name, view) in tensors.tensors() {
        if view.dtype() != safetensors::Dtype::F32 {
            return Err(format(format!(
                "{name} is {:?}, f32 expected",
                view.dtype()
            )));
        }
        let values: Vec<f32> = view
            .data()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        found.insert(name, (view.shape().to_vec(), values));
    }
    check_counts(&found, cores, subs, &net).map_err(format)?;
    let params = fill_groups(cores, subs, &net, |name| found.remove(name))
        .map_err(|(_, message)| format(message))?;
    Dmiso::new(cores, subs, net, deformation, params, device.clone()).map_err(format)
}

/// Checks the metadata's counts (`cores`, `subs_per_core`, `deform_width`) against the shapes
/// of the tensors the file holds, before anything is sized from them: a file whose metadata
/// claims more than its tensors hold is refused, not allocated for.
fn check_counts(
    found: &NamedValues,
    cores: usize,
    subs: usize,
    net: &NetShape,
) -> Result<(), String> {
    let expect = |name: &str, want: &[usize]| -> Result<(), String> {
        match found.get(name).map(|(shape, _)| shape.as_slice()) {
            Some(shape) if shape == want => Ok(()),
            Some(shape) => Err(format!(
                "the metadata says cores {cores}, subs_per_core {subs}, deform_width {}, so \
                 {name} should have shape {want:?}; it has {shape:?}",
                net.width
            )),
            None => Err(format!("no tensor {name} (of shape {want:?})")),
        }
    };
    expect("pseudomesh", &[cores, 3, 3])?;
    expect("alpha", &[cores, subs, 3])?;
    for (name, shape) in net.tensors() {
        expect(&format!("deform.{name}"), &shape)?;
    }
    Ok(())
}

/// The groups of a model from its tensors, each looked up by name (`get` gives its shape and
/// values); the error is the name of a missing tensor or of one of another shape, and a
/// message that names it.
fn fill_groups(
    cores: usize,
    subs: usize,
    net: &NetShape,
    mut get: impl FnMut(&str) -> Option<(Vec<usize>, Vec<f32>)>,
) -> Result<DmisoParams, (String, String)> {
    let lens = crate::model::group_lens(cores, subs, net);
    let mut groups: [Vec<f32>; 9] = lens.map(|n| vec![0.0; n]);
    for (name, shape, g, offset) in layout(cores, subs, net) {
        let Some((found, values)) = get(&name) else {
            let message = format!("no tensor {name} (of shape {shape:?})");
            return Err((name, message));
        };
        if found != shape {
            let message = format!(
                "{name} has shape {found:?}; {shape:?} expected for {cores} cores of {subs} \
                 sub-Gaussians and a network of width {}",
                net.width
            );
            return Err((name, message));
        }
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            let message = format!(
                "{name}{:?} is {} (a model's values must be finite numbers)",
                unravel(i, &shape),
                values[i]
            );
            return Err((name, message));
        }
        groups[g][offset..offset + values.len()].copy_from_slice(&values);
    }
    Ok(DmisoParams { groups })
}

/// The index of element `flat` of a row-major tensor of `shape`.
fn unravel(mut flat: usize, shape: &[usize]) -> Vec<usize> {
    let mut index = vec![0; shape.len()];
    for (k, &n) in shape.iter().enumerate().rev() {
        if n > 0 {
            index[k] = flat % n;
            flat /= n;
        }
    }
    index
}

/// Tensors by name: shape and f32 values.
type NamedValues = HashMap<String, (Vec<usize>, Vec<f32>)>;

/// Reads a PyTorch file (`torch.save` of a dict of tensors) through `pytorch_reader`, which
/// checks every length the file declares against the file: every tensor by name, as f32
/// values with their shape. Each tensor's type is checked before its bytes are read, and its
/// size against the file's length (a view may declare more elements than its storage holds:
/// the authors' files hold none), so no allocation exceeds the file.
fn read_pth(path: &Path) -> Result<NamedValues, DmisoFileError> {
    if !path.is_file() {
        return Err(DmisoFileError::Io {
            path: path.to_path_buf(),
            source: std::io::Error::new(std::io::ErrorKind::NotFound, "not found"),
        });
    }
    let checkpoint = |message: String| DmisoFileError::Checkpoint {
        path: path.to_path_buf(),
        message,
    };
    let file_len = std::fs::metadata(path)
        .map_err(|source| DmisoFileError::Io {
            path: path.to_path_buf(),
            source,
        })?
        .len();
    let reader = pytorch_reader::PytorchReader::new(path).map_err(|e| checkpoint(e.to_string()))?;
    reader
        .into_tensors()
        .into_iter()
        .map(|(name, tensor)| {
            let bad = |message| DmisoFileError::Format {
                path: path.to_path_buf(),
                message,
            };
            let dtype = float_dtype(&name, tensor.dtype()).map_err(bad)?;
            if tensor.byte_len() as u64 > file_len {
                return Err(bad(format!(
                    "tensor {name} of shape {:?} claims {} bytes, more than the file's {file_len}",
                    tensor.shape(),
                    tensor.byte_len()
                )));
            }
            let shape = tensor.shape().to_vec();
            let bytes = tensor.read().map_err(|e| checkpoint(e.to_string()))?;
            let values = Tensor::from_raw_buffer(&bytes, dtype, &shape, &Device::Cpu)
                .and_then(|t| t.to_dtype(candle_core::DType::F32))
                .and_then(|t| t.flatten_all())
                .and_then(|t| t.to_vec1::<f32>())
                .map_err(|e| checkpoint(format!("tensor {name}: {e}")))?;
            Ok((name, (shape, values)))
        })
        .collect()
}

/// The candle type of a tensor `name` stored as `dtype`, refused when it is not a float (a
/// checkpoint whose storage was changed to bytes or integers would otherwise be read as those
/// numbers).
fn float_dtype(name: &str, dtype: pytorch_reader::DType) -> Result<candle_core::DType, String> {
    use pytorch_reader::DType as Stored;
    match dtype {
        Stored::F16 => Ok(candle_core::DType::F16),
        Stored::BF16 => Ok(candle_core::DType::BF16),
        Stored::F32 => Ok(candle_core::DType::F32),
        Stored::F64 => Ok(candle_core::DType::F64),
        other => Err(format!(
            "tensor {name} is stored as {other:?}; a model's parameters are floats"
        )),
    }
}

/// Where the authors' code saved one iteration of a model in `dir`.
#[derive(Clone, Debug, PartialEq)]
pub struct AuthorsFiles {
    /// `point_cloud/iteration_<it>/point_cloud.ply` (the cores; only its count is read).
    pub ply: PathBuf,
    /// `point_cloud/iteration_<it>/model_params.pt`.
    pub params: PathBuf,
    /// `deform/iteration_<it>/deform.pth`.
    pub deform: PathBuf,
    /// `time_net/iteration_<it>/deform.pth`.
    pub time_net: PathBuf,
}

impl AuthorsFiles {
    /// The files of iteration `iteration` (`best`, or a number) of the model in `dir`; `None`
    /// takes `best` when it was saved, else the highest numbered iteration.
    pub fn find(dir: &Path, iteration: Option<&str>) -> Result<Self, DmisoFileError> {
        let clouds = dir.join("point_cloud");
        let iteration = match iteration {
            Some(it) => it.to_string(),
            None => latest_iteration(&clouds)?,
        };
        let at = |folder: &str, file: &str| {
            dir.join(folder)
                .join(format!("iteration_{iteration}"))
                .join(file)
        };
        let files = Self {
            ply: at("point_cloud", "point_cloud.ply"),
            params: at("point_cloud", "model_params.pt"),
            deform: at("deform", "deform.pth"),
            time_net: at("time_net", "deform.pth"),
        };
        for path in [&files.ply, &files.params, &files.deform, &files.time_net] {
            if !path.is_file() {
                return Err(DmisoFileError::Format {
                    path: path.clone(),
                    message: format!(
                        "not found: a D-MiSo model saves it at iteration {iteration} (is {} the \
                         folder D-MiSo's train.py wrote with -m?)",
                        dir.display()
                    ),
                });
            }
        }
        Ok(files)
    }
}

/// `best` when `point_cloud/iteration_best` exists, else the highest `iteration_<n>`.
fn latest_iteration(clouds: &Path) -> Result<String, DmisoFileError> {
    let entries = std::fs::read_dir(clouds).map_err(|source| DmisoFileError::Io {
        path: clouds.to_path_buf(),
        source,
    })?;
    let mut best = false;
    let mut highest: Option<u64> = None;
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().to_string();
        match name.strip_prefix("iteration_") {
            Some("best") => best = true,
            Some(n) => {
                if let Ok(n) = n.parse::<u64>() {
                    highest = highest.max(Some(n));
                }
            }
            None => {}
        }
    }
    match (best, highest) {
        (true, _) => Ok("best".into()),
        (false, Some(n)) => Ok(n.to_string()),
        (false, None) => Err(DmisoFileError::Format {
            path: clouds.to_path_buf(),
            message: "holds no iteration_<n> folder".into(),
        }),
    }
}

/// The background a model records: our file's `background` metadata (`R,G,B`), else its
/// `white_background`, or the `white_background` of the `cfg_args` beside the authors' folder;
/// `None` when it records none.
pub fn recorded_background(path: &Path) -> Result<Option<Background>, DmisoFileError> {
    let white_or_black = |white: bool| {
        if white {
            Background::White
        } else {
            Background::Black
        }
    };
    if path.is_dir() {
        return Ok(folder_flag(path, "white_background")?.map(white_or_black));
    }
    // Only the header: an 8-byte length, then the JSON header with the metadata.
    use std::io::Read;
    let not_ours = |what: String| DmisoFileError::Format {
        path: path.to_path_buf(),
        message: format!("not a safetensors file ({what})"),
    };
    let mut file = std::fs::File::open(path).map_err(|source| DmisoFileError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut len = [0u8; 8];
    file.read_exact(&mut len)
        .map_err(|e| not_ours(format!("header length: {e}")))?;
    let len = u64::from_le_bytes(len);
    if len > MAX_HEADER_BYTES {
        return Err(not_ours(format!("a header of {len} bytes")));
    }
    let mut header = vec![0u8; len as usize];
    file.read_exact(&mut header)
        .map_err(|e| not_ours(format!("header: {e}")))?;
    let header: serde_json::Value =
        serde_json::from_slice(&header).map_err(|e| not_ours(format!("header: {e}")))?;
    let metadata = &header["__metadata__"];
    if let Some(rgb) = metadata["background"].as_str() {
        return parse_background(rgb)
            .map(|rgb| Some(Background::from_rgb(rgb)))
            .map_err(|why| DmisoFileError::Format {
                path: path.to_path_buf(),
                message: format!("metadata background: {why}"),
            });
    }
    match metadata["white_background"].as_str() {
        None => Ok(None),
        Some("true") => Ok(Some(Background::White)),
        Some("false") => Ok(Some(Background::Black)),
        Some(other) => Err(DmisoFileError::Format {
            path: path.to_path_buf(),
            message: format!("metadata white_background is {other:?}; true or false expected"),
        }),
    }
}

/// The largest safetensors header read for its metadata (the format's own limit is 100 MB).
const MAX_HEADER_BYTES: u64 = 100_000_000;

/// The boolean `name` of `cfg_args` (a Python `Namespace(a=1, name=True, ...)`); `None` when it
/// has no such argument, an error when its value is not `True` or `False`.
pub fn cfg_flag(cfg_args: &str, name: &str) -> Result<Option<bool>, String> {
    let Some(rest) = ["(", " "]
        .iter()
        .find_map(|before| cfg_args.split(&format!("{before}{name}=")).nth(1))
    else {
        return Ok(None);
    };
    match rest.split([',', ')']).next().unwrap_or_default().trim() {
        "True" => Ok(Some(true)),
        "False" => Ok(Some(false)),
        other => Err(format!("{name}={other}: True or False expected")),
    }
}

/// The boolean `name` of the `cfg_args` beside the authors' model folder `dir`; `None` when
/// there is no `cfg_args` or it does not say; an error naming the file when it says neither
/// `True` nor `False`.
fn folder_flag(dir: &Path, name: &str) -> Result<Option<bool>, DmisoFileError> {
    let Some(text) = cfg_args(dir)? else {
        return Ok(None);
    };
    cfg_flag(&text, name).map_err(|message| DmisoFileError::Format {
        path: dir.join("cfg_args"),
        message,
    })
}

/// Whether the authors' model folder `path` was fitted with `--eval` (its `cfg_args` says
/// `eval=True`: D-MiSo then trained on the train split only); `None` for our model files and
/// for a folder whose `cfg_args` does not say.
pub fn recorded_eval(path: &Path) -> Result<Option<bool>, DmisoFileError> {
    if !path.is_dir() {
        return Ok(None);
    }
    folder_flag(path, "eval")
}

/// The `cfg_args` beside the authors' model folder `dir`; `None` when there is none.
fn cfg_args(dir: &Path) -> Result<Option<String>, DmisoFileError> {
    let cfg = dir.join("cfg_args");
    match std::fs::read_to_string(&cfg) {
        Ok(text) => Ok(Some(text)),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(source) => Err(DmisoFileError::Io { path: cfg, source }),
    }
}

/// Reads the model the authors' code saved (`files`), with its sub-Gaussians, its network on
/// `device`. The network's width is read from its tensors; every tensor must have the shape
/// that width and the model's cores and sub-Gaussians give.
pub fn read_authors(files: &AuthorsFiles, device: &Device) -> Result<Dmiso, DmisoFileError> {
    let mut params = read_pth(&files.params)?;
    let bad = |path: &Path, message: String| DmisoFileError::Format {
        path: path.to_path_buf(),
        message,
    };
    let (cores, subs) = match (params.get("pseudomesh"), params.get("alpha")) {
        (Some((mesh, _)), Some((alpha, _))) if mesh.len() == 3 && alpha.len() == 3 => {
            (mesh[0], alpha[1])
        }
        (None, _) => {
            return Err(bad(
                &files.params,
                "holds no pseudomesh: not a D-MiSo model_params.pt".into(),
            ))
        }
        (Some(_), None) => {
            return Err(bad(
                &files.params,
                "holds no sub-Gaussians (alpha): D-MiSo saved it before creating them (before \
                 densify_until_iter); take a later iteration"
                    .into(),
            ))
        }
        (Some((mesh, _)), Some((alpha, _))) => {
            return Err(bad(
                &files.params,
                format!(
                    "pseudomesh {mesh:?} and alpha {alpha:?}: [G, 3, 3] and [G, K, 3] expected"
                ),
            ))
        }
    };
    let cores_in_ply = ply_vertex_count(&files.ply)?;
    if cores_in_ply != cores {
        return Err(bad(
            &files.ply,
            format!("{cores_in_ply} cores, but model_params.pt holds {cores}: files of two models"),
        ));
    }
    let mut deform = read_pth(&files.deform)?;
    let width =
        match deform.get("timenet.0.weight") {
            Some((shape, _)) if shape.len() == 2 => shape[0],
            _ => return Err(bad(
                &files.deform,
                "holds no timenet.0.weight: not the deformation network of a D-MiSo model of a \
                 synthetic (D-NeRF) scene"
                    .into(),
            )),
        };
    let net = NetShape { width };
    let mut time_net = read_pth(&files.time_net)?;
    let filled = fill_groups(cores, subs, &net, |name| {
        if let Some(n) = name.strip_prefix("deform.") {
            deform.remove(n)
        } else if let Some(n) = name.strip_prefix("time_net.") {
            time_net.remove(n)
        } else {
            params.remove(name)
        }
    });
    let params = filled.map_err(|(name, message)| {
        let path = if name.starts_with("deform.") {
            &files.deform
        } else if name.starts_with("time_net.") {
            &files.time_net
        } else {
            &files.params
        };
        bad(path, message)
    })?;
    Dmiso::new(cores, subs, net, true, params, device.clone()).map_err(|m| bad(&files.params, m))
}

/// The vertex count of a binary PLY's header.
fn ply_vertex_count(path: &Path) -> Result<usize, DmisoFileError> {
    let bytes = std::fs::read(path).map_err(|source| DmisoFileError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let head = &bytes[..bytes.len().min(8192)];
    let text = String::from_utf8_lossy(head);
    if !text.starts_with("ply\n") || !text.contains("end_header") {
        return Err(DmisoFileError::Format {
            path: path.to_path_buf(),
            message: "not a PLY file".into(),
        });
    }
    text.lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .and_then(|n| n.trim().parse().ok())
        .ok_or_else(|| DmisoFileError::Format {
            path: path.to_path_buf(),
            message: "no vertex element".into(),
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every background a model file records comes back: white and black (also as the
    /// white-or-black record older readers take), any other colour by its channels.
    #[test]
    fn the_recorded_background_round_trips() {
        let dir = tempfile::tempdir().unwrap();
        let model = crate::init::initial_model(10, NetShape { width: 4 }, 1, &Device::Cpu).unwrap();
        for (background, white) in [
            (Some(Background::White), Some("true")),
            (Some(Background::Black), Some("false")),
            (Some(Background::Colour([0.25, 0.5, 1.0])), None),
            (None, None),
        ] {
            let path = dir.path().join("model.safetensors");
            save(&model, &path, background).unwrap();
            assert_eq!(recorded_background(&path).unwrap(), background);
            let bytes = std::fs::read(&path).unwrap();
            let len = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
            let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + len]).unwrap();
            assert_eq!(header["__metadata__"]["white_background"].as_str(), white);
        }
    }

    /// The header's objects are in key order, so saving the same model again (with maps of
    /// other hash seeds) gives the same bytes, and the file still loads.
    #[test]
    fn the_same_model_saves_to_the_same_bytes() {
        let dir = tempfile::tempdir().unwrap();
        let model = crate::init::initial_model(10, NetShape { width: 4 }, 1, &Device::Cpu).unwrap();
        let background = Some(Background::Colour([0.25, 0.5, 1.0]));
        let files: Vec<Vec<u8>> = (0..4)
            .map(|i| {
                let path = dir.path().join(format!("model{i}.safetensors"));
                save(&model, &path, background).unwrap();
                std::fs::read(&path).unwrap()
            })
            .collect();
        assert!(files.iter().all(|f| *f == files[0]));
        let len = u64::from_le_bytes(files[0][..8].try_into().unwrap()) as usize;
        let header = std::str::from_utf8(&files[0][8..8 + len]).unwrap();
        let keys = [
            "background",
            "cores",
            "deform_width",
            "deformation",
            "format",
        ];
        let at: Vec<usize> = keys
            .iter()
            .map(|k| header.find(&format!("\"{k}\"")).unwrap())
            .collect();
        assert!(at.windows(2).all(|w| w[0] < w[1]), "{header}");
        assert!(header.starts_with("{\"__metadata__\""), "{header}");
        let path = dir.path().join("model0.safetensors");
        assert_eq!(recorded_background(&path).unwrap(), background);
    }

    /// A small saved model: the folder it is in, its bytes, the header's length and the header.
    fn saved_model() -> (tempfile::TempDir, Vec<u8>, usize, serde_json::Value) {
        let dir = tempfile::tempdir().unwrap();
        let model = crate::init::initial_model(10, NetShape { width: 4 }, 1, &Device::Cpu).unwrap();
        let path = dir.path().join("model.safetensors");
        save(&model, &path, None).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let len = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
        let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + len]).unwrap();
        (dir, bytes, len, header)
    }

    /// A NaN or infinity anywhere in a model file is refused naming its tensor and index.
    #[test]
    fn a_nan_in_a_model_file_is_named_by_tensor_and_index() {
        let (dir, bytes, len, header) = saved_model();
        let mut checked = 0;
        for (name, info) in header.as_object().unwrap() {
            let Some(shape) = info["shape"].as_array() else {
                continue;
            };
            let shape: Vec<usize> = shape.iter().map(|v| v.as_u64().unwrap() as usize).collect();
            if shape.len() != 2 || shape.iter().product::<usize>() < 2 {
                continue;
            }
            let start = info["data_offsets"][0].as_u64().unwrap() as usize;
            // The last element: index [rows - 1, columns - 1].
            let element = shape[0] * shape[1] - 1;
            let at = 8 + len + start + 4 * element;
            for bad in [f32::NAN, f32::INFINITY] {
                let mut broken = bytes.clone();
                broken[at..at + 4].copy_from_slice(&bad.to_le_bytes());
                let file = dir.path().join("broken.safetensors");
                std::fs::write(&file, &broken).unwrap();
                let e = load(&file, &Device::Cpu).unwrap_err().to_string();
                let want = format!("{name}[{}, {}] is {bad}", shape[0] - 1, shape[1] - 1);
                assert!(e.contains(&want) && e.contains("broken.safetensors"), "{e}");
            }
            checked += 1;
        }
        assert!(
            checked >= 2,
            "two-dimensional tensors (the network's weights) checked"
        );
        assert_eq!(unravel(7, &[2, 3, 2]), [1, 0, 1]);
    }

    /// Metadata counts that claim more than the tensors hold are refused naming the tensor,
    /// before anything is sized from them (a huge `cores` once allocated gigabytes).
    #[test]
    fn metadata_counts_are_checked_against_the_tensors_first() {
        let (dir, bytes, len, header) = saved_model();
        for (key, value) in [
            ("cores", "4000000000"),
            ("subs_per_core", "1000000000000"),
            ("deform_width", "3000000000"),
        ] {
            let mut edited = header.clone();
            edited["__metadata__"][key] = value.into();
            let mut text = serde_json::to_vec(&edited).unwrap();
            text.resize(text.len().next_multiple_of(8), b' ');
            let mut file = (text.len() as u64).to_le_bytes().to_vec();
            file.extend(&text);
            file.extend(&bytes[8 + len..]);
            let broken = dir.path().join(format!("{key}.safetensors"));
            std::fs::write(&broken, file).unwrap();
            let e = load(&broken, &Device::Cpu).unwrap_err().to_string();
            assert!(
                e.contains(&format!("{key}.safetensors")) && e.contains("should have shape"),
                "{key}: {e}"
            );
        }
    }

    #[test]
    fn only_float_storages_hold_parameters() {
        use pytorch_reader::DType;
        for dtype in [DType::F16, DType::BF16, DType::F32, DType::F64] {
            assert!(float_dtype("w", dtype).is_ok());
        }
        for dtype in [DType::U8, DType::Bool, DType::I64] {
            let e = float_dtype("deform.linear.0.weight", dtype).unwrap_err();
            assert!(
                e.contains("deform.linear.0.weight") && e.contains("floats"),
                "{e}"
            );
        }
    }

    #[test]
    fn cfg_args_say_the_background() {
        let white = "Namespace(data_device='cuda', white_background=True, is_blender=True)";
        let black = "Namespace(white_background=False)";
        assert_eq!(cfg_flag(white, "white_background"), Ok(Some(true)));
        assert_eq!(cfg_flag(black, "white_background"), Ok(Some(false)));
        assert_eq!(
            cfg_flag("Namespace(eval=True)", "white_background"),
            Ok(None)
        );
        let cfg = "Namespace(eval=True, is_blender=True, load2gpu_on_the_fly=False)";
        assert_eq!(cfg_flag(cfg, "eval"), Ok(Some(true)));
        assert_eq!(
            cfg_flag("Namespace(sh_degree=3, eval=False)", "eval"),
            Ok(Some(false))
        );
        assert_eq!(
            cfg_flag("Namespace(no_eval=True)", "eval"),
            Ok(None),
            "whole names only"
        );
        // Strict: only True and False, whole.
        for bad in ["maybe", "Truex", "'True'", ""] {
            let e = cfg_flag(&format!("Namespace(eval={bad}, x=1)"), "eval").unwrap_err();
            assert!(e.contains(&format!("eval={bad}: True or False")), "{e}");
        }
    }

    #[test]
    fn a_folder_whose_cfg_args_says_maybe_is_refused_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("cfg_args"),
            "Namespace(white_background=maybe, eval=True)",
        )
        .unwrap();
        let e = recorded_background(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("cfg_args") && e.contains("white_background=maybe: True or False"),
            "{e}"
        );
        assert_eq!(recorded_eval(dir.path()).unwrap(), Some(true));
    }
}
