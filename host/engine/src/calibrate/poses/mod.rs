//! Static calibration from any known orientations: one least-squares fit of the
//! sensitivity matrix S and the offsets O to `y = g·S·ĝ + O` (docs/method.md §1, §3).
//!
//! The stepped method (Gaitan et al. (2021): ĝ from the condition and the table angle) and the
//! six-position method (AN4399, Ferraris et al.) are special cases: only the list of
//! poses differs. Readings repeated at one orientation are averaged into a pose mean with
//! its standard error (how still the device was). Each channel j is then fitted to the pose
//! means by weighted least squares with the weights 1/(se_p² + τ_j²): τ_j is the scatter
//! of the poses about the model beyond their own noise (a pose placed a little off its
//! nominal direction, say), estimated so that χ²/dof = 1 (Paule–Mandel), or 0 when the
//! poses agree within their noise. With one reading per pose this is ordinary least
//! squares with σ̂² = RSS/(P − 4). The expanded uncertainty uses Student's t for the
//! degrees of freedom behind the variance: P − 4 when τ > 0, else those of the pose noise.
//!
//! Here the fit's types, its result and the index of each parameter; `gather` makes the
//! poses from the readings, `fit` fits them (each channel alone, then jointly where it
//! can), `tilt` is the joint fit with the pose-tilt random effect, and `weigh` holds the
//! covariance's parts and how they weigh into one quantity's variance.
// Not yet free of unchecked indexing (docs/architecture.md, "Not yet").
#![allow(clippy::indexing_slicing)]

mod fit;
mod gather;
mod serial;
mod slow;
mod tilt;
mod weigh;

pub use fit::fit;
pub(crate) use fit::weakest;
pub use gather::{direction_name, poses_from_conditions, poses_from_oriented};
pub use serial::{Serial, Z_ALARM};
pub use slow::{SlowChannel, SlowPoses, SlowPosesError, SLOW_MIN_POSES};
pub use weigh::Weighing;

use crate::calibrate::budget::coverage_factor;
use fit::axis_pair_var;
use nalgebra::{Matrix3, SMatrix, SVector};
use rotacal_shared::intrinsic::Estimate;
use rotacal_shared::{Channel, Condition};

/// One condition of a static (stepped-angle) record.
#[derive(Clone, Copy, Debug)]
pub struct StaticCondition<'a> {
    /// The platter axis turned about.
    pub condition: Condition,
    /// Table angle of each row, degrees.
    pub angle_deg: &'a [f64],
    /// Readings u, v, w of each row.
    pub y: [&'a [f64]; 3],
    /// Session time of each row, s (empty when the record has none): the slow noise
    /// between poses is a function of it.
    pub t_s: &'a [f64],
    /// 1-based file line of the first row (0: not from a file).
    pub first_line: u64,
}

/// The readings at one orientation.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Pose {
    /// Its name: the `pose` column, else the direction (or condition and angle).
    pub name: String,
    /// ĝ, the direction of gravity's reading in the platter frame.
    pub gravity: [f64; 3],
    /// Readings averaged.
    pub n: usize,
    /// Mean reading u, v, w (output units).
    pub mean: [f64; 3],
    /// Sample standard deviation of the readings (output units): how still the device
    /// was. `None` for a single reading.
    pub std: Option<[f64; 3]>,
    /// 1-based file line of its first reading (stepped files: of its condition's first
    /// row; 0: not from a file).
    pub first_line: u64,
    /// The readings' noise per channel, estimated from them (at least
    /// [`NOISE_MODEL_MIN`] readings) or pooled over the file's shorter poses (2 readings or
    /// more): successive readings of a filtering sensor are correlated, and the mean's
    /// standard error is then not std/√n.
    pub noise: Option<[Option<PoseNoise>; 3]>,
    /// ∂ĝ/∂α, the direction ĝ moves in when the table angle α is off (stepped records;
    /// `None` for poses whose orientation is given directly).
    pub angle_direction: Option<[f64; 3]>,
    /// Session time of each reading, s (empty when the record has none).
    #[serde(skip)]
    pub times_s: Vec<f64>,
}

