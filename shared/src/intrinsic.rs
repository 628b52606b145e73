//! Intrinsic properties from the three rotation conditions, done exactly (docs/method.md §2).
//!
//! For each condition and channels j, k: `P_jk = A_j·A_k + B_j·B_k = g²·(in-plane dot product
//! of S_j and S_k)`. The three planes count every component twice, so the Gram matrix
//! `G = S·Sᵀ = (Pˣ + Pʸ + Pᶻ)/(2g²)` is exact at any mounting: `s_j = √G_jj` and
//! `cos φ_jk = G_jk/(s_j·s_k)`. The phase-difference angles of Gaitan & Geist (2022) (eqs. 12–16) are
//! also given, computed with atan2: they are the angles between the *projections* of S_j
//! and S_k on one plane and are biased once the device is tilted (docs/method.md §2).
//!
//! Uncertainties: first-order propagation with the full covariance of each fit's (A, B)
//! (the A–B correlation included); fits of different channels and conditions are
//! independent. The Jacobians are analytic, from the formulas above.
//!
//! Computed in f64 on every target: this runs once per calibration (on the device, in
//! software floating point, a few hundred operations).

/// What one condition's fits give: per channel u, v, w, the coefficients of `sin α` and
/// `cos α` and their 2×2 covariance `[[var A, cov AB], [cov AB, var B]]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ConditionFit {
    /// A per channel (output units).
    pub a: [f64; 3],
    /// B per channel (output units).
    pub b: [f64; 3],
    /// Covariance of (A, B) per channel.
    pub cov: [[[f64; 2]; 2]; 3],
}

impl ConditionFit {
    /// From a condition's fit (any model: A and B are its sine and cosine terms).
    pub fn from_fit<T: crate::Real, const CH: usize>(fit: &crate::FitResult<T, CH>) -> Self {
        use crate::Param;
        let mut out = ConditionFit {
            a: [0.0; 3],
            b: [0.0; 3],
            cov: [[[0.0; 2]; 2]; 3],
        };
        for (ch, ((a, b), cov)) in out
            .a
            .iter_mut()
            .zip(out.b.iter_mut())
            .zip(out.cov.iter_mut())
            .enumerate()
        {
            let get = |p| fit.coef(ch, p).map_or(f64::NAN, |v| v.to_f64());
            let c = |p, q| fit.covariance(ch, p, q).map_or(f64::NAN, |v| v.to_f64());
            *a = get(Param::A);
            *b = get(Param::B);
            *cov = [
                [c(Param::A, Param::A), c(Param::A, Param::B)],
                [c(Param::B, Param::A), c(Param::B, Param::B)],
            ];
        }
        out
    }
}

/// A value and its standard uncertainty.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Estimate {
    /// The value.
    pub value: f64,
    /// Its standard uncertainty (k = 1).
    pub std_unc: f64,
}

/// The channel pairs of the angles, in the order uv, vw, wu.
pub const ANGLE_PAIRS: [(usize, usize); 3] = [(0, 1), (1, 2), (2, 0)];

/// Intrinsic sensitivities and angles.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intrinsic {
    /// s_u, s_v, s_w in output units per m/s².
    pub sensitivity: [Estimate; 3],
    /// φ_uv, φ_vw, φ_wu in degrees.
    pub angle_deg: [Estimate; 3],
    /// Covariance of (s_u, s_v, s_w, φ_uv, φ_vw, φ_wu), angles in degrees.
    pub cov: [[f64; 6]; 6],
    /// The Gram matrix S·Sᵀ, (output units per m/s²)².
    pub gram: [[f64; 3]; 3],
}

/// Why no intrinsic properties could be computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum IntrinsicError {
    /// g is not a positive finite number.
    BadGravity,
    /// A channel shows no response, two channels are parallel, or an input is not
    /// finite: the sensitivities and angles are not defined.
    Degenerate,
}

impl core::fmt::Display for IntrinsicError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            IntrinsicError::BadGravity => write!(f, "g_loc must be a positive number"),
            IntrinsicError::Degenerate => write!(
                f,
                "the fits do not define the intrinsic properties (a dead channel, parallel axes or non-finite input)"
            ),
        }
    }
}

impl core::error::Error for IntrinsicError {}

fn at(v: &[f64; 3], i: usize) -> f64 {
    // Indices here are the constants 0..3; NaN (caught at the end) rather than a panic.
    v.get(i).copied().unwrap_or(f64::NAN)
}

