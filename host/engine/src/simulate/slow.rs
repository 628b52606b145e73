//! Noise slower than any filter: flicker (1/f) and bias random walk (1/f²), the bias
//! instability and acceleration random walk of IEEE Std 952 / 1554 (docs/simulator.md).
//!
//! Both are functions of session time, not of the sample index: the bias keeps wandering
//! through the gaps between conditions and poses. Each is drawn once per run on a grid at
//! the sample rate that spans the whole session, and a sample at true time t takes the
//! grid's value at round(t·fs).
//!
//! - Flicker is Kasdin's discrete 1/f process y = (1 − B)^(−½)w, w iid N(0, Q). It is not
//!   stationary, but its increments u = (1 − B)^(½)w are: ARFIMA(0, −½, 0), with
//!   autocovariances γ(0) = 4Q/π, γ(j) = −4Q/(π(4j² − 1)) (Hosking 1981). They are drawn
//!   exactly by circulant embedding (Davies & Harte 1987), whose eigenvalues are all
//!   positive because every γ(j), j ≥ 1, is negative, and summed from y = 0 at the start
//!   of the session. Its Allan variance is 2 ln 2·Q/π at long τ: Q = π·σ_floor²/(2 ln 2).
//! - The random walk is the sum of iid N(0, K²/fs) steps from 0: σ_A(τ) = K·√(τ/3) at
//!   long τ.
//!
//! Both start from the nominal offset at t = 0. [`allan_variance`] gives the exact
//! expected Allan variance of the sum at every averaging length from the structure
//! function D(k) = E[(e_{t+k} − e_t)²], which every noise here has.

use crate::allan::powerlaw::{flicker_increments, flicker_structure};
use crate::allan::MICRO_G;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rotacal_shared::Channel;
use std::f64::consts::{LN_2, PI};

pub use crate::allan::powerlaw::allan_variance;

/// The slow noise of the three channels, in output units.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SlowNoise {
    /// Flicker: the innovation variance Q of Kasdin's process, output units², per channel.
    pub flicker_q: [f64; 3],
    /// Random walk: the variance of one step (K²/fs), output units², per channel.
    pub walk_step_var: [f64; 3],
}

/// The slow noise's random stream (ChaCha8 stream 2 of the seed; the main draws are stream
/// 0, the filter's burn-in stream 1), so that it shifts no other draw: a file without slow
/// noise keeps its bytes, and one with it differs only by the slow noise.
const SLOW_STREAM: u64 = 2;

impl SlowNoise {
    /// From an Allan-deviation floor (µg) and a random walk (µg/√s) per channel, for a
    /// channel whose sensitivity is `sensitivity` output units per m/s², at `fs` Hz.
    pub fn from_physical(
        floor_ug: [f64; 3],
        walk_ug_per_sqrt_s: [f64; 3],
        sensitivity: [f64; 3],
        fs: f64,
    ) -> SlowNoise {
        let mut n = SlowNoise::default();
        let levels = floor_ug.iter().zip(&walk_ug_per_sqrt_s).zip(&sensitivity);
        let terms = n.flicker_q.iter_mut().zip(&mut n.walk_step_var);
        for ((q, w), ((floor, walk), s)) in terms.zip(levels) {
            // µg of standard gravity (the unit's definition; not the local g).
            let out = |ug: f64| ug * MICRO_G * s;
            *q = PI * out(*floor).powi(2) / (2.0 * LN_2);
            *w = out(*walk).powi(2) / fs;
        }
        n
    }

    /// True when neither term is present.
    pub fn is_none(&self) -> bool {
        self.flicker_q
            .iter()
            .chain(&self.walk_step_var)
            .all(|v| *v == 0.0)
    }

    /// The structure function of channel `ch`'s slow noise at lag `k` samples,
    /// E[(e_{t+k} − e_t)²], output units²: flicker (4Q/π)·Σ_{j=1..k} 1/(2j − 1), random
    /// walk k·(K²/fs).
    pub fn structure(&self, ch: Channel, k: u64) -> f64 {
        let (q, w) = (ch.of(&self.flicker_q), ch.of(&self.walk_step_var));
        q * flicker_structure(k) + w * k as f64
    }

    /// The three channels' slow noise on a grid of `len` samples (grid point i at time
    /// i/fs), each starting at 0, drawn from stream [`SLOW_STREAM`] of `seed`.
    pub(super) fn draw(&self, len: usize, seed: u64) -> [Vec<f64>; 3] {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(SLOW_STREAM);
        let mut out = [Vec::new(), Vec::new(), Vec::new()];
        for (series, (q, w)) in out
            .iter_mut()
            .zip(self.flicker_q.iter().zip(&self.walk_step_var))
        {
            // Flicker's increments (unit Q, scaled), then the walk's steps, then the sum.
            let fl = if *q > 0.0 {
                flicker_increments(len.saturating_sub(1), &mut rng)
            } else {
                Vec::new()
            };
            let (sq, sw) = (q.sqrt(), w.sqrt());
            let mut level = 0.0;
            series.reserve(len);
            for i in 0..len {
                if i > 0 {
                    let u = fl.get(i - 1).copied().unwrap_or(0.0);
                    let step = if *w > 0.0 {
                        rng.sample::<f64, _>(StandardNormal)
                    } else {
                        0.0
                    };
                    level += sq * u + sw * step;
                }
                series.push(level);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn random_walk_and_flicker_match_their_closed_forms() {
        // Random walk: q(2m² + 1)/(6m); flicker: 2 ln 2·Q/π at long m, and at m = 1
        // D(1)/2 = 2Q/π, 1/ln 2 times that.
        let n = SlowNoise {
            flicker_q: [0.0, 1.0, 0.0],
            walk_step_var: [2.0, 0.0, 0.0],
        };
        for m in [1u64, 3, 10, 100] {
            let a = allan_variance(m, |k| n.structure(Channel::U, k));
            let want = 2.0 * (2.0 * (m * m) as f64 + 1.0) / (6.0 * m as f64);
            assert!((a - want).abs() < 1e-9 * want, "m = {m}: {a} vs {want}");
        }
        let plateau = 2.0 * LN_2 / PI;
        let long = allan_variance(4096, |k| n.structure(Channel::V, k));
        assert!((long / plateau - 1.0).abs() < 1e-5, "{}", long / plateau);
        let one = allan_variance(1, |k| n.structure(Channel::V, k));
        assert!((one / plateau - std::f64::consts::LOG2_E).abs() < 1e-12);
    }
}
