//! Calibration from fits: the rotation method's intrinsic properties.
//!
//! Takes the fits of the three conditions (from `rotacal_shared::SineFit` or the batch
//! fit), assembles each fit's (A, B) covariance, and computes the Gram intrinsic
//! properties and the phase-difference angles with their uncertainties
//! (`rotacal_shared::intrinsic`); and the static stepped method (Gaitan et al. (2021)).

use crate::calibrate::poses::{self, PoseError, PoseFit, StaticCondition};
use crate::fit::batch::{self, BatchError};
use nalgebra::{DMatrix, DVector};
use rotacal_shared::intrinsic::{self, ConditionFit, Estimate, Intrinsic, IntrinsicError};
use rotacal_shared::Channel;

/// The rotation method's result for one rate.
#[derive(Clone, Debug)]
pub struct RotationCalibration {
    /// From the exact Gram matrix: the result.
    pub intrinsic: Intrinsic,
    /// Gaitan & Geist (2022)'s phase-difference angles φ_uv, φ_vw, φ_wu (degrees), for comparison.
    pub phase_angles_deg: [Estimate; 3],
}

/// Intrinsic properties from the (A, B) of conditions x, y, z and their covariances, in
/// gravity `g` (its uncertainty is a term of the budget, `crate::calibrate::budget`).
pub fn rotation(cf: &[ConditionFit; 3], g: f64) -> Result<RotationCalibration, IntrinsicError> {
    Ok(RotationCalibration {
        intrinsic: intrinsic::from_gram(cf, g, 0.0)?,
        phase_angles_deg: intrinsic::from_phase_differences(cf)?,
    })
}

/// A fit `y = A sin α + B cos α + O` of one channel of one condition.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SineFit3 {
    /// A, B, O.
    pub coef: [f64; 3],
    /// Their standard errors.
    pub se: [f64; 3],
    /// Residual RMS.
    pub rms_residual: f64,
    /// Rows fitted.
    pub n: usize,
}

/// The static method's result.
#[derive(Clone, Debug)]
pub struct StaticCalibration {
    /// Sensitivity matrix S (rows u, v, w; columns platter x, y, z), output units per
    /// m/s², from the least-squares fit of S and O to the poses (`crate::calibrate::poses`).
    pub s: [[f64; 3]; 3],
    /// Standard uncertainties of S.
    pub s_std: [[f64; 3]; 3],
    /// Offsets O_u, O_v, O_w (output units), of the chosen estimator.
    pub offsets: [Estimate; 3],
    /// Covariance of the nine elements of S (row-major): rows are correlated when a pose's
    /// tilt moves all three channels.
    pub s_cov: [[f64; 9]; 9],
    /// Intrinsic properties from the rows of S.
    pub intrinsic: Intrinsic,
    /// Gaitan et al. (2021)'s estimator (its eqs. 20–21): each element of S the mean of its two
    /// duplicates, each offset the mean over the conditions. For comparison; stepped
    /// (condition, angle) records only.
    pub duplicate_average: Option<DuplicateAverage>,
    /// Per condition (x, y, z) and channel, the sine fit of Gaitan et al. (2021)'s Table 1; stepped
    /// records only.
    pub fits: Option<[[SineFit3; 3]; 3]>,
    /// The pose fit behind S and O: poses, residuals, τ, conditioning, both offset
    /// estimators.
    pub pose_fit: PoseFit,
}

/// Gaitan et al. (2021)'s duplicate-averaging estimator, with standard uncertainties from the fits'
/// standard errors (independent conditions).
#[derive(Clone, Copy, Debug)]
pub struct DuplicateAverage {
    /// S, output units per m/s².
    pub s: [[Estimate; 3]; 3],
    /// Offsets.
    pub offsets: [Estimate; 3],
}

