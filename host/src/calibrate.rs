//! Calibration from fits: the rotation method's intrinsic properties.
//!
//! Takes the fits of the three conditions (from `rotacal_shared::SineFit` or the batch
//! fit), assembles each fit's (A, B) covariance, and computes the Gram intrinsic
//! properties and the phase-difference angles with their uncertainties
//! (`rotacal_shared::intrinsic`). Reading recordings, rate estimation and the static
//! method build on this.

use rotacal_shared::intrinsic::{self, ConditionFit, Estimate, Intrinsic, IntrinsicError};
use rotacal_shared::{FitResult, Param};

/// The (A, B) coefficients and their covariance per channel of one condition's fit.
pub fn condition_fit(fit: &FitResult<f64>) -> ConditionFit {
    let mut out = ConditionFit {
        a: [0.0; 3],
        b: [0.0; 3],
        cov: [[[0.0; 2]; 2]; 3],
    };
    for ch in 0..3 {
        let get = |p| fit.coef(ch, p).map(|v| v.to_f64()).unwrap_or(f64::NAN);
        let cov = |p, q| fit.covariance(ch, p, q).unwrap_or(f64::NAN);
        out.a[ch] = get(Param::A);
        out.b[ch] = get(Param::B);
        out.cov[ch] = [
            [cov(Param::A, Param::A), cov(Param::A, Param::B)],
            [cov(Param::B, Param::A), cov(Param::B, Param::B)],
        ];
    }
    out
}

/// The rotation method's result for one rate.
#[derive(Clone, Debug)]
pub struct RotationCalibration {
    /// From the exact Gram matrix: the result.
    pub intrinsic: Intrinsic,
    /// Seed 000's phase-difference angles φ_uv, φ_vw, φ_wu (degrees), for comparison.
    pub phase_angles_deg: [Estimate; 3],
}

/// Intrinsic properties from the fits of conditions x, y, z, in gravity `g` ± `u_g`.
pub fn rotation(
    fits: [&FitResult<f64>; 3],
    g: f64,
    u_g: f64,
) -> Result<RotationCalibration, IntrinsicError> {
    let cf = fits.map(condition_fit);
    Ok(RotationCalibration {
        intrinsic: intrinsic::from_gram(&cf, g, u_g)?,
        phase_angles_deg: intrinsic::from_phase_differences(&cf)?,
    })
}
