//! Rotation phase as an exact integer fraction of a turn.
//!
//! `sin(ω·t)` in f32 with t in seconds loses ~1e-4 rad after an hour (docs/method.md §6).
//! Instead the phase at tick `t` is `step · t mod 2⁶⁴` in units of 2⁻⁶⁴ turn: one integer
//! multiplication, exact, identical on host and device. Only the reduced angle within an
//! octant (≤ π/4) is ever converted to floating point.

use crate::dword::DoubleWord;
use crate::real::Real;
use crate::time::{TickRate, Ticks};

/// Rotation per tick, in units of 2⁻⁶⁴ turn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PhaseStep(pub u64);

/// A rotation angle, in units of 2⁻⁶⁴ turn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Phase(pub u64);

const TWO_POW_64: f64 = 18_446_744_073_709_551_616.0;

impl PhaseStep {
    /// The step for a rotation rate in micro-hertz, by exact integer arithmetic, so that
    /// host and device derive the same step from the same configured rate. `None` if the
    /// rate is not below the tick rate.
    pub fn from_micro_hz(rate_uhz: u64, clock: TickRate) -> Option<PhaseStep> {
        let den = u128::from(clock.hz()) * 1_000_000;
        let num = u128::from(rate_uhz) << 64;
        let step = (num + den / 2) / den;
        u64::try_from(step).ok().map(PhaseStep)
    }

    /// The step for a rotation rate in hertz (host side, e.g. a fitted rate). `None` if
    /// the rate is negative, not finite, or not below the tick rate.
    pub fn from_hz(rate_hz: f64, clock: TickRate) -> Option<PhaseStep> {
        let step = libm::round(rate_hz / f64::from(clock.hz()) * TWO_POW_64);
        if step.is_finite() && (0.0..TWO_POW_64).contains(&step) {
            Some(PhaseStep(step as u64))
        } else {
            None
        }
    }

    /// The rotation rate this step stands for, in hertz.
    pub fn to_hz(self, clock: TickRate) -> f64 {
        self.0 as f64 / TWO_POW_64 * f64::from(clock.hz())
    }

    /// Phase at time `t`, taking phase 0 at tick 0.
    #[inline]
    pub fn phase_at(self, t: Ticks) -> Phase {
        Phase(self.0.wrapping_mul(t.0))
    }

    /// Whole and fractional turns swept over `ticks`, as `turns·2⁶⁴` (exact, saturating).
    pub fn turns_x2_64(self, ticks: u64) -> u128 {
        u128::from(self.0).saturating_mul(u128::from(ticks))
    }
}

impl Phase {
    /// `(sin α, cos α)` of this angle.
    ///
    /// Reduced to an octant by integer operations (quadrant from the top two bits, then a
    /// reflection so the angle is ≤ π/4), so the only rounding is in
    /// [`Real::sin_cos_octant`]. Double word: see there why.
    pub fn sin_cos<T: Real>(self) -> (DoubleWord<T>, DoubleWord<T>) {
        const EIGHTH: u64 = 1 << 61; // one octant in 2⁻⁶⁴ turns
        let quadrant = self.0 >> 62;
        let r = self.0 & (2 * EIGHTH - 1);
        let dw = |(hi, lo): (T, T)| DoubleWord { hi, lo };
        let (s, c) = if r <= EIGHTH {
            let (s, c) = T::sin_cos_octant(r);
            (dw(s), dw(c))
        } else {
            let (s, c) = T::sin_cos_octant(2 * EIGHTH - r);
            (dw(c), dw(s))
        };
        match quadrant {
            0 => (s, c),
            1 => (c, -s),
            2 => (-s, -c),
            _ => (-c, s),
        }
    }

    /// The angle in radians, in [0, 2π) (host side: plots, reports).
    pub fn radians(self) -> f64 {
        self.0 as f64 / TWO_POW_64 * core::f64::consts::TAU
    }
}
