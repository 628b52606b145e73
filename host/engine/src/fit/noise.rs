//! The noise of a record, estimated from the data: an autoregressive model AR(p) of a fit's
//! residuals, per channel and group, and the covariance of the fit's coefficients under it
//! (docs/uncertainty.md).
//!
//! Real sensors filter their output, so successive samples are correlated, and no real
//! recording states its noise. σ̂²(HᵀH)⁻¹ then understates the variance of slowly varying
//! coefficients by about (1+ρ)/(1−ρ) for AR(1) noise. Here:
//!
//! - the autocovariances of the residuals give an AR(p) model by Yule–Walker (Levinson–
//!   Durbin), the order chosen by BIC (Schwarz) up to [`MAX_ORDER`]; samples flagged as clipped are
//!   left out of every lagged product, so a channel at its rails does not bias the level;
//! - the fit's coefficients keep their ordinary least-squares values (for sines and
//!   polynomials OLS is asymptotically as efficient as GLS: Grenander 1954), and their
//!   covariance is the sandwich (HᵀH)⁻¹ HᵀΣH (HᵀH)⁻¹ with Σ the AR model's, computed in
//!   O(N·p) as HᵀΣH = σ_ε²·ZᵀZ, Z = A⁻ᵀH (A the AR filter as a matrix, its first p rows the
//!   identity: exact but for the first p samples, an O(1/(N(1 − ρ²))) effect);
//! - the model is corrected for what the regression removed from the residuals (their
//!   expected autocovariances under it, E[(I − P)Σ(I − P)], matched to the observed ones),
//!   so white noise gives exactly RSS/(N − q) as before.

use nalgebra::DMatrix;

/// The largest AR order tried.
pub const MAX_ORDER: usize = 32;

/// Why no noise model could be estimated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NoiseError {
    /// Too few usable samples.
    #[error("too few samples to estimate the noise: {0} usable")]
    TooFew(usize),
    /// The residuals are all equal (no noise to measure).
    #[error("the residuals are constant: no noise to estimate")]
    Constant,
    /// The regressors are linearly dependent.
    #[error("singular fit: the regressors do not determine every coefficient")]
    Singular,
    /// Regressors for another number of samples than the model's.
    #[error("regressors for {0} samples, the noise model has {1}")]
    Length(usize, usize),
}

/// An AR(p) noise model: e_t = φ₁e_{t−1} + … + φ_p e_{t−p} + ε_t, var ε = σ_ε².
#[derive(Clone, Debug, PartialEq)]
pub struct NoiseModel {
    /// φ₁ … φ_p (empty: white noise).
    pub ar: Vec<f64>,
    /// σ_ε², output units².
    pub innovation_var: f64,
    /// The stationary variance γ₀ (output units²): the level of one sample's noise.
    pub var: f64,
    /// Autocorrelations ρ₀ … ρ_p of the model (equal to the sample ones up to lag p
    /// before [`NoiseModel::rescaled`] corrects them for the fit).
    rho: Vec<f64>,
    /// The residuals' sample autocovariances γ̂₀ … γ̂_p the model was estimated from.
    observed: Vec<f64>,
    /// Samples in the record.
    pub n: usize,
    /// Samples left out of the estimate (flagged as clipped).
    pub excluded: usize,
}

impl NoiseModel {
    /// White noise of variance `var` over `n` samples.
    pub fn white(var: f64, n: usize) -> Self {
        NoiseModel {
            ar: Vec::new(),
            innovation_var: var,
            var,
            rho: vec![1.0],
            observed: vec![var],
            n,
            excluded: 0,
        }
    }

    /// Estimate from residuals `e`; `flagged[t]` leaves sample t out (empty: none).
    pub fn estimate(e: &[f64], flagged: &[bool]) -> Result<Self, NoiseError> {
        let n = e.len();
        let ok = |t: usize| !flagged.get(t).copied().unwrap_or(false);
        let used = (0..n).filter(|&t| ok(t)).count();
        if used < 20 {
            return Err(NoiseError::TooFew(used));
        }
        let mean = (0..n).filter(|&t| ok(t)).map(|t| e[t]).sum::<f64>() / used as f64;
        let x: Vec<f64> = e.iter().map(|v| v - mean).collect();
        let max_p = MAX_ORDER.min(used / 10);
        // Biased autocovariances (divided by the samples used), pairs with a flagged
        // sample left out.
        let gamma: Vec<f64> = (0..=max_p)
            .map(|k| {
                (0..n.saturating_sub(k))
                    .filter(|&t| ok(t) && ok(t + k))
                    .map(|t| x[t] * x[t + k])
                    .sum::<f64>()
                    / used as f64
            })
            .collect();
        Self::from_autocovariances(&gamma, n, used)
    }

