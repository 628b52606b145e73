//! The sensor noise: the process `[sensor.noise]` describes (white, AR or low-passed),
//! checked stationary, with its autocorrelation and spectrum, and the three channels'
//! generator that draws it during a run.

use super::{ConfigError, Noise, SlowNoise};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use std::f64::consts::{PI, SQRT_2, TAU};

/// The shape of the sensor noise, common to the three channels (docs/simulator.md): unit
/// white innovations w through the filter y_t = Σ_{i=0..q} b_i·w_{t−i} − Σ_{i=1..p} a_i·y_{t−i},
/// scaled per channel to its marginal standard deviation.
#[derive(Clone, Debug, PartialEq)]
pub struct NoiseProcess {
    /// b_0 … b_q.
    b: Vec<f64>,
    /// a_1 … a_p.
    a: Vec<f64>,
    /// Autocovariance per unit innovation variance at lags 0 ..= max(p, q).
    acov: Vec<f64>,
    /// The largest pole modulus.
    radius: f64,
    /// Innovations run before the first sample so that it starts stationary.
    burn_in: u64,
}

/// Why a noise filter cannot be simulated (the key is named by [`ConfigError::NoiseFilter`]).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum FilterError {
    /// A pole on or outside the unit circle, of this modulus.
    #[error("not stationary: its largest pole has modulus {radius:.6} (it must be below 1)")]
    NotStationary {
        /// The largest pole modulus.
        radius: f64,
    },
    /// Not stationary, and the poles' moduli could not be computed.
    #[error("not stationary: a pole lies on or outside the unit circle")]
    NotStationaryUnknownRadius,
    /// Stationary, but the poles' moduli could not be computed.
    #[error("its poles could not be computed")]
    NoPoles,
    /// A pole so near the unit circle that the burn-in would exceed [`MAX_NOISE_BURN_IN`].
    #[error(
        "its memory is too long: the largest pole has modulus {radius:.9}, which needs more \
         than {} samples to decay below {:e}",
        MAX_NOISE_BURN_IN,
        BURN_IN_DECAY
    )]
    MemoryTooLong {
        /// The largest pole modulus.
        radius: f64,
    },
}

/// The longest burn-in allowed, samples: a longer memory is refused.
pub const MAX_NOISE_BURN_IN: u64 = 1_000_000;

/// What the slowest pole must decay below during the burn-in.
const BURN_IN_DECAY: f64 = 1e-12;

impl NoiseProcess {
    /// White noise.
    pub fn white() -> NoiseProcess {
        NoiseProcess {
            b: vec![1.0],
            a: Vec::new(),
            acov: vec![1.0],
            radius: 0.0,
            burn_in: 0,
        }
    }

    /// The process `[sensor.noise]` describes at sample rate `fs` (Hz); errors name the key.
    pub fn new(noise: &Noise, fs: f64) -> Result<NoiseProcess, ConfigError> {
        let (key, b, a) = match (&noise.ar, noise.lowpass_hz) {
            (Some(_), Some(_)) => {
                return Err(ConfigError::Invalid {
                    key: "sensor.noise.ar and sensor.noise.lowpass_hz",
                    why: "give one, not both",
                })
            }
            (None, None) => return Ok(NoiseProcess::white()),
            (Some(phi), None) => {
                if phi.is_empty() {
                    return Err(ConfigError::Invalid {
                        key: "sensor.noise.ar",
                        why: "give at least one coefficient (leave ar out for white noise)",
                    });
                }
                if phi.iter().any(|x| !x.is_finite()) {
                    return Err(ConfigError::NotFinite {
                        key: "sensor.noise.ar",
                    });
                }
                ("ar", vec![1.0], phi.iter().map(|x| -x).collect())
            }
            (None, Some(fc)) => {
                if !(fc.is_finite() && fc > 0.0 && fc < fs / 2.0) {
                    return Err(ConfigError::Lowpass {
                        nyquist_hz: fs / 2.0,
                    });
                }
                let (b, a) = butterworth(fc, fs);
                ("lowpass_hz", b, a)
            }
        };
        NoiseProcess::from_filter(b, a).map_err(|cause| ConfigError::NoiseFilter { key, cause })
    }

