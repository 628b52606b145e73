//! Slow noise in the tests that name effects (`rotacal discrepancy --slow-noise`;
//! docs/discrepancy.md, "Slow noise").
//!
//! Flicker and a bias random walk put power at the rotation frequency and below, where the
//! AR model of §2 sees only its white level, and a nested F-test then reads them as a
//! drift, a temperature coefficient, a rate error or a nonlinearity. With this option:
//!
//! - **The levels.** Each channel's flicker Q and walk q (per row) are estimated from the
//!   residuals of the generic fit of every group, pooled over the groups
//!   ([`crate::fit::noise::estimate_pooled`]: the residuals' Allan variances against their
//!   exact expectations for that fit, beyond the short-range correlation). The generic fit
//!   takes out a line and the temperature in each group, so an offset drift or a
//!   temperature coefficient the data hold does not raise them.
//! - **The test.** A candidate's parameters β are estimated as before. Their covariance is
//!   the fit's (AR) one scaled by χ²/dof, plus what flicker and the walk give them:
//!   Σ_j Q_j·GⱼᵀT_fl Gⱼ + q_j·GⱼᵀT_rw Gⱼ, Gⱼ the estimates' weights on channel j's readings
//!   ([`super::model::tested`]) placed on the session's grid of rows, and T the slow terms'
//!   generalised covariances. The grid keeps the time between groups, so one process runs
//!   through the session, as in the sensor. Each level counts as at least zero, and each
//!   parameter's slow variance is raised by 3.09 standard deviations of it (from the
//!   levels' bootstrap covariance): a record of a few periods bounds the levels loosely,
//!   and a test on the estimate alone would alarm whenever it fell short. The statistic is
//!   Wald's, F = βᵀC⁻¹β/k, against F(k, ν), ν the fit's degrees of freedom; its size is
//!   at most α + 10⁻³.
//! - **The reported uncertainties** ([`SlowLevels::uncertainty`]) are the estimate's: the
//!   GLS variance plus the slow share, with Welch–Satterthwaite degrees of freedom.

use super::model::{Data, Tested};
use crate::fit::noise::{self, NoiseError, SlowDesign, SlowFit, SlowForms, SlowPart};
use nalgebra::DMatrix;
use rotacal_shared::{Channel, Condition};
use serde::Serialize;

/// Why slow noise could not be estimated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SlowError {
    /// Groups whose rows are not one interval apart, as the grid needs.
    #[error(
        "slow noise: the {condition} group at {rate_hz} Hz has a row every {interval_s} s, \
         the recording {common_s} s; --slow-noise needs one row interval"
    )]
    UnevenRows {
        /// The group's condition.
        condition: Condition,
        /// Its nominal rate, Hz.
        rate_hz: f64,
        /// Its median row interval, s.
        interval_s: f64,
        /// The recording's, s.
        common_s: f64,
    },
    /// A recording without two rows.
    #[error("slow noise: too few rows to find the row interval")]
    NoInterval,
    /// A session whose grid of rows (gaps included) would be too long to hold.
    #[error(
        "slow noise: the session spans {rows} row intervals from its first row to its \
         last, more than the {MAX_GRID} --slow-noise can hold"
    )]
    TooLong {
        /// Its length in row intervals.
        rows: usize,
    },
    /// A channel whose residuals leave too few averaging lengths beyond their short-range
    /// correlation to fit the levels.
    #[error(
        "slow noise of channel {channel}: too few averaging lengths beyond the short-range \
         correlation to estimate it (strong slow noise can read as correlation); \
         --slow-noise cannot test this file"
    )]
    NotEstimable {
        /// The channel.
        channel: Channel,
    },
    /// The estimate itself, for a channel.
    #[error("slow noise of channel {channel}: {cause}")]
    Estimate {
        /// The channel.
        channel: Channel,
        /// Why.
        cause: NoiseError,
    },
}

/// The slow noise of a recording, per channel, and the session's grid of rows.
#[derive(Clone, Debug)]
pub struct SlowLevels {
    /// Per channel u, v, w: θ = (1, Q, q) with their covariance.
    pub channels: [SlowFit; 3],
    /// The row interval, s.
    pub row_interval_s: f64,
    /// Each group's first row on the grid.
    starts: Vec<usize>,
    /// The grid's length.
    grid: usize,
    /// Unit flicker and walk on the grid, built once for every test.
    forms: std::sync::Arc<SlowForms>,
}

