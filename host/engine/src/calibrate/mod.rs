//! `rotacal calibrate`: from a recording to the calibration JSON and a terminal table.
//!
//! Rotation files: per nominal rate and condition, the IEEE 1057 fit tests whether the
//! data's rotation rate differs from nominal (by more than 3 standard errors); if so that
//! rate is used (and reported as `rate_hz_fitted`). Each channel is then fitted with the
//! streaming fit in f64, and the intrinsic properties come from the Gram matrix.
//! Timestamps are converted to ticks of a 1 MHz clock (t_s has microsecond resolution in
//! every writer we know of).
//!
//! Its parts: [`methods`] (rotation and stepped methods from
//! fits, the static method from poses, their Monte Carlo), [`poses`] (the joint fit of S
//! and O to known orientations), [`budget`] (the GUM budget), [`correction`] (the correction
//! M·(y − O) and its covariance), [`json`] (the calibration JSON, docs/formats.md) and
//! [`table`] (the terminal summary).

pub mod budget;
pub mod correction;
pub mod free;
pub mod json;
pub mod methods;
mod pilot;
pub mod poses;
pub mod still;
pub mod stream;
pub mod table;

use crate::calibrate::budget::{Budget, Kind};
use crate::fit::batch;

use crate::calibrate::json::{CalibrationJson, CorrectionJson, FitJson, NoiseJson};

use crate::calibrate::poses::StaticCondition;
use crate::fit::noise::{self, NoiseError, NoiseModel};
use crate::recording::{Group, Method, Recording};
use nalgebra::DMatrix;
use rotacal_shared::intrinsic::{self, ConditionFit};
use rotacal_shared::{Condition, FitConfig, FitResult, Param, PhaseStep, SineFit, TickRate, Ticks};
use std::borrow::Cow;
use std::f64::consts::TAU;

/// Command-line choices, which override the file's metadata.
#[derive(Clone, Debug, Default)]
pub struct Options {
    /// Force the method.
    pub method: Option<Method>,
    /// Nominal rotation rate, Hz.
    pub rate_hz: Option<f64>,
    /// Local gravity, m/s².
    pub g_loc: Option<f64>,
    /// Also propagate by Monte Carlo (GUM Supplement 1) with this many trials.
    pub monte_carlo: Option<usize>,
    /// Static data: pose weighting and offset estimator.
    pub poses: poses::Options,
    /// Method free: how still intervals are found.
    pub still: still::Options,
    /// Standard uncertainties of the type-B inputs (override the file's `u_*` keys).
    pub inputs: TypeB,
}

/// Standard uncertainties of the inputs that are not in the data (type B).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TypeB {
    /// Local gravity, m/s² (`--u-g-loc`, `# u_g_loc=`).
    pub u_g_loc: Option<f64>,
    /// Each timestamp beyond its resolution (jitter), s (`--u-time-s`, `# u_time_s=`).
    pub u_time_s: Option<f64>,
    /// Each stepped table angle, degrees (`--u-angle-deg`, `# u_angle_deg=`).
    pub u_angle_deg: Option<f64>,
}

impl TypeB {
    /// These, else the recording's metadata.
    fn or_file(self, rec: &Recording) -> TypeB {
        TypeB {
            u_g_loc: self.u_g_loc.or(rec.meta.uncertainty("u_g_loc")),
            u_time_s: self.u_time_s.or(rec.meta.uncertainty("u_time_s")),
            u_angle_deg: self.u_angle_deg.or(rec.meta.uncertainty("u_angle_deg")),
        }
    }
}

/// A calibration failure, naming the file and, where it applies, the line.
#[derive(Debug, thiserror::Error)]
#[error("{source_name}{}: {message}", line.map(|l| format!(":{l}")).unwrap_or_default())]
pub struct CalibrateError {
    /// The recording.
    pub source_name: String,
    /// First line of the data concerned.
    pub line: Option<u64>,
    /// What is wrong.
    pub message: String,
}

/// The clock rotation timestamps are converted to (t_s has microsecond resolution).
pub const CLOCK: TickRate = TickRate::MHZ_1;

pub(crate) fn err(
    rec: &Recording,
    line: Option<u64>,
    message: impl Into<String>,
) -> CalibrateError {
    CalibrateError {
        source_name: rec.source.clone(),
        line,
        message: message.into(),
    }
}

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
            .map_err(|m| err(rec, Some(g.first_line), m))?;
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
fn fit_at(s: &[batch::Sample], step: PhaseStep) -> Result<FitResult<f64>, String> {
    let mut fit = SineFit::<f64>::new(FitConfig::sine(step, CLOCK));
    for (ap, y) in s {
        let n = ap.len().max(1) as f64;
        fit.update_sum(ap, y.map(|v| v * n))
            .map_err(|e| e.to_string())?;
    }
    fit.solve().map_err(|e| e.to_string())
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
    for (i, (ap, _)) in s.iter().enumerate() {
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
        for (j, v) in extra.into_iter().enumerate() {
            wide[(i, 3 + j)] = w * v;
        }
    }
    // Normal equations: the columns are near-orthogonal (sines, a centred trend), so their
    // Cholesky solve is as good as QR here and needs no N × q factor. Readings on a rail are
    // not measurements of the model: they are left out of this fit as of the estimate.
    let full = wide.tr_mul(&wide);
    let mut models = Vec::with_capacity(3);
    for ch in 0..3 {
        let plain: Vec<f64> = s.iter().map(|(_, y)| y[ch]).collect();
        let flags = noise::clipped(&plain);
        let y = nalgebra::DVector::from_iterator(
            s.len(),
            s.iter().map(|(ap, y)| batch::root_weight(ap) * y[ch]),
        );
        let mut normal = full.clone();
        let mut rhs = wide.tr_mul(&y);
        for (i, _) in flags.iter().enumerate().filter(|(_, f)| **f) {
            let row = wide.row(i);
            normal -= row.transpose() * row;
            rhs -= row.transpose() * y[i];
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
        for (a, row) in cov.iter_mut().enumerate() {
            for (b, x) in row.iter_mut().enumerate() {
                *x = c[(a, b)];
            }
        }
    }
    Ok(covs)
}

/// The rate's standard error under the channels' noise, and whether the fitted rate
/// differs from nominal (by more than 3 of it), from the IEEE 1057 fit's (rate, standard
/// error) and coefficients (A, B, C per channel).
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
) -> (f64, bool) {
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
    (se_rate, (rate_hz - nominal_hz).abs() > 3.0 * se_rate)
}