    /// The model from the residuals' biased sample autocovariances γ̂₀ … γ̂_K (K ≥ the
    /// largest order tried, min([`MAX_ORDER`], used/10)) over `n` samples of which `used`
    /// entered them: the order of least BIC by Levinson–Durbin.
    pub fn from_autocovariances(gamma: &[f64], n: usize, used: usize) -> Result<Self, NoiseError> {
        if used < 20 {
            return Err(NoiseError::TooFew(used));
        }
        let max_p = MAX_ORDER.min(used / 10).min(gamma.len().saturating_sub(1));
        let gamma = gamma.get(..=max_p).unwrap_or(gamma);
        let g0 = gamma.first().copied().unwrap_or(f64::NAN);
        if !(g0.is_finite() && g0 > 0.0) {
            return Err(NoiseError::Constant);
        }
        // Levinson–Durbin, keeping the order of least BIC: its penalty (ln N per
        // coefficient) rarely takes white noise for correlated (AIC's 2 would, often).
        let mut phi: Vec<f64> = Vec::new();
        let mut v = g0;
        let mut best = (used as f64 * v.ln(), Vec::new(), v);
        for p in 1..=max_p {
            let Some(next) = levinson_step(&mut phi, gamma, v) else {
                break;
            };
            v = next;
            let bic = used as f64 * v.ln() + p as f64 * (used as f64).ln();
            if bic < best.0 {
                best = (bic, phi.clone(), v);
            }
        }
        let (_, ar, innovation_var) = best;
        let p = ar.len();
        Ok(NoiseModel {
            rho: gamma.iter().take(p + 1).map(|g| g / g0).collect(),
            observed: gamma.iter().take(p + 1).copied().collect(),
            ar,
            innovation_var,
            var: g0,
            n,
            excluded: n - used,
        })
    }

    /// The same process at `factor` times the variance (its correlation kept).
    pub fn scaled(mut self, factor: f64) -> NoiseModel {
        self.var *= factor;
        self.innovation_var *= factor;
        for g in &mut self.observed {
            *g *= factor;
        }
        self
    }

    /// The AR order p.
    pub fn order(&self) -> usize {
        self.ar.len()
    }

    /// Standard deviation of one sample's noise.
    pub fn sd(&self) -> f64 {
        self.var.sqrt()
    }

    /// The model's autocorrelation at `lag` samples.
    pub fn autocorrelation(&self, lag: usize) -> f64 {
        if let Some(r) = self.rho.get(lag) {
            return *r;
        }
        let mut rho = self.rho.clone();
        while rho.len() <= lag {
            let k = rho.len();
            let next = self
                .ar
                .iter()
                .enumerate()
                .map(|(i, f)| f * rho[k - 1 - i])
                .sum();
            rho.push(next);
        }
        rho[lag]
    }

    /// 2π·S(ω)/γ₀ = Σ_k ρ_k cos(kω) at `omega` radians per sample: how many times the
    /// variance of a coefficient of a regressor at that frequency exceeds what white noise
    /// of the same level gives (1 for white noise; (1+ρ)/(1−ρ) for AR(1) at ω → 0).
    pub fn variance_factor(&self, omega: f64) -> f64 {
        let (mut re, mut im) = (1.0, 0.0);
        for (k, f) in self.ar.iter().enumerate() {
            let a = (k + 1) as f64 * omega;
            re -= f * a.cos();
            im += f * a.sin();
        }
        self.innovation_var / self.var / (re * re + im * im)
    }

    /// The effective number of independent samples for a regressor at `omega` radians
    /// per sample: N divided by the variance factor.
    pub fn n_eff(&self, omega: f64) -> f64 {
        self.n as f64 / self.variance_factor(omega)
    }

    /// Degrees of freedom of a variance taken from this model for a fit of `q`
    /// coefficients: N − q for white noise; for AR(p), N/(2p), from the asymptotic
    /// variance 2·(2p/N) of the AR spectral estimate near ω = 0 (Berk 1974).
    pub fn dof(&self, q: usize) -> f64 {
        let used = self.n.saturating_sub(self.excluded);
        let white = used.saturating_sub(q).max(1) as f64;
        match self.order() {
            0 => white,
            p => white.min(used as f64 / (2.0 * p as f64)).max(1.0),
        }
    }

    /// Z = A⁻ᵀH, A the AR filter as a lower-triangular matrix ((Ae)_t = e_t − Σφ_k e_{t−k}
    /// from t = p on): by the backward recursion z_t = h_t + Σ φ_k z_{t+k}. Works on Hᵀ
    /// (q × N, a sample's regressors contiguous), so the q columns' recursions run side by
    /// side rather than one long chain of dependent additions each.
    fn filter_back(&self, ht: &DMatrix<f64>) -> DMatrix<f64> {
        let mut z = ht.clone();
        let (q, n) = z.shape();
        let p = self.order();
        let zs = z.as_mut_slice();
        for t in (0..n).rev() {
            for (k, f) in self.ar.iter().enumerate() {
                let s = t + k + 1;
                if s < n && s >= p {
                    let (head, tail) = zs.split_at_mut(s * q);
                    let (Some(row), Some(later)) =
                        (head.get_mut(t * q..(t + 1) * q), tail.get(..q))
                    else {
                        continue;
                    };
                    for (v, l) in row.iter_mut().zip(later) {
                        *v += f * l;
                    }
                }
            }
        }
        z
    }

    /// ΣH/σ_ε² = A⁻¹A⁻ᵀH, transposed, from Zᵀ = (A⁻ᵀH)ᵀ: the forward recursion
    /// x_t = z_t + Σ φ_k x_{t−k} from t = p on.
    fn filter_forward(&self, mut zt: DMatrix<f64>) -> DMatrix<f64> {
        let (q, n) = zt.shape();
        let p = self.order();
        let zs = zt.as_mut_slice();
        for t in p..n {
            for (k, f) in self.ar.iter().enumerate() {
                let s = t - k - 1;
                let (head, tail) = zs.split_at_mut(t * q);
                let (Some(row), Some(earlier)) = (tail.get_mut(..q), head.get(s * q..(s + 1) * q))
                else {
                    continue;
                };
                for (v, e) in row.iter_mut().zip(earlier) {
                    *v += f * e;
                }
            }
        }
        zt
    }

