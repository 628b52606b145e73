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

use crate::calibrate::{gravity_direction, StaticCondition};
use crate::recording::Oriented;
use nalgebra::{DMatrix, Matrix4, Vector4};
use rotacal_shared::intrinsic::Estimate;

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
}

/// One channel's noise at one pose, from an AR model of its readings about their mean
/// ([`crate::noise`]).
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
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Options {
    /// Pose weighting.
    pub weights: Weights,
    /// Offset estimator.
    pub offsets: OffsetEstimator,
}

/// Why the poses cannot be fitted.
#[derive(Debug, thiserror::Error, PartialEq)]
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
}

impl PoseFit {
    /// S (rows u, v, w; columns platter x, y, z), output units per m/s².
    pub fn s(&self) -> [[f64; 3]; 3] {
        self.channels.map(|c| [c.coef[0], c.coef[1], c.coef[2]])
    }

    /// Covariance of each row S_j.
    pub fn row_cov(&self) -> [[[f64; 3]; 3]; 3] {
        self.channels.map(|c| {
            let mut r = [[0.0; 3]; 3];
            for (a, row) in r.iter_mut().enumerate() {
                for (b, x) in row.iter_mut().enumerate() {
                    *x = c.cov[a][b];
                }
            }
            r
        })
    }

    /// Standard uncertainties of S.
    pub fn s_std(&self) -> [[f64; 3]; 3] {
        self.channels
            .map(|c| [0, 1, 2].map(|a| c.cov[a][a].max(0.0).sqrt()))
    }

