//! The noise model without the physical model: for each group (condition × rate) and
//! channel, an AR(p) model ([`crate::fit::noise::NoiseModel`]: Yule–Walker, order by BIC) of the
//! residuals of a generic fit (a straight line, harmonics 1–4 of the nominal rate, τ·sin ωτ
//! and τ·cos ωτ, and the temperature where it varies), which takes out what the physical
//! model may leave (a drift, nonlinearity, a rate error's growing quadrature, a temperature
//! coefficient), so a missing effect does not read as noise. Readings at a rail
//! ([`crate::fit::noise::clipped`]) are left out of the generic fit and of the estimate, and the
//! level is rescaled for what the generic fit removed ([`NoiseModel::rescaled`]).
//!
//! The models are estimated once, before any physical model is fitted, and held fixed
//! through the baseline and every step, so nested tests compare like with like.

use super::locate::Place;
use super::model::{Data, GroupData};
use super::structure::{self, Kind, Structure};
use crate::fit::noise::{self, NoiseError, NoiseModel};
use nalgebra::{DMatrix, DVector};
use rotacal_shared::{Channel, Condition};
use statrs::distribution::{ContinuousCDF, FisherSnedecor, Normal};

/// Why a group's channel has no noise model.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ChannelNoiseError {
    /// The AR model of the generic fit's residuals.
    #[error(transparent)]
    Model(#[from] NoiseError),
    /// Not enough whitened rows beyond the generic fit's coefficients.
    #[error("too few rows to estimate the noise")]
    TooFewRows,
    /// The innovations' level came out zero or not finite.
    #[error("the noise estimate is zero: are the readings constant?")]
    Zero,
}

/// Why the noise models could not be estimated; the group is named by its condition and
/// rate.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NoiseEstimateError {
    /// A group too short for the generic fit.
    #[error(
        "a group has fewer than {} rows: too few to estimate the noise",
        MIN_ROWS
    )]
    ShortGroup {
        /// The group's condition.
        condition: Condition,
        /// Its nominal rate, Hz.
        rate_hz: f64,
        /// Its rows.
        rows: usize,
    },
    /// One channel's model. Its text is part of this one's (not a `source`: the CLI
    /// prints the chain, which would repeat it).
    #[error("noise model of a group's channel: {cause}")]
    Channel {
        /// The group's condition.
        condition: Condition,
        /// Its nominal rate, Hz.
        rate_hz: f64,
        /// The channel.
        channel: Channel,
        /// Why.
        cause: ChannelNoiseError,
    },
    /// An invariant of the estimate failed: a bug in rotacal, not a problem of the data.
    #[error("internal: a group without three noise models (a bug in rotacal; please report it)")]
    Internal,
}

/// The fewest rows a group needs for its noise to be estimated.
const MIN_ROWS: usize = 30;

/// How the estimate is made (for the JSON's `source`).
pub const HOW: &str = "AR(p) per group and channel, Yule-Walker with the order by BIC, of the \
                       residuals of a generic per-group fit (line, harmonics 1-4 of the \
                       nominal rate, tau*sin and tau*cos, temperature, and the harmonics and \
                       steps the structure scan found), readings at a rail left out; \
                       innovations' level from that fit made by GLS";

/// Harmonics of the nominal rate in the generic fit.
const HARMONICS: usize = 4;

pub use super::structure::{Extra, Generic};

