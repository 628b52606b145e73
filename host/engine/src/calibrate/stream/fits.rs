//! A streamed group's fits from its sums: prepared after pass 1 (and a correcting pass),
//! finished with the residuals' sums (from the pilots or the residual pass).

use super::first::GroupState;
use super::{REACH_FIT, REACH_REFIT};
use crate::calibrate::group::{rate_choice, GroupFit, RateInputs, Refit, SlowStatus};
use crate::calibrate::pilot::{self, Fitted, Piece};
use crate::calibrate::{err, CalibrateError, CalibrateErrorKind, GroupError, CLOCK};
use crate::fit::batch::BatchError;
use crate::fit::moments::{self, Moments, WIDE, WIDE_HARMONIC};
use crate::fit::noise::{LaggedSums, NoiseModel, LAGS};
use crate::recording::Recording;
use nalgebra::DMatrix;
use rotacal_shared::intrinsic::ConditionFit;
use rotacal_shared::{FitConfig, FitError, FitResult, PhaseStep};
use std::f64::consts::TAU;

/// A streamed group's fits before its residual pass.
pub(super) struct Prepared {
    /// The group's index.
    pub(super) index: usize,
    pub(super) nominal_hz: f64,
    pub(super) nominal: PhaseStep,
    /// The sums the fits come from (about nominal, or about the fitted rate after a
    /// correcting pass).
    pub(super) moments: Moments,
    pub(super) rails: [(Option<f64>, Option<f64>); 3],
    pub(super) four: moments::FourParam,
    pub(super) fitted: PhaseStep,
    /// The widened fit's coefficients per channel, at the fitted rate.
    pub(super) beta: [[f64; WIDE]; 3],
    pub(super) rows: usize,
    /// Clock ticks from the first conversion to the last.
    pub(super) span_ticks: u64,
    /// Each part's sums and pilot, in file order: from pass 1 (about the nominal rate), and
    /// from the correcting pass if it ran (about the rate pass 1 fitted).
    pub(super) pieces: Vec<Piece>,
    pub(super) pieces_fitted: Vec<Piece>,
}

/// A, B, C per channel.
type SineCoefficients = [[f64; 3]; 3];

/// A group's sine coefficients at the fitted and the nominal rate, and the fitted rate
/// less the nominal (rad/s).
pub(super) fn sine_pair(
    p: &Prepared,
) -> Result<(SineCoefficients, SineCoefficients, f64), BatchError> {
    let at_fitted = moments::sine_coefficients(&p.moments, p.fitted)?;
    let at_nominal = moments::sine_coefficients(&p.moments, p.nominal)?;
    Ok((
        at_fitted,
        at_nominal,
        moments::eps_between(p.fitted, p.nominal, CLOCK),
    ))
}

