//! The JSON that `rotacal calibrate --json OUT` writes: exactly the schema of
//! docs/formats.md (a contract with tests outside the project: keys may be
//! added, never renamed or removed).

use crate::calibrate::correction::Correction;
use crate::calibrate::methods::{RotationCalibration, StaticCalibration};
use crate::calibrate::poses::{self, OffsetEstimator, Weights};
use crate::recording::Method;
use rotacal_shared::intrinsic::Estimate;
use rotacal_shared::{Channel, Condition};
use serde::Serialize;

/// Coverage factor of every expanded uncertainty.
pub const K: f64 = 2.0;

/// `Q = {"value", "std_unc", "expanded_unc", "k"}`.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct Quantity {
    /// The value.
    pub value: f64,
    /// Standard uncertainty.
    pub std_unc: f64,
    /// Expanded uncertainty, k·std_unc.
    pub expanded_unc: f64,
    /// Coverage factor.
    pub k: f64,
}

impl From<Estimate> for Quantity {
    fn from(e: Estimate) -> Self {
        Quantity::with_k(e, K)
    }
}

/// Per channel.
#[derive(Clone, Debug, Serialize)]
pub struct Uvw {
    /// u
    pub u: Quantity,
    /// v
    pub v: Quantity,
    /// w
    pub w: Quantity,
}

/// Per channel pair.
#[derive(Clone, Debug, Serialize)]
pub struct Pairs {
    /// uv
    pub uv: Quantity,
    /// vw
    pub vw: Quantity,
    /// wu
    pub wu: Quantity,
}

impl Quantity {
    /// With coverage factor `k`.
    pub fn with_k(e: Estimate, k: f64) -> Self {
        Quantity {
            value: e.value,
            std_unc: e.std_unc,
            expanded_unc: k * e.std_unc,
            k,
        }
    }
}

fn uvw_k(e: [Estimate; 3], k: f64) -> Uvw {
    let [u, v, w] = e.map(|e| Quantity::with_k(e, k));
    Uvw { u, v, w }
}

fn pairs(e: [Estimate; 3]) -> Pairs {
    pairs_k(e, K)
}

fn pairs_k(e: [Estimate; 3], k: f64) -> Pairs {
    let [uv, vw, wu] = e.map(|e| Quantity::with_k(e, k));
    Pairs { uv, vw, wu }
}

/// `correction` (an extension of formats.md): how to turn readings into m/s².
#[derive(Clone, Debug, Serialize, serde::Deserialize, PartialEq)]
pub struct CorrectionJson {
    /// [`crate::calibrate::correction::CONVENTION`], in the file itself.
    pub convention: String,
    /// The readings' units.
    pub units_in: String,
    /// Always `m/s^2`.
    pub units_out: String,
    /// The device's orthonormal frame.
    pub device_frame: Correction,
    /// The platter frame (static data only).
    pub platter_frame: Option<Correction>,
    /// Coverage factor for 95 % intervals from the standard uncertainties here (and from
    /// `rotacal apply`'s `u_unc` columns): the calibration's.
    pub k: f64,
    /// Where the offsets come from.
    pub offset_source: String,
}

impl CorrectionJson {
    /// Both frames with the convention stated.
    pub fn new(
        units_in: &str,
        device: Correction,
        platter: Option<Correction>,
        k: f64,
        offset_source: &str,
    ) -> Self {
        CorrectionJson {
            convention: crate::calibrate::correction::CONVENTION.to_string(),
            units_in: units_in.to_string(),
            units_out: "m/s^2".to_string(),
            device_frame: device,
            platter_frame: platter,
            k,
            offset_source: offset_source.to_string(),
        }
    }
}

/// One pose in `poses.list`.
#[derive(Clone, Debug, Serialize)]
pub struct PoseJson {
    /// Name.
    pub name: String,
    /// ĝ in the platter frame.
    pub gravity: [f64; 3],
    /// Readings averaged.
    pub n: usize,
    /// Mean u, v, w.
    pub mean: [f64; 3],
    /// Standard deviation of the readings (how still); null for one reading.
    pub std: Option<[f64; 3]>,
    /// Standard error of the mean (under the readings' noise model where there is one).
    pub std_err: Option<[f64; 3]>,
    /// The readings' noise per channel (lag-1 autocorrelation, AR order, standard error,
    /// effective number of readings), with at least 100 readings; null for a channel whose
    /// model could not be made.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub noise: Option<[Option<crate::calibrate::poses::PoseNoise>; 3]>,
    /// Mean minus model.
    pub residual: [f64; 3],
    /// File line of its first reading; for stepped files, of its condition's first row
    /// (0: not from a file).
    pub first_line: u64,
}

