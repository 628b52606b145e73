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

use super::model::{Data, GroupData};
use crate::fit::noise::{self, NoiseError, NoiseModel};
use nalgebra::{DMatrix, DVector};
use rotacal_shared::{Channel, Condition};

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
}

/// The fewest rows a group needs for its noise to be estimated.
const MIN_ROWS: usize = 30;

/// How the estimate is made (for the JSON's `source`).
pub const HOW: &str = "AR(p) per group and channel, Yule-Walker with the order by BIC, of the \
                       residuals of a generic per-group fit (line, harmonics 1-4 of the \
                       nominal rate, tau*sin and tau*cos, temperature), readings at a rail \
                       left out; innovations' level from that fit made by GLS";

/// Harmonics of the nominal rate in the generic fit.
const HARMONICS: usize = 4;

/// Regressors of the generic fit: 1, τ (scaled to [0, 1]), sin kωτ and cos kωτ for
/// k = 1 … [`HARMONICS`], (τ/span)·sin ωτ and (τ/span)·cos ωτ (a rate error's growing
/// quadrature), and the temperature when `temp` is given; rows flagged in `skip` are zero.
fn design(tau: &[f64], omega: f64, temp: Option<&[f64]>, skip: &[bool]) -> DMatrix<f64> {
    let span = tau.last().copied().unwrap_or(1.0).max(f64::MIN_POSITIVE);
    let cols = 4 + 2 * HARMONICS + usize::from(temp.is_some());
    let mut x = DMatrix::zeros(tau.len(), cols);
    let mut temps = temp.map(<[f64]>::iter);
    for ((mut row, &t), &skipped) in x.row_iter_mut().zip(tau).zip(skip) {
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
        let values = [1.0, t / span]
            .into_iter()
            .chain((1..=HARMONICS).flat_map(|k| both(k as f64)))
            .chain(both(1.0).map(|h| t / span * h))
            .chain(temp_t);
        for (x, v) in row.iter_mut().zip(values) {
            *x = v;
        }
    }
    x
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
    x: &DMatrix<f64>,
    y: &DVector<f64>,
    flagged: &[bool],
) -> Result<f64, ChannelNoiseError> {
    let keep = whiten_keep(m, flagged);
    let rows = keep.iter().filter(|&&k| k).count();
    let mut xw = x.clone();
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
    if level.is_finite() && level > 0.0 {
        Ok(level)
    } else {
        Err(ChannelNoiseError::Zero)
    }
}

fn whiten_keep(m: &NoiseModel, flagged: &[bool]) -> Vec<bool> {
    super::model::kept(m.order(), flagged)
}

/// One group's channel's model: the generic fit's residuals, their AR model, its level
/// rescaled for the fit, and the innovations' level from the fit made by GLS.
fn model_of(
    y: &[f64],
    tau: &[f64],
    omega: f64,
    temp: Option<&[f64]>,
    flagged: &[bool],
) -> Result<NoiseModel, ChannelNoiseError> {
    let x = design(tau, omega, temp, flagged);
    let yv = DVector::from_iterator(
        y.len(),
        y.iter()
            .zip(flagged)
            .map(|(v, f)| if *f { 0.0 } else { *v }),
    );
    let qr = x.clone().qr();
    let q = qr.q();
    let e = &yv - &q * (q.transpose() * &yv);
    let m = NoiseModel::estimate(e.as_slice(), flagged).and_then(|m| m.rescaled(&x))?;
    let factor = whitened_level(&m, &x, &yv, flagged)?;
    Ok(m.scaled(factor))
}

/// The noise model per group and channel (u, v, w).
pub fn estimate(data: &Data) -> Result<Vec<[NoiseModel; 3]>, NoiseEstimateError> {
    data.groups.iter().map(group_models).collect()
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
pub(super) fn generic_fit(g: &GroupData, ch: Channel) -> Option<(DMatrix<f64>, Vec<f64>)> {
    let y = ch.of(&g.y);
    let flagged = noise::clipped(y);
    let rows: Vec<usize> = (0..y.len())
        .filter(|&i| !flagged.get(i).copied().unwrap_or(true))
        .collect();
    let fit = |temp: Option<&[f64]>| {
        let x = design(&g.tau, g.omega(), temp, &flagged).select_rows(rows.iter());
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

/// One group's models, u, v, w.
fn group_models(g: &GroupData) -> Result<[NoiseModel; 3], NoiseEstimateError> {
    let rows = g.tau.len();
    if rows < MIN_ROWS {
        return Err(NoiseEstimateError::ShortGroup {
            condition: g.condition,
            rate_hz: g.rate_hz,
            rows,
        });
    }
    let temp = varying_temperature(g);
    let model = |channel: Channel| {
        let y = channel.of(&g.y);
        let flagged = noise::clipped(y);
        // Without the temperature if it makes the fit singular (a temperature that is a
        // straight line in time).
        model_of(y, &g.tau, g.omega(), temp, &flagged)
            .or_else(|e| temp.map_or(Err(e), |_| model_of(y, &g.tau, g.omega(), None, &flagged)))
            .map_err(|cause| NoiseEstimateError::Channel {
                condition: g.condition,
                rate_hz: g.rate_hz,
                channel,
                cause,
            })
    };
    Ok([model(Channel::U)?, model(Channel::V)?, model(Channel::W)?])
}