/// A group's residual sums from its parts' pilots (`pilot`), without a residual pass:
/// `None` when a part has no pilot, or the corrections' error bound is not below
/// [`pilot::KAPPA`] of the sums' own scatter.
pub(super) fn from_pilots(p: &Prepared) -> Option<Residuals> {
    let (sine_fitted, sine_nominal, eps) = sine_pair(p).ok()?;
    let fit = Fitted {
        nominal: p.nominal,
        fitted: p.fitted,
        eps,
        wide: &p.beta,
        sine_fitted: &sine_fitted,
        sine_nominal: &sine_nominal,
    };
    let corrected = |pieces: &[Piece]| -> Option<Vec<pilot::PieceSums>> {
        pieces.iter().map(|pc| pilot::corrected(pc, &fit)).collect()
    };
    // The lagged sums and the fitted rate's RSS from the pilots about the rate the sums
    // were last gathered about; the nominal rate's RSS from pass 1's, about nominal.
    let at_nominal = corrected(&p.pieces)?;
    let sums = if p.pieces_fitted.is_empty() {
        None
    } else {
        Some(corrected(&p.pieces_fitted)?)
    };
    let sums = sums.as_ref().unwrap_or(&at_nominal);
    let mut out = Residuals {
        lagged: Default::default(),
        rss_fitted: [0.0; 3],
        rss_nominal: [0.0; 3],
    };
    let rows = p.rows.max(1) as f64;
    for ch in 0..3 {
        // Joined in file order, and the bounds summed over the parts: the fitted rate's
        // RSS from `sums`, the nominal rate's from `at_nominal`.
        let (mut joined, mut bound) = (None::<LaggedSums>, [0.0; LAGS]);
        let (mut rss, mut rss_bound) = ([0.0; 2], [0.0; 2]);
        for c in sums.iter().filter_map(|s| s.get(ch)) {
            joined = Some(match joined {
                Some(j) => j.followed_by(&c.lagged),
                None => c.lagged.clone(),
            });
            for (a, x) in bound.iter_mut().zip(c.bound) {
                *a += x;
            }
            rss[0] += c.rss[0];
            rss_bound[0] += c.rss_bound[0];
        }
        for c in at_nominal.iter().filter_map(|s| s.get(ch)) {
            rss[1] += c.rss[1];
            rss_bound[1] += c.rss_bound[1];
        }
        let joined = joined?;
        // The lagged sums' own standard error is about γ₀·√N, the RSS's RSS·√(2/N).
        let (prod, _) = joined.products();
        let own = prod.first().copied().unwrap_or(0.0) / rows.sqrt();
        let within = bound.iter().all(|b| *b <= pilot::KAPPA * own)
            && rss_bound
                .iter()
                .zip(rss)
                .all(|(b, r)| *b <= pilot::KAPPA * r * (2.0 / rows).sqrt());
        if !within || !own.is_finite() {
            return None;
        }
        if let (Some(l), Some(f), Some(n)) = (
            out.lagged.get_mut(ch),
            out.rss_fitted.get_mut(ch),
            out.rss_nominal.get_mut(ch),
        ) {
            (*l, *f, *n) = (joined, rss[0], rss[1]);
        }
    }
    Some(out)
}

/// Whether a channel of a group has readings on a rail.
pub(super) fn on_rails(rails: &[(Option<f64>, Option<f64>); 3]) -> bool {
    rails.iter().any(|r| r.0.is_some() || r.1.is_some())
}

/// A streamed group's fit, from its sums and its residuals: the noise model, the rate
/// the fit uses, the sine fit and its covariance, as [`super::fit_group`] makes them.
pub(super) fn finish(
    rec: &Recording,
    gs: &GroupState,
    p: &Prepared,
    r: Residuals,
) -> Result<GroupFit, CalibrateError> {
    let fail = |e: GroupError| e.of(rec, Some(gs.first_line), gs.condition);
    let span_s = p.span_ticks as f64 / f64::from(CLOCK.hz());
    let omega = TAU * p.four.rate_hz * span_s / (p.rows.max(2) - 1) as f64;
    let freqs: Vec<f64> = WIDE_HARMONIC
        .iter()
        .map(|k| f64::from(*k) * omega)
        .collect();
    let mut noise = Vec::with_capacity(3);
    for acc in &r.lagged {
        let (n, used) = acc.counts();
        let m = NoiseModel::from_autocovariances(&acc.autocovariances(), n, used)
            .and_then(|m| m.rescaled_for_sinusoids(n, &freqs))
            .map_err(|e| fail(e.into()))?;
        noise.push(m);
    }
    let Ok(noise) = <[NoiseModel; 3]>::try_from(noise) else {
        return Err(err(
            rec,
            Some(gs.first_line),
            CalibrateErrorKind::Internal("three channels' noise models expected"),
        ));
    };
    let inputs = RateInputs {
        fit: (p.four.rate_hz, p.four.se_rate_hz),
        coef: p.four.coef,
        omega_per_sample: omega,
        nominal_hz: p.nominal_hz,
    };
    let rate = rate_choice(&inputs, &noise, [1.0; 3]);
    let (step, rss) = if rate.fitted {
        (p.fitted, r.rss_fitted)
    } else {
        (p.nominal, r.rss_nominal)
    };
    let normal = p.moments.sine_at(step);
    let fit = sine_result(&normal, rss, p).map_err(fail)?;
    let gram = DMatrix::from_iterator(3, 3, normal.g.iter().copied());
    let mut cov = [[[0.0; 3]; 3]; 3];
    for (c, m) in cov.iter_mut().zip(&noise) {
        let s = m
            .sandwich_for_sinusoids(&gram, &[omega, omega, 0.0])
            .map_err(|e| fail(e.into()))?;
        for (row, s_row) in c.iter_mut().zip(s.row_iter()) {
            for (x, v) in row.iter_mut().zip(s_row.iter()) {
                *x = *v;
            }
        }
    }
    // A streamed group keeps sums only: its slow noise is not modelled (docs/uncertainty.md).
    Ok(GroupFit::new(
        gs.condition,
        fit,
        rate,
        (cov, noise, [None, None, None]),
        omega,
        SlowStatus::FromSums,
    ))
}