pub(crate) fn fit_group(
    rec: &Recording,
    g: &Group,
    s: &[batch::Sample],
    nominal_hz: f64,
) -> Result<GroupFit, CalibrateError> {
    let cond = g.condition.letter();
    let fail = |e: String| err(rec, Some(g.first_line), format!("condition {cond}: {e}"));
    let nominal = PhaseStep::from_hz(nominal_hz, CLOCK).ok_or_else(|| {
        err(
            rec,
            Some(g.first_line),
            format!("rotation rate {nominal_hz} Hz is not usable"),
        )
    })?;
    // Fitted first at the nominal rate: this also checks the span, so a short record gets
    // the plain 'too few periods' message rather than a failure of the rate fit.
    let at_nominal = fit_at(s, nominal).map_err(fail)?;
    let four =
        batch::fit_four_param(s, nominal, CLOCK).map_err(|e| fail(format!("rate fit: {e}")))?;
    let fitted_step = PhaseStep::from_hz(four.rate_hz, CLOCK)
        .ok_or_else(|| err(rec, Some(g.first_line), "fitted rate unusable"))?;
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
    let noise = noise_models(s, fitted_step).map_err(|e| fail(e.to_string()))?;
    let (se_rate, differs) = rate_choice(
        (four.rate_hz, four.se_rate_hz),
        &four_coef,
        &noise,
        omega_per_sample,
        nominal_hz,
    );
    let (step, fit, rate_hz, rate_fitted, u_rate_hz) = if differs {
        let fit = fit_at(s, fitted_step).map_err(fail)?;
        (fitted_step, fit, four.rate_hz, Some(four.rate_hz), se_rate)
    } else {
        let u = se_rate.hypot(four.rate_hz - nominal_hz);
        (nominal, at_nominal, nominal_hz, None, u)
    };
    let cov = sine_cov(s, step, &noise).map_err(|e| fail(e.to_string()))?;
    Ok(GroupFit {
        condition: g.condition,
        fit,
        rate_hz,
        rate_fitted,
        u_rate_hz,
        cov,
        noise,
        omega_per_sample,
    })
}

/// What a rotation entry needs beyond its fits.
pub(crate) struct Setting<'a> {
    /// Local gravity, m/s².
    pub g: f64,
    /// The type-B inputs.
    pub inputs: &'a TypeB,
    /// The output units.
    pub units: &'a str,
    /// Monte Carlo trials, if asked for.
    pub monte_carlo: Option<usize>,
}

/// The sine fit of a condition refitted at another rate (the budget's sensitivity to the
/// rate): from its samples, or from a streamed record's sums ([`stream`]).
pub(crate) trait Refit {
    /// (A, B) per channel of the sine fit at `rate_hz`.
    fn refit(&self, rate_hz: f64) -> Result<ConditionFit, String>;
}

impl Refit for Vec<batch::Sample> {
    fn refit(&self, rate_hz: f64) -> Result<ConditionFit, String> {
        let step = PhaseStep::from_hz(rate_hz, CLOCK)
            .ok_or_else(|| format!("rate {rate_hz} Hz unusable"))?;
        Ok(ConditionFit::from_fit(&fit_at(self, step)?))
    }
}

/// One rate's entry of a rotation calibration from its three conditions' fits.
pub(crate) fn rotation_entry(
    rec: &Recording,
    nominal: f64,
    fits: &[GroupFit; 3],
    refits: [&dyn Refit; 3],
    set: &Setting<'_>,
) -> Result<json::RateJson, CalibrateError> {
    let g = set.g;
    let cf = [0, 1, 2].map(|c| fits[c].condition_fit());
    let at_rate = |e: String| err(rec, None, format!("at {nominal} Hz: {e}"));
    let cal = methods::rotation(&cf, g).map_err(|e| at_rate(e.to_string()))?;
    let budget = rotation_budget(fits, refits, &cal, g, set.inputs, set.units).map_err(at_rate)?;
    let json_fits = fits.iter().flat_map(fit_json).collect();
    let mut entry = json::rotation_entry(nominal, &cal, &budget, json_fits);
    entry.noise = Some(fits.iter().flat_map(noise_json).collect());
    entry.uncertainty_budget = Some(budget);
    let device = rotation_correction(fits, g).map_err(|e| at_rate(e.to_string()))?;
    entry.correction = Some(CorrectionJson::new(
        set.units,
        device,
        None,
        json::K,
        "the mean of the three conditions' C at this rate: it includes the \
         centripetal acceleration ω²·r of a sensor off the axis, which one rate \
         cannot separate",
    ));
    if let Some(trials) = set.monte_carlo {
        let mc = methods::monte_carlo_rotation(&cf, g, trials, 1)
            .map_err(|e| err(rec, None, format!("Monte Carlo at {nominal} Hz: {e}")))?;
        entry.monte_carlo = Some(json::mc_map(mc));
    }
    Ok(entry)
}

