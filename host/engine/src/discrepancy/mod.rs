//! `rotacal discrepancy`: find where the model and the measurement disagree, name the
//! missing effect, add it, and show the gap shrink (docs/discrepancy.md).
//!
//! 1. Fit the current model and predict the recording with it at the measured timestamps
//!    ([`model`]: the simulator's equations, docs/simulator.md); the gap is measurement
//!    minus prediction.
//! 2. Measure the gap against the noise ([`noise`]: an AR(p) model per group and channel,
//!    estimated once from the data and used by every fit to whiten the residuals).
//! 3. Locate it ([`locate`]): harmonics of ω, trends, temperature, rails, rates.
//! 4. Test every applicable effect by a nested F-test; name the most significant one that
//!    passes, add it, refit, and repeat until none passes.

pub mod confirm;
pub mod locate;
pub mod model;
pub mod noise;
pub mod place;
pub mod slow;
pub mod structure;
pub mod trials;
pub mod verdict;

use crate::calibrate::json::Quantity;
use crate::recording::{Method, Recording};
use model::{Data, Effect, Fit, GroupData, ModelError};
use noise::NoiseEstimateError;
use rotacal_shared::intrinsic::{self, ConditionFit};
use rotacal_shared::{Channel, Condition};
use serde::Serialize;
use statrs::distribution::{ContinuousCDF, FisherSnedecor};
use std::collections::BTreeMap;

/// Significance of each F-test. With up to seven candidates per step, the chance that a
/// step names an effect that isn't there is at most 7·α = 0.7 % (Bonferroni).
pub const ALPHA: f64 = 1e-3;

/// How to run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Options {
    /// Local gravity, m/s² (else the file's).
    pub g_loc: Option<f64>,
    /// Nominal rate for a single-rate file without one, Hz.
    pub rate_hz: Option<f64>,
    /// Significance of each test.
    pub alpha: f64,
    /// Count flicker and a bias random walk in the tests ([`slow`]).
    pub slow_noise: bool,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            g_loc: None,
            rate_hz: None,
            alpha: ALPHA,
            slow_noise: false,
        }
    }
}

/// Why the workflow could not run on a recording.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DiscrepancyError {
    /// Not a rotation recording.
    #[error("{source_name}: the discrepancy workflow needs a rotation recording (t_s)")]
    NotRotation {
        /// The recording.
        source_name: String,
        /// Its method.
        method: Method,
    },
    /// Neither the options nor the file give local gravity.
    #[error("{source_name}: local gravity unknown: give --g-loc")]
    NoGravity {
        /// The recording.
        source_name: String,
    },
    /// A condition recorded in several boots of the device: the workflow's models run on
    /// one time line per condition, and a restart leaves the phase between boots unknown.
    #[error(
        "{source_name}: condition {} was recorded in several boots of the device (its `boot` \
         column): the discrepancy workflow needs each condition in one; calibrate joins \
         boots, the discrepancy workflow does not",
        condition.letter()
    )]
    SeveralBoots {
        /// The recording.
        source_name: String,
        /// The condition.
        condition: Condition,
    },
    /// A group whose rate neither the file nor the options give.
    #[error("{source_name}: rotation rate unknown: give --rate-hz")]
    NoRate {
        /// The recording.
        source_name: String,
        /// The group's condition.
        condition: Condition,
    },
    /// The noise models.
    #[error(transparent)]
    Noise(#[from] NoiseEstimateError),
    /// The baseline model's fit.
    #[error(transparent)]
    Fit(#[from] ModelError),
    /// The slow noise (`--slow-noise`).
    #[error(transparent)]
    Slow(#[from] slow::SlowError),
}

/// The noise level per channel and where it came from (always the estimate from the
/// data; the per-group models are in [`Analysis::noise_model`]).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct NoiseSigma {
    /// One sample's noise sd of u over all groups (root of the row-weighted mean
    /// variance), output units.
    pub u: f64,
    /// The same for v.
    pub v: f64,
    /// The same for w.
    pub w: f64,
    /// `estimated: <how>`.
    pub source: String,
}

/// One group's channel's noise model (JSON `noise_model`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct NoiseModelJson {
    /// The group's condition (JSON: x, y or z).
    pub condition: Condition,
    /// Nominal rate, Hz.
    pub rate_hz: f64,
    /// u, v or w.
    pub channel: Channel,
    /// AR coefficients φ₁ … φ_p (empty: white).
    pub ar: Vec<f64>,
    /// One sample's noise sd, output units.
    pub sd: f64,
    /// The innovations' sd (what the whitening divides by), output units.
    pub innovation_sd: f64,
    /// The model's lag-1 autocorrelation.
    pub lag1_autocorrelation: f64,
    /// 2πS(ω)/γ₀ at the rotation frequency: how many times the amplitudes' variance
    /// exceeds what white noise of the same level gives.
    pub variance_factor: f64,
    /// Rows of the group.
    pub n: usize,
    /// Rows left out of the estimate (at a rail).
    pub n_excluded: usize,
    /// n / variance_factor: the effective number of independent rows for the amplitudes.
    pub n_eff: f64,
}