/// One channel's noise at one pose, from an AR model of its readings about their mean
/// ([`crate::fit::noise`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct PoseNoise {
    /// Lag-1 autocorrelation of the model.
    pub lag1: f64,
    /// AR order.
    pub order: usize,
    /// Standard error of the mean under the model.
    pub se: f64,
    /// Effective number of independent readings: the model's variance of one reading over
    /// the mean's (close to std²/se²).
    pub n_eff: f64,
    /// Degrees of freedom of se²: n − 1 for a pose's own model; for a pooled model, from
    /// the jackknife of its mean variance over the poses it was pooled from (at most their
    /// Σ(n − 1)).
    pub dof: f64,
    /// How much se² grows per unit level of flicker and of a bias random walk within the
    /// pose (output units² per unit level, the levels of [`SlowPoses`]): the model
    /// takes their share of the readings' autocovariances as its own, and slow noise
    /// between poses must not be counted twice (docs/uncertainty.md, "Slow noise between
    /// poses"). Zeros where it could not be computed.
    #[serde(skip)]
    pub slow_slope: [f64; 2],
}

pub use super::NOISE_MODEL_MIN;

impl Pose {
    /// Standard error of the mean, per channel: under the readings' noise model where
    /// there is one, else std/√n (0 for a single reading: unknown).
    pub fn se(&self) -> [f64; 3] {
        let white = self
            .std
            .map(|s| s.map(|x| x / (self.n as f64).sqrt()))
            .unwrap_or([0.0; 3]);
        match &self.noise {
            Some(m) => Channel::ALL.map(|j| j.of(m).as_ref().map_or(*j.of(&white), |c| c.se)),
            None => white,
        }
    }
}

/// How to weight the pose means.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Weights {
    /// 1/(se² + τ²) with τ estimated (the default).
    #[default]
    RandomEffects,
    /// Every pose equally (ordinary least squares on the means, as imucal and most
    /// six-position tools do), variance from the residuals.
    Equal,
}

/// Which offsets to report as the result.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum OffsetEstimator {
    /// O_j from the joint fit of all poses (the default).
    #[default]
    Joint,
    /// imucal's (Ferraris et al.): O_j = (ȳ_j(+j) + ȳ_j(−j))/2 from the up/down pair of
    /// channel j's own axis only.
    AxisPairs,
}

/// Choices of the fit.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Options {
    /// Pose weighting.
    pub weights: Weights,
    /// Offset estimator.
    pub offsets: OffsetEstimator,
    /// Standard uncertainty of each table angle, rad (type B, `--u-angle-deg`): stepped
    /// records only.
    pub u_angle_rad: Option<f64>,
    /// Model flicker and a bias random walk between the poses (`--slow-noise`): records
    /// with reading times, repeated readings at every pose and the default weights and
    /// offsets.
    pub slow: bool,
}

/// How the scatter of the pose means beyond their own noise is modelled.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
#[serde(rename_all = "kebab-case", tag = "model")]
pub enum Scatter {
    /// None: the poses agree with the model within their noise (and any stated angle
    /// uncertainty).
    None,
    /// Each pose is tilted off its nominal direction by a random small rotation, normal
    /// with standard deviation `sd_deg` about each axis. It moves channel j by
    /// g·S_j·(t × ĝ): much where gravity lies across S_j, little along it, and the same
    /// tilt moves all three channels. One variance for every pose and channel, estimated
    /// so that the joint χ² equals its 3P − 12 degrees of freedom (Paule–Mandel). With
    /// [`Scatter::None`] too, the pose fit's covariance is scaled to the joint χ²/dof.
    Tilt {
        /// Per axis, degrees.
        sd_deg: f64,
    },
    /// A variance τ_j² per channel, added to each pose mean's own (single readings, equal
    /// weights, or scatter that no tilt explains).
    PerChannel,
    /// Flicker and a bias random walk in session time (`--slow-noise`, [`SlowPoses`]):
    /// the pose means err alike by how close in time they were read.
    Slow,
}

impl std::fmt::Display for Scatter {
    /// What the terminal and the report say of it.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Scatter::None => f.write_str("no scatter beyond the noise"),
            Scatter::Tilt { sd_deg } => {
                write!(f, "each pose tilted by {sd_deg:.2e}° per axis (estimated)")
            }
            Scatter::PerChannel => f.write_str("between-pose scatter"),
            Scatter::Slow => f.write_str("slow noise between poses (flicker, random walk)"),
        }
    }
}