fn fit_json(f: &GroupFit) -> Vec<FitJson> {
    ['u', 'v', 'w']
        .iter()
        .enumerate()
        .map(|(ch, name)| FitJson {
            condition: f.condition.letter().to_string(),
            channel: name.to_string(),
            a: f.coef(ch, Param::A),
            b: f.coef(ch, Param::B),
            c: f.coef(ch, Param::C),
            se_a: f.std_unc(ch, 0),
            se_b: f.std_unc(ch, 1),
            se_c: f.std_unc(ch, 2),
            n: u64::from(f.fit.n),
            rms_residual: f.fit.channels[ch].rms_residual,
            rate_hz_fitted: f.rate_fitted,
        })
        .collect()
}

fn noise_json(f: &GroupFit) -> Vec<NoiseJson> {
    ['u', 'v', 'w']
        .iter()
        .zip(&f.noise)
        .map(|(name, m)| NoiseJson::new(f.condition.letter(), *name, m, f.omega_per_sample))
        .collect()
}

/// What every calibration checks first: local gravity, the type-B inputs, the method and
/// the units.
pub(crate) fn preflight(
    rec: &Recording,
    opts: &Options,
) -> Result<(f64, TypeB, Method, String), CalibrateError> {
    let g = opts.g_loc.or(rec.meta.g_loc).ok_or_else(|| {
        err(
            rec,
            None,
            "local gravity unknown: give --g-loc or a '# g_loc=' line",
        )
    })?;
    if !(g.is_finite() && g > 0.0) {
        return Err(err(
            rec,
            None,
            format!("g_loc {g} is not a positive number"),
        ));
    }
    let inputs = opts.inputs.or_file(rec);
    if let Some((name, u)) = [
        ("--u-g-loc", inputs.u_g_loc),
        ("--u-time-s", inputs.u_time_s),
    ]
    .into_iter()
    .find_map(|(n, u)| u.filter(|u| !(u.is_finite() && *u >= 0.0)).map(|u| (n, u)))
    {
        return Err(err(
            rec,
            None,
            format!("{name} {u} is not a standard uncertainty (a finite number ≥ 0)"),
        ));
    }
    let method = opts.method.unwrap_or(rec.method);
    let units = rec
        .meta
        .units
        .clone()
        .unwrap_or_else(|| "output units".into());
    Ok((g, inputs, method, units))
}

/// The nominal rotation rate of a group whose `rate_hz` column says `column`: that, else
/// the command line's, else the file's metadata's.
pub(crate) fn nominal_rate(
    column: Option<f64>,
    opts: &Options,
    meta: &crate::recording::Metadata,
) -> Option<f64> {
    column.or(opts.rate_hz).or(meta.rate_hz)
}

/// Why a rotation file cannot be calibrated without more.
pub(crate) const NO_RATE: &str =
    "rotation rate unknown: give --rate-hz, a '# rate_hz=' line or a rate_hz column";

/// Calibrate a recording.
pub fn calibrate(rec: &Recording, opts: &Options) -> Result<CalibrationJson, CalibrateError> {
    let (g, inputs, method, units) = preflight(rec, opts)?;
    let mut by_rate = Vec::new();
    match method {
        Method::Rotation => {
            rec.require_conditions("rotation calibration")
                .map_err(|e| err(rec, None, e.kind.to_string()))?;
            for rate in rec.rates() {
                let nominal =
                    nominal_rate(rate, opts, &rec.meta).ok_or_else(|| err(rec, None, NO_RATE))?;
                let mut fits = Vec::new();
                let mut group_samples = Vec::new();
                for cond in Condition::ALL {
                    let grp = rec.group(cond, rate).ok_or_else(|| {
                        err(
                            rec,
                            None,
                            format!("condition {} missing at {nominal} Hz", cond.letter()),
                        )
                    })?;
                    if grp.t_s.len() != grp.u.len() {
                        return Err(err(
                            rec,
                            Some(grp.first_line),
                            "rotation needs a t_s column",
                        ));
                    }
                    let s = samples(rec, grp)?;
                    fits.push(fit_group(rec, grp, &s, nominal)?);
                    group_samples.push(s);
                }
                let (Ok(fits), Ok(group_samples)) = (
                    <[GroupFit; 3]>::try_from(fits),
                    <[Vec<batch::Sample>; 3]>::try_from(group_samples),
                ) else {
                    return Err(err(rec, None, "expected three conditions"));
                };
                let refits = [0, 1, 2].map(|c| -> &dyn Refit { &group_samples[c] });
                let setting = Setting {
                    g,
                    inputs: &inputs,
                    units: &units,
                    monte_carlo: opts.monte_carlo,
                };
                let entry = rotation_entry(rec, nominal, &fits, refits, &setting)?;
                by_rate.push(entry);
            }
            if by_rate.len() >= 2 {
                offsets_at_rest(&mut by_rate).map_err(|e| err(rec, None, e))?;
            }
        }
        Method::Free => by_rate.push(free_json(rec, opts, (g, &inputs), &units)?),
        Method::Static if rec.oriented.is_some() => {
            let poses = rec
                .oriented
                .as_ref()
                .map(poses::poses_from_oriented)
                .transpose()
                .map_err(|e| {
                    let line = match &e {
                        poses::PoseError::PoseDirection { line, .. } => Some(*line),
                        _ => None,
                    };
                    err(rec, line, e.to_string())
                })?
                .unwrap_or_default();
            let cal = methods::from_poses(poses, g, pose_options(opts, &inputs))
                .map_err(|e| err(rec, None, e.to_string()))?;
            by_rate.push(static_json(rec, &cal, opts, (g, &inputs), &units)?);
        }
        Method::Static => {
            let mut conds = Vec::new();
            for grp in &rec.groups {
                if grp.angle_deg.len() != grp.u.len() {
                    return Err(err(
                        rec,
                        Some(grp.first_line),
                        "static calibration needs an angle_deg column",
                    ));
                }
                conds.push(StaticCondition {
                    condition: grp.condition,
                    angle_deg: &grp.angle_deg,
                    y: [&grp.u, &grp.v, &grp.w],
                    first_line: grp.first_line,
                });
            }
            let cal = methods::static_method(&conds, g, pose_options(opts, &inputs))
                .map_err(|e| err(rec, None, e.to_string()))?;
            by_rate.push(static_json(rec, &cal, opts, (g, &inputs), &units)?);
        }
    }
    Ok(CalibrationJson {
        method: method.as_str().to_string(),
        g_loc: g,
        units,
        by_rate,
    })
}

