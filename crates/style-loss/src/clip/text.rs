//! CLIP's text tower (Hugging Face `CLIPTextTransformer`) up to the pooled end-of-text token.

use candle_core::{Device, Tensor};

use super::config::ClipTextConfig;
use super::transformer::{load_layer_norm, Encoder, EncoderShape};
use super::ClipPrecision;
use crate::error::{Result, StyleLossError};
use crate::nn::LayerNorm;
use crate::tensor_file::NamedTensors;

/// The eos id of legacy OpenAI configs; transformers then pools at the largest token id.
const LEGACY_EOS_TOKEN_ID: u32 = 2;

/// The causal text transformer.
#[derive(Clone, Debug)]
pub(crate) struct TextTower {
    config: ClipTextConfig,
    token_embedding: Tensor,
    position_embedding: Tensor,
    encoder: Encoder,
    final_layer_norm: LayerNorm,
}

impl TextTower {
    /// Loads `text_model.*`, the matrices and embeddings converted to `precision`'s formats.
    pub(crate) fn load(
        w: &NamedTensors,
        config: &ClipTextConfig,
        precision: ClipPrecision,
    ) -> Result<Self> {
        let dtype = precision.activation_dtype();
        let h = config.hidden_size;
        Ok(Self {
            token_embedding: w
                .get(
                    "text_model.embeddings.token_embedding.weight",
                    &[config.vocab_size, h],
                )?
                .to_dtype(dtype)?,
            position_embedding: w
                .get(
                    "text_model.embeddings.position_embedding.weight",
                    &[config.max_position_embeddings, h],
                )?
                .to_dtype(dtype)?,
            encoder: Encoder::load(
                w,
                "text_model.encoder",
                EncoderShape {
                    hidden: h,
                    intermediate: config.intermediate_size,
                    layers: config.num_hidden_layers,
                    heads: config.num_attention_heads,
                    activation: config.hidden_act,
                    layer_norm_eps: config.layer_norm_eps,
                    precision,
                },
            )?,
            final_layer_norm: load_layer_norm(
                w,
                "text_model.final_layer_norm",
                h,
                config.layer_norm_eps,
            )?,
            config: config.clone(),
        })
    }

    /// The position whose output is pooled, as transformers chooses it.
    fn pool_position(&self, ids: &[u32]) -> usize {
        if self.config.eos_token_id == LEGACY_EOS_TOKEN_ID {
            // argmax; the first maximum on ties, as torch.argmax.
            let max = ids.iter().copied().max().unwrap_or(0);
            ids.iter().position(|&id| id == max).unwrap_or(0)
        } else {
            ids.iter()
                .position(|&id| id == self.config.eos_token_id)
                .unwrap_or(0)
        }
    }

    /// Pooled output `[rows, hidden]` for rows of token ids (each at most the context length).
    ///
    /// Attention is causal, so the pooled token depends only on the tokens up to it: rows run in
    /// a few batches of close lengths ([`length_groups`]), each cut after its last pooled
    /// position, which changes nothing but the cost (the templates of a prompt range from 8 to
    /// 26 tokens).
    pub(crate) fn forward(&self, ids: &[Vec<u32>], device: &Device) -> Result<Tensor> {
        let context = self.config.max_position_embeddings;
        let input_error = |reason: String| StyleLossError::Input {
            name: "token ids".into(),
            reason,
        };
        if ids.is_empty() {
            return Err(input_error("no sequences".into()));
        }
        for (row, seq) in ids.iter().enumerate() {
            if seq.is_empty() || seq.len() > context {
                return Err(input_error(format!(
                    "row {row} has {} tokens, expected 1..={context}",
                    seq.len()
                )));
            }
            if let Some(&bad) = seq
                .iter()
                .find(|&&id| id as usize >= self.config.vocab_size)
            {
                return Err(input_error(format!(
                    "row {row} has token id {bad} >= vocab_size {}",
                    self.config.vocab_size
                )));
            }
        }
        let pooled: Vec<usize> = ids.iter().map(|seq| self.pool_position(seq)).collect();
        // Rows in a few groups of close lengths, each cut after its own last pooled position.
        let groups = length_groups(&pooled, LENGTH_GROUPS);
        let mut outputs = Vec::with_capacity(groups.len());
        let mut place = vec![0u32; ids.len()];
        let mut next = 0u32;
        for group in &groups {
            let group_ids: Vec<&[u32]> = group.iter().map(|&r| ids[r].as_slice()).collect();
            let group_pooled: Vec<usize> = group.iter().map(|&r| pooled[r]).collect();
            outputs.push(self.forward_cut(&group_ids, &group_pooled, device)?);
            for &r in group {
                place[r] = next;
                next += 1;
            }
        }
        let outputs = Tensor::cat(&outputs, 0)?;
        Ok(outputs.index_select(&Tensor::new(place, device)?, 0)?)
    }

