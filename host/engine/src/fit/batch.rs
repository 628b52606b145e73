//! Batch least squares in f64 over a whole record, by Householder QR (nalgebra): the
//! reference the streaming fit is checked against, and the host's own fits.
//!
//! Uses the same regressors as the streaming fit (`rotacal_shared`): the exact integer
//! phase at each tick, and τ in seconds. Time-dependent terms are written directly about
//! a given reference tick, so A, B, C mean the same as the streaming fit's re-referenced
//! values without going through its transformation.

use nalgebra::{DMatrix, DVector};
use rotacal_shared::{Aperture, Channel, Model, PhaseStep, TickRate, Ticks};
use std::f64::consts::TAU;

/// One fitted channel.
#[derive(Clone, Debug, PartialEq)]
pub struct BatchChannel {
    /// Parameters in `rotacal_shared::Model` order.
    pub coef: Vec<f64>,
    /// Standard errors √(σ̂²·[(HᵀH)⁻¹]ᵢᵢ).
    pub se: Vec<f64>,
    /// Residual sum of squares, summed from the residuals.
    pub rss: f64,
    /// σ̂ = √(RSS/(n − p)).
    pub sigma: f64,
}

/// A batch fit of every channel.
#[derive(Clone, Debug, PartialEq)]
pub struct BatchFit {
    /// Samples fitted.
    pub n: usize,
    /// (HᵀH)⁻¹.
    pub unscaled_cov: DMatrix<f64>,
    /// Per channel.
    pub channels: Vec<BatchChannel>,
}

/// Why a batch fit failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BatchError {
    /// Fewer samples than parameters + 1.
    #[error("too few samples: {n}, need at least {needed}")]
    TooFewSamples {
        /// Samples given.
        n: usize,
        /// Samples needed.
        needed: usize,
    },
    /// The regressors are linearly dependent.
    #[error("singular fit: the samples do not determine every parameter")]
    Singular,
    /// The iterated fit did not converge.
    #[error("four-parameter fit did not converge in {0} iterations")]
    NoConvergence(usize),
    /// An invariant of the fit failed: a bug in rotacal, not a problem of the data.
    #[error("internal: {0} (a bug in rotacal; please report it)")]
    Internal(&'static str),
}

/// Seconds from `t_ref` to `t` (negative before it).
pub fn seconds_between(t: Ticks, t_ref: Ticks, clock: TickRate) -> f64 {
    (t.0 as i128 - t_ref.0 as i128) as f64 / f64::from(clock.hz())
}

/// Least squares of each of `ys` on the regressor matrix `h` by QR, with standard
/// errors from σ̂²(HᵀH)⁻¹.
pub fn least_squares(h: DMatrix<f64>, ys: &[DVector<f64>]) -> Result<BatchFit, BatchError> {
    solve_qr(h, ys)
}

/// (HᵀH)⁻¹ = R⁻¹R⁻ᵀ from the triangular factor, refusing a (numerically) singular R.
pub(crate) fn unscaled_cov(r: &DMatrix<f64>) -> Result<DMatrix<f64>, BatchError> {
    let rmax = r.diagonal().amax();
    if r.diagonal().iter().any(|d| d.abs() <= 1e-13 * rmax) {
        return Err(BatchError::Singular);
    }
    let r_inv = r.clone().try_inverse().ok_or(BatchError::Singular)?;
    Ok(&r_inv * r_inv.transpose())
}

/// A channel's result from its coefficients and residual sum of squares over `n` rows:
/// standard errors √(σ̂²·[(HᵀH)⁻¹]ᵢᵢ) with σ̂² = RSS/(n − p).
fn channel(coef: &[f64], rss: f64, n: usize, unscaled_cov: &DMatrix<f64>) -> BatchChannel {
    let p = coef.len();
    let var = rss / (n - p) as f64;
    BatchChannel {
        coef: coef.to_vec(),
        se: (0..p)
            .map(|i| (var * unscaled_cov[(i, i)]).sqrt())
            .collect(),
        rss,
        sigma: var.sqrt(),
    }
}