/// One continuous stretch of readings searched for still intervals: borrowed from the
/// recording where it holds the rows as they are (a free recording), built otherwise.
pub struct Segment<'a> {
    /// What it is, for names and messages (empty for a whole recording).
    pub label: String,
    /// Time of each row, s.
    pub t_s: Cow<'a, [f64]>,
    /// Readings u, v, w of each row.
    pub y: Cow<'a, [[f64; 3]]>,
    /// File line of each row.
    pub line: Cow<'a, [u64]>,
    /// The `pose` column of a free recording: the poses are named, not found.
    pub names: Option<&'a [String]>,
}

/// The recording's continuous stretches: a free recording whole; a file with conditions
/// one per condition (and rate); a file with gravity directions whole, in file order (its
/// directions unused). Without `t_s`, the rows are `1/sample_rate_hz` apart.
pub fn segments(rec: &Recording) -> Result<Vec<Segment<'_>>, CalibrateError> {
    // The rows' times: `t` when every row has one, else 1/sample_rate_hz apart.
    fn clock<'t>(
        rec: &Recording,
        n: usize,
        t: Option<&'t Vec<f64>>,
        line: u64,
    ) -> Result<Cow<'t, [f64]>, CalibrateError> {
        match t {
            Some(t) if t.len() == n => Ok(Cow::Borrowed(t.as_slice())),
            _ => {
                let fs = rec.meta.sample_rate_hz.ok_or_else(|| {
                    err(
                        rec,
                        Some(line),
                        "finding still poses needs t_s or '# sample_rate_hz='",
                    )
                })?;
                Ok(Cow::Owned((0..n).map(|i| i as f64 / fs).collect()))
            }
        }
    }
    if let Some(s) = &rec.series {
        return Ok(vec![Segment {
            label: String::new(),
            t_s: Cow::Borrowed(&s.t_s),
            y: Cow::Borrowed(&s.y),
            line: Cow::Borrowed(&s.line),
            names: s.pose.as_deref(),
        }]);
    }
    if let Some(o) = &rec.oriented {
        let first = o.line.first().copied().unwrap_or(0);
        return Ok(vec![Segment {
            label: String::new(),
            t_s: clock(rec, o.y.len(), o.t_s.as_ref(), first)?,
            y: Cow::Borrowed(&o.y),
            line: Cow::Borrowed(&o.line),
            names: None,
        }]);
    }
    let mut out = Vec::new();
    for g in &rec.groups {
        let n = g.len();
        let t = (!g.t_s.is_empty()).then_some(&g.t_s);
        let rate = g.rate_hz.map(|r| format!(" at {r} Hz")).unwrap_or_default();
        out.push(Segment {
            label: format!("condition {}{rate}", g.condition.letter()),
            t_s: clock(rec, n, t, g.first_line)?,
            y: Cow::Owned(
                (0..n)
                    .map(|i| [&g.u, &g.v, &g.w].map(|c| c.get(i).copied().unwrap_or(f64::NAN)))
                    .collect(),
            ),
            // Rows of a group are consecutive lines unless the file interleaves them.
            line: Cow::Owned((0..n as u64).map(|i| g.first_line + i).collect()),
            names: None,
        });
    }
    Ok(out)
}