/// ∂output/∂(A, B) of one channel of one condition, for the six outputs.
type Gradients = [[[[f64; 2]; 3]; 3]; 6];

fn propagate(grad: &Gradients, fits: &[ConditionFit; 3]) -> [[f64; 6]; 6] {
    let mut cov = [[0.0; 6]; 6];
    for (row, gi) in cov.iter_mut().zip(grad.iter()) {
        for (out, gj) in row.iter_mut().zip(grad.iter()) {
            let mut sum = 0.0;
            for ((fit, ci), cj) in fits.iter().zip(gi.iter()).zip(gj.iter()) {
                for ((c, a), b) in fit.cov.iter().zip(ci.iter()).zip(cj.iter()) {
                    let [[caa, cab], [cba, cbb]] = *c;
                    sum += a[0] * (caa * b[0] + cab * b[1]) + a[1] * (cba * b[0] + cbb * b[1]);
                }
            }
            *out = sum;
        }
    }
    cov
}

fn estimates(values: [f64; 6], cov: &[[f64; 6]; 6]) -> [Estimate; 6] {
    let mut out = [Estimate {
        value: 0.0,
        std_unc: 0.0,
    }; 6];
    for ((o, v), (i, row)) in out.iter_mut().zip(values).zip(cov.iter().enumerate()) {
        let var = row.get(i).copied().unwrap_or(f64::NAN);
        *o = Estimate {
            value: v,
            std_unc: libm::sqrt(if var > 0.0 { var } else { 0.0 }),
        };
    }
    out
}

/// The result from the six values (s_u, s_v, s_w, φ_uv, φ_vw, φ_wu) and their covariance,
/// or `Degenerate` if anything is not finite.
fn finish(
    values: [f64; 6],
    cov: [[f64; 6]; 6],
    gram: [[f64; 3]; 3],
) -> Result<Intrinsic, IntrinsicError> {
    let finite = values
        .iter()
        .chain(cov.iter().flatten())
        .all(|v| v.is_finite());
    if !finite {
        return Err(IntrinsicError::Degenerate);
    }
    let [e0, e1, e2, e3, e4, e5] = estimates(values, &cov);
    Ok(Intrinsic {
        sensitivity: [e0, e1, e2],
        angle_deg: [e3, e4, e5],
        cov,
        gram,
    })
}

/// Intrinsic sensitivities and angles from the fits of conditions x, y, z (in that
/// order) in gravity `g` (m/s²), whose standard uncertainty `u_g` enters the
/// sensitivities (s ∝ 1/g) but not the angles.
pub fn from_gram(fits: &[ConditionFit; 3], g: f64, u_g: f64) -> Result<Intrinsic, IntrinsicError> {
    if !(g.is_finite() && g > 0.0 && u_g.is_finite() && u_g >= 0.0) {
        return Err(IntrinsicError::BadGravity);
    }
    let two_g2 = 2.0 * g * g;
    let mut gram = [[0.0; 3]; 3];
    for fit in fits {
        for (j, row) in gram.iter_mut().enumerate() {
            for (k, gjk) in row.iter_mut().enumerate() {
                *gjk += (at(&fit.a, j) * at(&fit.a, k) + at(&fit.b, j) * at(&fit.b, k)) / two_g2;
            }
        }
    }
    let gjk = |j: usize, k: usize| gram.get(j).map(|r| at(r, k)).unwrap_or(f64::NAN);
    let s = [0, 1, 2].map(|j| libm::sqrt(gjk(j, j)));
    let cosines = ANGLE_PAIRS.map(|(j, k)| gjk(j, k) / (at(&s, j) * at(&s, k)));
    let positive = s.iter().all(|v| v.is_finite() && *v > 0.0);
    if !positive || !cosines.iter().all(|c| c.is_finite() && c.abs() < 1.0) {
        return Err(IntrinsicError::Degenerate);
    }
    let angles = cosines.map(|c| libm::acos(c).to_degrees());

    // ∂G_jk/∂A_m = (δ_jm A_k + δ_km A_j)/(2g²), likewise B.
    let dg = |fit: &ConditionFit, j: usize, k: usize, m: usize| -> [f64; 2] {
        let mut d = [0.0; 2];
        if j == m {
            d[0] += at(&fit.a, k);
            d[1] += at(&fit.b, k);
        }
        if k == m {
            d[0] += at(&fit.a, j);
            d[1] += at(&fit.b, j);
        }
        d.map(|x| x / two_g2)
    };
    let mut grad: Gradients = [[[[0.0; 2]; 3]; 3]; 6];
    for (o, go) in grad.iter_mut().enumerate() {
        for (fit, gc) in fits.iter().zip(go.iter_mut()) {
            for (m, gm) in gc.iter_mut().enumerate() {
                *gm = if o < 3 {
                    // s_j = √G_jj: ∂s_j = ∂G_jj / (2 s_j)
                    dg(fit, o, o, m).map(|d| d / (2.0 * at(&s, o)))
                } else {
                    // φ = acos r, r = G_jk/(s_j s_k):
                    // ∂r = ∂G_jk/(s_j s_k) − r·(∂G_jj/(2 s_j²) + ∂G_kk/(2 s_k²))
                    let (j, k) = ANGLE_PAIRS.get(o - 3).copied().unwrap_or((0, 0));
                    let r = at(&cosines, o - 3);
                    let (sj, sk) = (at(&s, j), at(&s, k));
                    let (d_jk, d_jj, d_kk) = (dg(fit, j, k, m), dg(fit, j, j, m), dg(fit, k, k, m));
                    let dphi = -(1.0 / libm::sqrt(1.0 - r * r)).to_degrees();
                    [0, 1].map(|i| {
                        let pick = |d: [f64; 2]| d.get(i).copied().unwrap_or(f64::NAN);
                        dphi * (pick(d_jk) / (sj * sk)
                            - r * (pick(d_jj) / (2.0 * sj * sj) + pick(d_kk) / (2.0 * sk * sk)))
                    })
                };
            }
        }
    }
    let mut cov = propagate(&grad, fits);
    // g: s_j ∝ 1/g, so ∂s_j/∂g = −s_j/g; independent of the fits.
    for (i, row) in cov.iter_mut().enumerate().take(3) {
        for (j, c) in row.iter_mut().enumerate().take(3) {
            *c += at(&s, i) * at(&s, j) * (u_g / g) * (u_g / g);
        }
    }
    let values = [s[0], s[1], s[2], angles[0], angles[1], angles[2]];
    finish(values, cov, gram)
}

