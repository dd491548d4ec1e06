//! `exp` and the logistic sigmoid of f32 in straight-line arithmetic, which the compiler turns
//! into vector code inside CPU loops (the C library's `expf` is one call per element: a tenth
//! of CLIP's CPU time, and an eighth of a CPU fit's, went to it).
//!
//! `exp(x) = 2^n e^r` with `n = round(x / ln 2)` and `r = x - n ln 2` (ln 2 in two parts, so `r`
//! carries no rounding of `n ln 2`), `e^r` by the degree-7 polynomial of Cephes' `expf` on
//! `|r| <= ln 2 / 2`, `2^n` written into the exponent bits. Within 2 ulp of the exact value on
//! f32's normal range (tested against f64 over all of it); 0 where the exact value is below
//! f32's normal range (`x < -87.34`), infinity where it overflows, NaN for NaN.

/// `e^x` of f32 (the module's doc gives the method and the error).
#[inline(always)]
pub fn exp(x: f32) -> f32 {
    const LOG2_E: f32 = std::f32::consts::LOG2_E;
    // ln 2 = LN2_HI + LN2_LO, LN2_HI with 9 significant bits so `n * LN2_HI` is exact.
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    // Adding 1.5 * 2^23 rounds to an integer (to nearest, ties to even), which then sits in the
    // low mantissa bits.
    const ROUND: f32 = 12_582_912.0;
    // ln(2^-126) and ln(f32::MAX).
    const LOWEST: f32 = -87.336_55;
    const HIGHEST: f32 = 88.722_84;
    // n from -126 to 128 on f32's normal range (clamped beyond it, where the result is
    // replaced below).
    let t = (x * LOG2_E).clamp(-126.0, 128.0);
    let shifted = t + ROUND;
    let n_float = shifted - ROUND;
    let r = (x - n_float * LN2_HI) - n_float * LN2_LO;
    let p = ((((((1.987_569_1e-4 * r + 1.398_199_9e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2)
        * r
        + 1.666_666_5e-1)
        * r
        + 0.5)
        * r)
        * r
        + r
        + 1.0;
    // 2^n as 2^h 2^(n - h), h = floor(n / 2): each factor a normal f32 (2^128 is not), each
    // product exact.
    let n = shifted.to_bits() as i32 - ROUND.to_bits() as i32;
    let h = n >> 1;
    let power = |k: i32| f32::from_bits(((k + 127) as u32) << 23);
    let value = p * power(h) * power(n - h);
    if x < LOWEST {
        0.0
    } else if x > HIGHEST {
        f32::INFINITY
    } else if x.is_nan() {
        x
    } else {
        value
    }
}

/// `1 / (1 + e^-z)` of f32 by [`exp`]: 0 and 1 at the infinities, NaN for NaN.
#[inline(always)]
pub fn sigmoid(z: f32) -> f32 {
    1.0 / (1.0 + exp(-z))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Distance in units in the last place between `got` and the f32 nearest `exact`.
    fn ulps(got: f32, exact: f64) -> u32 {
        let want = exact as f32;
        (got.to_bits() as i64 - want.to_bits() as i64).unsigned_abs() as u32
    }

    #[test]
    fn exp_is_within_two_ulp_over_the_normal_range() {
        let (lowest, highest) = (-87.336_55f32, 88.722_84f32);
        let mut worst = 0;
        let mut x = lowest;
        while x <= highest {
            for y in [x, x.next_up(), -x.abs() * 1e-3, x * 1e-6] {
                let exact = f64::from(y).exp();
                if exact >= f64::from(f32::MIN_POSITIVE) && exact <= f64::from(f32::MAX) {
                    worst = worst.max(ulps(exp(y), exact));
                }
            }
            x += 1.0e-3 * (1.0 + x.abs());
        }
        // The top, where n is 128.
        for y in [88.0f32, 88.03, 88.3, 88.5, 88.72, highest] {
            worst = worst.max(ulps(exp(y), f64::from(y).exp()));
        }
        assert!(worst <= 2, "{worst} ulp");
        assert_eq!(exp(0.0), 1.0);
    }

    #[test]
    fn exp_underflows_to_zero_overflows_to_infinity_and_keeps_nan() {
        assert_eq!(exp(f32::NEG_INFINITY), 0.0);
        assert_eq!(exp(-88.0), 0.0);
        assert_eq!(exp(-1e30), 0.0);
        assert_eq!(exp(89.0), f32::INFINITY);
        assert_eq!(exp(f32::INFINITY), f32::INFINITY);
        assert!(exp(f32::NAN).is_nan());
    }

    #[test]
    fn sigmoid_matches_f64_and_saturates() {
        let mut z = -30f32;
        while z <= 30.0 {
            let exact = 1.0 / (1.0 + (-f64::from(z)).exp());
            assert!(
                (f64::from(sigmoid(z)) - exact).abs() <= 4e-7 * exact,
                "{z}: {} vs {exact}",
                sigmoid(z)
            );
            z += 0.01;
        }
        assert_eq!(sigmoid(f32::INFINITY), 1.0);
        assert_eq!(sigmoid(f32::NEG_INFINITY), 0.0);
        assert_eq!(sigmoid(-200.0), 0.0);
        assert_eq!(sigmoid(200.0), 1.0);
        assert!(sigmoid(f32::NAN).is_nan());
    }
}