/// A `noise_sigma` the file states, and whether the data contradict it. It is never used:
/// the noise model is always the one estimated from the data.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct NoiseStatement {
    /// The stated white-noise sd per sample, output units.
    pub stated: f64,
    /// The data contradict it: some channel's noise is not white (AR order > 0), or some
    /// channel's estimated variance differs from the stated one by more than 4 standard
    /// errors (√(2/ν), ν the rows used less the generic fit's 10 coefficients per group).
    pub contradicted: bool,
    /// Why (or "consistent").
    pub why: String,
}

/// The statement checked against the estimated models.
fn check_statement(stated: f64, data: &Data) -> NoiseStatement {
    let mut why = Vec::new();
    for ch in Channel::ALL {
        let name = ch.letter();
        let mut worst_order = 0;
        let mut nu = 0.0;
        for m in data.noise.iter().map(|g| ch.of(g)) {
            worst_order = worst_order.max(m.order());
            nu += (m.n - m.excluded).saturating_sub(10) as f64;
        }
        if worst_order > 0 {
            why.push(format!(
                "{name} is correlated (AR order up to {worst_order})"
            ));
        }
        let ratio = (ch.of(&data.sigma) / stated).powi(2);
        let bound = 4.0 * (2.0 / nu.max(1.0)).sqrt();
        if (ratio - 1.0).abs() > bound {
            why.push(format!(
                "{name}: estimated variance {ratio:.3} times the stated one (bound 1 ± {bound:.3})"
            ));
        }
    }
    NoiseStatement {
        stated,
        contradicted: !why.is_empty(),
        why: if why.is_empty() {
            "consistent".into()
        } else {
            why.join("; ")
        },
    }
}

/// The per-group models for the JSON.
pub fn noise_model_json(data: &Data) -> Vec<NoiseModelJson> {
    let mut out = Vec::new();
    for (g, models) in data.groups.iter().zip(&data.noise) {
        let n = g.tau.len();
        let dt = match (g.tau.first(), g.tau.last()) {
            (Some(a), Some(b)) if n > 1 => (b - a) / (n - 1) as f64,
            _ => 0.0,
        };
        let omega = g.omega() * dt;
        for (m, channel) in models.iter().zip(Channel::ALL) {
            out.push(NoiseModelJson {
                condition: g.condition,
                rate_hz: g.rate_hz,
                channel,
                ar: m.ar.clone(),
                sd: m.sd(),
                innovation_sd: m.innovation_var.sqrt(),
                // + 0.0: white noise's empty sum is −0.0.
                lag1_autocorrelation: m.autocorrelation(1) + 0.0,
                variance_factor: m.variance_factor(omega),
                n: m.n,
                n_excluded: m.excluded,
                n_eff: m.n_eff(omega),
            });
        }
    }
    out
}

/// χ²/dof and residual RMS of a model.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Goodness {
    /// χ²/dof.
    pub chi2_dof: f64,
    /// Residual RMS over all channels, output units.
    pub rms_residual: f64,
    /// Degrees of freedom.
    pub dof: f64,
}