fn solve_qr(h: DMatrix<f64>, ys: &[DVector<f64>]) -> Result<BatchFit, BatchError> {
    let (n, p) = h.shape();
    if n <= p {
        return Err(BatchError::TooFewSamples { n, needed: p + 1 });
    }
    let qr = h.clone().qr();
    let r = qr.r();
    let unscaled_cov = unscaled_cov(&r)?;
    let q = qr.q();
    let mut channels = Vec::with_capacity(ys.len());
    for y in ys {
        let qty = q.transpose() * y;
        let coef = r.solve_upper_triangular(&qty).ok_or(BatchError::Singular)?;
        let resid = y - &h * &coef;
        channels.push(channel(
            coef.as_slice(),
            resid.norm_squared(),
            n,
            &unscaled_cov,
        ));
    }
    Ok(BatchFit {
        n,
        unscaled_cov,
        channels,
    })
}

/// Least squares by QR of row blocks (TSQR): the rows of the augmented matrix [H | y]
/// are folded in a block at a time into its triangular factor T, so memory does not grow
/// with the number of rows. At the end T = [[R, z], [0, ρ]]: R c = z gives the
/// coefficients and ρ² is the residual sum of squares, without forming Q or residuals.
/// For one right-hand side (the joint rate fit, where H has 3N rows).
#[derive(Clone, Debug)]
pub struct IncrementalQr {
    p: usize,
    /// Triangular factor so far ((p+1)×(p+1)), or none before the first block.
    t: Option<DMatrix<f64>>,
    /// Rows waiting to be folded in.
    block: Vec<f64>,
    n: usize,
}

const QR_BLOCK_ROWS: usize = 4096;

impl IncrementalQr {
    /// For `p` regressors.
    pub fn new(p: usize) -> Self {
        IncrementalQr {
            p,
            t: None,
            block: Vec::with_capacity(QR_BLOCK_ROWS * (p + 1)),
            n: 0,
        }
    }

    /// Add one row: regressors `h` (length p) and observation `y`.
    pub fn push(&mut self, h: &[f64], y: f64) {
        self.block.extend_from_slice(h);
        self.block.push(y);
        self.n += 1;
        if self.block.len() >= QR_BLOCK_ROWS * (self.p + 1) {
            self.fold();
        }
    }

    fn fold(&mut self) {
        let w = self.p + 1;
        let rows = self.block.len() / w;
        if rows == 0 {
            return;
        }
        let top = self.t.as_ref().map_or(0, |t| t.nrows());
        let mut m = DMatrix::zeros(top + rows, w);
        if let Some(t) = &self.t {
            m.rows_mut(0, top).copy_from(t);
        }
        m.rows_mut(top, rows)
            .copy_from(&DMatrix::from_row_slice(rows, w, &self.block));
        self.block.clear();
        self.t = Some(m.qr().r());
    }

    /// Solve: coefficients and standard errors from σ̂²(HᵀH)⁻¹ = σ̂²R⁻¹R⁻ᵀ.
    pub fn solve(mut self) -> Result<BatchFit, BatchError> {
        let p = self.p;
        if self.n <= p {
            return Err(BatchError::TooFewSamples {
                n: self.n,
                needed: p + 1,
            });
        }
        self.fold();
        let t = self.t.ok_or(BatchError::Singular)?;
        if t.nrows() < p + 1 {
            return Err(BatchError::Singular);
        }
        let r = t.view((0, 0), (p, p)).into_owned();
        let z = t.view((0, p), (p, 1)).into_owned();
        let rss = t.get((p, p)).ok_or(BatchError::Singular)?.powi(2);
        let unscaled_cov = unscaled_cov(&r)?;
        let coef = r.solve_upper_triangular(&z).ok_or(BatchError::Singular)?;
        Ok(BatchFit {
            n: self.n,
            channels: vec![channel(coef.as_slice(), rss, self.n, &unscaled_cov)],
            unscaled_cov,
        })
    }
}

/// One streamed sample: the instants of the conversions it averages (ticks of the fit's
/// clock) and each channel's average over them. A plain sample is an aperture of one.
pub type Sample = (Aperture, [f64; 3]);

