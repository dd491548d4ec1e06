//! The scalar type the rasterizer is generic over: `f32` for work, `f64` for the reference that
//! finite-difference tests and error benchmarks compare against.

use std::fmt::Debug;
use std::ops::{Add, AddAssign, Div, DivAssign, Mul, MulAssign, Neg, Sub, SubAssign};

/// A real scalar (`f32` or `f64`) with the handful of operations the rasterizer needs.
pub trait Real:
    Copy
    + Send
    + Sync
    + Debug
    + Default
    + PartialOrd
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + SubAssign
    + MulAssign
    + DivAssign
    + 'static
{
    /// Zero.
    const ZERO: Self;
    /// One.
    const ONE: Self;
    /// Converts from `f64` (rounding for `f32`).
    fn from_f64(v: f64) -> Self;
    /// Converts to `f64` exactly.
    fn to_f64(self) -> f64;
    /// Square root.
    fn sqrt(self) -> Self;
    /// Natural exponential.
    fn exp(self) -> Self;
    /// Natural exponential in straight-line arithmetic that the compiler vectorizes inside a
    /// loop: `f32` by [`crate::vector_exp::exp`] (within 2 ulp of the exact value), `f64` the C
    /// library's, so that the f64 reference stays as exact as before (its loops stay scalar).
    fn exp_in_loop(self) -> Self;
    /// Natural logarithm.
    fn ln(self) -> Self;
    /// Absolute value.
    fn abs(self) -> Self;
    /// Smallest integer not below `self`.
    fn ceil(self) -> Self;
    /// Largest integer not above `self`.
    fn floor(self) -> Self;
    /// True unless NaN or infinite.
    fn is_finite(self) -> bool;
    /// Logistic sigmoid `1 / (1 + e^-x)`, evaluated without overflow for large `|x|`.
    fn sigmoid(self) -> Self;

    /// The smaller of two values (`other` when `self` is NaN).
    #[inline]
    fn min(self, other: Self) -> Self {
        if self < other {
            self
        } else {
            other
        }
    }
    /// The larger of two values (`other` when `self` is NaN).
    #[inline]
    fn max(self, other: Self) -> Self {
        if self > other {
            self
        } else {
            other
        }
    }
    /// `self` limited to `[lo, hi]`.
    #[inline]
    fn clamp(self, lo: Self, hi: Self) -> Self {
        self.max(lo).min(hi)
    }
}

macro_rules! impl_real {
    ($t:ty, $exp_in_loop:path) => {
        impl Real for $t {
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            #[inline]
            fn from_f64(v: f64) -> Self {
                v as $t
            }
            #[inline]
            fn to_f64(self) -> f64 {
                self as f64
            }
            #[inline]
            fn sqrt(self) -> Self {
                <$t>::sqrt(self)
            }
            #[inline]
            fn exp(self) -> Self {
                <$t>::exp(self)
            }
            #[inline(always)]
            fn exp_in_loop(self) -> Self {
                $exp_in_loop(self)
            }
            #[inline]
            fn ln(self) -> Self {
                <$t>::ln(self)
            }
            #[inline]
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
            #[inline]
            fn ceil(self) -> Self {
                <$t>::ceil(self)
            }
            #[inline]
            fn floor(self) -> Self {
                <$t>::floor(self)
            }
            #[inline]
            fn is_finite(self) -> bool {
                <$t>::is_finite(self)
            }
            #[inline]
            fn sigmoid(self) -> Self {
                if self >= 0.0 {
                    1.0 / (1.0 + (-self).exp())
                } else {
                    let e = self.exp();
                    e / (1.0 + e)
                }
            }
        }
    };
}

impl_real!(f32, crate::vector_exp::exp);
impl_real!(f64, f64::exp);

/// Converts a slice of one real type to another.
pub fn cast_slice<A: Real, B: Real>(v: &[A]) -> Vec<B> {
    v.iter().map(|x| B::from_f64(x.to_f64())).collect()
}