/// Regressors of the generic fit: 1, τ (scaled to [0, 1]), sin kωτ and cos kωτ for
/// k = 1 … [`HARMONICS`], (τ/span)·sin ωτ and (τ/span)·cos ωτ (a rate error's growing
/// quadrature), the temperature when `temp` is given, and `extras`; rows flagged in `skip`
/// are zero.
fn design(
    tau: &[f64],
    omega: f64,
    temp: Option<&[f64]>,
    skip: &[bool],
    extras: &[Extra],
) -> DMatrix<f64> {
    let span = tau.last().copied().unwrap_or(1.0).max(f64::MIN_POSITIVE);
    let extra_cols: usize = extras
        .iter()
        .map(|e| match e {
            Extra::Harmonic(_) => 2,
            Extra::Step(_) => 1,
        })
        .sum();
    let cols = 4 + 2 * HARMONICS + usize::from(temp.is_some()) + extra_cols;
    let mut x = DMatrix::zeros(tau.len(), cols);
    let mut temps = temp.map(<[f64]>::iter);
    for (i, ((mut row, &t), &skipped)) in x.row_iter_mut().zip(tau).zip(skip).enumerate() {
        let temp_t = temps.as_mut().and_then(Iterator::next).copied();
        if skipped {
            continue;
        }
        let harmonic = |k: f64, sine: bool| {
            if sine {
                (k * omega * t).sin()
            } else {
                (k * omega * t).cos()
            }
        };
        let both = |k: f64| [true, false].map(|sine| harmonic(k, sine));
        let extra = extras.iter().flat_map(|e| match *e {
            Extra::Harmonic(k) => both(k as f64).to_vec(),
            Extra::Step(from) => vec![if i >= from { 1.0 } else { 0.0 }],
        });
        let values = [1.0, t / span]
            .into_iter()
            .chain((1..=HARMONICS).flat_map(|k| both(k as f64)))
            .chain(both(1.0).map(|h| t / span * h))
            .chain(temp_t)
            .chain(extra);
        for (x, v) in row.iter_mut().zip(values) {
            *x = v;
        }
    }
    x
}

/// The coefficients of `y` (rows in `flagged` zero) by ordinary least squares on `x`;
/// `None` if `x` is singular.
fn ols_coefficients(x: &DMatrix<f64>, y: &[f64], flagged: &[bool]) -> Option<DVector<f64>> {
    let yv = masked(y, flagged);
    let qr = x.clone().qr();
    let qty = qr.q().transpose() * yv;
    qr.r().solve_upper_triangular(&qty)
}

/// `y` with the rows in `flagged` zero (readings at a rail, out of every fit).
fn masked(y: &[f64], flagged: &[bool]) -> DVector<f64> {
    DVector::from_iterator(
        y.len(),
        y.iter()
            .zip(flagged)
            .map(|(v, f)| if *f { 0.0 } else { *v }),
    )
}

/// Residuals of `y` (rows in `flagged` zero) by ordinary least squares on `x`.
fn ols_residuals(x: &DMatrix<f64>, y: &[f64], flagged: &[bool]) -> DVector<f64> {
    let yv = masked(y, flagged);
    let q = x.clone().qr().q();
    &yv - &q * (q.transpose() * &yv)
}

/// The innovations' variance as the generic fit made by generalised least squares under
/// `m` sees it, relative to `m`'s: RSS_w/(kept rows − coefficients), RSS_w the sum of the
/// squared whitened residuals. This is what a whitened fit's χ² is measured against, and
/// it is unbiased for it. (Rescaling the innovations like the marginal level,
/// [`NoiseModel::rescaled`], would not be: a slowly varying regressor takes a share
/// (1+ρ)/(1−ρ) of the marginal variance for AR(1) noise, but only one whitened degree of
/// freedom; for AR(1) ρ = 0.5 the χ²/dof would sit 0.5 % low.)
fn whitened_level(
    m: &NoiseModel,
    x: DMatrix<f64>,
    y: &DVector<f64>,
    flagged: &[bool],
) -> Result<(f64, Halves), ChannelNoiseError> {
    let keep = whiten_keep(m, flagged);
    let rows = keep.iter().filter(|&&k| k).count();
    // Whitened in place: the design is not needed after.
    let mut xw = x;
    for mut c in xw.column_iter_mut() {
        super::model::whiten(m, c.as_mut_slice(), &keep);
    }
    let mut yw = y.clone();
    super::model::whiten(m, yw.as_mut_slice(), &keep);
    let q = xw.ncols();
    if rows <= q + 10 {
        return Err(ChannelNoiseError::TooFewRows);
    }
    let qr = xw.qr();
    let qm = qr.q();
    let e = &yw - &qm * (qm.transpose() * &yw);
    let level = e.norm_squared() / (rows - q) as f64;
    // The kept rows' whitened residuals, first half against second.
    let kept_e: Vec<f64> = e
        .iter()
        .zip(&keep)
        .filter(|(_, k)| **k)
        .map(|(v, _)| *v)
        .collect();
    let (a, b) = kept_e.split_at(kept_e.len() / 2);
    let mean_square = |x: &[f64]| x.iter().map(|v| v * v).sum::<f64>() / x.len().max(1) as f64;
    let halves = Halves {
        first: mean_square(a),
        second: mean_square(b),
        n: [a.len(), b.len()],
    };
    if level.is_finite() && level > 0.0 {
        Ok((level, halves))
    } else {
        Err(ChannelNoiseError::Zero)
    }
}

