//! Noise slower than the AR model reaches: flicker (1/f) and a bias random walk (1/f²), the
//! bias instability and acceleration random walk of IEEE Std 952 / 1554, on top of the
//! AR(p) model of [`super`]; estimated from one fit's residuals and propagated exactly into
//! a fit's coefficients (docs/uncertainty.md, "Slow noise").
//!
//! The model of one channel's noise in a group, in output units at one sample per row:
//! e = (an AR model) + flicker (Kasdin's process, innovation variance Q) + random walk
//! (step variance q); [`SlowFit`] holds θ = (1, Q, q), the AR model's scale first.
//!
//! - **Exact without a cutoff.** Flicker and the walk have no stationary covariance. Their
//!   generalised covariance −½·D(|s − t|) (D the structure function) gives the exact
//!   covariance of every contrast (weights summing to zero), and a least-squares fit with an
//!   offset makes contrasts of its residuals and of every coefficient but the offset. The
//!   offset then measures the bias plus the slow noise's mean over the group.
//! - **Estimated from the residuals alone.** The overlapping Allan variances of the
//!   residuals at m = 1, 2, 4, … samples have expectations linear in the levels, computed
//!   exactly for the fit that made the residuals: E[ρᵀAρ] = tr(A(I − P)K(I − P)). Q and q
//!   come from their weighted least squares beyond the short-range correlation, pooled over
//!   groups ([`estimate_pooled`]); they keep their sign, so the variance they add is
//!   unbiased.
//! - **Their uncertainty** is a parametric bootstrap of the same estimator: the degrees of
//!   freedom of a coefficient's variance come from it, so a record with few slow periods
//!   gets a larger k.
//!
//! Rows that average several conversions are weighted by √n in the fit. The slow noise is
//! then w_t·b(t) in the weighted residuals, which the expectations follow exactly; the AR
//! term's diagonal uses the mean of 1/w² (exact when every row holds the same number of
//! conversions).

use super::{NoiseError, NoiseModel};
use crate::allan::powerlaw::{allan_variance, flicker_structure, FlickerIncrements};
use crate::allan::{expected_avar, TermKind};
use nalgebra::{DMatrix, DVector};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};
use std::sync::Arc;

/// The parametric bootstrap's replicates.
const REPLICATES: usize = 40;

/// The bootstrap's seed, mixed with the channel and the residuals (see [`bootstrap_seed`]).
const SEED: u64 = 0x5107_0000;

/// The three terms of the model.
const TERMS: usize = 3;

/// A symmetric Toeplitz matrix T_st = κ(|s − t|) of order n, applied by circulant embedding.
struct Toeplitz {
    n: usize,
    /// The circulant's eigenvalues divided by its size (real: the circulant is symmetric).
    lambda: Vec<f64>,
    fwd: Arc<dyn Fft<f64>>,
    inv: Arc<dyn Fft<f64>>,
}

impl Toeplitz {
    fn new(kappa: &[f64], planner: &mut FftPlanner<f64>) -> Toeplitz {
        let n = kappa.len();
        let size = (2 * n).next_power_of_two().max(2);
        let mut c = vec![Complex::new(0.0, 0.0); size];
        for (x, k) in c.iter_mut().zip(kappa) {
            x.re = *k;
        }
        for (x, k) in c.iter_mut().rev().zip(kappa.iter().skip(1)) {
            x.re = *k;
        }
        let fwd = planner.plan_fft_forward(size);
        let inv = planner.plan_fft_inverse(size);
        fwd.process(&mut c);
        let lambda = c.iter().map(|z| z.re / size as f64).collect();
        Toeplitz {
            n,
            lambda,
            fwd,
            inv,
        }
    }

    /// T·x for every column of `x` (n rows), two columns per complex transform.
    fn mul(&self, x: &DMatrix<f64>) -> DMatrix<f64> {
        let mut out = DMatrix::zeros(x.nrows(), x.ncols());
        let mut buf = vec![Complex::new(0.0, 0.0); self.lambda.len()];
        let cols: Vec<usize> = (0..x.ncols()).collect();
        for pair in cols.chunks(2) {
            buf.iter_mut().for_each(|z| *z = Complex::new(0.0, 0.0));
            let (a, b) = (pair.first().copied(), pair.get(1).copied());
            if let Some(a) = a {
                for (z, v) in buf.iter_mut().zip(x.column(a).iter()) {
                    z.re = *v;
                }
            }
            if let Some(b) = b {
                for (z, v) in buf.iter_mut().zip(x.column(b).iter()) {
                    z.im = *v;
                }
            }
            self.fwd.process(&mut buf);
            for (z, l) in buf.iter_mut().zip(&self.lambda) {
                *z *= *l;
            }
            self.inv.process(&mut buf);
            if let Some(a) = a {
                for (o, z) in out.column_mut(a).iter_mut().zip(&buf) {
                    *o = z.re;
                }
            }
            if let Some(b) = b {
                for (o, z) in out.column_mut(b).iter_mut().zip(&buf) {
                    *o = z.im;
                }
            }
        }
        debug_assert_eq!(out.nrows(), self.n);
        out
    }
}

/// The averaging lengths of the Allan variances: 1, 2, 4, … samples while at least a
/// quarter of the record's differences remain (N − 2m + 1 ≥ N/4).
fn octaves(n: usize) -> Vec<usize> {
    std::iter::successors(Some(1usize), |m| Some(m * 2))
        .take_while(|m| 4 * (n + 1).saturating_sub(2 * m) >= n && 2 * m < n)
        .collect()
}

/// Prefix sums S_0 = 0, S_{t+1} = S_t + x_t.
fn prefix(x: impl Iterator<Item = f64>) -> Vec<f64> {
    let mut s = vec![0.0];
    let mut acc = 0.0;
    for v in x {
        acc += v;
        s.push(acc);
    }
    s
}

