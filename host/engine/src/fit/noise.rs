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
        let g0 = gamma[0];
        if !(g0.is_finite() && g0 > 0.0) {
            return Err(NoiseError::Constant);
        }
        // Levinson–Durbin, keeping the order of least BIC: its penalty (ln N per
        // coefficient) rarely takes white noise for correlated (AIC's 2 would, often).
        let mut phi: Vec<f64> = Vec::new();
        let mut v = g0;
        let mut best = (used as f64 * v.ln(), Vec::new(), v);
        for p in 1..=max_p {
            let Some(next) = levinson_step(&mut phi, &gamma, v) else {
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
        const MAX_STEPS: usize = 100;
        const TOLERANCE: f64 = 1e-6;
        let p = self.order();
        let observed = self.observed.clone();
        let (n, q) = r.h.shape();
        if p == 0 {
            // White noise: the fixed point in closed form, σ̂² = RSS/(N − q).
            let g0 = observed.first().copied().unwrap_or(self.var) * n as f64
                / (n as f64 - q as f64).max(1.0);
            return self.with_autocovariances(&[g0]).ok_or(NoiseError::Constant);
        }
        let white = (n as f64 / (n as f64 - q as f64).max(1.0), self.clone());
        let mut m = self;
        for _ in 0..MAX_STEPS {
            let expected = m.expected_residual_autocov(r);
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