/// The mean squares of a group's channel's whitened generic residuals in its two halves
/// (relative to the model before its level is set), and their rows.
#[derive(Clone, Copy, Debug)]
struct Halves {
    first: f64,
    second: f64,
    n: [usize; 2],
}

impl Halves {
    /// Two-sided P of so large a ratio under one level: F(n₁, n₂) (Gaussian innovations;
    /// the few coefficients of the fit left out of the degrees of freedom).
    fn p_value(&self) -> f64 {
        let [n1, n2] = self.n.map(|n| n.max(1) as f64);
        let ratio = self.first / self.second.max(f64::MIN_POSITIVE);
        FisherSnedecor::new(n1, n2)
            .map(|d| 2.0 * d.cdf(ratio).min(d.sf(ratio)))
            .unwrap_or(1.0)
            .min(1.0)
    }
}

fn whiten_keep(m: &NoiseModel, flagged: &[bool]) -> Vec<bool> {
    super::model::kept(m.order(), flagged)
}

/// One group's channel's model: the generic fit's residuals, their AR model, its level
/// rescaled for the fit, and the innovations' level from the fit made by GLS; with the
/// whitened rows kept less the fit's coefficients.
fn model_of(
    y: &[f64],
    (tau, omega): (&[f64], f64),
    temp: Option<&[f64]>,
    flagged: &[bool],
    extras: &[Extra],
) -> Result<(NoiseModel, usize, usize, Halves), ChannelNoiseError> {
    let x = design(tau, omega, temp, flagged, extras);
    let yv = masked(y, flagged);
    let e = ols_residuals(&x, y, flagged);
    let m = NoiseModel::estimate(e.as_slice(), flagged).and_then(|m| m.rescaled(&x))?;
    let q = x.ncols();
    let (factor, halves) = whitened_level(&m, x, &yv, flagged)?;
    let kept = whiten_keep(&m, flagged).iter().filter(|&&k| k).count();
    // The halves' levels as one reading's marginal sd would be under the model.
    let halves = Halves {
        first: halves.first * m.var,
        second: halves.second * m.var,
        ..halves
    };
    Ok((m.scaled(factor), kept, q, halves))
}