/// Gaitan & Geist (2022)'s phase-difference angles (eqs. 12–16), with atan2 so there is no 180°
/// ambiguity: φ_uv from condition z, φ_vw from x, φ_wu from y (the two channels with the
/// large signals in each). Each is the angle between the two channels' (A, B) vectors,
/// i.e. between the projections of S_j and S_k on that condition's plane. In degrees.
pub fn from_phase_differences(fits: &[ConditionFit; 3]) -> Result<[Estimate; 3], IntrinsicError> {
    // (condition index, j, k) for uv, vw, wu.
    const USE: [(usize, usize, usize); 3] = [(2, 0, 1), (0, 1, 2), (1, 2, 0)];
    let mut out = [Estimate {
        value: 0.0,
        std_unc: 0.0,
    }; 3];
    for (o, (c, j, k)) in out.iter_mut().zip(USE) {
        let fit = fits.get(c).ok_or(IntrinsicError::Degenerate)?;
        let (aj, bj, ak, bk) = (at(&fit.a, j), at(&fit.b, j), at(&fit.a, k), at(&fit.b, k));
        let cross = aj * bk - bj * ak;
        let dot = aj * ak + bj * bk;
        let n2 = cross * cross + dot * dot; // = |p_j|²·|p_k|²
        if !(n2.is_finite() && n2 > 0.0) {
            return Err(IntrinsicError::Degenerate);
        }
        let phi = libm::atan2(cross, dot);
        // d atan2(y, x) = (x dy − y dx)/(x² + y²), and |φ| flips the sign for φ < 0.
        let sign = if phi < 0.0 { -1.0 } else { 1.0 };
        let d = |dcross: f64, ddot: f64| sign * (dot * dcross - cross * ddot) / n2;
        let gj = [d(bk, ak), d(-ak, bk)]; // ∂/∂A_j, ∂/∂B_j
        let gk = [d(-bj, aj), d(aj, bj)]; // ∂/∂A_k, ∂/∂B_k
        let var = |g: [f64; 2], m: usize| {
            let [[caa, cab], [cba, cbb]] = fit.cov.get(m).copied().unwrap_or([[f64::NAN; 2]; 2]);
            g[0] * (caa * g[0] + cab * g[1]) + g[1] * (cba * g[0] + cbb * g[1])
        };
        let var_deg = (var(gj, j) + var(gk, k)).to_degrees().to_degrees();
        if !var_deg.is_finite() {
            return Err(IntrinsicError::Degenerate);
        }
        *o = Estimate {
            value: libm::fabs(phi).to_degrees(),
            std_unc: libm::sqrt(var_deg.max(0.0)),
        };
    }
    Ok(out)
}

