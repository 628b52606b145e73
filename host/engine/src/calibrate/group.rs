//! One condition's fit at one rate from its rows: the samples, the IEEE 1057 rate fit and
//! the choice of rate, the sine fit in f64, the noise model of its residuals and the
//! fit's covariance under it; and the refit at another rate the budget needs.

use super::{err, CalibrateError, CalibrateErrorKind, GroupError, CLOCK};
use crate::fit::batch;
use crate::fit::noise::{self, NoiseError, NoiseModel};
use crate::recording::{Group, Recording};
use nalgebra::DMatrix;
use rotacal_shared::intrinsic::ConditionFit;
use rotacal_shared::{Channel, Condition};
use rotacal_shared::{FitConfig, FitError, FitResult, Param, PhaseStep, SineFit, Ticks};
use std::f64::consts::TAU;

/// A group's samples: the instants of the conversions each row averages, in ticks of the
/// 1 MHz clock from its first row (one, at `t_s`, without a `conv_gaps` column), and
/// [u, v, w]. The times and phases every rotation fit here uses.
pub fn samples(rec: &Recording, g: &Group) -> Result<Vec<batch::Sample>, CalibrateError> {
    let t0 = g.t_s.first().copied().unwrap_or(0.0);
    // conv_gaps count device ticks; here they become ticks of CLOCK (exact at 1 MHz).
    let scale = crate::recording::tick_scale(&rec.meta, CLOCK);
    let mut out = Vec::with_capacity(g.len());
    for (i, (t, (u, (v, w)))) in g
        .t_s
        .iter()
        .zip(g.u.iter().zip(g.v.iter().zip(g.w.iter())))
        .enumerate()
    {
        let gaps = g.conversions.as_ref().and_then(|c| c.get(i));
        let ap = crate::recording::row_aperture(*t, t0, gaps, scale, CLOCK)
            .map_err(|m| err(rec, Some(g.first_line), CalibrateErrorKind::Row(m)))?;
        out.push((ap, [*u, *v, *w]));
    }
    Ok(out)
}

/// One condition's fit at one rate: the coefficients of the streaming fit in f64, and
/// their covariance under the noise estimated from the fit's own residuals
/// ([`crate::fit::noise`]).
#[derive(Clone, Debug)]
pub struct GroupFit {
    /// The platter axis.
    pub condition: Condition,
    /// The fit (its own standard errors assume white noise: use `cov`).
    pub fit: FitResult<f64>,
    /// The rotation rate the fit used, Hz.
    pub rate_hz: f64,
    /// That rate, when it was estimated from the data (IEEE 1057) rather than nominal.
    pub rate_fitted: Option<f64>,
    /// Standard uncertainty of the rate the fit used, Hz: the rate fit's standard error
    /// (scaled for the noise), and, at the nominal rate, the distance to the fitted one too.
    pub u_rate_hz: f64,
    /// Covariance of (A, B, C) per channel under the noise model.
    pub cov: [[[f64; 3]; 3]; 3],
    /// The noise model per channel.
    pub noise: [NoiseModel; 3],
    /// The rotation's angle per sample, rad (mean over the group).
    pub omega_per_sample: f64,
}

impl GroupFit {
    /// The fit of `condition` at the rate `rate` chose, with its covariance under `noise`
    /// and the rotation's angle per sample, rad.
    pub(crate) fn new(
        condition: Condition,
        fit: FitResult<f64>,
        rate: RateChoice,
        cov: [[[f64; 3]; 3]; 3],
        noise: [NoiseModel; 3],
        omega_per_sample: f64,
    ) -> GroupFit {
        GroupFit {
            condition,
            fit,
            rate_hz: rate.rate_hz,
            rate_fitted: rate.rate_fitted,
            u_rate_hz: rate.u_rate_hz,
            cov,
            noise,
            omega_per_sample,
        }
    }

