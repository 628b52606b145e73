//! `rotacal simulate`: a forward model of the rotation-table experiment that writes
//! recordings in the format `calibrate` reads (formats.md).
//!
//! It is the ground truth for the tests, the demo and the discrepancy workflow, so its
//! physics is written out once, here, and in docs/simulator.md. For every sample:
//!
//! 1. true time t (session seconds) on the sensor's own schedule, 1/fs apart;
//! 2. table angle α(t) (rate, rate error, rate ripple; per channel at t + τ_j for skew);
//! 3. specific force in the platter frame, f = g·ĝ(α) − ω²·r·d̂ (docs/method.md §1 for ĝ);
//! 4. along each sensitive axis a_j = Ŝ_j·f, output s_j·(a_j + K2·a_j² + K3·a_j³) + O_j
//!    + drift + temperature term, with S the device's matrix turned by the mounting;
//! 5. plus sensor noise (white, or per `[sensor.noise]` an autoregressive or low-passed
//!    process per channel, and flicker and bias random walk in session time), then
//!    saturation rails, quantisation and the register range;
//! 6. the timestamp the device would write: (1 + ε)·t plus jitter, in whole ticks.
//!
//! Seeded (ChaCha8), so the same configuration and seed give the same file.

//!
//! Here the public types, the truth and the model's preparation; `noise` is the sensor
//! noise process and its generator, `slow` the flicker and random walk, `run` the
//! experiment sample by sample, `write` the file, the recording read back and the summary
//! for the terminal.

pub mod config;
pub mod device;
pub mod emulated;
pub mod geometry;
mod noise;
mod run;
pub mod slow;
mod write;

pub use config::{Config, ConfigError, Noise, NoiseSd, StepError, PRESETS};
pub use noise::{FilterError, NoiseProcess, MAX_NOISE_BURN_IN};
pub use slow::SlowNoise;
pub use write::render;

use crate::recording::{Columns, Metadata, Method, RecordingError};
use crate::simulate::geometry::sensitivity_from_intrinsic;
use crate::simulate::geometry::{mounted, rotation};
use rotacal_shared::Channel;
use std::io;

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
    /// Flicker and bias random walk, output units (none without them).
    pub slow: SlowNoise,
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

    /// The structure function of channel `ch`'s noise (before quantisation) at lag `k`
    /// samples, E[(e_{t+k} − e_t)²], output units²: the filtered noise's 2σ²(1 − ρ_k) plus
    /// the slow terms' (the samples of one stretch of the session, 1/fs apart).
    pub fn noise_structure(&self, ch: Channel, k: u64) -> f64 {
        let sd = *ch.of(&self.noise_sd);
        let fast = if k == 0 {
            0.0
        } else {
            2.0 * sd * sd * (1.0 - self.noise_process.autocorrelation(k))
        };
        fast + self.slow.structure(ch, k)
    }

    /// The expected Allan variance of channel `ch`'s noise (before quantisation) averaged
    /// over `m` samples, output units² ([`slow::allan_variance`] of the structure function).
    pub fn noise_allan_variance(&self, ch: Channel, m: u64) -> f64 {
        slow::allan_variance(m, |k| self.noise_structure(ch, k))
    }
}

/// Intrinsic sensitivities and angles (degrees) of a sensitivity matrix.
pub fn intrinsic_of(s: &[[f64; 3]; 3]) -> ([f64; 3], [f64; 3]) {
    let dot = |a: &[f64; 3], b: &[f64; 3]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let norm = s.map(|r| dot(&r, &r).sqrt());
    let angle = |(sj, nj): (&[f64; 3], f64), (sk, nk): (&[f64; 3], f64)| {
        (dot(sj, sk) / (nj * nk)).clamp(-1.0, 1.0).acos()
    };
    let ([s0, s1, s2], [n0, n1, n2]) = (s, norm);
    let (r0, r1, r2) = ((s0, n0), (s1, n1), (s2, n2));
    (
        norm,
        [angle(r0, r1), angle(r1, r2), angle(r2, r0)].map(f64::to_degrees),
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
    /// The slow noise (flicker, random walk) averaged over the rows written, u, v, w in
    /// output units: what a static calibration's offsets measure beside the bias (zero
    /// without slow noise).
    pub slow_mean: [f64; 3],
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
            if let Some(pi) = p.get_mut(i) {
                *pi = 0.0;
            }
            let n = p.iter().map(|v| v * v).sum::<f64>().sqrt();
            *o = p.map(|v| v / n);
        }
        let slow = match &cfg.sensor.noise {
            Some(n) => SlowNoise::from_physical(
                n.flicker_floor_ug
                    .as_ref()
                    .map_or([0.0; 3], |l| l.per_channel()),
                n.random_walk_ug_per_sqrt_s
                    .as_ref()
                    .map_or([0.0; 3], |l| l.per_channel()),
                sensitivity,
                cfg.timing.sample_rate_hz,
            ),
            None => SlowNoise::default(),
        };
        let truth = Truth {
            sensitivity,
            angles_deg,
            offsets: cfg.device.offsets,
            matrix_device: device,
            matrix_platter: s,
            noise_sigma,
            noise_sd,
            noise_process,
            slow,
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
            && self.truth.slow.is_none()
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
            conv_missed: false,
            boot: false,
        }
    }
}
