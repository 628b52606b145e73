//! Whether the pose residuals of a channel are correlated from one pose to the next, in
//! the order the poses were read (docs/uncertainty.md, "Drift between poses").
//!
//! The pose fit treats the poses' errors as independent: the readings' noise within each
//! pose and a random scatter τ. Slow noise (flicker, bias wander) makes successive pose
//! means err alike, which neither term describes; so does an effect that varies smoothly
//! with the table angle. Either way the residuals, standardised by the fit's own pose
//! variances, are correlated at lag 1.
//!
//! The statistic is the Durbin–Watson ratio d = Σ s_i s_{i+1} / Σ s_i² of the standardised
//! residuals s = R·z, z_i = y_i/√v_i, R the projection off the weighted design. If the
//! poses are independent with variances v_i, d is the ratio of quadratic forms zᵀRARz /
//! zᵀRz in a normal z, independent of its denominator (Pitman), so its mean and variance
//! are exact: E d = tr(RA)/m and var d = 2(m·tr((RA)²) − tr(RA)²)/(m²(m + 2)), m = P − 4,
//! A the symmetric lag-1 matrix (½ beside the diagonal). Each trace takes O(P) from an
//! orthonormal basis Q of the design: R = I − QQᵀ.

// Unlike the files beside it, this one does without unchecked indexing.
#![deny(clippy::indexing_slicing)]

use nalgebra::{DMatrix, DVector};

/// The lag-1 correlation of one channel's standardised pose residuals, against what
/// independent poses give.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Serial {
    /// d = Σ s_i s_{i+1} / Σ s_i², the residuals' lag-1 autocorrelation.
    pub lag1: f64,
    /// Its expectation for independent poses (slightly negative: the fit's projection).
    pub expected: f64,
    /// (d − E d)/sd(d).
    pub z: f64,
}

/// Fewest residual degrees of freedom for the test: below it the ratio is far from normal
/// and has no power.
pub const MIN_DOF: usize = 8;

/// The z above which a channel's residuals count as serially correlated: one-sided, a
/// false alarm in about 1 of 1000 channels of independent poses (normal tail; 3 channels a
/// calibration).
pub const Z_ALARM: f64 = 3.09;

/// The test for residuals `y − x·β` of a weighted fit: pose means `y`, design rows `x`,
/// pose variances `var` (the fit's weights are their inverses). `None` without
/// [`MIN_DOF`] degrees of freedom, or with a variance not positive.
pub fn lag1(x: &[[f64; 4]], y: &[f64], var: &[f64]) -> Option<Serial> {
    let p = y.len();
    if x.len() != p || var.len() != p || p < 4 + MIN_DOF {
        return None;
    }
    if !var.iter().all(|v| v.is_finite() && *v > 0.0) {
        return None;
    }
    let w: Vec<f64> = var.iter().map(|v| v.sqrt().recip()).collect();
    let u = DMatrix::from_fn(p, 4, |i, a| {
        x.get(i).and_then(|r| r.get(a)).copied().unwrap_or(0.0) * w.get(i).copied().unwrap_or(0.0)
    });
    let qr = u.qr();
    let q = qr.q();
    let diag_ok = qr.r().diagonal().iter().all(|d| d.abs() > 1e-12);
    if !diag_ok {
        return None;
    }
    let z = DVector::from_iterator(p, y.iter().zip(&w).map(|(y, w)| y * w));
    let s = &z - &q * (q.transpose() * &z);
    let ss = s.norm_squared();
    if !(ss.is_finite() && ss > 0.0) {
        return None;
    }
    let lagged: f64 = s.iter().zip(s.iter().skip(1)).map(|(a, b)| a * b).sum();
    let d = lagged / ss;
    // AQ: (AQ)_i = ½(Q_{i−1} + Q_{i+1}).
    let aq = DMatrix::from_fn(p, 4, |i, a| {
        let at = |k: usize| q.get((k, a)).copied().unwrap_or(0.0);
        let before = i.checked_sub(1).map_or(0.0, at);
        let after = if i + 1 < p { at(i + 1) } else { 0.0 };
        0.5 * (before + after)
    });
    let qaq = q.transpose() * &aq;
    // tr(RA) = tr(A) − tr(QᵀAQ), tr(A) = 0;
    // tr((RA)²) = tr(A²) − 2‖AQ‖² + tr((QᵀAQ)²), tr(A²) = (P − 1)/2.
    let t1 = -qaq.trace();
    let t2 = (p - 1) as f64 / 2.0 - 2.0 * aq.norm_squared() + (&qaq * &qaq).trace();
    let m = (p - 4) as f64;
    let expected = t1 / m;
    let var_d = 2.0 * (m * t2 - t1 * t1) / (m * m * (m + 2.0));
    if !(var_d.is_finite() && var_d > 0.0) {
        return None;
    }
    Some(Serial {
        lag1: d,
        expected,
        z: (d - expected) / var_d.sqrt(),
    })
}