/// Method free: still intervals found (or named), then G and O from |a| = g.
fn free_json(
    rec: &Recording,
    opts: &Options,
    (g, inputs): (f64, &TypeB),
    units: &str,
) -> Result<json::RateJson, CalibrateError> {
    if opts.monte_carlo.is_some() {
        return Err(err(
            rec,
            None,
            "--monte-carlo is not available for method free",
        ));
    }
    let mut detections: Vec<(String, Option<still::Detection>, Vec<still::Interval>)> = Vec::new();
    for seg in segments(rec)? {
        let found = match seg.names {
            Some(names) => (None, still::named(&seg.t_s, &seg.y, &seg.line, names)),
            None => match still::detect(&seg.t_s, &seg.y, &seg.line, opts.still) {
                Ok(d) => {
                    let iv = d.intervals.clone();
                    (Some(d), Ok(iv))
                }
                Err(e) => (None, Err(e)),
            },
        };
        let (det, intervals) = (
            found.0,
            found.1.map_err(|e| {
                let at = if seg.label.is_empty() {
                    String::new()
                } else {
                    format!("{}: ", seg.label)
                };
                err(rec, seg.line.first().copied(), format!("{at}{e}"))
            })?,
        );
        let intervals = intervals
            .into_iter()
            .map(|mut i| {
                if !seg.label.is_empty() {
                    i.name = format!("{} {}", seg.label, i.name);
                }
                i
            })
            .collect();
        detections.push((seg.label, det, intervals));
    }
    let poses: Vec<free::Pose> = detections
        .iter()
        .flat_map(|(_, _, iv)| iv.iter())
        .filter(|i| i.verdict == still::Verdict::Kept)
        .map(free::Pose::from_interval)
        .collect();
    let fit = free::fit(&poses, g, free::Residual::Geometric).map_err(|e| {
        err(
            rec,
            None,
            format!("{e}.\n{}", detection_summary(&detections, opts.still)),
        )
    })?;
    // The fit's rejections, on the intervals.
    for (_, _, iv) in &mut detections {
        for i in iv.iter_mut() {
            if let Some((_, v)) = fit.rejected.iter().find(|(n, _)| *n == i.name) {
                i.verdict = v.clone();
            }
        }
    }
    let s_cov = poses::s_block(&fit.cov);
    let intr = intrinsic::from_matrix_cov(&fit.l, &s_cov)
        .map_err(|e| err(rec, None, format!("intrinsic properties: {e:?}")))?;
    let offsets = [0, 1, 2].map(|j| intrinsic::Estimate {
        value: fit.offsets[j],
        std_unc: fit.cov[(9 + j, 9 + j)].max(0.0).sqrt(),
    });
    // The budget: the poses (noise, and τ when estimated) and g_loc.
    let mut b = new_budget(units, true);
    let mut contribution: Vec<f64> = (0..6).map(|q| intr.cov[q][q].max(0.0).sqrt()).collect();
    contribution.extend(offsets.iter().map(|o| o.std_unc));
    let nu = fit.nu.is_finite().then_some(fit.nu);
    let description = if fit.tau_ms2 > 0.0 {
        format!(
            "the fit of G and O to the {} still poses' means (JSON free.poses): each pose's \
             noise (an AR model of its readings about a line) and a scatter τ = {:.3e} m/s² \
             beyond it, with P − 9 = {} degrees of freedom",
            fit.poses.len(),
            fit.tau_ms2,
            fit.dof
        )
    } else {
        format!(
            "the fit of G and O to the {} still poses' means (JSON free.poses), each pose's \
             noise from an AR model of its readings about a line; χ² = {:.1} on {} degrees of \
             freedom agrees with that noise",
            fit.poses.len(),
            fit.chi2,
            fit.dof
        )
    };
    b.vector("poses", Kind::A, description, &contribution, &[nu; 9]);
    b.notes.extend(fit.notes.iter().cloned());
    let values = values6(&intr);
    let mut cg = vec![0.0; 9];
    for (c, v) in cg.iter_mut().zip(values.iter().take(3)) {
        *c = -v / g;
    }
    gravity_source(&mut b, g, inputs.u_g_loc, &cg);
    if inputs.u_time_s.is_some() || inputs.u_angle_deg.is_some() {
        b.notes.push(
            "u_time_s or u_angle_deg was given, but method free uses neither timestamps nor \
             angles"
                .into(),
        );
    }
    b.combine();
    let mut entry = json::free_entry(&intr, &offsets, &b, &fit, &detections);
    let cov12 = DMatrix::from_fn(12, 12, |i, j| fit.cov[(i, j)]);
    let (device, _) = correction::from_matrix(&fit.l, fit.offsets, &cov12)
        .map_err(|e| err(rec, None, e.to_string()))?;
    entry.correction = Some(CorrectionJson::new(
        units,
        device,
        None,
        fit.k,
        "the fit of G and O to the still poses (|a| = g)",
    ));
    entry.uncertainty_budget = Some(b);
    Ok(entry)
}

/// The detection in a few lines: what was found, at which threshold, and why each
/// interval not kept was left out.
pub fn detection_summary(
    detections: &[(String, Option<still::Detection>, Vec<still::Interval>)],
    opts: still::Options,
) -> String {
    let mut out = String::new();
    for (label, det, iv) in detections {
        let kept = iv
            .iter()
            .filter(|i| i.verdict == still::Verdict::Kept)
            .count();
        let at = if label.is_empty() {
            String::new()
        } else {
            format!("{label}: ")
        };
        match det {
            Some(d) => {
                out += &format!(
                "{at}{} still interval(s) found, {kept} kept: windows of {} s ({} rows), still \
                 when their variance is below {}× the noise variance (noise sd per channel \
                 {:.3e}, {:.3e}, {:.3e}, measured in the still windows; {:.0} % of the windows \
                 still), at least {} s each\n",
                iv.len(),
                opts.window_s,
                d.window_rows,
                opts.threshold,
                d.noise_sd[0],
                d.noise_sd[1],
                d.noise_sd[2],
                100.0 * d.still_fraction,
                opts.min_still_s
            )
            }
            None => out += &format!("{at}{} named pose(s), {kept} kept\n", iv.len()),
        }
        for i in iv.iter().filter(|i| i.verdict != still::Verdict::Kept) {
            out += &format!(
                "  {} ({:.2}–{:.2} s, line {}): {}\n",
                i.name,
                i.span_s.0,
                i.span_s.1,
                i.first_line,
                i.verdict.reason(opts.min_still_s)
            );
        }
    }
    out.trim_end().to_string()
}

