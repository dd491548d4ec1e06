//! CLIP's byte-level BPE tokenizer, from a Hugging Face `tokenizer.json`, with CLIP's framing:
//! start token, text, end token, then end tokens as padding up to the context length (77);
//! longer texts are truncated so that the start and end tokens still fit.

use std::path::{Path, PathBuf};

use tokenizers::{PaddingDirection, PaddingParams, PaddingStrategy, Tokenizer, TruncationParams};

use crate::error::{Result, StyleLossError};

/// CLIP's start-of-text token.
pub const START_TOKEN: &str = "<|startoftext|>";
/// CLIP's end-of-text token, also used for padding.
pub const END_TOKEN: &str = "<|endoftext|>";
/// CLIP's context length.
pub const CONTEXT_LENGTH: usize = 77;

/// A tokenizer producing rows of exactly [`CONTEXT_LENGTH`] token ids.
#[derive(Clone, Debug)]
pub struct ClipTokenizer {
    inner: Tokenizer,
    path: PathBuf,
    end_token_id: u32,
}

impl ClipTokenizer {
    /// Reads a Hugging Face `tokenizer.json` of a CLIP model (e.g. that of
    /// `openai/clip-vit-base-patch32`) and sets up padding and truncation.
    pub fn from_file(path: &Path) -> Result<Self> {
        let error = |message: String| StyleLossError::Tokenizer {
            path: path.to_path_buf(),
            message,
        };
        let mut inner = Tokenizer::from_file(path).map_err(|e| error(e.to_string()))?;
        let token_id = |token: &str| {
            inner
                .token_to_id(token)
                .ok_or_else(|| error(format!("the vocabulary has no `{token}`")))
        };
        token_id(START_TOKEN)?;
        let end_token_id = token_id(END_TOKEN)?;
        inner
            .with_truncation(Some(TruncationParams {
                max_length: CONTEXT_LENGTH,
                ..TruncationParams::default()
            }))
            .map_err(|e| error(e.to_string()))?;
        inner.with_padding(Some(PaddingParams {
            strategy: PaddingStrategy::Fixed(CONTEXT_LENGTH),
            direction: PaddingDirection::Right,
            pad_to_multiple_of: None,
            pad_id: end_token_id,
            pad_type_id: 0,
            pad_token: END_TOKEN.to_string(),
        }));
        Ok(Self {
            inner,
            path: path.to_path_buf(),
            end_token_id,
        })
    }

    /// The id of [`END_TOKEN`].
    pub fn end_token_id(&self) -> u32 {
        self.end_token_id
    }

    /// Token ids of `text`: exactly [`CONTEXT_LENGTH`] of them.
    pub fn encode(&self, text: &str) -> Result<Vec<u32>> {
        let encoding = self
            .inner
            .encode(text, true)
            .map_err(|e| StyleLossError::Tokenizer {
                path: self.path.clone(),
                message: format!("cannot encode {text:?}: {e}"),
            })?;
        Ok(encoding.get_ids().to_vec())
    }

    /// Token id rows of several texts.
    pub fn encode_all(&self, texts: &[String]) -> Result<Vec<Vec<u32>>> {
        texts.iter().map(|t| self.encode(t)).collect()
    }
}
