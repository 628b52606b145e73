//! Whether a named effect earns its name (docs/discrepancy.md, "Confirmed or candidate").
//!
//! The final model is fitted again on each half of every group (the first and the second
//! half of its rows), with every named effect on. For each effect, with θ its parameters
//! (K₂ per channel, δ, …) and u their standard uncertainties in each half's fit:
//!
//! - **Consistent**: the halves agree, χ² = Σ (θ_A − θ_B)²/(u_A² + u_B²) against χ²(k) at
//!   the workflow's α. An effect that stands in for something else (a 5th harmonic read as
//!   K₃, a step read as a drift) takes different values where that something differs.
//! - **Predicts**: each half's θ, as a direction, is found in the other half's data:
//!   z = Σ θ_A·θ_B/u_B² / √(Σ θ_A²/u_B²), N(0, 1) when the other half holds no such
//!   effect, must exceed the one-sided normal quantile at α, both ways (A → B and B → A).
//!   An effect fitted to noise does not recur in data it was not fitted to.
//!
//! Under `--slow-noise` the halves' uncertainties carry the slow terms, on the session's
//! grid with each half in its place. Channels are independent in the model, so a
//! parameter's own variance is its channel's; within a channel the parameters are taken as
//! uncorrelated (δ stands alone; the centripetal b of three conditions barely correlate).
//! Saturation has no fitted parameter (the rails are read from the data) and is confirmed
//! by the readings on its rails.

use super::model::{self, Data, Effect, Fit, GroupData, Params};
use super::slow::SlowLevels;
use super::DiscrepancyError;
use serde::Serialize;
use statrs::distribution::{ChiSquared, ContinuousCDF, Normal};

/// One named effect's checks.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Confirmation {
    /// The effect's name.
    pub effect: String,
    /// Whether it passed every check: its correction is applied.
    pub confirmed: bool,
    /// The halves' difference: χ², its degrees of freedom and P(χ²(k) ≥ it). None for an
    /// effect without fitted parameters.
    pub consistency: Option<Halves>,
    /// z of the first half's θ in the second half's data, and of the second's in the first.
    pub predicts: Option<[f64; 2]>,
    /// Why it is or is not confirmed, in a sentence.
    pub reason: String,
}

/// The halves' agreement.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Halves {
    /// Σ (θ_A − θ_B)²/(u_A² + u_B²).
    pub chi2: f64,
    /// Parameters compared.
    pub dof: usize,
    /// P(χ²(dof) ≥ chi2).
    pub p_value: f64,
}

/// The first (`first`) or the second half of every group's rows (noise models and generic
/// fits as the whole's).
fn half(data: &Data, first: bool) -> Data {
    let split = |g: &GroupData| -> GroupData {
        let at = g.tau.len() / 2;
        let part = |v: &[f64]| -> Vec<f64> {
            let (a, b) = v.split_at(at.min(v.len()));
            if first { a } else { b }.to_vec()
        };
        GroupData {
            condition: g.condition,
            rate_hz: g.rate_hz,
            tau: part(&g.tau),
            t: part(&g.t),
            temp: part(&g.temp),
            y: g.y.each_ref().map(|v| part(v)),
        }
    };
    Data {
        groups: data.groups.iter().map(split).collect(),
        g_loc: data.g_loc,
        sigma: data.sigma,
        noise: data.noise.clone(),
        generic: data.generic.clone(),
    }
}

/// An effect's fitted parameters, in a fixed order (none for saturation).
fn values(e: Effect, p: &Params) -> Vec<f64> {
    match e {
        Effect::RateError => p.delta.into_iter().collect(),
        Effect::OffsetDrift => p.drift.map(Vec::from).unwrap_or_default(),
        Effect::TemperatureOffset => p.temp.map(Vec::from).unwrap_or_default(),
        Effect::Nonlinearity2nd => p.k2.map(Vec::from).unwrap_or_default(),
        Effect::Nonlinearity3rd => p.k3.map(Vec::from).unwrap_or_default(),
        Effect::Centripetal => p
            .centripetal
            .map(|b| b.iter().flatten().copied().collect())
            .unwrap_or_default(),
        Effect::Saturation => Vec::new(),
    }
}

