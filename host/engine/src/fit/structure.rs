//! Structure a fit of a rotation leaves in its residuals that is not noise, found without
//! a noise model fitted to those residuals (such a model would already have absorbed what
//! the tests look for): harmonics of the table angle above those the fit holds, up to the
//! sampling limit, and a step in the level. The discrepancy workflow scans its generic
//! fits with them before it estimates the noise (docs/discrepancy.md, "The verdict"), and
//! `calibrate` its widened noise fits (docs/uncertainty.md, "Structure beyond the noise").
//!
//! - A harmonic's periodogram ordinate is compared with the ordinates around it, which a
//!   smooth noise spectrum makes alike (F(2, 2M) under the null).
//! - A step's standardised CUSUM is scaled by a long-run variance from the median of
//!   blocks' autocovariances, which one step (confined to one block) cannot move.

use crate::fit::noise::NoiseModel;
use nalgebra::{DMatrix, DVector};
use rustfft::num_complex::Complex;
use rustfft::FftPlanner;
use statrs::distribution::{Continuous, ContinuousCDF, Normal};

/// Harmonics of the table angle the scanned fits hold (1 to 4): the discrepancy
/// workflow's generic fit and calibrate's widened noise fit alike.
pub const GENERIC_HARMONICS: usize = 4;

/// Fourier bins each side of a harmonic whose ordinates make its background.
const BACKGROUND_BINS: usize = 12;

/// The fraction of a group left out at each end of the step scan.
const STEP_MARGIN: f64 = 0.05;

/// One harmonic's test.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HarmonicTest {
    /// Which harmonic.
    pub k: usize,
    /// Its amplitude in the residuals, output units.
    pub amplitude: f64,
    /// Amplitude over its standard error under the background.
    pub z: f64,
    /// P(F(2, 2M) ≥ ratio): the chance of so large an ordinate from the background.
    pub p_single: f64,
}

/// The harmonics k > [`GENERIC_HARMONICS`] of `rate_hz` below the sampling limit in the
/// residuals `e` (rows `dt` apart; rows at a rail zero), each tested against its
/// background: the mean of the periodogram ordinates a whole number of Fourier bins away
/// (2 … [`BACKGROUND_BINS`] each side), none within 1.5 bins of a harmonic the generic fit
/// took out (their power is gone) or of the test's own frequency. Ordinates are read on
/// the grid of the record zero-padded to four times a length N ≥ n ([`Padded`]), a quarter
/// bin apart or finer.
pub fn harmonics(e: &[f64], dt: f64, rate_hz: f64) -> Vec<HarmonicTest> {
    let n = e.len();
    if n < 16 || !(dt > 0.0 && rate_hz > 0.0) {
        return Vec::new();
    }
    let padded = Padded::new(n);
    // Frequencies in Fourier bins of the record (1/(n·dt)).
    let bin_of = |hz: f64| hz * n as f64 * dt;
    let nyquist = n as f64 / 2.0;
    let removed: Vec<f64> = (0..=GENERIC_HARMONICS)
        .map(|k| bin_of(k as f64 * rate_hz))
        .collect();
    // Each harmonic's ordinate and its background's, as places on the padded grid.
    let mut plans = Vec::new();
    for k in GENERIC_HARMONICS + 1.. {
        let centre = bin_of(k as f64 * rate_hz);
        if centre > nyquist - 2.0 {
            break;
        }
        let Some(at) = padded.index(centre) else {
            break;
        };
        let mut background = Vec::new();
        for m in 2..=BACKGROUND_BINS {
            for side in [-1.0, 1.0] {
                let b = centre + side * m as f64;
                if b < 1.5 || b > nyquist || removed.iter().any(|r| (b - r).abs() < 1.5) {
                    continue;
                }
                background.extend(padded.index(b));
            }
        }
        plans.push((k, at, background));
    }
    let wanted = plans
        .iter()
        .flat_map(|(_, at, background)| std::iter::once(*at).chain(background.iter().copied()));
    let ordinates = padded.ordinates(e, wanted);
    let ordinate = |i: usize| ordinates.get(&i).copied().filter(|v| v.is_finite());
    let mut out = Vec::new();
    for (k, at, background) in plans {
        let Some(p) = ordinate(at) else { continue };
        let background: Vec<f64> = background.into_iter().filter_map(ordinate).collect();
        let m = background.len();
        if m < 4 {
            continue;
        }
        let level = background.iter().sum::<f64>() / m as f64;
        if level.is_nan() || level <= 0.0 {
            continue;
        }
        let ratio = p / level;
        out.push(HarmonicTest {
            k,
            amplitude: 2.0 * (p / n as f64).sqrt(),
            z: (2.0 * ratio).sqrt(),
            // F(2, 2M) survival: (1 + ratio/M)^(−M).
            p_single: (1.0 + ratio / m as f64).powf(-(m as f64)),
        });
    }
    out
}

