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
//!
//! Here the model and its estimate; `regression` is the covariance of a fit's coefficients
//! under it (and the model corrected for what the fit removed), `rails` finds clipped
//! samples, `lagged` gathers the autocovariances one residual at a time.

mod lagged;
mod model_check;
mod rails;
mod regression;
mod slow;
mod streamed;

pub(crate) use lagged::behind;
pub use lagged::{LaggedSums, LAGS};
pub use model_check::{ModelCheck, PeriodScatter, Verdict, ALPHA as MODEL_CHECK_ALPHA};
pub use rails::{clipped, Rails};
pub use regression::Rescaler;
pub use slow::{
    estimate_pooled, unit_flicker_quadratic, ResidualAllan, SlowDesign, SlowFit, SlowForms,
    SlowPart,
};
pub use streamed::Rows;

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
        let mean = e
            .iter()
            .enumerate()
            .filter(|&(t, _)| ok(t))
            .map(|(_, v)| *v)
            .sum::<f64>()
            / used as f64;
        let x: Vec<f64> = e.iter().map(|v| v - mean).collect();
        let max_p = MAX_ORDER.min(used / 10);
        // Biased autocovariances (divided by the samples used), pairs with a flagged
        // sample left out.
        let gamma: Vec<f64> = (0..=max_p)
            .map(|k| {
                x.iter()
                    .zip(x.iter().skip(k))
                    .enumerate()
                    .filter(|&(t, _)| ok(t) && ok(t + k))
                    .map(|(_, (a, b))| a * b)
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
        let Some(&g0) = gamma.first() else {
            return Err(NoiseError::Constant);
        };
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
        self.autocorrelations(lag + 1)
            .last()
            .copied()
            .unwrap_or(0.0)
    }

    /// ρ₀ … ρ_{n−1}: beyond the stored ones, ρ_k = Σ_i φ_i ρ_{k−1−i}.
    fn autocorrelations(&self, n: usize) -> Vec<f64> {
        let mut rho: Vec<f64> = self.rho.iter().copied().take(n).collect();
        while rho.len() < n {
            let next = self
                .ar
                .iter()
                .zip(rho.iter().rev())
                .map(|(f, r)| f * r)
                .sum();
            rho.push(next);
        }
        rho
    }

    /// The model's autocovariances γ₀ … γ_{n−1} (O(n·p) for all of them).
    pub fn autocovariances(&self, n: usize) -> Vec<f64> {
        self.autocorrelations(n)
            .into_iter()
            .map(|r| r * self.var)
            .collect()
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
}

/// One Levinson–Durbin step: the AR(p−1) coefficients `phi` and innovation variance `v` to
/// AR(p) from the autocovariances `gamma`; `None` when the reflection coefficient is not
/// below 1 in size (not a stationary process, or the lags run out).
fn levinson_step(phi: &mut Vec<f64>, gamma: &[f64], v: f64) -> Option<f64> {
    let p = phi.len() + 1;
    // γ_p, and γ_{p−1} … γ_1 against φ_1 … φ_{p−1}.
    let (gamma_p, lower) = (gamma.get(p)?, gamma.get(1..p)?);
    let acc: f64 = phi.iter().zip(lower.iter().rev()).map(|(f, g)| f * g).sum();
    let kappa = (gamma_p - acc) / v;
    if !(kappa.is_finite() && kappa.abs() < 1.0) {
        return None;
    }
    let prev = phi.clone();
    phi.push(kappa);
    for (f, (a, b)) in phi.iter_mut().zip(prev.iter().zip(prev.iter().rev())) {
        *f = a - kappa * b;
    }
    Some(v * (1.0 - kappa * kappa))
}