    /// The covariance of the ordinary least-squares coefficients of regressors `h`
    /// (N × q) under this noise, the sandwich (HᵀH)⁻¹HᵀΣH(HᵀH)⁻¹. The model, estimated from
    /// that fit's residuals, is rescaled first for what the fit removed from them
    /// ([`NoiseModel::rescaled`]); the rescaled model is returned with it.
    pub fn regression_cov(
        self,
        h: &DMatrix<f64>,
    ) -> Result<(NoiseModel, DMatrix<f64>), NoiseError> {
        let r = Regressors::new(h, self.n)?;
        let m = self.rescaled_with(&r)?;
        let cov = m.sandwich_with(&r);
        Ok((m, cov))
    }

    /// The model corrected for what a least-squares fit of regressors `h` took out of the
    /// residuals it was estimated from. The residuals are r = (I − P)e, so their sample
    /// autocovariances are biased: E[Σ_t r_t r_{t+k}] = Σ_t [(I − P)Σ(I − P)]_{t,t+k}, low
    /// by what the fit absorbed (most at low frequency, where correlated noise has its
    /// power). The model's autocovariances γ₀ … γ_p are moved until their expected sample
    /// values match the observed ones (a few fixed-point steps at the same order), so
    /// white noise gives exactly σ̂² = RSS/(N − q).
    pub fn rescaled(self, h: &DMatrix<f64>) -> Result<NoiseModel, NoiseError> {
        let r = Regressors::new(h, self.n)?;
        self.rescaled_with(&r)
    }

    fn rescaled_with(self, r: &Regressors) -> Result<NoiseModel, NoiseError> {
        // Each step shrinks the error by about tr(PΣ)/(Nγ₀): 0.045 for the widened sine
        // fit of 4200 samples of AR(1) noise with ρ = 0.9, about 0.003 for white noise.
        // Iterated until it stops moving. A fit that takes out most of the residuals' power
        // under the model (the ratio near 1: residuals that are round-off of noise-free
        // data, or noise far slower than the record) cannot be corrected this way; the level
        // is then corrected as for white noise, N/(N − q). Stopped when a step moves the
        // level by less than TOLERANCE: the next step moves it by about 1 % of that (on the
        // low-pass of the coverage proofs), 10⁻⁸ of the level, some 10⁶ times below the
        // estimate's own scatter (1/√ν).
        let (n, q) = r.h.shape();
        self.fixed_point(n, q, |m| m.expected_residual_autocov(r))
    }

    /// The model whose expected sample autocovariances, after a fit of `q` regressors to
    /// `n` samples, match the observed ones: `expected` gives them for a model. Iterated
    /// until a step moves the level by less than 10⁻⁶ of it (see [`NoiseModel::rescaled`]).
    fn fixed_point(
        self,
        n: usize,
        q: usize,
        expected: impl Fn(&NoiseModel) -> Vec<f64>,
    ) -> Result<NoiseModel, NoiseError> {
        const MAX_STEPS: usize = 100;
        const TOLERANCE: f64 = 1e-6;
        let p = self.order();
        let observed = self.observed.clone();
        if p == 0 {
            // White noise: the fixed point in closed form, σ̂² = RSS/(N − q).
            let g0 = observed.first().copied().unwrap_or(self.var) * n as f64
                / (n as f64 - q as f64).max(1.0);
            return self.with_autocovariances(&[g0]).ok_or(NoiseError::Constant);
        }
        let white = (n as f64 / (n as f64 - q as f64).max(1.0), self.clone());
        let mut m = self;
        for _ in 0..MAX_STEPS {
            let expected = expected(&m);
            let next = (expected.first().copied().unwrap_or(0.0) >= 0.5 * m.var)
                .then(|| {
                    let target: Vec<f64> = (0..=p)
                        .map(|k| observed[k] + m.var * m.autocorrelation(k) - expected[k])
                        .collect();
                    m.with_autocovariances(&target)
                })
                .flatten();
            let Some(next) = next else {
                return Ok(white.1.scaled(white.0));
            };
            let moved = (next.var - m.var).abs() / m.var;
            m = next;
            if moved < TOLERANCE {
                return Ok(m);
            }
        }
        Ok(white.1.scaled(white.0))
    }

    /// [`NoiseModel::rescaled`] without the regressors, for a long record of `n` samples
    /// whose regressors are sinusoids (and constants and trends) at `freqs` radians per
    /// sample, one entry per column: a sinusoid is nearly an eigenvector of a stationary
    /// covariance, with eigenvalue 2π·S(ω), so a fit removes from the residuals about
    /// 2π·S(ω_c)·cos(ω_c·k) of the lag-k sum per column c, and E[γ̂_k]·N ≈ (N − k)γ_k −
    /// Σ_c γ₀·f(ω_c)·cos(ω_c·k) (f the variance factor). Exact for white noise (it is then
    /// RSS/(N − q)); for correlated noise its error is of order τ/N relative (τ the
    /// correlation time in samples): docs/streaming.md.
    pub fn rescaled_for_sinusoids(self, n: usize, freqs: &[f64]) -> Result<NoiseModel, NoiseError> {
        let nf = n as f64;
        self.fixed_point(n, freqs.len(), |m| {
            (0..=m.order())
                .map(|k| {
                    let removed: f64 = freqs
                        .iter()
                        .map(|w| m.var * m.variance_factor(*w) * (w * k as f64).cos())
                        .sum();
                    ((nf - k as f64) * m.var * m.autocorrelation(k) - removed) / nf
                })
                .collect()
        })
    }

