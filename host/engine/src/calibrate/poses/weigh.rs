//! The covariance of (S, O) in independent parts, as the joint or the per-channel fit
//! gives them, and how the parts weigh into one quantity's variance and degrees of freedom.
// Not yet free of unchecked indexing (docs/architecture.md, "Not yet").
#![allow(clippy::indexing_slicing)]

use super::tilt::Gls;
use super::{
    coef_index, join_coefs, split_coefs, ChannelFit, Cov12, CovPart, PartSource, Scatter,
    SlowPoses, TiltScale,
};
use crate::calibrate::budget::welch_satterthwaite;
use nalgebra::{Matrix3, Vector3};
use rotacal_shared::Channel;

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
    pub(super) parts: &'a [CovPart],
    pub(super) tilt: Option<&'a TiltScale>,
    pub(super) slow: Option<&'a SlowPoses>,
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
            // With slow noise, channel j's noise part and slow part come from one D and the
            // levels: one term, whose variance var_of_var gives; Welch–Satterthwaite's u⁴/ν
            // is half a term's variance (ν = 2u⁴/var u²).
            let modelled = |j: usize| self.slow.and_then(|s| s.of(j)).is_some();
            let (var, mut denom) = self
                .parts
                .iter()
                .filter(|c| c.source != PartSource::TableAngle)
                .map(|c| {
                    let x = of(c);
                    match c.source {
                        PartSource::Slow(j) | PartSource::Channel(j) if modelled(j) => (x, 0.0),
                        _ => (x, x * x / c.nu),
                    }
                })
                .fold((0.0, 0.0), |(v, d), (x, y)| (v + x, d + y));
            if let Some(s) = self.slow {
                for j in (0..3).filter(|j| modelled(*j)) {
                    denom += 0.5 * s.var_of_var(j, sum(PartSource::Channel(j)), &of);
                }
            }
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

/// Each channel fitted alone (`Weights::Equal`, poses of single readings, or scatter that
/// is not a tilt): its parts of the covariance, one per channel.
fn per_channel_parts(channels: &[ChannelFit; 3], se2: &[[f64; 3]]) -> Vec<CovPart> {
    channels
        .iter()
        .zip(Channel::ALL)
        .enumerate()
        .map(|(j, (c, ch))| {
            let mut theta = Cov12::zeros();
            for a in 0..4 {
                for b in 0..4 {
                    theta[(coef_index(j, a), coef_index(j, b))] = c.cov[a][b];
                }
            }
            let pose_cov = se2
                .iter()
                .map(|v| {
                    let d = c.pose_var.unwrap_or(ch.of(v) + c.tau * c.tau);
                    let diag = Channel::ALL.map(|k| if k == ch { d } else { 0.0 });
                    Matrix3::from_diagonal(&Vector3::from(diag))
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

/// The twelve parameters (S row-major, O) as fitted, jointly or channel by channel, with
/// the parts of their covariance.
pub(super) struct Combined {
    pub(super) theta: [f64; 12],
    /// The sum of `parts`.
    pub(super) cov: Cov12,
    pub(super) parts: Vec<CovPart>,
    pub(super) scatter: Scatter,
    /// χ²/dof of the joint fit.
    pub(super) chi2_dof: Option<f64>,
    pub(super) tilt_scale: Option<TiltScale>,
    /// Fitted jointly (else each channel alone).
    pub(super) joint: bool,
    /// The slow noise between poses, when modelled.
    pub(super) slow: Option<SlowPoses>,
}

impl Combined {
    /// From the joint fit of `p` poses, with the tilt variance `t2` (rad²) it estimated.
    pub(super) fn joint(
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
            slow: None,
        }
    }

    /// From each channel's own fit (`se2`: each pose mean's noise variance per channel).
    pub(super) fn per_channel(channels: &[ChannelFit; 3], se2: &[[f64; 3]]) -> Combined {
        let parts = per_channel_parts(channels, se2);
        let theta = join_coefs(channels.each_ref().map(|c| c.coef));
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
            slow: None,
        }
    }

    /// From each channel's fit at the noise-only weights, with the slow noise between the
    /// poses ([`SlowPoses`]) as a part of each channel's covariance.
    pub(super) fn with_slow(
        channels: &[ChannelFit; 3],
        se2: &[[f64; 3]],
        slow: SlowPoses,
    ) -> Combined {
        let mut parts = per_channel_parts(channels, se2);
        let noise = sum_of(&parts);
        parts.extend((0..3).filter_map(|j| slow.part(j, &noise)));
        let theta = join_coefs(channels.each_ref().map(|c| c.coef));
        Combined {
            theta,
            cov: sum_of(&parts),
            parts,
            scatter: Scatter::Slow,
            chi2_dof: None,
            tilt_scale: None,
            joint: false,
            slow: Some(slow),
        }
    }

    /// How the parts combine into one quantity's variance ([`Weighing`]).
    pub(super) fn weighing(&self) -> Weighing<'_> {
        Weighing {
            parts: &self.parts,
            tilt: self.tilt_scale.as_ref(),
            slow: self.slow.as_ref(),
        }
    }

    /// Parameter i's variance and degrees of freedom.
    pub(super) fn var_nu(&self, i: usize) -> (f64, f64) {
        self.weighing().total(|c| c.theta[(i, i)])
    }

    /// The channels as the joint fit has them: coefficients, covariance blocks, the
    /// tilt's scatter in each channel (rms over the `p` poses) and degrees of freedom.
    pub(super) fn set_joint_channels(&self, channels: &mut [ChannelFit; 3], p: usize) {
        let t2 = match self.scatter {
            Scatter::Tilt { sd_deg } => sd_deg.to_radians().powi(2),
            _ => 0.0,
        };
        let coefs = split_coefs(self.theta);
        for (j, (c, coef)) in channels.iter_mut().zip(coefs).enumerate() {
            c.coef = coef;
            for a in 0..4 {
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
