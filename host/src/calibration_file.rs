//! The JSON that `rotacal calibrate --json OUT` writes: exactly the schema of
//! ../shared/docs/formats.md (a contract with tests outside the project: keys may be
//! added, never renamed or removed).

use crate::calibrate::{RotationCalibration, StaticCalibration};
use rotacal_shared::intrinsic::Estimate;
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
        Quantity {
            value: e.value,
            std_unc: e.std_unc,
            expanded_unc: K * e.std_unc,
            k: K,
        }
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

fn uvw(e: [Estimate; 3]) -> Uvw {
    Uvw {
        u: e[0].into(),
        v: e[1].into(),
        w: e[2].into(),
    }
}

fn pairs(e: [Estimate; 3]) -> Pairs {
    Pairs {
        uv: e[0].into(),
        vw: e[1].into(),
        wu: e[2].into(),
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
#[derive(Clone, Debug, Serialize)]
pub struct FitJson {
    /// x, y or z.
    pub condition: String,
    /// u, v or w.
    pub channel: String,
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
}

/// One entry of `by_rate`.
#[derive(Clone, Debug, Serialize)]
pub struct RateJson {
    /// Nominal rate; null for static.
    pub rate_hz: Option<f64>,
    /// The result.
    pub intrinsic: IntrinsicJson,
    /// Seed 000 eqs. 12–16 (rotation only).
    pub angle_deg_phase_method: Option<Pairs>,
    /// Static only.
    pub sensitivity_matrix: Option<MatrixJson>,
    /// Every (condition, channel) fit.
    pub fits: Vec<FitJson>,
    /// With `--monte-carlo N` only (an extension of formats.md): the GUM Supplement 1
    /// propagation of the same inputs, keyed s_u, s_v, s_w, phi_uv, phi_vw, phi_wu.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub monte_carlo: Option<std::collections::BTreeMap<String, crate::calibrate::McSummary>>,
}

/// Keys of the Monte Carlo summaries, in output order.
pub const MC_KEYS: [&str; 6] = ["s_u", "s_v", "s_w", "phi_uv", "phi_vw", "phi_wu"];

/// The `monte_carlo` map from the six summaries.
pub fn mc_map(
    s: [crate::calibrate::McSummary; 6],
) -> std::collections::BTreeMap<String, crate::calibrate::McSummary> {
    MC_KEYS.iter().map(|k| k.to_string()).zip(s).collect()
}

/// The whole file.
#[derive(Clone, Debug, Serialize)]
pub struct CalibrationJson {
    /// "rotation" or "static".
    pub method: String,
    /// m/s².
    pub g_loc: f64,
    /// Output units.
    pub units: String,
    /// One entry per nominal rate (static: one, rate null).
    pub by_rate: Vec<RateJson>,
}

/// The `by_rate` entry of a rotation calibration.
pub fn rotation_entry(rate_hz: f64, cal: &RotationCalibration, fits: Vec<FitJson>) -> RateJson {
    RateJson {
        rate_hz: Some(rate_hz),
        intrinsic: IntrinsicJson {
            sensitivity: uvw(cal.intrinsic.sensitivity),
            angle_deg: pairs(cal.intrinsic.angle_deg),
            offset: None,
        },
        angle_deg_phase_method: Some(pairs(cal.phase_angles_deg)),
        sensitivity_matrix: None,
        fits,
        monte_carlo: None,
    }
}

/// The `by_rate` entry of a static calibration.
pub fn static_entry(cal: &StaticCalibration) -> RateJson {
    let mut fits = Vec::new();
    for (cond, per_ch) in ['x', 'y', 'z'].iter().zip(&cal.fits) {
        for (ch, f) in ['u', 'v', 'w'].iter().zip(per_ch) {
            fits.push(FitJson {
                condition: cond.to_string(),
                channel: ch.to_string(),
                a: f.coef[0],
                b: f.coef[1],
                c: f.coef[2],
                se_a: f.se[0],
                se_b: f.se[1],
                se_c: f.se[2],
                n: f.n as u64,
                rms_residual: f.rms_residual,
                rate_hz_fitted: None,
            });
        }
    }
    RateJson {
        rate_hz: None,
        intrinsic: IntrinsicJson {
            sensitivity: uvw(cal.intrinsic.sensitivity),
            angle_deg: pairs(cal.intrinsic.angle_deg),
            offset: Some(uvw(cal.offsets)),
        },
        angle_deg_phase_method: None,
        sensitivity_matrix: Some(MatrixJson {
            value: cal.s,
            std_unc: cal.s_std,
        }),
        fits,
        monte_carlo: None,
    }
}
