//! The correction that turns readings into acceleration: `a = M·(y − O)` in m/s².
//!
//! Two frames (docs/calibration.md, "Applying a calibration"):
//! - **device**: the device's own orthonormal frame x′ y′ z′, x′ along u's sensitive axis,
//!   y′ in the plane of u's and v's, z′ completing it on w's side. From the Gram matrix
//!   G = S·Sᵀ = L·Lᵀ (Cholesky, L lower triangular): M = L⁻¹, because y − O = S·a_platter
//!   = L·(Q·a_platter) with Q = L⁻¹·S orthonormal. It needs only G, so the rotation method
//!   gives it too.
//! - **platter**: the frame the poses were given in, M = S⁻¹ (static data only: the
//!   rotation method does not fix how the device sat on the platter).
//!
//! Both give the same |a|. The covariance of (M, O) comes from the calibration's own by
//! linear propagation with a numerical Jacobian; [`Correction::apply`] uses it to give
//! each corrected reading its standard uncertainty from the calibration (the reading's own
//! noise is not included: it is the measurement, not the correction).

use nalgebra::{DMatrix, Matrix3};
use serde::{Deserialize, Serialize};

/// A Gram matrix as a function of parameters.
pub type GramFn<'a> = dyn Fn(&[f64]) -> Option<[[f64; 3]; 3]> + 'a;

/// Number of correction parameters: M row-major, then O.
pub const PARAMS: usize = 12;

/// The frame of the corrected acceleration.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Frame {
    /// The device's own orthonormal frame (from the Gram matrix).
    Device,
    /// The platter (pose) frame: static data only.
    Platter,
}

impl Frame {
    /// `device` or `platter`.
    pub const fn as_str(self) -> &'static str {
        match self {
            Frame::Device => "device",
            Frame::Platter => "platter",
        }
    }
}

/// The convention, written into every calibration file beside the numbers.
pub const CONVENTION: &str = "a = M · (y − O). y: the reading (u, v, w) in the file's units; \
O: the offset, in those units; M: the 3×3 matrix, m/s² per unit, rows give a's components; \
a: acceleration (specific force: +g along the axis that points up) in m/s². device frame: x′ \
along u's sensitive axis, y′ in the plane of u's and v's, z′ completing an orthonormal frame on \
w's side; M = L⁻¹ with L the lower Cholesky factor of the Gram matrix G = S·Sᵀ. platter frame: \
the frame the gravity directions were given in; M = S⁻¹. covariance: of (M row-major, O), 12×12.";

/// One frame's correction with its uncertainty.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Correction {
    /// The frame of `a`.
    pub frame: Frame,
    /// M, m/s² per output unit.
    pub matrix: [[f64; 3]; 3],
    /// Standard uncertainties of M.
    pub matrix_std_unc: [[f64; 3]; 3],
    /// O, output units.
    pub offset: [f64; 3],
    /// Standard uncertainties of O.
    pub offset_std_unc: [f64; 3],
    /// Covariance of (M row-major, O).
    pub covariance: Vec<Vec<f64>>,
}

/// Why no correction could be made.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum CorrectionError {
    /// S is singular or G not positive definite.
    #[error("the sensitivity matrix is singular: no correction")]
    Singular,
    /// A covariance of the wrong size.
    #[error("the correction's covariance must be 12×12")]
    Covariance,
}

fn to_m3(m: &[[f64; 3]; 3]) -> Matrix3<f64> {
    Matrix3::from_fn(|i, j| m[i][j])
}

fn from_m3(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    [0, 1, 2].map(|i| [0, 1, 2].map(|j| m[(i, j)]))
}

/// L⁻¹ for G = L·Lᵀ.
pub fn device_matrix(gram: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let l = to_m3(gram).cholesky()?.l();
    l.try_inverse().map(|m| from_m3(&m))
}

/// S⁻¹.
pub fn platter_matrix(s: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    to_m3(s).try_inverse().map(|m| from_m3(&m))
}

/// S·Sᵀ.
pub fn gram_of(s: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let m = to_m3(s);
    from_m3(&(m * m.transpose()))
}

/// The Jacobian of `f` at `x` by central differences. The step for x_k is 1e-6 of |x_k|,
/// but not below 1e-9 of the largest |x| (so that an element near zero still moves).
pub fn jacobian(f: &dyn Fn(&[f64]) -> Option<Vec<f64>>, x: &[f64]) -> Option<DMatrix<f64>> {
    let y0 = f(x)?;
    let big = x.iter().fold(0.0f64, |a, v| a.max(v.abs())).max(1e-300);
    let mut j = DMatrix::zeros(y0.len(), x.len());
    for k in 0..x.len() {
        let h = 1e-6 * x.get(k).map_or(big, |v| v.abs()).max(1e-3 * big);
        let mut xp = x.to_vec();
        let mut xm = x.to_vec();
        if let (Some(p), Some(m)) = (xp.get_mut(k), xm.get_mut(k)) {
            *p += h;
            *m -= h;
        }
        let (yp, ym) = (f(&xp)?, f(&xm)?);
        for (i, (a, b)) in yp.iter().zip(&ym).enumerate() {
            j[(i, k)] = (a - b) / (2.0 * h);
        }
    }
    Some(j)
}

/// Covariance of `f(x)` by linear propagation, `J·Σ·Jᵀ`.
pub fn propagate(
    f: &dyn Fn(&[f64]) -> Option<Vec<f64>>,
    x: &[f64],
    cov: &DMatrix<f64>,
) -> Option<DMatrix<f64>> {
    let j = jacobian(f, x)?;
    Some(&j * cov * j.transpose())
}