/// A candidate's test under the slow noise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SlowTest {
    /// βᵀC⁻¹β/k.
    pub f: f64,
    /// Degrees of freedom of the denominator.
    pub dof: f64,
    /// The slow terms' share of C's trace, 0 … 1.
    pub slow_share: f64,
}

/// How many standard uncertainties of the slow variance are added to it in a test: the
/// one-sided normal quantile at [`super::ALPHA`], so the variance falls short of the
/// truth with probability about 10⁻³ and a test's size is at most α + 10⁻³.
const UPPER: f64 = 3.09;

/// The longest session grid (rows, gaps included): 2²² rows is 11 hours at 104 Hz.
const MAX_GRID: usize = 1 << 22;

/// The median of `x` (sorted in place); `None` if empty.
fn median(x: &mut [f64]) -> Option<f64> {
    x.sort_by(f64::total_cmp);
    x.get(x.len() / 2).copied()
}

/// The median spacing of a group's times.
fn interval(tau: &[f64]) -> Option<f64> {
    let mut d: Vec<f64> = tau
        .iter()
        .zip(tau.iter().skip(1))
        .map(|(a, b)| b - a)
        .collect();
    median(&mut d)
}

/// Estimate the slow noise of `data`'s channels.
pub fn estimate(data: &Data) -> Result<SlowLevels, SlowError> {
    let mut all: Vec<f64> = data
        .groups
        .iter()
        .flat_map(|g| g.tau.iter().zip(g.tau.iter().skip(1)).map(|(a, b)| b - a))
        .collect();
    let dt = median(&mut all)
        .filter(|d| *d > 0.0)
        .ok_or(SlowError::NoInterval)?;
    for g in &data.groups {
        let own = interval(&g.tau).unwrap_or(dt);
        if ((own / dt) - 1.0).abs() > 0.01 {
            return Err(SlowError::UnevenRows {
                condition: g.condition,
                rate_hz: g.rate_hz,
                interval_s: own,
                common_s: dt,
            });
        }
    }
    // The grid: each group's rows one interval apart from where its first row falls, and
    // never over the rows of a group before it.
    let t_min = data
        .groups
        .iter()
        .filter_map(|g| g.t.first())
        .fold(f64::INFINITY, |a, &b| a.min(b));
    let mut order: Vec<usize> = (0..data.groups.len()).collect();
    let first = |i: usize| data.groups.get(i).and_then(|g| g.t.first()).copied();
    order.sort_by(|&a, &b| first(a).unwrap_or(0.0).total_cmp(&first(b).unwrap_or(0.0)));
    let mut starts = vec![0usize; data.groups.len()];
    let mut end = 0usize;
    for i in order {
        let Some(g) = data.groups.get(i) else {
            continue;
        };
        let at = ((first(i).unwrap_or(t_min) - t_min) / dt).round().max(0.0);
        if at >= MAX_GRID as f64 {
            return Err(SlowError::TooLong { rows: at as usize });
        }
        let start = (at as usize).max(end);
        if let Some(s) = starts.get_mut(i) {
            *s = start;
        }
        end = start + g.tau.len();
    }
    if end > MAX_GRID {
        return Err(SlowError::TooLong { rows: end });
    }
    let [u, v, w] = Channel::ALL.map(|ch| channel_levels(data, ch));
    let channels = [u?, v?, w?];
    Ok(SlowLevels {
        channels,
        row_interval_s: dt,
        starts,
        grid: end,
        forms: std::sync::Arc::new(SlowForms::new(end)),
    })
}