impl Goodness {
    fn of(f: &Fit) -> Self {
        Goodness {
            chi2_dof: f.chi2_dof(),
            rms_residual: f.rms_all(),
            dof: f.dof,
        }
    }
}

/// The test of one effect against the current model.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Criterion {
    /// The effect.
    pub effect: String,
    /// "nested F-test", or "Wald test with slow noise" under `--slow-noise`.
    pub test: &'static str,
    /// F statistic.
    pub f: f64,
    /// Parameters added.
    pub k: usize,
    /// Residual degrees of freedom with the effect.
    pub dof: f64,
    /// P(F ≥ f) under "no such effect".
    pub p_value: f64,
    /// The significance it must beat.
    pub alpha: f64,
    /// ΔBIC = Δχ² − k ln N (ranks the effects that pass).
    pub delta_bic: f64,
    /// p < α.
    pub passed: bool,
    /// Under `--slow-noise`: the slow terms' share of the tested parameters' variance
    /// (the trace of their covariance), 0 … 1.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub slow_share: Option<f64>,
}

/// Intrinsic properties at one rate.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RateIntrinsic {
    /// Nominal rate, Hz.
    pub rate_hz: f64,
    /// s_u, s_v, s_w; output units per m/s².
    pub sensitivity: [Quantity; 3],
    /// φ_uv, φ_vw, φ_wu; degrees.
    pub angle_deg: [Quantity; 3],
}

/// One step: the effect named, its parameters and what it did.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Step {
    /// The effect's name.
    pub effect: String,
    /// Its parameters (names as in the simulator's configuration).
    pub parameters: BTreeMap<String, serde_json::Value>,
    /// The test that named it.
    pub criterion: Criterion,
    /// χ²/dof with it.
    pub chi2_dof: f64,
    /// Residual RMS with it.
    pub rms_residual: f64,
    /// Every candidate's test at this step.
    pub candidates: Vec<Criterion>,
    /// Intrinsic properties before and after, per rate.
    pub intrinsic_before: Vec<RateIntrinsic>,
    /// See `intrinsic_before`.
    pub intrinsic_after: Vec<RateIntrinsic>,
}

/// The whole analysis (formats.md `rotacal discrepancy --json`, with added keys).
#[derive(Clone, Debug, Serialize)]
pub struct Analysis {
    /// The noise level per channel (the estimate; formats.md's key).
    pub noise_sigma: NoiseSigma,
    /// The noise model per group and channel, estimated once from the data and used by
    /// every fit (prewhitening).
    pub noise_model: Vec<NoiseModelJson>,
    /// Under `--slow-noise`: each channel's flicker and walk levels ([`slow`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub slow_noise: Option<Vec<slow::SlowNoiseJson>>,
    /// The file's `noise_sigma`, if stated, and whether the data contradict it (never used).
    pub noise_sigma_stated: Option<NoiseStatement>,
    /// The significance each test had to beat.
    pub alpha: f64,
    /// The papers' model.
    pub baseline: Goodness,
    /// Where the baseline's gap lies, largest first.
    pub findings: Vec<locate::Finding>,
    /// Effects added, in order.
    pub steps: Vec<Step>,
    /// Their names.
    pub named_effects: Vec<String>,
    /// Each named effect's parameters in the final model (with all the others).
    pub final_parameters: BTreeMap<String, BTreeMap<String, serde_json::Value>>,
    /// Intrinsic properties per rate: the baseline's and the final model's.
    pub intrinsic_baseline: Vec<RateIntrinsic>,
    /// See `intrinsic_baseline`.
    pub intrinsic_final: Vec<RateIntrinsic>,
    /// The named effects that are confirmed, whose corrections the result applies: those
    /// that pass the halves' checks when the verdict is "explained", none otherwise (each
    /// was named by a test that assumed the larger model right, which the data then showed
    /// it is not).
    pub confirmed_effects: Vec<String>,
    /// Intrinsic properties per rate with only the confirmed effects modelled: the result.
    pub intrinsic_confirmed: Vec<RateIntrinsic>,
    /// Each named effect's checks on the halves of the data, when the verdict is
    /// "explained" ([`confirm`]).
    pub confirmation: Vec<confirm::Confirmation>,
    /// The last model.
    #[serde(rename = "final")]
    pub final_: Goodness,
    /// Every candidate's test once nothing more passed.
    pub last_candidates: Vec<Criterion>,
    /// The effects that could not be tested on this file, and why.
    pub untestable: Vec<(String, String)>,
    /// Whether the final model and the noise account for the data, and where not.
    pub verdict: verdict::Verdict,
    /// Structure the generic fit would have left, found before the noise was estimated
    /// (and kept out of the noise model).
    pub structure: Vec<structure::Structure>,
    /// The fits, for plots (not serialised).
    #[serde(skip)]
    pub fits: Vec<Fit>,
    /// The data.
    #[serde(skip)]
    pub data: Data,
}

