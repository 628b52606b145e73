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
use super::model::{Triangle, Whitener};
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

/// Regressors of the generic fit, one row at a time: 1, τ (scaled to [0, 1]), sin kωτ and
/// cos kωτ for k = 1 … [`HARMONICS`], (τ/span)·sin ωτ and (τ/span)·cos ωτ (a rate error's
/// growing quadrature), the temperature when `temp` is given, and `extras`. The fits
/// stream these rows ([`Triangle`]) rather than hold rows × columns of them.
struct DesignRows<'a> {
    tau: &'a [f64],
    omega: f64,
    span: f64,
    temp: Option<&'a [f64]>,
    extras: &'a [Extra],
    cols: usize,
}

impl<'a> DesignRows<'a> {
    fn new(tau: &'a [f64], omega: f64, temp: Option<&'a [f64]>, extras: &'a [Extra]) -> Self {
        let span = tau.last().copied().unwrap_or(1.0).max(f64::MIN_POSITIVE);
        let extra_cols: usize = extras
            .iter()
            .map(|e| match e {
                Extra::Harmonic(_) => 2,
                Extra::Step(_) => 1,
            })
            .sum();
        DesignRows {
            tau,
            omega,
            span,
            temp,
            extras,
            cols: 4 + 2 * HARMONICS + usize::from(temp.is_some()) + extra_cols,
        }
    }

    /// Row `i`'s regressors into `out` (its first [`DesignRows::cols`] values). The
    /// harmonics 2 … [`HARMONICS`] come from the first by the angle-sum rule (a few
    /// roundings from sin kωτ itself), so a row costs one sine and cosine: the fits make
    /// each row a dozen times.
    fn row(&self, i: usize, out: &mut [f64]) {
        let (omega, span) = (self.omega, self.span);
        let t = self.tau.get(i).copied().unwrap_or(0.0);
        let (s1, c1) = (omega * t).sin_cos();
        let mut slots = out.iter_mut();
        let mut put = |v: f64| {
            if let Some(x) = slots.next() {
                *x = v;
            }
        };
        put(1.0);
        put(t / span);
        let (mut s, mut c) = (s1, c1);
        for _ in 1..=HARMONICS {
            put(s);
            put(c);
            (s, c) = (s * c1 + c * s1, c * c1 - s * s1);
        }
        put(t / span * s1);
        put(t / span * c1);
        if let Some(temp) = self.temp {
            put(temp.get(i).copied().unwrap_or(0.0));
        }
        for e in self.extras {
            match *e {
                Extra::Harmonic(k) => {
                    let (s, c) = (k as f64 * omega * t).sin_cos();
                    put(s);
                    put(c);
                }
                Extra::Step(from) => put(if i >= from { 1.0 } else { 0.0 }),
            }
        }
    }

    /// Row `i` as [x | y] (cols + 1 values), all zero where `skip` (a reading at a rail:
    /// never in a kept whitened window).
    fn augmented(&self, i: usize, y: f64, skip: bool, buf: &mut [f64]) {
        if skip {
            buf.fill(0.0);
        } else {
            self.row(i, buf);
            if let Some(last) = buf.last_mut() {
                *last = y;
            }
        }
    }

    /// The triangle of the whitened rows [x | y] under `m` (`y` row by row, rows in
    /// `flagged` at a rail), and the whitened rows kept.
    fn whitened_triangle(
        &self,
        m: &NoiseModel,
        y: impl Fn(usize) -> f64,
        flagged: &[bool],
    ) -> (DMatrix<f64>, usize) {
        let w = self.cols + 1;
        let (mut raw, mut out) = (vec![0.0; w], vec![0.0; w]);
        let mut whitener = Whitener::new(m, w);
        let mut tri = Triangle::new(w);
        let mut kept = 0usize;
        for (i, &f) in flagged.iter().enumerate() {
            self.augmented(i, y(i), f, &mut raw);
            if whitener.push(&raw, f, &mut out) {
                tri.push(&out);
                kept += 1;
            }
        }
        (tri.finish(), kept)
    }
}