    /// [`NoiseModel::sandwich`] from the regressors' Gram matrix HᵀH alone, for a long
    /// record whose columns are sinusoids (or constants) at `freqs` radians per sample:
    /// HᵀΣH ≈ γ₀·[HᵀH]_ij·(f(ω_i) + f(ω_j))/2 (sinusoids are nearly eigenvectors of Σ).
    /// Exact for white noise; docs/streaming.md.
    pub fn sandwich_for_sinusoids(
        &self,
        gram: &DMatrix<f64>,
        freqs: &[f64],
    ) -> Result<DMatrix<f64>, NoiseError> {
        let inv = gram.clone().try_inverse().ok_or(NoiseError::Singular)?;
        if inv.iter().any(|v| !v.is_finite()) || freqs.len() != gram.nrows() {
            return Err(NoiseError::Singular);
        }
        let meat = if self.ar.is_empty() {
            gram * self.innovation_var
        } else {
            let f: Vec<f64> = freqs.iter().map(|w| self.variance_factor(*w)).collect();
            DMatrix::from_fn(gram.nrows(), gram.ncols(), |i, j| {
                let (fi, fj) = (f.get(i).copied(), f.get(j).copied());
                self.var * gram[(i, j)] * (fi.unwrap_or(1.0) + fj.unwrap_or(1.0)) / 2.0
            })
        };
        Ok(&inv * meat * &inv)
    }

    /// The AR(p) model (same p) whose autocovariances at lags 0 … p are `gamma`, by
    /// Levinson–Durbin; `None` if they are not those of a stationary process.
    fn with_autocovariances(&self, gamma: &[f64]) -> Option<NoiseModel> {
        let p = self.order();
        let g0 = *gamma.first()?;
        if !(g0.is_finite() && g0 > 0.0) {
            return None;
        }
        let mut phi: Vec<f64> = Vec::with_capacity(p);
        let mut v = g0;
        for _ in 1..=p {
            v = levinson_step(&mut phi, gamma, v)?;
        }
        Some(NoiseModel {
            ar: phi,
            innovation_var: v,
            var: g0,
            rho: gamma.iter().map(|g| g / g0).collect(),
            observed: self.observed.clone(),
            n: self.n,
            excluded: self.excluded,
        })
    }

    /// E[γ̂_k] = E[Σ_t r_t r_{t+k}]/N for k = 0 … p, the residuals r = (I − P)e of a fit of
    /// regressors `h` to noise of this model: with B = (HᵀH)⁻¹HᵀΣ and C = (HᵀH)⁻¹HᵀΣH(HᵀH)⁻¹,
    /// Σ_t [Σ − PΣ − ΣP + PΣP]_{t,t+k} = (N−k)γ_k − Σ_t h_tᵀb_{t+k} − Σ_t h_{t+k}ᵀb_t
    /// + Σ_t h_tᵀC h_{t+k}.
    fn expected_residual_autocov(&self, r: &Regressors) -> Vec<f64> {
        let (h, inv) = (r.h, &r.inv);
        let (n, q) = h.shape();
        // ΣH = σ_ε²·A⁻¹A⁻ᵀH: the backward recursion (Z, shared with the meat), then the
        // forward one.
        let zt = self.filter_back(&r.ht);
        let meat = self.meat_of(&zt);
        let sh = self.filter_forward(zt).transpose() * self.innovation_var;
        // Columns of H, of B·ᵀ = ΣH(HᵀH)⁻¹ and of HC, each contiguous: the sums over t are
        // dot products of shifted columns.
        let bt = sh * inv; // N × q: rows b_tᵀ
        let c = inv * meat * inv;
        let hc = h * &c; // N × q: rows h_tᵀC
        (0..=self.order())
            .map(|k| {
                let mut sum = (n - k) as f64 * self.var * self.autocorrelation(k);
                for col in 0..q {
                    let (hcol, bcol, hccol) = (h.column(col), bt.column(col), hc.column(col));
                    let (hs, bs, hcs) = (hcol.as_slice(), bcol.as_slice(), hccol.as_slice());
                    let [x, y, w] = lagged_dots(hs, bs, hcs, k);
                    sum += x - y - w;
                }
                sum / n as f64
            })
            .collect()
    }

    /// The sandwich (HᵀH)⁻¹HᵀΣH(HᵀH)⁻¹ under this model as it stands.
    pub fn sandwich(&self, h: &DMatrix<f64>) -> Result<DMatrix<f64>, NoiseError> {
        Ok(self.sandwich_with(&Regressors::new(h, self.n)?))
    }

    fn sandwich_with(&self, r: &Regressors) -> DMatrix<f64> {
        let meat = if self.ar.is_empty() {
            r.h.tr_mul(r.h) * self.innovation_var
        } else {
            self.meat_of(&self.filter_back(&r.ht))
        };
        &r.inv * meat * &r.inv
    }

    /// The meat HᵀΣH = σ_ε²·ZᵀZ from Zᵀ = (A⁻ᵀH)ᵀ, as a matrix product (blocked,
    /// vectorised) rather than q² long dot products.
    fn meat_of(&self, zt: &DMatrix<f64>) -> DMatrix<f64> {
        zt * zt.transpose() * self.innovation_var
    }
}

/// Regressors H (N × q) with Hᵀ and (HᵀH)⁻¹, which a rescaling needs at every step.
struct Regressors<'a> {
    h: &'a DMatrix<f64>,
    ht: DMatrix<f64>,
    inv: DMatrix<f64>,
}

