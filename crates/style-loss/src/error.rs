//! The error type of this crate.

use std::path::PathBuf;

/// Everything that can go wrong while loading models or computing the style losses.
#[derive(Debug, thiserror::Error)]
pub enum StyleLossError {
    /// A candle operation failed (shape mismatch inside an op, device error, ...).
    #[error("candle: {0}")]
    Candle(#[from] candle_core::Error),
    /// A file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A file (model config, tokenizer, weights) could not be parsed.
    #[error("cannot parse {path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// What the parser said.
        message: String,
    },
    /// A tensor of a weight file was read but could not be made into an f32 tensor on its
    /// device (a format conversion, or the device's memory).
    #[error("{path}: tensor `{tensor}`: {source}")]
    TensorLoad {
        /// The weight file.
        path: PathBuf,
        /// The tensor name in the checkpoint layout.
        tensor: String,
        /// What candle said (boxed: it is large, and this variant rare).
        source: Box<candle_core::Error>,
    },
    /// A weight file lacks a tensor the model needs.
    #[error("{source_name}: missing tensor `{tensor}`")]
    MissingTensor {
        /// The weight file (or a description of where the tensors came from).
        source_name: String,
        /// The tensor name in the checkpoint layout.
        tensor: String,
    },
    /// A tensor of a weight file has the wrong shape for the configured model.
    #[error("{source_name}: tensor `{tensor}` has shape {found:?}, expected {expected:?}")]
    TensorShape {
        /// The weight file (or a description of where the tensors came from).
        source_name: String,
        /// The tensor name in the checkpoint layout.
        tensor: String,
        /// The shape in the file.
        found: Vec<usize>,
        /// The shape the configuration implies.
        expected: Vec<usize>,
    },
    /// A configuration value is invalid.
    #[error("invalid configuration: {field} = {value}: {reason}")]
    Config {
        /// The field, e.g. `vision_config.hidden_size`.
        field: String,
        /// The offending value.
        value: String,
        /// Why it is rejected.
        reason: String,
    },
    /// An input tensor has an unsupported shape or value.
    #[error("invalid input `{name}`: {reason}")]
    Input {
        /// The argument name.
        name: String,
        /// What is wrong with it.
        reason: String,
    },
    /// The tokenizer failed.
    #[error("tokenizer {path}: {message}")]
    Tokenizer {
        /// The tokenizer.json file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// A weight file could not be found anywhere.
    #[error(
        "cannot find `{file}` of the Hugging Face repository `{repo}` (revision `{revision}`). \
         Tried: {tried}. Download it from https://huggingface.co/{repo} and either pass its path, \
         set the environment variable {env_var} to it, or put it in the Hugging Face cache \
         ($HF_HUB_CACHE, $HF_HOME/hub or ~/.cache/huggingface/hub)"
    )]
    WeightsNotFound {
        /// The repository, e.g. `openai/clip-vit-base-patch32`.
        repo: String,
        /// The revision looked up in the cache.
        revision: String,
        /// The file name in the repository.
        file: String,
        /// The environment variable that may name the file.
        env_var: String,
        /// The places that were looked at, in order.
        tried: String,
    },
    /// A computed value is NaN or infinite.
    #[error("non-finite value in {what}")]
    NonFinite {
        /// Which quantity.
        what: String,
    },
}

/// Result alias of this crate.
pub type Result<T> = std::result::Result<T, StyleLossError>;