/// One channel's levels, pooled over the groups' generic fits.
fn channel_levels(data: &Data, ch: Channel) -> Result<SlowFit, SlowError> {
    let fits: Vec<(SlowDesign, Vec<f64>, usize)> = data
        .groups
        .iter()
        .enumerate()
        .filter_map(|(gi, g)| {
            let extras: &[super::noise::Extra] = data
                .generic
                .extras
                .get(gi)
                .map_or(&[], |e| ch.of(e).as_slice());
            let (x, r) = super::noise::generic_fit(g, ch, extras)?;
            let design = SlowDesign::new(&x, &vec![1.0; x.nrows()]).ok()?;
            Some((design, r, gi))
        })
        .collect();
    let parts: Vec<SlowPart<'_>> = fits
        .iter()
        .filter_map(|(design, resid, gi)| {
            Some(SlowPart {
                design,
                resid,
                ar: ch.of(data.noise.get(*gi)?),
            })
        })
        .collect();
    let est = noise::estimate_pooled(&parts, ch.index() as u64)
        .map_err(|cause| SlowError::Estimate { channel: ch, cause })?;
    // A channel without levels would be tested as if it had no slow noise, the false
    // alarms this option exists to prevent: refuse instead.
    est.and_then(|e| e.into_iter().next())
        .map(|(fit, _)| fit)
        .ok_or(SlowError::NotEstimable { channel: ch })
}

impl SlowLevels {
    /// What the slow terms give the parameters of `t`: their covariance (each level taken
    /// as at least zero) and, per parameter, the standard deviation of its slow variance
    /// (from the levels' covariance).
    fn slow_part(&self, data: &Data, t: &Tested) -> (DMatrix<f64>, Vec<f64>) {
        let k = t.values.len();
        let mut cov = DMatrix::zeros(k, k);
        let mut var_of_var = vec![0.0; k];
        for (j, level) in self.channels.iter().enumerate() {
            let [fl, rw] = self.forms.of(&self.on_grid(data, t, j, k));
            let [_, q_fl, q_rw] = level.theta;
            cov += &fl * q_fl.max(0.0) + &rw * q_rw.max(0.0);
            let c = |a: usize, b: usize| {
                level
                    .cov
                    .get(a)
                    .and_then(|r| r.get(b))
                    .copied()
                    .unwrap_or(0.0)
            };
            for (a, v) in var_of_var.iter_mut().enumerate() {
                let (f, r) = (
                    fl.get((a, a)).copied().unwrap_or(0.0),
                    rw.get((a, a)).copied().unwrap_or(0.0),
                );
                *v += f * f * c(1, 1) + 2.0 * f * r * c(1, 2) + r * r * c(2, 2);
            }
        }
        (
            cov,
            var_of_var.into_iter().map(|v| v.max(0.0).sqrt()).collect(),
        )
    }

    /// The test of a candidate's parameters `t`, whose fit has χ²/dof `scale` and `dof`
    /// degrees of freedom: each parameter's slow variance raised by 3.09 of its
    /// standard deviations.
    pub fn test(&self, data: &Data, t: &Tested, scale: f64, dof: f64) -> Option<SlowTest> {
        let k = t.values.len();
        let (slow, sd) = self.slow_part(data, t);
        let mut cov = &t.gls_cov * scale + slow;
        let gls_trace = t.gls_cov.trace() * scale;
        for (a, s) in sd.iter().enumerate() {
            if let Some(d) = cov.get_mut((a, a)) {
                *d += UPPER * s;
            }
        }
        let total = cov.trace();
        let inv = cov.try_inverse()?;
        let beta = nalgebra::DVector::from_column_slice(&t.values);
        let w = beta.dot(&(inv * &beta));
        Some(SlowTest {
            f: w / k.max(1) as f64,
            dof,
            slow_share: if total > 0.0 {
                1.0 - gls_trace / total
            } else {
                0.0
            },
        })
    }

    /// The parameters of `t` as reported: per parameter its standard uncertainty with the
    /// slow terms (the GLS variance plus their estimated share) and its degrees of freedom
    /// (Welch–Satterthwaite, the GLS part taken as exact; at least 1).
    pub fn uncertainty(&self, data: &Data, t: &Tested) -> (Vec<f64>, Vec<f64>) {
        let (slow, sd) = self.slow_part(data, t);
        let cov = &t.gls_cov + slow;
        let var = cov.diagonal();
        let u = var.iter().map(|v| v.max(0.0).sqrt()).collect();
        let nu = var
            .iter()
            .zip(&sd)
            .map(|(v, s)| {
                if *s > 0.0 {
                    (2.0 * v * v / (s * s)).max(1.0)
                } else {
                    f64::INFINITY
                }
            })
            .collect();
        (u, nu)
    }