/// The noise model per group and channel (u, v, w), each from its generic fit with the
/// structure the scan finds added to it ([`super::structure`], at the workflow's
/// [`super::ALPHA`] over every test made on the file).
pub fn estimate(data: &Data) -> Result<(Vec<[NoiseModel; 3]>, Generic), NoiseEstimateError> {
    for g in &data.groups {
        if g.tau.len() < MIN_ROWS {
            return Err(NoiseEstimateError::ShortGroup {
                condition: g.condition,
                rate_hz: g.rate_hz,
                rows: g.tau.len(),
            });
        }
    }
    // Harmonics first, every group's channel, so that the Bonferroni count is the file's.
    let mut tests = Vec::new();
    for g in &data.groups {
        let temp = varying_temperature(g);
        tests.push(Channel::ALL.map(|ch| {
            let y = ch.of(&g.y);
            let flagged = noise::clipped(y);
            let e = ols_residuals(&design(&g.tau, g.omega(), temp, &flagged, &[]), y, &flagged);
            structure::harmonics(e.as_slice(), sample_interval(&g.tau), g.rate_hz)
        }));
    }
    let count = tests.iter().flatten().map(Vec::len).sum::<usize>().max(1) as f64;
    let channels = (3 * data.groups.len()).max(1) as f64;
    let mut generic = Generic::default();
    let mut models = Vec::new();
    for (g, found) in data.groups.iter().zip(&tests) {
        let temp = varying_temperature(g);
        let mut extras: [Vec<Extra>; 3] = Default::default();
        let mut group_models = Vec::new();
        for ((channel, found), extras) in Channel::ALL.into_iter().zip(found).zip(&mut extras) {
            let at = Place::Group {
                condition: g.condition,
                rate_hz: g.rate_hz,
                channel,
            };
            for h in found {
                let p = (h.p_single * count).min(1.0);
                if p < super::ALPHA {
                    extras.push(Extra::Harmonic(h.k));
                    generic.structure.push(Structure {
                        at,
                        what: Kind::Harmonic(h.k),
                        size: h.amplitude,
                        z: h.z,
                        p_value: p,
                    });
                }
            }
            let y = channel.of(&g.y);
            let flagged = noise::clipped(y);
            let x = design(&g.tau, g.omega(), temp, &flagged, extras);
            let e = ols_residuals(&x, y, &flagged);
            let basis = x.qr().q();
            let found = structure::step(e.as_slice(), &basis);
            // Each of these is rows × coefficients: not held through the fits below.
            drop(basis);
            drop(e);
            if let Some(s) = found {
                let p = (s.p_single * channels).min(1.0);
                if p < super::ALPHA {
                    extras.push(Extra::Step(s.row));
                    // Its height refitted with the step in the design: the scan's own
                    // reading (Frisch–Waugh) is the same value to rounding, but under slow
                    // noise it moved the proofs' witness sessions beyond their tolerance.
                    let x = design(&g.tau, g.omega(), temp, &flagged, extras);
                    let size = ols_coefficients(&x, y, &flagged)
                        .and_then(|b| b.iter().next_back().copied())
                        .unwrap_or(s.size);
                    generic.structure.push(Structure {
                        at,
                        what: Kind::Step {
                            tau_s: g.tau.get(s.row).copied().unwrap_or(0.0),
                            lambda: s.lambda,
                        },
                        size,
                        z: s.z,
                        p_value: p,
                    });
                }
            }
            // Without the temperature if it makes the fit singular (a temperature that is
            // a straight line in time).
            let fit = |temp| model_of(y, (&g.tau, g.omega()), temp, &flagged, extras);
            let (m, kept, q, halves) = fit(temp)
                .or_else(|e| temp.map_or(Err(e), |_| fit(None)))
                .map_err(|cause| NoiseEstimateError::Channel {
                    condition: g.condition,
                    rate_hz: g.rate_hz,
                    channel,
                    cause,
                })?;
            let p = (halves.p_value() * channels).min(1.0);
            if p < super::ALPHA {
                generic.structure.push(Structure {
                    at,
                    what: Kind::NoiseChange {
                        first_sd: halves.first.sqrt(),
                        second_sd: halves.second.sqrt(),
                    },
                    size: halves.second.sqrt() - halves.first.sqrt(),
                    // The normal deviate of the single test's two-sided p.
                    z: -Normal::standard().inverse_cdf((halves.p_value() / 2.0).max(1e-300)),
                    p_value: p,
                });
            }
            generic.dof += kept.saturating_sub(q) as f64;
            generic.coefficients += q;
            group_models.push(m);
        }
        let [u, v, w]: [NoiseModel; 3] = group_models
            .try_into()
            .map_err(|_| NoiseEstimateError::Internal)?;
        models.push([u, v, w]);
        generic.extras.push(extras);
    }
    Ok((models, generic))
}

/// The mean interval between a group's rows, s.
fn sample_interval(tau: &[f64]) -> f64 {
    match (tau.first(), tau.last()) {
        (Some(a), Some(b)) if tau.len() > 1 => (b - a) / (tau.len() - 1) as f64,
        _ => 0.0,
    }
}

/// The group's temperature, where it varies within the group by more than 0.05 °C (only
/// then is it a regressor).
fn varying_temperature(g: &GroupData) -> Option<&[f64]> {
    let (lo, hi) = g
        .temp
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| {
            (lo.min(x), hi.max(x))
        });
    (hi - lo > 0.05).then_some(g.temp.as_slice())
}

/// A group's channel's generic fit for the slow-noise estimate ([`super::slow`]): its
/// design and its residuals by ordinary least squares over the rows not at a rail (those
/// rows are dropped, and the stretches either side joined). Without the temperature where
/// it leaves the fit nearly singular; `None` if the fit is singular anyway.
pub(super) fn generic_fit(
    g: &GroupData,
    ch: Channel,
    extras: &[Extra],
) -> Option<(DMatrix<f64>, Vec<f64>)> {
    let y = ch.of(&g.y);
    let flagged = noise::clipped(y);
    let rows: Vec<usize> = (0..y.len())
        .filter(|&i| !flagged.get(i).copied().unwrap_or(true))
        .collect();
    let fit = |temp: Option<&[f64]>| {
        let x = design(&g.tau, g.omega(), temp, &flagged, extras).select_rows(rows.iter());
        let yk = DVector::from_iterator(rows.len(), rows.iter().filter_map(|&i| y.get(i).copied()));
        let qr = x.clone().qr();
        let r = qr.r();
        let diag = r.diagonal().map(f64::abs);
        if diag.min() <= 1e-10 * diag.max() || yk.len() != x.nrows() {
            return None;
        }
        let q = qr.q();
        let e = &yk - &q * q.tr_mul(&yk);
        Some((x, e.as_slice().to_vec()))
    };
    let temp = varying_temperature(g);
    fit(temp).or_else(|| temp.and_then(|_| fit(None)))
}