/// The design's rows with those flagged zero, as the AR model's rescaling reads them.
struct Masked<'a> {
    rows: &'a DesignRows<'a>,
    flagged: &'a [bool],
}

impl noise::Rows for Masked<'_> {
    fn len(&self) -> usize {
        self.flagged.len()
    }

    fn cols(&self) -> usize {
        self.rows.cols
    }

    fn row(&self, t: usize, out: &mut [f64]) {
        if self.flagged.get(t).copied().unwrap_or(true) {
            out.fill(0.0);
        } else {
            self.rows.row(t, out);
        }
    }
}

/// The generic fit's regressors as a matrix, rows flagged in `skip` zero (for the slow-noise
/// levels, [`generic_fit`], which need every row at once).
fn design(
    tau: &[f64],
    omega: f64,
    temp: Option<&[f64]>,
    skip: &[bool],
    extras: &[Extra],
) -> DMatrix<f64> {
    let rows = DesignRows::new(tau, omega, temp, extras);
    let mut x = DMatrix::zeros(tau.len(), rows.cols);
    let mut buf = vec![0.0; rows.cols];
    for (i, (mut row, &skipped)) in x.row_iter_mut().zip(skip).enumerate() {
        if !skipped {
            rows.row(i, &mut buf);
            for (x, v) in row.iter_mut().zip(&buf) {
                *x = *v;
            }
        }
    }
    x
}

/// A generic fit and its residuals, made once and handed on to what uses the same design
/// (the step scan, the noise model).
type Fitted = (Ols, Vec<f64>);

/// An ordinary least-squares fit of `y` on the design's rows, rows in `flagged` left out:
/// its triangle R (q × q, RᵀR = XᵀX) and coefficients.
#[derive(Clone)]
struct Ols {
    r: DMatrix<f64>,
    beta: DVector<f64>,
}

/// The fit, streamed; `None` if the design is singular (a diagonal of R below 10⁻¹⁰ of
/// the largest: a temperature that is a straight line in time, say).
fn ols(rows: &DesignRows, y: &[f64], flagged: &[bool]) -> Option<Ols> {
    let q = rows.cols;
    let mut tri = Triangle::new(q + 1);
    let mut buf = vec![0.0; q + 1];
    for (i, (&v, &f)) in y.iter().zip(flagged).enumerate() {
        if !f {
            rows.augmented(i, v, false, &mut buf);
            tri.push(&buf);
        }
    }
    let full = tri.finish();
    let r = full.view((0, 0), (q, q)).into_owned();
    let qty = full.view((0, q), (q, 1)).into_owned();
    let diag = r.diagonal().map(f64::abs);
    if q == 0 || diag.min() <= 1e-10 * diag.max() {
        return None;
    }
    let beta = r.solve_upper_triangular(&qty)?;
    Some(Ols {
        r,
        beta: DVector::from_column_slice(beta.as_slice()),
    })
}

/// Residuals of `y` from the fit `f` on the design's rows; rows in `flagged` zero.
fn ols_residuals(rows: &DesignRows, f: &Ols, y: &[f64], flagged: &[bool]) -> Vec<f64> {
    let mut x = DVector::zeros(rows.cols);
    y.iter()
        .zip(flagged)
        .enumerate()
        .map(|(i, (&v, &skip))| {
            if skip {
                0.0
            } else {
                rows.row(i, x.as_mut_slice());
                v - x.dot(&f.beta)
            }
        })
        .collect()
}

