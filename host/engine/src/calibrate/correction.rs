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

use nalgebra::{DMatrix, Matrix3, Vector3};
use rotacal_shared::Channel;
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
    /// An invariant of the engine failed: a bug in rotacal, not a problem of the data.
    #[error("internal: {0} (a bug in rotacal; please report it)")]
    Internal(&'static str),
}

fn to_m3(m: &[[f64; 3]; 3]) -> Matrix3<f64> {
    // nalgebra takes the arrays for columns: transposed, they are the rows.
    Matrix3::from(*m).transpose()
}

/// Nine values, row-major, as a 3 × 3 matrix (none unless there are nine).
fn unpack(x: &[f64]) -> Option<[[f64; 3]; 3]> {
    let [m00, m01, m02, m10, m11, m12, m20, m21, m22] = <[f64; 9]>::try_from(x).ok()?;
    Some([[m00, m01, m02], [m10, m11, m12], [m20, m21, m22]])
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
    for ((k, xk), mut column) in x.iter().enumerate().zip(j.column_iter_mut()) {
        let h = 1e-6 * xk.abs().max(1e-3 * big);
        let mut xp = x.to_vec();
        let mut xm = x.to_vec();
        if let (Some(p), Some(m)) = (xp.get_mut(k), xm.get_mut(k)) {
            *p += h;
            *m -= h;
        }
        let (yp, ym) = (f(&xp)?, f(&xm)?);
        for (out, (a, b)) in column.iter_mut().zip(yp.iter().zip(&ym)) {
            *out = (a - b) / (2.0 * h);
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
        let d = Channel::ALL.map(|ch| ch.of(&y) - ch.of(&self.offset));
        let a = self
            .matrix
            .map(|row| row.iter().zip(&d).map(|(m, d)| m * d).sum());
        // ∂a_i/∂M_ik = d_k, ∂a_i/∂O_k = −M_ik.
        let u = Channel::ALL.map(|i| {
            // (M row-major, O): d in row i's block, zeros in the others', then −M_i.
            let blocks = Channel::ALL
                .into_iter()
                .flat_map(|b| if b == i { d } else { [0.0; 3] });
            let minus_m = i.of(&self.matrix).map(|m| -m);
            let mut jrow = [0.0; PARAMS];
            for (out, v) in jrow.iter_mut().zip(blocks.chain(minus_m)) {
                *out = v;
            }
            // The covariance is 12 × 12 (`new`, and checked where a file is read).
            let mut var = 0.0;
            for (jp, row) in jrow.iter().zip(&self.covariance) {
                for (jq, c) in jrow.iter().zip(row) {
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
    let flat = |m: Option<[[f64; 3]; 3]>| -> Option<Vec<f64>> { Some(m?.concat()) };
    // (x and its perturbations have nine values.)
    let dev = |x: &[f64]| flat(device_matrix(&gram_of(&unpack(x)?)));
    let pla = |x: &[f64]| flat(platter_matrix(&unpack(x)?));
    let build = |frame, f: &dyn Fn(&[f64]) -> Option<Vec<f64>>| {
        let m = f(&x).ok_or(CorrectionError::Singular)?;
        let jm = jacobian(f, &x).ok_or(CorrectionError::Singular)?;
        let mut j = DMatrix::zeros(PARAMS, PARAMS);
        j.view_mut((0, 0), (9, 9)).copy_from(&jm);
        j.view_mut((9, 9), (3, 3)).fill_diagonal(1.0);
        let m = unpack(&m).ok_or(CorrectionError::Internal("M without nine elements"))?;
        Correction::new(frame, m, offset, &(&j * cov * j.transpose()))
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
    cov.view_mut((9, 9), (3, 3))
        .set_diagonal(&Vector3::from(offset_std.map(|s| s * s)));
    let matrix = unpack(&m).ok_or(CorrectionError::Internal("M without nine elements"))?;
    Correction::new(Frame::Device, matrix, offset, &cov)
}