/// Where one part of the covariance of (S, O) comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum PartSource {
    /// The readings' noise within each pose (type A, with the degrees of freedom of the
    /// poses' noise models: Σ(n − 1), a pooled model's from its jackknife).
    PoseNoise,
    /// The poses' tilt ([`Scatter::Tilt`]; type A, 3P − 12 degrees of freedom).
    PoseTilt,
    /// The stated uncertainty of each table angle (type B).
    TableAngle,
    /// Channel j's own fit, its variance from its scatter ([`Scatter::PerChannel`] or
    /// equal weights; type A).
    Channel(usize),
    /// Channel j's slow noise between poses ([`Scatter::Slow`]; type A, its degrees of
    /// freedom from the levels' covariance).
    Slow(usize),
}

/// One part of the covariance of (S, O): the parts are independent and add up to it.
#[derive(Clone, Debug, PartialEq)]
pub struct CovPart {
    /// Its source.
    pub source: PartSource,
    /// Its covariance of (S row-major, O).
    pub theta: Cov12,
    /// Its covariance of each pose mean (u, v, w).
    pub pose_cov: Vec<Matrix3<f64>>,
    /// Its degrees of freedom (infinite for type B).
    pub nu: f64,
}

/// A covariance of (S row-major, O): twelve parameters.
pub type Cov12 = SMatrix<f64, 12, 12>;
type Theta = SVector<f64, 12>;
/// One pose's rows of the joint design (u, v, w against (S row-major, O)).
type Design = SMatrix<f64, 3, 12>;

/// The largest tilt (standard deviation per axis, rad) the tilt model accepts: beyond it
/// the poses' directions are not "known", and the scatter is taken per channel.
pub const TILT_MAX_RAD: f64 = 0.1;

/// Why the poses cannot be fitted.
#[derive(Clone, Debug, thiserror::Error, PartialEq)]
pub enum PoseError {
    /// Fewer than four distinct orientations, or all in one plane or cone.
    #[error(
        "the poses leave S and O under-determined ({poses} pose(s), condition number {cond:.3e}): \
         add a pose with gravity along {missing}"
    )]
    UnderDetermined {
        /// Distinct poses.
        poses: usize,
        /// Condition number of the design (∞ when rank-deficient).
        cond: f64,
        /// The orientation that would help most.
        missing: String,
    },
    /// Exactly determined and single readings: no uncertainty can be given.
    #[error(
        "{0} poses of one reading each determine S and O exactly, which leaves nothing to estimate \
         the uncertainty from: add a pose, or repeat the readings at each pose"
    )]
    NoUncertainty(usize),
    /// A pose name used for two directions.
    #[error("pose '{name}' has a different gravity direction than on line {first}")]
    PoseDirection {
        /// The pose.
        name: String,
        /// Where it first appeared.
        first: u64,
        /// The conflicting line.
        line: u64,
    },
    /// imucal's offsets need the six axis poses.
    #[error(
        "the axis-pairs offset estimator needs exactly one pose with gravity along {0}; \
         the poses have {1}"
    )]
    AxisPose(String, usize),
}

/// The design's conditioning.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Conditioning {
    /// Condition number of the unit design rows (ĝ, 1): 1.73 for the six axis poses.
    pub condition_number: f64,
    /// Above [`WELL_CONDITIONED`], the orientation whose addition helps most.
    pub suggestion: Option<String>,
}

/// Condition numbers up to this are not flagged (six axis poses: √3).
pub const WELL_CONDITIONED: f64 = 10.0;
/// Beyond this the design is treated as rank-deficient.
const SINGULAR: f64 = 1e8;
/// A pose whose standard deviation exceeds this multiple of the median pose's, in any
/// channel, is flagged as not still.
pub const NOT_STILL_FACTOR: f64 = 3.0;

/// The fit of one channel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChannelFit {
    /// S_jx, S_jy, S_jz, O_j.
    pub coef: [f64; 4],
    /// Their covariance.
    pub cov: [[f64; 4]; 4],
    /// Between-pose scatter τ_j (output units).
    pub tau: f64,
    /// χ²/dof of the pose means with their own standard errors only (τ = 0): much above
    /// 1, the poses depart from the model by more than their noise. NaN when undefined.
    pub chi2_dof_noise_only: f64,
    /// Degrees of freedom behind the variance.
    pub nu: f64,
    /// Equal weights: the variance of one pose mean, from the residuals (noise and scatter
    /// together). `None` for random-effects weights (then it is se_p² + τ²).
    pub pose_var: Option<f64>,
}

