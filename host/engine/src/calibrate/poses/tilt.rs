//! The joint fit of the three channels with the pose-tilt random effect: generalised
//! least squares with a 3×3 covariance per pose mean, the tilt variance found by
//! bisection of χ² (the bisection also serves the per-channel scatter τ_j).

use super::TILT_MAX_RAD;
use super::{o_index, s_index, Cov12, CovPart, Design, PartSource, Pose, Theta, TiltScale};
use crate::calibrate::bisect::bracket;
use nalgebra::{Matrix3, RowVector3, Vector3};

/// The poses' design in (S row-major, O): row j of pose p is (g·ĝ_p in S_j's columns, 1
/// in O_j's).
fn design(poses: &[Pose], g: f64) -> Vec<Design> {
    poses
        .iter()
        .map(|q| {
            let mut x = Design::zeros();
            let row = RowVector3::from(q.gravity.map(|gk| g * gk));
            for j in 0..3 {
                x.fixed_view_mut::<1, 3>(j, s_index(j, 0)).copy_from(&row);
            }
            x.fixed_view_mut::<3, 3>(0, o_index(0)).fill_with_identity();
            x
        })
        .collect()
}

/// The joint generalised least-squares fit of (S, O) with a 3×3 covariance per pose mean.
pub(super) struct Gls {
    pub(super) theta: Theta,
    pub(super) cov: Cov12,
    pub(super) chi2: f64,
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

/// The joint fit with the tilt random effect (see [`Scatter::Tilt`](super::Scatter::Tilt));
/// `None` when the poses scatter in a way no tilt up to [`TILT_MAX_RAD`] explains.
pub(super) fn joint_fit(
    poses: &[Pose],
    g: f64,
    se2: &[[f64; 3]],
    s0: &[[f64; 3]; 3],
    u_angle_rad: Option<f64>,
    noise_dof: f64,
) -> Option<(Gls, Vec<CovPart>, f64, Option<TiltScale>)> {
    let x = design(poses, g);
    let y: Vec<Vector3<f64>> = poses.iter().map(|q| Vector3::from(q.mean)).collect();
    // Rows of s0 are the matrix's rows; `From` takes arrays as columns.
    let s = Matrix3::from(*s0).transpose();
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