impl Correction {
    /// From M, O and the covariance of (M row-major, O).
    pub fn new(
        frame: Frame,
        matrix: [[f64; 3]; 3],
        offset: [f64; 3],
        cov: &DMatrix<f64>,
    ) -> Result<Self, CorrectionError> {
        if cov.nrows() != PARAMS || cov.ncols() != PARAMS {
            return Err(CorrectionError::Covariance);
        }
        let sd = |k: usize| cov[(k, k)].max(0.0).sqrt();
        Ok(Correction {
            frame,
            matrix,
            matrix_std_unc: [0, 1, 2].map(|i| [0, 1, 2].map(|j| sd(3 * i + j))),
            offset,
            offset_std_unc: [0, 1, 2].map(|j| sd(9 + j)),
            covariance: (0..PARAMS)
                .map(|i| (0..PARAMS).map(|j| cov[(i, j)]).collect())
                .collect(),
        })
    }

    /// The corrected acceleration for reading `y`, m/s², and its standard uncertainty
    /// from the calibration (per component).
    pub fn apply(&self, y: [f64; 3]) -> ([f64; 3], [f64; 3]) {
        let d = [0, 1, 2].map(|k| y[k] - self.offset[k]);
        let a = self.matrix.map(|row| (0..3).map(|k| row[k] * d[k]).sum());
        // ∂a_i/∂M_ik = d_k, ∂a_i/∂O_k = −M_ik.
        let u = [0, 1, 2].map(|i| {
            let mut jrow = [0.0; PARAMS];
            for k in 0..3 {
                jrow[3 * i + k] = d[k];
                jrow[9 + k] = -self.matrix[i][k];
            }
            let mut var = 0.0;
            for (p, jp) in jrow.iter().enumerate() {
                for (q, jq) in jrow.iter().enumerate() {
                    let c = self
                        .covariance
                        .get(p)
                        .and_then(|r| r.get(q))
                        .copied()
                        .unwrap_or(0.0);
                    var += jp * c * jq;
                }
            }
            var.max(0.0).sqrt()
        });
        (a, u)
    }
}

/// Device- and platter-frame corrections from S and O with the covariance of
/// (S row-major, O) (static data). M depends on S alone, so the Jacobian of (M, O) is
/// block-diagonal: numerical for M, the identity for O.
pub fn from_matrix(
    s: &[[f64; 3]; 3],
    offset: [f64; 3],
    cov: &DMatrix<f64>,
) -> Result<(Correction, Correction), CorrectionError> {
    if cov.nrows() != PARAMS || cov.ncols() != PARAMS {
        return Err(CorrectionError::Covariance);
    }
    let x: Vec<f64> = s.iter().flatten().copied().collect();
    let unpack = |x: &[f64]| -> [[f64; 3]; 3] {
        [0, 1, 2].map(|i| [0, 1, 2].map(|j| x.get(3 * i + j).copied().unwrap_or(f64::NAN)))
    };
    let flat = |m: Option<[[f64; 3]; 3]>| -> Option<Vec<f64>> { Some(m?.concat()) };
    let dev = |x: &[f64]| flat(device_matrix(&gram_of(&unpack(x))));
    let pla = |x: &[f64]| flat(platter_matrix(&unpack(x)));
    let build = |frame, f: &dyn Fn(&[f64]) -> Option<Vec<f64>>| {
        let m = f(&x).ok_or(CorrectionError::Singular)?;
        let jm = jacobian(f, &x).ok_or(CorrectionError::Singular)?;
        let mut j = DMatrix::zeros(PARAMS, PARAMS);
        j.view_mut((0, 0), (9, 9)).copy_from(&jm);
        for k in 9..PARAMS {
            j[(k, k)] = 1.0;
        }
        Correction::new(frame, unpack(&m), offset, &(&j * cov * j.transpose()))
    };
    Ok((build(Frame::Device, &dev)?, build(Frame::Platter, &pla)?))
}

/// The device-frame correction from a Gram matrix that is a function `gram(θ)` of
/// parameters θ with covariance `cov_theta`, and offsets with their standard
/// uncertainties (independent of θ) (rotation data).
pub fn from_gram(
    gram: &GramFn<'_>,
    theta: &[f64],
    cov_theta: &DMatrix<f64>,
    offset: [f64; 3],
    offset_std: [f64; 3],
) -> Result<Correction, CorrectionError> {
    let f = |x: &[f64]| -> Option<Vec<f64>> {
        Some(
            device_matrix(&gram(x)?)?
                .iter()
                .flatten()
                .copied()
                .collect(),
        )
    };
    let m = f(theta).ok_or(CorrectionError::Singular)?;
    let cm = propagate(&f, theta, cov_theta).ok_or(CorrectionError::Singular)?;
    let mut cov = DMatrix::zeros(PARAMS, PARAMS);
    cov.view_mut((0, 0), (9, 9)).copy_from(&cm);
    for (k, s) in offset_std.iter().enumerate() {
        cov[(9 + k, 9 + k)] = s * s;
    }
    let matrix =
        [0, 1, 2].map(|i| [0, 1, 2].map(|j| m.get(3 * i + j).copied().unwrap_or(f64::NAN)));
    Correction::new(Frame::Device, matrix, offset, &cov)
}
