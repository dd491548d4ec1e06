//! VeGaS's global time function: frame `f` of `F` sits at time
//! `t_f = sum_{j < f} softmax(logits)_j` for `F - 1` learned logits, so `t_0 = 0`,
//! `t_{F-1} = 1`, and the gaps between frames are learned. Equal logits (VeGaS initialises them
//! to ones) give uniform times `f / (F - 1)`.

use gs_core::Real;

/// The times of all `logits.len() + 1` frames.
pub fn frame_times<T: Real>(logits: &[T]) -> Vec<T> {
    let p = softmax(logits);
    let mut times = Vec::with_capacity(logits.len() + 1);
    let mut t = T::from_f64(0.0);
    times.push(t);
    for pj in p {
        t += pj;
        times.push(t);
    }
    times
}

/// The time of frame `frame` alone (`frame <= logits.len()`).
pub fn frame_time<T: Real>(logits: &[T], frame: usize) -> T {
    softmax(logits)
        .into_iter()
        .take(frame)
        .fold(T::from_f64(0.0), |a, b| a + b)
}

/// Adds to `out` (`[F - 1]`) the gradient with respect to the logits of a loss whose gradient
/// with respect to `t_frame` is `grad_t`: `dt_f / dl_k = p_k ([k < f] - t_f)`.
pub fn add_time_grads<T: Real>(logits: &[T], frame: usize, grad_t: T, out: &mut [T]) {
    let p = softmax(logits);
    let t = p.iter().take(frame).fold(T::from_f64(0.0), |a, &b| a + b);
    for (k, (pk, o)) in p.into_iter().zip(out.iter_mut()).enumerate() {
        let inside = if k < frame {
            T::from_f64(1.0)
        } else {
            T::from_f64(0.0)
        };
        *o += grad_t * pk * (inside - t);
    }
}

/// Softmax with the maximum subtracted (no overflow at any finite logit).
fn softmax<T: Real>(logits: &[T]) -> Vec<T> {
    let max = logits
        .iter()
        .copied()
        .fold(T::from_f64(f64::NEG_INFINITY), T::max);
    let e: Vec<T> = logits.iter().map(|&l| (l - max).exp()).collect();
    let sum = e.iter().fold(T::from_f64(0.0), |a, &b| a + b);
    e.into_iter().map(|v| v / sum).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn equal_logits_give_uniform_times_from_zero_to_one() {
        let times = frame_times(&[1.0f64; 4]);
        assert_eq!(times.len(), 5);
        for (f, t) in times.iter().enumerate() {
            assert!((t - f as f64 / 4.0).abs() < 1e-15, "frame {f}: {t}");
        }
        assert_eq!(frame_time(&[1.0f64; 4], 3), times[3]);
        // A single frame has no logits and sits at 0.
        assert_eq!(frame_times::<f64>(&[]), vec![0.0]);
    }

    #[test]
    fn huge_logits_do_not_overflow() {
        let times = frame_times(&[1000.0f64, -1000.0, 0.0]);
        assert!(times.iter().all(|t| t.is_finite()));
        assert!((times[1] - 1.0).abs() < 1e-12 && (times[3] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn time_gradient_matches_finite_differences() {
        let logits = [0.3f64, -1.2, 2.0, 0.0, 0.7];
        for frame in 0..=logits.len() {
            let mut grad = vec![0.0; logits.len()];
            add_time_grads(&logits, frame, 1.7, &mut grad);
            for k in 0..logits.len() {
                let h = 1e-6;
                let (mut up, mut down) = (logits, logits);
                up[k] += h;
                down[k] -= h;
                let fd = 1.7 * (frame_time(&up, frame) - frame_time(&down, frame)) / (2.0 * h);
                assert!(
                    (grad[k] - fd).abs() < 1e-8,
                    "frame {frame} logit {k}: {} vs {fd}",
                    grad[k]
                );
            }
        }
    }
}
