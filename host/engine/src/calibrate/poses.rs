//! Static calibration from any known orientations: one least-squares fit of the
//! sensitivity matrix S and the offsets O to `y = g·S·ĝ + O` (method.md §1, §3).
//!
//! The stepped method (seed 001: ĝ from the condition and the table angle) and the
//! six-position method (AN4399, Ferraris et al.) are special cases: only the list of
//! poses differs. Readings repeated at one orientation are averaged into a pose mean with
//! its standard error (how still the device was). Each channel j is then fitted to the pose
//! means by weighted least squares with the weights 1/(se_p² + τ_j²): τ_j is the scatter
//! of the poses about the model beyond their own noise (a pose placed a little off its
//! nominal direction, say), estimated so that χ²/dof = 1 (Paule–Mandel), or 0 when the
//! poses agree within their noise. With one reading per pose this is ordinary least
//! squares with σ̂² = RSS/(P − 4). The expanded uncertainty uses Student's t for the
//! degrees of freedom behind the variance: P − 4 when τ > 0, else those of the pose noise.

use crate::calibrate::budget::{coverage_factor, welch_satterthwaite};
use crate::recording::Oriented;
use nalgebra::{DMatrix, DVector, Matrix3, Matrix4, SMatrix, SVector, Vector3, Vector4};
use rotacal_shared::intrinsic::Estimate;
use rotacal_shared::Condition;

/// One condition of a static (stepped-angle) record.
#[derive(Clone, Copy, Debug)]
pub struct StaticCondition<'a> {
    /// The platter axis turned about.
    pub condition: Condition,
    /// Table angle of each row, degrees.
    pub angle_deg: &'a [f64],
    /// Readings u, v, w of each row.
    pub y: [&'a [f64]; 3],
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
    /// [`NOISE_MODEL_MIN`] readings): successive readings of a filtering sensor are
    /// correlated, and the mean's standard error is then not std/√n.
    pub noise: Option<[Option<PoseNoise>; 3]>,
    /// ∂ĝ/∂α, the direction ĝ moves in when the table angle α is off (stepped records;
    /// `None` for poses whose orientation is given directly).
    pub angle_direction: Option<[f64; 3]>,
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
}

/// Readings a pose needs for its noise to be modelled; fewer use std/√n. (The model's
/// correction for the mean taken out needs N well above the noise's correlation time.)
pub const NOISE_MODEL_MIN: usize = 100;

impl Pose {
    /// Standard error of the mean, per channel: under the readings' noise model where
    /// there is one, else std/√n (0 for a single reading: unknown).
    pub fn se(&self) -> [f64; 3] {
        let white = self
            .std
            .map(|s| s.map(|x| x / (self.n as f64).sqrt()))
            .unwrap_or([0.0; 3]);
        match &self.noise {
            Some(m) => [0, 1, 2].map(|j| m[j].map_or(white[j], |c| c.se)),
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
        }
    }
}