/// The recording as the model's data, with its noise model estimated from the data (a
/// stated `noise_sigma` is not used: see [`NoiseStatement`]).
pub fn data_from(rec: &Recording, opts: &Options) -> Result<(Data, NoiseSigma), DiscrepancyError> {
    with_noise(rows_from(rec.clone(), opts)?)
}

/// The recording's rows as the model sees them, before any noise is estimated: what
/// [`data_from`] starts from. The recording is consumed group by group (its readings move,
/// its other columns are freed), so the rows are never held twice.
pub fn rows_from(rec: Recording, opts: &Options) -> Result<Data, DiscrepancyError> {
    if rec.method != Method::Rotation {
        return Err(DiscrepancyError::NotRotation {
            source_name: rec.source.clone(),
            method: rec.method,
        });
    }
    let g_loc = opts
        .g_loc
        .or(rec.meta.g_loc)
        .ok_or_else(|| DiscrepancyError::NoGravity {
            source_name: rec.source.clone(),
        })?;
    if let Some(g) = rec.groups.iter().find(|g| g.in_several_boots()) {
        return Err(DiscrepancyError::SeveralBoots {
            source_name: rec.source.clone(),
            condition: g.condition,
        });
    }
    let t_mean = {
        let (s, n) = rec
            .groups
            .iter()
            .flat_map(|g| &g.t_s)
            .fold((0.0, 0usize), |(s, n), t| (s + t, n + 1));
        s / n.max(1) as f64
    };
    let temps: Vec<f64> = rec
        .groups
        .iter()
        .filter_map(|g| g.temp_c.as_ref())
        .flatten()
        .copied()
        .collect();
    let temp_mean = if temps.is_empty() {
        0.0
    } else {
        temps.iter().sum::<f64>() / temps.len() as f64
    };
    let mut rates = Vec::with_capacity(rec.groups.len());
    for g in &rec.groups {
        rates.push(rec.nominal_rate(g).or(opts.rate_hz).ok_or_else(|| {
            DiscrepancyError::NoRate {
                source_name: rec.source.clone(),
                condition: g.condition,
            }
        })?);
    }
    let mut groups = Vec::with_capacity(rec.groups.len());
    for (g, rate_hz) in rec.groups.into_iter().zip(rates) {
        let t0 = g.t_s.first().copied().unwrap_or(0.0);
        let n = g.len();
        groups.push(GroupData {
            condition: g.condition,
            rate_hz,
            tau: g.t_s.iter().map(|t| t - t0).collect(),
            // In place: t_s's own storage.
            t: g.t_s.into_iter().map(|t| t - t_mean).collect(),
            temp: match g.temp_c {
                Some(t) => t.into_iter().map(|x| x - temp_mean).collect(),
                None => vec![0.0; n],
            },
            y: [g.u, g.v, g.w],
        });
    }
    Ok(Data {
        groups,
        g_loc,
        sigma: [1.0; 3],
        noise: Vec::new(),
        generic: structure::Generic::default(),
    })
}