impl<'a> Regressors<'a> {
    fn new(h: &'a DMatrix<f64>, n: usize) -> Result<Self, NoiseError> {
        if h.nrows() != n {
            return Err(NoiseError::Length(h.nrows(), n));
        }
        let inv = h.tr_mul(h).try_inverse().ok_or(NoiseError::Singular)?;
        if inv.iter().any(|v| !v.is_finite()) {
            return Err(NoiseError::Singular);
        }
        Ok(Regressors {
            h,
            ht: h.transpose(),
            inv,
        })
    }
}

/// Σ_t hc_t·h_{t+k}, Σ_t h_t·b_{t+k} and Σ_t h_{t+k}·b_t over t < N − k, in one pass with
/// four partial sums each, so the additions do not wait on each other.
// The lane index l < LANES indexes arrays of LANES elements.
#[allow(clippy::indexing_slicing)]
fn lagged_dots(h: &[f64], b: &[f64], hc: &[f64], k: usize) -> [f64; 3] {
    const LANES: usize = 4;
    type Lanes<'a> = &'a [f64; LANES];
    let (lo, hi) = (h.len().saturating_sub(k), k.min(h.len()));
    let (h_lo, h_hi) = (h.get(..lo).unwrap_or(&[]), h.get(hi..).unwrap_or(&[]));
    let (b_lo, b_hi) = (b.get(..lo).unwrap_or(&[]), b.get(hi..).unwrap_or(&[]));
    let hc_lo = hc.get(..lo).unwrap_or(&[]);
    let (mut sa, mut sb, mut sc) = ([0.0; LANES], [0.0; LANES], [0.0; LANES]);
    let chunks = (h_lo.chunks_exact(LANES).zip(h_hi.chunks_exact(LANES)))
        .zip(b_lo.chunks_exact(LANES).zip(b_hi.chunks_exact(LANES)))
        .zip(hc_lo.chunks_exact(LANES));
    for (((hl, hh), (bl, bh)), cl) in chunks {
        let (Ok(hl), Ok(hh), Ok(bl), Ok(bh), Ok(cl)) = (
            Lanes::try_from(hl),
            Lanes::try_from(hh),
            Lanes::try_from(bl),
            Lanes::try_from(bh),
            Lanes::try_from(cl),
        ) else {
            continue;
        };
        for l in 0..LANES {
            sa[l] += cl[l] * hh[l];
            sb[l] += hl[l] * bh[l];
            sc[l] += hh[l] * bl[l];
        }
    }
    // The last few samples.
    let whole = lo - lo % LANES;
    for t in whole..lo {
        if let (Some(hl), Some(hh), Some(bl), Some(bh), Some(cl)) = (
            h_lo.get(t),
            h_hi.get(t),
            b_lo.get(t),
            b_hi.get(t),
            hc_lo.get(t),
        ) {
            sa[0] += cl * hh;
            sb[0] += hl * bh;
            sc[0] += hh * bl;
        }
    }
    [sa, sb, sc].map(|lanes| lanes.iter().sum())
}

/// One Levinson–Durbin step: the AR(p−1) coefficients `phi` and innovation variance `v` to
/// AR(p) from the autocovariances `gamma`; `None` when the reflection coefficient is not
/// below 1 in size (not a stationary process, or the lags run out).
fn levinson_step(phi: &mut Vec<f64>, gamma: &[f64], v: f64) -> Option<f64> {
    let p = phi.len() + 1;
    let acc: f64 = phi
        .iter()
        .enumerate()
        .map(|(j, f)| f * gamma.get(p - 1 - j).copied().unwrap_or(f64::NAN))
        .sum();
    let kappa = (gamma.get(p)? - acc) / v;
    if !(kappa.is_finite() && kappa.abs() < 1.0) {
        return None;
    }
    let prev = phi.clone();
    phi.push(kappa);
    for j in 0..p - 1 {
        phi[j] = prev[j] - kappa * prev[p - 2 - j];
    }
    Some(v * (1.0 - kappa * kappa))
}

/// Readings at a channel's rails: the smallest (largest) value, when at least three
/// readings sit exactly on it and more than on the next value inward, as a clipping sensor
/// piles them up.
pub fn clipped(y: &[f64]) -> Vec<bool> {
    let lo = y.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = y.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let count = |v: f64| y.iter().filter(|&&x| x == v).count();
    // The next value inward on each side: noise quantised to a few steps puts several
    // readings on its extreme value too, but fewer than on the value next to it; a rail
    // piles them up.
    let inner_lo = y
        .iter()
        .copied()
        .filter(|&x| x > lo)
        .fold(f64::INFINITY, f64::min);
    let inner_hi = y
        .iter()
        .copied()
        .filter(|&x| x < hi)
        .fold(f64::NEG_INFINITY, f64::max);
    let rail = |v: f64, inner: f64| {
        let c = count(v);
        c >= 3 && c > count(inner)
    };
    let (lo_rail, hi_rail) = (rail(lo, inner_lo), rail(hi, inner_hi));
    y.iter()
        .map(|&x| (lo_rail && x == lo) || (hi_rail && x == hi))
        .collect()
}

/// A channel's rails as [`clipped`] finds them, gathered one reading at a time: the
/// smallest and largest values with their counts, and the next value inward on each side
/// with its count.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rails {
    lo: (f64, u64),
    lo_inner: (f64, u64),
    hi: (f64, u64),
    hi_inner: (f64, u64),
}