/// `poses` (static only; an extension of formats.md): the fit of S and O to the poses.
#[derive(Clone, Debug, Serialize)]
pub struct PosesJson {
    /// `random-effects` or `equal`.
    pub weights: Weights,
    /// The offsets reported in `intrinsic.offset`: `joint` or `axis-pairs`.
    pub offset_estimator: OffsetEstimator,
    /// Poses − 4.
    pub dof: usize,
    /// Coverage factor of this entry's expanded uncertainties.
    pub k: f64,
    /// Degrees of freedom behind each channel's variance.
    pub nu: [f64; 3],
    /// Between-pose scatter per channel (output units): with a tilt model, the tilt's rms
    /// effect on the channel over the poses.
    pub tau: [f64; 3],
    /// How the scatter beyond the poses' noise was modelled: `{"model": "none"}`,
    /// `{"model": "tilt", "sd_deg": x}` or `{"model": "per-channel"}`.
    pub scatter: poses::Scatter,
    /// χ²/dof of the joint fit of the three channels (3P − 12 degrees of freedom) with
    /// the noise alone (no tilt estimated) or 1 (a tilt estimated); null when the channels
    /// were fitted alone.
    pub chi2_dof_joint: Option<f64>,
    /// χ²/dof of the pose means with their own noise only, per channel.
    pub chi2_dof_noise_only: [Option<f64>; 3],
    /// Condition number of the design (ĝ, 1).
    pub condition_number: f64,
    /// When poorly conditioned, the orientation to add.
    pub suggestion: Option<String>,
    /// Poses much less still than the median.
    pub not_still: Vec<String>,
    /// Offsets of the joint fit.
    pub offsets_joint: Uvw,
    /// imucal's estimator (up/down pair of each channel's own axis), when the six axis
    /// poses are there.
    pub offsets_axis_pairs: Option<Uvw>,
    /// joint − axis pairs: how far the real poses depart from the model.
    pub offsets_difference: Option<[f64; 3]>,
    /// The slow noise between the poses, when modelled (`--slow-noise`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub slow_noise: Option<PosesSlowJson>,
    /// The poses.
    pub list: Vec<PoseJson>,
}

fn poses_json(f: &poses::PoseFit) -> PosesJson {
    let finite = |x: f64| x.is_finite().then_some(x);
    PosesJson {
        weights: f.options.weights,
        offset_estimator: f.options.offsets,
        dof: f.dof,
        k: f.k,
        nu: f.channels.map(|c| c.nu),
        tau: f.channels.map(|c| c.tau),
        scatter: f.scatter,
        chi2_dof_joint: f.chi2_dof,
        chi2_dof_noise_only: f.channels.map(|c| finite(c.chi2_dof_noise_only)),
        condition_number: f.conditioning.condition_number,
        suggestion: f.conditioning.suggestion.clone(),
        not_still: f.not_still.clone(),
        offsets_joint: uvw_k(f.offsets_joint, f.k),
        offsets_axis_pairs: f.offsets_axis_pairs.map(|o| uvw_k(o, f.k)),
        offsets_difference: f
            .offsets_axis_pairs
            .map(|o| Channel::ALL.map(|ch| ch.of(&f.offsets_joint).value - ch.of(&o).value)),
        slow_noise: f.slow.as_ref().map(|s| {
            // Each channel's sensitivity: the norm of its row of S.
            let sens = f.s().map(|r| r.iter().map(|x| x * x).sum::<f64>().sqrt());
            poses_slow_json(s, sens)
        }),
        list: f
            .poses
            .iter()
            .zip(&f.residuals)
            .map(|(q, r)| PoseJson {
                name: q.name.clone(),
                gravity: q.gravity,
                n: q.n,
                mean: q.mean,
                std: q.std,
                std_err: q.std.map(|_| q.se()),
                noise: q.noise,
                residual: *r,
                first_line: q.first_line,
            })
            .collect(),
    }
}

/// `intrinsic`.
#[derive(Clone, Debug, Serialize)]
pub struct IntrinsicJson {
    /// Output units per m/s².
    pub sensitivity: Uvw,
    /// Degrees.
    pub angle_deg: Pairs,
    /// Static only.
    pub offset: Option<Uvw>,
}

/// Names of the six intrinsic properties, in [`IntrinsicJson::quantities`] order.
pub const PROPERTY_NAMES: [&str; 6] = ["s_u", "s_v", "s_w", "φ_uv", "φ_vw", "φ_wu"];