/// [`rows_from`]'s data with each group's channel's noise model estimated (after the
/// structure scan, [`noise::estimate`]), and the noise level per channel it gives.
pub fn with_noise(mut data: Data) -> Result<(Data, NoiseSigma), DiscrepancyError> {
    (data.noise, data.generic) = noise::estimate(&data)?;
    let rows = data.rows().max(1) as f64;
    data.sigma = Channel::ALL.map(|ch| {
        (data
            .noise
            .iter()
            .zip(&data.groups)
            .map(|(m, g)| ch.of(m).var * g.tau.len() as f64)
            .sum::<f64>()
            / rows)
            .sqrt()
    });
    let noise = NoiseSigma {
        u: data.sigma[0],
        v: data.sigma[1],
        w: data.sigma[2],
        source: format!("estimated: {}", noise::HOW),
    };
    Ok((data, noise))
}

/// The effects this file can test, and why the others can't be.
pub fn applicable(data: &Data) -> (Vec<Effect>, Vec<(String, String)>) {
    let mut yes = Vec::new();
    let mut no = Vec::new();
    for e in Effect::ALL {
        let why = match e {
            Effect::Centripetal if data.rates().len() < 2 => {
                Some("needs several rates (it moves the offsets with ω²)")
            }
            Effect::TemperatureOffset if !data.temperature_varies() => {
                Some("the temperature does not vary (no temp_c, or within 0.05 °C)")
            }
            Effect::Saturation if data.rails() == [None, None] => {
                Some("no readings repeat at the extremes of the file (no rails)")
            }
            _ => None,
        };
        match why {
            Some(w) => no.push((e.name().to_string(), w.to_string())),
            None => yes.push(e),
        }
    }
    (yes, no)
}

/// The nested F-test of `with` against `base`; k is the parameters added (at least 1:
/// saturation's rails are read off the data, not fitted). Saturation also leaves out the
/// whitened rows whose window holds a reading it puts at a rail; the Δχ² they give is its
/// evidence that the fitted curve reaches a value at which at least three readings sit
/// exactly. Without clipping the curve stays some σ below the file's extreme readings,
/// leaves nothing out and gains nothing, so this does not add false alarms (the clean
/// proofs). Counting each left-out row as a degree of freedom instead would ask the
/// clipped readings to sit further from the curve than noise, which shallow clipping
/// (a rail within about 2σ of the peaks) never does: a clipped reading is nearer the
/// curve than an unclipped one would be (white limit 8 counts against 1).
fn criterion(e: Effect, base: &Fit, with: &Fit, n: f64, alpha: f64) -> Criterion {
    let k = with.n_params.saturating_sub(base.n_params).max(1);
    let d_chi2 = (base.chi2 - with.chi2).max(0.0);
    let f = (d_chi2 / k as f64) / (with.chi2 / with.dof);
    let p_value = FisherSnedecor::new(k as f64, with.dof)
        .map(|d| d.sf(f))
        .unwrap_or(1.0);
    Criterion {
        effect: e.name().to_string(),
        test: "nested F-test",
        f,
        k,
        dof: with.dof,
        p_value,
        alpha,
        delta_bic: d_chi2 - k as f64 * n.ln(),
        passed: p_value < alpha,
        slow_share: None,
    }
}

/// [`criterion`] under slow noise: the Wald test of the effect's parameters with the slow
/// terms in their covariance ([`slow`]). Saturation, which adds no estimated parameter,
/// keeps the F-test.
fn slow_criterion(
    data: &Data,
    levels: &slow::SlowLevels,
    (e, base, with): (Effect, &Fit, &Fit),
    n: f64,
    alpha: f64,
) -> Result<Criterion, DiscrepancyError> {
    let plain = criterion(e, base, with, n, alpha);
    let Some(tested) = model::tested(data, with, e)? else {
        return Ok(plain);
    };
    let k = tested.values.len();
    let Some(t) = levels.test(data, &tested, with.chi2_dof(), with.dof) else {
        return Err(DiscrepancyError::Fit(ModelError::Internal(
            "the tested parameters' covariance under slow noise is singular",
        )));
    };
    let p_value = FisherSnedecor::new(k as f64, t.dof)
        .map(|d| d.sf(t.f))
        .unwrap_or(1.0);
    Ok(Criterion {
        test: "Wald test with slow noise",
        f: t.f,
        k,
        dof: t.dof,
        p_value,
        passed: p_value < alpha,
        slow_share: Some(t.slow_share),
        ..plain
    })
}

