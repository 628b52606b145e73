//! The covariance of a least-squares fit's coefficients under the noise model (the
//! sandwich, through the AR filter), and the model corrected for what the fit took out of
//! the residuals it was estimated from.

use super::{levinson_step, NoiseError, NoiseModel};
use nalgebra::DMatrix;
use std::borrow::Cow;

impl NoiseModel {
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

    /// [`Self::rescaled`] for white noise, which needs only how many regressors the fit
    /// had (σ̂² = RSS/(N − q)), not the regressors; `None` for a correlated model, which
    /// needs them.
    pub fn rescaled_white(&self, q: usize) -> Option<Result<NoiseModel, NoiseError>> {
        (self.order() == 0).then(|| self.clone().fixed_point(self.n, q, |_| Vec::new()))
    }

    /// [`Self::rescaled`] for regressors prepared once ([`Rescaler`]).
    pub fn rescaled_by(self, r: &Rescaler) -> Result<NoiseModel, NoiseError> {
        if r.0.h.nrows() != self.n {
            return Err(NoiseError::Length(r.0.h.nrows(), self.n));
        }
        self.rescaled_with(&r.0)
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
    pub(super) fn fixed_point(
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
            let next = expected
                .first()
                .is_some_and(|&e0| e0 >= 0.5 * m.var)
                .then(|| {
                    let target: Vec<f64> = observed
                        .iter()
                        .zip(&expected)
                        .take(p + 1)
                        .enumerate()
                        .map(|(k, (o, e))| o + m.var * m.autocorrelation(k) - e)
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

    /// One model for several short records of the same noise, each with its own mean
    /// taken out (the readings of the poses of one file): the residuals' biased
    /// autocovariances pooled over the records (pairs within a record only), the order by
    /// BIC over all readings, and the model corrected for what each record's mean took out
    /// (the expected pooled autocovariances matched to the observed ones, as
    /// [`NoiseModel::rescaled`] does for one record; white noise gives RSS/(N − P)).
    /// `records` are residuals about each record's mean; each needs 2 readings or more.
    pub fn pooled_about_means(records: &[&[f64]]) -> Result<NoiseModel, NoiseError> {
        let used: usize = records.iter().map(|r| r.len()).sum();
        if used < 20 || records.iter().any(|r| r.len() < 2) {
            return Err(NoiseError::TooFew(used));
        }
        let longest = records.iter().map(|r| r.len()).max().unwrap_or(0);
        let max_p = super::MAX_ORDER.min(used / 10).min(longest - 1);
        let gamma: Vec<f64> = (0..=max_p)
            .map(|k| {
                let lagged = records.iter().map(|r| {
                    r.iter()
                        .zip(r.iter().skip(k))
                        .map(|(a, b)| a * b)
                        .sum::<f64>()
                });
                lagged.sum::<f64>() / used as f64
            })
            .collect();
        let lengths: Vec<usize> = records.iter().map(|r| r.len()).collect();
        NoiseModel::from_autocovariances(&gamma, used, used)?.pooled_corrected(&lengths)
    }

    /// This model corrected for what the means of records of `lengths` took out of the
    /// pooled autocovariances it was estimated from ([`Self::pooled_about_means`]).
    pub fn pooled_corrected(self, lengths: &[usize]) -> Result<NoiseModel, NoiseError> {
        let used: usize = lengths.iter().sum();
        // Records of one length share their expectation: one regressor set per length.
        let mut counts: Vec<(usize, usize)> = Vec::new();
        for &len in lengths {
            match counts.iter_mut().find(|(l, _)| *l == len) {
                Some((_, count)) => *count += 1,
                None => counts.push((len, 1)),
            }
        }
        let regressors = counts
            .iter()
            .map(|&(len, count)| Ok((Regressors::ones(len)?, (count * len) as f64)))
            .collect::<Result<Vec<_>, NoiseError>>()?;
        self.fixed_point(used, lengths.len(), |m| {
            let mut sum = vec![0.0; m.order() + 1];
            for (r, weight) in &regressors {
                for (s, e) in sum.iter_mut().zip(m.expected_residual_autocov(r)) {
                    *s += weight * e / used as f64;
                }
            }
            sum
        })
    }

    /// The model at the same order had the observed autocovariances been lower by `shift`
    /// (lags 0 … p), before any correction for a fit: with [`Self::rescaled`] or
    /// [`Self::pooled_corrected`] after it, how an estimate answers a known share of its
    /// autocovariances, such as slow noise within the records.
    pub fn shifted(&self, shift: &[f64]) -> Result<NoiseModel, NoiseError> {
        let observed: Vec<f64> = self
            .observed
            .iter()
            .enumerate()
            .map(|(k, o)| o - shift.get(k).copied().unwrap_or(0.0))
            .collect();
        NoiseModel {
            observed: observed.clone(),
            ..self.clone()
        }
        .with_autocovariances(&observed)
        .ok_or(NoiseError::Constant)
    }

    /// The degrees of freedom of this pooled model's mean variance at `n` readings, 2 over
    /// the variance of its logarithm, by a parametric bootstrap of
    /// [`NoiseModel::pooled_about_means`] on records of the `lengths` given (the order
    /// chosen again in each replicate): Σ(n − 1) would state about a twentieth of the spread
    /// for 36 poses of 20 readings of AR(1) at ρ = 0.6, a jackknife at a fixed order two
    /// thirds of it, and for white noise (where BIC's choice of order is what varies) less
    /// than half. `seed` makes it repeatable; `None` when no replicate could be fitted.
    pub fn pooled_mean_variance_dof(&self, lengths: &[usize], n: usize, seed: u64) -> Option<f64> {
        use rand::SeedableRng;
        // Records drawn from one series with this many samples between them: independent
        // to within ρ^GAP.
        const GAP: usize = 200;
        const REPLICATES: usize = 60;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let total: usize = lengths.iter().map(|l| l + GAP).sum();
        let logs: Vec<f64> = (0..REPLICATES)
            .filter_map(|_| {
                let series = super::slow::draw_ar(self, 1.0, total, &mut rng);
                let mut records: Vec<Vec<f64>> = Vec::with_capacity(lengths.len());
                let mut rest = series.as_slice();
                for &len in lengths {
                    let (r, after) = rest.split_at(len.min(rest.len()));
                    let m = r.iter().sum::<f64>() / len.max(1) as f64;
                    records.push(r.iter().map(|v| v - m).collect());
                    rest = after.get(GAP..).unwrap_or(&[]);
                }
                let slices: Vec<&[f64]> = records.iter().map(Vec::as_slice).collect();
                let v = NoiseModel::pooled_about_means(&slices)
                    .ok()?
                    .mean_variance(n)
                    .ok()?;
                (v > 0.0).then(|| v.ln())
            })
            .collect();
        let k = logs.len() as f64;
        if k < 2.0 {
            return None;
        }
        let mean = logs.iter().sum::<f64>() / k;
        let var = logs.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / (k - 1.0);
        (var > 0.0).then(|| 2.0 / var)
    }

    /// The variance of the mean of `n` successive readings under this model.
    pub fn mean_variance(&self, n: usize) -> Result<f64, NoiseError> {
        let cov = self.sandwich_with(&Regressors::ones(n)?);
        cov.get((0, 0)).copied().ok_or(NoiseError::Singular)
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
        let (h, inv) = (r.h.as_ref(), &r.inv);
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
            r.h.tr_mul(&r.h) * self.innovation_var
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

/// Regressors prepared for [`NoiseModel::rescaled_by`], for many models of one fit.
pub struct Rescaler(Regressors<'static>);

impl Rescaler {
    /// For weighted regressors `h` (N × q).
    pub fn new(h: &DMatrix<f64>) -> Result<Rescaler, NoiseError> {
        let r = Regressors::new(h, h.nrows())?;
        Ok(Rescaler(Regressors {
            h: Cow::Owned(h.clone()),
            ..r
        }))
    }

    /// The regressors H (N × q).
    pub fn h(&self) -> &DMatrix<f64> {
        &self.0.h
    }

    /// (HᵀH)⁻¹.
    pub fn gram_inv(&self) -> &DMatrix<f64> {
        &self.0.inv
    }
}

/// Regressors H (N × q) with Hᵀ and (HᵀH)⁻¹, which a rescaling needs at every step.
struct Regressors<'a> {
    h: Cow<'a, DMatrix<f64>>,
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
            h: Cow::Borrowed(h),
            ht: h.transpose(),
            inv,
        })
    }

    /// A column of `n` ones: the regressor of a mean.
    fn ones(n: usize) -> Result<Regressors<'static>, NoiseError> {
        if n == 0 {
            return Err(NoiseError::TooFew(0));
        }
        let h = DMatrix::from_element(n, 1, 1.0);
        Ok(Regressors {
            ht: h.transpose(),
            inv: DMatrix::from_element(1, 1, 1.0 / n as f64),
            h: Cow::Owned(h),
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    /// 36 poses of 20 readings of AR(1) noise at ρ, each about its own mean.
    fn poses_of(rng: &mut ChaCha8Rng, rho: f64) -> Vec<Vec<f64>> {
        (0..36)
            .map(|_| {
                let e0: f64 = rng.sample(StandardNormal);
                let mut x = e0 / (1.0 - rho * rho).sqrt();
                let mut r: Vec<f64> = (0..20)
                    .map(|_| {
                        let e: f64 = rng.sample(StandardNormal);
                        x = rho * x + e;
                        x
                    })
                    .collect();
                let m = r.iter().sum::<f64>() / 20.0;
                r.iter_mut().for_each(|v| *v -= m);
                r
            })
            .collect()
    }

    /// The bootstrap's degrees of freedom state the spread of the pooled model's mean
    /// variance over many records: the variance of its logarithm over 400 records against
    /// the mean of 2/ν, within four standard errors of that variance (√(2/399)). With
    /// Σ(n − 1) = 684 instead, AR(1) at ρ = 0.6 would state about a twentieth of it, and a
    /// jackknife at the model's order 0.66 of it (white noise: 0.42).
    #[test]
    fn pooled_dof_states_the_spread_of_the_mean_variance() {
        let mut rng = ChaCha8Rng::seed_from_u64(30);
        for rho in [0.0, 0.6] {
            let (mut logs, mut stated) = (Vec::new(), 0.0);
            let draws = 400;
            for _ in 0..draws {
                let poses = poses_of(&mut rng, rho);
                let records: Vec<&[f64]> = poses.iter().map(Vec::as_slice).collect();
                let model = NoiseModel::pooled_about_means(&records).unwrap();
                logs.push(model.mean_variance(20).unwrap().ln());
                let lengths = vec![20; 36];
                let dof = model
                    .pooled_mean_variance_dof(&lengths, 20, rng.gen())
                    .unwrap()
                    .min(684.0);
                stated += 2.0 / dof / f64::from(draws);
            }
            let mean = logs.iter().sum::<f64>() / f64::from(draws);
            let spread =
                logs.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / f64::from(draws - 1);
            let ratio = spread / stated;
            let band = 4.0 * (2.0 / f64::from(draws - 1)).sqrt();
            assert!(
                (ratio - 1.0).abs() <= band,
                "ρ = {rho}: spread {spread:.4} of ln var against stated {stated:.4} (ratio {ratio:.3}, band ±{band:.3})"
            );
        }
    }
}