/// The six and the offsets, as static results give them.
pub const PROPERTY_NAMES_WITH_OFFSETS: [&str; 9] = [
    "s_u", "s_v", "s_w", "φ_uv", "φ_vw", "φ_wu", "O_u", "O_v", "O_w",
];

impl IntrinsicJson {
    /// s_u, s_v, s_w, φ_uv, φ_vw, φ_wu, then O_u, O_v, O_w when present.
    pub fn quantities(&self) -> Vec<&Quantity> {
        let (s, a) = (&self.sensitivity, &self.angle_deg);
        let mut q = vec![&s.u, &s.v, &s.w, &a.uv, &a.vw, &a.wu];
        if let Some(o) = &self.offset {
            q.extend([&o.u, &o.v, &o.w]);
        }
        q
    }
}

/// `sensitivity_matrix`.
#[derive(Clone, Debug, Serialize)]
pub struct MatrixJson {
    /// Output units per m/s².
    pub value: [[f64; 3]; 3],
    /// Standard uncertainties.
    pub std_unc: [[f64; 3]; 3],
}

/// One entry of `fits`.
#[derive(Clone, Serialize)]
pub struct FitJson {
    /// x, y or z.
    pub condition: Condition,
    /// u, v or w.
    pub channel: Channel,
    /// Coefficient of sin α.
    #[serde(rename = "A")]
    pub a: f64,
    /// Coefficient of cos α.
    #[serde(rename = "B")]
    pub b: f64,
    /// Offset.
    #[serde(rename = "C")]
    pub c: f64,
    /// Standard error of A.
    #[serde(rename = "se_A")]
    pub se_a: f64,
    /// Standard error of B.
    #[serde(rename = "se_B")]
    pub se_b: f64,
    /// Standard error of C.
    #[serde(rename = "se_C")]
    pub se_c: f64,
    /// Samples.
    pub n: u64,
    /// Residual RMS.
    pub rms_residual: f64,
    /// The rotation rate the fit used when it was estimated from the data (Hz).
    pub rate_hz_fitted: Option<f64>,
    /// The device's boots the condition was recorded in, joined by the fit (absent for
    /// one: docs/calibration.md, "A condition in several boots").
    #[serde(skip_serializing_if = "Option::is_none")]
    pub boots: Option<usize>,
}

// As derived, but `boots` only where the JSON has it: the statistical proofs' witnesses
// (bench/proofs) digest this text, and a condition in one boot is what it was.
impl std::fmt::Debug for FitJson {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("FitJson");
        d.field("condition", &self.condition)
            .field("channel", &self.channel)
            .field("a", &self.a)
            .field("b", &self.b)
            .field("c", &self.c)
            .field("se_a", &self.se_a)
            .field("se_b", &self.se_b)
            .field("se_c", &self.se_c)
            .field("n", &self.n)
            .field("rms_residual", &self.rms_residual)
            .field("rate_hz_fitted", &self.rate_hz_fitted);
        if let Some(b) = self.boots {
            d.field("boots", &b);
        }
        d.finish()
    }
}

/// One entry of `by_rate`.
#[derive(Clone, Debug, Serialize)]
pub struct RateJson {
    /// Nominal rate; null for static.
    pub rate_hz: Option<f64>,
    /// The result.
    pub intrinsic: IntrinsicJson,
    /// Gaitan & Geist (2022) eqs. 12–16 (rotation only).
    pub angle_deg_phase_method: Option<Pairs>,
    /// Static only.
    pub sensitivity_matrix: Option<MatrixJson>,
    /// Every (condition, channel) fit.
    pub fits: Vec<FitJson>,
    /// With `--monte-carlo N` only (an extension of formats.md): the GUM Supplement 1
    /// propagation of the same inputs, keyed s_u, s_v, s_w, phi_uv, phi_vw, phi_wu.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub monte_carlo:
        Option<std::collections::BTreeMap<String, crate::calibrate::methods::McSummary>>,
    /// An extension of formats.md: how to apply the calibration (`rotacal apply`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub correction: Option<CorrectionJson>,
    /// An extension of formats.md, static only: the poses and their fit.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub poses: Option<PosesJson>,
    /// An extension of formats.md, method free only: the still intervals and the fit.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub free: Option<FreeJson>,
    /// An extension of formats.md: the noise model of each condition and channel,
    /// estimated from the fit residuals (rotation).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub noise: Option<Vec<NoiseJson>>,
    /// An extension of formats.md: the GUM budget behind every uncertainty of `intrinsic`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub uncertainty_budget: Option<crate::calibrate::budget::Budget>,
}