/// Intrinsic sensitivities and angles from a sensitivity matrix `s` (rows u, v, w, in
/// output units per m/s²) whose rows are estimated independently with covariances
/// `row_cov[j]` (3×3): [`from_matrix_cov`] with a block-diagonal covariance.
pub fn from_matrix(
    s: &[[f64; 3]; 3],
    row_cov: &[[[f64; 3]; 3]; 3],
) -> Result<Intrinsic, IntrinsicError> {
    let mut full = [[0.0; 9]; 9];
    for (j, block) in row_cov.iter().enumerate() {
        for (a, brow) in block.iter().enumerate() {
            if let Some(frow) = full.get_mut(3 * j + a) {
                for (b, x) in brow.iter().enumerate() {
                    if let Some(f) = frow.get_mut(3 * j + b) {
                        *f = *x;
                    }
                }
            }
        }
    }
    from_matrix_cov(s, &full)
}

/// Intrinsic sensitivities and angles from a sensitivity matrix `s` (rows u, v, w, in
/// output units per m/s²) with the covariance `cov` of its nine elements (row-major), as
/// the static method gives them: `s_j = |S_j|`, `cos φ_jk = S_j·S_k/(s_j s_k)`. The rows
/// may be correlated (a pose's tilt moves all three channels).
pub fn from_matrix_cov(
    s: &[[f64; 3]; 3],
    cov9: &[[f64; 9]; 9],
) -> Result<Intrinsic, IntrinsicError> {
    let dot = |a: &[f64; 3], b: &[f64; 3]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let row = |j: usize| s.get(j).copied().unwrap_or([f64::NAN; 3]);
    let norms = [0, 1, 2].map(|j| libm::sqrt(dot(&row(j), &row(j))));
    let cosines = ANGLE_PAIRS.map(|(j, k)| dot(&row(j), &row(k)) / (at(&norms, j) * at(&norms, k)));
    let positive = norms.iter().all(|v| v.is_finite() && *v > 0.0);
    if !positive || !cosines.iter().all(|c| c.is_finite() && c.abs() < 1.0) {
        return Err(IntrinsicError::Degenerate);
    }
    let angles = cosines.map(|c| libm::acos(c).to_degrees());
    // Gradient of each output with respect to the nine elements of S (row-major).
    let mut grad = [[0.0f64; 9]; 6];
    for (o, go) in grad.iter_mut().enumerate() {
        for (m, gm) in go.chunks_exact_mut(3).enumerate() {
            if o < 3 {
                if m == o {
                    // ∂|S_m|/∂S_m = S_m/s_m
                    for (g, x) in gm.iter_mut().zip(row(m)) {
                        *g = x / at(&norms, m);
                    }
                }
            } else {
                let (j, k) = ANGLE_PAIRS.get(o - 3).copied().unwrap_or((0, 0));
                let r = at(&cosines, o - 3);
                let dphi = -(1.0 / libm::sqrt(1.0 - r * r)).to_degrees();
                let (sj, sk) = (at(&norms, j), at(&norms, k));
                // ∂r/∂S_j = S_k/(s_j s_k) − r·S_j/s_j², likewise for k.
                let (this, other, s_this) = if m == j {
                    (row(j), row(k), sj)
                } else if m == k {
                    (row(k), row(j), sk)
                } else {
                    continue;
                };
                for ((g, t), u) in gm.iter_mut().zip(this).zip(other) {
                    *g = dphi * (u / (sj * sk) - r * t / (s_this * s_this));
                }
            }
        }
    }
    let mut cov = [[0.0; 6]; 6];
    for (ci, gi) in cov.iter_mut().zip(grad.iter()) {
        for (c, gj) in ci.iter_mut().zip(grad.iter()) {
            *c = gi
                .iter()
                .zip(cov9.iter())
                .map(|(a, crow)| a * crow.iter().zip(gj).map(|(x, b)| x * b).sum::<f64>())
                .sum();
        }
    }
    let mut gram = [[0.0; 3]; 3];
    for (j, gr) in gram.iter_mut().enumerate() {
        for (k, g) in gr.iter_mut().enumerate() {
            *g = dot(&row(j), &row(k));
        }
    }
    let values = [
        norms[0], norms[1], norms[2], angles[0], angles[1], angles[2],
    ];
    finish(values, cov, gram)
}