/// The χ² of a physical model's `residual` in group `g`'s channel `ch` over the rows the
/// generic fit kept (under `m`, whitened as the generic fit was): what the generic fit's
/// χ², its degrees of freedom, is compared with. (A physical model also counts the rows
/// the generic fit leaves out as at a rail; on a channel whose quantised readings repeat
/// at their extremes those are noise's largest, and would weigh against it unfairly.)
pub(super) fn chi2_on_generic_rows(
    g: &GroupData,
    ch: Channel,
    m: &NoiseModel,
    residual: &[f64],
) -> f64 {
    let flagged = noise::clipped(ch.of(&g.y).as_slice());
    let keep = whiten_keep(m, &flagged);
    let mut r = masked(residual, &flagged);
    super::model::whiten(m, r.as_mut_slice(), &keep);
    r.norm_squared()
}

/// One part of the generic fit, measured in a physical model's residuals.
#[derive(Clone, Debug, PartialEq)]
pub struct Component {
    /// What: "trend", "harmonic k of the table angle", …
    pub what: String,
    /// Its size: an amplitude or a level, output units (a trend: its change over the group).
    pub size: f64,
    /// Wald χ² of its coefficients under the group's channel's noise model.
    pub chi2: f64,
    /// Its coefficients.
    pub k: usize,
    /// The regressor the structure scan added, if it is one (the scan reports it).
    pub extra: Option<Extra>,
    /// Its coefficients' values.
    pub values: Vec<f64>,
    /// Their covariance under the noise model.
    pub cov: DMatrix<f64>,
    /// Per coefficient, its weights on the group's channel's residuals (Σ weight × residual
    /// is the coefficient): for the slow terms' share of its variance.
    pub weights: Vec<Vec<f64>>,
}

/// The transpose of [`super::model::whiten`]: the weights on the raw rows of a linear
/// form `v` of the whitened rows.
fn whiten_transpose(m: &NoiseModel, v: &[f64], keep: &[bool]) -> Vec<f64> {
    let w = 1.0 / m.innovation_var.sqrt().max(f64::MIN_POSITIVE);
    let kept = |t: usize| keep.get(t).copied().unwrap_or(false);
    let at = |t: usize| {
        if kept(t) {
            v.get(t).copied().unwrap_or(0.0)
        } else {
            0.0
        }
    };
    (0..v.len())
        .map(|s| {
            let later: f64 =
                m.ar.iter()
                    .enumerate()
                    .map(|(k, f)| f * at(s + k + 1))
                    .sum();
            (at(s) - later) * w
        })
        .collect()
}