#[cfg(test)]
#[allow(clippy::indexing_slicing)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    /// A stepped-like design: three conditions of 12 angles, gravity about x, y, z.
    fn design() -> Vec<[f64; 4]> {
        let mut x = Vec::new();
        for c in 0..3 {
            for k in 0..12 {
                let a = f64::from(k) * 30f64.to_radians();
                let (s, co) = a.sin_cos();
                let g = match c {
                    0 => [0.0, co, s],
                    1 => [s, 0.0, co],
                    _ => [co, s, 0.0],
                };
                x.push([9.8 * g[0], 9.8 * g[1], 9.8 * g[2], 1.0]);
            }
        }
        x
    }

    /// Under independent poses of unequal variance, the mean and variance of z over many
    /// draws are 0 and 1 (their standard errors from the draws), and the alarm rate is
    /// near its nominal 0.1 %; under a random walk between poses, z is large.
    #[test]
    fn z_is_standard_for_independent_poses_and_large_for_a_walk() {
        let x = design();
        let var: Vec<f64> = (0..x.len()).map(|i| 1.0 + (i % 5) as f64).collect();
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let n = 4000;
        let (mut sum, mut sum2, mut alarms) = (0.0, 0.0, 0);
        for _ in 0..n {
            let y: Vec<f64> = x
                .iter()
                .zip(&var)
                .map(|(r, v)| {
                    let e: f64 = rng.sample(StandardNormal);
                    2.0 * r[0] - r[1] + 0.5 * r[2] + 3.0 + e * v.sqrt()
                })
                .collect();
            let s = lag1(&x, &y, &var).unwrap();
            sum += s.z;
            sum2 += s.z * s.z;
            alarms += usize::from(s.z > Z_ALARM);
        }
        let mean = sum / n as f64;
        let var_z = sum2 / n as f64 - mean * mean;
        // mean: se 1/√n; variance: se ≈ √(2/n) (a little more for the skewed ratio).
        assert!(mean.abs() < 4.0 / (n as f64).sqrt(), "mean z {mean}");
        assert!(
            (var_z - 1.0).abs() < 4.0 * (2.5 / n as f64).sqrt(),
            "var z {var_z}"
        );
        // Binomial: 0.001 nominal; 4000 draws → mean 4, P(> 16) < 1e-5.
        assert!(alarms <= 16, "alarms {alarms}");
        // A walk of step sd 1 between poses, on top of the same noise.
        let mut walk = 0.0;
        let y: Vec<f64> = x
            .iter()
            .zip(&var)
            .map(|(r, v)| {
                let e: f64 = rng.sample(StandardNormal);
                let step: f64 = rng.sample(StandardNormal);
                walk += step;
                r[0] + walk + e * v.sqrt()
            })
            .collect();
        let s = lag1(&x, &y, &var).unwrap();
        assert!(s.z > Z_ALARM, "walk: {s:?}");
    }

    #[test]
    fn too_few_poses_or_bad_variances_give_none() {
        let x = design();
        let y = vec![1.0; x.len()];
        assert!(lag1(&x[..11], &y[..11], &[1.0; 11]).is_none());
        let mut var = vec![1.0; x.len()];
        var[3] = 0.0;
        assert!(lag1(&x, &y, &var).is_none());
    }
}