/// √n for an average of `ap`'s n conversions: the factor its row and value are scaled by,
/// so that least squares weights it by n (its variance is σ²/n for white conversions).
pub fn root_weight(ap: &Aperture) -> f64 {
    (ap.len().max(1) as f64).sqrt()
}

/// `f` averaged over the conversions of `ap` (a mean of n values, exactly the model of an
/// average; for one conversion, `f` at it).
pub fn mean_over<const K: usize>(ap: &Aperture, f: impl Fn(Ticks) -> [f64; K]) -> [f64; K] {
    let mut acc = [0.0; K];
    for t in ap.ticks() {
        for (a, v) in acc.iter_mut().zip(f(t)) {
            *a += v;
        }
    }
    let n = ap.len().max(1) as f64;
    acc.map(|a| a / n)
}

/// Fit `model` to samples with rotation `step` per tick; τ terms are taken about `t_ref`.
/// Averages are weighted by their conversion counts: rows and values scaled by √n.
pub fn fit(
    samples: &[Sample],
    step: PhaseStep,
    clock: TickRate,
    model: Model,
    t_ref: Ticks,
) -> Result<BatchFit, BatchError> {
    let h = design(samples, step, clock, model, t_ref);
    let ys = Channel::ALL.map(|ch| {
        DVector::from_iterator(
            samples.len(),
            samples.iter().map(|(ap, y)| root_weight(ap) * *ch.of(y)),
        )
    });
    solve_qr(h, &ys)
}

/// The regressor matrix of `model` (the exact integer phase; τ terms about `t_ref`), one
/// row per sample: the mean of the rows at its conversions, times √n (see [`fit`]).
pub fn design(
    samples: &[Sample],
    step: PhaseStep,
    clock: TickRate,
    model: Model,
    t_ref: Ticks,
) -> DMatrix<f64> {
    let p = model.n_params();
    let mut h = DMatrix::zeros(samples.len(), p);
    for (mut h_row, (ap, _)) in h.row_iter_mut().zip(samples) {
        let w = root_weight(ap);
        let [s, c, tau, ts, tc] = mean_over(ap, |t| {
            let (s, c) = step.phase_at(t).sin_cos::<f64>();
            let tau = seconds_between(t, t_ref, clock);
            [s.hi, c.hi, tau, tau * s.hi, tau * c.hi]
        });
        let mut row = vec![s, c, 1.0];
        if model.offset_drift {
            row.push(tau);
        }
        if model.rate_error {
            row.push(ts);
            row.push(tc);
        }
        for (h, v) in h_row.iter_mut().zip(row) {
            *h = w * v;
        }
    }
    h
}

/// Whether the IEEE 1057 iteration has converged after a step of `dw` rad/s (standard
/// error `se_dw`) from phase step `steps.0` to `steps.1`: the step is below 10⁻³ of its
/// standard error, or below the resolution of a [`PhaseStep`] (the steps are then equal, or
/// a step apart: a long record's standard error can fall below that resolution, and the
/// iteration would go back and forth between two neighbouring steps).
pub fn converged(dw: f64, se_dw: f64, steps: (PhaseStep, PhaseStep), clock: TickRate) -> bool {
    let resolution = TAU * PhaseStep(1).to_hz(clock);
    dw.abs() <= 1e-3 * se_dw || steps.0 == steps.1 || dw.abs() < resolution
}

/// Result of the four-parameter fit.
#[derive(Clone, Debug, PartialEq)]
pub struct FourParamFit {
    /// Estimated rotation rate, Hz (one rate shared by the three channels).
    pub rate_hz: f64,
    /// Its standard error, Hz.
    pub se_rate_hz: f64,
    /// A, B, C per channel at the estimated rate (phase from tick 0, as always).
    pub fit: BatchFit,
    /// Iterations used.
    pub iterations: usize,
}