/// One entry of `noise`: a channel's noise in one condition (docs/uncertainty.md).
#[derive(Clone, Debug, Serialize)]
pub struct NoiseJson {
    /// x, y or z.
    pub condition: Condition,
    /// u, v or w.
    pub channel: Channel,
    /// How it was estimated.
    pub model: String,
    /// Standard deviation of one sample's noise, output units.
    pub sd: f64,
    /// Standard deviation of the AR model's innovations, output units.
    pub innovation_sd: f64,
    /// AR coefficients φ₁ … φ_p (empty: white).
    pub ar: Vec<f64>,
    /// The model's lag-1 autocorrelation.
    pub lag1_autocorrelation: f64,
    /// How many times the variance of the sine amplitudes exceeds what white noise of the
    /// same level would give: 2πS(ω)/γ₀ at the rotation frequency.
    pub variance_factor: f64,
    /// Samples in the fit.
    pub n: usize,
    /// Samples left out of the noise estimate (at a rail).
    pub n_excluded: usize,
    /// Effective number of independent samples for the amplitudes: n / variance_factor.
    pub n_eff: f64,
    /// Degrees of freedom of the variance.
    pub dof: f64,
    /// Flicker and bias random walk, present when the residuals show either
    /// (docs/uncertainty.md, "Slow noise").
    #[serde(skip_serializing_if = "Option::is_none")]
    pub slow: Option<SlowJson>,
}

/// A channel's slow noise in one condition: flicker and a bias random walk beyond the AR
/// model, each with its standard uncertainty (parametric bootstrap), in output units and
/// in µg. The levels are pooled over the recording's groups held in memory.
#[derive(Clone, Debug, Serialize)]
pub struct SlowJson {
    /// The model and how it was estimated.
    pub model: String,
    /// The levels.
    #[serde(flatten)]
    pub terms: SlowTerms,
    /// Degrees of freedom of the channel's sine-amplitude variance under the whole model
    /// (Welch–Satterthwaite with the terms' covariances).
    pub dof_amplitude: f64,
    /// The residuals' overlapping Allan variance at each averaging length the levels were
    /// fitted over, beside the model's exact expectation for this group's fit.
    pub residual_allan: Vec<ResidualAllanJson>,
    /// The still recording pooled with the groups in the levels (`--noise-from`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub noise_from: Option<crate::calibrate::noise_from::StillSource>,
    /// The model against the data: the channel's whole-turn sine and cosine coefficients
    /// against the model's prediction, pooled over its groups; absent below two whole
    /// turns in every group.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub model_check: Option<ModelCheckJson>,
}

/// `model_check` of a channel (docs/uncertainty.md, "The model against the data, checked").
#[derive(Clone, Debug, Serialize)]
pub struct ModelCheckJson {
    /// Whole turns over the channel's groups.
    pub turns: usize,
    /// The coefficients' observed scatter over the model's expectation.
    pub ratio: f64,
    /// The scatter's degrees of freedom.
    pub dof: f64,
    /// The model's expectation's degrees of freedom (null: infinite).
    pub dof_model: Option<f64>,
    /// The probability of a ratio at least this large under the model.
    pub p_above: f64,
    /// The probability of a ratio at most this large under the model.
    pub p_below: f64,
    /// The level each side is tested at.
    pub alpha: f64,
    /// What was done.
    pub action: crate::fit::noise::Verdict,
    /// The factor the channel's noise terms were multiplied by (1 unless widened or
    /// narrowed).
    pub rescaled_by: f64,
}

/// One averaging length of `residual_allan`: Allan variances of the raw residuals, output
/// units².
#[derive(Clone, Debug, Serialize)]
pub struct ResidualAllanJson {
    /// τ, s.
    pub tau_s: f64,
    /// Rows averaged.
    pub m: usize,
    /// The residuals' own Allan variance.
    pub observed_avar: f64,
    /// The 1σ interval of the Allan deviation, output units (noise id, Greenhall EDF), where
    /// one can be given.
    pub observed_adev_interval: Option<[f64; 2]>,
    /// Its equivalent degrees of freedom.
    pub edf: Option<f64>,
    /// The model's expectation: the sum of the three terms below.
    pub expected_avar: f64,
    /// Of it, the AR (short-range) model's share through the fit.
    pub short_range_avar: f64,
    /// The flicker's share, at its signed level.
    pub flicker_avar: f64,
    /// The walk's share, at its signed level.
    pub walk_avar: f64,
}

