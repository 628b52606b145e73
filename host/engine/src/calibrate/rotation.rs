//! The rotation method (Gaitan & Geist (2022)): the plan of rates and conditions, each group's fit from
//! its rows ([`super::group`]) or from a streamed file's sums ([`super::stream`]), and one
//! assembly of the entries for both: budgets, corrections, offsets at rest.

use super::budget::{Budget, KFrom, Kind};
use super::group::{fit_group, joined, pool_slow, GroupFit, Refit, SlowStatus};
use super::json::{self, CalibrationJson, CorrectionJson, FitJson, NoiseJson};
use super::sources::{gravity_source, new_budget, values6, variances6};
use super::{
    correction, err, methods, nominal_rate, CalibrateError, CalibrateErrorKind, GroupError,
    Options, Preflight, RateError, TypeB, CLOCK,
};
use crate::fit::noise;
use crate::recording::{same_rate, Group, Recording};
use nalgebra::DMatrix;
use rotacal_shared::intrinsic::{self, ConditionFit};
use rotacal_shared::{Channel, Condition, Param};
use std::f64::consts::TAU;

/// One rate of a rotation calibration: its nominal rate and its three conditions' groups
/// (x, y, z), as indices into the list of groups the plan was made from.
pub(super) struct RatePlan {
    /// The nominal rate, Hz.
    pub nominal_hz: f64,
    /// The groups of conditions x, y and z.
    pub groups: [usize; 3],
}

/// The rates of a rotation file in order of first appearance, each with its three
/// conditions' groups; `keys` gives each group's condition and `rate_hz` column.
pub(super) fn plan(
    rec: &Recording,
    keys: &[(Condition, Option<f64>)],
    opts: &Options,
) -> Result<Vec<RatePlan>, CalibrateError> {
    let mut rates: Vec<Option<f64>> = Vec::new();
    for (_, rate) in keys {
        if !rates.iter().any(|r| same_rate(*r, *rate)) {
            rates.push(*rate);
        }
    }
    rates
        .into_iter()
        .map(|rate| {
            let nominal_hz = nominal_rate(rate, opts, &rec.meta)
                .ok_or_else(|| err(rec, None, CalibrateErrorKind::NoRate))?;
            let mut groups = [0; 3];
            for (slot, cond) in groups.iter_mut().zip(Condition::ALL) {
                *slot = keys
                    .iter()
                    .position(|(c, r)| *c == cond && same_rate(*r, rate))
                    .ok_or_else(|| {
                        err(
                            rec,
                            None,
                            CalibrateErrorKind::MissingCondition {
                                condition: cond,
                                rate_hz: nominal_hz,
                            },
                        )
                    })?;
            }
            Ok(RatePlan { nominal_hz, groups })
        })
        .collect()
}

/// One condition's fit at its rate and its refit at other rates (the budget's): the same
/// whether it came from rows held in memory or from a streamed file's sums.
pub(super) struct FittedGroup<'a> {
    /// The fit.
    pub fit: GroupFit,
    /// Its refit at another rate.
    pub refit: Box<dyn Refit + 'a>,
}

/// The fit of a group held in memory, at `nominal_hz` or the rate its data show; its slow
/// noise modelled when `slow`.
pub(super) fn held(
    rec: &Recording,
    group: &Group,
    nominal_hz: f64,
    slow: bool,
) -> Result<FittedGroup<'static>, CalibrateError> {
    if group.t_s.len() != group.u.len() {
        return Err(err(rec, Some(group.first_line), CalibrateErrorKind::NoTime));
    }
    let (s, joint) = joined(rec, group, nominal_hz)?;
    let fit = fit_group(rec, group, &s, nominal_hz, slow, joint.as_ref())?;
    Ok(FittedGroup {
        fit,
        refit: Box::new(s),
    })
}