/// The Allan differences at m of a series from its prefix sums: c_i = S_{i+2m} − 2S_{i+m}
/// + S_i, i = 0 … N − 2m (the sum of the second block of m minus the first).
fn differences(s: &[f64], m: usize) -> impl Iterator<Item = f64> + '_ {
    s.iter()
        .zip(s.iter().skip(m))
        .zip(s.iter().skip(2 * m))
        .map(|((a, b), c)| c - 2.0 * b + a)
}

/// The overlapping Allan variance at m from prefix sums: Σc²/(2·n·m²).
fn allan_from_prefix(s: &[f64], m: usize) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for c in differences(s, m) {
        sum += c * c;
        n += 1;
    }
    sum / (2.0 * n.max(1) as f64 * (m * m) as f64)
}

/// A group's design as the slow-noise estimate and the propagation need it, shared by its
/// channels: the weighted regressors of the fit that made the residuals, and the slow
/// terms' expected Allan variances for that fit.
pub struct SlowDesign {
    /// √(conversions) of each row.
    weights: Vec<f64>,
    /// The weighted regressors H_w (N × q) with (H_wᵀH_w)⁻¹, prepared for rescaling AR
    /// models too (many per bootstrap).
    rescaler: super::Rescaler,
    /// The raw regressors' (H₀ = W⁻¹H_w) prefix sums per column (N + 1 each).
    h0_prefix: Vec<Vec<f64>>,
    /// Per averaging length: H₀ᵀAH₀.
    octaves: Vec<Octave>,
    /// The mean of 1/w².
    mean_inv_w2: f64,
    /// Unit flicker and unit walk as Toeplitz operators, and their expected Allan
    /// variances for this fit.
    flicker: Toeplitz,
    walk: Toeplitz,
    expected_slow: [Vec<f64>; 2],
    /// The slow terms' expected residual autocovariances at lags 0 … [`super::MAX_ORDER`].
    lagged_slow: [Vec<f64>; 2],
    /// Unit white noise's expected Allan variances for this fit (the short-range a/m).
    expected_white: Vec<f64>,
}

impl std::fmt::Debug for SlowDesign {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SlowDesign")
            .field("rows", &self.hw().nrows())
            .field("columns", &self.hw().ncols())
            .finish_non_exhaustive()
    }
}

/// One averaging length's share of the expectations.
struct Octave {
    m: usize,
    /// n·2m²: the statistic's normaliser.
    norm: f64,
    /// H₀ᵀAH₀ (q × q).
    hah: DMatrix<f64>,
}

impl SlowDesign {
    /// The weighted regressors H_w (N × q).
    fn hw(&self) -> &DMatrix<f64> {
        self.rescaler.h()
    }

    /// (H_wᵀH_w)⁻¹.
    fn gram_inv(&self) -> &DMatrix<f64> {
        self.rescaler.gram_inv()
    }

    /// For a fit of weighted regressors `hw` (N × q, with an offset column w) to rows
    /// of weights `weights`.
    pub fn new(hw: &DMatrix<f64>, weights: &[f64]) -> Result<SlowDesign, NoiseError> {
        let n = hw.nrows();
        if weights.len() != n {
            return Err(NoiseError::Length(weights.len(), n));
        }
        if n < 64 {
            return Err(NoiseError::TooFew(n));
        }
        let rescaler = super::Rescaler::new(hw)?;
        let q = hw.ncols();
        let h0 = DMatrix::from_fn(n, q, |t, j| {
            hw[(t, j)] / weights.get(t).copied().unwrap_or(1.0)
        });
        let h0_prefix: Vec<Vec<f64>> = (0..q)
            .map(|j| prefix(h0.column(j).iter().copied()))
            .collect();
        let octaves = octaves(n)
            .into_iter()
            .map(|m| {
                let mut hah = DMatrix::zeros(q, q);
                let mut count = 0usize;
                let rows = column_differences(&h0_prefix, m);
                for c in &rows {
                    hah += c * c.transpose();
                    count += 1;
                }
                let norm = 2.0 * count.max(1) as f64 * (m * m) as f64;
                Octave {
                    m,
                    norm,
                    hah: hah / norm,
                }
            })
            .collect();
        let mean_inv_w2 = weights.iter().map(|w| 1.0 / (w * w)).sum::<f64>() / n as f64;
        let mut planner = FftPlanner::new();
        let fl: Vec<f64> = (0..n as u64).map(|k| -0.5 * flicker_structure(k)).collect();
        let rw: Vec<f64> = (0..n).map(|k| -0.5 * k as f64).collect();
        let flicker = Toeplitz::new(&fl, &mut planner);
        let walk = Toeplitz::new(&rw, &mut planner);
        let mut d = SlowDesign {
            weights: weights.to_vec(),
            h0_prefix,
            octaves,
            mean_inv_w2,
            flicker,
            walk,
            expected_slow: [Vec::new(), Vec::new()],
            lagged_slow: [Vec::new(), Vec::new()],
            expected_white: Vec::new(),
            rescaler,
        };
        // The slow terms act on the rows as W·T·W (the walk's b(t) scaled by each row's
        // weight); W⁻¹KH_w = T·(W H_w).
        let whw = d.weighted_rows(d.hw());
        let kx_fl = d.flicker.mul(&whw);
        let kx_rw = d.walk.mul(&whw);
        let fl_exp = d.expected(&kx_fl, &whw.tr_mul(&kx_fl), |m| {
            expected_avar(TermKind::Flicker, m)
        });
        let rw_exp = d.expected(&kx_rw, &whw.tr_mul(&kx_rw), |m| {
            expected_avar(TermKind::RandomWalk, m)
        });
        let lags = super::MAX_ORDER.min(n - 1);
        let fl_lag = d.expected_lagged(&kx_fl, &whw.tr_mul(&kx_fl), lags, |k| {
            -0.5 * flicker_structure(k as u64)
        });
        let rw_lag = d.expected_lagged(&kx_rw, &whw.tr_mul(&kx_rw), lags, |k| -0.5 * k as f64);
        d.expected_slow = [fl_exp, rw_exp];
        d.lagged_slow = [fl_lag, rw_lag];
        // Channel-independent: once per design, not per channel.
        let white_gamma: Vec<f64> = std::iter::once(1.0)
            .chain(std::iter::repeat_n(0.0, n - 1))
            .collect();
        d.expected_white = d.expected_ar(&NoiseModel::white(1.0, n), &white_gamma);
        Ok(d)
    }