/// Multi-rate rotation: each condition's C_j against ω² is a line whose intercept is the
/// offset at rest (the centripetal term grows as ω²·r); O_j is the mean of the three
/// conditions' intercepts, and every rate's correction gets it.
pub(crate) fn offsets_at_rest(by_rate: &mut [json::RateJson]) -> Result<(), String> {
    let mut offset = [0.0; 3];
    let mut var = [0.0; 3];
    for cond in ["x", "y", "z"] {
        for (j, ch) in ["u", "v", "w"].iter().enumerate() {
            // (ω², C, se_C) over the rates.
            let pts: Vec<(f64, f64, f64)> = by_rate
                .iter()
                .filter_map(|r| {
                    let f = r
                        .fits
                        .iter()
                        .find(|f| f.condition == cond && f.channel == *ch)?;
                    let hz = f.rate_hz_fitted.or(r.rate_hz)?;
                    Some(((std::f64::consts::TAU * hz).powi(2), f.c, f.se_c))
                })
                .collect();
            // Weighted line C = O + b·ω².
            let (mut s, mut sx, mut sxx, mut sy, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for (x, y, se) in &pts {
                let w = 1.0 / (se * se);
                s += w;
                sx += w * x;
                sxx += w * x * x;
                sy += w * y;
                sxy += w * x * y;
            }
            let det = s * sxx - sx * sx;
            if !(det.is_finite() && det > 0.0) {
                return Err(format!(
                    "condition {cond}, channel {ch}: the offsets against ω² cannot be fitted"
                ));
            }
            offset[j] += (sxx * sy - sx * sxy) / det / 3.0;
            var[j] += sxx / det / 9.0;
        }
    }
    let source = format!(
        "each condition's C at ω = 0 from a line C = O + b·ω² over {} rates (the \
         centripetal term removed), averaged over the three conditions",
        by_rate.len()
    );
    for r in by_rate.iter_mut() {
        if let Some(c) = r.correction.as_mut() {
            let d = &mut c.device_frame;
            for j in 0..3 {
                d.offset[j] = offset[j];
                d.offset_std_unc[j] = var[j].sqrt();
                for (k, row) in d.covariance.iter_mut().enumerate() {
                    for (l, x) in row.iter_mut().enumerate() {
                        if k == 9 + j || l == 9 + j {
                            *x = if k == l { var[j] } else { 0.0 };
                        }
                    }
                }
            }
            c.offset_source = source.clone();
        }
    }
    Ok(())
}

/// The pose fit's options with the stated table-angle uncertainty.
fn pose_options(opts: &Options, inputs: &TypeB) -> poses::Options {
    poses::Options {
        u_angle_rad: inputs.u_angle_deg.map(f64::to_radians),
        ..opts.poses
    }
}

fn static_json(
    rec: &Recording,
    cal: &methods::StaticCalibration,
    opts: &Options,
    (g, inputs): (f64, &TypeB),
    units: &str,
) -> Result<json::RateJson, CalibrateError> {
    let budget = static_budget(cal, g, inputs, units).map_err(|e| err(rec, None, e))?;
    let mut entry = json::static_entry(cal, &budget);
    entry.uncertainty_budget = Some(budget);
    if let Some(trials) = opts.monte_carlo {
        let mc = methods::monte_carlo_static(cal, trials, 1)
            .map_err(|e| err(rec, None, format!("Monte Carlo: {e}")))?;
        entry.monte_carlo = Some(json::mc_map(mc));
    }
    let (device, platter) = static_correction(cal).map_err(|e| err(rec, None, e.to_string()))?;
    let source = match cal.pose_fit.options.offsets {
        poses::OffsetEstimator::Joint => "the joint fit of S and O to all poses",
        poses::OffsetEstimator::AxisPairs => {
            "the up/down pair of each channel's own axis (imucal's estimator)"
        }
    };
    entry.correction = Some(CorrectionJson::new(
        units,
        device,
        Some(platter),
        cal.pose_fit.k,
        source,
    ));
    Ok(entry)
}

/// Both corrections of a static calibration. The covariance of (S, O) is the pose fit's;
/// imucal's offsets are taken as uncorrelated with S (with balanced up/down poses their
/// correlation is zero).
pub fn static_correction(
    cal: &methods::StaticCalibration,
) -> Result<(correction::Correction, correction::Correction), correction::CorrectionError> {
    let mut cov = DMatrix::zeros(correction::PARAMS, correction::PARAMS);
    let joint = cal.pose_fit.options.offsets == poses::OffsetEstimator::Joint;
    let full = &cal.pose_fit.cov;
    for a in 0..12 {
        for b in 0..12 {
            if joint || (a < 9 && b < 9) {
                cov[(a, b)] = full[(a, b)];
            }
        }
    }
    if !joint {
        for j in 0..3 {
            cov[(9 + j, 9 + j)] = cal.offsets[j].std_unc.powi(2);
        }
    }
    correction::from_matrix(&cal.s, cal.offsets.map(|o| o.value), &cov)
}

/// The device-frame correction of a rotation calibration: M from the Gram matrix of the
/// three conditions' (A, B) (method.md §2) with their covariances; O_j the mean of the
/// three conditions' C_j (over whole turns the mean of ĝ is zero, so C_j = O_j).
pub fn rotation_correction(
    fits: &[GroupFit; 3],
    g: f64,
) -> Result<correction::Correction, correction::CorrectionError> {
    let mut theta = Vec::with_capacity(18);
    let mut cov = DMatrix::zeros(18, 18);
    for (c, f) in fits.iter().map(GroupFit::condition_fit).enumerate() {
        for j in 0..3 {
            let base = 6 * c + 2 * j;
            theta.extend([f.a[j], f.b[j]]);
            for a in 0..2 {
                for b in 0..2 {
                    cov[(base + a, base + b)] = f.cov[j][a][b];
                }
            }
        }
    }
    let gram = move |t: &[f64]| -> Option<[[f64; 3]; 3]> {
        let mut gm = [[0.0; 3]; 3];
        for c in 0..3 {
            for (j, row) in gm.iter_mut().enumerate() {
                for (k, x) in row.iter_mut().enumerate() {
                    let (aj, bj) = (t.get(6 * c + 2 * j)?, t.get(6 * c + 2 * j + 1)?);
                    let (ak, bk) = (t.get(6 * c + 2 * k)?, t.get(6 * c + 2 * k + 1)?);
                    *x += (aj * ak + bj * bk) / (2.0 * g * g);
                }
            }
        }
        Some(gm)
    };
    let mut offset = [0.0; 3];
    let mut offset_std = [0.0; 3];
    for j in 0..3 {
        offset[j] = fits.iter().map(|f| f.coef(j, Param::C)).sum::<f64>() / 3.0;
        offset_std[j] = fits
            .iter()
            .map(|f| f.std_unc(j, 2).powi(2))
            .sum::<f64>()
            .sqrt()
            / 3.0;
    }
    correction::from_gram(&gram, &theta, &cov, offset, offset_std)
}

/// The six properties' values.
fn values6(i: &intrinsic::Intrinsic) -> [f64; 6] {
    let [s0, s1, s2] = i.sensitivity.map(|e| e.value);
    let [a0, a1, a2] = i.angle_deg.map(|e| e.value);
    [s0, s1, s2, a0, a1, a2]
}

/// An empty budget for the six properties, and the offsets too when `offsets`.
fn new_budget(units: &str, offsets: bool) -> Budget {
    let su = format!("{units} per m/s^2");
    let mut unit_of = vec![su.clone(), su.clone(), su];
    unit_of.extend(["deg", "deg", "deg"].map(String::from));
    if offsets {
        unit_of.extend([units, units, units].map(String::from));
        Budget::new(&json::PROPERTY_NAMES_WITH_OFFSETS, &unit_of)
    } else {
        Budget::new(&json::PROPERTY_NAMES, &unit_of)
    }
}

/// The static methods' budget: the parts of the pose fit's covariance (the readings'
/// noise, the poses' tilt, the stated table angles; or each channel's own scatter) and
/// g_loc (S ∝ 1/g_loc; angles and offsets do not depend on it).
pub fn static_budget(
    cal: &methods::StaticCalibration,
    g: f64,
    inputs: &TypeB,
    units: &str,
) -> Result<Budget, String> {
    let mut b = new_budget(units, true);
    let fit = &cal.pose_fit;
    let values = values6(&cal.intrinsic);
    // Each part's variance of the nine properties, and its degrees of freedom.
    let forms = |part: &poses::CovPart| -> Result<[f64; 9], String> {
        let s_part = poses::s_block(&part.theta);
        let prop = intrinsic::from_matrix_cov(&cal.s, &s_part).map_err(|e| e.to_string())?;
        let mut var = [0.0; 9];
        for (q, v) in var.iter_mut().take(6).enumerate() {
            *v = prop.cov[q][q];
        }
        for (v, o) in var.iter_mut().skip(6).zip(fit.offset_var(part)) {
            *v = o;
        }
        Ok(var)
    };
    // Each part's variances (the unit tilt's too), computed once.
    let unit = fit.tilt_scale.as_ref().map(|t| &t.unit);
    let cache = fit
        .parts
        .iter()
        .chain(unit)
        .map(|c| Ok((c, forms(c)?)))
        .collect::<Result<Vec<_>, String>>()?;
    let of = |q: usize| {
        let cache = &cache;
        move |c: &poses::CovPart| {
            cache
                .iter()
                .find(|(p, _)| std::ptr::eq(*p, c))
                .map_or(0.0, |(_, v)| v[q])
        }
    };
    for (part, var) in &cache {
        if part.source == poses::PartSource::TableAngle {
            let u = inputs.u_angle_deg.unwrap_or(f64::NAN);
            let sd: Vec<f64> = var.iter().map(|v| v.max(0.0).sqrt()).collect();
            b.vector(
                "table_angle",
                Kind::B,
                format!(
                    "each table angle off by u = {u} deg (stated; independent from step to \
                     step), moving ĝ along the rotation; through the joint fit"
                ),
                &sd,
                &[None; 9],
            );
        }
    }
    let weigh = fit.weighing();
    let (contribution, dof): (Vec<f64>, Vec<Option<f64>>) = (0..9)
        .map(|q| {
            let (var, nu) = weigh.poses(of(q));
            (var.max(0.0).sqrt(), nu.is_finite().then_some(nu))
        })
        .unzip();
    let description = match fit.scatter {
        poses::Scatter::PerChannel => "the least-squares fit of S and O to the pose means \
             (JSON poses), each channel alone with its variance from the poses' scatter and its \
             degrees of freedom"
            .to_string(),
        poses::Scatter::None
            if fit
                .parts
                .iter()
                .any(|p| matches!(p.source, poses::PartSource::Channel(_))) =>
        {
            "the least-squares fit of S and O to the pose means (JSON poses), each channel alone \
             with its variance from its readings' noise"
                .to_string()
        }
        poses::Scatter::None => format!(
            "the readings' noise within each pose (JSON poses) through the joint fit of S and \
             O; no tilt estimated (joint χ²/dof = {}), so each quantity's share that a tilt \
             would move is scaled by χ²/dof with 3P − 12 degrees of freedom, the rest keeps \
             the readings' Σ(n − 1) (docs/uncertainty.md)",
            fit.chi2_dof
                .map_or("undefined".to_string(), |q| format!("{q:.3}"))
        ),
        poses::Scatter::Tilt { sd_deg } => format!(
            "the readings' noise within each pose and a random tilt of each pose off its \
             nominal direction of {sd_deg:.2e}° per axis (standard deviation), estimated so that \
             the joint fit's χ² equals its 3P − 12 degrees of freedom; degrees of freedom \
             between those and the readings' Σ(n − 1) by how much a tilt moves each quantity \
             (docs/uncertainty.md)"
        ),
    };
    b.vector("poses", Kind::A, description, &contribution, &dof);
    b.notes.extend(fit.notes.iter().cloned());
    let mut cg = vec![0.0; 9];
    for (c, v) in cg.iter_mut().zip(values.iter().take(3)) {
        *c = -v / g;
    }
    gravity_source(&mut b, g, inputs.u_g_loc, &cg);
    if inputs.u_time_s.is_some() {
        b.notes
            .push("u_time_s was given but a static calibration does not use the timestamps".into());
    }
    b.combine();
    Ok(b)
}

/// The budget's g_loc line: a sensitivity of −s/g_loc per sensitivity, or, when its
/// uncertainty is not given, a line that says so (and a note the terminal warns with).
fn gravity_source(b: &mut Budget, g: f64, u_g_loc: Option<f64>, cg: &[f64]) {
    match u_g_loc {
        Some(u) => b.scalar(
            "g_loc",
            Kind::B,
            format!("local gravity g_loc = {g} m/s²: every sensitivity is ∝ 1/g_loc, the angles and offsets do not depend on it"),
            (u, "m/s^2"),
            cg,
            None,
        ),
        None => {
            b.scalar(
                "g_loc",
                Kind::B,
                format!("local gravity g_loc = {g} m/s²: its uncertainty was NOT GIVEN (--u-g-loc or '# u_g_loc='), so it is taken as exact: a gravity model or map gives about 1e-5 relative, a formula from latitude and height about 1e-4, an absolute gravimeter 1e-8"),
                (0.0, "m/s^2"),
                cg,
                None,
            );
            b.notes.push(
                "g_loc's uncertainty was not given: the budget has no term for it".into(),
            );
        }
    }
}

/// The rotation method's budget at one rate (docs/uncertainty.md): the fits (type A, the
/// noise model's covariance propagated whole), g_loc, each condition's rotation rate, and
/// the timestamps.
fn rotation_budget(
    fits: &[GroupFit; 3],
    refits: [&dyn Refit; 3],
    cal: &methods::RotationCalibration,
    g: f64,
    inputs: &TypeB,
    units: &str,
) -> Result<Budget, String> {
    let mut b = new_budget(units, false);
    let cf = fits.clone().map(|f| f.condition_fit());
    let values = values6(&cal.intrinsic);
    let diag = |c: &[[f64; 6]; 6]| [0, 1, 2, 3, 4, 5].map(|q| c[q][q].max(0.0));
    // Type A. The nine channel fits are independent, so each one's share of the variance
    // is the propagation with the others' covariance set to zero; their degrees of freedom
    // combine by Welch–Satterthwaite.
    let total = diag(&cal.intrinsic.cov);
    let mut per_dof = [0.0; 6];
    for (c, fit) in fits.iter().enumerate() {
        for j in 0..3 {
            let mut only = cf;
            for (oc, f) in only.iter_mut().enumerate() {
                for (oj, m) in f.cov.iter_mut().enumerate() {
                    if (oc, oj) != (c, j) {
                        *m = [[0.0; 2]; 2];
                    }
                }
            }
            let part = diag(
                &intrinsic::from_gram(&only, g, 0.0)
                    .map_err(|e| e.to_string())?
                    .cov,
            );
            let nu = fit.noise[j].dof(3);
            for (d, x) in per_dof.iter_mut().zip(part) {
                *d += x * x / nu;
            }
        }
    }
    let dof: Vec<Option<f64>> = (0..6)
        .map(|q| (per_dof[q] > 0.0).then(|| total[q] * total[q] / per_dof[q]))
        .collect();
    b.vector(
        "fits",
        Kind::A,
        "the sine fits of the three conditions: (A, B) with their covariance under the noise \
         model estimated from the residuals (JSON noise), propagated through the Gram form",
        &total.map(f64::sqrt),
        &dof,
    );
    let cg = [
        -values[0] / g,
        -values[1] / g,
        -values[2] / g,
        0.0,
        0.0,
        0.0,
    ];
    gravity_source(&mut b, g, inputs.u_g_loc, &cg);
    for (c, (f, s)) in fits.iter().zip(refits).enumerate() {
        let u = f.u_rate_hz;
        let at = |rate: f64| -> Result<[f64; 6], String> {
            let mut moved = cf;
            moved[c] = ConditionFit {
                cov: cf[c].cov,
                ..s.refit(rate)?
            };
            Ok(values6(
                &intrinsic::from_gram(&moved, g, 0.0).map_err(|e| e.to_string())?,
            ))
        };
        // The Gram form is blind to the common phase a rate error makes, so what is left is
        // mostly even in δ (an amplitude loss) and a central difference would cancel it:
        // the larger one-sided change per u is taken.
        let sens: Vec<f64> = if u > 0.0 {
            let (hi, lo) = (at(f.rate_hz + u)?, at(f.rate_hz - u)?);
            (0..6)
                .map(|q| {
                    let (a, b) = (hi[q] - values[q], lo[q] - values[q]);
                    if a.abs() >= b.abs() {
                        a / u
                    } else {
                        -b / u
                    }
                })
                .collect()
        } else {
            vec![0.0; 6]
        };
        let how = match f.rate_fitted {
            Some(_) => "fitted (IEEE 1057): its standard error",
            None => "nominal: the fitted rate's standard error and its distance from nominal",
        };
        let nu = f
            .noise
            .iter()
            .map(|m| m.dof(4))
            .fold(f64::INFINITY, f64::min);
        b.scalar(
            &format!("rate_{}", f.condition.letter()),
            Kind::A,
            format!(
                "the rotation rate of condition {} ({:.9} Hz, {how}); sensitivity by refitting at ±u",
                f.condition.letter(),
                f.rate_hz
            ),
            (u, "Hz"),
            &sens,
            Some(nu),
        );
    }
    // A timestamp error of standard deviation σ_t attenuates every amplitude by
    // (ωσ_t)²/2 (method.md §7), the same for the three channels, so the angles keep.
    let resolution = 1.0 / f64::from(CLOCK.hz());
    let jitter = inputs.u_time_s.unwrap_or(0.0);
    let sigma_t = (resolution * resolution / 12.0 + jitter * jitter).sqrt();
    let omega = TAU * fits.iter().map(|f| f.rate_hz).fold(0.0, f64::max);
    let ct: Vec<f64> = (0..6)
        .map(|q| {
            if q < 3 {
                // c·σ_t = −s(ωσ_t)²/2: the attenuation lowers s.
                -values[q] * omega * omega * sigma_t / 2.0
            } else {
                0.0
            }
        })
        .collect();
    b.scalar(
        "timestamps",
        Kind::B,
        format!(
            "each timestamp's error: resolution {resolution:e} s (uniform) and jitter {jitter:e} s{}; amplitude attenuation (ωσ_t)²/2 taken as the standard uncertainty",
            if inputs.u_time_s.is_some() { "" } else { " (not given: --u-time-s or '# u_time_s=')" }
        ),
        (sigma_t, "s"),
        &ct,
        None,
    );
    b.combine();
    Ok(b)
}