/// Intrinsic properties per rate from a fit's A, B (all effects taken out).
pub fn intrinsic_per_rate(data: &Data, fit: &Fit) -> Vec<RateIntrinsic> {
    let mut out = Vec::new();
    for rate in data.rates() {
        let mut cf: [Option<ConditionFit>; 3] = [None; 3];
        let fitted = fit.params.ab.iter().zip(&fit.ab_cov);
        for (g, (ab, cov)) in data.groups.iter().zip(fitted) {
            if g.rate_hz == rate {
                *g.condition.of_mut(&mut cf) = Some(ConditionFit {
                    a: ab.map(|[a, _]| a),
                    b: ab.map(|[_, b]| b),
                    cov: *cov,
                });
            }
        }
        if let [Some(x), Some(y), Some(z)] = cf {
            if let Ok(i) = intrinsic::from_gram(&[x, y, z], data.g_loc, 0.0) {
                out.push(RateIntrinsic {
                    rate_hz: rate,
                    sensitivity: i.sensitivity.map(Quantity::from),
                    angle_deg: i.angle_deg.map(Quantity::from),
                });
            }
        }
    }
    out
}

/// A value with its standard uncertainty, expanded with k for `nu` degrees of freedom
/// (k = 2 without).
fn q(value: f64, u: f64, nu: Option<f64>) -> serde_json::Value {
    let e = rotacal_shared::intrinsic::Estimate { value, std_unc: u };
    let quantity = match nu {
        Some(nu) => Quantity::with_k(e, crate::calibrate::budget::coverage_factor(nu)),
        None => Quantity::from(e),
    };
    serde_json::to_value(quantity).unwrap_or(serde_json::Value::Null)
}

fn uvw(v: Option<[f64; 3]>, u: Option<[f64; 3]>, nu: Option<[f64; 3]>) -> serde_json::Value {
    match (v, u) {
        (Some(v), Some(u)) => {
            let n = |i: usize| nu.and_then(|n| n.get(i).copied());
            serde_json::json!({
                "u": q(v[0], u[0], n(0)),
                "v": q(v[1], u[1], n(1)),
                "w": q(v[2], u[2], n(2)),
            })
        }
        _ => serde_json::Value::Null,
    }
}

/// A fit's effects' uncertainties with the slow noise in them (`--slow-noise`), in the
/// fit's shape: the standard uncertainties and the degrees of freedom each U's k comes
/// from.
#[derive(Clone, Debug)]
pub struct SlowUncertainty {
    /// Standard uncertainties.
    pub unc: model::Params,
    /// Degrees of freedom.
    pub nu: model::Params,
}