/// The generic fit's parts in `residual` (a physical model's, of group `g`'s channel `ch`)
/// by generalised least squares under `m`: each part's size and Wald χ². What the physical
/// model explains leaves every part at noise (χ² of its k coefficients); what it misses
/// shows where. The parts are taken orthogonal (whitened) to the group's own constant and
/// first harmonic, which the physical model fits freely: so each part's coefficient is the
/// same linear form of the readings as of the residuals, and its weights (for the slow
/// terms' share of its variance) are exact. The constant and the first harmonic are not
/// parts: their residual coefficients are zero.
pub(super) fn components(
    g: &GroupData,
    ch: Channel,
    extras: &[Extra],
    m: &NoiseModel,
    residual: &[f64],
) -> Vec<Component> {
    let flagged = noise::clipped(ch.of(&g.y).as_slice());
    let temp = varying_temperature(g);
    let x = design(&g.tau, g.omega(), temp, &flagged, extras);
    let keep = whiten_keep(m, &flagged);
    let mut xw = x.clone();
    for mut c in xw.column_iter_mut() {
        super::model::whiten(m, c.as_mut_slice(), &keep);
    }
    // The local span (constant, sin ωτ, cos ωτ: columns 0, 2, 3) projected out of the rest.
    let local = [0usize, 2, 3];
    let s = xw.select_columns(local.iter());
    let q = s.clone().qr().q();
    for (j, mut c) in xw.column_iter_mut().enumerate() {
        if !local.contains(&j) {
            let proj = &q * (q.transpose() * &c);
            c -= proj;
        }
    }
    let mut yw = masked(residual, &flagged);
    super::model::whiten(m, yw.as_mut_slice(), &keep);
    let Some(cov) = (xw.transpose() * &xw).try_inverse() else {
        return Vec::new();
    };
    let beta = &cov * (xw.transpose() * yw);
    // Each coefficient's weights on the whitened rows are the rows of cov·Xwᵀ.
    let hat = &xw * &cov;
    // Each part's columns and how its size is read.
    let mut parts: Vec<(String, Vec<usize>, Option<Extra>)> = vec![("trend".into(), vec![1], None)];
    for k in 2..=HARMONICS {
        let c = 2 * k;
        parts.push((
            format!("harmonic {k} of the table angle"),
            vec![c, c + 1],
            None,
        ));
    }
    let mut next = 2 + 2 * HARMONICS;
    parts.push((
        "harmonic 1 growing through the group (a rate)".into(),
        vec![next, next + 1],
        None,
    ));
    next += 2;
    if temp.is_some() {
        parts.push(("temperature".into(), vec![next], None));
        next += 1;
    }
    for e in extras {
        match *e {
            Extra::Harmonic(k) => {
                parts.push((
                    format!("harmonic {k} of the table angle"),
                    vec![next, next + 1],
                    Some(*e),
                ));
                next += 2;
            }
            Extra::Step(row) => {
                let tau = g.tau.get(row).copied().unwrap_or(0.0);
                parts.push((
                    format!("a step in the level {tau:.1} s into the group"),
                    vec![next],
                    Some(*e),
                ));
                next += 1;
            }
        }
    }
    parts
        .into_iter()
        .filter_map(|(what, cols, extra)| {
            let b = DVector::from_iterator(
                cols.len(),
                cols.iter().filter_map(|&c| beta.get(c).copied()),
            );
            let c = cov.select_rows(cols.iter()).select_columns(cols.iter());
            let c_keep = c.clone();
            let chi2 = c.try_inverse().map(|ci| (b.transpose() * ci * &b).sum())?;
            // A pair's amplitude; one coefficient's value (the trend's regressor is τ/span,
            // so its coefficient is the change over the group; the temperature's, per °C).
            let size = if cols.len() == 2 { b.norm() } else { b.sum() };
            let weights = cols
                .iter()
                .map(|&c| {
                    let col: Vec<f64> = hat.column(c).iter().copied().collect();
                    whiten_transpose(m, &col, &keep)
                })
                .collect();
            Some(Component {
                what,
                size,
                chi2,
                k: cols.len(),
                extra,
                values: b.iter().copied().collect(),
                cov: c_keep,
                weights,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The weights on the raw rows give what the whitened form gives: v·W(x) = Wᵀ(v)·x for
    /// an AR(2) filter, with rows left out at the start and around a flagged one.
    #[test]
    fn whitening_transposed_is_its_adjoint() {
        // Only the filter matters here: φ and σ_ε.
        let mut m = NoiseModel::white(4.0, 50);
        m.ar = vec![0.5, -0.2];
        let n = 50;
        let flagged: Vec<bool> = (0..n).map(|i| i == 20).collect();
        let keep = whiten_keep(&m, &flagged);
        let x: Vec<f64> = (0..n).map(|i| ((i * 37 % 11) as f64 - 5.0) * 0.3).collect();
        let v: Vec<f64> = (0..n).map(|i| ((i * 17 % 7) as f64 - 3.0) * 0.7).collect();
        let mut wx = x.clone();
        super::super::model::whiten(&m, &mut wx, &keep);
        let lhs: f64 = v.iter().zip(&wx).map(|(a, b)| a * b).sum();
        let rhs: f64 = whiten_transpose(&m, &v, &keep)
            .iter()
            .zip(&x)
            .map(|(a, b)| a * b)
            .sum();
        assert!(
            (lhs - rhs).abs() < 1e-12 * lhs.abs().max(1.0),
            "{lhs} {rhs}"
        );
    }
}