/// The sine fit as the streaming fit reports it ([`rotacal_shared::SineFit::solve`]),
/// from the sums' normal equations at its rate and the residual sums of squares the
/// residual pass measured.
fn sine_result(
    normal: &moments::SineNormal,
    rss: [f64; 3],
    p: &Prepared,
) -> Result<FitResult<f64>, GroupError> {
    let chol = normal
        .g
        .cholesky()
        .ok_or(GroupError::Fit(FitError::Singular))?;
    let inv = chol.inverse();
    let n = u32::try_from(p.rows).map_err(|_| GroupError::TooManyRows)?;
    let mut unscaled_cov = [[0.0; rotacal_shared::MAX_PARAMS]; rotacal_shared::MAX_PARAMS];
    for (row, inv_row) in unscaled_cov.iter_mut().zip(inv.row_iter()).take(3) {
        for (x, v) in row.iter_mut().zip(inv_row.iter()).take(3) {
            *x = *v;
        }
    }
    let mut channels = [rotacal_shared::ChannelFit::<f64> {
        coef: [rotacal_shared::DoubleWord { hi: 0.0, lo: 0.0 }; rotacal_shared::MAX_PARAMS],
        se: [0.0; rotacal_shared::MAX_PARAMS],
        rss: 0.0,
        sigma: 0.0,
        rms_residual: 0.0,
    }; 3];
    for (ch, (out, rss)) in channels.iter_mut().zip(rss).enumerate() {
        let b = chol.solve(&normal.xh.column(ch).into_owned());
        let var = rss / f64::from(n.saturating_sub(3).max(1));
        let inv_diag = inv.diagonal();
        let coef_se = out.coef.iter_mut().zip(out.se.iter_mut());
        for ((c, se), (bi, d)) in coef_se.zip(b.iter().zip(inv_diag.iter())).take(3) {
            *c = rotacal_shared::DoubleWord { hi: *bi, lo: 0.0 };
            *se = (var * d.max(0.0)).sqrt();
        }
        out.rss = rss;
        out.sigma = var.sqrt();
        out.rms_residual = (rss / f64::from(n.max(1))).sqrt();
    }
    Ok(FitResult {
        model: rotacal_shared::Model::SINE,
        n,
        t_first: rotacal_shared::Ticks(0),
        t_last: rotacal_shared::Ticks(p.span_ticks),
        t_ref: None,
        unscaled_cov,
        channels,
    })
}