/// Why the static method failed.
#[derive(Debug, thiserror::Error)]
pub enum StaticError {
    /// A condition is missing or given twice.
    #[error("static calibration needs each of the conditions x, y and z exactly once")]
    Conditions,
    /// Columns of unequal length.
    #[error("condition {0}: angle and reading columns differ in length")]
    Lengths(char),
    /// A least-squares problem failed.
    #[error("condition {0}: {1}")]
    Fit(char, BatchError),
    /// The poses cannot be fitted.
    #[error(transparent)]
    Poses(#[from] PoseError),
    /// No intrinsic properties.
    #[error(transparent)]
    Intrinsic(#[from] IntrinsicError),
    /// An invariant of the engine failed: a bug in rotacal, not a problem of the data.
    #[error("internal: {0} (a bug in rotacal; please report it)")]
    Internal(&'static str),
}

/// The stepped static method (Gaitan et al. (2021)): the per-condition sine fits of its Table 1 and
/// its duplicate-averaging estimator for comparison; the result is the fit of S and O to
/// the poses (one per condition and table angle, `y = g·S_j·ĝ(α) + O_j`, docs/method.md §3),
/// then intrinsic properties from the rows of S with the rows' covariances.
pub fn static_method(
    conds: &[StaticCondition<'_>],
    g: f64,
    opts: poses::Options,
) -> Result<StaticCalibration, StaticError> {
    let mut by_cond: [Option<&StaticCondition<'_>>; 3] = [None; 3];
    for c in conds {
        let slot = by_cond
            .get_mut(c.condition.index())
            .ok_or(StaticError::Internal("a condition beyond x, y and z"))?;
        if slot.is_some() {
            return Err(StaticError::Conditions);
        }
        if c.y.iter().any(|y| y.len() != c.angle_deg.len()) {
            return Err(StaticError::Lengths(c.condition.letter()));
        }
        *slot = Some(c);
    }
    let [Some(cx), Some(cy), Some(cz)] = by_cond else {
        return Err(StaticError::Conditions);
    };
    let ordered = [cx, cy, cz];

    // Per-condition sine fits (Gaitan et al. (2021) Table 1).
    let mut fits = [[SineFit3 {
        coef: [0.0; 3],
        se: [0.0; 3],
        rms_residual: 0.0,
        n: 0,
    }; 3]; 3];
    for (fc, c) in fits.iter_mut().zip(ordered) {
        let n = c.angle_deg.len();
        let regressors = c.angle_deg.iter().flat_map(|a| {
            let a = a.to_radians();
            [a.sin(), a.cos(), 1.0]
        });
        let h = DMatrix::from_row_iterator(n, 3, regressors);
        let ys: Vec<DVector<f64>> = c.y.iter().map(|y| DVector::from_column_slice(y)).collect();
        let r =
            batch::least_squares(h, &ys).map_err(|e| StaticError::Fit(c.condition.letter(), e))?;
        for (out, ch) in fc.iter_mut().zip(&r.channels) {
            let three = |v: &[f64]| {
                <[f64; 3]>::try_from(v)
                    .map_err(|_| StaticError::Internal("a sine fit without three coefficients"))
            };
            *out = SineFit3 {
                coef: three(&ch.coef)?,
                se: three(&ch.se)?,
                rms_residual: (ch.rss / n as f64).sqrt(),
                n,
            };
        }
    }

    let mut cal = from_poses(poses::poses_from_conditions(&ordered.map(|c| *c)), g, opts)?;

    // Gaitan et al. (2021) eqs. 20–21: S_jx from A of y and z, S_jy from A of x and B of z, S_jz
    // from B of x and y; offsets averaged over the three conditions.
    let mean2 = |(c1, se1): (f64, f64), (c2, se2): (f64, f64)| Estimate {
        value: (c1 + c2) / (2.0 * g),
        std_unc: se1.hypot(se2) / (2.0 * g),
    };
    // A and B of a fit, each with its standard error.
    let ab = |f: &SineFit3| {
        let ([a, b, _], [se_a, se_b, _]) = (f.coef, f.se);
        ((a, se_a), (b, se_b))
    };
    // Channel j's fits in conditions x, y, z.
    let by_channel = Channel::ALL.map(|ch| fits.each_ref().map(|fc| *ch.of(fc)));
    let dup_s = by_channel.map(|[fx, fy, fz]| {
        let ((ax, bx), (ay, by), (az, bz)) = (ab(&fx), ab(&fy), ab(&fz));
        [mean2(ay, az), mean2(ax, bz), mean2(bx, by)]
    });
    let dup_o = by_channel.map(|f| Estimate {
        value: f.iter().map(|x| x.coef[2]).sum::<f64>() / 3.0,
        std_unc: f.iter().map(|x| x.se[2].powi(2)).sum::<f64>().sqrt() / 3.0,
    });
    cal.duplicate_average = Some(DuplicateAverage {
        s: dup_s,
        offsets: dup_o,
    });
    cal.fits = Some(fits);
    Ok(cal)
}

/// The static method from poses (any known orientations): the fit of S and O, and the
/// intrinsic properties from the rows of S with their covariances.
pub fn from_poses(
    poses: Vec<poses::Pose>,
    g: f64,
    opts: poses::Options,
) -> Result<StaticCalibration, StaticError> {
    let fit = poses::fit(poses, g, opts)?;
    let (s, s_cov) = (fit.s(), fit.s_cov());
    let intrinsic = intrinsic::from_matrix_cov(&s, &s_cov)?;
    Ok(StaticCalibration {
        s,
        s_std: fit.s_std(),
        offsets: fit.offsets(),
        s_cov,
        intrinsic,
        duplicate_average: None,
        fits: None,
        pose_fit: fit,
    })
}

/// A Monte Carlo (GUM Supplement 1) propagation of one output.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct McSummary {
    /// Mean of the trials.
    pub mean: f64,
    /// Standard deviation of the trials: the Monte Carlo standard uncertainty.
    pub std_unc: f64,
    /// Probabilistically symmetric 95 % coverage interval, low end.
    pub low_95: f64,
    /// High end.
    pub high_95: f64,
}

fn summarise(mut v: Vec<f64>) -> McSummary {
    let n = v.len().max(2) as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    v.sort_by(f64::total_cmp);
    // The trial a fraction p of the way through the sorted trials.
    let q = |p: f64| {
        v.get(((v.len() as f64 - 1.0) * p).round() as usize)
            .copied()
    };
    // Without trials (--monte-carlo 0) there is no interval: NaN, null in the JSON.
    let (low_95, high_95) = q(0.025).zip(q(0.975)).unwrap_or((f64::NAN, f64::NAN));
    McSummary {
        mean,
        std_unc: var.sqrt(),
        low_95,
        high_95,
    }
}

/// Lower Cholesky factor of a small covariance matrix (positive semi-definite: a zero
/// pivot gives a zero column).
fn chol<const N: usize>(c: &[[f64; N]; N]) -> [[f64; N]; N] {
    let mut l = [[0.0; N]; N];
    // Row by row, each entry L_ij (j ≤ i) from the row's entries before it: off the
    // diagonal with row j above and its diagonal L_jj, then the diagonal.
    let mut above: Vec<([f64; N], f64)> = Vec::with_capacity(N);
    for (c_row, l_row) in c.iter().zip(l.iter_mut()) {
        let mut row: Vec<f64> = Vec::with_capacity(N);
        let mut diagonal = 0.0;
        let with = above.iter().map(Some).chain(std::iter::once(None));
        for (c_ij, row_j) in c_row.iter().zip(with) {
            let dot = |l_j: &[f64]| row.iter().zip(l_j).map(|(a, b)| a * b).sum::<f64>();
            let l_ij = match row_j {
                Some((l_j, l_jj)) => {
                    let s = c_ij - dot(l_j);
                    if *l_jj > 0.0 {
                        s / l_jj
                    } else {
                        0.0
                    }
                }
                None => {
                    diagonal = (c_ij - dot(&row)).max(0.0).sqrt();
                    diagonal
                }
            };
            row.push(l_ij);
        }
        for (out, v) in l_row.iter_mut().zip(row) {
            *out = v;
        }
        above.push((*l_row, diagonal));
    }
    l
}

fn draw<const N: usize, R: rand::Rng>(mean: [f64; N], l: &[[f64; N]; N], rng: &mut R) -> [f64; N] {
    use rand_distr::{Distribution, StandardNormal};
    let z: [f64; N] = std::array::from_fn(|_| StandardNormal.sample(rng));
    let mut out = mean;
    // L is lower triangular: row i against z_0 … z_i.
    for (i, (o, l_i)) in out.iter_mut().zip(l).enumerate() {
        *o += l_i
            .iter()
            .zip(&z)
            .take(i + 1)
            .map(|(l, z)| l * z)
            .sum::<f64>();
    }
    out
}

/// GUM Supplement 1 check of the rotation method: `trials` draws of every fit's (A, B)
/// from its normal distribution, pushed through the exact (nonlinear) Gram computation.
/// Outputs in the order s_u, s_v, s_w, φ_uv, φ_vw, φ_wu.
pub fn monte_carlo_rotation(
    fits: &[ConditionFit; 3],
    g: f64,
    trials: usize,
    seed: u64,
) -> Result<[McSummary; 6], IntrinsicError> {
    use rand::SeedableRng;
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let factors = fits.map(|f| f.cov.map(|c| chol(&c)));
    let mut out: [Vec<f64>; 6] = Default::default();
    for _ in 0..trials {
        let mut draw_fits = *fits;
        // Each channel's (A, B) drawn in place of the fit's (a copy of it).
        for (df, ls) in draw_fits.iter_mut().zip(&factors) {
            for ((a, b), l) in df.a.iter_mut().zip(df.b.iter_mut()).zip(ls) {
                [*a, *b] = draw([*a, *b], l, &mut rng);
            }
        }
        let r = intrinsic::from_gram(&draw_fits, g, 0.0)?;
        for (o, e) in out
            .iter_mut()
            .zip(r.sensitivity.iter().chain(r.angle_deg.iter()))
        {
            o.push(e.value);
        }
    }
    Ok(out.map(summarise))
}

/// GUM Supplement 1 check of the static method: draws of S from its normal distribution
/// through the intrinsic computation. Outputs s_u … φ_wu as above.
pub fn monte_carlo_static(
    cal: &StaticCalibration,
    trials: usize,
    seed: u64,
) -> Result<[McSummary; 6], IntrinsicError> {
    use rand::SeedableRng;
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let l = chol(&cal.s_cov);
    let [[s00, s01, s02], [s10, s11, s12], [s20, s21, s22]] = cal.s;
    let mean = [s00, s01, s02, s10, s11, s12, s20, s21, s22];
    let mut out: [Vec<f64>; 6] = Default::default();
    for _ in 0..trials {
        let [d00, d01, d02, d10, d11, d12, d20, d21, d22] = draw(mean, &l, &mut rng);
        let s = [[d00, d01, d02], [d10, d11, d12], [d20, d21, d22]];
        let r = intrinsic::from_matrix_cov(&s, &cal.s_cov)?;
        for (o, e) in out
            .iter_mut()
            .zip(r.sensitivity.iter().chain(r.angle_deg.iter()))
        {
            o.push(e.value);
        }
    }
    Ok(out.map(summarise))
}