impl Default for Rails {
    fn default() -> Self {
        Rails {
            lo: (f64::INFINITY, 0),
            lo_inner: (f64::INFINITY, 0),
            hi: (f64::NEG_INFINITY, 0),
            hi_inner: (f64::NEG_INFINITY, 0),
        }
    }
}

impl Rails {
    /// Add a reading.
    pub fn add(&mut self, x: f64) {
        // The low side; the high side is the same with the order reversed.
        fn side(
            x: f64,
            end: &mut (f64, u64),
            inner: &mut (f64, u64),
            beyond: fn(f64, f64) -> bool,
        ) {
            if beyond(x, end.0) {
                *inner = *end;
                *end = (x, 1);
            } else if x == end.0 {
                end.1 += 1;
            } else if beyond(x, inner.0) {
                *inner = (x, 1);
            } else if x == inner.0 {
                inner.1 += 1;
            }
        }
        side(x, &mut self.lo, &mut self.lo_inner, |a, b| a < b);
        side(x, &mut self.hi, &mut self.hi_inner, |a, b| a > b);
    }

    /// The rails found (as [`clipped`]: at least three readings on the extreme value and
    /// more than on the next value inward): the low and the high one, if any.
    pub fn found(&self) -> (Option<f64>, Option<f64>) {
        let rail = |end: (f64, u64), inner: (f64, u64)| {
            (end.1 >= 3 && end.1 > inner.1 && end.0.is_finite()).then_some(end.0)
        };
        (rail(self.lo, self.lo_inner), rail(self.hi, self.hi_inner))
    }

    /// The rails of this channel's readings and `other`'s together.
    pub fn merged(&self, other: &Rails) -> Rails {
        // The two extreme values on each side, with their counts: those of either.
        fn two(cands: [(f64, u64); 4], lower: bool) -> ((f64, u64), (f64, u64)) {
            let mut merged: Vec<(f64, u64)> = Vec::with_capacity(4);
            for (v, c) in cands {
                if c == 0 {
                    continue;
                }
                match merged.iter_mut().find(|(w, _)| *w == v) {
                    Some((_, k)) => *k += c,
                    None => merged.push((v, c)),
                }
            }
            merged.sort_by(|a, b| {
                if lower {
                    a.0.total_cmp(&b.0)
                } else {
                    b.0.total_cmp(&a.0)
                }
            });
            let far = if lower {
                f64::INFINITY
            } else {
                f64::NEG_INFINITY
            };
            let mut it = merged.into_iter();
            (it.next().unwrap_or((far, 0)), it.next().unwrap_or((far, 0)))
        }
        let (lo, lo_inner) = two([self.lo, self.lo_inner, other.lo, other.lo_inner], true);
        let (hi, hi_inner) = two([self.hi, self.hi_inner, other.hi, other.hi_inner], false);
        Rails {
            lo,
            lo_inner,
            hi,
            hi_inner,
        }
    }

    /// Whether reading `x` is on a rail found.
    pub fn flags(rails: (Option<f64>, Option<f64>), x: f64) -> bool {
        rails.0 == Some(x) || rails.1 == Some(x)
    }
}

/// The sample autocovariances of a series of residuals at lags 0 … [`MAX_ORDER`], gathered
/// one residual at a time (as [`NoiseModel::estimate`] computes them from the whole
/// series: about the mean of the samples used, pairs with a flagged sample left out,
/// divided by the samples used).
///
/// The last lags' residuals sit in a window stored twice over, so that the newest
/// [`LAGS`] are always contiguous and each sample's products are one vectorised loop.
/// Without flagged samples, the sums that centre the products come from the series'
/// total and its first and last [`LAGS`] values.
#[derive(Clone, Debug)]
pub struct LaggedSums {
    /// Residuals (0 for a flagged one), each at two slots LAGS apart: from `pos` on, the
    /// newest LAGS, newest first.
    win: [f64; 2 * LAGS],
    /// 1 for a sample used, 0 for a flagged one, stored as `win`.
    ok: [f64; 2 * LAGS],
    pos: usize,
    /// Σ e_t e_{t−k} over pairs of samples used.
    prod: [f64; LAGS],
    /// With flagged samples: Σ e_{t−k}, Σ e_t and the count, over pairs used.
    earlier: [f64; LAGS],
    later: [f64; LAGS],
    pairs: [f64; LAGS],
    /// Whether a sample has been flagged: the centring sums are then kept pair by pair.
    pairwise: bool,
    /// The first LAGS residuals (for the centring sums without flags, and for joining a
    /// series read in parts), and 1 or 0 for each as it was used or flagged.
    head: Vec<f64>,
    head_ok: Vec<f64>,
    n: usize,
    used: usize,
    sum: f64,
}

/// Lags 0 … [`MAX_ORDER`].
pub const LAGS: usize = MAX_ORDER + 1;

// LaggedSums::add takes the lags after 0 in pairs.
const _: () = assert!(MAX_ORDER % 2 == 0, "the lags after 0 go in pairs");

impl Default for LaggedSums {
    fn default() -> Self {
        LaggedSums {
            win: [0.0; 2 * LAGS],
            ok: [0.0; 2 * LAGS],
            pos: 0,
            prod: [0.0; LAGS],
            earlier: [0.0; LAGS],
            later: [0.0; LAGS],
            pairs: [0.0; LAGS],
            pairwise: false,
            head: Vec::with_capacity(LAGS),
            head_ok: Vec::with_capacity(LAGS),
            n: 0,
            used: 0,
            sum: 0.0,
        }
    }
}

