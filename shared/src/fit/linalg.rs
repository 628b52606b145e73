//! Small dense linear algebra for the fit's ≤ 6×6 normal equations.
//!
//! Index helpers return [`FitError::Internal`] instead of panicking: every index here is
//! below `MAX_PARAMS` by construction, but the crate forbids code that could panic.

use super::{FitError, MAX_PARAMS};
use crate::dword::DoubleWord;
use crate::real::Real;

pub(crate) type Mat<T> = [[T; MAX_PARAMS]; MAX_PARAMS];
pub(crate) type Vector<T> = [T; MAX_PARAMS];

pub(crate) fn at<T: Copy>(m: &Mat<T>, i: usize, j: usize) -> Result<T, FitError> {
    m.get(i)
        .and_then(|row| row.get(j))
        .copied()
        .ok_or(FitError::Internal)
}

pub(crate) fn at_mut<T>(m: &mut Mat<T>, i: usize, j: usize) -> Result<&mut T, FitError> {
    m.get_mut(i)
        .and_then(|row| row.get_mut(j))
        .ok_or(FitError::Internal)
}

pub(crate) fn el<T: Copy>(v: &Vector<T>, i: usize) -> Result<T, FitError> {
    v.get(i).copied().ok_or(FitError::Internal)
}

pub(crate) fn el_mut<T>(v: &mut Vector<T>, i: usize) -> Result<&mut T, FitError> {
    v.get_mut(i).ok_or(FitError::Internal)
}

/// Cholesky factor of the equilibrated matrix `D·M·D` with `D = diag(1/√M_ii)`, which
/// makes the factorisation independent of the regressors' scales (seconds vs. unitless).
pub(crate) struct Cholesky<T> {
    l: Mat<T>,
    d: Vector<T>,
    p: usize,
}

impl<T: Real> Cholesky<T> {
    /// Factor the leading `p×p` block of the symmetric matrix `m`. Fails with
    /// [`FitError::Singular`] when a pivot falls below `100·u` of the unit diagonal, i.e.
    /// when the condition number is too large for refinement to recover full accuracy.
    pub(crate) fn new(m: &Mat<T>, p: usize) -> Result<Self, FitError> {
        let mut d = [T::ZERO; MAX_PARAMS];
        for i in 0..p {
            let mii = at(m, i, i)?;
            if !(mii.is_finite() && mii > T::ZERO) {
                return Err(FitError::Singular);
            }
            *el_mut(&mut d, i)? = T::ONE / mii.sqrt();
        }
        let tol = T::from_f64(100.0) * T::EPSILON;
        let mut l = [[T::ZERO; MAX_PARAMS]; MAX_PARAMS];
        for i in 0..p {
            for j in 0..=i {
                let mut s = at(m, i, j)? * el(&d, i)? * el(&d, j)?;
                for k in 0..j {
                    s -= at(&l, i, k)? * at(&l, j, k)?;
                }
                if i == j {
                    if !(s.is_finite() && s > tol) {
                        return Err(FitError::Singular);
                    }
                    *at_mut(&mut l, i, i)? = s.sqrt();
                } else {
                    *at_mut(&mut l, i, j)? = s / at(&l, j, j)?;
                }
            }
        }
        Ok(Cholesky { l, d, p })
    }

    /// Solve `M·x = b`.
    pub(crate) fn solve(&self, b: &Vector<T>) -> Result<Vector<T>, FitError> {
        let p = self.p;
        let mut z = [T::ZERO; MAX_PARAMS];
        for i in 0..p {
            let mut s = el(b, i)? * el(&self.d, i)?;
            for k in 0..i {
                s -= at(&self.l, i, k)? * el(&z, k)?;
            }
            *el_mut(&mut z, i)? = s / at(&self.l, i, i)?;
        }
        for i in (0..p).rev() {
            let mut s = el(&z, i)?;
            for k in i + 1..p {
                s -= at(&self.l, k, i)? * el(&z, k)?;
            }
            *el_mut(&mut z, i)? = s / at(&self.l, i, i)?;
        }
        for (zi, di) in z.iter_mut().zip(self.d.iter()).take(p) {
            *zi = *zi * *di;
        }
        Ok(z)
    }
}

/// Solve `M·x = b` to double-word accuracy by iterative refinement: each correction is
/// solved in `T` with the Cholesky factor of `M` rounded to `T`, while the residual
/// `b − M·x` is formed in double-word arithmetic. Converges while cond(M)·u ≪ 1, which
/// the pivot threshold of [`Cholesky::new`] ensures.
pub(crate) fn refine<T: Real>(
    m: &Mat<DoubleWord<T>>,
    b: &Vector<DoubleWord<T>>,
    chol: &Cholesky<T>,
) -> Result<Vector<DoubleWord<T>>, FitError> {
    const ITERATIONS: usize = 3;
    let p = chol.p;
    let mut x = [DoubleWord::<T>::ZERO; MAX_PARAMS];
    for _ in 0..ITERATIONS {
        let mut r = [T::ZERO; MAX_PARAMS];
        for i in 0..p {
            let mut ri = el(b, i)?;
            for j in 0..p {
                ri = ri - at(m, i, j)? * el(&x, j)?;
            }
            *el_mut(&mut r, i)? = ri.to_t();
        }
        let dx = chol.solve(&r)?;
        for (xi, di) in x.iter_mut().zip(dx.iter()).take(p) {
            *xi = *xi + DoubleWord::from_t(*di);
        }
    }
    Ok(x)
}

/// `M⁻¹` (leading `p×p` block; the rest zero), each column refined like [`refine`], so
/// the standard errors are as accurate as the parameters.
pub(crate) fn refined_inverse<T: Real>(
    m: &Mat<DoubleWord<T>>,
    chol: &Cholesky<T>,
) -> Result<Mat<T>, FitError> {
    let mut inv = [[T::ZERO; MAX_PARAMS]; MAX_PARAMS];
    for j in 0..chol.p {
        let mut e = [DoubleWord::<T>::ZERO; MAX_PARAMS];
        *el_mut(&mut e, j)? = DoubleWord::from_t(T::ONE);
        let col = refine(m, &e, chol)?;
        for i in 0..chol.p {
            *at_mut(&mut inv, i, j)? = el(&col, i)?.to_t();
        }
    }
    Ok(inv)
}
