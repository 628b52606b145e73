//! The floating-point types the fit runs on: `f32` on the device, `f64` on the host.

use core::fmt::Debug;
use core::ops::{Add, AddAssign, Div, Mul, Neg, Sub, SubAssign};

/// A binary floating-point type with IEEE round-to-nearest arithmetic.
///
/// Only what the fit needs. `sin_cos_octant` is the one function whose implementation
/// differs by type: see its docs.
pub trait Real:
    Copy
    + Debug
    + PartialOrd
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + SubAssign
{
    /// 0
    const ZERO: Self;
    /// 1
    const ONE: Self;
    /// π/4, correctly rounded
    const FRAC_PI_4: Self;
    /// Unit roundoff u = 2^-p (half an ulp of 1)
    const EPSILON: Self;
    /// Dekker's splitting constant 2^⌈p/2⌉ + 1, for exact products without FMA.
    const SPLITTER: Self;

    /// Nearest value to `x`.
    fn from_f64(x: f64) -> Self;
    /// Nearest value to `x` (round to nearest even, as `as` does).
    fn from_u64(x: u64) -> Self;
    /// Exact widening to f64.
    fn to_f64(self) -> f64;
    /// Square root (correctly rounded, from libm).
    fn sqrt(self) -> Self;
    /// Absolute value.
    fn abs(self) -> Self;
    /// Whether the value is neither NaN nor infinite.
    fn is_finite(self) -> bool;
    /// `(sin x, cos x)` for `0 ≤ x ≤ π/4`.
    ///
    /// For `f32` this is a polynomial evaluated in `f32`, because libm's `sinf`/`cosf`
    /// work in `f64`, which the Cortex-M4F can only emulate in software (hundreds of
    /// instructions each, beyond the per-sample budget). On `[0, π/4]` the truncated
    /// Taylor series errs by < 3e-9, below f32's resolution. For `f64` it is libm.
    fn sin_cos_octant(x: Self) -> (Self, Self);
}

impl Real for f32 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    const FRAC_PI_4: Self = core::f32::consts::FRAC_PI_4;
    const EPSILON: Self = f32::EPSILON / 2.0;
    const SPLITTER: Self = 4097.0; // 2^12 + 1
    fn from_f64(x: f64) -> Self {
        x as f32
    }
    fn from_u64(x: u64) -> Self {
        x as f32
    }
    fn to_f64(self) -> f64 {
        f64::from(self)
    }
    fn sqrt(self) -> Self {
        libm::sqrtf(self)
    }
    fn abs(self) -> Self {
        libm::fabsf(self)
    }
    fn is_finite(self) -> bool {
        f32::is_finite(self)
    }
    fn sin_cos_octant(x: Self) -> (Self, Self) {
        let x2 = x * x;
        // Horner forms of the Taylor series to x^9 and x^10.
        let s = x
            * (1.0
                - x2 * (1.0 / 6.0
                    - x2 * (1.0 / 120.0 - x2 * (1.0 / 5040.0 - x2 * (1.0 / 362_880.0)))));
        let c = 1.0
            - x2 * (0.5
                - x2 * (1.0 / 24.0
                    - x2 * (1.0 / 720.0 - x2 * (1.0 / 40_320.0 - x2 * (1.0 / 3_628_800.0)))));
        (s, c)
    }
}

impl Real for f64 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    const FRAC_PI_4: Self = core::f64::consts::FRAC_PI_4;
    const EPSILON: Self = f64::EPSILON / 2.0;
    const SPLITTER: Self = 134_217_729.0; // 2^27 + 1
    fn from_f64(x: f64) -> Self {
        x
    }
    fn from_u64(x: u64) -> Self {
        x as f64
    }
    fn to_f64(self) -> f64 {
        self
    }
    fn sqrt(self) -> Self {
        libm::sqrt(self)
    }
    fn abs(self) -> Self {
        libm::fabs(self)
    }
    fn is_finite(self) -> bool {
        f64::is_finite(self)
    }
    fn sin_cos_octant(x: Self) -> (Self, Self) {
        (libm::sin(x), libm::cos(x))
    }
}