/// An effect's parameters from a fit, named as in the simulator's configuration; with
/// `slow` (`--slow-noise`), their uncertainties from it.
pub fn parameters(
    e: Effect,
    f: &Fit,
    data: &Data,
    slow: Option<&SlowUncertainty>,
) -> BTreeMap<String, serde_json::Value> {
    let p = &f.params;
    let u = slow.map_or(&f.unc, |s| &s.unc);
    let nu = slow.map(|s| &s.nu);
    let mut m = BTreeMap::new();
    match e {
        Effect::RateError => {
            m.insert(
                "relative".into(),
                q(
                    p.delta.unwrap_or(0.0),
                    u.delta.unwrap_or(0.0),
                    nu.and_then(|n| n.delta),
                ),
            );
        }
        Effect::OffsetDrift => {
            m.insert(
                "per_s".into(),
                uvw(p.drift, u.drift, nu.and_then(|n| n.drift)),
            );
        }
        Effect::TemperatureOffset => {
            m.insert("per_c".into(), uvw(p.temp, u.temp, nu.and_then(|n| n.temp)));
        }
        Effect::Nonlinearity2nd => {
            m.insert("k2".into(), uvw(p.k2, u.k2, nu.and_then(|n| n.k2)));
        }
        Effect::Nonlinearity3rd => {
            m.insert("k3".into(), uvw(p.k3, u.k3, nu.and_then(|n| n.k3)));
        }
        Effect::Saturation => {
            let [low, high] = p.rails.unwrap_or([f64::NEG_INFINITY, f64::INFINITY]);
            let side = |x: f64| {
                if x.is_finite() {
                    serde_json::json!(x)
                } else {
                    serde_json::Value::Null
                }
            };
            m.insert("rails".into(), serde_json::json!([side(low), side(high)]));
        }
        Effect::Centripetal => {
            let s = p.sensitivity(data);
            if let (Some(b), Some(ub)) = (p.centripetal, u.centripetal) {
                // Per condition: the centripetal acceleration per ω² is r·d̂ seen through
                // S, so |b_c/s| is the radius (axes near orthogonal).
                let nub = nu.and_then(|n| n.centripetal);
                let [x, y, z] = Condition::ALL.map(|c| {
                    let (bc, ubc) = (c.of(&b), c.of(&ub));
                    let v: Vec<f64> = bc.iter().zip(&s).map(|(b, s)| b / s).collect();
                    let r = v.iter().map(|x| x * x).sum::<f64>().sqrt();
                    // Each channel's share of u(r)²; with degrees of freedom, theirs
                    // combine by Welch–Satterthwaite.
                    let shares: Vec<f64> = if r > 0.0 {
                        v.iter()
                            .zip(ubc)
                            .zip(&s)
                            .map(|((v, ub), s)| (v / r * ub / s).powi(2))
                            .collect()
                    } else {
                        vec![0.0; 3]
                    };
                    let ur2: f64 = shares.iter().sum();
                    let nu_r = nub.map(|n| {
                        let denominator: f64 =
                            shares.iter().zip(c.of(&n)).map(|(w, n)| w * w / n).sum();
                        if denominator > 0.0 {
                            (ur2 * ur2 / denominator).max(1.0)
                        } else {
                            f64::INFINITY
                        }
                    });
                    q(r, ur2.sqrt(), nu_r)
                });
                m.insert(
                    "radius_m".into(),
                    serde_json::json!({"x": x, "y": y, "z": z}),
                );
            }
        }
    }
    m
}

/// The uncertainties of a fit's effects with the slow noise in them.
fn slow_uncertainty(
    data: &Data,
    levels: &slow::SlowLevels,
    f: &Fit,
) -> Result<SlowUncertainty, DiscrepancyError> {
    let mut out = SlowUncertainty {
        unc: f.unc.clone(),
        nu: f.unc.clone(),
    };
    for &e in &f.effects {
        if let Some(t) = model::tested(data, f, e)? {
            let (u, nu) = levels.uncertainty(data, &t);
            t.write(&u, &mut out.unc);
            t.write(&nu, &mut out.nu);
        }
    }
    Ok(out)
}