impl LaggedSums {
    /// Add the next residual; `flagged` leaves it out.
    #[inline]
    pub fn add(&mut self, e: f64, flagged: bool) {
        if flagged && !self.pairwise {
            // The first flagged sample: from here on the centring sums go pair by pair.
            let (earlier, later, pairs) = self.centring_from_totals();
            (self.earlier, self.later, self.pairs) = (earlier, later, pairs);
            self.pairwise = true;
        }
        let (x, o) = if flagged { (0.0, 0.0) } else { (e, 1.0) };
        // The new sample goes in front of the window (slot pos − 1 mod LAGS, twice), so
        // that win[pos + k] is e_{t−k} (0 before the series began).
        self.pos = (self.pos + LAGS - 1) % LAGS;
        for slot in [self.pos, self.pos + LAGS] {
            if let (Some(w), Some(k)) = (self.win.get_mut(slot), self.ok.get_mut(slot)) {
                (*w, *k) = (x, o);
            }
        }
        if self.head.len() < LAGS {
            self.head.push(x);
            self.head_ok.push(o);
        }
        self.n += 1;
        if flagged {
            return;
        }
        self.used += 1;
        self.sum += x;
        let (Some(lagged), Some(oks)) = (
            self.win.get(self.pos..self.pos + LAGS),
            self.ok.get(self.pos..self.pos + LAGS),
        ) else {
            return;
        };
        // Lag 0 from x itself, not from the slot just written: loading a store still in
        // flight together with its neighbour stalls. Then pairs of lags at a time: two
        // independent lanes the compiler vectorises.
        let (p0, older) = self.prod.split_at_mut(1);
        if let Some(p) = p0.first_mut() {
            *p += x * x;
        }
        let older_lagged = lagged.get(1..).unwrap_or(&[]);
        for (p, l) in older.chunks_exact_mut(2).zip(older_lagged.chunks_exact(2)) {
            if let (Some(p), Some(l)) = (
                <&mut [f64; 2]>::try_from(p).ok(),
                <&[f64; 2]>::try_from(l).ok(),
            ) {
                *p = [p[0] + x * l[0], p[1] + x * l[1]];
            }
        }
        if self.pairwise {
            for (((a, b), c), (l, k)) in self
                .earlier
                .iter_mut()
                .zip(self.later.iter_mut())
                .zip(self.pairs.iter_mut())
                .zip(lagged.iter().zip(oks))
            {
                *a += l;
                *b += x * k;
                *c += k;
            }
        }
    }

    /// Without a flagged sample so far: Σ e_{t−k}, Σ e_t and the pair count over t ≥ k,
    /// from the total less the last (first) k samples.
    fn centring_from_totals(&self) -> ([f64; LAGS], [f64; LAGS], [f64; LAGS]) {
        let (mut earlier, mut later, mut pairs) = ([0.0; LAGS], [0.0; LAGS], [0.0; LAGS]);
        let (mut last_k, mut first_k) = (0.0, 0.0);
        let newest = self.win.get(self.pos..self.pos + LAGS).unwrap_or(&[]);
        for (k, ((a, b), c)) in earlier
            .iter_mut()
            .zip(later.iter_mut())
            .zip(pairs.iter_mut())
            .enumerate()
        {
            if k >= self.n {
                break;
            }
            *a = self.sum - last_k;
            *b = self.sum - first_k;
            *c = (self.n - k) as f64;
            last_k += newest.get(k).copied().unwrap_or(0.0);
            first_k += self.head.get(k).copied().unwrap_or(0.0);
        }
        (earlier, later, pairs)
    }

    /// Σ e_t e_{t−k} for k = 0 … [`MAX_ORDER`], and Σ e_t, over the samples used.
    pub fn products(&self) -> ([f64; LAGS], f64) {
        (self.prod, self.sum)
    }

    /// The sums of a series of `n` samples, none flagged, whose lagged products `prod`
    /// and total `sum` were found otherwise (the streaming engine's pilot corrections,
    /// docs/streaming.md), with its first samples `head` and its newest `newest` (newest
    /// first), LAGS of each or all there are: for [`LaggedSums::followed_by`] and for
    /// reading out.
    pub fn assembled(
        prod: [f64; LAGS],
        sum: f64,
        head: &[f64],
        newest: &[f64],
        n: usize,
    ) -> LaggedSums {
        let mut out = LaggedSums {
            prod,
            sum,
            n,
            used: n,
            ..LaggedSums::default()
        };
        for (j, e) in newest.iter().take(LAGS.min(n)).enumerate() {
            for slot in [j, j + LAGS] {
                if let (Some(w), Some(k)) = (out.win.get_mut(slot), out.ok.get_mut(slot)) {
                    (*w, *k) = (*e, 1.0);
                }
            }
        }
        for e in head.iter().take(LAGS.min(n)) {
            out.head.push(*e);
            out.head_ok.push(1.0);
        }
        out
    }

    /// Samples added, and those used (not flagged).
    pub fn counts(&self) -> (usize, usize) {
        (self.n, self.used)
    }