/// A rotation recording held in memory, calibrated.
pub(super) fn calibrate_held(
    rec: &Recording,
    opts: &Options,
    pre: Preflight,
) -> Result<CalibrationJson, CalibrateError> {
    rec.require_conditions("rotation calibration")
        .map_err(|e| err(rec, None, CalibrateErrorKind::NeedsConditions(e.kind)))?;
    let keys: Vec<_> = rec
        .groups
        .iter()
        .map(|g| (g.condition, g.rate_hz))
        .collect();
    let plan = plan(rec, &keys, opts)?;
    let mut fitted: Vec<Option<FittedGroup<'_>>> = keys.iter().map(|_| None).collect();
    for rate in &plan {
        for &i in &rate.groups {
            if let (Some(group), Some(slot)) = (rec.groups.get(i), fitted.get_mut(i)) {
                *slot = Some(held(rec, group, rate.nominal_hz, opts.slow_noise)?);
            }
        }
    }
    assemble(rec, pre, opts, &plan, fitted)
}

/// The calibration from every planned group's fit (`fitted`, by group index): an entry per
/// rate, and with two rates or more the offsets at rest.
pub(super) fn assemble(
    rec: &Recording,
    pre: Preflight,
    opts: &Options,
    plan: &[RatePlan],
    mut fitted: Vec<Option<FittedGroup<'_>>>,
) -> Result<CalibrationJson, CalibrateError> {
    let setting = Setting {
        g: pre.g_loc,
        inputs: &pre.inputs,
        units: &pre.units,
        monte_carlo: opts.monte_carlo,
        slow_noise: opts.slow_noise,
    };
    // Slow noise is a property of each channel: pooled over every group held in memory.
    let mut held: Vec<&mut GroupFit> = fitted.iter_mut().flatten().map(|f| &mut f.fit).collect();
    let still = opts.noise_from.as_deref().filter(|_| opts.slow_noise);
    if let Some(s) = still {
        let intervals = held
            .iter()
            .filter_map(|f| f.pending_row_interval_s().map(|dt| (f.condition, dt)));
        s.check(&pre.units, intervals)
            .map_err(|kind| err(rec, None, kind))?;
    }
    pool_slow(&mut held, still)
        .map_err(|(condition, e)| GroupError::Noise(e).of(rec, None, condition))?;
    let checked = structure_check(
        plan.iter().flat_map(|rate| {
            rate.groups
                .iter()
                .filter_map(|&i| fitted.get(i).and_then(Option::as_ref))
                .map(|f| (rate.nominal_hz, &f.fit))
        }),
        opts.slow_noise,
    );
    let mut by_rate = Vec::with_capacity(plan.len());
    let mut all_fits = Vec::with_capacity(plan.len());
    for rate in plan {
        let [x, y, z] = rate
            .groups
            .map(|i| fitted.get_mut(i).and_then(Option::take));
        let (Some(x), Some(y), Some(z)) = (x, y, z) else {
            return Err(err(
                rec,
                None,
                CalibrateErrorKind::Internal("a planned group was not fitted"),
            ));
        };
        let refits: [&dyn Refit; 3] = [&*x.refit, &*y.refit, &*z.refit];
        let fits = [x.fit, y.fit, z.fit];
        by_rate.push(rotation_entry(
            rec,
            rate.nominal_hz,
            &fits,
            refits,
            &setting,
        )?);
        all_fits.push(fits);
    }
    if by_rate.len() >= 2 {
        let at_rest = offsets_at_rest(&all_fits).map_err(|e| err(rec, None, e))?;
        set_offsets_at_rest(&mut by_rate, at_rest);
    }
    let mut json = pre.json(by_rate);
    json.residual_structure = Some(checked);
    Ok(json)
}

/// What a rotation entry needs beyond its fits.
struct Setting<'a> {
    /// Local gravity, m/s².
    pub g: f64,
    /// The type-B inputs.
    pub inputs: &'a TypeB,
    /// The output units.
    pub units: &'a str,
    /// Monte Carlo trials, if asked for.
    pub monte_carlo: Option<usize>,
    /// Whether slow noise was asked for (`--slow-noise`).
    pub slow_noise: bool,
}