/// The iterated four-parameter sine fit of IEEE Std 1057 (§4.1.3.3), with one frequency
/// shared by the three channels, since they see the same rotation.
///
/// Each iteration linearises about the current rate: besides sin, cos and 1 per channel,
/// a shared column per channel ∂y/∂ω = τ·(A cos α − B sin α) with τ measured from the
/// record's middle. The joint system is solved by QR and ω updated until the step is
/// below 1e-3 of its standard error, or below the resolution of a [`PhaseStep`]
/// ([`converged`]). The starting rate (nominal) must be within about
/// 1/(4·span) Hz of the truth, as for any IEEE 1057 fit.
pub fn fit_four_param(
    samples: &[Sample],
    nominal: PhaseStep,
    clock: TickRate,
) -> Result<FourParamFit, BatchError> {
    const MAX_ITER: usize = 50;
    let n = samples.len();
    let (Some(first), Some(last_s)) = (samples.first(), samples.last()) else {
        return Err(BatchError::TooFewSamples { n, needed: 8 });
    };
    if n < 8 {
        return Err(BatchError::TooFewSamples { n, needed: 8 });
    }
    let t_mid = Ticks((first.0.first().0 + last_s.0.last().0) / 2);
    let mut rate = nominal.to_hz(clock);
    let mut last = fit(samples, nominal, clock, Model::SINE, t_mid)?;
    for iter in 1..=MAX_ITER {
        let step = PhaseStep::from_hz(rate, clock).ok_or(BatchError::Singular)?;
        let ab = sine_ab(&last)?;
        // Joint unknowns: (A, B, C) × 3 channels, then δω; 3N rows, folded in blocks.
        let mut joint = IncrementalQr::new(10);
        for (ap, v) in samples {
            let w = root_weight(ap);
            let [s, c, ts, tc] = rate_terms(ap, step, t_mid, clock);
            for ((ch, [a, b]), y) in Channel::ALL.into_iter().zip(ab).zip(v) {
                let h = joint_row(ch, [w * s, w * c, w], w * (a * tc - b * ts));
                joint.push(&h, w * y);
            }
        }
        let joint = joint.solve()?;
        let (dw, se_dw) = joint
            .channels
            .first()
            .and_then(|c| c.coef.get(9).zip(c.se.get(9)))
            .map(|(dw, se)| (*dw, *se))
            .ok_or(BatchError::Internal("the joint fit has no rate column"))?;
        rate += dw / TAU;
        let next = PhaseStep::from_hz(rate, clock).ok_or(BatchError::Singular)?;
        last = fit(samples, next, clock, Model::SINE, t_mid)?;
        if converged(dw, se_dw, (step, next), clock) {
            return Ok(FourParamFit {
                rate_hz: rate,
                se_rate_hz: se_dw / TAU,
                fit: last,
                iterations: iter,
            });
        }
    }
    Err(BatchError::NoConvergence(MAX_ITER))
}

/// The averages over `ap`'s conversions of sin α, cos α, τ·sin α and τ·cos α (τ in seconds
/// from `t_mid`): a row of the IEEE 1057 rate fit.
pub fn rate_terms(ap: &Aperture, step: PhaseStep, t_mid: Ticks, clock: TickRate) -> [f64; 4] {
    mean_over(ap, |t| {
        let (s, c) = step.phase_at(t).sin_cos::<f64>();
        let tau = seconds_between(t, t_mid, clock);
        [s.hi, c.hi, tau * s.hi, tau * c.hi]
    })
}

/// A and B of each channel of a sine fit (three channels, coefficients A, B, C).
fn sine_ab(fit: &BatchFit) -> Result<[[f64; 2]; 3], BatchError> {
    let ab = |c: &BatchChannel| match c.coef.as_slice() {
        [a, b, ..] => Ok([*a, *b]),
        _ => Err(BatchError::Internal("a sine fit without A and B")),
    };
    match fit.channels.as_slice() {
        [u, v, w] => Ok([ab(u)?, ab(v)?, ab(w)?]),
        _ => Err(BatchError::Internal("a sine fit without three channels")),
    }
}

/// A row of the joint rate fit for channel `ch`: its (sin, cos, 1) in its own three
/// columns, the others' zero, and the rate column last.
fn joint_row(ch: Channel, [s, c, one]: [f64; 3], rate: f64) -> [f64; 10] {
    match ch {
        Channel::U => [s, c, one, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, rate],
        Channel::V => [0.0, 0.0, 0.0, s, c, one, 0.0, 0.0, 0.0, rate],
        Channel::W => [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, s, c, one, rate],
    }
}