/// Run the workflow on prepared data, at `opts`' significance, counting slow noise if it
/// asks (its g_loc and rate_hz are [`data_from`]'s).
pub fn analyse(
    data: Data,
    noise: NoiseSigma,
    stated: Option<f64>,
    opts: &Options,
) -> Result<Analysis, DiscrepancyError> {
    let alpha = opts.alpha;
    let n = (data.rows() * 3) as f64;
    let levels = if opts.slow_noise {
        Some(slow::estimate(&data)?)
    } else {
        None
    };
    let (candidates, untestable) = applicable(&data);
    let baseline = model::fit(&data, &[], None)?;
    let intrinsic_baseline = intrinsic_per_rate(&data, &baseline);
    let mut findings = locate::locate(&data, &baseline);
    findings.extend(locate::angles_against_rate(&intrinsic_baseline));
    findings.sort_by(|a, b| b.z.total_cmp(&a.z));
    let baseline_goodness = Goodness::of(&baseline);
    // The fits in order, the last the current model: each held once (a fit holds its
    // residuals, rows × 3).
    let mut fits = vec![baseline];
    let no_fit = || DiscrepancyError::Fit(ModelError::Internal("no fit was kept"));
    let mut steps = Vec::new();
    let mut intrinsic_now = intrinsic_baseline.clone();
    let last_candidates = loop {
        let current = fits.last().ok_or_else(no_fit)?;
        let mut tests = Vec::new();
        let mut best: Option<(Criterion, Fit, Effect)> = None;
        for &e in candidates.iter().filter(|e| !current.effects.contains(e)) {
            let mut effects = current.effects.clone();
            effects.push(e);
            let Ok(with) = model::fit(&data, &effects, Some(&current.params)) else {
                continue;
            };
            let c = match &levels {
                Some(l) => slow_criterion(&data, l, (e, current, &with), n, alpha)?,
                None => criterion(e, current, &with, n, alpha),
            };
            if c.passed
                && best
                    .as_ref()
                    .is_none_or(|(b, _, _)| c.delta_bic > b.delta_bic)
            {
                best = Some((c.clone(), with, e));
            }
            tests.push(c);
        }
        let Some((c, with, e)) = best else {
            break tests;
        };
        let slow_unc = match &levels {
            Some(l) => Some(slow_uncertainty(&data, l, &with)?),
            None => None,
        };
        steps.push(Step {
            effect: e.name().to_string(),
            parameters: parameters(e, &with, &data, slow_unc.as_ref()),
            criterion: c,
            chi2_dof: with.chi2_dof(),
            rms_residual: with.rms_all(),
            candidates: tests,
            intrinsic_before: std::mem::take(&mut intrinsic_now),
            intrinsic_after: intrinsic_per_rate(&data, &with),
        });
        intrinsic_now = steps
            .last()
            .map(|s| s.intrinsic_after.clone())
            .unwrap_or_default();
        fits.push(with);
    };
    let current = fits.last().ok_or_else(no_fit)?;
    let slow_unc = match &levels {
        Some(l) => Some(slow_uncertainty(&data, l, current)?),
        None => None,
    };
    let final_parameters = current
        .effects
        .iter()
        .map(|&e| {
            let p = parameters(e, current, &data, slow_unc.as_ref());
            (e.name().to_string(), p)
        })
        .collect();
    let verdict = verdict::judge(&data, current, alpha, levels.as_ref());
    // Named effects in explained data are checked on the halves; in unexplained data they
    // stay candidates (each was named by a test that assumed the larger model right).
    let confirmation = if verdict.explained {
        confirm::check(&data, current, alpha, levels.as_ref())
    } else {
        Vec::new()
    };
    let confirmed_effects: Vec<Effect> = current
        .effects
        .iter()
        .copied()
        .filter(|e| {
            confirmation
                .iter()
                .any(|c| c.confirmed && c.effect == e.name())
        })
        .collect();
    let intrinsic_confirmed = if confirmed_effects.len() == current.effects.len() {
        intrinsic_now.clone()
    } else if confirmed_effects.is_empty() {
        intrinsic_baseline.clone()
    } else {
        let confirmed_fit = model::fit(&data, &confirmed_effects, Some(&current.params))?;
        intrinsic_per_rate(&data, &confirmed_fit)
    };
    Ok(Analysis {
        confirmed_effects: confirmed_effects
            .iter()
            .map(|e| e.name().to_string())
            .collect(),
        intrinsic_confirmed,
        confirmation,
        verdict,
        structure: data.generic.structure.clone(),
        final_parameters,
        alpha,
        intrinsic_baseline,
        intrinsic_final: intrinsic_now,
        noise_sigma: noise,
        noise_model: noise_model_json(&data),
        slow_noise: levels.as_ref().map(slow::SlowLevels::json),
        noise_sigma_stated: stated
            .filter(|s| *s > 0.0)
            .map(|s| check_statement(s, &data)),
        baseline: baseline_goodness,
        findings,
        named_effects: steps.iter().map(|s| s.effect.clone()).collect(),
        steps,
        final_: Goodness::of(current),
        last_candidates,
        untestable,
        fits,
        data,
    })
}

/// Read, prepare and analyse a recording.
pub fn run(rec: &Recording, opts: &Options) -> Result<Analysis, DiscrepancyError> {
    let (data, noise) = data_from(rec, opts)?;
    analyse(data, noise, rec.meta.noise_sigma, opts)
}
