//! Which views each training step renders: batches of view indices, drawn in the order of a
//! [`BatchOrder`] from a seeded stream, so that a run (and a resumed one) is reproducible.

use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The views of one training step, and what their summed loss is divided by.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Batch {
    /// View indices, in the order they are rendered.
    pub views: Vec<usize>,
    /// The sampler's batch size: the step's losses and gradients are summed and divided by it,
    /// also when the epoch's last batch of [`BatchOrder::Consecutive`] is shorter (the authors'
    /// `batch_loss / BATCH_SIZE`).
    pub divisor: usize,
}

/// How a [`ViewSampler`] groups views into the batches of steps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BatchOrder {
    /// Each batch is the next views of a shuffle-without-replacement stream (every view once
    /// per epoch, a fresh random order each epoch).
    Shuffled,
    /// CLIPGaussian's 4D batches (and D-MiSo's): each batch is `B` consecutive entries of the
    /// views not yet drawn this epoch, kept in dataset order (neighbouring cameras and times),
    /// from a start drawn uniformly in `0..=max(0, left - B)`; so a batch may join views either
    /// side of an earlier batch, and the epoch's last one may be shorter than `B` (its loss is
    /// still divided by `B`, as the authors' `batch_loss / BATCH_SIZE`). The list refills when
    /// empty.
    Consecutive,
    /// D-MiSo's fit: the [`BatchOrder::Consecutive`] rule over the views in an order shuffled
    /// once, when the sampler is made (its `Scene(..., shuffle=True)` shuffles the camera list
    /// at load), the same order every epoch.
    ConsecutiveShuffledOnce,
}

/// Draws the views of each training step: batches of `batch` view indices in a
/// [`BatchOrder`]. Deterministic for a seed.
#[derive(Clone, Debug)]
pub struct ViewSampler {
    rng: ChaCha8Rng,
    count: usize,
    batch: usize,
    order: BatchOrder,
    /// The views of an epoch in the order runs are cut from (consecutive orders).
    epoch: Vec<usize>,
    pending: Vec<usize>,
}

impl ViewSampler {
    /// A sampler of one view per step, shuffled without replacement over `count` views.
    ///
    /// # Panics
    /// If `count` is 0.
    pub fn new(count: usize, seed: u64) -> Self {
        Self::batches(count, 1, BatchOrder::Shuffled, seed)
    }

    /// A sampler of `batch` views per step over `count` views, in `order`.
    ///
    /// # Panics
    /// If `count` or `batch` is 0.
    pub fn batches(count: usize, batch: usize, order: BatchOrder, seed: u64) -> Self {
        assert!(count > 0, "a view sampler needs at least one view");
        assert!(batch > 0, "a batch holds at least one view");
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut epoch: Vec<usize> = (0..count).collect();
        if order == BatchOrder::ConsecutiveShuffledOnce {
            epoch.shuffle(&mut rng);
        }
        Self {
            rng,
            count,
            batch,
            order,
            epoch,
            pending: Vec::new(),
        }
    }

    /// The same sampler after `steps` batches were drawn, so that a resumed run sees the view
    /// order of an uninterrupted one.
    pub fn advanced(mut self, steps: u64) -> Self {
        for _ in 0..steps {
            self.next_batch();
        }
        self
    }

    /// Number of views it draws from.
    pub fn count(&self) -> usize {
        self.count
    }

    /// Views per step.
    pub fn batch_size(&self) -> usize {
        self.batch
    }

    /// The next view of a shuffle-without-replacement stream ([`BatchOrder::Shuffled`]);
    /// refills and reshuffles when the epoch is used up.
    pub fn next_view(&mut self) -> usize {
        debug_assert_eq!(
            self.order,
            BatchOrder::Shuffled,
            "next_view draws single views"
        );
        if self.pending.is_empty() {
            self.pending = (0..self.count).collect();
            self.pending.shuffle(&mut self.rng);
        }
        self.pending.pop().expect("refilled above")
    }