/// A record of n rows zero-padded to 4N rows, N ≥ n the next length with no prime factor
/// above 5 (fast for the FFT). Its spectrum at index 4j + r is the N-point spectrum, at
/// bin j, of the record turned by e^(−2πi·r·t/4N): four FFTs of N points, one buffer of N
/// at a time, where one FFT of the padded record would hold four times as much (an hour
/// at 104 Hz: 6 MB, not 34 MB, with as much again for the FFT's scratch and twiddles).
struct Padded {
    n: usize,
    base: usize,
}

impl Padded {
    fn new(n: usize) -> Self {
        let smooth = |mut m: usize| {
            for f in [2, 3, 5] {
                while m % f == 0 {
                    m /= f;
                }
            }
            m == 1
        };
        let base = (n.max(1)..).find(|&m| smooth(m)).unwrap_or(n);
        Padded { n, base }
    }

    /// The padded grid's index nearest `bins` (Fourier bins of the record), if it lies in
    /// 0 … Nyquist.
    fn index(&self, bins: f64) -> Option<usize> {
        let len = 4 * self.base;
        let i = (bins * len as f64 / self.n as f64).round();
        (0.0..=len as f64 / 2.0).contains(&i).then_some(i as usize)
    }

    /// The periodogram ordinates |X|²/n of `e` at the padded indices `wanted`.
    fn ordinates(
        &self,
        e: &[f64],
        wanted: impl Iterator<Item = usize>,
    ) -> std::collections::BTreeMap<usize, f64> {
        let mut out: std::collections::BTreeMap<usize, f64> =
            wanted.map(|i| (i, f64::NAN)).collect();
        let len = 4 * self.base;
        let fft = FftPlanner::new().plan_fft_forward(self.base);
        let mut buf = vec![Complex::new(0.0, 0.0); self.base];
        for r in 0..4 {
            if !out.keys().any(|i| i % 4 == r) {
                continue;
            }
            for (t, (z, &v)) in buf.iter_mut().zip(e).enumerate() {
                // The angle reduced exactly first: r·t mod 4N.
                let turn = (r * t) % len;
                let (sin, cos) = (std::f64::consts::TAU * turn as f64 / len as f64).sin_cos();
                *z = Complex::new(v * cos, -v * sin);
            }
            for z in buf.iter_mut().skip(e.len()) {
                *z = Complex::new(0.0, 0.0);
            }
            fft.process(&mut buf);
            for (i, o) in out.iter_mut().filter(|(i, _)| *i % 4 == r) {
                if let Some(z) = buf.get(i / 4) {
                    *o = z.norm_sqr() / self.n as f64;
                }
            }
        }
        out
    }
}

/// A step's test in one group's channel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepTest {
    /// The first row after the step.
    pub row: usize,
    /// The step's height with the fit's regressors beside it (level after less level
    /// before), in the residuals' units.
    pub size: f64,
    /// The standardised CUSUM's largest size.
    pub z: f64,
    /// The chance that noise alone gives so large a maximum (Siegmund's approximation).
    pub p_single: f64,
    /// The scan's decorrelation Λ ([`scan_max_p`]).
    pub lambda: f64,
}