/// One slow term: value and standard uncertainty, in output units and in µg (through the
/// channel's sensitivity at this rate; µg of standard gravity), squared for a variance.
#[derive(Clone, Debug, Serialize)]
pub struct SlowTerm {
    /// Output units (squared, per s or per √s as the key says).
    pub value: f64,
    /// Its standard uncertainty.
    pub u: f64,
    /// In µg (µg², µg²/s or µg/√s).
    pub value_ug: Option<f64>,
    /// Its standard uncertainty in the same unit.
    pub u_ug: Option<f64>,
}

/// A channel's flicker and walk levels as the JSON gives them.
#[derive(Clone, Debug, Serialize)]
pub struct SlowTerms {
    /// The flicker's Allan variance 2 ln 2·Q/π (the floor squared), output units²; signed:
    /// a record that cannot tell a level from zero gives an estimate of either sign.
    pub flicker_allan_variance: SlowTerm,
    /// The walk's K² = q·f_s (σ_A(τ)² = K²·τ/3), output units² per s; signed.
    pub random_walk_k2: SlowTerm,
    /// The flicker floor √(2 ln 2·Q/π), output units, when its estimate is positive.
    pub flicker_floor: Option<SlowTerm>,
    /// The walk K, output units per √s, when its estimate is positive.
    pub random_walk_per_sqrt_s: Option<SlowTerm>,
}

impl SlowTerms {
    /// From the levels (Q, q) per sample at `per_s` samples a second and their standard
    /// uncertainties; `sensitivity` is the channel's output units per m/s².
    pub fn new(levels: [f64; 2], u: [f64; 2], per_s: f64, sensitivity: Option<f64>) -> Self {
        let [q, w] = levels;
        let [u_q, u_w] = u;
        let per_ug = sensitivity
            .filter(|s| *s > 0.0)
            .map(|s| 1.0 / (s * crate::allan::MICRO_G));
        let linear = |value: f64, u: f64, power: i32| SlowTerm {
            value,
            u,
            value_ug: per_ug.map(|f| value * f.powi(power)),
            u_ug: per_ug.map(|f| u * f.powi(power)),
        };
        // The square root of a positive level c²θ: u = c·u_θ/(2√θ).
        let root = |theta: f64, u_theta: f64, c: f64| {
            (theta > 0.0).then(|| {
                let value = c * theta.sqrt();
                linear(value, c * u_theta / (2.0 * theta.sqrt()), 1)
            })
        };
        let floor2 = crate::allan::powerlaw::FLICKER_ALLAN_PLATEAU;
        SlowTerms {
            flicker_allan_variance: linear(floor2 * q, floor2 * u_q, 2),
            random_walk_k2: linear(w * per_s, u_w * per_s, 2),
            flicker_floor: root(q, u_q, floor2.sqrt()),
            random_walk_per_sqrt_s: root(w, u_w, per_s.sqrt()),
        }
    }
}

/// `poses.slow_noise` (`--slow-noise`, static records): each channel's flicker and walk
/// between the poses (docs/uncertainty.md, "Slow noise between poses").
#[derive(Clone, Debug, Serialize)]
pub struct PosesSlowJson {
    /// The model and how it was estimated.
    pub model: String,
    /// The readings' rate the levels are per sample at, Hz.
    pub rate_hz: f64,
    /// Per channel u, v, w.
    pub channels: Vec<PosesSlowChannel>,
}

/// One channel of `poses.slow_noise`.
#[derive(Clone, Debug, Serialize)]
pub struct PosesSlowChannel {
    /// `u`, `v` or `w`.
    pub channel: Channel,
    /// The levels.
    #[serde(flatten)]
    pub terms: SlowTerms,
    /// The correlation of the flicker and walk estimates.
    pub correlation: f64,
}

fn poses_slow_json(s: &poses::SlowPoses, sens: [f64; 3]) -> PosesSlowJson {
    PosesSlowJson {
        model: "white/AR (the readings' own noise) + flicker (Kasdin 1/f) + bias random walk \
                in session time; the levels from quadratic forms of the pose residuals with \
                their exact expectations, unbiased and signed; uncertainties from the forms' \
                Gaussian covariance"
            .into(),
        rate_hz: s.fs,
        channels: s
            .channels
            .iter()
            .zip(Channel::ALL)
            .map(|(c, ch)| {
                let cov = c.cov();
                let u = [cov[0][0], cov[1][1]].map(|v| v.max(0.0).sqrt());
                PosesSlowChannel {
                    channel: ch,
                    terms: SlowTerms::new(c.levels, u, s.fs, Some(*ch.of(&sens))),
                    correlation: cov[0][1] / (u[0] * u[1]).max(f64::MIN_POSITIVE),
                }
            })
            .collect(),
    }
}