    /// The expected biased autocovariances (1/N)·Σ_t r_t r_{t+k} of the weighted residuals
    /// at lags 0 … `lags` for one slow term, from kx = T·(WH_w), M = H_wᵀK_wH_w and κ:
    /// (tr(L_kK_w) − 2·tr(L_kPK_w) + tr(L_kPK_wP))/N, L_k the symmetrised lag-k sum.
    fn expected_lagged(
        &self,
        kx: &DMatrix<f64>,
        mw: &DMatrix<f64>,
        lags: usize,
        kappa: impl Fn(usize) -> f64,
    ) -> Vec<f64> {
        let n = self.hw().nrows();
        let wkxg = self.weighted_rows(kx) * self.gram_inv();
        let y = self.hw() * (self.gram_inv() * mw * self.gram_inv());
        let lagged_dot = |a: &DMatrix<f64>, b: &DMatrix<f64>, k: usize| -> f64 {
            let (mut sum, mut back) = (0.0, 0.0);
            for (ra, rb) in a.row_iter().zip(b.row_iter().skip(k)) {
                sum += ra.dot(&rb);
            }
            for (rb, ra) in b.row_iter().zip(a.row_iter().skip(k)) {
                back += ra.dot(&rb);
            }
            (sum + back) / 2.0
        };
        (0..=lags)
            .map(|k| {
                let ww: f64 = self
                    .weights
                    .iter()
                    .zip(self.weights.iter().skip(k))
                    .map(|(a, b)| a * b)
                    .sum();
                let t1 = kappa(k) * ww;
                let t2 = lagged_dot(&wkxg, self.hw(), k);
                let t3 = lagged_dot(&y, self.hw(), k);
                (t1 - 2.0 * t2 + t3) / n as f64
            })
            .collect()
    }

    /// The rows of `x` times their weights.
    fn weighted_rows(&self, x: &DMatrix<f64>) -> DMatrix<f64> {
        let mut out = x.clone();
        for (mut row, w) in out.row_iter_mut().zip(&self.weights) {
            row *= *w;
        }
        out
    }

    /// The expected Allan variances of the raw residuals at each octave for one term, from
    /// kx = W⁻¹K_wH_w (N × q), M = H_wᵀK_wH_w and tr(A·K) per m:
    /// tr(AK) − 2·tr(G·Σc(kx)ᵀc(H₀))/norm + tr(G·H₀ᵀAH₀·G·M).
    fn expected(
        &self,
        kx: &DMatrix<f64>,
        mw: &DMatrix<f64>,
        tr_ak: impl Fn(usize) -> f64,
    ) -> Vec<f64> {
        let q = kx.ncols();
        let kx_prefix: Vec<Vec<f64>> = (0..q)
            .map(|j| prefix(kx.column(j).iter().copied()))
            .collect();
        let gm = self.gram_inv() * mw * self.gram_inv();
        self.octaves
            .iter()
            .map(|o| {
                let hs = column_differences(&self.h0_prefix, o.m);
                let ks = column_differences(&kx_prefix, o.m);
                let cross: f64 = hs
                    .iter()
                    .zip(&ks)
                    .map(|(h, k)| (k.transpose() * self.gram_inv() * h).to_scalar())
                    .sum::<f64>()
                    / o.norm;
                let last = (&o.hah * &gm).trace();
                tr_ak(o.m) - 2.0 * cross + last
            })
            .collect()
    }

    /// The raw residuals' Allan variances at each octave.
    fn statistics(&self, weighted_resid: &[f64]) -> Vec<f64> {
        self.raw_statistics(&self.unweighted(weighted_resid))
    }

    /// The raw residuals r/w.
    fn unweighted(&self, weighted_resid: &[f64]) -> Vec<f64> {
        weighted_resid
            .iter()
            .zip(&self.weights)
            .map(|(r, w)| r / w)
            .collect()
    }

    /// [`Self::statistics`] of raw residuals.
    fn raw_statistics(&self, raw: &[f64]) -> Vec<f64> {
        let s = prefix(raw.iter().copied());
        self.octaves
            .iter()
            .map(|o| allan_from_prefix(&s, o.m))
            .collect()
    }

    /// The AR term's expectations: its autocovariances γ₀ … γ_{N−1} as a Toeplitz Γ on the
    /// weighted rows, so W⁻¹ΓH_w and H_wᵀΓH_w; tr(AΓ) as mean(1/w²)·AVAR.
    fn expected_ar(&self, ar: &NoiseModel, gamma: &[f64]) -> Vec<f64> {
        let mut planner = FftPlanner::new();
        let t = Toeplitz::new(gamma, &mut planner);
        let gh = t.mul(self.hw());
        let mut kx = gh.clone();
        for (mut row, w) in kx.row_iter_mut().zip(&self.weights) {
            row /= *w;
        }
        let mw = self.hw().tr_mul(&gh);
        let g0 = ar.var;
        let d = |k: u64| 2.0 * (g0 - gamma.get(k as usize).copied().unwrap_or(0.0));
        let scale = self.mean_inv_w2;
        self.expected(&kx, &mw, |m| scale * allan_variance(m as u64, d))
    }