/// One rate's entry of a rotation calibration from its three conditions' fits.
fn rotation_entry(
    rec: &Recording,
    nominal: f64,
    fits: &[GroupFit; 3],
    refits: [&dyn Refit; 3],
    set: &Setting<'_>,
) -> Result<json::RateJson, CalibrateError> {
    let g = set.g;
    let cf = fits.each_ref().map(GroupFit::condition_fit);
    let at_rate = |e: RateError| {
        err(
            rec,
            None,
            CalibrateErrorKind::Rate {
                rate_hz: nominal,
                source: e,
            },
        )
    };
    let cal = methods::rotation(&cf, g).map_err(|e| at_rate(e.into()))?;
    let budget = rotation_budget(
        fits,
        refits,
        &cal,
        (g, set.slow_noise),
        set.inputs,
        set.units,
    )
    .map_err(at_rate)?;
    let json_fits = fits.iter().flat_map(fit_json).collect();
    let mut entry = json::rotation_entry(nominal, &cal, &budget, json_fits).ok_or_else(|| {
        err(
            rec,
            None,
            CalibrateErrorKind::Internal("a budget without a line per property"),
        )
    })?;
    let [s_u, s_v, s_w, ..] = values6(&cal.intrinsic);
    entry.noise = Some(
        fits.iter()
            .flat_map(|f| noise_json(f, [s_u, s_v, s_w]))
            .collect(),
    );
    entry.uncertainty_budget = Some(budget);
    let device = rotation_correction(fits, g).map_err(|e| at_rate(e.into()))?;
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
        let mc = methods::monte_carlo_rotation(&cf, g, trials, 1).map_err(|cause| {
            err(
                rec,
                None,
                CalibrateErrorKind::MonteCarlo {
                    rate_hz: Some(nominal),
                    cause,
                },
            )
        })?;
        entry.monte_carlo = Some(json::mc_map(mc));
    }
    Ok(entry)
}

/// The JSON `fits` of a condition: its three channels' sine fits.
fn fit_json(f: &GroupFit) -> Vec<FitJson> {
    Channel::ALL
        .map(|channel| {
            let ch = channel.index();
            FitJson {
                condition: f.condition,
                channel,
                a: f.coef(ch, Param::A),
                b: f.coef(ch, Param::B),
                c: f.coef(ch, Param::C),
                se_a: f.std_unc(ch, 0),
                se_b: f.std_unc(ch, 1),
                se_c: f.std_unc(ch, 2),
                n: u64::from(f.fit.n),
                rms_residual: channel.of(&f.fit.channels).rms_residual,
                rate_hz_fitted: f.rate_fitted,
                boots: (f.boots > 1).then_some(f.boots),
            }
        })
        .into()
}

/// The JSON `noise` of a condition: its three channels' noise models.
fn noise_json(f: &GroupFit, sensitivity: [f64; 3]) -> Vec<NoiseJson> {
    Channel::ALL
        .map(|channel| {
            let mut n = NoiseJson::new(
                f.condition,
                channel,
                channel.of(&f.noise),
                f.omega_per_sample,
            );
            n.slow = channel
                .of(&f.slow)
                .as_ref()
                .map(|s| json::SlowJson::new(s, Some(*channel.of(&sensitivity))));
            n
        })
        .into()
}

