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
    /// Largest sample magnitude a fit accepts: far beyond any sensor's range, and small
    /// enough that Dekker splits, squares and 2³² of them summed cannot overflow.
    const MAX_SAMPLE: Self;
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
    /// `(sin x, cos x)` in double-word precision, each as (hi, lo) with |lo| ≤ ulp(hi)/2,
    /// for `x = r·(π/4)/2⁶¹`, `r ≤ 2⁶¹` (an angle within the first octant, in 2⁻⁶⁴
    /// turns). `crate::phase` makes them `DoubleWord`s.
    ///
    /// Why double word: during a steady rotation the samples fall on the same few hundred
    /// phases again and again, so the rounding of an f32 sine does not average out; it
    /// biased A by up to 8e-3 σ_CRLB in the hour-long records. For `f32` the value comes
    /// from a 257-point table of (hi, lo) pairs and a short series for the remainder
    /// angle (≤ 1.6e-3 rad), accurate to ~1e-10 in about 20 f32 operations; libm's
    /// `sinf` would be both less accurate and, working in f64, which the Cortex-M4F only
    /// emulates, hundreds of instructions. For `f64` it is libm's sin and cos.
    fn sin_cos_octant(r: u64) -> ((Self, Self), (Self, Self));
}

/// Fast2Sum (Dekker): `(s, e)` with `s = fl(a + b)` and `a + b = s + e` exactly, when
/// |a| ≥ |b| is known: three operations instead of TwoSum's six.
#[inline(always)]
pub(crate) fn fast_two_sum<T: Real>(a: T, b: T) -> (T, T) {
    let s = a + b;
    (s, b - (s - a))
}

impl Real for f32 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    const FRAC_PI_4: Self = core::f32::consts::FRAC_PI_4;
    const EPSILON: Self = f32::EPSILON / 2.0;
    const MAX_SAMPLE: Self = 1e12;
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
    fn sin_cos_octant(r: u64) -> ((Self, Self), (Self, Self)) {
        const SHIFT: u32 = 61 - 8; // 256 table steps per octant
        let i = (r + (1 << (SHIFT - 1))) >> SHIFT;
        // Remainder from the nearest table point, |d| ≤ 2⁵², as an angle b.
        let d = r as i64 - (i << SHIFT) as i64;
        let b = d as f32 * (core::f32::consts::FRAC_PI_4 / (1u64 << 61) as f32);
        let [sh, sl, ch, cl] = octant_table::OCTANT_TABLE_F32
            .get(i as usize)
            .copied()
            .unwrap_or([0, 0, 0x3f80_0000, 0])
            .map(f32::from_bits);
        // sin(a+b) = S + [S·(cos b − 1) + C·sin b], cos(a+b) = C + [C·(cos b − 1) − S·sin b];
        // the brackets are ≤ 1.6e-3, so their f32 rounding is ≤ 1e-10.
        let b2 = b * b;
        let cos_b_1 = -0.5 * b2;
        let sin_b = b - b * b2 * (1.0 / 6.0);
        // Renormalised (|lo| ≤ ulp(hi)/2) so that products of two regressors may drop
        // lo·lo. Fast2Sum is exact here: the table value always dominates the bracket
        // (|S| ≥ sin(π/1024) > 1.6e-3 except at i = 0, where S = 0).
        let s = fast_two_sum(sh, sl + (sh * cos_b_1 + ch * sin_b));
        let c = fast_two_sum(ch, cl + (ch * cos_b_1 - sh * sin_b));
        (s, c)
    }
}

mod octant_table {
    include!(concat!(env!("OUT_DIR"), "/octant_table.rs"));
}

impl Real for f64 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    const FRAC_PI_4: Self = core::f64::consts::FRAC_PI_4;
    const EPSILON: Self = f64::EPSILON / 2.0;
    const MAX_SAMPLE: Self = 1e100;
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
    #[inline]
    fn sin_cos_octant(r: u64) -> ((Self, Self), (Self, Self)) {
        let x = r as f64 * (core::f64::consts::FRAC_PI_4 / (1u64 << 61) as f64);
        // One call: on [0, π/4] libm's sincos is its sin and cos kernels, as sin and cos.
        let (sin, cos) = libm::sincos(x);
        ((sin, 0.0), (cos, 0.0))
    }
}

#[cfg(test)]
mod tests {
    use super::Real;

    /// The f64 octant is libm's sin and cos exactly, as it was before it called sincos:
    /// a million angles over the octant, its ends and the tiny angles sincos returns as
    /// they are.
    #[test]
    fn f64_octant_is_libm_sin_and_cos() {
        const EIGHTH: u64 = 1 << 61;
        let steps = 1_000_000u64;
        let rs = (0..=steps).map(|i| EIGHTH / steps * i + i % 977).chain([
            0,
            1,
            2,
            1 << 20,
            1 << 33,
            EIGHTH - 1,
            EIGHTH,
        ]);
        for r in rs.filter(|r| *r <= EIGHTH) {
            let x = r as f64 * (core::f64::consts::FRAC_PI_4 / (1u64 << 61) as f64);
            let ((s, _), (c, _)) = f64::sin_cos_octant(r);
            assert_eq!(s.to_bits(), libm::sin(x).to_bits(), "sin at r = {r}");
            assert_eq!(c.to_bits(), libm::cos(x).to_bits(), "cos at r = {r}");
        }
    }
}