    /// Check stationarity and memory, and compute the autocovariances.
    fn from_filter(b: Vec<f64>, a: Vec<f64>) -> Result<NoiseProcess, FilterError> {
        let radius = pole_radius(&a);
        if !reflection_stable(&a) {
            return Err(match radius {
                Some(radius) => FilterError::NotStationary { radius },
                None => FilterError::NotStationaryUnknownRadius,
            });
        }
        let radius = radius.ok_or(FilterError::NoPoles)?;
        let burn_in = if radius == 0.0 {
            0.0
        } else {
            (BURN_IN_DECAY.ln() / radius.ln()).ceil()
        };
        if !(radius < 1.0 && burn_in <= MAX_NOISE_BURN_IN as f64) {
            return Err(FilterError::MemoryTooLong { radius });
        }
        let burn_in = burn_in as u64;
        let lags = a.len().max(b.len().saturating_sub(1));
        let mut p = NoiseProcess {
            b,
            a,
            acov: vec![0.0; lags + 1],
            radius,
            burn_in,
        };
        // The impulse response beyond 2·burn-in has decayed as radius^k < 1e-24: summed
        // up to there, the autocovariances are exact to rounding.
        let terms = (2 * burn_in).max(lags as u64 + 1).max(p.b.len() as u64);
        let mut state = p.state();
        let mut recent = vec![0.0; lags + 1];
        let mut acov = vec![0.0; lags + 1];
        for k in 0..terms {
            let h = p.step(&mut state, if k == 0 { 1.0 } else { 0.0 });
            push_front(&mut recent, h);
            for (g, r) in acov.iter_mut().zip(&recent) {
                *g += h * r;
            }
        }
        p.acov = acov;
        Ok(p)
    }

    /// True for white noise (no filter).
    pub fn is_white(&self) -> bool {
        self.a.is_empty() && self.b == [1.0]
    }

    /// Feed-forward coefficients b_0 … b_q.
    pub fn feedforward(&self) -> &[f64] {
        &self.b
    }

    /// Feedback coefficients a_1 … a_p (for AR, a_i = −φ_i).
    pub fn feedback(&self) -> &[f64] {
        &self.a
    }

    /// The largest modulus of the filter's poles (0 for white noise).
    pub fn pole_radius(&self) -> f64 {
        self.radius
    }

    /// Innovations each channel runs before the file's first sample.
    pub fn burn_in(&self) -> u64 {
        self.burn_in
    }

    /// The stationary variance of y per unit innovation variance: Σ h_k².
    pub fn variance_per_innovation(&self) -> f64 {
        self.acov.first().copied().unwrap_or(1.0)
    }

    /// The autocorrelation at `lag` samples.
    pub fn autocorrelation(&self, lag: u64) -> f64 {
        let v = self.variance_per_innovation();
        if let Some(g) = usize::try_from(lag).ok().and_then(|l| self.acov.get(l)) {
            return g / v;
        }
        // Beyond max(p, q) the autocovariance follows the feedback recursion; past twice
        // the burn-in it is below 1e-24 and taken as 0.
        if lag >= 2 * self.burn_in {
            return 0.0;
        }
        let mut g = self.acov.clone();
        g.reverse(); // newest first: γ_{k−1}, γ_{k−2}, …
        for _ in self.acov.len() as u64..=lag {
            let next = -self.a.iter().zip(&g).map(|(a, x)| a * x).sum::<f64>();
            push_front(&mut g, next);
        }
        g.first().map_or(0.0, |x| x / v)
    }