/// The result.
#[derive(Clone, Debug)]
pub struct PoseFit {
    /// The poses, in order of first appearance.
    pub poses: Vec<Pose>,
    /// Per channel u, v, w.
    pub channels: [ChannelFit; 3],
    /// P − 4.
    pub dof: usize,
    /// Coverage factor for 95 %: Student's t at the smallest ν of the channels (2 when the
    /// degrees of freedom are many).
    pub k: f64,
    /// Pose mean minus the fitted model, per pose and channel (output units).
    pub residuals: Vec<[f64; 3]>,
    /// Per channel, the lag-1 correlation of its residuals in the order the poses were
    /// read, against independent poses (`None` with too few poses).
    pub serial: [Option<Serial>; 3],
    /// Conditioning of the design.
    pub conditioning: Conditioning,
    /// Offsets of the joint fit.
    pub offsets_joint: [Estimate; 3],
    /// imucal's offsets, when the six axis poses are present.
    pub offsets_axis_pairs: Option<[Estimate; 3]>,
    /// The options used.
    pub options: Options,
    /// Poses whose scatter exceeds [`NOT_STILL_FACTOR`] times the median.
    pub not_still: Vec<String>,
    /// Covariance of (S row-major, O), the sum of `parts`.
    pub cov: Cov12,
    /// Its independent parts, each with its source and degrees of freedom.
    pub parts: Vec<CovPart>,
    /// How the scatter beyond the pose noise was modelled.
    pub scatter: Scatter,
    /// χ²/dof of the joint fit (3P − 12 degrees of freedom) with the tilt estimated: the
    /// factor its covariance was scaled by (1 with a tilt). `None` when the channels were
    /// fitted alone or there are no degrees of freedom.
    pub chi2_dof: Option<f64>,
    /// The ±x, ±y, ±z poses behind imucal's offsets, when there is exactly one of each.
    pub axis_poses: Option<[[usize; 2]; 3]>,
    /// What the fit did that its user should know, each in a sentence.
    pub notes: Vec<String>,
    /// The joint fit's view of a tilt, behind each quantity's variance and degrees of
    /// freedom ([`Weighing`]); `None` when the channels were fitted alone or
    /// there are no degrees of freedom.
    pub tilt_scale: Option<TiltScale>,
    /// The slow noise between poses, when modelled ([`Scatter::Slow`]).
    pub slow: Option<SlowPoses>,
}

/// How visible a tilt is in each quantity and in the joint fit's χ².
#[derive(Clone, Debug, PartialEq)]
pub struct TiltScale {
    /// The covariance a tilt variance of 1 rad² would give (at the noise-only weights).
    pub unit: CovPart,
    /// How much that tilt variance raises E[χ²]/dof, per rad².
    pub chi2_per_dof_per_rad2: f64,
    /// χ²/dof at the noise-only weights when no tilt was estimated (below 1), else 1.
    pub q: f64,
}

impl PoseFit {
    /// S (rows u, v, w; columns platter x, y, z), output units per m/s².
    pub fn s(&self) -> [[f64; 3]; 3] {
        self.channels.map(|c| [c.coef[0], c.coef[1], c.coef[2]])
    }

    /// Covariance of the nine elements of S (row-major).
    pub fn s_cov(&self) -> [[f64; 9]; 9] {
        s_block(&self.cov)
    }

    /// One part's variance of each offset of the chosen estimator. Signed, as the parts of
    /// S are: a slow part at signed levels, or how a part moves with the levels, may be
    /// negative where the sum of the parts is not.
    pub fn offset_var(&self, part: &CovPart) -> [f64; 3] {
        match (self.options.offsets, self.axis_poses) {
            (OffsetEstimator::AxisPairs, Some(ix)) => [0, 1, 2].map(|j| axis_pair_var(part, ix, j)),
            _ => {
                // The offsets O_u, O_v, O_w are the last three of (S row-major, O).
                let [.., u, v, w]: [f64; 12] = part.theta.diagonal().into();
                [u, v, w]
            }
        }
    }