    /// Pooled outputs `[rows, hidden]` of checked rows of token ids, pooled at `pooled`, the
    /// sequences cut after the last pooled position.
    fn forward_cut(&self, ids: &[&[u32]], pooled: &[usize], device: &Device) -> Result<Tensor> {
        let len = pooled.iter().max().copied().unwrap_or(0) + 1;
        let rows = ids.len();
        let flat: Vec<u32> = ids
            .iter()
            .flat_map(|seq| (0..len).map(move |i| seq.get(i).copied().unwrap_or(0)))
            .collect();
        let h = self.config.hidden_size;
        let flat = Tensor::from_vec(flat, rows * len, device)?;
        let x = self
            .token_embedding
            .index_select(&flat, 0)?
            .reshape((rows, len, h))?
            .broadcast_add(&self.position_embedding.narrow(0, 0, len)?)?;
        let mask: Vec<f32> = (0..len * len)
            .map(|i| {
                if i % len > i / len {
                    f32::NEG_INFINITY
                } else {
                    0.0
                }
            })
            .collect();
        let mask = Tensor::from_vec(mask, (len, len), device)?;
        let x = self.encoder.forward(&x, Some(&mask))?;
        let x = self
            .final_layer_norm
            .forward(&x)?
            .reshape((rows * len, h))?;
        let rows_at: Vec<u32> = pooled
            .iter()
            .enumerate()
            .map(|(row, &p)| (row * len + p) as u32)
            .collect();
        Ok(x.index_select(&Tensor::new(rows_at, device)?, 0)?)
    }
}

/// Batches of rows the text tower runs apart ([`TextTower::forward`]).
const LENGTH_GROUPS: usize = 4;

/// Splits the rows, whose pooled positions are `pooled`, into at most `groups` sets of rows of
/// consecutive lengths that pad the fewest tokens (each row padded to its set's longest; by
/// dynamic programming over the distinct lengths). Each set lists its rows in increasing order.
fn length_groups(pooled: &[usize], groups: usize) -> Vec<Vec<usize>> {
    let mut lengths: Vec<usize> = pooled.to_vec();
    lengths.sort_unstable();
    lengths.dedup();
    let count = |len: usize| pooled.iter().filter(|&&p| p == len).count();
    let counts: Vec<usize> = lengths.iter().map(|&l| count(l)).collect();
    let n = lengths.len();
    // cost(i, j): the tokens of lengths i..j padded to lengths[j - 1] (+ 1 for the pooled one).
    let cost = |i: usize, j: usize| counts[i..j].iter().sum::<usize>() * (lengths[j - 1] + 1);
    // best[g][j]: fewest tokens for the first j lengths in g sets; cut[g][j]: where the last starts.
    let sets = groups.clamp(1, n.max(1));
    let mut best = vec![vec![usize::MAX; n + 1]; sets + 1];
    let mut cut = vec![vec![0usize; n + 1]; sets + 1];
    best[0][0] = 0;
    for g in 1..=sets {
        for j in 1..=n {
            for i in (g - 1)..j {
                if best[g - 1][i] == usize::MAX {
                    continue;
                }
                let total = best[g - 1][i] + cost(i, j);
                if total < best[g][j] {
                    best[g][j] = total;
                    cut[g][j] = i;
                }
            }
        }
    }
    let g = (1..=sets).min_by_key(|&g| best[g][n]).unwrap_or(1);
    let mut bounds = Vec::with_capacity(g);
    let (mut g, mut j) = (g, n);
    while g > 0 && j > 0 {
        let i = cut[g][j];
        bounds.push(lengths[i]..=lengths[j - 1]);
        j = i;
        g -= 1;
    }
    bounds.reverse();
    bounds
        .into_iter()
        .map(|range| {
            (0..pooled.len())
                .filter(|&r| range.contains(&pooled[r]))
                .collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::length_groups;

    #[test]
    fn length_groups_pad_the_fewest_tokens_and_keep_every_row_once() {
        // The style prompt's template lengths of the main job (pooled positions).
        let mut pooled = Vec::new();
        for (len, n) in [
            (8, 1),
            (11, 2),
            (13, 10),
            (16, 14),
            (17, 16),
            (18, 16),
            (26, 2),
        ] {
            pooled.extend(std::iter::repeat_n(len - 1, n));
        }
        pooled.reverse();
        let groups = length_groups(&pooled, 4);
        assert!(groups.len() <= 4);
        let mut seen: Vec<usize> = groups.iter().flatten().copied().collect();
        seen.sort_unstable();
        assert_eq!(seen, (0..pooled.len()).collect::<Vec<_>>());
        let padded = |groups: &[Vec<usize>]| -> usize {
            groups
                .iter()
                .map(|g| g.len() * (g.iter().map(|&r| pooled[r]).max().unwrap() + 1))
                .sum()
        };
        // Every split into at most 4 runs of the 7 sorted lengths pads at least as many.
        let lengths = [7, 10, 12, 15, 16, 17, 25];
        let mut fewest = usize::MAX;
        for a in 1..7 {
            for b in a..7 {
                for c in b..7 {
                    let cuts = [0, a, b, c, 7];
                    let total: usize = cuts
                        .windows(2)
                        .filter(|w| w[0] < w[1])
                        .map(|w| {
                            let top = lengths[w[1] - 1] + 1;
                            let rows = pooled
                                .iter()
                                .filter(|&&p| p >= lengths[w[0]] && p <= lengths[w[1] - 1])
                                .count();
                            rows * top
                        })
                        .sum();
                    fewest = fewest.min(total);
                }
            }
        }
        assert_eq!(padded(&groups), fewest);
        assert!(
            fewest < pooled.len() * 26,
            "grouping pads less than one batch"
        );
        // One length, one row: one group.
        assert_eq!(length_groups(&[3, 3, 3], 4), vec![vec![0, 1, 2]]);
        assert_eq!(length_groups(&[0], 4), vec![vec![0]]);
    }
}