    /// The spectral density at `nu` cycles per sample, normalised so that it integrates
    /// to 1 over −½ … ½: |H(e^{2πiν})|² / Σ h_k². A channel's two-sided density is
    /// sd²·shape(f/fs)/fs.
    pub fn spectral_shape(&self, nu: f64) -> f64 {
        let theta = TAU * nu;
        let gain = |c: &mut dyn Iterator<Item = (usize, f64)>| {
            let (re, im) = c.fold((0.0, 0.0), |(re, im), (i, x)| {
                let (s, co) = (theta * i as f64).sin_cos();
                (re + x * co, im - x * s)
            });
            re * re + im * im
        };
        let num = gain(&mut self.b.iter().copied().enumerate());
        let den = gain(
            &mut std::iter::once(1.0)
                .chain(self.a.iter().copied())
                .enumerate(),
        );
        num / den / self.variance_per_innovation()
    }

    /// Σ_k ρ_k over all lags (−∞ … ∞): the variance of a long mean is sd²·this/n.
    pub fn long_run_factor(&self) -> f64 {
        self.spectral_shape(0.0)
    }

    fn state(&self) -> FilterState {
        FilterState {
            w: vec![0.0; self.b.len()],
            y: vec![0.0; self.a.len()],
        }
    }

    /// One step of the filter: innovation in, y out.
    fn step(&self, st: &mut FilterState, w: f64) -> f64 {
        push_front(&mut st.w, w);
        let ff: f64 = self.b.iter().zip(&st.w).map(|(b, w)| b * w).sum();
        let fb: f64 = self.a.iter().zip(&st.y).map(|(a, y)| a * y).sum();
        let y = ff - fb;
        push_front(&mut st.y, y);
        y
    }
}

/// A filter's memory: recent innovations and outputs, newest first.
#[derive(Clone, Debug)]
struct FilterState {
    w: Vec<f64>,
    y: Vec<f64>,
}

fn push_front(hist: &mut [f64], x: f64) {
    if !hist.is_empty() {
        hist.rotate_right(1);
    }
    if let Some(first) = hist.first_mut() {
        *first = x;
    }
}

/// The 2nd-order digital Butterworth low-pass (bilinear transform, cutoff pre-warped):
/// (b, a) with a_0 = 1 left out.
fn butterworth(fc: f64, fs: f64) -> (Vec<f64>, Vec<f64>) {
    let k = (PI * fc / fs).tan();
    let d = 1.0 + SQRT_2 * k + k * k;
    let b0 = k * k / d;
    (
        vec![b0, 2.0 * b0, b0],
        vec![2.0 * (k * k - 1.0) / d, (1.0 - SQRT_2 * k + k * k) / d],
    )
}

/// Whether 1 + a_1·z⁻¹ + … + a_p·z⁻ᵖ has all its roots inside the unit circle, by the
/// step-down (Schur–Cohn) recursion: every reflection coefficient below 1 in size. Exact
/// at the boundary, where computed roots are not.
fn reflection_stable(a: &[f64]) -> bool {
    let mut c = a.to_vec();
    while let Some(&k) = c.last() {
        if k.is_nan() || k.abs() >= 1.0 {
            return false;
        }
        let m = c.len() - 1;
        let d = 1.0 - k * k;
        c = c
            .iter()
            .zip(c.iter().rev().skip(1))
            .take(m)
            .map(|(x, y)| (x - k * y) / d)
            .collect();
    }
    true
}

/// The largest modulus of the roots of z^p + a_1·z^{p−1} + … + a_p (the companion matrix's
/// eigenvalues); None if they do not converge.
fn pole_radius(a: &[f64]) -> Option<f64> {
    let p = a.len();
    if p == 0 {
        return Some(0.0);
    }
    // −a on the first row, ones below the diagonal.
    let mut companion = nalgebra::DMatrix::from_fn(p, p, |i, j| if i == j + 1 { 1.0 } else { 0.0 });
    for (m, v) in companion.row_mut(0).iter_mut().zip(a) {
        *m = -v;
    }
    let schur = nalgebra::linalg::Schur::try_new(companion, f64::EPSILON, 10_000 * p)?;
    Some(
        schur
            .complex_eigenvalues()
            .iter()
            .map(|z| z.norm())
            .fold(0.0, f64::max),
    )
}

