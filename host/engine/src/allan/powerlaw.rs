//! Power-law noise of an accelerometer's bias (IEEE Std 952 / 1554): white, flicker (1/f)
//! and random walk (1/f²). Their structure functions D(k) = E[(e_{t+k} − e_t)²], the exact
//! expected Allan variance of any noise with stationary increments from its D, and an exact
//! generator of flicker (docs/simulator.md, docs/allan.md). The simulator draws from here,
//! and the terms fit of [`super::fit_terms`] uses both.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};
use statrs::function::gamma::digamma;
use std::f64::consts::{LN_2, PI};
use std::sync::Arc;

/// The Allan variance of unit-Q Kasdin flicker at long averaging times, 2 ln 2/π: a
/// flicker level Q has the Allan-deviation floor √(Q·2 ln 2/π).
pub const FLICKER_ALLAN_PLATEAU: f64 = 2.0 * LN_2 / PI;

/// The structure function of unit-Q Kasdin flicker at lag `k`: (4/π)·Σ_{j=1..k} 1/(2j − 1),
/// summed up to k = 64 and beyond by Σ = (ψ(k + ½) − ψ(½))/2 (ψ the digamma function,
/// ψ(½) = −γ − 2 ln 2), so that an Allan variance at factor m costs O(m).
pub fn flicker_structure(k: u64) -> f64 {
    const DIRECT: u64 = 64;
    let odd_harmonic = if k <= DIRECT {
        (1..=k).map(|j| 1.0 / (2 * j - 1) as f64).sum::<f64>()
    } else {
        let psi_half = -EULER_GAMMA - 2.0 * LN_2;
        (digamma(k as f64 + 0.5) - psi_half) / 2.0
    };
    4.0 / PI * odd_harmonic
}

/// The Euler–Mascheroni constant γ.
const EULER_GAMMA: f64 = 0.577_215_664_901_532_9;

/// `n` stationary increments of unit-Q flicker (ARFIMA(0, −½, 0)) by circulant embedding:
/// the autocovariances up to lag M ≥ n wrapped into a circle of 2M, its eigenvalues λ by
/// one FFT, then the real part of FFT(√(λ/2M)·(Z₁ + iZ₂)).
pub fn flicker_increments(n: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
    FlickerIncrements::new(n).draw(rng)
}

/// The circulant embedding of [`flicker_increments`] for `n` increments, made once for
/// many draws (the eigenvalues' FFT is half the work of a draw).
pub struct FlickerIncrements {
    n: usize,
    /// √(λ_k/2M).
    amplitude: Vec<f64>,
    fft: Arc<dyn Fft<f64>>,
}

impl FlickerIncrements {
    /// The embedding for `n` increments.
    pub fn new(n: usize) -> Self {
        let m = n.max(1).next_power_of_two();
        let size = 2 * m;
        let gamma = |j: usize| {
            let j = j as f64;
            if j == 0.0 {
                4.0 / PI
            } else {
                -4.0 / (PI * (4.0 * j * j - 1.0))
            }
        };
        let mut c: Vec<Complex<f64>> = (0..size)
            .map(|i| Complex::new(gamma(if i <= m { i } else { size - i }), 0.0))
            .collect();
        let fft = FftPlanner::new().plan_fft_forward(size);
        fft.process(&mut c);
        // The eigenvalues are positive in exact arithmetic (the smallest, at frequency 0,
        // is (4/π)/(2M + 1) − γ(M) > 0); round-off may leave them a few ulps below zero.
        let scale = 1.0 / size as f64;
        let amplitude = c.iter().map(|l| (l.re.max(0.0) * scale).sqrt()).collect();
        FlickerIncrements { n, amplitude, fft }
    }

    /// One draw of the `n` increments: two normals per eigenvalue from `rng`.
    pub fn draw(&self, rng: &mut ChaCha8Rng) -> Vec<f64> {
        if self.n == 0 {
            return Vec::new();
        }
        let mut x: Vec<Complex<f64>> = self
            .amplitude
            .iter()
            .map(|a| {
                Complex::new(
                    a * rng.sample::<f64, _>(StandardNormal),
                    a * rng.sample::<f64, _>(StandardNormal),
                )
            })
            .collect();
        self.fft.process(&mut x);
        x.iter().take(self.n).map(|z| z.re).collect()
    }
}

/// The expected Allan variance at averaging length `m` samples of a noise with structure
/// function `d` (d(k) = E[(e_{t+k} − e_t)²]): −1/(2m²)·Σ_{k=1}^{2m−1} r(k)·d(k), r the
/// autocorrelation of the Allan weights (−1 × m, +1 × m), r(k) = 2m − 3k up to k = m and
/// k − 2m beyond. Exact for any noise with stationary increments: white, AR, flicker and
/// random walk alike (for white noise of variance σ², σ²/m).
pub fn allan_variance(m: u64, d: impl Fn(u64) -> f64) -> f64 {
    if m == 0 {
        return f64::NAN;
    }
    let mf = m as f64;
    let sum: f64 = (1..2 * m)
        .map(|k| {
            let r = if k <= m {
                2.0 * mf - 3.0 * k as f64
            } else {
                k as f64 - 2.0 * mf
            };
            r * d(k)
        })
        .sum();
    -sum / (2.0 * mf * mf)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn the_digamma_form_continues_the_direct_sum() {
        let direct = |k: u64| 4.0 / PI * (1..=k).map(|j| 1.0 / (2 * j - 1) as f64).sum::<f64>();
        for k in [65u64, 100, 1000, 100_000] {
            let (a, b) = (flicker_structure(k), direct(k));
            assert!((a / b - 1.0).abs() < 1e-13, "k = {k}: {a} vs {b}");
        }
    }

    #[test]
    fn white_noise_gives_sigma_squared_over_m() {
        for m in [1, 2, 7, 64] {
            let a = allan_variance(m, |_| 2.0 * 3.0);
            assert!((a - 3.0 / m as f64).abs() < 1e-12 * 3.0, "m = {m}: {a}");
        }
    }

    #[test]
    fn flicker_increments_have_the_arfima_autocovariances() {
        // 64 draws of 4096 increments: the sample lag-0 and lag-1 autocovariances against
        // 4/π and −4/(3π), within 5 standard errors of their Monte Carlo mean.
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (mut g0, mut g1) = (Vec::new(), Vec::new());
        for _ in 0..64 {
            let u = flicker_increments(4096, &mut rng);
            let n = u.len() as f64;
            g0.push(u.iter().map(|x| x * x).sum::<f64>() / n);
            g1.push(
                u.iter()
                    .zip(u.iter().skip(1))
                    .map(|(a, b)| a * b)
                    .sum::<f64>()
                    / (n - 1.0),
            );
        }
        for (vals, want) in [(g0, 4.0 / PI), (g1, -4.0 / (3.0 * PI))] {
            let k = vals.len() as f64;
            let mean = vals.iter().sum::<f64>() / k;
            let sd = (vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (k - 1.0)).sqrt();
            assert!(
                (mean - want).abs() < 5.0 * sd / k.sqrt(),
                "{mean} vs {want} (se {})",
                sd / k.sqrt()
            );
        }
    }
}