    /// (A, B) per channel and their covariance.
    pub fn condition_fit(&self) -> ConditionFit {
        let mut cf = ConditionFit::from_fit(&self.fit);
        for (c, m) in cf.cov.iter_mut().zip(&self.cov) {
            *c = [[m[0][0], m[0][1]], [m[1][0], m[1][1]]];
        }
        cf
    }

    /// Coefficient `p` (0 = A, 1 = B, 2 = C) of channel `ch`.
    pub fn coef(&self, ch: usize, p: Param) -> f64 {
        self.fit.coef(ch, p).map_or(f64::NAN, |v| v.to_f64())
    }

    /// Standard uncertainty of coefficient A, B or C of channel `ch` under the noise model.
    pub fn std_unc(&self, ch: usize, i: usize) -> f64 {
        self.cov
            .get(ch)
            .and_then(|m| m.get(i))
            .and_then(|r| r.get(i))
            .map_or(f64::NAN, |v| v.max(0.0).sqrt())
    }
}

/// The streaming fit of (sin, cos, 1) at `step` in f64 (an average enters as its sum).
fn fit_at(s: &[batch::Sample], step: PhaseStep) -> Result<FitResult<f64>, FitError> {
    let mut fit = SineFit::<f64>::new(FitConfig::sine(step, CLOCK));
    for (ap, y) in s {
        let n = ap.len().max(1) as f64;
        fit.update_sum(ap, y.map(|v| v * n))?;
    }
    fit.solve()
}

/// Regressors that take out of the residuals what a sine fit leaves that is not noise:
/// a linear trend and harmonics 2 to 4 of the rotation (drift, nonlinearity, clipping).
/// Left in, such a deterministic remainder would read as strongly correlated noise: a
/// second harmonic of 16 counts on a 10 mHz run read as an AR process of variance factor
/// 170 at ω.
const CLEANING_HARMONICS: std::ops::RangeInclusive<u32> = 2..=4;

/// The cleaning fit's columns beyond the sine's: a trend, then sin and cos of each harmonic.
const CLEANING_COLUMNS: usize =
    1 + 2 * (*CLEANING_HARMONICS.end() - *CLEANING_HARMONICS.start() + 1) as usize;

/// The noise model of each channel, from the residuals of the sine fit at `step` widened by
/// [`CLEANING_HARMONICS`] and a trend, its level corrected for that wider fit.
fn noise_models(s: &[batch::Sample], step: PhaseStep) -> Result<[NoiseModel; 3], NoiseError> {
    let h = batch::design(s, step, CLOCK, rotacal_shared::Model::SINE, Ticks(0));
    let t_end = s.last().map_or(1.0, |x| x.0.last().0.max(1) as f64);
    // A trend and the harmonics' sines and cosines, averaged over each sample's conversions
    // and weighted as `h`'s rows.
    let mut wide = DMatrix::zeros(s.len(), 3 + CLEANING_COLUMNS);
    wide.columns_mut(0, 3).copy_from(&h);
    for ((ap, _), mut row) in s.iter().zip(wide.row_iter_mut()) {
        let extra = batch::mean_over(ap, |t| {
            let mut r = [0.0; CLEANING_COLUMNS];
            r[0] = t.0 as f64 / t_end - 0.5;
            let alpha = step.phase_at(t).radians();
            for (k, pair) in CLEANING_HARMONICS.zip(r[1..].chunks_mut(2)) {
                if let [a, b] = pair {
                    (*a, *b) = (f64::from(k) * alpha).sin_cos();
                }
            }
            r
        });
        let w = batch::root_weight(ap);
        for (x, v) in row.iter_mut().skip(3).zip(extra) {
            *x = w * v;
        }
    }
    // Normal equations: the columns are near-orthogonal (sines, a centred trend), so their
    // Cholesky solve is as good as QR here and needs no N × q factor. Readings on a rail are
    // not measurements of the model: they are left out of this fit as of the estimate.
    let full = wide.tr_mul(&wide);
    let mut models = Vec::with_capacity(3);
    for ch in Channel::ALL {
        let plain: Vec<f64> = s.iter().map(|(_, y)| *ch.of(y)).collect();
        let flags = noise::clipped(&plain);
        let y = nalgebra::DVector::from_iterator(
            s.len(),
            s.iter().map(|(ap, y)| batch::root_weight(ap) * ch.of(y)),
        );
        let mut normal = full.clone();
        let mut rhs = wide.tr_mul(&y);
        for ((row, _), yi) in wide
            .row_iter()
            .zip(&flags)
            .zip(y.iter())
            .filter(|((_, f), _)| **f)
        {
            normal -= row.transpose() * row;
            rhs -= row.transpose() * *yi;
        }
        let beta = normal.cholesky().ok_or(NoiseError::Singular)?.solve(&rhs);
        let resid = &y - &wide * beta;
        models.push(NoiseModel::estimate(resid.as_slice(), &flags)?.rescaled(&wide)?);
    }
    models.try_into().map_err(|_| NoiseError::TooFew(0))
}