impl SlowJson {
    /// From a group's slow noise; `sensitivity` is the channel's output units per m/s².
    pub fn new(s: &crate::calibrate::group::SlowNoise, sensitivity: Option<f64>) -> Self {
        let fit = &s.fit;
        let [_, q, w] = fit.theta;
        let sd = |i: usize| {
            fit.cov
                .get(i)
                .and_then(|r| r.get(i))
                .map_or(0.0, |v| v.max(0.0).sqrt())
        };
        let per_s = 1.0 / s.row_interval_s.max(f64::MIN_POSITIVE);
        let terms = SlowTerms::new([q, w], [sd(1), sd(2)], per_s, sensitivity);
        SlowJson {
            model: "white/AR + flicker (Kasdin 1/f) + bias random walk; the levels fitted to \
                    the residuals' overlapping Allan variances beyond the short-range \
                    correlation, with their exact expectations for the fit, pooled over \
                    the groups; uncertainties by parametric bootstrap"
                .into(),
            terms,
            dof_amplitude: s.amplitude_dof(),
            residual_allan: s
                .allan
                .iter()
                .map(|a| ResidualAllanJson {
                    tau_s: a.m as f64 * s.row_interval_s,
                    m: a.m,
                    observed_avar: a.observed,
                    observed_adev_interval: a.interval.map(|i| [i.lo, i.hi]),
                    edf: a.interval.map(|i| i.edf),
                    expected_avar: a.expected(),
                    short_range_avar: a.short_range,
                    flicker_avar: a.flicker,
                    walk_avar: a.walk,
                })
                .collect(),
            noise_from: s.still.clone(),
            model_check: s.check.map(|c| ModelCheckJson {
                turns: c.periods,
                ratio: c.ratio,
                dof: c.dof,
                dof_model: c.dof_model.is_finite().then_some(c.dof_model),
                p_above: c.p_above,
                p_below: c.p_below,
                alpha: crate::fit::noise::MODEL_CHECK_ALPHA,
                action: c.verdict(),
                rescaled_by: c.factor(),
            }),
        }
    }
}

impl NoiseJson {
    /// From a model; `omega` is the rotation's angle per sample (rad).
    pub fn new(
        condition: Condition,
        channel: Channel,
        m: &crate::fit::noise::NoiseModel,
        omega: f64,
    ) -> Self {
        NoiseJson {
            condition,
            channel,
            model: format!(
                "AR({}) by Yule–Walker on the fit residuals, order by BIC (≤ {})",
                m.order(),
                crate::fit::noise::MAX_ORDER
            ),
            sd: m.sd(),
            innovation_sd: m.innovation_var.sqrt(),
            ar: m.ar.clone(),
            lag1_autocorrelation: m.autocorrelation(1),
            variance_factor: m.variance_factor(omega),
            n: m.n,
            n_excluded: m.excluded,
            n_eff: m.n_eff(omega),
            dof: m.dof(3),
            slow: None,
        }
    }
}

/// Keys of the Monte Carlo summaries, in output order.
pub const MC_KEYS: [&str; 6] = ["s_u", "s_v", "s_w", "phi_uv", "phi_vw", "phi_wu"];

/// The `monte_carlo` map from the six summaries.
pub fn mc_map(
    s: [crate::calibrate::methods::McSummary; 6],
) -> std::collections::BTreeMap<String, crate::calibrate::methods::McSummary> {
    MC_KEYS.iter().map(|k| k.to_string()).zip(s).collect()
}

/// The whole file.
#[derive(Clone, Debug, Serialize)]
pub struct CalibrationJson {
    /// "rotation", "static" or "free".
    pub method: Method,
    /// m/s².
    pub g_loc: f64,
    /// Output units.
    pub units: String,
    /// One entry per nominal rate (static: one, rate null).
    pub by_rate: Vec<RateJson>,
    /// An extension of formats.md, rotation only: structure in the fits' residuals that no
    /// noise model should take in (docs/uncertainty.md, "Structure beyond the noise").
    #[serde(skip_serializing_if = "Option::is_none")]
    pub residual_structure: Option<StructureCheckJson>,
}

/// `residual_structure`: the check of every group's widened-fit residuals for a harmonic
/// of the table angle above the fourth or a step in the level.
#[derive(Clone, Debug, Serialize)]
pub struct StructureCheckJson {
    /// Whether anything was found: the calibration's uncertainties then rest on a noise
    /// model that has taken in structure, and the terminal warns.
    pub found: bool,
    /// The chance that noise alone reports something, per kind of test, over the file.
    pub alpha: f64,
    /// Groups scanned (held in memory).
    pub groups_scanned: usize,
    /// Groups calibrated from a streamed file's sums, whose residuals were not held.
    pub groups_not_scanned: usize,
    /// Whether steps were tested against the flicker and walk levels (`--slow-noise`).
    pub slow_noise: bool,
    /// What was found.
    pub structure: Vec<StructureJson>,
}