    /// The sums of this series followed by `later` (the same series read on, by another
    /// thread from where this one stopped): the pairs that straddle the join added from
    /// this one's last samples and `later`'s first. The result is for reading out, not
    /// for adding to.
    pub fn followed_by(&self, later: &LaggedSums) -> LaggedSums {
        let totals = |a: &LaggedSums| {
            if a.pairwise {
                (a.earlier, a.later, a.pairs)
            } else {
                a.centring_from_totals()
            }
        };
        let (mut earlier, mut lat, mut pairs) = totals(self);
        let (e2, l2, p2) = totals(later);
        let mut prod = self.prod;
        for k in 0..LAGS {
            if let (Some(p), Some(q)) = (prod.get_mut(k), later.prod.get(k)) {
                *p += q;
            }
            let add = |a: &mut [f64; LAGS], b: &[f64; LAGS]| {
                if let (Some(x), Some(y)) = (a.get_mut(k), b.get(k)) {
                    *x += y;
                }
            };
            add(&mut earlier, &e2);
            add(&mut lat, &l2);
            add(&mut pairs, &p2);
        }
        // This one's newest samples: win[pos + j] is e_{n−1−j}.
        let newest = self.win.get(self.pos..self.pos + LAGS).unwrap_or(&[]);
        let newest_ok = self.ok.get(self.pos..self.pos + LAGS).unwrap_or(&[]);
        for k in 1..LAGS {
            // Pairs (later's sample i, this one's sample k − i − 1 from its newest).
            for i in 0..k.min(later.head.len()) {
                let j = k - i - 1;
                if j >= self.n.min(LAGS) {
                    continue;
                }
                let (Some(h), Some(ho), Some(w), Some(wo)) = (
                    later.head.get(i),
                    later.head_ok.get(i),
                    newest.get(j),
                    newest_ok.get(j),
                ) else {
                    continue;
                };
                if let (Some(p), Some(a), Some(b), Some(c)) = (
                    prod.get_mut(k),
                    earlier.get_mut(k),
                    lat.get_mut(k),
                    pairs.get_mut(k),
                ) {
                    *p += h * w;
                    *a += w * ho;
                    *b += h * wo;
                    *c += ho * wo;
                }
            }
        }
        let mut out = self.clone();
        out.prod = prod;
        out.earlier = earlier;
        out.later = lat;
        out.pairs = pairs;
        out.pairwise = true;
        out.n += later.n;
        out.used += later.used;
        out.sum += later.sum;
        out
    }

    /// γ̂₀ … γ̂_K about the mean of the samples used, divided by the samples used.
    pub fn autocovariances(&self) -> Vec<f64> {
        let used = self.used.max(1) as f64;
        let mean = self.sum / used;
        let (earlier, later, pairs) = if self.pairwise {
            (self.earlier, self.later, self.pairs)
        } else {
            self.centring_from_totals()
        };
        (0..LAGS)
            .map(|k| {
                let get = |a: &[f64; LAGS]| a.get(k).copied().unwrap_or(0.0);
                let (p, f, s, c) = (get(&self.prod), get(&earlier), get(&later), get(&pairs));
                (p - mean * (f + s) + mean * mean * c) / used
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::{LaggedSums, LAGS};
    use proptest::prelude::*;

    /// γ̂ₖ from its definition (as NoiseModel::estimate has it).
    fn direct(e: &[f64], flagged: &[bool]) -> Vec<f64> {
        let ok = |t: usize| !flagged[t];
        let used = (0..e.len()).filter(|&t| ok(t)).count() as f64;
        let mean = (0..e.len()).filter(|&t| ok(t)).map(|t| e[t]).sum::<f64>() / used;
        (0..LAGS)
            .map(|k| {
                (0..e.len().saturating_sub(k))
                    .filter(|&t| ok(t) && ok(t + k))
                    .map(|t| (e[t] - mean) * (e[t + k] - mean))
                    .sum::<f64>()
                    / used
            })
            .collect()
    }

    fn sums(e: &[f64], flagged: &[bool]) -> LaggedSums {
        let mut s = LaggedSums::default();
        for (x, f) in e.iter().zip(flagged) {
            s.add(*x, *f);
        }
        s
    }

    proptest! {
        /// Whole, and read in two parts joined (as the streaming calibration reads a
        /// file), the sums give the definition's autocovariances: flagged samples or none,
        /// the cut anywhere (within the first lags too).
        #[test]
        fn lagged_sums_give_the_autocovariances(
            e in prop::collection::vec(-50.0f64..50.0, 40..2600),
            flag_every in prop_oneof![Just(0usize), 2usize..200],
            cut in 0.0f64..1.0,
        ) {
            let n = e.len();
            let flagged: Vec<bool> =
                (0..n).map(|t| flag_every > 0 && t % flag_every == 7).collect();
            prop_assume!(flagged.iter().filter(|f| !**f).count() > 10);
            let want = direct(&e, &flagged);
            let a = (cut * n as f64) as usize;
            let whole = sums(&e, &flagged).autocovariances();
            let two = sums(&e[..a], &flagged[..a])
                .followed_by(&sums(&e[a..], &flagged[a..]))
                .autocovariances();
            // Each part assembled from its products, total, first and newest samples (as
            // the pilots' corrections give them), when nothing is flagged.
            let assembled = |e: &[f64]| {
                let (prod, sum) = sums(e, &vec![false; e.len()]).products();
                let newest: Vec<f64> = e.iter().rev().copied().collect();
                LaggedSums::assembled(prod, sum, e, &newest, e.len())
            };
            let parts = if flag_every == 0 {
                assembled(&e[..a]).followed_by(&assembled(&e[a..])).autocovariances()
            } else {
                two.clone()
            };
            let scale = want[0].abs().max(1e-300);
            for got in [&whole, &two, &parts] {
                for (k, (g, w)) in got.iter().zip(&want).enumerate() {
                    prop_assert!((g - w).abs() <= 1e-12 * scale, "lag {k}: {g} against {w}");
                }
            }
        }
    }
}
