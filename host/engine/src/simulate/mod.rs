//! `rotacal simulate`: a forward model of the rotation-table experiment that writes
//! recordings in the format `calibrate` reads (formats.md).
//!
//! It is the ground truth for the tests, the demo and the discrepancy workflow, so its
//! physics is written out once, here, and in docs/simulator.md. For every sample:
//!
//! 1. true time t (session seconds) on the sensor's own schedule, 1/fs apart;
//! 2. table angle α(t) (rate, rate error, rate ripple; per channel at t + τ_j for skew);
//! 3. specific force in the platter frame, f = g·ĝ(α) − ω²·r·d̂ (method.md §1 for ĝ);
//! 4. along each sensitive axis a_j = Ŝ_j·f, output s_j·(a_j + K2·a_j² + K3·a_j³) + O_j
//!    + drift + temperature term, with S the device's matrix turned by the mounting;
//! 5. plus sensor noise (white, or per `[sensor.noise]` an autoregressive or low-passed
//!    process per channel), then saturation rails, quantisation and the register range;
//! 6. the timestamp the device would write: (1 + ε)·t plus jitter, in whole ticks.
//!
//! Seeded (ChaCha8), so the same configuration and seed give the same file.

pub mod config;
pub mod device;
pub mod emulated;
pub mod geometry;

pub use config::{Config, ConfigError, Noise, NoiseSd, StepError, PRESETS};

use crate::recording::{self, Columns, Metadata, Method, Recording, RecordingError, Row, Writer};
use crate::simulate::geometry::sensitivity_from_intrinsic;
use crate::simulate::geometry::{mounted, rotation};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rotacal_shared::{Channel, Condition};
use std::f64::consts::{PI, SQRT_2, TAU};
use std::io::{self, Write};
use std::path::Path;

/// What the simulated device truly is.
#[derive(Clone, Debug, PartialEq)]
pub struct Truth {
    /// s_u, s_v, s_w, output units per m/s².
    pub sensitivity: [f64; 3],
    /// φ_uv, φ_vw, φ_wu, degrees.
    pub angles_deg: [f64; 3],
    /// O_u, O_v, O_w, output units.
    pub offsets: [f64; 3],
    /// S in the device's own frame.
    pub matrix_device: [[f64; 3]; 3],
    /// S as the platter sees it (after the mounting rotation): what the static method
    /// estimates.
    pub matrix_platter: [[f64; 3]; 3],
    /// The noise level, output units (before quantisation): the marginal standard
    /// deviation shared by the channels, or the root mean square of the three when they
    /// differ (`noise_sd` has each).
    pub noise_sigma: f64,
    /// Each channel's marginal noise standard deviation (u, v, w), output units.
    pub noise_sd: [f64; 3],
    /// The noise process's shape, common to the channels (white without `[sensor.noise]`).
    pub noise_process: NoiseProcess,
}

impl Truth {
    /// s_u, s_v, s_w, φ_uv, φ_vw, φ_wu, O_u, O_v, O_w: the order of
    /// `IntrinsicJson::quantities`.
    pub fn properties(&self) -> [f64; 9] {
        let [s, a, o] = [self.sensitivity, self.angles_deg, self.offsets];
        [s[0], s[1], s[2], a[0], a[1], a[2], o[0], o[1], o[2]]
    }

    /// The theoretical autocorrelation of a channel's noise at `lag` samples (the
    /// channels share the process's shape).
    pub fn noise_autocorrelation(&self, _channel: Channel, lag: u64) -> f64 {
        self.noise_process.autocorrelation(lag)
    }
}

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
    let companion = nalgebra::DMatrix::from_fn(p, p, |i, j| {
        if i == 0 {
            -a.get(j).copied().unwrap_or(0.0)
        } else if i == j + 1 {
            1.0
        } else {
            0.0
        }
    });
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
struct NoiseGen<'a> {
    process: &'a NoiseProcess,
    sd: [f64; 3],
    /// sd / √(Σ h_k²): the innovation level giving each channel its marginal sd.
    scale: [f64; 3],
    state: [FilterState; 3],
}