/// A streamed group's fits from its pass-1 sums.
pub(super) fn prepare(
    rec: &Recording,
    index: usize,
    gs: &mut GroupState,
    nominal_hz: f64,
) -> Result<Prepared, CalibrateError> {
    let line = Some(gs.first_line);
    let condition = gs.condition;
    let fail = |e: GroupError| e.of(rec, line, condition);
    if gs.t0.is_none() {
        return Err(err(rec, line, CalibrateErrorKind::NoTime));
    }
    if let Some(m) = gs.row_problem {
        return Err(err(rec, line, CalibrateErrorKind::Row(m)));
    }
    let (Some((_, nominal)), Some(moments)) = (gs.nominal, gs.moments.take()) else {
        return Err(err(rec, line, CalibrateErrorKind::UnusableRate(nominal_hz)));
    };
    // Each part's sums and pilot (a group one thread read whole: its own).
    let pieces = std::mem::take(&mut gs.pilots).into_pieces(&moments);
    // Folded once: every fit below reads the dense sums.
    let moments = moments.dense();
    // As the streaming fit checks its record (docs/method.md §5).
    let cfg = FitConfig::sine(nominal, CLOCK);
    let span = gs.span_ticks;
    let milli = (nominal.turns_x2_64(span).saturating_mul(1000) >> 64) as u64;
    if milli < u64::from(cfg.min_milli_periods) {
        let e = rotacal_shared::FitError::TooFewPeriods {
            milli_periods: milli,
            needed: cfg.min_milli_periods,
        };
        return Err(fail(e.into()));
    }
    let four =
        moments::four_param(&moments, nominal, CLOCK).map_err(|e| fail(GroupError::RateFit(e)))?;
    let fitted = PhaseStep::from_hz(four.rate_hz, CLOCK)
        .ok_or_else(|| err(rec, line, CalibrateErrorKind::UnusableFittedRate))?;
    let rails = gs.rails.map(|r| r.found());
    // The widened fit's coefficients, if the sums reach the fitted rate (else the
    // correcting pass computes them, as it does with rails).
    let beta = if moments.within(fitted, REACH_FIT) {
        moments::wide_betas(&moments, &[None, None, None], fitted).map_err(|e| fail(e.into()))?
    } else {
        [[0.0; WIDE]; 3]
    };
    Ok(Prepared {
        index,
        nominal_hz,
        nominal,
        moments,
        rails,
        four,
        fitted,
        beta,
        rows: gs.rows,
        span_ticks: gs.span_ticks,
        pieces,
        pieces_fitted: Vec::new(),
    })
}

/// A streamed condition's sine refitted at a nearby rate: the fit's own (A, B) moved by
/// the change the sums give between its rate (`central`) and the new one.
pub(super) struct StreamRefit {
    pub(super) moments: Moments,
    pub(super) central: PhaseStep,
    pub(super) fit: ConditionFit,
}

impl Refit for StreamRefit {
    fn refit(&self, rate_hz: f64) -> Result<ConditionFit, GroupError> {
        let step = PhaseStep::from_hz(rate_hz, CLOCK).ok_or(GroupError::Rate(rate_hz))?;
        if !self.moments.within(step, REACH_REFIT) {
            return Err(GroupError::OutOfReach {
                rate_hz,
                reach: self.moments.reach(step),
                limit: REACH_REFIT,
            });
        }
        let (at, here) = (
            moments::sine_coefficients(&self.moments, step)?,
            moments::sine_coefficients(&self.moments, self.central)?,
        );
        let mut out = self.fit;
        for ch in 0..3 {
            if let (Some(a), Some(b), Some(x), Some(h)) = (
                out.a.get_mut(ch),
                out.b.get_mut(ch),
                at.get(ch),
                here.get(ch),
            ) {
                *a += x[0] - h[0];
                *b += x[1] - h[1];
            }
        }
        Ok(out)
    }
}

/// What the residual pass gives for a group.
pub(super) struct Residuals {
    /// Per channel, the widened fit's residuals' lagged sums.
    pub(super) lagged: [LaggedSums; 3],
    /// Per channel, Σ n·(y − ŷ)² of the sine fit at the fitted and at the nominal rate.
    pub(super) rss_fitted: [f64; 3],
    pub(super) rss_nominal: [f64; 3],
}