/// Multi-rate rotation: each condition's C_j against ω² is a line whose intercept is the
/// offset at rest (the centripetal term grows as ω²·r); O_j is the mean of the three
/// conditions' intercepts. `fits` holds each rate's three conditions; the result is each
/// channel's offset at rest and its variance.
fn offsets_at_rest(fits: &[[GroupFit; 3]]) -> Result<([f64; 3], [f64; 3]), CalibrateErrorKind> {
    let mut offset = [0.0; 3];
    let mut var = [0.0; 3];
    for condition in Condition::ALL {
        for ((offset, var), channel) in offset.iter_mut().zip(var.iter_mut()).zip(Channel::ALL) {
            let j = channel.index();
            // (ω², C, se_C) over the rates.
            let pts: Vec<(f64, f64, f64)> = fits
                .iter()
                .filter_map(|rate| rate.get(condition.index()))
                .map(|f| {
                    (
                        (TAU * f.rate_hz).powi(2),
                        f.coef(j, Param::C),
                        f.std_unc(j, 2),
                    )
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
                return Err(CalibrateErrorKind::OffsetsAtRest { condition, channel });
            }
            *offset += (sxx * sy - sx * sxy) / det / 3.0;
            *var += sxx / det / 9.0;
        }
    }
    Ok((offset, var))
}

/// Every rate's correction gets the offsets at rest (`offset`, `var`).
fn set_offsets_at_rest(by_rate: &mut [json::RateJson], (offset, var): ([f64; 3], [f64; 3])) {
    let source = format!(
        "each condition's C at ω = 0 from a line C = O + b·ω² over {} rates (the \
         centripetal term removed), averaged over the three conditions",
        by_rate.len()
    );
    for c in by_rate.iter_mut().filter_map(|r| r.correction.as_mut()) {
        let d = &mut c.device_frame;
        for (j, (o, v)) in offset.iter().zip(var).enumerate() {
            if let (Some(dst), Some(u)) = (d.offset.get_mut(j), d.offset_std_unc.get_mut(j)) {
                *dst = *o;
                *u = v.sqrt();
            }
            for (k, row) in d.covariance.iter_mut().enumerate() {
                for (l, x) in row.iter_mut().enumerate() {
                    if k == 9 + j || l == 9 + j {
                        *x = if k == l { v } else { 0.0 };
                    }
                }
            }
        }
        c.offset_source = source.clone();
    }
}

/// The device-frame correction of a rotation calibration: M from the Gram matrix of the
/// three conditions' (A, B) (docs/method.md §2) with their covariances; O_j the mean of the
/// three conditions' C_j (over whole turns the mean of ĝ is zero, so C_j = O_j).
pub fn rotation_correction(
    fits: &[GroupFit; 3],
    g: f64,
) -> Result<correction::Correction, correction::CorrectionError> {
    // θ: (A, B) of each channel of each condition; its covariance block diagonal, a 2 × 2
    // block for each.
    let mut theta = Vec::with_capacity(18);
    let mut blocks: Vec<[[f64; 2]; 2]> = Vec::with_capacity(9);
    for f in fits.iter().map(GroupFit::condition_fit) {
        for ((a, b), cov) in f.a.iter().zip(&f.b).zip(f.cov) {
            theta.extend([*a, *b]);
            blocks.push(cov);
        }
    }
    let n = theta.len();
    let rows = blocks.iter().enumerate().flat_map(|(k, block)| {
        block.iter().flat_map(move |row| {
            let before = std::iter::repeat_n(0.0, 2 * k);
            let after = std::iter::repeat_n(0.0, n.saturating_sub(2 * k + 2));
            before.chain(row.iter().copied()).chain(after)
        })
    });
    let cov = DMatrix::from_row_iterator(n, n, rows);
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
    let offset = Channel::ALL.map(|ch| {
        fits.iter()
            .map(|f| f.coef(ch.index(), Param::C))
            .sum::<f64>()
            / 3.0
    });
    let offset_std = Channel::ALL.map(|ch| {
        fits.iter()
            .map(|f| f.std_unc(ch.index(), 2).powi(2))
            .sum::<f64>()
            .sqrt()
            / 3.0
    });
    correction::from_gram(&gram, &theta, &cov, offset, offset_std)
}

/// The rotation method's budget at one rate (docs/uncertainty.md): the fits (type A, the
/// noise model's covariance propagated whole), g_loc, each condition's rotation rate, and
/// the timestamps.
fn rotation_budget(
    fits: &[GroupFit; 3],
    refits: [&dyn Refit; 3],
    cal: &methods::RotationCalibration,
    (g, slow_noise): (f64, bool),
    inputs: &TypeB,
    units: &str,
) -> Result<Budget, RateError> {
    let mut b = new_budget(units, false);
    let cf = fits.clone().map(|f| f.condition_fit());
    let values = values6(&cal.intrinsic);
    // Type A. The nine channel fits are independent, so each one's share of the variance
    // is the propagation with the others' covariance set to zero; their degrees of freedom
    // combine by Welch–Satterthwaite.
    let total = nonneg_variances(&cal.intrinsic.cov);
    let (per_dof, short_range) = fits_per_dof(fits, &cf, g)?;
    // ν's V is at least what the short-range noise alone gives (`fits_per_dof`).
    let dof: Vec<Option<f64>> = per_dof
        .iter()
        .zip(&total)
        .zip(&short_range)
        .map(|((p, t), s)| (*p > 0.0).then(|| t.max(*s).powi(2) / p))
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
    rate_sources(&mut b, fits, refits, &cf, &values, g)?;
    timestamps_source(&mut b, fits, &values, inputs);
    if slow_noise {
        slow_notes(&mut b, fits);
        b.combine_with(KFrom::NormalVariance);
    } else {
        b.combine();
    }
    Ok(b)
}

/// The six properties' variances from their covariance, rounding's negatives as zero.
fn nonneg_variances(cov: &[[f64; 6]; 6]) -> [f64; 6] {
    variances6(cov).map(|x| x.max(0.0))
}

/// Var(V̂)/2 of each property's `fits` line, for ν = V²/(Var(V̂)/2): each channel fit's
/// share V_cj²/ν_cj, and with slow noise each channel's slow terms (see below).
///
/// Also each property's variance with every slow channel's fit under its AR model as first
/// estimated from the residuals, the slow noise's short-range share in it: the V of ν is
/// at least that (docs/uncertainty.md, "k from the estimate's own degrees of freedom"). A
/// slow level estimated below zero takes V̂ below what the residuals' short-range
/// correlation alone shows, which the noise cannot be; with V̂ itself in ν, ν fell with
/// V̂² (below 1, k 12.7, in some sessions) and AR(1) 0.6 covered s at 0.969–0.980.
fn fits_per_dof(
    fits: &[GroupFit; 3],
    cf: &[ConditionFit; 3],
    g: f64,
) -> Result<([f64; 6], [f64; 6]), RateError> {
    let mut short_range = [0.0; 6];
    // Var(V̂)/2 per property (so that ν = V²/per_dof): Σ over channel fits of V²/ν, and
    // with slow noise per channel the slow terms' share, whose levels the three conditions
    // share (pooled): their contributions add before the covariance of (Q̂, q̂) applies.
    let mut per_dof = [0.0; 6];
    let propagated = |c: usize, j: usize, m: [[f64; 2]; 2]| -> Result<[f64; 6], RateError> {
        let mut only = *cf;
        for (oc, f) in only.iter_mut().enumerate() {
            for (oj, cov) in f.cov.iter_mut().enumerate() {
                *cov = if (oc, oj) == (c, j) { m } else { [[0.0; 2]; 2] };
            }
        }
        Ok(nonneg_variances(&intrinsic::from_gram(&only, g, 0.0)?.cov))
    };
    let ab = |m: &[[f64; 3]; 3], scale: f64| {
        [
            [m[0][0] * scale, m[0][1] * scale],
            [m[1][0] * scale, m[1][1] * scale],
        ]
    };
    let mut shared = [([0.0; 6], [0.0; 6], None); 3];
    for (c, fit) in fits.iter().enumerate() {
        for (j, (shared_fl, shared_rw, slow_cov)) in shared.iter_mut().enumerate() {
            // The fit's own share of V, for the floor and for a channel without slow terms.
            let own = || {
                let m = fit.cov.get(j).copied().unwrap_or([[0.0; 3]; 3]);
                propagated(c, j, ab(&m, 1.0))
            };
            match fit.slow.get(j).and_then(Option::as_ref) {
                // Rescaled by the model check: below; its variance is its own floor.
                Some(sl) if sl.rescaled().is_some() => {
                    for (s, x) in short_range.iter_mut().zip(own()?) {
                        *s += x;
                    }
                }
                Some(sl) => {
                    let [ar_unit, fl_unit, rw_unit] = &sl.unit_cov;
                    let [t0, tq, tw] = sl.theta_used;
                    let ar = propagated(c, j, ab(ar_unit, t0))?;
                    let nu_ar = fit.noise.get(j).map_or(1.0, |m| m.dof(3));
                    for (d, x) in per_dof.iter_mut().zip(ar) {
                        *d += x * x / nu_ar;
                    }
                    // A level taken as zero adds no variance, nor any of its own.
                    let on = |t: f64| f64::from(u8::from(t != 0.0));
                    let fl = propagated(c, j, ab(fl_unit, on(tq)))?;
                    let rw = propagated(c, j, ab(rw_unit, on(tw)))?;
                    let first = propagated(c, j, ab(&sl.first_cov, 1.0))?;
                    for (x, f) in short_range.iter_mut().zip(first) {
                        *x += f;
                    }
                    for (s, f) in shared_fl.iter_mut().zip(fl) {
                        *s += f;
                    }
                    for (s, r) in shared_rw.iter_mut().zip(rw) {
                        *s += r;
                    }
                    *slow_cov = Some(sl.fit.cov);
                }
                None => {
                    let nu = fit.dof(j);
                    for ((d, s), x) in per_dof.iter_mut().zip(short_range.iter_mut()).zip(own()?) {
                        *d += x * x / nu;
                        *s += x;
                    }
                }
            }
        }
    }
    for (shared_fl, shared_rw, slow_cov) in &shared {
        let Some(cov) = slow_cov else { continue };
        for (d, (f, r)) in per_dof.iter_mut().zip(shared_fl.iter().zip(shared_rw)) {
            let var = f * f * cov[1][1] + 2.0 * f * r * cov[1][2] + r * r * cov[2][2];
            *d += var / 2.0;
        }
    }
    for (d, x) in per_dof.iter_mut().zip(rescaled_per_dof(fits, &propagated)?) {
        *d += x;
    }
    Ok((per_dof, short_range))
}

/// The `rate_x`, `rate_y`, `rate_z` lines: each condition refitted at its rate ± u.
fn rate_sources(
    b: &mut Budget,
    fits: &[GroupFit; 3],
    refits: [&dyn Refit; 3],
    cf: &[ConditionFit; 3],
    values: &[f64; 6],
    g: f64,
) -> Result<(), RateError> {
    for (c, (f, s)) in fits.iter().zip(refits).enumerate() {
        let u = f.u_rate_hz;
        let at = |rate: f64| -> Result<[f64; 6], RateError> {
            let refit = s.refit(rate)?;
            let mut moved = *cf;
            // Condition c refitted at the rate, its covariance kept.
            for (_, m) in moved.iter_mut().enumerate().filter(|(k, _)| *k == c) {
                *m = ConditionFit {
                    cov: m.cov,
                    ..refit
                };
            }
            Ok(values6(&intrinsic::from_gram(&moved, g, 0.0)?))
        };
        // The Gram form is blind to the common phase a rate error makes, so what is left is
        // mostly even in δ (an amplitude loss) and a central difference would cancel it:
        // the larger one-sided change per u is taken.
        let sens: Vec<f64> = if u > 0.0 {
            let (hi, lo) = (at(f.rate_hz + u)?, at(f.rate_hz - u)?);
            hi.iter()
                .zip(&lo)
                .zip(values)
                .map(|((hi, lo), v)| {
                    let (a, b) = (hi - v, lo - v);
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
    Ok(())
}

/// The `timestamps` line.
fn timestamps_source(b: &mut Budget, fits: &[GroupFit; 3], values: &[f64; 6], inputs: &TypeB) {
    // A timestamp error of standard deviation σ_t attenuates every amplitude by
    // (ωσ_t)²/2 (docs/method.md §7), the same for the three channels, so the angles keep.
    let resolution = 1.0 / f64::from(CLOCK.hz());
    let jitter = inputs.u_time_s.unwrap_or(0.0);
    let sigma_t = (resolution * resolution / 12.0 + jitter * jitter).sqrt();
    let omega = TAU * fits.iter().map(|f| f.rate_hz).fold(0.0, f64::max);
    let ct: Vec<f64> = values
        .iter()
        .enumerate()
        .map(|(q, v)| {
            if q < 3 {
                // c·σ_t = −s(ωσ_t)²/2: the attenuation lowers s.
                -v * omega * omega * sigma_t / 2.0
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
}

/// With `--slow-noise`: the model check's notes, and a note for each condition or channel
/// whose slow terms are not modelled, and why.
fn slow_notes(b: &mut Budget, fits: &[GroupFit; 3]) {
    b.notes.extend(check_notes(fits));
    for f in fits {
        if f.slow_status == SlowStatus::Modelled {
            for ch in Channel::ALL
                .into_iter()
                .filter(|ch| ch.of(&f.slow).is_none())
            {
                b.notes.push(format!(
                    "condition {}, channel {}: flicker and random walk are not modelled, as \
                     they could not be estimated (more than one reading in {} on a rail, or \
                     too few averaging lengths); its fits' uncertainty counts the short-range \
                     (AR) noise only (docs/uncertainty.md)",
                    f.condition.letter(),
                    ch.letter(),
                    super::group::RAIL_ROWS
                ));
            }
        }
        let why = match f.slow_status {
            SlowStatus::FromSums => {
                "its rows were calibrated from sums (a group longer than \
                                     the rows held in memory)"
            }
            SlowStatus::TooShort => "it has fewer than 64 rows",
            SlowStatus::Modelled | SlowStatus::NotAsked => continue,
        };
        b.notes.push(format!(
            "condition {}: flicker and random walk are not modelled, as {why}; the fits' \
             uncertainty counts the short-range (AR) noise only (docs/uncertainty.md)",
            f.condition.letter()
        ));
    }
}

/// The Welch–Satterthwaite terms (Var/2 per property) of the channels whose noise terms the
/// model check rescaled (`group::check_model`). Their variance R·V̂ is the whole-turn
/// scatter's own estimate (the levels cancel in the ratio to first order), so R's ν
/// replaces the model's: Var = V²·2/ν_R, the conditions' contributions of a channel added
/// first, as R is shared. `propagated(c, j, m)`: the properties' variances from
/// covariance m of condition c's channel j alone.
fn rescaled_per_dof(
    fits: &[GroupFit; 3],
    propagated: &dyn Fn(usize, usize, [[f64; 2]; 2]) -> Result<[f64; 6], RateError>,
) -> Result<[f64; 6], RateError> {
    let mut out = [0.0; 6];
    for ch in Channel::ALL {
        let j = ch.index();
        let mut whole = [0.0; 6];
        let mut nu = None;
        for (c, fit) in fits.iter().enumerate() {
            let Some(sl) = ch.of(&fit.slow).as_ref() else {
                continue;
            };
            let Some(check) = sl.rescaled() else {
                continue;
            };
            // The fit's covariance: Σ θ·unit, rescaled.
            let [[aa, ab, _], [ba, bb, _], _] = fit.cov.get(j).copied().unwrap_or_default();
            for (w, v) in whole
                .iter_mut()
                .zip(propagated(c, j, [[aa, ab], [ba, bb]])?)
            {
                *w += v;
            }
            nu = Some(check.dof);
        }
        if let Some(nu) = nu {
            for (o, w) in out.iter_mut().zip(whole) {
                *o += w * w / nu;
            }
        }
    }
    Ok(out)
}

/// The budget's notes on the model check (`group::check_model`), one per channel whose
/// whole-turn coefficients scatter beyond what its noise model allows, either way.
fn check_notes(fits: &[GroupFit; 3]) -> Vec<String> {
    let mut notes = Vec::new();
    for ch in Channel::ALL {
        let Some(c) = fits
            .iter()
            .find_map(|f| ch.of(&f.slow).as_ref().and_then(|s| s.check))
        else {
            continue;
        };
        let (done, p, side) = match c.verdict() {
            noise::Verdict::Widened => ("WIDENED", c.p_above, "large"),
            noise::Verdict::Narrowed => ("NARROWED", c.p_below, "small"),
            noise::Verdict::None => continue,
        };
        notes.push(format!(
            "channel {}: the residuals' sine and cosine coefficients over {} whole turns \
             scatter {:.2} times what the noise model predicts for them (ν = {:.1}, the \
             model's {:.1}; a ratio this {side} has p = {p:.1e} under it, below {:.0e}): it is wrong \
             near the rotation frequency, so the channel's noise terms in U are {done} by \
             that factor (docs/uncertainty.md, \"The model against the data, checked\")",
            ch.letter(),
            c.periods,
            c.ratio,
            c.dof,
            c.dof_model,
            noise::MODEL_CHECK_ALPHA
        ));
    }
    notes
}

/// The file's check over the groups `fits` (each with its nominal rate): the harmonics'
/// p-values multiplied by the number of harmonics tested in the file, the steps' by the
/// number of channels scanned (Bonferroni); what falls below [`super::structure::ALPHA`] is reported.
/// Groups calibrated from a streamed file's sums were not scanned, and are counted so.
fn structure_check<'a>(
    fits: impl Iterator<Item = (f64, &'a GroupFit)> + Clone,
    slow_noise: bool,
) -> json::StructureCheckJson {
    let scanned = fits.clone().filter_map(|(_, f)| f.scan.as_ref());
    let harmonics = scanned
        .clone()
        .flatten()
        .map(|c| c.harmonics.len())
        .sum::<usize>()
        .max(1) as f64;
    let channels = (3 * scanned.clone().count()).max(1) as f64;
    let mut found = Vec::new();
    for (rate_hz, f) in fits.clone() {
        let Some(scan) = &f.scan else { continue };
        for (channel, c) in Channel::ALL.into_iter().zip(scan) {
            let at = |kind, harmonic, at_s, size, z, p_value| json::StructureJson {
                rate_hz,
                condition: f.condition,
                channel,
                kind,
                harmonic,
                at_s,
                size,
                z,
                p_value,
            };
            for h in &c.harmonics {
                let p = (h.p_single * harmonics).min(1.0);
                if p < super::structure::ALPHA {
                    found.push(at("harmonic", Some(h.k), None, h.amplitude, h.z, p));
                }
            }
            if let Some((s, t)) = &c.step {
                // Under the slow noise, the maximum is re-read at the scan's row: smaller
                // than the slow-standardised maximum, and Λ, from the AR scan, counts more
                // chances than the slower statistic has; both err towards silence.
                let (z, p_single) = match c.slow_z {
                    Some(z) => (z, crate::fit::structure::scan_max_p(z, s.lambda)),
                    None => (s.z, s.p_single),
                };
                let p = (p_single * channels).min(1.0);
                if p < super::structure::ALPHA {
                    found.push(at("step", None, Some(*t), s.size, z, p));
                }
            }
        }
    }
    let groups_scanned = fits.clone().filter(|(_, f)| f.scan.is_some()).count();
    json::StructureCheckJson {
        found: !found.is_empty(),
        alpha: super::structure::ALPHA,
        groups_scanned,
        groups_not_scanned: fits.count() - groups_scanned,
        slow_noise,
        structure: found,
    }
}