    /// Standard uncertainties of S.
    pub fn s_std(&self) -> [[f64; 3]; 3] {
        let w = self.weighing();
        [0, 1, 2].map(|j| {
            [0, 1, 2].map(|k| {
                let i = s_index(j, k);
                w.total(|c| c.theta[(i, i)]).0.max(0.0).sqrt()
            })
        })
    }

    /// Coverage factor of each element of (S row-major, O): Student's t at its degrees of
    /// freedom ([`Weighing`]).
    pub fn k_theta(&self) -> [f64; 12] {
        let w = self.weighing();
        std::array::from_fn(|i| coverage_factor(w.total(|c| c.theta[(i, i)]).1))
    }

    /// The covariance of (S row-major, O) with each element's variance as the
    /// [`Weighing`] gives it (what the JSON reports for S and the joint offsets) and the
    /// fit's correlations: D·C·D, D = diag(√(var_i / C_ii)). The weighing mixes the noise
    /// and the poses' scatter per quantity, which no single matrix does for every linear
    /// combination; this one agrees with every reported u and stays positive semidefinite.
    /// Without it the correction's u(O) was the noise's alone: at χ²/dof = 0.2 on six poses,
    /// half the offsets' reported u (issue 34).
    pub fn cov_weighed(&self) -> Cov12 {
        let w = self.weighing();
        // Each element's variance as reported, where it and the fit's are positive.
        let reported: [Option<f64>; 12] = std::array::from_fn(|i| {
            let v = w.total(|p| p.theta[(i, i)]).0;
            (self.cov[(i, i)] > 0.0 && v > 0.0).then_some(v)
        });
        let scale = std::array::from_fn::<f64, 12, _>(|i| {
            reported[i].map_or(1.0, |v| (v / self.cov[(i, i)]).sqrt())
        });
        let d = Cov12::from_diagonal(&nalgebra::SVector::<f64, 12>::from(scale));
        let mut c = d * self.cov * d;
        // The variances themselves, not their rescaled rounding: u(O) is then the
        // offsets' reported u to the last bit.
        for (i, v) in reported.iter().enumerate() {
            if let Some(v) = v {
                c[(i, i)] = *v;
            }
        }
        c
    }

    /// How the parts of the covariance combine into one quantity's variance.
    pub fn weighing(&self) -> Weighing<'_> {
        Weighing {
            parts: &self.parts,
            tilt: self.tilt_scale.as_ref(),
            slow: self.slow.as_ref(),
        }
    }

    /// The offsets of the chosen estimator.
    pub fn offsets(&self) -> [Estimate; 3] {
        match (self.options.offsets, self.offsets_axis_pairs) {
            (OffsetEstimator::AxisPairs, Some(o)) => o,
            _ => self.offsets_joint,
        }
    }
}

/// The S block of a covariance of (S, O), as an array.
pub fn s_block(c: &Cov12) -> [[f64; 9]; 9] {
    std::array::from_fn(|a| std::array::from_fn(|b| c[(a, b)]))
}

/// Index of S_jk in (S row-major, O).
const fn s_index(j: usize, k: usize) -> usize {
    3 * j + k
}

/// Index of O_j in (S row-major, O).
const fn o_index(j: usize) -> usize {
    9 + j
}

/// (S row-major, O) from each channel's coefficients (S_j0, S_j1, S_j2, O_j).
fn join_coefs(channels: [[f64; 4]; 3]) -> [f64; 12] {
    let [[s0, s1, s2, o0], [s3, s4, s5, o1], [s6, s7, s8, o2]] = channels;
    [s0, s1, s2, s3, s4, s5, s6, s7, s8, o0, o1, o2]
}

/// Each channel's coefficients (S_j0, S_j1, S_j2, O_j) from (S row-major, O).
fn split_coefs(theta: [f64; 12]) -> [[f64; 4]; 3] {
    let [s0, s1, s2, s3, s4, s5, s6, s7, s8, o0, o1, o2] = theta;
    [[s0, s1, s2, o0], [s3, s4, s5, o1], [s6, s7, s8, o2]]
}

/// Index of coefficient a of channel j (S_j0, S_j1, S_j2, O_j) in (S row-major, O).
const fn coef_index(j: usize, a: usize) -> usize {
    if a < 3 {
        s_index(j, a)
    } else {
        o_index(j)
    }
}
