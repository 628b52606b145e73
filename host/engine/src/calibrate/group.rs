//! One condition's fit at one rate from its rows: the samples, the IEEE 1057 rate fit and
//! the choice of rate, the sine fit in f64, the noise model of its residuals and the
//! fit's covariance under it; and the refit at another rate the budget needs.

use super::structure::{scan_channel, ChannelScan, ALPHA as STRUCTURE_ALPHA};
use super::{err, CalibrateError, CalibrateErrorKind, GroupError, CLOCK};
use crate::fit::batch;
use crate::fit::noise::{self, NoiseError, NoiseModel, SlowDesign, SlowFit};
use crate::recording::{Group, Recording};
use nalgebra::DMatrix;
use rotacal_shared::intrinsic::ConditionFit;
use rotacal_shared::{Channel, Condition};
use rotacal_shared::{FitConfig, FitError, FitResult, Param, PhaseStep, SineFit, Ticks};
use std::f64::consts::TAU;

/// A group's samples: the instants of the conversions each row averages, in ticks of the
/// 1 MHz clock from its first row (one, at `t_s`, without a `conv_gaps` column), and
/// [u, v, w]. The times and phases every rotation fit here uses.
///
/// A group recorded in several segments (a `boot` column: each boot's rows are a segment) has each segment's from its
/// own first row: [`joined`] puts them on one time line.
pub fn samples(rec: &Recording, g: &Group) -> Result<Vec<batch::Sample>, CalibrateError> {
    let starts = segment_starts(g);
    // conv_gaps count device ticks; here they become ticks of CLOCK (exact at 1 MHz).
    let scale = crate::recording::tick_scale(&rec.meta, CLOCK);
    let mut out = Vec::with_capacity(g.len());
    let mut t0 = g.t_s.first().copied().unwrap_or(0.0);
    for (i, (t, (u, (v, w)))) in g
        .t_s
        .iter()
        .zip(g.u.iter().zip(g.v.iter().zip(g.w.iter())))
        .enumerate()
    {
        if starts.contains(&i) {
            t0 = *t;
        }
        let gaps = g.conversions.as_ref().and_then(|c| c.get(i));
        let ap = crate::recording::row_aperture(*t, t0, gaps, scale, CLOCK)
            .map_err(|m| err(rec, Some(g.first_line), CalibrateErrorKind::Row(m)))?;
        out.push((ap, [*u, *v, *w]));
    }
    Ok(out)
}

/// The index of the first row of each of `g`'s segments after its first (none for a group
/// without a `boot` column or in one segment).
pub fn segment_starts(g: &Group) -> Vec<usize> {
    let Some(seg) = g.boot.as_ref() else {
        return Vec::new();
    };
    seg.windows(2)
        .enumerate()
        .filter(|(_, w)| matches!(w, [a, b] if a != b))
        .map(|(i, _)| i + 1)
        .collect()
}

/// The phase step of `nominal_hz`, or the error that names `g`'s rate as unusable.
fn nominal_step(rec: &Recording, g: &Group, nominal_hz: f64) -> Result<PhaseStep, CalibrateError> {
    PhaseStep::from_hz(nominal_hz, CLOCK).ok_or_else(|| {
        err(
            rec,
            Some(g.first_line),
            CalibrateErrorKind::UnusableRate(nominal_hz),
        )
    })
}

/// A group's samples on one time line: [`samples`], with a group in several segments
/// joined at the rate fitted with their phases free ([`crate::fit::segments`]), and that
/// rate fit (`None` for one segment).
pub fn joined(
    rec: &Recording,
    g: &Group,
    nominal_hz: f64,
) -> Result<(Vec<batch::Sample>, Option<batch::FourParamFit>), CalibrateError> {
    let mut s = samples(rec, g)?;
    let starts = segment_starts(g);
    if starts.is_empty() {
        return Ok((s, None));
    }
    let nominal = nominal_step(rec, g, nominal_hz)?;
    let four = crate::fit::segments::join(&mut s, &starts, nominal, CLOCK)
        .map_err(|e| GroupError::RateFit(e).of(rec, Some(g.first_line), g.condition))?;
    Ok((s, Some(four)))
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
    /// The slow noise (flicker, random walk) per channel, where the record shows it.
    pub slow: [Option<SlowNoise>; 3],
    /// Whether slow noise was looked for.
    pub slow_status: SlowStatus,
    /// A held group's inputs to the slow-noise estimate, until [`pool_slow`] uses them.
    pub(crate) pending: Option<std::sync::Arc<PendingSlow>>,
    /// The rotation's angle per sample, rad (mean over the group).
    pub omega_per_sample: f64,
    /// The structure scan of each channel's widened-fit residuals; none for a group
    /// calibrated from a streamed file's sums.
    pub scan: Option<[ChannelScan; 3]>,
    /// The device's boots the condition was recorded in (1 but for a restart).
    pub boots: usize,
}