/// One entry of `residual_structure.structure`.
#[derive(Clone, Debug, Serialize)]
pub struct StructureJson {
    /// The group's nominal rate, Hz.
    pub rate_hz: f64,
    /// x, y or z.
    pub condition: Condition,
    /// u, v or w.
    pub channel: Channel,
    /// "harmonic" or "step".
    pub kind: &'static str,
    /// Which harmonic of the table angle (harmonics only).
    pub harmonic: Option<usize>,
    /// The step's time from the group's first row, s (steps only).
    pub at_s: Option<f64>,
    /// The harmonic's amplitude or the step's height, output units.
    pub size: f64,
    /// Size over its standard error under the noise around it.
    pub z: f64,
    /// The chance that noise alone shows something as large among the file's tests of
    /// its kind (Bonferroni).
    pub p_value: f64,
}

/// Property `i` of a budget as a [`Quantity`] with `value` and its combined uncertainty
/// (none when the budget has no line `i`).
fn budget_quantity(b: &crate::calibrate::budget::Budget, i: usize, value: f64) -> Option<Quantity> {
    b.combined.get(i).map(|c| Quantity {
        value,
        std_unc: c.std_unc,
        expanded_unc: c.expanded_unc,
        k: c.k,
    })
}

/// `intrinsic`: the values, each with the uncertainty of its combined line in the budget
/// (in the order s_u … φ_wu, then the offsets); none when the budget lacks one of them.
fn intrinsic_json(
    i: &rotacal_shared::intrinsic::Intrinsic,
    offsets: Option<&[Estimate; 3]>,
    budget: &crate::calibrate::budget::Budget,
) -> Option<IntrinsicJson> {
    let q = |k: usize, e: &Estimate| budget_quantity(budget, k, e.value);
    let uvw = |[u, v, w]: &[Estimate; 3], at: usize| -> Option<Uvw> {
        Some(Uvw {
            u: q(at, u)?,
            v: q(at + 1, v)?,
            w: q(at + 2, w)?,
        })
    };
    let [uv, vw, wu] = &i.angle_deg;
    Some(IntrinsicJson {
        sensitivity: uvw(&i.sensitivity, 0)?,
        angle_deg: Pairs {
            uv: q(3, uv)?,
            vw: q(4, vw)?,
            wu: q(5, wu)?,
        },
        offset: match offsets {
            Some(o) => Some(uvw(o, 6)?),
            None => None,
        },
    })
}

/// The `by_rate` entry of a rotation calibration: the values, with the uncertainties of
/// the budget (none when the budget lacks a property).
pub fn rotation_entry(
    rate_hz: f64,
    cal: &RotationCalibration,
    budget: &crate::calibrate::budget::Budget,
    fits: Vec<FitJson>,
) -> Option<RateJson> {
    Some(RateJson {
        rate_hz: Some(rate_hz),
        intrinsic: intrinsic_json(&cal.intrinsic, None, budget)?,
        angle_deg_phase_method: Some(pairs(cal.phase_angles_deg)),
        sensitivity_matrix: None,
        fits,
        monte_carlo: None,
        correction: None,
        poses: None,
        free: None,
        noise: None,
        uncertainty_budget: None,
    })
}

/// The `by_rate` entry of a static calibration: the values, with the uncertainties of the
/// budget (properties s_u … φ_wu, O_u, O_v, O_w; none when the budget lacks one).
pub fn static_entry(
    cal: &StaticCalibration,
    budget: &crate::calibrate::budget::Budget,
) -> Option<RateJson> {
    let mut fits = Vec::new();
    for (condition, per_ch) in Condition::ALL.into_iter().zip(cal.fits.iter().flatten()) {
        for (channel, f) in Channel::ALL.into_iter().zip(per_ch) {
            fits.push(FitJson {
                condition,
                channel,
                a: f.coef[0],
                b: f.coef[1],
                c: f.coef[2],
                se_a: f.se[0],
                se_b: f.se[1],
                se_c: f.se[2],
                n: f.n as u64,
                rms_residual: f.rms_residual,
                rate_hz_fitted: None,
                boots: None,
            });
        }
    }
    Some(RateJson {
        rate_hz: None,
        intrinsic: intrinsic_json(&cal.intrinsic, Some(&cal.offsets), budget)?,
        angle_deg_phase_method: None,
        sensitivity_matrix: Some(MatrixJson {
            value: cal.s,
            std_unc: cal.s_std,
        }),
        fits,
        monte_carlo: None,
        correction: None,
        poses: Some(poses_json(&cal.pose_fit)),
        free: None,
        noise: None,
        uncertainty_budget: None,
    })
}