    /// The raw residuals' overlapping Allan variance at each averaging length the slow
    /// levels are fitted over, beside its exact expectation for this fit under the model:
    /// the AR model `ar` and the slow levels `[Q, q]` (signed, as estimated), term by term.
    /// A check of the model against the data: the AR model's line covers the short times,
    /// the slow terms the long ones (docs/uncertainty.md, "Slow noise").
    pub fn residual_allan(
        &self,
        weighted_resid: &[f64],
        ar: &NoiseModel,
        [q_fl, q_rw]: [f64; 2],
    ) -> Vec<ResidualAllan> {
        let gamma = ar.autocovariances(self.hw().nrows());
        let short = self.expected_ar(ar, &gamma);
        let raw = self.unweighted(weighted_resid);
        let observed = self.raw_statistics(&raw);
        self.octaves
            .iter()
            .zip(observed)
            .zip(short)
            .zip(self.expected_slow[0].iter().zip(&self.expected_slow[1]))
            .map(|(((o, observed), short_range), (fl, rw))| ResidualAllan {
                m: o.m,
                observed,
                interval: crate::allan::interval_of(&raw, observed.max(0.0).sqrt(), o.m),
                short_range,
                flicker: q_fl * fl,
                walk: q_rw * rw,
            })
            .collect()
    }

    /// One bootstrap draw of the fit's weighted residuals under AR model `ar` at `scale`
    /// times its variance plus flicker Q and walk q, for each (Q, q) of `levels`
    /// from the same random numbers (common random numbers: their differences are the
    /// levels' effect, not the draws' scatter).
    fn draw_residuals(
        &self,
        (ar, scale): (&NoiseModel, f64),
        levels: &[(f64, f64)],
        flicker_gen: &FlickerIncrements,
        rng: &mut ChaCha8Rng,
    ) -> Vec<Vec<f64>> {
        let n = self.hw().nrows();
        let e = draw_ar(ar, scale, n, rng);
        // The unit flicker and walk, weighted as the rows are.
        let mut fl = vec![0.0; n];
        let inc = flicker_gen.draw(rng);
        let mut level = 0.0;
        for (x, (d, w)) in fl
            .iter_mut()
            .skip(1)
            .zip(inc.iter().zip(self.weights.iter().skip(1)))
        {
            level += d;
            *x = w * level;
        }
        let mut rw = vec![0.0; n];
        let mut level = 0.0;
        for (x, w) in rw.iter_mut().zip(&self.weights).skip(1) {
            level += rng.sample::<f64, _>(StandardNormal);
            *x = w * level;
        }
        levels
            .iter()
            .map(|&(fq, wq)| {
                let (a, b) = (fq.max(0.0).sqrt(), wq.max(0.0).sqrt());
                let ev = DVector::from_iterator(
                    n,
                    e.iter()
                        .zip(fl.iter().zip(&rw))
                        .map(|(x, (f, r))| x + a * f + b * r),
                );
                let beta = self.gram_inv() * self.hw().tr_mul(&ev);
                (ev - self.hw() * beta).as_slice().to_vec()
            })
            .collect()
    }

    /// The covariance of the coefficients of weighted regressors `hs` (N × p, an offset
    /// column among them) under unit flicker and unit walk: W̃ᵀ(WTW)W̃ with W̃ the
    /// estimator's weights made contrasts (the offset's measurand is the bias plus the slow
    /// noise's weighted mean over the group).
    pub fn slow_covariances(&self, hs: &DMatrix<f64>) -> Result<[DMatrix<f64>; 2], NoiseError> {
        if hs.nrows() != self.hw().nrows() {
            return Err(NoiseError::Length(hs.nrows(), self.hw().nrows()));
        }
        let inv = hs.tr_mul(hs).try_inverse().ok_or(NoiseError::Singular)?;
        let est = hs * inv;
        let w = DVector::from_column_slice(&self.weights);
        let v = est.tr_mul(&w);
        let wtw = w.dot(&w);
        let contrast = &est - &w * v.transpose() / wtw;
        let scaled = self.weighted_rows(&contrast);
        let fl = scaled.tr_mul(&self.flicker.mul(&scaled));
        let rw = scaled.tr_mul(&self.walk.mul(&scaled));
        Ok([fl, rw])
    }
}

impl SlowDesign {
    /// xᵀ(WTW)x under unit flicker and unit walk, for a contrast x of the weighted rows
    /// (xᵀw = 0): the variance a fit coefficient with estimator weights x takes from them.
    pub fn slow_quadratic(&self, x: &DVector<f64>) -> [f64; 2] {
        let [fl, rw] = self.slow_gram(&DMatrix::from_column_slice(x.len(), 1, x.as_slice()));
        [fl.get((0, 0)), rw.get((0, 0))].map(|v| v.copied().unwrap_or(0.0))
    }

    /// Xᵀ(WTW)X under unit flicker and unit walk, for contrasts X of the weighted rows.
    pub(super) fn slow_gram(&self, x: &DMatrix<f64>) -> [DMatrix<f64>; 2] {
        let scaled = self.weighted_rows(x);
        let fl = scaled.tr_mul(&self.flicker.mul(&scaled));
        let rw = scaled.tr_mul(&self.walk.mul(&scaled));
        [fl, rw]
    }

    /// XᵀΓX for the AR model `ar`'s autocovariances Γ on the weighted rows.
    pub(super) fn ar_gram(&self, ar: &NoiseModel, x: &DMatrix<f64>) -> DMatrix<f64> {
        let gamma = ar.autocovariances(x.nrows());
        let t = Toeplitz::new(&gamma, &mut FftPlanner::new());
        x.tr_mul(&t.mul(x))
    }

    /// X less its projection on the fit's regressors: (I − P)X, weighted rows.
    pub(crate) fn off_fit(&self, x: &DMatrix<f64>) -> DMatrix<f64> {
        x - self.hw() * (self.gram_inv() * self.hw().tr_mul(x))
    }

    /// Each row's weight.
    pub(super) fn weights(&self) -> &[f64] {
        &self.weights
    }
}

