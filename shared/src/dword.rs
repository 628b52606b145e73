//! Double-word arithmetic: a value held as an unevaluated sum `hi + lo` of two floats,
//! with about twice the precision of one (≈ 48 bits for `f32`, ≈ 106 for `f64`).
//!
//! Why: the fit's sums over an hour of data, and the results themselves, need more than
//! f32's 24 bits. Half an ulp of a 1 g amplitude is 3e-8 g, while σ_CRLB of that
//! amplitude after an hour at 16 Hz is 1.5e-6 g: a plain f32 result alone would use
//! 2 % of the error budget. Built on the error-free transformations TwoSum (Knuth) and
//! TwoProd (Dekker, no FMA needed), so it is exact IEEE arithmetic on every platform.

use crate::real::{fast_two_sum, Real};
use core::ops::{Add, Mul, Neg, Sub};

/// `hi + lo` with `|lo| ≤ ulp(hi)/2` after normalisation.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DoubleWord<T> {
    /// Leading part: the value rounded to `T`.
    pub hi: T,
    /// Trailing part: the rounding error of `hi`.
    pub lo: T,
}

/// `(s, e)` with `s = fl(a + b)` and `a + b = s + e` exactly.
#[inline(always)]
pub fn two_sum<T: Real>(a: T, b: T) -> (T, T) {
    let s = a + b;
    let bb = s - a;
    let e = (a - (s - bb)) + (b - bb);
    (s, e)
}

#[inline(always)]
fn split<T: Real>(a: T) -> (T, T) {
    let c = T::SPLITTER * a;
    let hi = c - (c - a);
    (hi, a - hi)
}

/// `(p, e)` with `p = fl(a·b)` and `a·b = p + e` exactly (Dekker; no overflow for the
/// magnitudes used here).
#[inline(always)]
pub fn two_prod<T: Real>(a: T, b: T) -> (T, T) {
    Split::new(a).two_prod(Split::new(b))
}

/// A value with its Dekker split into two halves of ≤ p/2 significant bits, whose
/// pairwise products are exact. Splitting once and reusing it makes each further exact
/// product cost 7 operations instead of 17.
#[derive(Clone, Copy, Debug)]
pub struct Split<T> {
    v: T,
    hi: T,
    lo: T,
}

impl<T: Real> Split<T> {
    /// Split `v`.
    #[inline(always)]
    pub fn new(v: T) -> Self {
        let (hi, lo) = split(v);
        Split { v, hi, lo }
    }

    /// The value split.
    #[inline(always)]
    pub fn value(self) -> T {
        self.v
    }

    /// `(p, e)` with `p = fl(self·other)` and `self·other = p + e` exactly.
    #[inline(always)]
    pub fn two_prod(self, other: Self) -> (T, T) {
        let p = self.v * other.v;
        let e = ((self.hi * other.hi - p) + self.hi * other.lo + self.lo * other.hi)
            + self.lo * other.lo;
        (p, e)
    }
}

impl<T: Real> DoubleWord<T> {
    /// Zero.
    pub const ZERO: Self = Self {
        hi: T::ZERO,
        lo: T::ZERO,
    };

    /// The exact value of one `T`.
    pub fn from_t(x: T) -> Self {
        Self { hi: x, lo: T::ZERO }
    }

    /// The exact product of two `T`s.
    pub fn from_prod(a: T, b: T) -> Self {
        let (hi, lo) = two_prod(a, b);
        Self { hi, lo }
    }

    /// Normalise an arbitrary pair so that `hi` is the sum rounded to `T`.
    pub fn normalised(hi: T, lo: T) -> Self {
        let (hi, lo) = two_sum(hi, lo);
        Self { hi, lo }
    }

    /// Normalise `hi + lo` when `|hi| ≥ |lo|` or `hi = 0` is known (Fast2Sum).
    pub fn fast_normalised(hi: T, lo: T) -> Self {
        let (hi, lo) = fast_two_sum(hi, lo);
        Self { hi, lo }
    }