/// The sandwich covariance of (A, B, C) per channel at `step` under `models`.
fn sine_cov(
    s: &[batch::Sample],
    step: PhaseStep,
    models: &[NoiseModel; 3],
) -> Result<[[[f64; 3]; 3]; 3], NoiseError> {
    let h = batch::design(s, step, CLOCK, rotacal_shared::Model::SINE, Ticks(0));
    let mut covs = [[[0.0; 3]; 3]; 3];
    for (cov, m) in covs.iter_mut().zip(models) {
        let c = m.sandwich(&h)?;
        for (row, c_row) in cov.iter_mut().zip(c.row_iter()) {
            for (x, v) in row.iter_mut().zip(c_row.iter()) {
                *x = *v;
            }
        }
    }
    Ok(covs)
}

/// The rate a condition's fit uses ([`rate_choice`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct RateChoice {
    /// The fitted rate, which differs from nominal by more than 3 of its standard errors.
    pub(crate) fitted: bool,
    /// The rate the fit uses, Hz.
    pub(crate) rate_hz: f64,
    /// That rate, when it is the fitted one.
    pub(crate) rate_fitted: Option<f64>,
    /// Its standard uncertainty, Hz: the fitted rate's standard error, and at the nominal
    /// rate the distance to the fitted one too.
    pub(crate) u_rate_hz: f64,
}

/// The rate the fit uses: the fitted one if it differs from nominal by more than 3 of its
/// standard error under the channels' noise, else the nominal; from the IEEE 1057 fit's
/// (rate, standard error) and coefficients (A, B, C per channel).
///
/// The rate's standard error is that of one unweighted joint fit with a pooled σ̂² (the
/// mean of the channels' variances). Under the channels' own noise its variance is
/// Σ f_j γ₀_j A_j² / (Σ A_j²)² against σ̄²/Σ A_j²: f_j the variance factor at ω, γ₀_j
/// the level, A_j² the channel's share of the rate information.
pub(crate) fn rate_choice(
    (rate_hz, se_rate_hz): (f64, f64),
    coef: &[[f64; 3]; 3],
    noise: &[NoiseModel; 3],
    omega_per_sample: f64,
    nominal_hz: f64,
) -> RateChoice {
    let (mut num, mut den) = (0.0, 0.0);
    for (m, c) in noise.iter().zip(coef) {
        let amp2 = c[0] * c[0] + c[1] * c[1];
        num += m.variance_factor(omega_per_sample) * m.var * amp2;
        den += amp2;
    }
    let pooled = noise.iter().map(|m| m.var).sum::<f64>() / 3.0;
    let factor = if den > 0.0 && pooled > 0.0 {
        num / (den * pooled)
    } else {
        1.0
    };
    let se_rate = se_rate_hz * factor.max(1e-6).sqrt();
    if (rate_hz - nominal_hz).abs() > 3.0 * se_rate {
        RateChoice {
            fitted: true,
            rate_hz,
            rate_fitted: Some(rate_hz),
            u_rate_hz: se_rate,
        }
    } else {
        RateChoice {
            fitted: false,
            rate_hz: nominal_hz,
            rate_fitted: None,
            u_rate_hz: se_rate.hypot(rate_hz - nominal_hz),
        }
    }
}