/// xᵀTx under unit flicker for a contrast x of n rows of unit weight (xᵀ1 = 0): the
/// variance unit flicker gives an estimator with weights x. What
/// [`SlowDesign::slow_quadratic`] gives for flicker, without building a whole design.
pub fn unit_flicker_quadratic(x: &DVector<f64>) -> f64 {
    let kappa: Vec<f64> = (0..x.len() as u64)
        .map(|k| -0.5 * flicker_structure(k))
        .collect();
    let t = Toeplitz::new(&kappa, &mut FftPlanner::new());
    let col = DMatrix::from_column_slice(x.len(), 1, x.as_slice());
    col.tr_mul(&t.mul(&col)).get((0, 0)).copied().unwrap_or(0.0)
}

/// Unit flicker and unit walk as Toeplitz operators on a grid of `n` rows one interval
/// apart, built once for every set of weights on that grid.
pub struct SlowForms {
    flicker: Toeplitz,
    walk: Toeplitz,
}

impl std::fmt::Debug for SlowForms {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SlowForms")
            .field("rows", &self.flicker.n)
            .finish_non_exhaustive()
    }
}

impl SlowForms {
    /// The operators for a grid of `n` rows.
    pub fn new(n: usize) -> Self {
        let mut planner = FftPlanner::new();
        let fl: Vec<f64> = (0..n as u64).map(|k| -0.5 * flicker_structure(k)).collect();
        let rw: Vec<f64> = (0..n).map(|k| -0.5 * k as f64).collect();
        SlowForms {
            flicker: Toeplitz::new(&fl, &mut planner),
            walk: Toeplitz::new(&rw, &mut planner),
        }
    }

    /// XᵀTX under unit flicker and under unit walk, for columns X (the grid's rows) that
    /// are contrasts (each column sums to zero): the covariance that estimators with weights
    /// X take from them. Rows between two stretches of a record can be zero, so the
    /// stretches' slow noise is one process, as it is in the sensor.
    pub fn of(&self, x: &DMatrix<f64>) -> [DMatrix<f64>; 2] {
        [x.tr_mul(&self.flicker.mul(x)), x.tr_mul(&self.walk.mul(x))]
    }
}

/// The Allan differences at m of every column, as one vector per difference.
fn column_differences(prefixes: &[Vec<f64>], m: usize) -> Vec<DVector<f64>> {
    let cols: Vec<Vec<f64>> = prefixes
        .iter()
        .map(|s| differences(s, m).collect())
        .collect();
    let n = cols.first().map_or(0, Vec::len);
    (0..n)
        .map(|i| {
            DVector::from_iterator(
                cols.len(),
                cols.iter().map(|c| c.get(i).copied().unwrap_or(0.0)),
            )
        })
        .collect()
}

/// `n` samples of the AR model at `scale` times its variance, after a burn-in.
pub(crate) fn draw_ar(m: &NoiseModel, scale: f64, n: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
    const BURN_IN: usize = 2000;
    let sd = (m.innovation_var * scale.max(0.0)).sqrt();
    let p = m.order();
    let mut hist: Vec<f64> = vec![0.0; p];
    let mut out = Vec::with_capacity(n);
    for t in 0..BURN_IN + n {
        let e =
            m.ar.iter()
                .zip(hist.iter().rev())
                .map(|(f, x)| f * x)
                .sum::<f64>()
                + sd * rng.sample::<f64, _>(StandardNormal);
        if p > 0 {
            hist.remove(0);
            hist.push(e);
        }
        if t >= BURN_IN {
            out.push(e);
        }
    }
    out
}

/// One averaging length of [`SlowDesign::residual_allan`]: Allan variances of the raw
/// residuals, output units².
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ResidualAllan {
    /// Rows averaged.
    pub m: usize,
    /// The residuals' own.
    pub observed: f64,
    /// The 1σ interval of its square root, the Allan deviation (noise id and Greenhall's
    /// degrees of freedom, as `rotacal allan` gives it), where one can be given.
    pub interval: Option<crate::allan::Interval>,
    /// Expected from the AR (short-range) model through the fit.
    pub short_range: f64,
    /// Expected from the flicker, at its signed level.
    pub flicker: f64,
    /// Expected from the walk, at its signed level.
    pub walk: f64,
}

impl ResidualAllan {
    /// The model's expectation, all terms.
    pub fn expected(&self) -> f64 {
        self.short_range + self.flicker + self.walk
    }
}

/// One group's share of a pooled estimate: its design, its weighted residuals of the fit
/// the design describes, and the AR model estimated from them (rescaled for that fit).
pub struct SlowPart<'a> {
    /// The group's design.
    pub design: &'a SlowDesign,
    /// Its weighted residuals.
    pub resid: &'a [f64],
    /// Its AR model.
    pub ar: &'a NoiseModel,
}

/// The slow terms' indices among the pooled parameters: flicker Q, walk q; then two
/// short-range nuisance levels per group.
const SLOW: usize = 2;

/// The smallest averaging length the slow levels are fitted from, in units of the
/// short-range model's correlation length (its variance factor at ω = 0), and at least 8.
const LENGTHS_PER_CORRELATION: f64 = 4.0;