/// Where one part of the covariance of (S, O) comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum PartSource {
    /// The readings' noise within each pose (type A, Σ(n − 1) degrees of freedom).
    PoseNoise,
    /// The poses' tilt ([`Scatter::Tilt`]; type A, 3P − 12 degrees of freedom).
    PoseTilt,
    /// The stated uncertainty of each table angle (type B).
    TableAngle,
    /// Channel j's own fit, its variance from its scatter ([`Scatter::PerChannel`] or
    /// equal weights; type A).
    Channel(usize),
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

    /// One part's variance of each offset of the chosen estimator.
    pub fn offset_var(&self, part: &CovPart) -> [f64; 3] {
        match (self.options.offsets, self.axis_poses) {
            (OffsetEstimator::AxisPairs, Some(ix)) => [0, 1, 2].map(|j| axis_pair_var(part, ix, j)),
            _ => [0, 1, 2].map(|j| part.theta[(o_index(j), o_index(j))].max(0.0)),
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

    /// How the parts of the covariance combine into one quantity's variance.
    pub fn weighing(&self) -> Weighing<'_> {
        Weighing {
            parts: &self.parts,
            tilt: self.tilt_scale.as_ref(),
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

/// How the independent parts of the pose fit's covariance combine into one quantity's
/// variance and degrees of freedom. The quantity (an element of S or O, an offset, or
/// through its Jacobian a sensitivity or angle) is given by its variance from each part,
/// `of(part)`.
///
/// With six poses the joint χ² has 6 degrees of freedom, too few to tell a small tilt from
/// none: a tilt variance estimated only when χ² exceeds them (Paule–Mandel) would leave U
/// too large when there is none and too small when it is just below what χ² can see. What
/// saves a quantity that a tilt moves (an off-diagonal element of S, an angle) is to take
/// its variance from the poses' scatter, as χ² gives it, with Student's t at 3P − 12
/// (Knapp–Hartung); a quantity a tilt hardly moves (a diagonal element, a sensitivity)
/// keeps its noise variance and the readings' many degrees of freedom. Between the two,
/// w = (the quantity's relative increase per rad² of tilt) / (χ²/dof's increase per rad²),
/// in [0, 1], weighs the first way against the second. Without a joint fit (each channel
/// alone) the parts add, their degrees of freedom by Welch–Satterthwaite.
#[derive(Clone, Copy, Debug)]
pub struct Weighing<'a> {
    parts: &'a [CovPart],
    tilt: Option<&'a TiltScale>,
}

impl Weighing<'_> {
    /// The poses' line (every part but the stated table angle): variance and ν.
    pub fn poses(&self, of: impl Fn(&CovPart) -> f64) -> (f64, f64) {
        let sum = |src: PartSource| {
            self.parts
                .iter()
                .filter(|c| c.source == src)
                .map(&of)
                .sum::<f64>()
        };
        let Some(ts) = self.tilt else {
            let (var, denom) = self
                .parts
                .iter()
                .filter(|c| c.source != PartSource::TableAngle)
                .map(|c| {
                    let x = of(c);
                    (x, x * x / c.nu)
                })
                .fold((0.0, 0.0), |(v, d), (x, y)| (v + x, d + y));
            return (var, welch_satterthwaite(var, denom));
        };
        let (noise, tilt) = (sum(PartSource::PoseNoise), sum(PartSource::PoseTilt));
        let w = if noise > 0.0 && ts.chi2_per_dof_per_rad2 > 0.0 {
            ((of(&ts.unit) / noise) / ts.chi2_per_dof_per_rad2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        // Known from the readings, and from the poses' scatter (3P − 12 = the unit part's ν).
        let known = (1.0 - w) * noise;
        let scatter = if tilt > 0.0 {
            w * noise + tilt
        } else {
            w * ts.q * noise
        };
        let var = known + scatter;
        let noise_nu = self
            .parts
            .iter()
            .find(|c| c.source == PartSource::PoseNoise)
            .map_or(f64::INFINITY, |c| c.nu);
        let denom = known.powi(2) / noise_nu + scatter.powi(2) / ts.unit.nu;
        (var, welch_satterthwaite(var, denom))
    }

    /// The poses' line and the stated table angle's (ν infinite) together.
    pub fn total(&self, of: impl Fn(&CovPart) -> f64) -> (f64, f64) {
        let angle: f64 = self
            .parts
            .iter()
            .filter(|c| c.source == PartSource::TableAngle)
            .map(&of)
            .sum();
        let (var, nu) = self.poses(of);
        let total = var + angle;
        (total, welch_satterthwaite(total, var * var / nu))
    }
}

/// Each channel's noise model at a pose, when it has enough readings: the mean's variance
/// is the AR sandwich for a regressor of ones. A channel whose model cannot be made (a
/// constant reading, say) keeps std/√n.
fn pose_noise(rows: &[[f64; 3]], mean: &[f64; 3]) -> Option<[Option<PoseNoise>; 3]> {
    if rows.len() < NOISE_MODEL_MIN {
        return None;
    }
    let ones = nalgebra::DMatrix::from_element(rows.len(), 1, 1.0);
    Some([0, 1, 2].map(|j| {
        let resid: Vec<f64> = rows.iter().map(|r| r[j] - mean[j]).collect();
        let (m, cov) = crate::fit::noise::NoiseModel::estimate(&resid, &[])
            .ok()?
            .regression_cov(&ones)
            .ok()?;
        let var = cov[(0, 0)];
        Some(PoseNoise {
            lag1: m.autocorrelation(1),
            order: m.order(),
            se: var.max(0.0).sqrt(),
            n_eff: m.var / var,
        })
    }))
}

fn mean_std(rows: &[[f64; 3]]) -> ([f64; 3], Option<[f64; 3]>) {
    let n = rows.len() as f64;
    let mean = [0, 1, 2].map(|c| rows.iter().map(|r| r[c]).sum::<f64>() / n);
    let std = (rows.len() >= 2).then(|| {
        [0, 1, 2].map(|c| {
            (rows.iter().map(|r| (r[c] - mean[c]).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
        })
    });
    (mean, std)
}

/// A direction as text: `+x` for an axis, else the vector.
pub fn direction_name(g: &[f64; 3]) -> String {
    for (k, axis) in ['x', 'y', 'z'].iter().enumerate() {
        let others = (0..3).filter(|&i| i != k).all(|i| g[i].abs() < 1e-9);
        if others {
            if let Some(&c) = g.get(k) {
                if (c - 1.0).abs() < 1e-9 {
                    return format!("+{axis}");
                }
                if (c + 1.0).abs() < 1e-9 {
                    return format!("-{axis}");
                }
            }
        }
    }
    format!("({:.4}, {:.4}, {:.4})", g[0], g[1], g[2])
}

/// The poses of a file with gravity directions: by the `pose` column, else by direction.
pub fn poses_from_oriented(o: &Oriented) -> Result<Vec<Pose>, PoseError> {
    // (key, gravity, rows, first line)
    type Rows = Vec<[f64; 3]>;
    let mut groups: Vec<(String, [f64; 3], Rows, u64)> = Vec::new();
    for (i, (g, y)) in o.gravity.iter().zip(&o.y).enumerate() {
        let line = o.line.get(i).copied().unwrap_or(0);
        // Without names, a pose is one exact direction (named after grouping).
        let key = match &o.pose {
            Some(names) => names.get(i).cloned().unwrap_or_default(),
            None => format!("{:?}", g.map(f64::to_bits)),
        };
        match groups.iter_mut().find(|p| p.0 == key) {
            Some(p) => {
                if p.1.iter().zip(g).any(|(a, b)| (a - b).abs() > 1e-9) {
                    return Err(PoseError::PoseDirection {
                        name: key,
                        first: p.3,
                        line,
                    });
                }
                p.2.push(*y);
            }
            None => groups.push((key, *g, vec![*y], line)),
        }
    }
    let named = o.pose.is_some();
    let mut names: Vec<String> = Vec::new();
    Ok(groups
        .into_iter()
        .map(|(key, gravity, rows, first_line)| {
            let (mean, std) = mean_std(&rows);
            let noise = pose_noise(&rows, &mean);
            let name = if named {
                key
            } else {
                // Directions that print alike get the line of their first reading too.
                let d = direction_name(&gravity);
                let name = if names.contains(&d) {
                    format!("{d} (line {first_line})")
                } else {
                    d
                };
                names.push(name.clone());
                name
            };
            Pose {
                name,
                gravity,
                n: rows.len(),
                mean,
                std,
                first_line,
                noise,
                angle_direction: None,
            }
        })
        .collect())
}

/// The poses of a stepped (condition, angle) record: one per condition and table angle.
pub fn poses_from_conditions(conds: &[StaticCondition<'_>]) -> Vec<Pose> {
    let mut out = Vec::new();
    for g in conds {
        let mut angles: Vec<(u64, Vec<[f64; 3]>)> = Vec::new();
        for (i, a) in g.angle_deg.iter().enumerate() {
            let y = g.y.map(|c| c.get(i).copied().unwrap_or(f64::NAN));
            match angles.iter_mut().find(|(k, _)| *k == a.to_bits()) {
                Some((_, rows)) => rows.push(y),
                None => angles.push((a.to_bits(), vec![y])),
            }
        }
        for (bits, rows) in angles {
            let deg = f64::from_bits(bits);
            let (mean, std) = mean_std(&rows);
            let noise = pose_noise(&rows, &mean);
            out.push(Pose {
                name: format!("{} {deg}°", g.condition.letter()),
                gravity: g.condition.gravity_direction(deg.to_radians()),
                n: rows.len(),
                mean,
                std,
                first_line: g.first_line,
                noise,
                angle_direction: Some(
                    g.condition
                        .gravity_direction(deg.to_radians() + std::f64::consts::FRAC_PI_2),
                ),
            });
        }
    }
    out
}

/// Condition number of the unit design and, if poor, the axis orientation that helps most.
fn conditioning(poses: &[Pose]) -> (f64, String) {
    let x = DMatrix::from_fn(poses.len().max(4), 4, |i, j| match poses.get(i) {
        Some(p) => match j {
            3 => 1.0,
            _ => p.gravity.get(j).copied().unwrap_or(0.0),
        },
        None => 0.0,
    });
    let (smin, smax, v) = weakest(x);
    let cond = if smin > 0.0 {
        smax / smin
    } else {
        f64::INFINITY
    };
    // The right singular vector of the smallest singular value is the combination of
    // (S_j·ĝ, O_j) the poses see least; the axis pose that sees it most is the suggestion.
    let v = [0, 1, 2, 3].map(|j| v.get(j).copied().unwrap_or(0.0));
    let mut best = ([0.0; 3], -1.0);
    for k in 0..3 {
        for sign in [1.0, -1.0] {
            let mut g = [0.0; 3];
            g[k] = sign;
            let score = (g[k] * v[k] + v[3]).abs();
            if score > best.1 + 1e-12 {
                best = (g, score);
            }
        }
    }
    let d = direction_name(&best.0);
    let axis = d.trim_start_matches(['+', '-']);
    let reads = if d.starts_with('+') { "+g" } else { "−g" };
    (cond, format!("{d} (the {axis} axis reading {reads})"))
}

/// Weighted fit of one channel with variances `var` (all > 0, or all equal).
fn wls(x: &[[f64; 4]], y: &[f64], var: &[f64]) -> Option<([f64; 4], Matrix4<f64>, f64)> {
    let mut m = Matrix4::zeros();
    let mut b = Vector4::zeros();
    for ((row, yi), v) in x.iter().zip(y).zip(var) {
        let h = Vector4::from(*row);
        let w = 1.0 / v;
        m += w * h * h.transpose();
        b += w * *yi * h;
    }
    let inv = m.try_inverse()?;
    let beta = inv * b;
    let chi2 = x
        .iter()
        .zip(y)
        .zip(var)
        .map(|((row, yi), v)| (yi - Vector4::from(*row).dot(&beta)).powi(2) / v)
        .sum();
    Some((beta.into(), inv, chi2))
}

/// Index of S_jk in (S row-major, O).
const fn s_index(j: usize, k: usize) -> usize {
    3 * j + k
}

/// Index of O_j in (S row-major, O).
const fn o_index(j: usize) -> usize {
    9 + j
}

/// Index of coefficient a of channel j (S_j0, S_j1, S_j2, O_j) in (S row-major, O).
const fn coef_index(j: usize, a: usize) -> usize {
    if a < 3 {
        s_index(j, a)
    } else {
        o_index(j)
    }
}

/// The poses' design in (S row-major, O): row j of pose p is (g·ĝ_p in S_j's columns, 1
/// in O_j's).
fn design(poses: &[Pose], g: f64) -> Vec<Design> {
    poses
        .iter()
        .map(|q| {
            let mut x = Design::zeros();
            for j in 0..3 {
                for k in 0..3 {
                    x[(j, s_index(j, k))] = g * q.gravity[k];
                }
                x[(j, o_index(j))] = 1.0;
            }
            x
        })
        .collect()
}

/// The joint generalised least-squares fit of (S, O) with a 3×3 covariance per pose mean.
struct Gls {
    theta: Theta,
    cov: Cov12,
    chi2: f64,
    weights: Vec<Matrix3<f64>>,
}

fn gls(x: &[Design], y: &[Vector3<f64>], v: &[Matrix3<f64>]) -> Option<Gls> {
    let mut m = Cov12::zeros();
    let mut b = Theta::zeros();
    let mut weights = Vec::with_capacity(v.len());
    for ((xp, yp), vp) in x.iter().zip(y).zip(v) {
        let w = vp.try_inverse()?;
        let xtw = xp.transpose() * w;
        m += xtw * xp;
        b += xtw * yp;
        weights.push(w);
    }
    let cov = m.try_inverse()?;
    let theta = cov * b;
    let chi2 = x
        .iter()
        .zip(y)
        .zip(&weights)
        .map(|((xp, yp), w)| {
            let r = yp - xp * theta;
            r.dot(&(w * r))
        })
        .sum();
    Some(Gls {
        theta,
        cov,
        chi2,
        weights,
    })
}

/// The covariance one part `v` of the pose means' covariance gives (S, O) under the
/// weights of `fit`: C·(Σ XᵀW·V·WX)·C. The parts add up to C.
fn sandwich(fit: &Gls, x: &[Design], v: &[Matrix3<f64>]) -> Cov12 {
    fit.cov * meat(fit, x, v) * fit.cov
}

/// Σ XᵀW·V·WX under the weights of `fit`.
fn meat(fit: &Gls, x: &[Design], v: &[Matrix3<f64>]) -> Cov12 {
    x.iter()
        .zip(&fit.weights)
        .zip(v)
        .fold(Cov12::zeros(), |m, ((xp, w), vp)| {
            let wx = w * xp;
            m + wx.transpose() * vp * wx
        })
}

/// The root of the decreasing `f(x) = target` between `lo` (f > target) and `hi`.
fn bisect(f: &impl Fn(f64) -> f64, target: f64, lo: f64, hi: f64) -> f64 {
    let (lo, hi) = bracket(f, target, (lo, hi), 100, f64::NEG_INFINITY);
    0.5 * (lo + hi)
}

/// Bisection of the decreasing `f(x) = target` from the bracket `(lo, hi)` (f(lo) > target
/// ≥ f(hi)): the last bracket, after at most `steps` halvings, once it no longer narrows,
/// or once `hi` is below `floor`.
fn bracket(
    f: &impl Fn(f64) -> f64,
    target: f64,
    (mut lo, mut hi): (f64, f64),
    steps: usize,
    floor: f64,
) -> (f64, f64) {
    for _ in 0..steps {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi || hi < floor {
            break;
        }
        if f(mid) > target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    (lo, hi)
}

/// The joint fit with the tilt random effect (see [`Scatter::Tilt`]); `None` when the
/// poses scatter in a way no tilt up to [`TILT_MAX_RAD`] explains.
fn joint_fit(
    poses: &[Pose],
    g: f64,
    se2: &[[f64; 3]],
    s0: &[[f64; 3]; 3],
    u_angle_rad: Option<f64>,
    noise_dof: f64,
) -> Option<(Gls, Vec<CovPart>, f64, Option<TiltScale>)> {
    let x = design(poses, g);
    let y: Vec<Vector3<f64>> = poses.iter().map(|q| Vector3::from(q.mean)).collect();
    let s = Matrix3::from_fn(|j, k| s0[j][k]);
    let noise: Vec<Matrix3<f64>> = se2
        .iter()
        .map(|v| Matrix3::from_diagonal(&Vector3::from(*v)))
        .collect();
    // A tilt t (rad per axis) moves ĝ by t × ĝ: the reading by g·S·(t × ĝ), of covariance
    // g²·S·(I − ĝĝᵀ)·Sᵀ per rad² (ĝ a unit vector).
    let tilt: Vec<Matrix3<f64>> = poses
        .iter()
        .map(|q| {
            let gh = Vector3::from(q.gravity);
            let n2 = gh.norm_squared();
            let perp = Matrix3::identity() * n2 - gh * gh.transpose();
            (g * g) * s * perp * s.transpose()
        })
        .collect();
    // A table angle off by δα moves ĝ by δα·∂ĝ/∂α.
    let angle: Vec<Matrix3<f64>> = poses
        .iter()
        .map(|q| match (u_angle_rad, q.angle_direction) {
            (Some(u), Some(d)) => {
                let sd = g * u * (s * Vector3::from(d));
                sd * sd.transpose()
            }
            _ => Matrix3::zeros(),
        })
        .collect();
    let total = |t2: f64| -> Vec<Matrix3<f64>> {
        noise
            .iter()
            .zip(&tilt)
            .zip(&angle)
            .map(|((n, t), a)| n + t * t2 + a)
            .collect()
    };
    let dof = (3 * poses.len()).saturating_sub(12) as f64;
    let at_zero = gls(&x, &y, &total(0.0))?;
    let chi2 = |t2: f64| gls(&x, &y, &total(t2)).map_or(f64::NAN, |f| f.chi2);
    // χ² falls as the tilt variance grows (every pose's covariance grows): the variance
    // that makes it equal its degrees of freedom (Paule–Mandel), or 0 when χ² is below them
    // already.
    let t2 = if dof == 0.0 || at_zero.chi2 <= dof {
        0.0
    } else {
        let mut hi = 1e-10;
        while chi2(hi) > dof {
            hi *= 4.0;
            if hi > TILT_MAX_RAD * TILT_MAX_RAD {
                return None;
            }
        }
        bisect(&chi2, dof, 0.0, hi)
    };
    // How a unit tilt variance shows at the noise-only weights: in each quantity (B₁ =
    // C·Σ XᵀW·T·WX·C) and in χ² (E[χ²] grows by Σ tr(W·T) − tr(C·Σ XᵀW·T·WX) per rad²).
    let tilt_meat = meat(&at_zero, &x, &tilt);
    let unit_tilt = at_zero.cov * tilt_meat * at_zero.cov;
    let tr_wt: f64 = at_zero
        .weights
        .iter()
        .zip(&tilt)
        .map(|(w, t)| (w * t).trace())
        .sum();
    let chi2_per_rad2 = tr_wt - (at_zero.cov * tilt_meat).trace();
    let scale = (dof > 0.0).then(|| TiltScale {
        unit: CovPart {
            source: PartSource::PoseTilt,
            theta: unit_tilt,
            pose_cov: tilt.clone(),
            nu: dof,
        },
        chi2_per_dof_per_rad2: chi2_per_rad2 / dof,
        q: if t2 > 0.0 { 1.0 } else { at_zero.chi2 / dof },
    });
    let fit = gls(&x, &y, &total(t2))?;
    let mut parts = vec![CovPart {
        source: PartSource::PoseNoise,
        theta: sandwich(&fit, &x, &noise),
        pose_cov: noise.clone(),
        nu: noise_dof,
    }];
    if t2 > 0.0 {
        let v: Vec<Matrix3<f64>> = tilt.iter().map(|t| t * t2).collect();
        parts.push(CovPart {
            source: PartSource::PoseTilt,
            theta: sandwich(&fit, &x, &v),
            pose_cov: v,
            nu: dof,
        });
    }
    if angle.iter().any(|a| a.norm() > 0.0) {
        parts.push(CovPart {
            source: PartSource::TableAngle,
            theta: sandwich(&fit, &x, &angle),
            pose_cov: angle,
            nu: f64::INFINITY,
        });
    }
    Some((fit, parts, t2, scale))
}

/// Each channel fitted alone (`Weights::Equal`, poses of single readings, or scatter that
/// is not a tilt): its parts of the covariance, one per channel.
fn per_channel_parts(channels: &[ChannelFit; 3], se2: &[[f64; 3]]) -> Vec<CovPart> {
    channels
        .iter()
        .enumerate()
        .map(|(j, c)| {
            let mut theta = Cov12::zeros();
            for a in 0..4 {
                for b in 0..4 {
                    theta[(coef_index(j, a), coef_index(j, b))] = c.cov[a][b];
                }
            }
            let pose_cov = se2
                .iter()
                .map(|v| {
                    let mut m = Matrix3::zeros();
                    m[(j, j)] = c.pose_var.unwrap_or(v[j] + c.tau * c.tau);
                    m
                })
                .collect();
            CovPart {
                source: PartSource::Channel(j),
                theta,
                pose_cov,
                nu: c.nu,
            }
        })
        .collect()
}

/// The sum of the parts of a covariance.
fn sum_of(parts: &[CovPart]) -> Cov12 {
    parts.iter().fold(Cov12::zeros(), |a, c| a + c.theta)
}

/// What every step of [`fit`] reads: the poses, their design and noise, and the degrees
/// of freedom.
struct Problem<'a> {
    poses: &'a [Pose],
    /// Gravity, m/s².
    g: f64,
    opts: Options,
    /// Each pose's row (g·ĝ, 1) of one channel's design.
    x: Vec<[f64; 4]>,
    /// Each pose mean's variance from its own noise, per channel ([`pose_se2`]).
    se2: Vec<[f64; 3]>,
    /// P − 4.
    dof: usize,
    /// Σ(n − 1) over the poses: the degrees of freedom of their noise.
    noise_dof: f64,
    /// Every pose has repeated readings.
    all_repeated: bool,
    /// The design's condition number and the pose that would help most, for the error.
    cond: f64,
    suggestion: &'a str,
}

impl Problem<'_> {
    /// The error for a design too close to singular to solve.
    fn singular(&self) -> PoseError {
        PoseError::UnderDetermined {
            poses: self.poses.len(),
            cond: self.cond,
            missing: self.suggestion.to_string(),
        }
    }

    /// The channels u, v, w, each fitted alone.
    fn fit_channels(&self) -> Result<[ChannelFit; 3], PoseError> {
        let mut channels = Vec::with_capacity(3);
        for j in 0..3 {
            channels.push(self.fit_channel(j)?);
        }
        let [cu, cv, cw] = channels.as_slice() else {
            return Err(self.singular());
        };
        Ok([*cu, *cv, *cw])
    }

    /// Channel j fitted alone to the pose means, weighted as the options say.
    fn fit_channel(&self, j: usize) -> Result<ChannelFit, PoseError> {
        let (x, dof, p) = (&self.x, self.dof, self.poses.len());
        let y: Vec<f64> = self.poses.iter().map(|q| q.mean[j]).collect();
        let se2: Vec<f64> = self.se2.iter().map(|v| v[j]).collect();
        let ones = vec![1.0; p];
        // Ordinary least squares: the equal-weights result, and the top of τ²'s bracket.
        let ols = wls(x, &y, &ones).ok_or_else(|| self.singular())?;
        let rss = ols.2;
        let chi2_noise = if self.all_repeated && se2.iter().all(|v| *v > 0.0) && dof > 0 {
            wls(x, &y, &se2).map_or(f64::NAN, |r| r.2 / dof as f64)
        } else {
            f64::NAN
        };
        let (coef, cov, tau2, nu) = match self.opts.weights {
            Weights::Equal => {
                let (beta, inv, _) = ols;
                let s2 = rss / dof as f64;
                // τ² here: what the scatter of the means has beyond their own noise.
                let noise = se2.iter().sum::<f64>() / p as f64;
                (beta, inv * s2, (s2 - noise).max(0.0), dof as f64)
            }
            Weights::RandomEffects => self.random_effects(&y, &se2, ols)?,
        };
        let mut c = [[0.0; 4]; 4];
        for (a, row) in c.iter_mut().enumerate() {
            for (b, v) in row.iter_mut().enumerate() {
                *v = cov[(a, b)];
            }
        }
        Ok(ChannelFit {
            coef,
            cov: c,
            tau: tau2.sqrt(),
            chi2_dof_noise_only: chi2_noise,
            nu,
            pose_var: match self.opts.weights {
                Weights::Equal => Some(rss / dof as f64),
                Weights::RandomEffects => None,
            },
        })
    }

    /// One channel's fit to the pose means `y` under the weights 1/(se² + τ²), from its
    /// ordinary least-squares fit `ols`: τ² = 0 when the means agree within their noise,
    /// else the τ² that brings χ² down to its degrees of freedom. Gives the coefficients,
    /// their covariance, τ² and the degrees of freedom.
    fn random_effects(
        &self,
        y: &[f64],
        se2: &[f64],
        ols: ([f64; 4], Matrix4<f64>, f64),
    ) -> Result<([f64; 4], Matrix4<f64>, f64, f64), PoseError> {
        let (x, dof) = (&self.x, self.dof);
        let (ols_beta, ols_inv, rss) = ols;
        let var = |t2: f64| se2.iter().map(|s| s + t2).collect::<Vec<f64>>();
        let positive = se2.iter().all(|v| *v > 0.0);
        let at_zero = if positive { wls(x, y, se2) } else { None };
        match at_zero {
            Some((beta, inv, chi2)) if dof == 0 || chi2 <= dof as f64 => {
                Ok((beta, inv, 0.0, self.noise_dof))
            }
            _ if dof == 0 => Err(PoseError::NoUncertainty(self.poses.len())),
            _ => {
                // χ²(τ²) falls as τ² grows; at RSS/dof it is ≤ dof.
                let top = rss / dof as f64;
                if top > 0.0 {
                    let chi2 = |t2: f64| wls(x, y, &var(t2)).map_or(0.0, |r| r.2);
                    // Below 1e-9 of the top, τ² no longer matters (and poses of one
                    // reading would get weights without bound).
                    let (_, hi) = bracket(&chi2, dof as f64, (0.0, top), 200, 1e-9 * top);
                    let (beta, inv, _) = wls(x, y, &var(hi)).ok_or_else(|| self.singular())?;
                    Ok((beta, inv, hi, dof as f64))
                } else {
                    // Noise-free single readings: an exact fit.
                    Ok((ols_beta, ols_inv * 0.0, 0.0, dof as f64))
                }
            }
        }
    }

    /// The twelve parameters: the joint fit when it can be made, else the channels'
    /// own fits. A note says why when the joint fit was tried and refused.
    fn combine(&self, channels: &[ChannelFit; 3], notes: &mut Vec<String>) -> Combined {
        // Repeated readings give each pose mean a known variance: then the three channels
        // are fitted together, and the scatter beyond the noise is a tilt of each pose (one
        // variance for all channels and poses, shaped by S and ĝ), not a variance per
        // channel.
        let joint_possible = self.opts.weights == Weights::RandomEffects
            && self.all_repeated
            && self.se2.iter().all(|v| v.iter().all(|x| *x > 0.0));
        let s_first = channels.map(|c| [c.coef[0], c.coef[1], c.coef[2]]);
        let joint = if joint_possible {
            let j = joint_fit(
                self.poses,
                self.g,
                &self.se2,
                &s_first,
                self.opts.u_angle_rad,
                self.noise_dof,
            );
            if j.is_none() {
                notes.push(format!(
                    "the poses scatter about the model by more than their noise in a way a tilt of \
                     up to {:.1}° does not explain: each channel's own scatter τ_j is used instead",
                    TILT_MAX_RAD.to_degrees()
                ));
            }
            j
        } else {
            None
        };
        match joint {
            Some((fit, parts, t2, scale)) => {
                Combined::joint(&fit, parts, t2, scale, self.poses.len())
            }
            None => Combined::per_channel(channels, &self.se2),
        }
    }
}

/// Each pose mean's variance from its own noise, per channel. A pose whose readings did
/// not change at all in a channel (a quantised sensor held still) has se = 0, which is
/// not a known variance: it gets the smallest standard error of the other poses.
fn pose_se2(poses: &[Pose]) -> Vec<[f64; 3]> {
    let mut se2 = vec![[0.0; 3]; poses.len()];
    for j in 0..3 {
        let floor = poses
            .iter()
            .map(|q| q.se()[j].powi(2))
            .filter(|v| *v > 0.0)
            .fold(f64::INFINITY, f64::min);
        for (v, q) in se2.iter_mut().zip(poses) {
            v[j] = match q.std {
                Some(_) if floor.is_finite() => q.se()[j].powi(2).max(floor),
                _ => 0.0,
            };
        }
    }
    se2
}

/// The twelve parameters (S row-major, O) as fitted, jointly or channel by channel, with
/// the parts of their covariance.
struct Combined {
    theta: [f64; 12],
    /// The sum of `parts`.
    cov: Cov12,
    parts: Vec<CovPart>,
    scatter: Scatter,
    /// χ²/dof of the joint fit.
    chi2_dof: Option<f64>,
    tilt_scale: Option<TiltScale>,
    /// Fitted jointly (else each channel alone).
    joint: bool,
}

impl Combined {
    /// From the joint fit of `p` poses, with the tilt variance `t2` (rad²) it estimated.
    fn joint(
        fit: &Gls,
        parts: Vec<CovPart>,
        t2: f64,
        tilt_scale: Option<TiltScale>,
        p: usize,
    ) -> Combined {
        let dof3 = (3 * p).saturating_sub(12);
        let chi2_dof = (dof3 > 0).then(|| fit.chi2 / dof3 as f64);
        let scatter = if t2 > 0.0 {
            Scatter::Tilt {
                sd_deg: t2.sqrt().to_degrees(),
            }
        } else {
            Scatter::None
        };
        let mut theta = [0.0; 12];
        for (t, v) in theta.iter_mut().zip(fit.theta.iter()) {
            *t = *v;
        }
        Combined {
            theta,
            cov: sum_of(&parts),
            parts,
            scatter,
            chi2_dof,
            tilt_scale,
            joint: true,
        }
    }

    /// From each channel's own fit (`se2`: each pose mean's noise variance per channel).
    fn per_channel(channels: &[ChannelFit; 3], se2: &[[f64; 3]]) -> Combined {
        let parts = per_channel_parts(channels, se2);
        let mut theta = [0.0; 12];
        for (j, c) in channels.iter().enumerate() {
            for (a, v) in c.coef.iter().enumerate() {
                theta[coef_index(j, a)] = *v;
            }
        }
        let scatter = if channels.iter().any(|c| c.tau > 0.0) {
            Scatter::PerChannel
        } else {
            Scatter::None
        };
        Combined {
            theta,
            cov: sum_of(&parts),
            parts,
            scatter,
            chi2_dof: None,
            tilt_scale: None,
            joint: false,
        }
    }

    /// How the parts combine into one quantity's variance ([`Weighing`]).
    fn weighing(&self) -> Weighing<'_> {
        Weighing {
            parts: &self.parts,
            tilt: self.tilt_scale.as_ref(),
        }
    }

    /// Parameter i's variance and degrees of freedom.
    fn var_nu(&self, i: usize) -> (f64, f64) {
        self.weighing().total(|c| c.theta[(i, i)])
    }

    /// The channels as the joint fit has them: coefficients, covariance blocks, the
    /// tilt's scatter in each channel (rms over the `p` poses) and degrees of freedom.
    fn set_joint_channels(&self, channels: &mut [ChannelFit; 3], p: usize) {
        let t2 = match self.scatter {
            Scatter::Tilt { sd_deg } => sd_deg.to_radians().powi(2),
            _ => 0.0,
        };
        for (j, c) in channels.iter_mut().enumerate() {
            for a in 0..4 {
                c.coef[a] = self.theta[coef_index(j, a)];
                for b in 0..4 {
                    c.cov[a][b] = self.cov[(coef_index(j, a), coef_index(j, b))];
                }
            }
            // The unit tilt's covariance of each pose mean, T_p, is the tilt scale's.
            let mean_tilt_var = self.tilt_scale.as_ref().map_or(0.0, |ts| {
                t2 * ts.unit.pose_cov.iter().map(|m| m[(j, j)]).sum::<f64>() / p as f64
            });
            c.tau = mean_tilt_var.max(0.0).sqrt();
            c.nu = [0, 1, 2, 3]
                .map(|a| self.var_nu(coef_index(j, a)).1)
                .into_iter()
                .fold(f64::INFINITY, f64::min);
        }
    }
}

/// Why a stated table-angle uncertainty was not counted, when it was given and not.
fn u_angle_note(poses: &[Pose], parts: &[CovPart], opts: Options) -> Option<&'static str> {
    // Nothing to say when none was given.
    opts.u_angle_rad?;
    if poses.iter().all(|q| q.angle_direction.is_none()) {
        Some(
            "u_angle_deg was given but the poses are not table angles (it applies to stepped \
             records)",
        )
    } else if !parts.iter().any(|c| c.source == PartSource::TableAngle) {
        Some(
            "u_angle_deg was given, but with each channel's scatter estimated from the poses \
             (single readings, equal weights, or scatter a tilt does not explain) the angles' \
             scatter is already part of it and is not counted again",
        )
    } else {
        None
    }
}

/// Pose mean minus the fitted model (design rows `x`), per pose and channel.
fn residuals(poses: &[Pose], x: &[[f64; 4]], channels: &[ChannelFit; 3]) -> Vec<[f64; 3]> {
    poses
        .iter()
        .zip(x)
        .map(|(q, h)| {
            [0, 1, 2].map(|j| q.mean[j] - (0..4).map(|a| h[a] * channels[j].coef[a]).sum::<f64>())
        })
        .collect()
}

/// The poses whose std in some channel exceeds [`NOT_STILL_FACTOR`] times the median
/// pose's, in order of first appearance.
fn not_still(poses: &[Pose]) -> Vec<String> {
    let mut not_still = Vec::new();
    for j in 0..3 {
        let mut sds: Vec<f64> = poses.iter().filter_map(|q| q.std.map(|s| s[j])).collect();
        sds.sort_by(f64::total_cmp);
        if let Some(&med) = sds.get(sds.len() / 2) {
            for q in poses {
                if q.std.is_some_and(|s| s[j] > NOT_STILL_FACTOR * med)
                    && !not_still.contains(&q.name)
                {
                    not_still.push(q.name.clone());
                }
            }
        }
    }
    not_still
}

/// Fit S and O to the poses in gravity `g`.
pub fn fit(poses: Vec<Pose>, g: f64, opts: Options) -> Result<PoseFit, PoseError> {
    let p = poses.len();
    let (cond, suggestion) = conditioning(&poses);
    if p < 4 || cond.is_nan() || cond >= SINGULAR {
        return Err(PoseError::UnderDetermined {
            poses: p,
            cond,
            missing: suggestion,
        });
    }
    let dof = p - 4;
    let x: Vec<[f64; 4]> = poses
        .iter()
        .map(|q| [g * q.gravity[0], g * q.gravity[1], g * q.gravity[2], 1.0])
        .collect();
    let all_repeated = poses.iter().all(|q| q.std.is_some());
    if dof == 0 && (!all_repeated || opts.weights == Weights::Equal) {
        return Err(PoseError::NoUncertainty(p));
    }
    let problem = Problem {
        poses: &poses,
        g,
        opts,
        x,
        se2: pose_se2(&poses),
        dof,
        noise_dof: poses.iter().map(|q| q.n.saturating_sub(1) as f64).sum(),
        all_repeated,
        cond,
        suggestion: &suggestion,
    };
    let mut channels = problem.fit_channels()?;
    let mut notes = Vec::new();
    let fitted = problem.combine(&channels, &mut notes);
    notes.extend(u_angle_note(&poses, &fitted.parts, opts).map(String::from));
    if fitted.joint {
        fitted.set_joint_channels(&mut channels, p);
    }
    let residuals = residuals(&poses, &problem.x, &channels);
    let offsets_joint = [0, 1, 2].map(|j| Estimate {
        value: fitted.theta[o_index(j)],
        std_unc: fitted.var_nu(o_index(j)).0.max(0.0).sqrt(),
    });
    let axis_poses = axis_poses(&poses);
    if opts.offsets == OffsetEstimator::AxisPairs {
        if let Err(e) = &axis_poses {
            return Err(e.clone());
        }
    }
    let axis_poses = axis_poses.ok();
    let weigh = fitted.weighing();
    let offsets_axis_pairs = axis_poses.map(|ix| {
        [0, 1, 2].map(|j| Estimate {
            value: 0.5
                * ix[j]
                    .iter()
                    .map(|i| poses.get(*i).map_or(f64::NAN, |q| q.mean[j]))
                    .sum::<f64>(),
            std_unc: weigh.total(|c| axis_pair_var(c, ix, j)).0.max(0.0).sqrt(),
        })
    });
    let k = coverage_factor(
        (0..12)
            .map(|i| fitted.var_nu(i).1)
            .fold(f64::INFINITY, f64::min),
    );
    let not_still = not_still(&poses);
    Ok(PoseFit {
        poses,
        channels,
        dof,
        k,
        residuals,
        conditioning: Conditioning {
            condition_number: cond,
            suggestion: (cond > WELL_CONDITIONED).then_some(suggestion),
        },
        offsets_joint,
        offsets_axis_pairs,
        options: opts,
        not_still,
        cov: fitted.cov,
        parts: fitted.parts,
        scatter: fitted.scatter,
        chi2_dof: fitted.chi2_dof,
        axis_poses,
        notes,
        tilt_scale: fitted.tilt_scale,
    })
}

/// One part's variance of imucal's offset O_j = (ȳ_j(+e_j) + ȳ_j(−e_j))/2.
fn axis_pair_var(part: &CovPart, ix: [[usize; 2]; 3], j: usize) -> f64 {
    let v = |p: usize| part.pose_cov.get(p).map_or(0.0, |m| m[(j, j)]);
    0.25 * (v(ix[j][0]) + v(ix[j][1]))
}

/// For each channel j, the poses with gravity along +e_j and −e_j (imucal's offsets need
/// exactly one of each).
fn axis_poses(poses: &[Pose]) -> Result<[[usize; 2]; 3], PoseError> {
    let find = |k: usize, sign: f64| -> Result<usize, PoseError> {
        let mut e = [0.0; 3];
        e[k] = sign;
        let hits: Vec<usize> = poses
            .iter()
            .enumerate()
            .filter(|(_, q)| q.gravity.iter().zip(&e).all(|(a, b)| (a - b).abs() < 1e-9))
            .map(|(i, _)| i)
            .collect();
        match hits.as_slice() {
            [one] => Ok(*one),
            other => Err(PoseError::AxisPose(direction_name(&e), other.len())),
        }
    };
    let mut out = [[0; 2]; 3];
    for (k, o) in out.iter_mut().enumerate() {
        *o = [find(k, 1.0)?, find(k, -1.0)?];
    }
    Ok(out)
}

/// The smallest and largest singular values of `m`, and the right singular vector of the
/// smallest: the parameter combination the data determine least (zeros if the SVD gave no
/// V). Shared with the free method's geometry check.
pub(crate) fn weakest(m: DMatrix<f64>) -> (f64, f64, DVector<f64>) {
    let cols = m.ncols();
    let svd = m.svd(false, true);
    let (mut imin, mut smin, mut smax) = (0, f64::INFINITY, 0.0f64);
    for (i, s) in svd.singular_values.iter().enumerate() {
        if *s < smin {
            smin = *s;
            imin = i;
        }
        smax = smax.max(*s);
    }
    let v = svd
        .v_t
        .as_ref()
        .filter(|vt| imin < vt.nrows())
        .map(|vt| vt.row(imin).transpose())
        .unwrap_or_else(|| DVector::zeros(cols));
    (smin, smax, v)
}