    /// The offsets of the chosen estimator.
    pub fn offsets(&self) -> [Estimate; 3] {
        match (self.options.offsets, self.offsets_axis_pairs) {
            (OffsetEstimator::AxisPairs, Some(o)) => o,
            _ => self.offsets_joint,
        }
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
        let (m, cov) = crate::noise::NoiseModel::estimate(&resid, &[])
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
                gravity: gravity_direction(g.condition, deg.to_radians()),
                n: rows.len(),
                mean,
                std,
                first_line: g.first_line,
                noise,
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
    let svd = x.svd(false, true);
    let (mut imin, mut smin, mut smax) = (0, f64::INFINITY, 0.0f64);
    for (i, s) in svd.singular_values.iter().enumerate() {
        if *s < smin {
            smin = *s;
            imin = i;
        }
        smax = smax.max(*s);
    }
    let cond = if smin > 0.0 {
        smax / smin
    } else {
        f64::INFINITY
    };
    // The right singular vector of the smallest singular value is the combination of
    // (S_j·ĝ, O_j) the poses see least; the axis pose that sees it most is the suggestion.
    let v = svd
        .v_t
        .as_ref()
        .map(|vt| [0, 1, 2, 3].map(|j| vt[(imin, j)]))
        .unwrap_or([0.0; 4]);
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

/// Student's t quantile for a two-sided 95 % interval.
pub fn coverage_factor(nu: f64) -> f64 {
    use statrs::distribution::{ContinuousCDF, StudentsT};
    // k = 2 (the convention of every other result here) unless few degrees of freedom
    // call for more.
    if !(1.0..=1e6).contains(&nu) {
        return 2.0;
    }
    StudentsT::new(0.0, 1.0, nu)
        .map(|t| t.inverse_cdf(0.975).max(2.0))
        .unwrap_or(2.0)
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
    let noise_dof: f64 = poses.iter().map(|q| q.n.saturating_sub(1) as f64).sum();
    let singular = || PoseError::UnderDetermined {
        poses: p,
        cond,
        missing: suggestion.clone(),
    };
    let mut channels = Vec::with_capacity(3);
    for j in 0..3 {
        let y: Vec<f64> = poses.iter().map(|q| q.mean[j]).collect();
        // A pose whose readings did not change at all in this channel (a quantised sensor
        // held still) has se = 0, which is not a known variance: it gets the smallest
        // standard error of the other poses.
        let floor = poses
            .iter()
            .map(|q| q.se()[j].powi(2))
            .filter(|v| *v > 0.0)
            .fold(f64::INFINITY, f64::min);
        let se2: Vec<f64> = poses
            .iter()
            .map(|q| match q.std {
                Some(_) if floor.is_finite() => q.se()[j].powi(2).max(floor),
                _ => 0.0,
            })
            .collect();
        let ones = vec![1.0; p];
        // Ordinary least squares: the equal-weights result, and the top of τ²'s bracket.
        let (ols_beta, ols_inv, rss) = wls(&x, &y, &ones).ok_or_else(singular)?;
        let chi2_noise = if all_repeated && se2.iter().all(|v| *v > 0.0) && dof > 0 {
            wls(&x, &y, &se2).map_or(f64::NAN, |r| r.2 / dof as f64)
        } else {
            f64::NAN
        };
        let (coef, cov, tau2, nu) = match opts.weights {
            Weights::Equal => {
                let (beta, inv) = (ols_beta, ols_inv);
                let s2 = rss / dof as f64;
                // τ² here: what the scatter of the means has beyond their own noise.
                let noise = se2.iter().sum::<f64>() / p as f64;
                (beta, inv * s2, (s2 - noise).max(0.0), dof as f64)
            }
            Weights::RandomEffects => {
                let var = |t2: f64| se2.iter().map(|s| s + t2).collect::<Vec<f64>>();
                let positive = se2.iter().all(|v| *v > 0.0);
                let at_zero = if positive { wls(&x, &y, &se2) } else { None };
                match at_zero {
                    Some((beta, inv, chi2)) if dof == 0 || chi2 <= dof as f64 => {
                        (beta, inv, 0.0, noise_dof)
                    }
                    _ if dof == 0 => return Err(PoseError::NoUncertainty(p)),
                    _ => {
                        // χ²(τ²) falls as τ² grows; at RSS/dof it is ≤ dof.
                        let (mut lo, mut hi) = (0.0f64, rss / dof as f64);
                        let top = hi;
                        if hi > 0.0 {
                            for _ in 0..200 {
                                let mid = 0.5 * (lo + hi);
                                // Below 1e-9 of the top, τ² no longer matters (and poses of
                                // one reading would get weights without bound).
                                if mid <= lo || mid >= hi || hi < 1e-9 * top {
                                    break;
                                }
                                let chi2 = wls(&x, &y, &var(mid)).map_or(0.0, |r| r.2);
                                if chi2 > dof as f64 {
                                    lo = mid;
                                } else {
                                    hi = mid;
                                }
                            }
                            let (beta, inv, _) = wls(&x, &y, &var(hi)).ok_or_else(singular)?;
                            (beta, inv, hi, dof as f64)
                        } else {
                            // Noise-free single readings: an exact fit.
                            (ols_beta, ols_inv * 0.0, 0.0, dof as f64)
                        }
                    }
                }
            }
        };
        let mut c = [[0.0; 4]; 4];
        for (a, row) in c.iter_mut().enumerate() {
            for (b, v) in row.iter_mut().enumerate() {
                *v = cov[(a, b)];
            }
        }
        channels.push(ChannelFit {
            coef,
            cov: c,
            tau: tau2.sqrt(),
            chi2_dof_noise_only: chi2_noise,
            nu,
            pose_var: match opts.weights {
                Weights::Equal => Some(rss / dof as f64),
                Weights::RandomEffects => None,
            },
        });
    }
    let [cu, cv, cw] = channels.as_slice() else {
        return Err(singular());
    };
    let channels = [*cu, *cv, *cw];
    let nu = channels.iter().map(|c| c.nu).fold(f64::INFINITY, f64::min);
    let residuals = poses
        .iter()
        .zip(&x)
        .map(|(q, h)| {
            [0, 1, 2].map(|j| q.mean[j] - (0..4).map(|a| h[a] * channels[j].coef[a]).sum::<f64>())
        })
        .collect();
    let offsets_joint = channels.map(|c| Estimate {
        value: c.coef[3],
        std_unc: c.cov[3][3].max(0.0).sqrt(),
    });
    let offsets_axis_pairs = match (axis_pairs(&poses, &channels), opts.offsets) {
        (Err(e), OffsetEstimator::AxisPairs) => return Err(e),
        (r, _) => r.ok(),
    };
    // Stillness: each channel's std against the median pose's.
    let mut not_still = Vec::new();
    for j in 0..3 {
        let mut sds: Vec<f64> = poses.iter().filter_map(|q| q.std.map(|s| s[j])).collect();
        sds.sort_by(f64::total_cmp);
        if let Some(&med) = sds.get(sds.len() / 2) {
            for q in &poses {
                if q.std.is_some_and(|s| s[j] > NOT_STILL_FACTOR * med)
                    && !not_still.contains(&q.name)
                {
                    not_still.push(q.name.clone());
                }
            }
        }
    }
    Ok(PoseFit {
        poses,
        channels,
        dof,
        k: coverage_factor(nu),
        residuals,
        conditioning: Conditioning {
            condition_number: cond,
            suggestion: (cond > WELL_CONDITIONED).then_some(suggestion),
        },
        offsets_joint,
        offsets_axis_pairs,
        options: opts,
        not_still,
    })
}

/// imucal's offsets: O_j = (ȳ_j(+e_j) + ȳ_j(−e_j))/2, each pose mean with variance
/// se² + τ_j².
fn axis_pairs(poses: &[Pose], ch: &[ChannelFit; 3]) -> Result<[Estimate; 3], PoseError> {
    let find = |k: usize, sign: f64| -> Result<&Pose, PoseError> {
        let mut e = [0.0; 3];
        e[k] = sign;
        let hits: Vec<&Pose> = poses
            .iter()
            .filter(|q| q.gravity.iter().zip(&e).all(|(a, b)| (a - b).abs() < 1e-9))
            .collect();
        match hits.as_slice() {
            [one] => Ok(one),
            other => Err(PoseError::AxisPose(direction_name(&e), other.len())),
        }
    };
    let mut out = [Estimate {
        value: 0.0,
        std_unc: 0.0,
    }; 3];
    for (j, o) in out.iter_mut().enumerate() {
        let (up, down) = (find(j, 1.0)?, find(j, -1.0)?);
        let v = match ch[j].pose_var {
            Some(s2) => 2.0 * s2,
            None => up.se()[j].powi(2) + down.se()[j].powi(2) + 2.0 * ch[j].tau.powi(2),
        };
        *o = Estimate {
            value: 0.5 * (up.mean[j] + down.mean[j]),
            std_unc: 0.5 * v.sqrt(),
        };
    }
    Ok(out)
}
