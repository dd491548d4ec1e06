//! Deterministic pseudo-random values (xorshift), for the `auto` precision probe's operands and
//! for tests that must see the same inputs on every run.

/// `len` values in `[-scale, scale)` from `seed` (any seed, 0 included).
pub(crate) fn seeded_values(len: usize, seed: u64, scale: f32) -> Vec<f32> {
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    (0..len)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            ((state >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0) * scale
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_fill_their_range_and_follow_the_seed() {
        let v = seeded_values(10_000, 0, 2.0);
        assert!(v.iter().all(|x| (-2.0..2.0).contains(x)));
        let mean = v.iter().sum::<f32>() / v.len() as f32;
        assert!(mean.abs() < 0.1, "{mean}");
        assert!(v.iter().any(|&x| x > 1.9) && v.iter().any(|&x| x < -1.9));
        assert_eq!(seeded_values(5, 7, 1.0), seeded_values(5, 7, 1.0));
        assert_ne!(seeded_values(5, 7, 1.0), seeded_values(5, 8, 1.0));
    }
}
