//! Where a model's residuals disagree with the noise: per condition, rate and channel,
//! the residual's 2nd and 3rd harmonics of ω, its trend in time, its correlation with
//! temperature, readings at the rails; across rates, the offsets against ω² and the angles
//! against ω.
//! Each finding has a size (output units) and a z-score (size over its standard error
//! under the group's and channel's noise model: white noise's, times the square root of
//! the model's variance factor at the frequency concerned); those beyond 5 are listed,
//! largest first.

use super::model::{Data, Fit};
use super::RateIntrinsic;
use rotacal_shared::{Channel, Condition};
use serde::Serialize;

/// z beyond which a finding is listed.
pub const Z_LIST: f64 = 5.0;

pub use super::place::Place;

/// One place where the residuals are not noise.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Finding {
    /// Condition, rate and channel.
    pub at: Place,
    /// What: "harmonic 2", "trend", "temperature", "rails", "offset vs ω²".
    pub what: String,
    /// Size, output units (per s for a trend, per °C, per (rad/s)²).
    pub size: f64,
    /// Size over its standard error.
    pub z: f64,
}

fn slope(x: &[f64], y: &[f64], sigma: f64) -> (f64, f64) {
    let n = x.len() as f64;
    let mx = x.iter().sum::<f64>() / n;
    let my = y.iter().sum::<f64>() / n;
    let sxx: f64 = x.iter().map(|v| (v - mx).powi(2)).sum();
    if sxx <= 0.0 {
        return (0.0, 0.0);
    }
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let b = sxy / sxx;
    (b, b / (sigma / sxx.sqrt()))
}

/// The mean interval between a group's rows, s.
fn sample_interval(tau: &[f64]) -> f64 {
    match (tau.first(), tau.last()) {
        (Some(a), Some(b)) if tau.len() > 1 => (b - a) / (tau.len() - 1) as f64,
        _ => 0.0,
    }
}

/// The findings for `fit`'s residuals.
pub fn locate(data: &Data, fit: &Fit) -> Vec<Finding> {
    let mut out = Vec::new();
    let temperature = data.temperature_varies();
    for (gi, g) in data.groups.iter().enumerate() {
        let alpha: Vec<f64> = g.tau.iter().map(|t| g.omega() * t).collect();
        let omega = g.omega() * sample_interval(&g.tau);
        for channel in Channel::ALL {
            let r = &fit.residuals(data, gi, channel);
            let model = data.noise.get(gi).map(|m| channel.of(m));
            // The sd of a slowly varying coefficient (trend, temperature) and of one at k·ω.
            let sd_at = |w: f64| {
                model.map_or(*channel.of(&data.sigma), |m| {
                    m.sd() * m.variance_factor(w).sqrt()
                })
            };
            let sigma = sd_at(0.0);
            let at = Place::Group {
                condition: g.condition,
                rate_hz: g.rate_hz,
                channel,
            };
            // Amplitudes at k·ω; a coefficient's variance is ≈ 2σ²/n under white noise.
            let amps = crate::fit::harmonics::harmonic_amplitudes(&alpha, r);
            // Harmonics 2 and 3 (the first is the signal's).
            for (k, &amp) in (1usize..).zip(&amps).skip(1).take(2) {
                let se = sd_at(k as f64 * omega) * (2.0 / r.len() as f64).sqrt();
                out.push(Finding {
                    at,
                    what: format!("harmonic {k}"),
                    size: amp,
                    z: amp / se,
                });
            }
            let (b, z) = slope(&g.tau, r, sigma);
            out.push(Finding {
                at,
                what: "trend (per s)".into(),
                size: b,
                z: z.abs(),
            });
            if temperature {
                let (b, z) = slope(&g.temp, r, sigma);
                out.push(Finding {
                    at,
                    what: "temperature (per °C)".into(),
                    size: b,
                    z: z.abs(),
                });
            }
        }
    }
    let [lo, hi] = data.rails();
    for (side, v) in [("low", lo), ("high", hi)] {
        if let Some(v) = v {
            let n = data
                .groups
                .iter()
                .flat_map(|g| g.y.iter().flatten())
                .filter(|&&x| x == v)
                .count();
            out.push(Finding {
                at: Place::AllChannels,
                what: format!("{n} readings at the {side} rail {v}"),
                size: v,
                z: f64::INFINITY,
            });
        }
    }
    if data.rates().len() > 1 {
        // Offsets against ω²: each group's mean residual (the baseline shares one offset
        // across rates).
        for c in Condition::ALL {
            for channel in Channel::ALL {
                let (mut w2, mut m) = (Vec::new(), Vec::new());
                let mut n_min = usize::MAX;
                let mut sd = 0.0f64;
                for (gi, g) in data.groups.iter().enumerate() {
                    if g.condition == c {
                        let r = fit.residuals(data, gi, channel);
                        if let Some(m) = data.noise.get(gi).map(|m| channel.of(m)) {
                            sd = sd.max(m.sd() * m.variance_factor(0.0).sqrt());
                        }
                        w2.push(g.omega().powi(2));
                        m.push(r.iter().sum::<f64>() / r.len() as f64);
                        n_min = n_min.min(r.len());
                    }
                }
                if w2.len() > 1 {
                    let (b, z) = slope(&w2, &m, sd / (n_min as f64).sqrt());
                    out.push(Finding {
                        at: Place::AcrossRatesOf {
                            condition: c,
                            channel,
                        },
                        what: "offset vs ω² (per (rad/s)²)".into(),
                        size: b,
                        z: z.abs(),
                    });
                }
            }
        }
    }
    out.retain(|f| f.z > Z_LIST);
    out.sort_by(|a, b| b.z.total_cmp(&a.z));
    out
}

/// Across rates: each angle's weighted slope against ω (an axis time skew shows so).
pub fn angles_against_rate(per_rate: &[RateIntrinsic]) -> Vec<Finding> {
    let mut out = Vec::new();
    if per_rate.len() < 2 {
        return out;
    }
    // Per angle: Σw, Σwx, Σwy, Σwx², Σwxy over the rates.
    let mut sums = [[0.0; 5]; 3];
    for r in per_rate {
        for ([sw, swx, swy, swxx, swxy], q) in sums.iter_mut().zip(&r.angle_deg) {
            let w = 1.0 / q.std_unc.powi(2);
            let x = std::f64::consts::TAU * r.rate_hz;
            *sw += w;
            *swx += w * x;
            *swy += w * q.value;
            *swxx += w * x * x;
            *swxy += w * x * q.value;
        }
    }
    for ([sw, swx, swy, swxx, swxy], name) in sums.into_iter().zip(["φ_uv", "φ_vw", "φ_wu"]) {
        let det = sw * swxx - swx * swx;
        if det > 0.0 {
            let b = (sw * swxy - swx * swy) / det;
            let z = b / (sw / det).sqrt();
            if z.abs() > Z_LIST {
                out.push(Finding {
                    at: Place::AcrossRates,
                    what: format!("{name} vs ω (° per rad/s)"),
                    size: b,
                    z: z.abs(),
                });
            }
        }
    }
    out
}