/// A half's fit and its parameters' standard uncertainties (with the slow terms when
/// `levels` are given, the half placed on the session's grid at `shift`).
fn half_fit(
    half: &Data,
    current: &Fit,
    levels: Option<(&SlowLevels, &[usize])>,
) -> Result<(Fit, Params), DiscrepancyError> {
    let f = model::fit(half, &current.effects, Some(&current.params))?;
    let unc = match levels {
        Some((l, shift)) => super::slow_uncertainty(half, &l.shifted(shift), &f)?.unc,
        None => f.unc.clone(),
    };
    Ok((f, unc))
}

/// Under slow noise, the halves' difference θ_A − θ_B as one linear form of all the
/// readings (each half's weights in its rows, the second's negated), tested as the
/// candidates are ([`SlowLevels::test`]): the slow terms' covariance of the difference
/// includes what one walk through both halves gives them in common, and each parameter's
/// slow variance is raised by 3.09 of its standard deviations. Returns (k·F, k).
fn slow_difference(
    data: &Data,
    levels: &SlowLevels,
    (a, fa): (&Data, &Fit),
    (b, fb): (&Data, &Fit),
    e: Effect,
) -> Option<(f64, usize)> {
    let ta = model::tested(a, fa, e).ok()??;
    let tb = model::tested(b, fb, e).ok()??;
    let k = ta.values.len();
    if k == 0 || tb.values.len() != k {
        return None;
    }
    let values: Vec<f64> = ta
        .values
        .iter()
        .zip(&tb.values)
        .map(|(x, y)| x - y)
        .collect();
    // Each half's GLS covariance scaled by its χ²/dof, as a candidate's test scales it.
    let gls = &ta.gls_cov * fa.chi2_dof() + &tb.gls_cov * fb.chi2_dof();
    // Per parameter and channel: group after group, the first half's weights then the
    // second's negated, in the whole data's rows.
    let weights = ta
        .weights
        .iter()
        .zip(&tb.weights)
        .map(|(wa, wb)| {
            let mut out: [Vec<f64>; 3] = Default::default();
            for ((o, wa), wb) in out.iter_mut().zip(wa).zip(wb) {
                let (mut ra, mut rb) = (wa.as_slice(), wb.as_slice());
                for ((ga, gb), g) in a.groups.iter().zip(&b.groups).zip(&data.groups) {
                    let (pa, rest_a) = ra.split_at(ga.tau.len().min(ra.len()));
                    let (pb, rest_b) = rb.split_at(gb.tau.len().min(rb.len()));
                    ra = rest_a;
                    rb = rest_b;
                    o.reserve(g.tau.len());
                    o.extend_from_slice(pa);
                    o.extend(pb.iter().map(|v| -v));
                }
            }
            out
        })
        .collect();
    let diff = model::Tested::linear(values, gls, weights);
    let t = levels.test(data, &diff, 1.0, fa.dof.min(fb.dof))?;
    Some((t.f * k as f64, k))
}