    /// The value rounded to `T`.
    pub fn to_t(self) -> T {
        self.hi + self.lo
    }

    /// The value in `f64`: exact for `f32` parts (48 bits fit in 53), rounded for `f64`.
    pub fn to_f64(self) -> f64 {
        self.hi.to_f64() + self.lo.to_f64()
    }

    /// `self / x` for a plain `T` (the fit divides by a conversion count): the quotient
    /// rounded, then the exact remainder divided again, so about `2u²` relative.
    pub fn div_t(self, x: T) -> Self {
        let q = self.hi / x;
        let (p, e) = two_prod(q, x);
        let r = ((self.hi - p) - e) + self.lo;
        let (hi, lo) = fast_two_sum(q, r / x);
        Self { hi, lo }
    }

    /// `self · x` for a plain `T`.
    pub fn mul_t(self, x: T) -> Self {
        let (p, e) = two_prod(self.hi, x);
        let (hi, lo) = fast_two_sum(p, e + self.lo * x);
        Self { hi, lo }
    }
}

impl<T: Real> Add for DoubleWord<T> {
    type Output = Self;
    /// Accurate to about `2u²` relative.
    fn add(self, other: Self) -> Self {
        let (s, e) = two_sum(self.hi, other.hi);
        let (t, f) = two_sum(self.lo, other.lo);
        let (s, e) = fast_two_sum(s, e + t);
        let (hi, lo) = fast_two_sum(s, e + f);
        Self { hi, lo }
    }
}

impl<T: Real> Neg for DoubleWord<T> {
    type Output = Self;
    fn neg(self) -> Self {
        Self {
            hi: -self.hi,
            lo: -self.lo,
        }
    }
}

impl<T: Real> Sub for DoubleWord<T> {
    type Output = Self;
    fn sub(self, other: Self) -> Self {
        self + (-other)
    }
}

impl<T: Real> Mul for DoubleWord<T> {
    type Output = Self;
    /// Accurate to about `7u²` relative.
    fn mul(self, other: Self) -> Self {
        let (p, e) = two_prod(self.hi, other.hi);
        let e = e + (self.hi * other.lo + self.lo * other.hi);
        let (hi, lo) = fast_two_sum(p, e);
        Self { hi, lo }
    }
}

/// A running sum kept as `hi + lo` without renormalising on every term (Ogita, Rump &
/// Oishi's Sum2): 7 operations a term. With [`Accumulator::renormalise`] called every few
/// dozen terms it is as accurate as a double-word sum.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Accumulator<T> {
    hi: T,
    lo: T,
}

impl<T: Real> Accumulator<T> {
    /// An empty sum.
    pub const ZERO: Self = Self {
        hi: T::ZERO,
        lo: T::ZERO,
    };

    /// Add one term.
    #[inline(always)]
    pub fn add(&mut self, x: T) {
        let (s, e) = two_sum(self.hi, x);
        self.hi = s;
        self.lo += e;
    }

    /// Add an exact double-word term (e.g. from [`two_prod`]).
    #[inline(always)]
    pub fn add_dw(&mut self, hi: T, lo: T) {
        let (s, e) = two_sum(self.hi, hi);
        self.hi = s;
        self.lo += e + lo;
    }

    /// Fold `lo` back into `hi`. Sum2 lets `lo` grow like u·|sum|·√n, and its own
    /// roundings then cost ~u²·n relative (1e-9 after an hour at 104 Hz in f32); folding
    /// every few dozen terms keeps `lo` below an ulp of `hi` and that error negligible.
    pub fn renormalise(&mut self) {
        let (hi, lo) = two_sum(self.hi, self.lo);
        self.hi = hi;
        self.lo = lo;
    }

    /// The sum so far.
    pub fn value(&self) -> DoubleWord<T> {
        DoubleWord::normalised(self.hi, self.lo)
    }
}