/// The three channels' noise generators during a run.
pub(super) struct NoiseGen<'a> {
    process: &'a NoiseProcess,
    sd: [f64; 3],
    /// sd / √(Σ h_k²): the innovation level giving each channel its marginal sd.
    scale: [f64; 3],
    state: [FilterState; 3],
    /// The slow noise (flicker, random walk) on a grid at `fs` over the session (empty
    /// without it).
    slow: [Vec<f64>; 3],
    fs: f64,
    /// The seed, and the dwell stream once a static dwell has used it.
    seed: u64,
    dwell: Option<ChaCha8Rng>,
}

/// The noise burn-in's random stream (ChaCha8 stream 1 of the seed; the main draws are
/// stream 0), so that it shifts no other draw.
const NOISE_STREAM: u64 = 1;

/// The innovations of the time between a static angle's readings and the next angle's
/// (stream 3; stream 2 is the slow noise's).
const DWELL_STREAM: u64 = 3;

impl<'a> NoiseGen<'a> {
    /// Start each channel in its stationary distribution: from rest, u then v then w run
    /// `burn_in` innovations of their own stream.
    pub(super) fn new(process: &'a NoiseProcess, sd: [f64; 3], seed: u64) -> NoiseGen<'a> {
        let v = process.variance_per_innovation();
        let mut state = [process.state(), process.state(), process.state()];
        if !process.is_white() {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            rng.set_stream(NOISE_STREAM);
            for st in &mut state {
                for _ in 0..process.burn_in {
                    process.step(st, rng.sample(StandardNormal));
                }
            }
        }
        NoiseGen {
            process,
            sd,
            scale: sd.map(|s| s / v.sqrt()),
            state,
            slow: [Vec::new(), Vec::new(), Vec::new()],
            fs: 1.0,
            seed,
            dwell: None,
        }
    }

    /// Let `steps` samples' time pass unread (a static table moving to its next angle):
    /// each channel's filter runs on, u then v then w, with innovations from the dwell
    /// stream, so that the next angle's readings are as correlated with these as that
    /// time allows. White noise has no memory: nothing is drawn.
    pub(super) fn idle(&mut self, steps: u64) {
        if self.process.is_white() || steps == 0 {
            return;
        }
        let rng = self.dwell.get_or_insert_with(|| {
            let mut r = ChaCha8Rng::seed_from_u64(self.seed);
            r.set_stream(DWELL_STREAM);
            r
        });
        for st in &mut self.state {
            for _ in 0..steps {
                self.process.step(st, rng.sample(StandardNormal));
            }
        }
    }

    /// With slow noise `slow`, drawn on a grid at `fs` Hz of `len` points.
    pub(super) fn with_slow(mut self, slow: &SlowNoise, len: usize, fs: f64, seed: u64) -> Self {
        if !slow.is_none() {
            self.slow = slow.draw(len, seed);
            self.fs = fs;
        }
        self
    }

    /// The slow noise on u, v, w at true session time `t` (s): the grid point nearest t
    /// (zero without slow noise).
    pub(super) fn slow_at(&self, t: f64) -> [f64; 3] {
        let i = (t * self.fs).round().max(0.0) as usize;
        let [u, v, w] = &self.slow;
        [u, v, w].map(|series| series.get(i).or(series.last()).copied().unwrap_or(0.0))
    }

    /// One sample's noise on u, v, w: one standard normal per channel from `rng`, in that
    /// order (where white noise has always been drawn, so white files keep their bytes).
    pub(super) fn draw(&mut self, rng: &mut ChaCha8Rng) -> [f64; 3] {
        let mut e = [0.0; 3];
        let white = self.process.is_white();
        let channels = self.sd.iter().zip(&self.scale).zip(&mut self.state);
        for (ej, ((sd, scale), st)) in e.iter_mut().zip(channels) {
            let n: f64 = rng.sample(StandardNormal);
            *ej = if white {
                sd * n
            } else {
                scale * self.process.step(st, n)
            };
        }
        e
    }
}