/// Each named effect of `current` (the final model on `data`) checked on the halves, at
/// significance `alpha`; unchecked, and so not confirmed, where a half cannot be fitted.
pub(super) fn check(
    data: &Data,
    current: &Fit,
    alpha: f64,
    levels: Option<&SlowLevels>,
) -> Vec<Confirmation> {
    if current.effects.is_empty() {
        return Vec::new();
    }
    // Each group's row where its second half starts.
    let at: Vec<usize> = data.groups.iter().map(|g| g.tau.len() / 2).collect();
    let none = vec![0; data.groups.len()];
    // One half's rows at a time, but for the slow test of their difference, which needs
    // both (each half is as large as half the recording).
    let a = half(data, true);
    let fits = half_fit(&a, current, levels.map(|l| (l, none.as_slice()))).and_then(|fa| {
        let a = levels.is_some().then_some(a);
        let b = half(data, false);
        half_fit(&b, current, levels.map(|l| (l, at.as_slice()))).map(|fb| (fa, fb, a, b))
    });
    // Halves too short or too poor to fit leave every effect unchecked: none is confirmed.
    let ((fa, ua), (fb, ub), a, b) = match fits {
        Ok(f) => f,
        Err(e) => {
            return current
                .effects
                .iter()
                .map(|effect| Confirmation {
                    effect: effect.name().to_string(),
                    confirmed: false,
                    consistency: None,
                    predicts: None,
                    reason: format!("the halves could not be fitted ({e}), so it is unchecked"),
                })
                .collect();
        }
    };
    let z_alpha = Normal::standard().inverse_cdf(1.0 - alpha);
    let mut out = Vec::new();
    for &e in &current.effects {
        let (ta, sa, tb, sb) = (
            values(e, &fa.params),
            values(e, &ua),
            values(e, &fb.params),
            values(e, &ub),
        );
        if ta.is_empty() {
            out.push(Confirmation {
                effect: e.name().to_string(),
                confirmed: true,
                consistency: None,
                predicts: None,
                reason: "no fitted parameter: the rails are read from the data".into(),
            });
            continue;
        }
        let usable: Vec<(f64, f64, f64, f64)> = ta
            .iter()
            .zip(&sa)
            .zip(tb.iter().zip(&sb))
            .map(|((&x, &ux), (&y, &uy))| (x, ux, y, uy))
            .filter(|(x, ux, y, uy)| {
                [x, ux, y, uy].iter().all(|v| v.is_finite()) && *ux > 0.0 && *uy > 0.0
            })
            .collect();
        let independent = || -> (f64, usize) {
            let chi2 = usable
                .iter()
                .map(|(x, ux, y, uy)| (x - y).powi(2) / (ux * ux + uy * uy))
                .sum();
            (chi2, usable.len())
        };
        let (chi2, dof) = match (levels, &a) {
            (Some(l), Some(a)) => match slow_difference(data, l, (a, &fa), (&b, &fb), e) {
                Some(d) => d,
                None => independent(),
            },
            _ => independent(),
        };
        let p_value = match ChiSquared::new(dof.max(1) as f64) {
            Ok(d) if dof > 0 => d.sf(chi2),
            _ => f64::NAN,
        };
        // z of the direction θ_from in the data whose estimate is θ_to ± u_to.
        let predicts = |from_is_a: bool| -> f64 {
            let (mut num, mut den) = (0.0, 0.0);
            for (x, ux, y, uy) in &usable {
                let (from, to, u_to) = if from_is_a { (x, y, uy) } else { (y, x, ux) };
                num += from * to / (u_to * u_to);
                den += from * from / (u_to * u_to);
            }
            if den > 0.0 {
                num / den.sqrt()
            } else {
                0.0
            }
        };
        let z = [predicts(true), predicts(false)];
        let consistent = p_value >= alpha;
        let predicting = z.iter().all(|z| *z > z_alpha);
        let reason = match (consistent, predicting) {
            (true, true) => format!(
                "the halves agree (χ² = {chi2:.1} on {dof}, p = {p_value:.2}) and each half's \
                 fit is found in the other's data (z = {:.1}, {:.1})",
                z[0], z[1]
            ),
            (false, _) => format!(
                "the halves disagree (χ² = {chi2:.1} on {dof}, p = {p_value:.1e} < {alpha}): \
                 it stands in for something that differs between them"
            ),
            (true, false) => format!(
                "a half's fit is not found in the other's data (z = {:.1}, {:.1}; needed \
                 above {z_alpha:.2} both ways)",
                z[0], z[1]
            ),
        };
        out.push(Confirmation {
            effect: e.name().to_string(),
            confirmed: consistent && predicting,
            consistency: Some(Halves { chi2, dof, p_value }),
            predicts: Some(z),
            reason,
        });
    }
    out
}
