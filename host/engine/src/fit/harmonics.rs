//! Harmonic analysis of fit residuals against the table angle: how much of each harmonic
//! k·α is left. The report plots it; the discrepancy workflow reads it to name effects.

use nalgebra::{Matrix3, Vector3};

/// Harmonics of ω whose residual amplitude is reported.
pub const HARMONICS: usize = 8;

/// Residual amplitude at harmonic k = 1..HARMONICS: LS fit of a·sin kα + b·cos kα + c.
pub fn harmonic_amplitudes(alpha: &[f64], r: &[f64]) -> Vec<f64> {
    let mut sums = HarmonicSums::default();
    for (a, y) in alpha.iter().zip(r) {
        sums.add(*a, *y);
    }
    sums.amplitudes()
}

/// The normal equations of [`harmonic_amplitudes`]'s fits, gathered one residual at a
/// time (a record too long to hold).
#[derive(Clone, Debug, Default)]
pub struct HarmonicSums {
    m: [Matrix3<f64>; HARMONICS],
    v: [Vector3<f64>; HARMONICS],
}

impl HarmonicSums {
    /// Add residual `r` at table angle `alpha` (rad).
    pub fn add(&mut self, alpha: f64, r: f64) {
        for (k, (m, v)) in self.m.iter_mut().zip(self.v.iter_mut()).enumerate() {
            let k = (k + 1) as f64;
            let h = Vector3::new((k * alpha).sin(), (k * alpha).cos(), 1.0);
            *m += h * h.transpose();
            *v += h * r;
        }
    }

    /// The amplitude √(a² + b²) at each harmonic (NaN where the fit is singular).
    pub fn amplitudes(&self) -> Vec<f64> {
        self.m
            .iter()
            .zip(&self.v)
            .map(|(m, v)| {
                m.lu()
                    .solve(v)
                    .map_or(f64::NAN, |c| (c.x * c.x + c.y * c.y).sqrt())
            })
            .collect()
    }
}