/// Estimate one channel's slow terms from several groups of the same recording: one
/// flicker Q and one walk q (a property of the sensor's channel), each group its own AR
/// model. `None` when there are too few averaging lengths to fit them; else per group its
/// [`SlowFit`] and its AR model re-estimated without the slow share. `channel` seeds the
/// bootstrap.
///
/// - The slow levels come from the averaging lengths m ≥ m₀ beyond the short-range noise's
///   correlation, where that noise's Allan variance is a/m + b/m² (a, b free per group; the
///   a/m column exact for the fit, the b/m² one plain): a 32-lag AR model would read part
///   of the slow power as correlation, and its shape at long m carry it twice.
/// - Then each group's AR model again, from its residuals' autocovariances less the slow
///   terms' exact expected share; m₀ from that model (at most the fourth-longest length,
///   so that a model that took up slow power cannot leave too few: at a 100 µg floor that
///   refused about a third of the channels); and the levels once more.
/// - Their covariance and bias by [`bootstrap_covariance`]; the bias is subtracted (on
///   white noise it was 0.075 of the flicker level's u, low).
/// - The estimates keep their sign: a negative Q or q is the unbiased estimate of a level
///   the record cannot tell from zero, so that the variance they add is unbiased too (a
///   truncated one overstated U by 9 % on white noise).
pub fn estimate_pooled(
    parts: &[SlowPart<'_>],
    channel: u64,
) -> Result<Option<Vec<(SlowFit, NoiseModel)>>, NoiseError> {
    for p in parts {
        if p.resid.len() != p.design.hw().nrows() {
            return Err(NoiseError::Length(p.resid.len(), p.design.hw().nrows()));
        }
    }
    let Some((theta, models)) = fit_levels(parts, true)? else {
        return Ok(None);
    };
    let (cov, bias) = bootstrap_covariance(parts, &models, theta, channel);
    let theta = [theta[0] - bias[0], theta[1] - bias[1]];
    // Each group's AR model again at the levels used: the short-range share is what the
    // residuals hold beyond the slow terms at these levels, not at the biased ones (the
    // model at the fitted levels where these are too large for its autocovariances).
    // Fitted at the biased levels, a walk's share of 0.4 counts² at every lag left one
    // channel's autocovariances negative and its AR(32) a notch at the fit frequency:
    // U 34 times too small (docs/uncertainty.md).
    let models: Vec<NoiseModel> = parts
        .iter()
        .zip(models)
        .map(|(p, m)| model_without(p, &autocovariances(p), theta, true).unwrap_or(m))
        .collect();
    let c = |i: usize, j: usize| cov.get((i, j)).copied().unwrap_or(0.0);
    let out = models
        .into_iter()
        .map(|model| {
            // The AR model's own scale estimate: relative variance 2/ν.
            let ar_var = 2.0 / model.dof(3);
            let fit = SlowFit {
                theta: [1.0, theta[0], theta[1]],
                cov: [
                    [ar_var, 0.0, 0.0],
                    [0.0, c(0, 0), c(0, 1)],
                    [0.0, c(1, 0), c(1, 1)],
                ],
            };
            (fit, model)
        })
        .collect();
    Ok(Some(out))
}

/// A group's residuals' autocovariances at lags 0 to the AR models' highest order.
fn autocovariances(p: &SlowPart<'_>) -> Vec<f64> {
    let n = p.resid.len();
    (0..=super::MAX_ORDER.min(n / 10))
        .map(|k| {
            let lagged = p.resid.iter().zip(p.resid.iter().skip(k));
            lagged.map(|(a, b)| a * b).sum::<f64>() / n as f64
        })
        .collect()
}

/// A group's AR model from its residuals' autocovariances `observed` less the slow terms'
/// expected share at `levels` (rescaled for the fit with `rescale`); `None` where the
/// levels are too large for these autocovariances.
fn model_without(
    p: &SlowPart<'_>,
    observed: &[f64],
    levels: [f64; SLOW],
    rescale: bool,
) -> Option<NoiseModel> {
    let n = p.resid.len();
    let adjusted: Vec<f64> = observed
        .iter()
        .enumerate()
        .map(|(k, gk)| {
            let share = |i: usize, level: f64| {
                let unit = p.design.lagged_slow.get(i).and_then(|l| l.get(k));
                level * unit.copied().unwrap_or(0.0)
            };
            gk - share(0, levels[0]) - share(1, levels[1])
        })
        .collect();
    NoiseModel::from_autocovariances(&adjusted, n, n)
        .and_then(|m| {
            if rescale {
                m.rescaled_by(&p.design.rescaler)
            } else {
                Ok(m)
            }
        })
        .ok()
}

/// The slow levels (Q, q) and each group's AR model without their share.
type Levels = ([f64; SLOW], Vec<NoiseModel>);

/// The [`Levels`] of [`estimate_pooled`]; `None` when there are too few averaging lengths.
///
/// `rescale`: whether the AR models are rescaled for the fit (as reported); the bootstrap,
/// which needs only the levels, uses the models only for the averaging lengths and leaves
/// it out: a high-order model's rescaling costs some 100 times the rest.
fn fit_levels(parts: &[SlowPart<'_>], rescale: bool) -> Result<Option<Levels>, NoiseError> {
    let groups = parts.len();
    let stats: Vec<Vec<f64>> = parts.iter().map(|p| p.design.statistics(p.resid)).collect();
    let observed: Vec<Vec<f64>> = parts.iter().map(autocovariances).collect();
    let mut m0 = vec![8usize; groups];
    let mut models: Vec<NoiseModel> = parts.iter().map(|p| p.ar.clone()).collect();
    let mut fit = None;
    for round in 0..2 {
        let Some(sys) = LevelSystem::new(parts, &stats, &m0) else {
            return Ok(None);
        };
        let est = sys.fit().ok_or(NoiseError::Singular)?;
        let levels = [est.theta(0), est.theta(1)];
        fit = Some(est);
        if round == 1 && !rescale {
            break;
        }
        // Each group's AR model without the slow terms' expected share; where the levels
        // are too large for its autocovariances, the model as first estimated.
        for (((model, p), obs), m0) in models.iter_mut().zip(parts).zip(&observed).zip(&mut m0) {
            *model = model_without(p, obs, levels, rescale).unwrap_or_else(|| p.ar.clone());
            if round == 0 {
                let corr = model.variance_factor(0.0).clamp(1.0, 1e6);
                let want = (LENGTHS_PER_CORRELATION * corr).ceil() as usize;
                // At most the fourth-longest averaging length: a model that took up slow
                // power (its own fit failed) would otherwise leave too few to fit.
                let cap = p.design.octaves.last().map_or(8, |o| (o.m / 8).max(8));
                *m0 = want.max(8).next_power_of_two().min(cap);
            }
        }
    }
    Ok(fit.map(|est| ([est.theta(0), est.theta(1)], models)))
}

/// The covariance and the bias of (Q̂, q̂) by a parametric bootstrap of the whole
/// estimate: residuals drawn from the groups' AR models plus the slow terms through each
/// group's fit, and [`fit_levels`] run on them.
///
/// - The whole estimate, not its linearisation: the averaging lengths used, the weights
///   and the AR models all follow the data, which a fixed linear map of the statistics
///   did not see (the flicker's standard error 17 % short on white noise).
/// - The estimator's covariance grows with the levels. Drawn at the estimates with a
///   negative one taken as zero (plug-in), it is biased up where a level is near zero: half
///   the records draw at a positive level, none below. So it is taken at the signed
///   estimates: from the same draws at (0, 0), (|Q̂|, 0), (0, |q̂|) and (|Q̂|, |q̂|), the
///   bilinear form in the levels through them evaluated at (Q̂, q̂) (the plug-in itself when
///   both are positive). Each variance is kept at least half of the plug-in's, the
///   correlation that of C(0, 0) where the form would lose it.
/// - The bias: each replicate's estimates less the levels drawn, through the same form;
///   their mean, whose sampling covariance (over the replicates) is added to the levels'.
fn bootstrap_covariance(
    parts: &[SlowPart<'_>],
    models: &[NoiseModel],
    theta: [f64; SLOW],
    channel: u64,
) -> (DMatrix<f64>, [f64; SLOW]) {
    let mut rng = ChaCha8Rng::seed_from_u64(bootstrap_seed(parts, channel));
    let gens: Vec<FlickerIncrements> = parts
        .iter()
        .map(|p| FlickerIncrements::new(p.resid.len().saturating_sub(1)))
        .collect();
    let [fq, wq] = theta;
    let levels = [
        (0.0, 0.0),
        (fq.abs(), 0.0),
        (0.0, wq.abs()),
        (fq.abs(), wq.abs()),
    ];
    let mut draws: [Vec<Vec<f64>>; 4] = Default::default();
    // The bias at the signed estimates, replicate by replicate (the four draws share their
    // random numbers): the same bilinear form of each corner's estimate less its level.
    let (sf, sw) = (fq.signum(), wq.signum());
    let form = [1.0 - sf - sw + sf * sw, sf - sf * sw, sw - sf * sw, sf * sw];
    let mut biases: Vec<Vec<f64>> = Vec::with_capacity(REPLICATES);
    for _ in 0..REPLICATES {
        let drawn: Vec<Vec<Vec<f64>>> = parts
            .iter()
            .zip(models)
            .zip(&gens)
            .map(|((p, m), gen)| p.design.draw_residuals((m, 1.0), &levels, gen, &mut rng))
            .collect();
        let mut bias = Some([0.0; SLOW]);
        for (l, (out, (at, weight))) in draws.iter_mut().zip(levels.iter().zip(form)).enumerate() {
            // The AR model a part carries is only fit_levels' fallback: the drawing one.
            let again: Vec<SlowPart<'_>> = parts
                .iter()
                .zip(&drawn)
                .zip(models)
                .filter_map(|((p, g), ar)| {
                    g.get(l).map(|r| SlowPart {
                        design: p.design,
                        resid: r,
                        ar,
                    })
                })
                .collect();
            match fit_levels(&again, false) {
                Ok(Some((t, _))) => {
                    for (b, (est, level)) in
                        bias.iter_mut().flatten().zip(t.iter().zip([at.0, at.1]))
                    {
                        *b += weight * (est - level);
                    }
                    out.push(t.to_vec());
                }
                _ => bias = None,
            }
        }
        biases.extend(bias.map(|b| b.to_vec()));
    }
    let [c0, cf, cw, cb] = draws.map(|d| sample_covariance(&d, SLOW));
    let c = &c0 + (&cf - &c0) * sf + (&cw - &c0) * sw + (&cb - &cf - &cw + &c0) * (sf * sw);
    let at = |m: &DMatrix<f64>, i: usize, j: usize| m.get((i, j)).copied().unwrap_or(0.0);
    // The plug-in, negative levels drawn as zero: the form may lower a variance below it by
    // at most half (far below zero a level's line says nothing).
    let boundary = match (fq > 0.0, wq > 0.0) {
        (true, true) => &cb,
        (true, false) => &cf,
        (false, true) => &cw,
        (false, false) => &c0,
    };
    let var = |i: usize| at(&c, i, i).max(0.5 * at(boundary, i, i));
    let (v0, v1) = (var(0), var(1));
    let corr = {
        let r = at(&c, 0, 1) / (at(&c, 0, 0) * at(&c, 1, 1)).sqrt();
        if r.is_finite() && r.abs() < 1.0 && at(&c, 0, 0) > 0.0 && at(&c, 1, 1) > 0.0 {
            r
        } else {
            at(&c0, 0, 1) / (at(&c0, 0, 0) * at(&c0, 1, 1)).sqrt()
        }
    };
    let off = if corr.is_finite() {
        corr * (v0 * v1).sqrt()
    } else {
        0.0
    };
    // The correction's own sampling variance adds to the estimate's.
    let n = biases.len() as f64;
    let mean = sample_mean(&biases, SLOW);
    let cov = DMatrix::from_row_slice(2, 2, &[v0, off, off, v1])
        + sample_covariance(&biases, SLOW) / n.max(1.0);
    (
        cov,
        [
            mean.first().copied().unwrap_or(0.0),
            mean.get(1).copied().unwrap_or(0.0),
        ],
    )
}

/// The bootstrap's seed: a function of the channel and of every residual's bits, so that a
/// calibration is reproducible, yet two records never share their replicates. With one
/// seed per channel every record drew the same 40 replicates, and their sampling error
/// became a bias of that channel's stated u (docs/uncertainty.md, "Seeded by the data").
fn bootstrap_seed(parts: &[SlowPart<'_>], channel: u64) -> u64 {
    // splitmix64's finaliser over the bits: cheap, and stable across toolchains.
    let mix = |mut z: u64| {
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    };
    let bits = parts
        .iter()
        .flat_map(|p| p.resid.iter().map(|r| r.to_bits()));
    bits.fold(mix(SEED ^ channel), |h, b| mix(h ^ b))
}

/// The stacked statistics of the slow levels' fit and their expectation columns: per
/// group the rows m ≥ m₀; columns Q, q, then a/m (exact white) and b/m² per group.
struct LevelSystem {
    columns: Vec<Vec<f64>>,
    stats: Vec<f64>,
    ms: Vec<f64>,
}

impl LevelSystem {
    fn new(parts: &[SlowPart<'_>], stats: &[Vec<f64>], m0: &[usize]) -> Option<LevelSystem> {
        let groups = parts.len();
        let params = SLOW + 2 * groups;
        let mut columns = vec![Vec::new(); params];
        let (mut st, mut ms) = (Vec::new(), Vec::new());
        for (j, (p, s)) in parts.iter().zip(stats).enumerate() {
            let m_lo = m0.get(j).copied().unwrap_or(8);
            let f = p.design.octaves.iter().position(|o| o.m >= m_lo)?;
            for (r, o) in p.design.octaves.iter().enumerate().skip(f) {
                st.push(s.get(r).copied().unwrap_or(0.0));
                ms.push(o.m as f64);
                for (i, col) in columns.iter_mut().enumerate() {
                    let v = match i {
                        0 | 1 => p
                            .design
                            .expected_slow
                            .get(i)
                            .and_then(|c| c.get(r))
                            .copied(),
                        _ if i == SLOW + 2 * j => p.design.expected_white.get(r).copied(),
                        _ if i == SLOW + 2 * j + 1 => Some(1.0 / (o.m * o.m) as f64),
                        _ => Some(0.0),
                    };
                    col.push(v.unwrap_or(0.0));
                }
            }
        }
        // At least one more statistic than parameters.
        (st.len() > params).then_some(LevelSystem {
            columns,
            stats: st,
            ms,
        })
    }

    fn fit(&self) -> Option<Wls> {
        wls(&self.columns, &self.stats, &self.ms)
    }
}

/// The mean of bootstrap draws of `k` parameters (zeros without draws).
fn sample_mean(draws: &[Vec<f64>], k: usize) -> Vec<f64> {
    let n = draws.len().max(1) as f64;
    let mut mean = vec![0.0; k];
    for d in draws {
        for (m, v) in mean.iter_mut().zip(d) {
            *m += v / n;
        }
    }
    mean
}

/// The sample covariance of bootstrap draws of `k` parameters.
fn sample_covariance(draws: &[Vec<f64>], k: usize) -> DMatrix<f64> {
    let n = draws.len().max(2) as f64;
    let mean = sample_mean(draws, k);
    let mut cov = DMatrix::zeros(k, k);
    for d in draws {
        let c = DVector::from_iterator(k, d.iter().zip(&mean).map(|(v, m)| v - m));
        cov += &c * c.transpose() / (n - 1.0);
    }
    cov
}

/// A weighted least-squares fit of the statistics to the terms' expectations.
struct Wls {
    theta: Vec<f64>,
}

impl Wls {
    fn theta(&self, i: usize) -> f64 {
        self.theta.get(i).copied().unwrap_or(0.0)
    }
}

/// θ by weighted least squares, weights ∝ (N/m)/E_m² (the Allan variance's degrees of
/// freedom over its expected square; `ms` the m of each row), iterated on the fitted E.
fn wls(columns: &[Vec<f64>], stats: &[f64], ms: &[f64]) -> Option<Wls> {
    let rows = stats.len();
    let params = columns.len();
    let g = DMatrix::from_fn(rows, params, |r, c| {
        columns
            .get(c)
            .and_then(|col| col.get(r))
            .copied()
            .unwrap_or(0.0)
    });
    let mut fitted: Vec<f64> = stats.to_vec();
    let mut best = None;
    for _ in 0..4 {
        let mut gw = g.clone();
        for ((mut row, e), m) in gw.row_iter_mut().zip(&fitted).zip(ms) {
            let e = e.abs().max(1e-300);
            row /= m * e * e;
        }
        let map = gw.tr_mul(&g).try_inverse()? * gw.transpose();
        let theta = &map * DVector::from_column_slice(stats);
        fitted = (&g * &theta).iter().copied().collect();
        best = Some(Wls {
            theta: theta.iter().copied().collect(),
        });
    }
    best
}

/// The slow terms of one channel's noise: θ = (AR scale, flicker Q, walk q), output units²
/// for Q and q, with the covariance of their estimates.
#[derive(Clone, Debug, PartialEq)]
pub struct SlowFit {
    /// (θ₀, Q, q).
    pub theta: [f64; TERMS],
    /// Covariance of θ̂ (parametric bootstrap).
    pub cov: [[f64; TERMS]; TERMS],
}

impl SlowFit {
    /// The degrees of freedom of a variance V = Σ θ_i a_i: 2V²/(aᵀ Cov(θ̂) a).
    pub fn dof(&self, a: &[f64; TERMS]) -> f64 {
        let v: f64 = self.theta.iter().zip(a).map(|(t, x)| t * x).sum();
        let mut var = 0.0;
        for (row, ai) in self.cov.iter().zip(a) {
            for (c, aj) in row.iter().zip(a) {
                var += ai * c * aj;
            }
        }
        if var > 0.0 {
            2.0 * v * v / var
        } else {
            f64::INFINITY
        }
    }
}

#[cfg(test)]
pub(super) mod tests;