/// The long-run variance of the residuals (2π times their spectrum at zero) from blocks:
/// each block's autocovariances about its own mean, their median lag by lag, an AR model
/// of those (order by BIC) and its S(0), corrected once for what the blocks' means took
/// out (σ²_LR/L at every lag). A step moves one block's autocovariances, not the median.
fn long_run_variance(e: &[f64]) -> Option<f64> {
    let n = e.len();
    let blocks = (n / 128).clamp(1, 8);
    let len = n / blocks;
    let lags = crate::fit::noise::MAX_ORDER.min(len / 10);
    if len < 32 {
        return None;
    }
    let mut per_lag: Vec<Vec<f64>> = vec![Vec::with_capacity(blocks); lags + 1];
    for b in e.chunks_exact(len) {
        let mean = b.iter().sum::<f64>() / len as f64;
        let x: Vec<f64> = b.iter().map(|v| v - mean).collect();
        for (h, acc) in per_lag.iter_mut().enumerate() {
            let g = x
                .iter()
                .zip(x.iter().skip(h))
                .map(|(a, b)| a * b)
                .sum::<f64>();
            acc.push(g / len as f64);
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        let m = v.len();
        match (v.get((m - 1) / 2), v.get(m / 2)) {
            (Some(a), Some(b)) => (a + b) / 2.0,
            _ => 0.0,
        }
    };
    let gamma: Vec<f64> = per_lag.iter_mut().map(median).collect();
    let lrv = |gamma: &[f64]| -> Option<f64> {
        let m = NoiseModel::from_autocovariances(gamma, n, n).ok()?;
        let s0 = m.var * m.variance_factor(0.0);
        (s0.is_finite() && s0 > 0.0).then_some(s0)
    };
    let first = lrv(&gamma)?;
    let corrected: Vec<f64> = gamma.iter().map(|g| g + first / len as f64).collect();
    lrv(&corrected)
}

/// The most likely step in the residuals `e` of a least-squares fit whose regressors span
/// the orthonormal columns of `basis` (a constant among them), from 5 % to 95 % of the way
/// through. For a step from row t on, H_t, the fit's regressors take out what they can of
/// it: what is left, h̃_t = H_t − Q·Qᵀ·H_t, has eᵀh̃_t = Σ_{i≥t} e_i (the residuals are
/// orthogonal to Q) and ‖h̃_t‖² = (n − t) − ‖Σ_{i≥t} q_i‖². Its statistic is
/// eᵀh̃_t/(σ_LR·‖h̃_t‖): with only the constant in Q, the standardised CUSUM. A line or a
/// slow temperature beside it absorbs part of a step, and this asks only for what they
/// cannot.
pub fn step(e: &[f64], basis: &DMatrix<f64>) -> Option<StepTest> {
    if basis.nrows() != e.len() {
        return None;
    }
    step_by(e, basis.ncols(), |t, row| {
        for (x, b) in row.iter_mut().zip(basis.row(t).iter()) {
            *x = *b;
        }
    })
}

/// [`step`] with the orthonormal basis given row by row: `basis_row(t, row)` writes row t
/// (of `cols` values) into `row`, so that no rows × columns matrix need be held.
pub fn step_by(
    e: &[f64],
    cols: usize,
    mut basis_row: impl FnMut(usize, &mut DVector<f64>),
) -> Option<StepTest> {
    let n = e.len();
    let lrv = long_run_variance(e)?;
    let sd = lrv.sqrt();
    let nf = n as f64;
    let first = ((STEP_MARGIN * nf).ceil() as usize).max(1);
    let last = n.saturating_sub(first);
    let mut suffix = 0.0;
    let mut c = DVector::<f64>::zeros(cols);
    let mut row = DVector::<f64>::zeros(cols);
    let mut best: Option<(usize, f64, f64)> = None;
    // Λ = Σ (1 − corr(z_t, z_{t+1})) over the scan: the statistic's decorrelation, which
    // sets how many near-independent chances the maximum had (for the bridge, ½·ln of the
    // span's odds ratio).
    let mut lambda = 0.0;
    let mut previous: Option<(DVector<f64>, f64)> = None;
    for t in (first..n).rev() {
        suffix += e.get(t).copied().unwrap_or(0.0);
        basis_row(t, &mut row);
        c += &row;
        if t < last {
            let left = (n - t) as f64 - c.norm_squared();
            if left > 1e-9 * nf {
                if let Some((cp, left_p)) = &previous {
                    // h̃_t·h̃_{t+1} = (n − t − 1) − c_t·c_{t+1}.
                    let dot = (n - t - 1) as f64 - c.dot(cp);
                    lambda += (1.0 - dot / (left * left_p).sqrt()).max(0.0);
                }
                let z = suffix / (sd * left.sqrt());
                if best.is_none_or(|(_, bz, _)| z.abs() > bz.abs()) {
                    // The step's height beside the fit's regressors (Frisch–Waugh):
                    // eᵀh̃_t/‖h̃_t‖².
                    best = Some((t, z, suffix / left));
                }
                previous = Some((c.clone(), left));
            }
        }
    }
    let (row, z, size) = best?;
    Some(StepTest {
        row,
        size,
        z: z.abs(),
        p_single: scan_max_p(z.abs(), lambda),
        lambda,
    })
}

/// P(max |z_t| > c) for a standardised Gaussian scan whose neighbours decorrelate by
/// Λ in all (Siegmund's approximation, both sides; for the standardised Brownian bridge
/// over [t₀, t₁], Λ = ½·ln(t₁(1 − t₀)/(t₀(1 − t₁)))).
pub fn scan_max_p(c: f64, lambda: f64) -> f64 {
    let phi = Normal::standard().pdf(c);
    small_c_guard(c, 2.0 * (phi * (c - 1.0 / c) * lambda + 4.0 * phi / c))
}

/// The approximations hold for large maxima; below c = 1.5 (where c − 1/c turns negative
/// and the formula would fall to zero) the chance is 1, and never below a single normal
/// deviate's two-sided tail, which the maximum exceeds.
fn small_c_guard(c: f64, approx: f64) -> f64 {
    if c.is_nan() || c < 1.5 {
        return 1.0;
    }
    let single = 2.0 * Normal::standard().sf(c);
    approx.max(single).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    /// The constant's column, normalised.
    fn constant(n: usize) -> DMatrix<f64> {
        DMatrix::from_element(n, 1, 1.0 / (n as f64).sqrt())
    }

    /// An orthonormal basis of 1, a line and a sine of period `period` rows.
    fn smooth(n: usize, period: f64) -> DMatrix<f64> {
        let x = DMatrix::from_fn(n, 3, |i, j| match j {
            0 => 1.0,
            1 => i as f64 / n as f64,
            _ => (std::f64::consts::TAU * i as f64 / period).sin(),
        });
        x.qr().q()
    }

    /// Residuals of `y` on the orthonormal `q`.
    fn residuals(y: &[f64], q: &DMatrix<f64>) -> Vec<f64> {
        let yv = DVector::from_column_slice(y);
        let e = &yv - q * (q.transpose() * &yv);
        e.iter().copied().collect()
    }

    fn ar1(n: usize, rho: f64, seed: u64) -> Vec<f64> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut x = 0.0;
        let scale = (1.0 - rho * rho).sqrt();
        (0..n)
            .map(|_| {
                let e: f64 = StandardNormal.sample(&mut rng);
                x = rho * x + scale * e;
                x
            })
            .collect()
    }

    /// A 5th harmonic of 0.6 units in AR(1) noise of sd 1 is found with its amplitude;
    /// the same noise without it gives no ordinate beyond what 1e-3 over the tests allows.
    #[test]
    fn a_high_harmonic_is_found_and_noise_passes() {
        let (n, dt, f) = (4200, 1.0 / 16.0, 0.01);
        let (mut false_alarms, mut at_5_percent, mut tests_made) = (0, 0, 0);
        for seed in 0..40 {
            let noise = ar1(n, 0.6, seed);
            let tests = harmonics(&noise, dt, f);
            let count = tests.len() as f64;
            false_alarms += tests.iter().filter(|t| t.p_single * count < 1e-3).count();
            at_5_percent += tests.iter().filter(|t| t.p_single < 0.05).count();
            tests_made += tests.len();
            let with: Vec<f64> = noise
                .iter()
                .enumerate()
                .map(|(i, v)| {
                    v + 0.6 * (5.0 * std::f64::consts::TAU * f * i as f64 * dt + 0.3).sin()
                })
                .collect();
            let tests = harmonics(&with, dt, f);
            let count = tests.len() as f64;
            let five = tests.iter().find(|t| t.k == 5);
            assert!(
                five.is_some_and(|t| t.p_single * count < 1e-3 && (t.amplitude - 0.6).abs() < 0.25),
                "seed {seed}: {five:?}"
            );
        }
        // 40 records of ~790 tests at 1e-3 over all: more than 2 is p < 1e-3.
        assert!(false_alarms <= 2, "{false_alarms} false alarms");
        // Each test holds its size, both ways: the share below 0.05 within 4 binomial
        // sd of it (each record's tests share backgrounds, so doubled).
        let share = at_5_percent as f64 / tests_made as f64;
        let sd = (0.05 * 0.95 / tests_made as f64).sqrt();
        assert!(
            (share - 0.05).abs() < 8.0 * sd,
            "{share} of {tests_made} tests below 0.05"
        );
    }

    /// A step of 1.5 sd in AR(1) ρ = 0.5 noise is found near its place with its size; the
    /// noise alone is not taken for a step more often than the approximation allows.
    #[test]
    fn a_step_is_found_and_noise_passes() {
        let n = 4200;
        let mut alarms = 0;
        for seed in 0..1000 {
            let noise = ar1(n, 0.5, 100 + seed);
            let mean = noise.iter().sum::<f64>() / n as f64;
            let centred: Vec<f64> = noise.iter().map(|v| v - mean).collect();
            if step(&centred, &constant(n)).is_some_and(|s| s.p_single < 0.05) {
                alarms += 1;
            }
            if seed < 20 {
                let mut with: Vec<f64> = noise
                    .iter()
                    .enumerate()
                    .map(|(i, v)| v + if i >= 1500 { 1.5 } else { 0.0 })
                    .collect();
                let m = with.iter().sum::<f64>() / n as f64;
                with.iter_mut().for_each(|v| *v -= m);
                let s = step(&with, &constant(n));
                assert!(
                    s.is_some_and(|s| s.p_single < 1e-6
                        && s.row.abs_diff(1500) < 60
                        && (s.size - 1.5).abs() < 0.3),
                    "seed {seed}: {s:?}"
                );
            }
        }
        // P(max > c) = 0.05 per record if the approximation holds: binomial(1000, 0.05)
        // lies within 29 … 73 with probability above 0.999 (both ways: an overstated
        // long-run variance would hide steps as surely as an understated one invents them).
        assert!((29..=73).contains(&alarms), "{alarms} of 1000");
    }

    /// With a line and a slow sine fitted beside it (as the generic fit's line and a
    /// temperature swing are), a step of 1.5 sd at 30 % is still found near its place, and
    /// noise alone holds the test's size both ways.
    #[test]
    fn a_step_beside_a_line_and_a_slow_swing() {
        let n = 4200;
        let q = smooth(n, 9600.0);
        let mut alarms = 0;
        for seed in 0..1000 {
            let noise = ar1(n, 0.5, 5000 + seed);
            if step(&residuals(&noise, &q), &q).is_some_and(|s| s.p_single < 0.05) {
                alarms += 1;
            }
            if seed < 20 {
                let with: Vec<f64> = noise
                    .iter()
                    .enumerate()
                    .map(|(i, v)| v + if i >= 1260 { 1.5 } else { 0.0 })
                    .collect();
                let s = step(&residuals(&with, &q), &q);
                assert!(
                    s.is_some_and(|s| s.p_single < 1e-6 && s.row.abs_diff(1260) < 60),
                    "seed {seed}: {s:?}"
                );
            }
        }
        // Binomial(1000, 0.05) within 29 … 73 with probability above 0.999.
        assert!((29..=73).contains(&alarms), "{alarms} of 1000");
    }
}
