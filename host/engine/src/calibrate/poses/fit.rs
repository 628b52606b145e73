//! The pose fit itself: each channel fitted alone to the pose means (weighted least
//! squares, τ_j by Paule–Mandel), then jointly where the poses allow ([`super::tilt`]),
//! with the design's conditioning, the residuals, the poses not still and imucal's
//! axis-pair offsets.
// Not yet free of unchecked indexing (docs/architecture.md, "Not yet").
#![allow(clippy::indexing_slicing)]

use super::gather::direction_name;
use super::serial;
use super::tilt::joint_fit;
use super::weigh::Combined;
use super::{
    coef_index, o_index, ChannelFit, Conditioning, CovPart, OffsetEstimator, Options, PartSource,
    Pose, PoseError, PoseFit, Serial, SlowPoses, Weights, NOISE_MODEL_MIN, NOT_STILL_FACTOR,
    SINGULAR, TILT_MAX_RAD, WELL_CONDITIONED, Z_ALARM,
};
use crate::calibrate::bisect::bracket;
use crate::calibrate::budget::coverage_factor;
use nalgebra::{DMatrix, DVector, Matrix4, Vector4};
use rotacal_shared::intrinsic::Estimate;
use rotacal_shared::Channel;

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
pub(super) fn wls(x: &[[f64; 4]], y: &[f64], var: &[f64]) -> Option<([f64; 4], Matrix4<f64>, f64)> {
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
    /// The degrees of freedom of the poses' own noise ([`noise_dof`]).
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

    /// Each channel's serial test, on its residuals under the weights it was fitted with.
    fn serial(&self, channels: &[ChannelFit; 3]) -> [Option<Serial>; 3] {
        [0, 1, 2].map(|j| {
            let y: Vec<f64> = self.poses.iter().map(|q| q.mean[j]).collect();
            let var: Vec<f64> = match self.opts.weights {
                Weights::Equal => vec![1.0; y.len()],
                Weights::RandomEffects => {
                    let tau2 = channels[j].tau.powi(2);
                    self.se2.iter().map(|v| v[j] + tau2).collect()
                }
            };
            serial::lag1(&self.x, &y, &var)
        })
    }

    /// With `--slow-noise`: each channel at the noise-only weights 1/se², and the slow
    /// noise between the poses estimated from their residuals. `None` with a note saying
    /// why where the poses do not allow it.
    fn slow(&self, notes: &mut Vec<String>) -> Option<(Combined, [ChannelFit; 3])> {
        let why = if self.opts.weights != Weights::RandomEffects {
            Some("equal weights take the poses' scatter as it is".to_string())
        } else if self.opts.offsets != OffsetEstimator::Joint {
            Some("imucal's axis-pair offsets are not propagated under it".to_string())
        } else if !self.all_repeated {
            Some("some pose has a single reading".to_string())
        } else {
            None
        };
        let slow = match why {
            Some(w) => Err(w),
            None => SlowPoses::estimate(self.poses, &self.x, &self.se2, self.noise_dof)
                .map_err(|e| e.to_string()),
        };
        match slow {
            Ok(s) => {
                // Each channel at the noise-only weights, its pose means' own variances less
                // the slow share their readings' model saw.
                let mut se2 = self.se2.clone();
                let mut channels = Vec::with_capacity(3);
                for c in &s.channels {
                    channels.push(c.fit);
                    for (v, own) in se2.iter_mut().zip(&c.noise_var) {
                        v[c.channel] = *own;
                    }
                }
                let ch = <[ChannelFit; 3]>::try_from(channels).ok()?;
                Some((Combined::with_slow(&ch, &se2, s), ch))
            }
            Err(why) => {
                notes.push(format!(
                    "--slow-noise: the slow noise between poses is not modelled, because {why}; \
                     the poses' scatter beyond their noise is modelled as without the option"
                ));
                None
            }
        }
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

/// The degrees of freedom of the pose means' own variances: Σ(n − 1) over the poses with
/// a noise model of their own (or std/√n), plus a pooled model's own once (the jackknife's,
/// [`PoseNoise::dof`]), the least over the channels.
fn noise_dof(poses: &[Pose]) -> f64 {
    let pooled = |q: &Pose| q.n < NOISE_MODEL_MIN && q.noise.is_some();
    (0..3)
        .map(|j| {
            let own: f64 = poses
                .iter()
                .filter(|q| !pooled(q) || q.noise.is_some_and(|m| m[j].is_none()))
                .map(|q| q.n.saturating_sub(1) as f64)
                .sum();
            let shared = poses
                .iter()
                .filter(|q| pooled(q))
                .find_map(|q| q.noise.and_then(|m| m[j]))
                .map_or(0.0, |m| m.dof);
            own + shared
        })
        .fold(f64::INFINITY, f64::min)
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
    } else if parts
        .iter()
        .any(|c| matches!(c.source, PartSource::Slow(_)))
    {
        Some(
            "u_angle_deg was given, but with the slow noise between poses modelled \
             (--slow-noise) a stated table-angle uncertainty is not propagated yet and is \
             not counted",
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

/// A warning for each channel whose residuals are correlated from pose to pose.
fn serial_notes(serial: &[Option<Serial>; 3]) -> Vec<String> {
    Channel::ALL
        .iter()
        .zip(serial)
        .filter_map(|(c, s)| s.filter(|s| s.z > Z_ALARM).map(|s| (c, s)))
        .map(|(c, s)| {
            format!(
                "the pose residuals of channel {c} are correlated from one pose to the next \
                 (lag-1 autocorrelation {:.2}, independent poses give {:.2}; z = {:.1} > {Z_ALARM}): \
                 slow drift between poses (flicker, bias wander) or an effect that varies \
                 smoothly with the angle, which this uncertainty does not include; an offset \
                 also carries the drift's mean over the session, which no residual shows",
                s.lag1, s.expected, s.z
            )
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
        noise_dof: noise_dof(&poses),
        all_repeated,
        cond,
        suggestion: &suggestion,
    };
    let mut channels = problem.fit_channels()?;
    let mut notes = Vec::new();
    let slow = if opts.slow {
        problem.slow(&mut notes)
    } else {
        None
    };
    let fitted = match slow {
        Some((fitted, noise_only)) => {
            channels = noise_only;
            // Each channel's degrees of freedom: its least certain coefficient's.
            for (j, c) in channels.iter_mut().enumerate() {
                c.nu = (0..4)
                    .map(|a| fitted.var_nu(coef_index(j, a)).1)
                    .fold(f64::INFINITY, f64::min);
            }
            fitted
        }
        None => problem.combine(&channels, &mut notes),
    };
    notes.extend(u_angle_note(&poses, &fitted.parts, opts).map(String::from));
    if fitted.joint {
        fitted.set_joint_channels(&mut channels, p);
    }
    let residuals = residuals(&poses, &problem.x, &channels);
    let serial = problem.serial(&channels);
    // With the slow noise modelled, the correlation the serial test looks for is in U.
    if fitted.slow.is_none() {
        notes.extend(serial_notes(&serial));
    }
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
    // Under slow noise imucal's offsets would need their own contrast: not given.
    let offsets_axis_pairs = axis_poses.filter(|_| fitted.slow.is_none()).map(|ix| {
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
        serial,
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
        slow: fitted.slow,
    })
}

/// One part's variance of imucal's offset O_j = (ȳ_j(+e_j) + ȳ_j(−e_j))/2.
pub(super) fn axis_pair_var(part: &CovPart, ix: [[usize; 2]; 3], j: usize) -> f64 {
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