pub(crate) fn fit_group(
    rec: &Recording,
    g: &Group,
    s: &[batch::Sample],
    nominal_hz: f64,
) -> Result<GroupFit, CalibrateError> {
    let fail = |e: GroupError| e.of(rec, Some(g.first_line), g.condition);
    let nominal = PhaseStep::from_hz(nominal_hz, CLOCK).ok_or_else(|| {
        err(
            rec,
            Some(g.first_line),
            CalibrateErrorKind::UnusableRate(nominal_hz),
        )
    })?;
    // Fitted first at the nominal rate: this also checks the span, so a short record gets
    // the plain 'too few periods' message rather than a failure of the rate fit.
    let at_nominal = fit_at(s, nominal).map_err(|e| fail(e.into()))?;
    let four =
        batch::fit_four_param(s, nominal, CLOCK).map_err(|e| fail(GroupError::RateFit(e)))?;
    let fitted_step = PhaseStep::from_hz(four.rate_hz, CLOCK).ok_or_else(|| {
        err(
            rec,
            Some(g.first_line),
            CalibrateErrorKind::UnusableFittedRate,
        )
    })?;
    let span_s = match (s.first(), s.last()) {
        (Some(a), Some(b)) => batch::seconds_between(b.0.last(), a.0.first(), CLOCK),
        _ => 0.0,
    };
    let omega_per_sample = TAU * four.rate_hz * span_s / (s.len().max(2) - 1) as f64;
    let coef_of = |f: &batch::BatchFit| {
        [0, 1, 2].map(|ch| {
            let c = |i: usize| {
                f.channels
                    .get(ch)
                    .and_then(|x| x.coef.get(i))
                    .copied()
                    .unwrap_or(f64::NAN)
            };
            [c(0), c(1), c(2)]
        })
    };
    let four_coef = coef_of(&four.fit);
    // The noise is modelled once, about the fitted rate (the best description of the
    // data): at the nominal rate a rate error's growing quadrature would read as noise.
    let noise = noise_models(s, fitted_step).map_err(|e| fail(e.into()))?;
    let rate = rate_choice(
        (four.rate_hz, four.se_rate_hz),
        &four_coef,
        &noise,
        omega_per_sample,
        nominal_hz,
    );
    let (step, fit) = if rate.fitted {
        let fit = fit_at(s, fitted_step).map_err(|e| fail(e.into()))?;
        (fitted_step, fit)
    } else {
        (nominal, at_nominal)
    };
    let cov = sine_cov(s, step, &noise).map_err(|e| fail(e.into()))?;
    Ok(GroupFit::new(
        g.condition,
        fit,
        rate,
        cov,
        noise,
        omega_per_sample,
    ))
}

/// The sine fit of a condition refitted at another rate (the budget's sensitivity to the
/// rate): from its samples, or from a streamed record's sums ([`stream`]).
pub(crate) trait Refit {
    /// (A, B) per channel of the sine fit at `rate_hz`.
    fn refit(&self, rate_hz: f64) -> Result<ConditionFit, GroupError>;
}

impl Refit for Vec<batch::Sample> {
    fn refit(&self, rate_hz: f64) -> Result<ConditionFit, GroupError> {
        let step = PhaseStep::from_hz(rate_hz, CLOCK).ok_or(GroupError::Rate(rate_hz))?;
        Ok(ConditionFit::from_fit(&fit_at(self, step)?))
    }
}