    /// The views of the next step ([`BatchOrder`]).
    pub fn next_batch(&mut self) -> Batch {
        let views = match self.order {
            BatchOrder::Shuffled => (0..self.batch).map(|_| self.next_view()).collect(),
            BatchOrder::Consecutive | BatchOrder::ConsecutiveShuffledOnce => {
                if self.pending.is_empty() {
                    self.pending = self.epoch.clone();
                }
                let left = self.pending.len();
                let start = self.rng.random_range(0..=left.saturating_sub(self.batch));
                let end = (start + self.batch).min(left);
                self.pending.drain(start..end).collect()
            }
        };
        Batch {
            views,
            divisor: self.batch,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn consecutive_batches_are_runs_of_the_views_left_from_a_uniform_start() {
        let mut s = ViewSampler::batches(7, 3, BatchOrder::Consecutive, 1);
        for _ in 0..5 {
            // One epoch: runs of increasing views, every view once, the last run maybe short.
            let mut left: Vec<usize> = (0..7).collect();
            while !left.is_empty() {
                let batch = s.next_batch().views;
                assert_eq!(batch.len(), 3.min(left.len()), "{batch:?} of {left:?}");
                let start = left.iter().position(|&v| v == batch[0]).unwrap();
                assert_eq!(
                    batch,
                    left[start..start + batch.len()],
                    "consecutive in {left:?}"
                );
                left.drain(start..start + batch.len());
            }
        }
        // The start is uniform over 0..=left-B: every start of a 7-view epoch occurs.
        let starts: std::collections::BTreeSet<usize> = (0..200)
            .map(|seed| {
                ViewSampler::batches(7, 3, BatchOrder::Consecutive, seed)
                    .next_batch()
                    .views[0]
            })
            .collect();
        assert_eq!(starts.into_iter().collect::<Vec<_>>(), vec![0, 1, 2, 3, 4]);
        // Shuffled once: the same runs rule over one fixed permutation, every epoch.
        let mut once = ViewSampler::batches(7, 3, BatchOrder::ConsecutiveShuffledOnce, 1);
        let order = once.epoch.clone();
        assert_ne!(order, (0..7).collect::<Vec<_>>());
        for _ in 0..5 {
            let mut left = order.clone();
            while !left.is_empty() {
                let batch = once.next_batch().views;
                let start = left.iter().position(|&v| v == batch[0]).unwrap();
                assert_eq!(batch, left[start..start + batch.len()], "runs of {left:?}");
                left.drain(start..start + batch.len());
            }
        }
        let mut shuffled = ViewSampler::batches(4, 2, BatchOrder::Shuffled, 2);
        let mut epoch: Vec<usize> = (0..2).flat_map(|_| shuffled.next_batch().views).collect();
        epoch.sort_unstable();
        assert_eq!(epoch, vec![0, 1, 2, 3]);
    }

    #[test]
    fn sampler_visits_every_view_once_per_epoch() {
        let mut s = ViewSampler::new(5, 3);
        for _ in 0..4 {
            let mut seen: Vec<usize> = (0..5).map(|_| s.next_view()).collect();
            seen.sort_unstable();
            assert_eq!(seen, vec![0, 1, 2, 3, 4]);
        }
    }

    #[test]
    fn resumed_sampler_continues_the_same_sequence() {
        let mut full = ViewSampler::new(7, 11);
        let all: Vec<usize> = (0..30).map(|_| full.next_view()).collect();
        let mut resumed = ViewSampler::new(7, 11).advanced(12);
        let rest: Vec<usize> = (0..18).map(|_| resumed.next_view()).collect();
        assert_eq!(rest, all[12..]);
        let mut other = ViewSampler::new(7, 12);
        let other_seq: Vec<usize> = (0..30).map(|_| other.next_view()).collect();
        assert_ne!(other_seq, all);
    }
}