/// The noise burn-in's random stream (ChaCha8 stream 1 of the seed; the main draws are
/// stream 0), so that it shifts no other draw.
const NOISE_STREAM: u64 = 1;

impl<'a> NoiseGen<'a> {
    /// Start each channel in its stationary distribution: from rest, u then v then w run
    /// `burn_in` innovations of their own stream.
    fn new(process: &'a NoiseProcess, sd: [f64; 3], seed: u64) -> NoiseGen<'a> {
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
        }
    }

    /// One sample's noise on u, v, w: one standard normal per channel from `rng`, in that
    /// order (where white noise has always been drawn, so white files keep their bytes).
    fn draw(&mut self, rng: &mut ChaCha8Rng) -> [f64; 3] {
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

/// Intrinsic sensitivities and angles (degrees) of a sensitivity matrix.
pub fn intrinsic_of(s: &[[f64; 3]; 3]) -> ([f64; 3], [f64; 3]) {
    let dot = |a: &[f64; 3], b: &[f64; 3]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let norm = s.map(|r| dot(&r, &r).sqrt());
    let angle = |j: usize, k: usize| {
        (dot(&s[j], &s[k]) / (norm[j] * norm[k]))
            .clamp(-1.0, 1.0)
            .acos()
    };
    (
        norm,
        [angle(0, 1), angle(1, 2), angle(2, 0)].map(f64::to_degrees),
    )
}

/// Why a simulation's recording could not be written and read back
/// ([`Simulation::recording`]).
#[derive(Debug, thiserror::Error)]
pub enum ReadBackError {
    /// Writing it (or running it through the device's logic).
    #[error(transparent)]
    Write(#[from] io::Error),
    /// Reading it back.
    #[error(transparent)]
    Read(#[from] RecordingError),
}

/// What a run produced.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Summary {
    /// Rows written.
    pub rows: u64,
    /// Samples dropped (their `seq` is missing).
    pub dropped: u64,
    /// Readings (channel values) clipped at the saturation rails or the output range.
    pub clipped: u64,
    /// Session length, s of true time.
    pub duration_s: f64,
}

/// A configured simulation.
#[derive(Clone, Debug)]
pub struct Simulation {
    cfg: Config,
    /// S in the platter frame.
    s: [[f64; 3]; 3],
    /// Row norms of `s` (the sensitivities).
    norm: [f64; 3],
    truth: Truth,
    /// Centripetal outward directions per condition (unit, across the axis).
    outward: [[f64; 3]; 3],
}

fn mount(cfg: &Config) -> [[f64; 3]; 3] {
    match cfg.mounting.matrix {
        Some(m) => m,
        None => rotation(cfg.mounting.axis, cfg.mounting.angle_deg),
    }
}

impl Simulation {
    /// Check the configuration and prepare the model.
    pub fn new(cfg: Config) -> Result<Simulation, ConfigError> {
        let d = &cfg.device;
        let device = match (d.sensitivity, d.angles_deg, d.matrix) {
            (Some(s), Some(a), None) => sensitivity_from_intrinsic(s, a),
            (None, None, Some(m)) => m,
            _ => {
                return Err(ConfigError::Invalid {
                    key: "device",
                    why: "give either sensitivity and angles_deg, or matrix",
                })
            }
        };
        let (sensitivity, angles_deg) = intrinsic_of(&device);
        if sensitivity.iter().any(|s| s.is_nan() || *s <= 0.0)
            || angles_deg.iter().any(|a| !a.is_finite())
        {
            return Err(ConfigError::Invalid {
                key: "device",
                why: "the sensitivity matrix has a zero or non-finite row",
            });
        }
        let s = mounted(&device, &mount(&cfg));
        let norm = s.map(|r| r.iter().map(|v| v * v).sum::<f64>().sqrt());
        let noise_sd = cfg.noise_sd()?;
        let noise_process = match &cfg.sensor.noise {
            Some(n) => NoiseProcess::new(n, cfg.timing.sample_rate_hz)?,
            None => NoiseProcess::white(),
        };
        let [su, sv, sw] = noise_sd;
        let noise_sigma = if su == sv && sv == sw {
            su
        } else {
            ((su * su + sv * sv + sw * sw) / 3.0).sqrt()
        };
        let dirs = cfg
            .effects
            .centripetal
            .as_ref()
            .and_then(|c| c.directions)
            .unwrap_or([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]);
        let mut outward = [[0.0; 3]; 3];
        for (i, (o, d)) in outward.iter_mut().zip(dirs).enumerate() {
            let mut p = d;
            p[i] = 0.0;
            let n = p.iter().map(|v| v * v).sum::<f64>().sqrt();
            *o = p.map(|v| v / n);
        }
        let truth = Truth {
            sensitivity,
            angles_deg,
            offsets: cfg.device.offsets,
            matrix_device: device,
            matrix_platter: s,
            noise_sigma,
            noise_sd,
            noise_process,
        };
        Ok(Simulation {
            cfg,
            s,
            norm,
            truth,
            outward,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &Config {
        &self.cfg
    }

    /// The truth the recording should give back.
    pub fn truth(&self) -> &Truth {
        &self.truth
    }

    fn multi_rate(&self) -> bool {
        self.cfg.method == Method::Rotation && self.cfg.rates_hz().len() > 1
    }

    /// The per-sample noise written as `noise_sigma`: white noise plus quantisation
    /// (lsb²/12), which is what a correct model's residuals show. With levels that differ
    /// per channel it uses `Truth::noise_sigma`, their root mean square.
    pub fn noise_floor(&self) -> f64 {
        (self.truth.noise_sigma.powi(2) + self.cfg.sensor.lsb.powi(2) / 12.0).sqrt()
    }

    /// Whether the file states `noise_sigma`: only when it is true of the noise, white and
    /// one level for all channels, and `sensor.noise.state` does not turn it off.
    pub fn states_noise_sigma(&self) -> bool {
        let [su, sv, sw] = self.truth.noise_sd;
        self.cfg.sensor.noise.as_ref().is_none_or(|n| n.state)
            && self.truth.noise_process.is_white()
            && su == sv
            && sv == sw
    }

    /// The file's metadata.
    pub fn metadata(&self) -> Metadata {
        let c = &self.cfg;
        let mut meta = Metadata {
            method: Some(c.method),
            rate_hz: None,
            g_loc: Some(c.g_loc),
            units: Some(c.units.clone()),
            sample_rate_hz: Some(c.timing.sample_rate_hz),
            noise_sigma: self.states_noise_sigma().then(|| self.noise_floor()),
            device: c.device.name.clone(),
            other: Default::default(),
        };
        if c.method == Method::Rotation && !self.multi_rate() {
            meta.rate_hz = self.cfg.rates_hz().first().copied();
        }
        meta.other.insert(
            "simulator".into(),
            format!("rotacal {}", env!("CARGO_PKG_VERSION")),
        );
        meta.other.insert("seed".into(), c.seed.to_string());
        if let Some(p) = &c.preset {
            meta.other.insert("preset".into(), p.clone());
        }
        meta
    }

    /// The file's columns.
    pub fn columns(&self) -> Columns {
        Columns {
            t_s: true,
            angle_deg: self.cfg.method == Method::Static,
            seq: true,
            temp_c: true,
            rate_hz: self.multi_rate(),
            gravity: false,
            pose: false,
            unc: false,
            conv_gaps: false,
        }
    }

    /// Temperature at session time t, °C (unrounded).
    pub fn temperature(&self, t: f64) -> f64 {
        let p = &self.cfg.temperature;
        p.t0_c + p.ramp_c_per_h * t / 3600.0 + p.swing_c * (TAU * t / p.period_s).sin()
    }

    /// The analog output of channel `ch` (before noise) for specific force `f` (m/s²,
    /// platter frame) at session time `t` and temperature `temp`.
    pub fn analog(&self, ch: Channel, f: [f64; 3], t: f64, temp: f64) -> f64 {
        let j = ch.index();
        let (row, sj) = (self.s[j], self.norm[j]);
        let e = &self.cfg.effects;
        let a = row.iter().zip(f).map(|(s, f)| s * f).sum::<f64>() / sj;
        let mut resp = a;
        if let Some(n) = &e.nonlinearity_2nd {
            resp += n.k2[j] * a * a;
        }
        if let Some(n) = &e.nonlinearity_3rd {
            resp += n.k3[j] * a * a * a;
        }
        let mut y = sj * resp + self.cfg.device.offsets[j];
        if let Some(d) = &e.offset_drift {
            y += d.per_s[j] * t;
        }
        if let Some(c) = &e.temperature_offset {
            y += c.per_c[j] * (temp - self.cfg.temperature.t0_c);
        }
        y
    }

    /// Rails, quantisation and range applied to the analog output plus its noise: the
    /// reading the device reports.
    fn output(&self, noisy: f64, clipped: &mut u64) -> f64 {
        let mut y = noisy;
        if let Some(s) = &self.cfg.effects.saturation {
            if y < s.rails[0] || y > s.rails[1] {
                *clipped += 1;
                y = y.clamp(s.rails[0], s.rails[1]);
            }
        }
        let lsb = self.cfg.sensor.lsb;
        if lsb > 0.0 {
            y = (y / lsb).round() * lsb;
        }
        let [lo, hi] = self.cfg.sensor.full_scale;
        if y < lo || y > hi {
            *clipped += 1;
            y = y.clamp(lo, hi);
        }
        y
    }

    /// The timestamp written for true time t: (1 + ε)·t plus jitter, in whole ticks.
    fn timestamp(&self, t: f64, rng: &mut ChaCha8Rng) -> f64 {
        let tm = &self.cfg.timing;
        let mut ts = t * (1.0 + tm.clock_error_ppm * 1e-6);
        if tm.jitter_s > 0.0 {
            let n: f64 = rng.sample(StandardNormal);
            ts += tm.jitter_s * n;
        }
        (ts * tm.tick_hz).round().max(0.0) / tm.tick_hz
    }

    fn temp_written(&self, t: f64) -> f64 {
        let r = self.cfg.temperature.resolution_c;
        let x = self.temperature(t);
        if r > 0.0 {
            (x / r).round() * r
        } else {
            x
        }
    }

    /// Run the experiment, handing every row to `sink` in file order.
    pub fn run(&self, mut sink: impl FnMut(&Row) -> io::Result<()>) -> io::Result<Summary> {
        let c = &self.cfg;
        let mut rng = ChaCha8Rng::seed_from_u64(c.seed);
        let mut noise = NoiseGen::new(&self.truth.noise_process, self.truth.noise_sd, c.seed);
        let mut sum = Summary::default();
        let fs = c.timing.sample_rate_hz;
        let mut seq: u64 = 0;
        let mut t0 = 0.0;
        let mut emit = |row: &mut Row, t: f64, rng: &mut ChaCha8Rng, sum: &mut Summary| {
            row.seq = Some(seq);
            seq += 1;
            row.t_s = Some(self.timestamp(t, rng));
            row.temp_c = Some(self.temp_written(t));
            if c.timing.drop_probability > 0.0 && rng.gen::<f64>() < c.timing.drop_probability {
                sum.dropped += 1;
                return Ok(());
            }
            sum.rows += 1;
            sink(row)
        };
        match c.method {
            Method::Rotation => {
                let n = c.samples_per_condition();
                let multi = self.multi_rate();
                for rate in c.rates_hz() {
                    let omega = TAU
                        * rate
                        * (1.0 + c.effects.rate_error.as_ref().map_or(0.0, |r| r.relative));
                    for cond in Condition::ALL {
                        let start: f64 = match c.table.start_angle_deg {
                            Some(a) => a[cond.index()].to_radians(),
                            None => rng.gen::<f64>() * TAU,
                        };
                        for k in 0..n {
                            let tau = k as f64 / fs;
                            let t = t0 + tau;
                            let temp = self.temperature(t);
                            let mut y = noise.draw(&mut rng);
                            for (ch, yj) in Channel::ALL.into_iter().zip(&mut y) {
                                let f = self.specific_force(cond, omega, start, tau, ch);
                                *yj = self
                                    .output(self.analog(ch, f, t, temp) + *yj, &mut sum.clipped);
                            }
                            let mut row = Row::new(cond, y[0], y[1], y[2]);
                            row.rate_hz = multi.then_some(rate);
                            emit(&mut row, t, &mut rng, &mut sum)?;
                        }
                        t0 += n as f64 / fs + c.timing.gap_s;
                    }
                }
            }
            Method::Free => {
                t0 = self.run_free(&mut rng, &mut noise, &mut sum, &mut emit)?;
            }
            Method::Static => {
                let angles = c.static_angles();
                let readings = c.table.readings_per_angle.unwrap_or(1);
                let dwell = c
                    .table
                    .dwell_s
                    .unwrap_or(10.0)
                    .max(f64::from(readings) / fs);
                for cond in Condition::ALL {
                    for (k, deg) in angles.iter().enumerate() {
                        let g_hat = match &c.effects.step_error {
                            Some(e) => step_orientation(cond, *deg, e, &mut rng),
                            None => cond.gravity_direction(deg.to_radians()),
                        };
                        let f = g_hat.map(|v| c.g_loc * v);
                        for r in 0..readings {
                            let t = t0 + k as f64 * dwell + f64::from(r) / fs;
                            let temp = self.temperature(t);
                            let mut y = noise.draw(&mut rng);
                            for (ch, yj) in Channel::ALL.into_iter().zip(&mut y) {
                                *yj = self
                                    .output(self.analog(ch, f, t, temp) + *yj, &mut sum.clipped);
                            }
                            let mut row = Row::new(cond, y[0], y[1], y[2]);
                            row.angle_deg = Some(*deg);
                            emit(&mut row, t, &mut rng, &mut sum)?;
                        }
                    }
                    t0 += angles.len() as f64 * dwell + c.timing.gap_s;
                }
            }
        }
        sum.duration_s = (t0 - c.timing.gap_s).max(0.0);
        Ok(sum)
    }

    /// Method free: the poses one after the other (docs/simulator.md), each row through
    /// `emit`; returns the session's length, s.
    fn run_free(
        &self,
        rng: &mut ChaCha8Rng,
        noise: &mut NoiseGen<'_>,
        sum: &mut Summary,
        emit: &mut impl FnMut(&mut Row, f64, &mut ChaCha8Rng, &mut Summary) -> io::Result<()>,
    ) -> io::Result<f64> {
        let c = &self.cfg;
        let p = c.poses.clone().unwrap_or_default();
        let fs = c.timing.sample_rate_hz;
        let normal = |rng: &mut ChaCha8Rng| -> f64 { rng.sample(StandardNormal) };
        let unit = |v: [f64; 3]| {
            let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            v.map(|x| x / n)
        };
        let dirs: Vec<[f64; 3]> = match &p.directions {
            Some(d) => d.iter().map(|v| unit(*v)).collect(),
            None => (0..p.count)
                .map(|_| unit([normal(rng), normal(rng), normal(rng)]))
                .collect(),
        };
        let n_still = (p.still_s * fs).round().max(1.0) as u64;
        let n_move = (p.move_s * fs).round() as u64;
        let mut k: u64 = 0;
        let mut prev: Option<[f64; 3]> = None;
        let mut row_at =
            |g: [f64; 3], scale: f64, k: &mut u64, rng: &mut ChaCha8Rng, sum: &mut Summary| {
                let t = *k as f64 / fs;
                *k += 1;
                let temp = self.temperature(t);
                let f = g.map(|v| c.g_loc * v);
                let mut y = noise.draw(rng);
                for (ch, yj) in Channel::ALL.into_iter().zip(&mut y) {
                    *yj = self.output(self.analog(ch, f, t, temp) + scale * *yj, &mut sum.clipped);
                }
                let mut row = Row::new(Condition::X, y[0], y[1], y[2]);
                emit(&mut row, t, rng, sum)
            };
        for (i, dir) in dirs.iter().enumerate() {
            if let Some(from) = prev {
                for m in 0..n_move {
                    let x = 0.5 - 0.5 * (PI * m as f64 / n_move as f64).cos();
                    row_at(slerp(from, *dir, x), 1.0, &mut k, rng, sum)?;
                }
            }
            let scale = p.noise_spread.powf(2.0 * rng.gen::<f64>() - 1.0);
            let ring = unit([normal(rng), normal(rng), normal(rng)]);
            // A pose that turns: about an axis across its direction.
            let axis = unit(cross(*dir, ring));
            let mut end = *dir;
            for m in 0..n_still {
                let tau = m as f64 / fs;
                let mut g = *dir;
                if let Some(mv) = p.moved.filter(|mv| mv.pose == i) {
                    let a = mv.deg.to_radians() * m as f64 / n_still as f64;
                    g = rotate_about(*dir, axis, a);
                }
                end = g;
                let amp = p.settle_ms2 / c.g_loc * (-tau / 0.1).exp() * (TAU * 12.0 * tau).sin();
                let g = [0, 1, 2].map(|a| g[a] + amp * ring[a]);
                row_at(g, scale, &mut k, rng, sum)?;
            }
            prev = Some(end);
        }
        Ok(k as f64 / fs + c.timing.gap_s)
    }

    /// Specific force on channel `ch`'s sample `tau` seconds into a condition (the
    /// channel's own sampling instant, with skew).
    fn specific_force(
        &self,
        cond: Condition,
        omega: f64,
        start: f64,
        tau: f64,
        ch: Channel,
    ) -> [f64; 3] {
        let e = &self.cfg.effects;
        let tj = tau
            + e.axis_time_skew
                .as_ref()
                .map_or(0.0, |s| s.skew_s[ch.index()]);
        let mut alpha = start + omega * tj;
        if let Some(r) = &e.rate_ripple {
            let psi = r.phase_deg.to_radians();
            alpha += r.relative * ((omega * tj + psi).sin() - psi.sin());
        }
        let mut f = cond.gravity_direction(alpha).map(|v| self.cfg.g_loc * v);
        if let Some(cp) = &e.centripetal {
            let a = omega * omega * cp.radius_m;
            for (fi, d) in f.iter_mut().zip(self.outward[cond.index()]) {
                *fi -= a * d;
            }
        }
        f
    }

    /// Write the recording to `w`.
    pub fn write<W: Write>(&self, w: W) -> io::Result<(Summary, W)> {
        let mut out = Writer::new(w, &self.metadata(), &self.columns())?;
        let sum = self.run(|row| out.write_row(row))?;
        Ok((sum, out.into_inner()?))
    }

    /// Write the recording to a file, synced to disk.
    pub fn write_file(&self, path: &Path) -> io::Result<Summary> {
        let mut out = Writer::create(path, &self.metadata(), &self.columns())?;
        let sum = self.run(|row| out.write_row(row))?;
        out.sync()?;
        Ok(sum)
    }

    /// The recording as `calibrate` would read it from the file (written to memory and
    /// read back, so tests go through the same parser as users).
    pub fn recording(&self) -> Result<Recording, ReadBackError> {
        let (_, buf) = self.write(Vec::new())?;
        Ok(recording::read_from(&buf[..], "simulated")?)
    }

    /// The recording the device would stream of this simulation, its conversions averaged
    /// by the firmware's logic ([`device::record`]), read back as `calibrate` reads it.
    pub fn recording_through_device(&self) -> Result<Recording, ReadBackError> {
        let (mut rows, mut fits) = (Vec::new(), Vec::new());
        device::record(self, &mut rows, &mut fits)?;
        Ok(recording::read_from(
            &rows[..],
            "simulated through the device",
        )?)
    }
}

/// A summary of the truth and the run for the terminal.
pub fn render(sim: &Simulation, sum: &Summary, out: &Path) -> String {
    let t = sim.truth();
    let c = sim.config();
    let u = &c.units;
    let mut o = format!(
        "wrote {}: {} rows ({} dropped, {} readings clipped), {:.1} s of session time, seed {}\n",
        out.display(),
        sum.rows,
        sum.dropped,
        sum.clipped,
        sum.duration_s,
        c.seed
    );
    o += &format!(
        "truth: s = [{:.6}, {:.6}, {:.6}] {u} per m/s², φ_uv, φ_vw, φ_wu = [{:.5}, {:.5}, {:.5}]°, O = [{}, {}, {}] {u}\n",
        t.sensitivity[0], t.sensitivity[1], t.sensitivity[2],
        t.angles_deg[0], t.angles_deg[1], t.angles_deg[2],
        t.offsets[0], t.offsets[1], t.offsets[2],
    );
    if c.sensor.noise.is_none() {
        o += &format!(
            "noise σ = {:.6} {u} per sample (with quantisation {:.6})\n",
            t.noise_sigma,
            sim.noise_floor()
        );
        return o;
    }
    let p = &t.noise_process;
    let kind = match c.sensor.noise.as_ref().and_then(|n| n.lowpass_hz) {
        _ if p.is_white() => "white".to_string(),
        Some(fc) => format!("white through a 2nd-order Butterworth low-pass at {fc} Hz"),
        None => format!(
            "AR({}) φ = {:?}",
            p.feedback().len(),
            p.feedback().iter().map(|a| -a).collect::<Vec<_>>()
        ),
    };
    let [su, sv, sw] = t.noise_sd;
    o += &format!(
        "noise: {kind}, marginal sd u, v, w = {su:.6}, {sv:.6}, {sw:.6} {u}, lag-1 autocorrelation {:.6}; noise_sigma {}\n",
        p.autocorrelation(1),
        if sim.states_noise_sigma() { "stated" } else { "not stated" }
    );
    o
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// `v` turned by `angle` (rad) about the unit `axis` (Rodrigues).
fn rotate_about(v: [f64; 3], axis: [f64; 3], angle: f64) -> [f64; 3] {
    let (s, c) = angle.sin_cos();
    let k = cross(axis, v);
    let d: f64 = (0..3).map(|i| axis[i] * v[i]).sum();
    [0, 1, 2].map(|i| v[i] * c + k[i] * s + axis[i] * d * (1.0 - c))
}

/// The unit vector a fraction `x` of the way from `a` to `b` along the great circle.
fn slerp(a: [f64; 3], b: [f64; 3], x: f64) -> [f64; 3] {
    let d: f64 = (0..3).map(|i| a[i] * b[i]).sum::<f64>().clamp(-1.0, 1.0);
    let omega = d.acos();
    if omega < 1e-9 {
        return b;
    }
    let c = cross(a, b);
    let n = c.iter().map(|v| v * v).sum::<f64>().sqrt();
    // Opposite directions: any axis across a will do.
    let axis = if n < 1e-12 {
        let t = if a[0].abs() < 0.9 {
            [1.0, 0.0, 0.0]
        } else {
            [0.0, 1.0, 0.0]
        };
        let c = cross(a, t);
        let n = c.iter().map(|v| v * v).sum::<f64>().sqrt();
        c.map(|v| v / n)
    } else {
        c.map(|v| v / n)
    };
    rotate_about(a, axis, omega * x)
}

/// ĝ at one step of a stepped table with `step_error`: the angle off by a normal error, then
/// tilted by a small rotation t (normal about each axis): ĝ + t × ĝ, normalised.
fn step_orientation(
    cond: Condition,
    deg: f64,
    e: &config::StepError,
    rng: &mut impl Rng,
) -> [f64; 3] {
    let mut normal =
        || -> f64 { rand_distr::Distribution::sample(&rand_distr::StandardNormal, &mut *rng) };
    let alpha = (deg + e.angle_sd_deg * normal()).to_radians();
    let g = cond.gravity_direction(alpha);
    let t = [0; 3].map(|_| e.tilt_sd_deg.to_radians() * normal());
    let r = [
        g[0] + t[1] * g[2] - t[2] * g[1],
        g[1] + t[2] * g[0] - t[0] * g[2],
        g[2] + t[0] * g[1] - t[1] * g[0],
    ];
    let n = r.iter().map(|v| v * v).sum::<f64>().sqrt();
    r.map(|v| v / n)
}