    /// The same levels for data whose group i starts `by[i]` rows into the group it was
    /// part of (the second half of each group, say), so that its weights fall where its
    /// rows were.
    pub(super) fn shifted(&self, by: &[usize]) -> SlowLevels {
        let mut out = self.clone();
        for (s, b) in out.starts.iter_mut().zip(by) {
            *s += b;
        }
        out
    }

    /// Channel `j`'s weights of the `k` parameters of `t`, placed on the session's grid.
    fn on_grid(&self, data: &Data, t: &Tested, j: usize, k: usize) -> DMatrix<f64> {
        let mut x = DMatrix::zeros(self.grid, k);
        for (a, w) in t.weights.iter().enumerate() {
            let Some(wj) = w.get(j) else {
                continue;
            };
            let mut rest = wj.as_slice();
            for (g, start) in data.groups.iter().zip(&self.starts) {
                let n = g.tau.len().min(rest.len());
                let (part, tail) = rest.split_at(n);
                rest = tail;
                for (i, v) in part.iter().enumerate() {
                    if let Some(cell) = x.get_mut((start + i, a)) {
                        *cell = *v;
                    }
                }
            }
        }
        x
    }
}

/// A value and its standard uncertainty.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Estimate {
    /// The value.
    pub value: f64,
    /// Its standard uncertainty.
    pub u: f64,
}

/// One channel's slow noise in the JSON (docs/formats.md, discrepancy keys).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SlowNoiseJson {
    /// The channel.
    pub channel: Channel,
    /// The flicker's Allan variance 2 ln 2·Q/π (its floor squared), output units²;
    /// signed (a record that cannot tell it from zero gives either sign).
    pub flicker_allan_variance: Estimate,
    /// The walk's K² = q/Δt (σ_A(τ)² = K²τ/3), output units² per s; signed.
    pub random_walk_k2: Estimate,
}

impl SlowLevels {
    /// The levels as the JSON gives them.
    pub fn json(&self) -> Vec<SlowNoiseJson> {
        let plateau = crate::allan::powerlaw::FLICKER_ALLAN_PLATEAU;
        let per_s = 1.0 / self.row_interval_s;
        Channel::ALL
            .into_iter()
            .zip(&self.channels)
            .map(|(channel, fit)| {
                let term = |i: usize, factor: f64| Estimate {
                    value: fit.theta.get(i).copied().unwrap_or(0.0) * factor,
                    u: fit
                        .cov
                        .get(i)
                        .and_then(|r| r.get(i))
                        .map_or(0.0, |v| v.max(0.0).sqrt())
                        * factor,
                };
                SlowNoiseJson {
                    channel,
                    flicker_allan_variance: term(1, plateau),
                    random_walk_k2: term(2, per_s),
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::discrepancy::model::GroupData;

    fn group(condition: Condition, dt: f64, t0: f64) -> GroupData {
        let n = 400;
        let times = |from: f64| (0..n).map(|i| from + i as f64 * dt).collect::<Vec<_>>();
        GroupData {
            condition,
            rate_hz: 0.01,
            tau: times(0.0),
            t: times(t0),
            temp: vec![0.0; n],
            y: [vec![0.0; n], vec![0.0; n], vec![0.0; n]],
        }
    }

    fn data(groups: Vec<GroupData>) -> Data {
        Data {
            groups,
            g_loc: 9.81,
            sigma: [1.0; 3],
            noise: Vec::new(),
            generic: Default::default(),
        }
    }

    /// The grid needs one row interval, and a session it can hold: each refusal names why.
    #[test]
    fn uneven_rows_and_too_long_a_session_are_refused() {
        let uneven = data(vec![
            group(Condition::X, 1.0 / 16.0, 0.0),
            group(Condition::Y, 1.0 / 16.0, 100.0),
            group(Condition::Z, 1.0 / 8.0, 200.0),
        ]);
        match estimate(&uneven) {
            Err(
                e @ SlowError::UnevenRows {
                    condition: Condition::Z,
                    ..
                },
            ) => {
                assert!(e.to_string().contains("z group"), "{e}");
            }
            other => panic!("{other:?}"),
        }
        let day_apart = data(vec![
            group(Condition::X, 1.0 / 16.0, 0.0),
            group(Condition::Y, 1.0 / 16.0, 86_400.0 * 4.0),
        ]);
        assert!(matches!(
            estimate(&day_apart),
            Err(SlowError::TooLong { .. })
        ));
    }
}