/// One candidate interval in `free.detection[].intervals`.
#[derive(Clone, Debug, Serialize)]
pub struct IntervalJson {
    /// The interval, with its verdict.
    #[serde(flatten)]
    pub interval: crate::calibrate::still::Interval,
    /// The verdict in a sentence.
    pub reason: String,
}

/// One segment's detection in `free.detection`.
#[derive(Clone, Debug, Serialize)]
pub struct DetectionJson {
    /// Which rows: empty for a whole free recording, else `condition x` (and its rate).
    pub segment: String,
    /// The detection's settings and noise (null when the poses were named in the file).
    pub found: Option<crate::calibrate::still::Detection>,
    /// Every candidate interval.
    pub intervals: Vec<IntervalJson>,
}

/// `free` (method free only; an extension of formats.md).
#[derive(Clone, Debug, Serialize)]
pub struct FreeJson {
    /// The residual minimised.
    pub residual: crate::calibrate::free::Residual,
    /// Per segment, the still intervals found.
    pub detection: Vec<DetectionJson>,
    /// The poses fitted: fitted ĝ in the device frame and |a| − g.
    pub poses: Vec<crate::calibrate::free::PoseResult>,
    /// χ² of the poses with their noise alone, and its degrees of freedom P − 9.
    pub chi2: f64,
    /// P − 9.
    pub dof: usize,
    /// Scatter beyond the noise per pose, m/s² (0: none needed).
    pub tau_ms2: f64,
    /// With `--slow-noise`: the scatter measured in every fit, τ² signed, m²/s⁴ (and µg²),
    /// with its standard uncertainty (absent otherwise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tau2_measured: Option<SlowTerm>,
    /// Degrees of freedom of the fit's covariance (null: infinite).
    pub nu: Option<f64>,
    /// Condition number of the unit design.
    pub condition_number: f64,
    /// When flagged, the directions to add.
    pub suggestion: Option<String>,
}

/// The `by_rate` entry of a free calibration (properties s_u … φ_wu, O_u, O_v, O_w; none
/// when the budget lacks one).
pub fn free_entry(
    intr: &rotacal_shared::intrinsic::Intrinsic,
    offsets: &[Estimate; 3],
    budget: &crate::calibrate::budget::Budget,
    fit: &crate::calibrate::free::FreeFit,
    detections: &[(
        String,
        Option<crate::calibrate::still::Detection>,
        Vec<crate::calibrate::still::Interval>,
    )],
) -> Option<RateJson> {
    let detection = detections
        .iter()
        .map(|(label, d, iv)| {
            let min = d.as_ref().map_or(0.0, |d| d.options.min_still_s);
            DetectionJson {
                segment: label.clone(),
                found: d.as_ref().map(|d| crate::calibrate::still::Detection {
                    intervals: Vec::new(),
                    ..d.clone()
                }),
                intervals: iv
                    .iter()
                    .map(|i| IntervalJson {
                        interval: i.clone(),
                        reason: i.verdict.reason(min),
                    })
                    .collect(),
            }
        })
        .collect();
    Some(RateJson {
        rate_hz: None,
        intrinsic: intrinsic_json(intr, Some(offsets), budget)?,
        angle_deg_phase_method: None,
        sensitivity_matrix: None,
        fits: Vec::new(),
        monte_carlo: None,
        correction: None,
        poses: None,
        free: Some(FreeJson {
            residual: fit.residual,
            detection,
            poses: fit.poses.clone(),
            chi2: fit.chi2,
            dof: fit.dof,
            tau_ms2: fit.tau_ms2,
            tau2_measured: fit.tau2_measured.map(|(value, var)| {
                // µg of standard gravity, squared.
                let per_ug2 = crate::allan::MICRO_G.powi(-2);
                let u = var.max(0.0).sqrt();
                SlowTerm {
                    value,
                    u,
                    value_ug: Some(value * per_ug2),
                    u_ug: Some(u * per_ug2),
                }
            }),
            nu: fit.nu.is_finite().then_some(fit.nu),
            condition_number: fit.condition_number,
            suggestion: fit.suggestion.clone(),
        }),
        noise: None,
        uncertainty_budget: None,
    })
}