/// The innovations' variance as the generic fit made by generalised least squares under
/// `m` sees it, relative to `m`'s: RSS_w/(kept rows − coefficients), RSS_w the sum of the
/// squared whitened residuals. This is what a whitened fit's χ² is measured against, and
/// it is unbiased for it. (Rescaling the innovations like the marginal level,
/// [`NoiseModel::rescaled`], would not be: a slowly varying regressor takes a share
/// (1+ρ)/(1−ρ) of the marginal variance for AR(1) noise, but only one whitened degree of
/// freedom; for AR(1) ρ = 0.5 the χ²/dof would sit 0.5 % low.) Two streamed passes: the
/// fit, then its whitened residuals' halves. Also the whitened rows kept.
fn whitened_level(
    m: &NoiseModel,
    rows: &DesignRows,
    y: &[f64],
    flagged: &[bool],
) -> Result<(f64, Halves, usize), ChannelNoiseError> {
    let q = rows.cols;
    let value = |i: usize| y.get(i).copied().unwrap_or(0.0);
    let (full, kept) = rows.whitened_triangle(m, value, flagged);
    if kept <= q + 10 {
        return Err(ChannelNoiseError::TooFewRows);
    }
    let r = full.view((0, 0), (q, q)).into_owned();
    let qty = full.view((0, q), (q, 1)).into_owned();
    let rss = full.get((q, q)).map_or(0.0, |v| v * v);
    let level = rss / (kept - q) as f64;
    let beta = r
        .solve_upper_triangular(&qty)
        .ok_or(ChannelNoiseError::Zero)?;
    // The kept rows' whitened residuals, first half against second.
    let half = kept / 2;
    let mut whitener = Whitener::new(m, q + 1);
    let (mut raw, mut out) = (vec![0.0; q + 1], vec![0.0; q + 1]);
    let (mut sums, mut seen) = ([0.0; 2], 0usize);
    for (i, &f) in flagged.iter().enumerate() {
        rows.augmented(i, value(i), f, &mut raw);
        if whitener.push(&raw, f, &mut out) {
            let fitted: f64 = out.iter().zip(beta.iter()).map(|(x, b)| x * b).sum();
            let e = out.last().copied().unwrap_or(0.0) - fitted;
            if let Some(s) = sums.get_mut(usize::from(seen >= half)) {
                *s += e * e;
            }
            seen += 1;
        }
    }
    let n = [half, kept - half];
    let halves = Halves {
        first: sums[0] / n[0].max(1) as f64,
        second: sums[1] / n[1].max(1) as f64,
        n,
    };
    if level.is_finite() && level > 0.0 {
        Ok((level, halves, kept))
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
    (extras, fitted): (&[Extra], Option<Fitted>),
) -> Result<(NoiseModel, usize, usize, Halves), ChannelNoiseError> {
    let rows = DesignRows::new(tau, omega, temp, extras);
    let q = rows.cols;
    let (fit, e) = match fitted {
        Some(f) => f,
        None => {
            let fit = ols(&rows, y, flagged).ok_or(NoiseError::Singular)?;
            let e = ols_residuals(&rows, &fit, y, flagged);
            (fit, e)
        }
    };
    let m = NoiseModel::estimate(&e, flagged)?;
    drop(e);
    let m = match m.rescaled_white(q) {
        Some(white) => white?,
        // A correlated model's rescaling needs the regressors themselves, row by row.
        None => {
            let inv = fit
                .r
                .clone()
                .try_inverse()
                .map(|ri| &ri * ri.transpose())
                .ok_or(NoiseError::Singular)?;
            m.rescaled_rows(
                &Masked {
                    rows: &rows,
                    flagged,
                },
                &inv,
            )?
        }
    };
    let (factor, halves, kept) = whitened_level(&m, &rows, y, flagged)?;
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
            let scan = |temp| {
                let rows = DesignRows::new(&g.tau, g.omega(), temp, &[]);
                ols(&rows, y, &flagged).map(|fit| {
                    let e = ols_residuals(&rows, &fit, y, &flagged);
                    let found = structure::harmonics(&e, sample_interval(&g.tau), g.rate_hz);
                    (found, fit)
                })
            };
            // The temperature is left out of this channel's generic fit where it makes it
            // singular (a temperature that is a straight line in time); a fit singular
            // without it too has no residuals to scan (its noise model reports it). The fit
            // is kept (its residuals are not: rows each) for the step scan below, which
            // uses the same design when no harmonic is found.
            match scan(temp) {
                Some((found, fit)) => (found, temp, Some(fit)),
                None => match scan(None) {
                    Some((found, fit)) => (found, None, Some(fit)),
                    None => (Vec::new(), None, None),
                },
            }
        }));
    }
    let count = tests
        .iter()
        .flatten()
        .map(|(found, _, _)| found.len())
        .sum::<usize>()
        .max(1) as f64;
    let channels = (3 * data.groups.len()).max(1) as f64;
    let mut generic = Generic::default();
    let mut models = Vec::new();
    for (g, found) in data.groups.iter().zip(&tests) {
        let mut extras: [Vec<Extra>; 3] = Default::default();
        let mut group_models = Vec::new();
        for ((channel, (found, temp, plain)), extras) in
            Channel::ALL.into_iter().zip(found).zip(&mut extras)
        {
            let temp = *temp;
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
            // The generic fit with the harmonics found (without any, the first scan's), its
            // residuals scanned for a step, and both handed on to the noise model.
            let (mut fitted, found) = {
                let rows = DesignRows::new(&g.tau, g.omega(), temp, extras);
                let fit = if extras.is_empty() {
                    plain.clone()
                } else {
                    ols(&rows, y, &flagged)
                };
                let fitted = fit.map(|fit| {
                    let e = ols_residuals(&rows, &fit, y, &flagged);
                    (fit, e)
                });
                let found = fitted
                    .as_ref()
                    .and_then(|(fit, e)| step_scan(&rows, fit, e, &flagged));
                (fitted, found)
            };
            if let Some(s) = found {
                let p = (s.p_single * channels).min(1.0);
                if p < super::ALPHA {
                    extras.push(Extra::Step(s.row));
                    // Its height refitted with the step in the design: the scan's own
                    // reading (Frisch–Waugh) is the same value to rounding, but under slow
                    // noise it moved the proofs' witness sessions beyond their tolerance.
                    // That fit is the noise model's.
                    let rows = DesignRows::new(&g.tau, g.omega(), temp, extras);
                    fitted = ols(&rows, y, &flagged).map(|fit| {
                        let e = ols_residuals(&rows, &fit, y, &flagged);
                        (fit, e)
                    });
                    let size = fitted
                        .as_ref()
                        .and_then(|(f, _)| f.beta.iter().next_back().copied())
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
            // a straight line in time, with the scan's regressors beside it).
            let fit =
                |temp, fitted| model_of(y, (&g.tau, g.omega()), temp, &flagged, (extras, fitted));
            let (m, kept, q, halves) = fit(temp, fitted)
                .or_else(|e| temp.map_or(Err(e), |_| fit(None, None)))
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

/// The step scan ([`structure::step_by`]) of the generic fit's residuals `e`, its
/// orthonormal basis rows made from the design's rows and R (q_t = R⁻ᵀx_t) as the scan asks
/// for them.
fn step_scan(
    rows: &DesignRows,
    fit: &Ols,
    e: &[f64],
    flagged: &[bool],
) -> Option<structure::StepTest> {
    let rt = fit.r.transpose();
    structure::step_by(e, rows.cols, |t, row| {
        if flagged.get(t).copied().unwrap_or(true) {
            row.fill(0.0);
        } else {
            rows.row(t, row.as_mut_slice());
            rt.solve_lower_triangular_mut(row);
        }
    })
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
    mut residual: Vec<f64>,
) -> f64 {
    let flagged = noise::clipped(ch.of(&g.y).as_slice());
    super::model::whitened_ss(m, &mut residual, &flagged).0
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
    /// is the coefficient): for the slow terms' share of its variance (empty unless asked
    /// for).
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
/// parts: their residual coefficients are zero. The weights (rows × coefficients) are made
/// only `with_weights`; the rest is streamed from the rows.
pub(super) fn components(
    g: &GroupData,
    ch: Channel,
    extras: &[Extra],
    m: &NoiseModel,
    residual: &[f64],
    with_weights: bool,
) -> Vec<Component> {
    let flagged = noise::clipped(ch.of(&g.y).as_slice());
    let temp = varying_temperature(g);
    let rows = DesignRows::new(&g.tau, g.omega(), temp, extras);
    let q = rows.cols;
    let value = |i: usize| residual.get(i).copied().unwrap_or(0.0);
    let (t, _) = rows.whitened_triangle(m, value, &flagged);
    // [XᵀX  Xᵀy] of the whitened rows.
    let gram = t.tr_mul(&t);
    // The local span (constant, sin ωτ, cos ωτ: columns 0, 2, 3) projected out of the rest:
    // X̃_O = X_O − X_L·P with P = G_LL⁻¹G_LO, so X̃ᵀX̃ is block diagonal with G_LL and the
    // Schur complement G_OO − G_OL·P, and X̃ᵀy has y's L part and g_O − Pᵀg_L.
    let local = [0usize, 2, 3];
    let others: Vec<usize> = (0..q).filter(|j| !local.contains(j)).collect();
    let block = |r: &[usize], c: &[usize]| gram.select_rows(r.iter()).select_columns(c.iter());
    let Some(ll_inv) = block(&local, &local).try_inverse() else {
        return Vec::new();
    };
    let proj = &ll_inv * block(&local, &others);
    let schur = block(&others, &others) - block(&others, &local) * &proj;
    let Some(oo_inv) = schur.try_inverse() else {
        return Vec::new();
    };
    let gy = |r: &[usize]| block(r, &[q]);
    let beta_l = &ll_inv * gy(&local);
    let beta_o = &oo_inv * (gy(&others) - proj.tr_mul(&gy(&local)));
    // In the design's column order.
    let mut cov = DMatrix::zeros(q, q);
    let mut beta = DVector::zeros(q);
    for (idx, inv, b) in [
        (&local[..], &ll_inv, &beta_l),
        (&others[..], &oo_inv, &beta_o),
    ] {
        for (a, &i) in idx.iter().enumerate() {
            if let (Some(x), Some(v)) = (beta.get_mut(i), b.get(a)) {
                *x = *v;
            }
            for (c, &j) in idx.iter().enumerate() {
                if let (Some(x), Some(v)) = (cov.get_mut((i, j)), inv.get((a, c))) {
                    *x = *v;
                }
            }
        }
    }
    let parts = component_parts(g, temp.is_some(), extras);
    // Each coefficient's weights on the whitened rows are the rows of X̃·cov: a second pass
    // over the rows, only where they are asked for (the slow terms' share).
    let mut hat = with_weights.then(|| {
        let wanted: Vec<usize> = parts.iter().flat_map(|(_, c, _)| c.clone()).collect();
        let mut cols: Vec<Vec<f64>> = vec![Vec::with_capacity(flagged.len()); wanted.len()];
        let mut whitener = Whitener::new(m, q + 1);
        let (mut raw, mut out) = (vec![0.0; q + 1], vec![0.0; q + 1]);
        let mut x = DVector::zeros(q);
        for (i, &f) in flagged.iter().enumerate() {
            rows.augmented(i, value(i), f, &mut raw);
            let kept = whitener.push(&raw, f, &mut out);
            if kept {
                for (v, o) in x.iter_mut().zip(&out) {
                    *v = *o;
                }
                let xl = x.select_rows(local.iter());
                let moved = proj.tr_mul(&xl);
                for (&j, d) in others.iter().zip(moved.iter()) {
                    if let Some(v) = x.get_mut(j) {
                        *v -= d;
                    }
                }
            }
            for (col, &c) in cols.iter_mut().zip(&wanted) {
                col.push(if kept { x.dot(&cov.column(c)) } else { 0.0 });
            }
        }
        let keep = whiten_keep(m, &flagged);
        wanted
            .into_iter()
            .zip(cols)
            .map(|(c, col)| (c, whiten_transpose(m, &col, &keep)))
            .collect::<Vec<_>>()
    });
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
            // The parts' columns are disjoint: each column's weights move to its part.
            let weights = hat.as_mut().map_or_else(Vec::new, |hat| {
                cols.iter()
                    .filter_map(|c| {
                        let (_, w) = hat.iter_mut().find(|(j, _)| j == c)?;
                        Some(std::mem::take(w))
                    })
                    .collect()
            });
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

/// The generic fit's parts: what each is, its columns in the design, and the scan's
/// regressor it is, if one.
fn component_parts(
    g: &GroupData,
    with_temp: bool,
    extras: &[Extra],
) -> Vec<(String, Vec<usize>, Option<Extra>)> {
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
    if with_temp {
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
