//! The noise floor without the physical model: for each group and channel, the residuals
//! of a generic fit (a straight line and harmonics 1–4 of the nominal rate), then the
//! second differences of those residuals, which cancel what is left smooth (a slow drift,
//! a rate error's growing quadrature). For white noise e, (e₋ − 2e + e₊)/√6 has variance σ².

use super::model::Data;
use nalgebra::{DMatrix, DVector};

/// How the estimate is made (for the JSON's `source`).
pub const HOW: &str = "second differences of the residuals of a generic per-group fit \
                       (line + harmonics 1-4 of the nominal rate)";

/// σ per channel.
pub fn estimate(data: &Data) -> Result<[f64; 3], String> {
    let mut sum = [0.0; 3];
    let mut count = 0usize;
    for g in &data.groups {
        let n = g.tau.len();
        if n < 30 {
            return Err("a group has fewer than 30 rows: too few to estimate the noise".into());
        }
        let omega = g.omega();
        let cols = 2 + 2 * 4;
        let x = DMatrix::from_fn(n, cols, |r, c| {
            let tau = g.tau[r];
            match c {
                0 => 1.0,
                1 => tau,
                _ => {
                    let k = ((c - 2) / 2 + 1) as f64;
                    if c % 2 == 0 {
                        (k * omega * tau).sin()
                    } else {
                        (k * omega * tau).cos()
                    }
                }
            }
        });
        let qr = x.qr();
        let q = qr.q();
        for (j, s) in sum.iter_mut().enumerate() {
            let y = DVector::from_column_slice(&g.y[j]);
            let e = &y - &q * (q.transpose() * &y);
            *s += e
                .as_slice()
                .windows(3)
                .map(|w| (w[0] - 2.0 * w[1] + w[2]).powi(2) / 6.0)
                .sum::<f64>();
        }
        count += n - 2;
    }
    let s = sum.map(|s| (s / count.max(1) as f64).sqrt());
    if s.iter().any(|x| !(x.is_finite() && *x > 0.0)) {
        return Err("the noise estimate is zero: are the readings constant?".into());
    }
    Ok(s)
}