impl GroupFit {
    /// Seconds between the rows of a group whose slow noise is still to be estimated.
    pub(crate) fn pending_row_interval_s(&self) -> Option<f64> {
        self.pending.as_ref().map(|p| p.row_interval_s)
    }

    /// The fit of `condition` at the rate `rate` chose, with its covariance under `noise`
    /// and the rotation's angle per sample, rad.
    pub(crate) fn new(
        condition: Condition,
        fit: FitResult<f64>,
        rate: RateChoice,
        (cov, noise, slow): Covariance,
        omega_per_sample: f64,
        slow_status: SlowStatus,
    ) -> GroupFit {
        GroupFit {
            condition,
            fit,
            rate_hz: rate.rate_hz,
            rate_fitted: rate.rate_fitted,
            u_rate_hz: rate.u_rate_hz,
            cov,
            noise,
            slow,
            slow_status,
            pending: None,
            omega_per_sample,
            scan: None,
            boots: 1,
        }
    }

    /// The degrees of freedom of channel `ch`'s (A, B) variance: from the slow noise's
    /// estimate where there is one, else the AR model's.
    pub fn dof(&self, ch: usize) -> f64 {
        match self.slow.get(ch).and_then(Option::as_ref) {
            Some(slow) => slow.amplitude_dof(),
            None => self.noise.get(ch).map_or(1.0, |m| m.dof(3)),
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
/// [`CLEANING_HARMONICS`] and a trend, its level corrected for that wider fit; and when
/// `slow`, the residuals and design its flicker and random walk are estimated from
/// ([`SlowDesign`]), the channel's rate direction fitted too ([`rate_direction`]).
/// `coef` is the rate fit's (A, B, C) per channel.
fn noise_models(
    s: &[batch::Sample],
    step: PhaseStep,
    slow: bool,
    coef: &[[f64; 3]; 3],
) -> Result<GroupNoise, NoiseError> {
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
    let weights: Vec<f64> = s.iter().map(|(ap, _)| batch::root_weight(ap)).collect();
    // Per channel: its widened fit with its rate direction, and that fit's design.
    let designs = if slow {
        let mut out = Vec::with_capacity(3);
        for c in coef {
            let x = rate_direction(s, (step, t_end), &wide, c);
            match SlowDesign::new(&x, &weights) {
                Ok(d) => out.push((x, d)),
                Err(NoiseError::TooFew(_)) => break,
                Err(e) => return Err(e),
            }
        }
        <[(DMatrix<f64>, SlowDesign); 3]>::try_from(out).ok()
    } else {
        None
    };
    let mut models = Vec::with_capacity(3);
    let mut resid_of = [None, None, None];
    let mut scan: [ChannelScan; 3] = Default::default();
    let mut step_joined: [Option<(SlowDesign, Vec<f64>)>; 3] = [None, None, None];
    let t0 = s.first().map_or(Ticks(0), |x| x.0.first());
    let times: Vec<f64> = s
        .iter()
        .map(|(ap, _)| batch::seconds_between(ap.first(), t0, CLOCK))
        .collect();
    let dt_s = times.last().copied().unwrap_or(0.0) / (s.len().max(2) - 1) as f64;
    let rms_weight = (weights.iter().map(|w| w * w).sum::<f64>() / s.len().max(1) as f64).sqrt();
    let scan_at = (dt_s, step.to_hz(CLOCK), rms_weight);
    let harmonic_columns = |ks: &[usize]| {
        let mut x = DMatrix::zeros(s.len(), 2 * ks.len());
        for ((ap, _), mut row) in s.iter().zip(x.row_iter_mut()) {
            let w = batch::root_weight(ap);
            for (&k, pair) in ks
                .iter()
                .zip(row.iter_mut().collect::<Vec<_>>().chunks_mut(2))
            {
                let [sin, cos] = batch::mean_over(ap, |t| {
                    let (a, b) = (k as f64 * step.phase_at(t).radians()).sin_cos();
                    [a, b]
                });
                if let [a, b] = pair {
                    **a = w * sin;
                    **b = w * cos;
                }
            }
        }
        x
    };
    for (((ch, slot), scan), test_slot) in Channel::ALL
        .into_iter()
        .zip(&mut resid_of)
        .zip(&mut scan)
        .zip(&mut step_joined)
    {
        let plain: Vec<f64> = s.iter().map(|(_, y)| *ch.of(y)).collect();
        let flags = noise::clipped(&plain);
        let y = nalgebra::DVector::from_iterator(
            s.len(),
            s.iter().map(|(ap, y)| batch::root_weight(ap) * ch.of(y)),
        );
        let resid = residuals(&wide, &y, &flags)?;
        // Scanned with the rate direction in the fit: a rate fit a little off (a harmonic
        // beside the sine moves it) leaves a growing first harmonic, whose CUSUM reads as
        // steps.
        let own;
        let with_rate = match designs.as_ref().and_then(|d| d.get(ch.index())) {
            Some((x, _)) => x,
            None => {
                own = rate_direction(s, (step, t_end), &wide, ch.of(coef));
                &own
            }
        };
        // With slow noise, also the residuals the slow levels are estimated from.
        let rate_resid = residuals(with_rate, &y, &flags)?;
        *scan = scan_channel(
            &rate_resid,
            (with_rate, &harmonic_columns),
            &flags,
            scan_at,
            &times,
        );
        let model = NoiseModel::estimate(resid.as_slice(), &flags)?.rescaled(&wide)?;
        // Readings on a rail leave the fit, which the slow terms' expectations do not
        // follow: such a channel keeps the AR model alone. A few of them (at most one row
        // in RAIL_ROWS) are more often a peak's top value repeated by chance, 3 % of the
        // groups of a 10 mHz rotation: their residuals stay in the statistics, whose
        // expectations they then move by well under their scatter.
        let on_rail = flags.iter().filter(|f| **f).count();
        if let Some((x, _)) = designs.as_ref().and_then(|d| d.get(ch.index())) {
            if on_rail * RAIL_ROWS <= s.len() {
                *slot = Some(rate_resid.as_slice().to_vec());
                // A step the group's scan finds (Bonferroni over its three channels) joins
                // a second fit, from which the slow levels its test uses are estimated, so
                // that the step does not raise them ([`step_under_slow`]). U keeps the
                // levels of the fit without it: a walk's largest excursion, taken for a
                // step, would lower them.
                if let Some((st, _)) = scan
                    .step
                    .filter(|(st, _)| st.p_single * 3.0 < STRUCTURE_ALPHA)
                {
                    let q = x.ncols();
                    let mut wider = x.clone().insert_column(q, 0.0);
                    for (v, w) in wider.column_mut(q).iter_mut().zip(&weights).skip(st.row) {
                        *v = *w;
                    }
                    let joined = SlowDesign::new(&wider, &weights)?;
                    let resid = residuals(&wider, &y, &flags)?.as_slice().to_vec();
                    *test_slot = Some((joined, resid));
                }
            }
        }
        models.push(model);
    }
    let models = models.try_into().map_err(|_| NoiseError::TooFew(0))?;
    Ok(GroupNoise {
        models,
        resid: resid_of,
        design: designs.map(|d| d.map(|(_, design)| design)),
        scan,
        step_joined,
    })
}

/// The weighted residuals of the fit of `y` to the columns of `x`, rows flagged on a rail
/// left out of the fit. Normal equations: the columns are near-orthogonal (sines, a
/// centred trend), so their Cholesky solve is as good as QR here and needs no N × q factor.
/// Readings on a rail are not measurements of the model.
fn residuals(
    x: &DMatrix<f64>,
    y: &nalgebra::DVector<f64>,
    flags: &[bool],
) -> Result<nalgebra::DVector<f64>, NoiseError> {
    let mut normal = x.tr_mul(x);
    let mut rhs = x.tr_mul(y);
    for ((row, _), yi) in x
        .row_iter()
        .zip(flags)
        .zip(y.iter())
        .filter(|((_, f), _)| **f)
    {
        normal -= row.transpose() * row;
        rhs -= row.transpose() * *yi;
    }
    let beta = normal.cholesky().ok_or(NoiseError::Singular)?.solve(&rhs);
    Ok(y - x * beta)
}

/// The widened fit `wide` with one more column for a channel of rate-fit coefficients `c`
/// (A, B, C): its rate direction t·(A cos α − B sin α), the trend times the sine's
/// derivative in the phase, unit amplitude; `step` the fit's phase step and `t_end` the
/// trend's scale, as `wide` was made with.
///
/// The rate was fitted to the same data (the noise is modelled about the fitted rate),
/// which takes part of this direction out of each channel's residuals (one rate for the
/// three channels: about half of it for each of the two the rotation sweeps). The slow
/// statistics' expectations follow the fit's projection only, and at the longest averaging
/// lengths, a few degrees of freedom, the missing half-direction showed: over 100
/// white-noise sessions the residuals' Allan variance at m = 512 and 1024 was 0.94 and 0.96
/// of the model's expectation, and the flicker level read low. With the direction in the
/// fit, the residuals lose all of it, which the expectations then follow exactly. A channel
/// the rotation does not sweep (zero amplitude) keeps `wide`.
fn rate_direction(
    s: &[batch::Sample],
    (step, t_end): (PhaseStep, f64),
    wide: &DMatrix<f64>,
    c: &[f64; 3],
) -> DMatrix<f64> {
    let amplitude = c[0].hypot(c[1]);
    if !(amplitude > 0.0 && amplitude.is_finite()) {
        return wide.clone();
    }
    let column = s.iter().map(|(ap, _)| {
        let [v] = batch::mean_over(ap, |t| {
            let trend = t.0 as f64 / t_end - 0.5;
            let (sin, cos) = step.phase_at(t).radians().sin_cos();
            [trend * (c[0] * cos - c[1] * sin) / amplitude]
        });
        batch::root_weight(ap) * v
    });
    let q = wide.ncols();
    let mut x = wide.clone().insert_column(q, 0.0);
    for (xi, v) in x.column_mut(q).iter_mut().zip(column) {
        *xi = v;
    }
    x
}

/// Whether a group's slow noise was looked for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SlowStatus {
    /// Estimated from the residuals (and found or not).
    Modelled,
    /// Not asked for (no `--slow-noise`).
    NotAsked,
    /// The group was calibrated from sums (longer than the rows held in memory).
    FromSums,
    /// Too few rows (under 64).
    TooShort,
}

/// A group's noise: the AR model of each channel, its slow terms where the record shows
/// them, and the design they were estimated for.
struct GroupNoise {
    models: [NoiseModel; 3],
    /// Each channel's weighted residuals of the widened fit (none for a channel with
    /// readings on a rail).
    resid: [Option<Vec<f64>>; 3],
    /// Per channel, the design of the fit its slow residuals come from.
    design: Option<[SlowDesign; 3]>,
    /// Per channel, the structure scan of the widened fit's residuals.
    scan: [ChannelScan; 3],
    /// Per channel whose scan found a step: the slow design and residuals with the step
    /// joined, from which the levels its test uses are estimated.
    step_joined: [Option<(SlowDesign, Vec<f64>)>; 3],
}

/// What the slow-noise estimate needs of a group held in memory, kept until every group of
/// the recording is fitted ([`pool_slow`]).
#[derive(Debug)]
pub struct PendingSlow {
    /// Per channel, the design of the fit its residuals come from ([`rate_direction`]).
    design: [SlowDesign; 3],
    resid: [Option<Vec<f64>>; 3],
    /// The sine fit's weighted regressors.
    h: DMatrix<f64>,
    row_interval_s: f64,
    /// The rate choice's inputs, made again once the slow noise is known.
    rate: RateInputs,
    /// The fit and regressors of the other choice (nominal or fitted rate).
    other: (FitResult<f64>, DMatrix<f64>),
    /// Each row's time from the first, s.
    times: Vec<f64>,
    /// [`GroupNoise::step_joined`].
    step_joined: [Option<(SlowDesign, Vec<f64>)>; 3],
}

/// What [`rate_choice`] takes: the IEEE 1057 fit's (rate, standard error) in Hz and
/// coefficients (A, B, C per channel), the rotation's angle per sample and the nominal
/// rate.
#[derive(Clone, Debug)]
pub(crate) struct RateInputs {
    pub(crate) fit: (f64, f64),
    pub(crate) coef: [[f64; 3]; 3],
    pub(crate) omega_per_sample: f64,
    pub(crate) nominal_hz: f64,
}

/// A fit's covariance of (A, B, C) per channel, the noise models, and the slow noise.
pub(crate) type Covariance = ([[[f64; 3]; 3]; 3], [NoiseModel; 3], [Option<SlowNoise>; 3]);

/// One channel's slow noise in a group: the estimate, and the covariance of (A, B, C)
/// per unit of each term (AR scale, flicker Q, walk q), so that cov = Σ θ_i·unit_i.
#[derive(Clone, Debug)]
pub struct SlowNoise {
    /// The terms and their estimates' covariance.
    pub fit: SlowFit,
    /// Covariance of (A, B, C) per unit of each term.
    pub unit_cov: [[[f64; 3]; 3]; 3],
    /// Covariance of (A, B, C) under the AR model as first estimated from the residuals,
    /// the slow noise's short-range share still in it.
    pub first_cov: [[f64; 3]; 3],
    /// Seconds between rows.
    pub row_interval_s: f64,
    /// The levels the covariance used: θ, or with negative levels taken as zero where
    /// signed ones would not give a positive definite covariance.
    pub theta_used: [f64; 3],
    /// The residuals' Allan variances beside the model's expectation, per averaging length.
    pub allan: Vec<noise::ResidualAllan>,
    /// The still recording pooled into the levels (`--noise-from`), if any.
    pub still: Option<super::noise_from::StillSource>,
    /// This group's share of the channel's check of the model against the data.
    pub scatter: Option<noise::PeriodScatter>,
    /// The channel's check, pooled over its groups; `None` below two whole turns in
    /// every group. Its [`noise::ModelCheck::factor`] multiplied `unit_cov`.
    pub check: Option<noise::ModelCheck>,
}

impl SlowNoise {
    /// The check, where it rescaled this channel's noise terms.
    pub fn rescaled(&self) -> Option<noise::ModelCheck> {
        self.check.filter(|c| c.verdict() != noise::Verdict::None)
    }

    /// The degrees of freedom of the amplitude variance var A + var B.
    pub fn amplitude_dof(&self) -> f64 {
        let a = self.unit_cov.map(|c| c[0][0] + c[1][1]);
        self.fit.dof(&a)
    }
}

/// A fit's covariance matrix as an array.
fn to_array(c: &DMatrix<f64>) -> [[f64; 3]; 3] {
    let mut out = [[0.0; 3]; 3];
    for (row, c_row) in out.iter_mut().zip(c.row_iter()) {
        for (x, v) in row.iter_mut().zip(c_row.iter()) {
            *x = *v;
        }
    }
    out
}

/// The sandwich covariance of (A, B, C) per channel for the sine fit's weighted regressors
/// `h` under `models`.
fn sine_cov(h: &DMatrix<f64>, models: &[NoiseModel; 3]) -> Result<[[[f64; 3]; 3]; 3], NoiseError> {
    let mut covs = [[[0.0; 3]; 3]; 3];
    for (cov, m) in covs.iter_mut().zip(models) {
        *cov = to_array(&m.sandwich(h)?);
    }
    Ok(covs)
}

/// Σ θ_i·unit_i; where signed levels would leave it not positive definite (a negative
/// estimate larger than the AR part allows), the negative levels are taken as zero.
fn combined(unit: &[[[f64; 3]; 3]; 3], theta: &[f64; 3]) -> ([[f64; 3]; 3], [f64; 3]) {
    let sum = |theta: &[f64; 3]| {
        let mut c = [[0.0; 3]; 3];
        for (u, t) in unit.iter().zip(theta) {
            for (row, u_row) in c.iter_mut().zip(u) {
                for (x, v) in row.iter_mut().zip(u_row) {
                    *x += t * v;
                }
            }
        }
        c
    };
    let c = sum(theta);
    let m =
        nalgebra::Matrix3::from_fn(|i, j| c.get(i).and_then(|r| r.get(j)).copied().unwrap_or(0.0));
    if m.cholesky().is_some() {
        (c, *theta)
    } else {
        let clamped = theta.map(|t| t.max(0.0));
        (sum(&clamped), clamped)
    }
}

/// Per channel, the slow levels and the AR model re-estimated with them (none for a
/// channel with readings on a rail).
type ChannelLevels = [Option<(SlowFit, NoiseModel)>; 3];

/// Standard deviations of the slow share's estimate added to it in the step's test: the
/// one-sided normal quantile at the structure check's α.
const SLOW_RAISE: f64 = 3.09;

/// Each channel's scanned step, read again under its slow noise `est` (estimated with the
/// step joined to the fit where the scan found one): the residuals' sum from the step on,
/// eᵀd with d the step's indicator off the fit (the channel's slow design), over √(dᵀΣd),
/// Σ the AR model scaled by θ₀ plus Q·T_fl + q·T_rw with the slow share raised by
/// [`SLOW_RAISE`] standard deviations of its estimate
/// ([`super::structure::ChannelScan::slow_z`]).
fn step_under_slow(
    scan: &mut [ChannelScan; 3],
    est: &ChannelLevels,
    p: &PendingSlow,
) -> Result<(), NoiseError> {
    for ((c, e), (design, resid)) in scan.iter_mut().zip(est).zip(p.design.iter().zip(&p.resid)) {
        let (Some((s, _)), Some((fit, model)), Some(resid)) = (&c.step, e, resid) else {
            continue;
        };
        let n = resid.len();
        let indicator = DMatrix::from_fn(n, 1, |i, _| if i >= s.row { 1.0 } else { 0.0 });
        let d = design.off_fit(&indicator);
        let dd = d.norm_squared();
        if dd <= 0.0 || dd.is_nan() {
            continue;
        }
        let num: f64 = resid.iter().skip(s.row).sum();
        let ar = model.sandwich(&d)?.get((0, 0)).copied().unwrap_or(0.0) * dd * dd;
        let dv = nalgebra::DVector::from_column_slice(d.as_slice());
        let [fl, rw] = design.slow_quadratic(&dv);
        // The slow share raised by 3.09 standard deviations of its estimate (from the
        // levels' covariance): a group of a few turns bounds the levels loosely, and a test
        // on the estimate alone alarms whenever it falls short (as the discrepancy
        // workflow's slow tests, docs/discrepancy.md, "Slow noise").
        let a = [0.0, fl, rw];
        let slow: f64 = fit.theta.iter().zip(&a).map(|(t, x)| t * x).sum();
        let mut v = 0.0;
        for (row, ai) in fit.cov.iter().zip(&a) {
            for (c, aj) in row.iter().zip(&a) {
                v += ai * c * aj;
            }
        }
        let var = fit.theta[0].max(0.0) * ar + slow.max(0.0) + SLOW_RAISE * v.max(0.0).sqrt();
        if var > 0.0 {
            c.slow_z = Some(num.abs() / var.sqrt());
        }
    }
    Ok(())
}

/// A channel keeps its slow terms with at most one reading in this many on a rail
/// ([`noise_models`]).
pub(crate) const RAIL_ROWS: usize = 200;

/// The slow noise of every held group of a recording, pooled per channel (one flicker and
/// one walk per channel, each group its own AR model: [`noise::estimate_pooled`]), and
/// each group's covariance of (A, B, C) under it: the re-estimated AR model's sandwich plus
/// the flicker's and the walk's exact covariances ([`SlowDesign::slow_covariances`]).
pub(crate) fn pool_slow(
    fits: &mut [&mut GroupFit],
    still: Option<&super::noise_from::NoiseFrom>,
) -> Result<(), (Condition, NoiseError)> {
    // Per group and channel, the pooled estimate; and for the steps' tests, where a
    // group's scan found a step, the estimate with the step joined to its fit.
    let mut found: Vec<[Option<(SlowFit, NoiseModel)>; 3]> =
        fits.iter().map(|_| [None, None, None]).collect();
    let mut for_steps = found.clone();
    for ch in Channel::ALL {
        let mut members = Vec::new();
        let mut parts = Vec::new();
        let mut joined = Vec::new();
        for (i, f) in fits.iter().enumerate() {
            if let Some(p) = &f.pending {
                if let (Some(resid), Some(design)) = (ch.of(&p.resid), p.design.get(ch.index())) {
                    members.push(i);
                    let ar = ch.of(&f.noise);
                    parts.push(noise::SlowPart { design, resid, ar });
                    joined.push(match ch.of(&p.step_joined) {
                        Some((design, resid)) => noise::SlowPart { design, resid, ar },
                        None => noise::SlowPart { design, resid, ar },
                    });
                }
            }
        }
        let any_joined = fits
            .iter()
            .filter_map(|f| f.pending.as_ref())
            .any(|p| ch.of(&p.step_joined).is_some());
        // A still recording's stretches are more parts of the same levels.
        if !parts.is_empty() {
            parts.extend(still.into_iter().flat_map(|s| s.parts(ch)));
        }
        let first = members
            .first()
            .and_then(|&i| fits.get(i))
            .map_or(Condition::X, |f| f.condition);
        let estimates =
            noise::estimate_pooled(&parts, ch.index() as u64).map_err(|e| (first, e))?;
        // The still recording's parts join the steps' estimate too.
        if any_joined {
            joined.extend(still.into_iter().flat_map(|s| s.parts(ch)));
        }
        let for_test = if any_joined {
            noise::estimate_pooled(&joined, ch.index() as u64).map_err(|e| (first, e))?
        } else {
            estimates.clone()
        };
        for ((&i, est), test) in members
            .iter()
            .zip(estimates.into_iter().flatten())
            .zip(for_test.into_iter().flatten())
        {
            if let Some(slot) = found.get_mut(i).and_then(|g| g.get_mut(ch.index())) {
                *slot = Some(est);
            }
            if let Some(slot) = for_steps.get_mut(i).and_then(|g| g.get_mut(ch.index())) {
                *slot = Some(test);
            }
        }
    }
    for ((f, est), test) in fits.iter_mut().zip(found).zip(for_steps) {
        if est.iter().all(Option::is_none) {
            f.pending = None;
            continue;
        }
        update_group(
            f,
            (est, &test),
            still.map(super::noise_from::NoiseFrom::summary),
        )
        .map_err(|e| (f.condition, e))?;
        f.pending = None;
    }
    for ch in Channel::ALL {
        check_model(fits, ch);
    }
    Ok(())
}

/// The model against the data for one channel ([`noise::ModelCheck`]): its groups' turn
/// coefficients pooled. Where they scatter more or less than the model allows (p < 10⁻³
/// either way), every group's noise terms of the channel are multiplied by the observed
/// ratio R, whose degrees of freedom then replace the model's in the budget
/// (docs/uncertainty.md, "The model against the data, checked"): an overstated U fails a
/// calibration as surely as an understated one.
fn check_model(fits: &mut [&mut GroupFit], ch: Channel) {
    let i = ch.index();
    let shares: Vec<noise::PeriodScatter> = fits
        .iter()
        .filter_map(|f| f.slow.get(i).and_then(Option::as_ref))
        .filter_map(|s| s.scatter)
        .collect();
    let Some(check) = noise::ModelCheck::pool(&shares) else {
        return;
    };
    let factor = check.factor();
    for f in fits.iter_mut() {
        let Some(Some(slow)) = f.slow.get_mut(i) else {
            continue;
        };
        slow.check = Some(check);
        if factor == 1.0 {
            continue;
        }
        for unit in &mut slow.unit_cov {
            for x in unit.iter_mut().flatten() {
                *x *= factor;
            }
        }
        if let Some(c) = f.cov.get_mut(i) {
            for x in c.iter_mut().flatten() {
                *x *= factor;
            }
        }
    }
}

/// One group under its slow noise: the rate chosen again with the rate's standard error
/// under it, then the covariance of (A, B, C) per channel: the re-estimated AR model's
/// sandwich plus the flicker's and the walk's exact covariances.
fn update_group(
    f: &mut GroupFit,
    (est, for_steps): (ChannelLevels, &ChannelLevels),
    still: Option<super::noise_from::StillSource>,
) -> Result<(), NoiseError> {
    let Some(p) = f.pending.take() else {
        return Ok(());
    };
    // The rate information of each channel: the derivative of its sine with respect to
    // the rate, t·(A cos − B sin), less what the sine fit takes; its variance under the
    // full model against the AR model's.
    let h = &p.h;
    let gram = h.tr_mul(h).try_inverse().ok_or(NoiseError::Singular)?;
    let mut ratio = [1.0; 3];
    for (((r, c), (e, first_model)), design) in ratio
        .iter_mut()
        .zip(&p.rate.coef)
        .zip(est.iter().zip(&f.noise))
        .zip(&p.design)
    {
        let Some((fit, model)) = e else { continue };
        let d = nalgebra::DVector::from_iterator(
            h.nrows(),
            h.row_iter().zip(&p.times).map(|(row, t)| {
                let (s, co) = (
                    row.get(0).copied().unwrap_or(0.0),
                    row.get(1).copied().unwrap_or(0.0),
                );
                t * (c[0] * co - c[1] * s)
            }),
        );
        let d = &d - h * (&gram * h.tr_mul(&d));
        let dd = d.dot(&d);
        let col = DMatrix::from_column_slice(d.len(), 1, d.as_slice());
        let quad = |m: &NoiseModel| -> Result<f64, NoiseError> {
            Ok(m.sandwich(&col)?.get((0, 0)).copied().unwrap_or(0.0) * dd * dd)
        };
        let [fl, rw] = design.slow_quadratic(&d);
        let [theta0, q_fl, q_rw] = fit.theta;
        let full = theta0 * quad(model)? + q_fl * fl + q_rw * rw;
        let before = quad(first_model)?;
        if before > 0.0 && full > 0.0 {
            *r = full / before;
        }
    }
    let choice = rate_choice(&p.rate, &f.noise, ratio);
    let was_fitted = f.rate_fitted.is_some();
    let (fit_other, h_other) = &p.other;
    let h = if choice.fitted != was_fitted {
        f.fit = *fit_other;
        h_other
    } else {
        &p.h
    };
    f.rate_hz = choice.rate_hz;
    f.rate_fitted = choice.rate_fitted;
    f.u_rate_hz = choice.u_rate_hz;
    if let Some(scan) = f.scan.as_mut() {
        step_under_slow(scan, for_steps, &p)?;
    }
    // The flicker's and the walk's covariances of the sine fit depend on the rows' weights
    // only, which every channel's design shares: made once.
    let [fl, rw] = match p.design.first() {
        Some(d) => d.slow_covariances(h)?.map(|m| to_array(&m)),
        None => return Ok(()),
    };
    // The table angle of each row in turns, for the model check.
    let cycles: Vec<f64> = p.times.iter().map(|t| t * f.rate_hz).collect();
    for ((ch, e), design) in Channel::ALL.into_iter().zip(est).zip(&p.design) {
        let i = ch.index();
        match e {
            Some((slow_fit, model)) => {
                let unit_cov = [to_array(&model.sandwich(h)?), fl, rw];
                let allan = ch.of(&p.resid).as_ref().map_or_else(Vec::new, |r| {
                    let [_, q_fl, q_rw] = slow_fit.theta;
                    design.residual_allan(r, &model, [q_fl, q_rw])
                });
                let scatter = ch
                    .of(&p.resid)
                    .as_ref()
                    .and_then(|r| design.period_scatter(r, &model, &slow_fit, &cycles));
                let (cov, theta_used) = combined(&unit_cov, &slow_fit.theta);
                let first_cov = match f.noise.get(i) {
                    Some(m) => to_array(&m.sandwich(h)?),
                    None => cov,
                };
                if let Some(c) = f.cov.get_mut(i) {
                    *c = cov;
                }
                if let Some(m) = f.noise.get_mut(i) {
                    *m = model;
                }
                if let Some(slot) = f.slow.get_mut(i) {
                    *slot = Some(SlowNoise {
                        fit: slow_fit,
                        unit_cov,
                        first_cov,
                        row_interval_s: p.row_interval_s,
                        theta_used,
                        allan,
                        still: still.clone(),
                        scatter,
                        check: None,
                    });
                }
            }
            None => {
                // A channel with readings on a rail: its AR model alone, at the rate chosen.
                if let (Some(c), Some(m)) = (f.cov.get_mut(i), f.noise.get(i)) {
                    *c = to_array(&m.sandwich(h)?);
                }
            }
        }
    }
    Ok(())
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
/// the level, A_j² the channel's share of the rate information. `slow` multiplies each
/// channel's share: the variance of its rate information under the slow noise against
/// the AR model's (1 without; [`pool_slow`]).
pub(crate) fn rate_choice(
    inputs: &RateInputs,
    noise: &[NoiseModel; 3],
    slow: [f64; 3],
) -> RateChoice {
    let RateInputs {
        fit: (rate_hz, se_rate_hz),
        coef,
        omega_per_sample,
        nominal_hz,
    } = *inputs;
    let (mut num, mut den) = (0.0, 0.0);
    for ((m, c), r) in noise.iter().zip(&coef).zip(slow) {
        let amp2 = c[0] * c[0] + c[1] * c[1];
        num += m.variance_factor(omega_per_sample) * m.var * amp2 * r;
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
    slow: bool,
    joint: Option<&batch::FourParamFit>,
) -> Result<GroupFit, CalibrateError> {
    let fail = |e: GroupError| e.of(rec, Some(g.first_line), g.condition);
    let nominal = nominal_step(rec, g, nominal_hz)?;
    // Fitted first at the nominal rate: this also checks the span, so a short record gets
    // the plain 'too few periods' message rather than a failure of the rate fit.
    let at_nominal = fit_at(s, nominal).map_err(|e| fail(e.into()))?;
    // Segments joined: their rate fit, whose phases were free (a fit of the joined record
    // would take the joins as known and understate the rate's uncertainty).
    let four = match joint {
        Some(f) => f.clone(),
        None => {
            batch::fit_four_param(s, nominal, CLOCK).map_err(|e| fail(GroupError::RateFit(e)))?
        }
    };
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
    let noise = noise_models(s, fitted_step, slow, &four_coef).map_err(|e| fail(e.into()))?;
    let inputs = RateInputs {
        fit: (four.rate_hz, four.se_rate_hz),
        coef: four_coef,
        omega_per_sample,
        nominal_hz,
    };
    let rate = rate_choice(&inputs, &noise.models, [1.0; 3]);
    let at_fitted = if rate.fitted || noise.design.is_some() {
        Some(fit_at(s, fitted_step).map_err(|e| fail(e.into()))?)
    } else {
        None
    };
    let (step, fit, other) = match (rate.fitted, at_fitted) {
        (true, Some(f)) => (fitted_step, f, Some((at_nominal, nominal))),
        (false, Some(f)) => (nominal, at_nominal, Some((f, fitted_step))),
        (_, None) => (nominal, at_nominal, None),
    };
    let status = match (slow, noise.design.is_some()) {
        (false, _) => SlowStatus::NotAsked,
        (true, true) => SlowStatus::Modelled,
        (true, false) => SlowStatus::TooShort,
    };
    let h = batch::design(s, step, CLOCK, rotacal_shared::Model::SINE, Ticks(0));
    let cov = sine_cov(&h, &noise.models).map_err(|e| fail(e.into()))?;
    let scan = noise.scan;
    let pending = match (noise.design, other) {
        (Some(design), Some((other_fit, other_step))) => {
            let t0 = s.first().map_or(Ticks(0), |x| x.0.first());
            Some(PendingSlow {
                design,
                resid: noise.resid,
                h: h.clone(),
                row_interval_s: span_s / (s.len().max(2) - 1) as f64,
                rate: inputs,
                other: (
                    other_fit,
                    batch::design(s, other_step, CLOCK, rotacal_shared::Model::SINE, Ticks(0)),
                ),
                times: s
                    .iter()
                    .map(|(ap, _)| batch::seconds_between(ap.first(), t0, CLOCK))
                    .collect(),
                step_joined: noise.step_joined,
            })
        }
        _ => None,
    };
    let mut f = GroupFit::new(
        g.condition,
        fit,
        rate,
        (cov, noise.models, [None, None, None]),
        omega_per_sample,
        status,
    );
    f.pending = pending.map(std::sync::Arc::new);
    f.scan = Some(scan);
    f.boots = segment_starts(g).len() + 1;
    Ok(f)
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
