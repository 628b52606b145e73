//! Harmonic analysis of fit residuals against the table angle: how much of each harmonic
//! k·α is left. The report plots it; the discrepancy workflow reads it to name effects.

use nalgebra::{Matrix3, Vector3};

/// Harmonics of ω whose residual amplitude is reported.
pub const HARMONICS: usize = 8;

/// Residual amplitude at harmonic k = 1..HARMONICS: LS fit of a·sin kα + b·cos kα + c.
pub fn harmonic_amplitudes(alpha: &[f64], r: &[f64]) -> Vec<f64> {
    (1..=HARMONICS)
        .map(|k| {
            let k = k as f64;
            let mut m = Matrix3::zeros();
            let mut v = Vector3::zeros();
            for (a, y) in alpha.iter().zip(r) {
                let h = Vector3::new((k * a).sin(), (k * a).cos(), 1.0);
                m += h * h.transpose();
                v += h * *y;
            }
            m.lu()
                .solve(&v)
                .map_or(f64::NAN, |c| (c[0] * c[0] + c[1] * c[1]).sqrt())
        })
        .collect()
}
