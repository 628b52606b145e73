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
//! 5. plus white noise, then saturation rails, quantisation and the register range;
//! 6. the timestamp the device would write: (1 + ε)·t plus jitter, in whole ticks.
//!
//! Seeded (ChaCha8), so the same configuration and seed give the same file.

pub mod config;

pub use config::{Config, ConfigError, PRESETS};

use crate::calibrate::gravity_direction;
use crate::demo::sensitivity_from_intrinsic;
use crate::geometry::{mounted, rotation};
use crate::recording::{self, Columns, Metadata, Method, Recording, Row, Writer};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rotacal_shared::Condition;
use std::f64::consts::TAU;
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
    /// White noise per sample, output units (before quantisation).
    pub noise_sigma: f64,
}

impl Truth {
    /// s_u, s_v, s_w, φ_uv, φ_vw, φ_wu, O_u, O_v, O_w: the order of
    /// `IntrinsicJson::quantities`.
    pub fn properties(&self) -> [f64; 9] {
        let [s, a, o] = [self.sensitivity, self.angles_deg, self.offsets];
        [s[0], s[1], s[2], a[0], a[1], a[2], o[0], o[1], o[2]]
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
    sigma: f64,
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
                return Err(ConfigError(
                    "device: give either sensitivity and angles_deg, or matrix".into(),
                ))
            }
        };
        let (sensitivity, angles_deg) = intrinsic_of(&device);
        if sensitivity.iter().any(|s| s.is_nan() || *s <= 0.0)
            || angles_deg.iter().any(|a| !a.is_finite())
        {
            return Err(ConfigError(
                "device: the sensitivity matrix has a zero or non-finite row".into(),
            ));
        }
        let s = mounted(&device, &mount(&cfg));
        let norm = s.map(|r| r.iter().map(|v| v * v).sum::<f64>().sqrt());
        let sigma = cfg.noise_sigma()?;
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
            noise_sigma: sigma,
        };
        Ok(Simulation {
            cfg,
            s,
            norm,
            sigma,
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
    /// (lsb²/12), which is what a correct model's residuals show.
    pub fn noise_floor(&self) -> f64 {
        (self.sigma.powi(2) + self.cfg.sensor.lsb.powi(2) / 12.0).sqrt()
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
            noise_sigma: Some(self.noise_floor()),
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
        }
    }

    /// Temperature at session time t, °C (unrounded).
    pub fn temperature(&self, t: f64) -> f64 {
        let p = &self.cfg.temperature;
        p.t0_c + p.ramp_c_per_h * t / 3600.0 + p.swing_c * (TAU * t / p.period_s).sin()
    }

    /// The analog output of channel j (before noise) for specific force `f` (m/s²,
    /// platter frame) at session time `t` and temperature `temp`.
    pub fn analog(&self, j: usize, f: [f64; 3], t: f64, temp: f64) -> f64 {
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

    /// Noise, rails, quantisation and range: the reading the device reports.
    fn output(&self, analog: f64, rng: &mut ChaCha8Rng, clipped: &mut u64) -> f64 {
        let n: f64 = rng.sample(StandardNormal);
        let mut y = analog + self.sigma * n;
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
                            let mut y = [0.0; 3];
                            for (j, yj) in y.iter_mut().enumerate() {
                                let f = self.specific_force(cond, omega, start, tau, j);
                                *yj = self.output(
                                    self.analog(j, f, t, temp),
                                    &mut rng,
                                    &mut sum.clipped,
                                );
                            }
                            let mut row = Row::new(cond, y[0], y[1], y[2]);
                            row.rate_hz = multi.then_some(rate);
                            emit(&mut row, t, &mut rng, &mut sum)?;
                        }
                        t0 += n as f64 / fs + c.timing.gap_s;
                    }
                }
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
                        let g_hat = gravity_direction(cond, deg.to_radians());
                        let f = g_hat.map(|v| c.g_loc * v);
                        for r in 0..readings {
                            let t = t0 + k as f64 * dwell + f64::from(r) / fs;
                            let temp = self.temperature(t);
                            let mut y = [0.0; 3];
                            for (j, yj) in y.iter_mut().enumerate() {
                                *yj = self.output(
                                    self.analog(j, f, t, temp),
                                    &mut rng,
                                    &mut sum.clipped,
                                );
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

    /// Specific force on channel j's sample `tau` seconds into a condition (the channel's
    /// own sampling instant, with skew).
    fn specific_force(
        &self,
        cond: Condition,
        omega: f64,
        start: f64,
        tau: f64,
        j: usize,
    ) -> [f64; 3] {
        let e = &self.cfg.effects;
        let tj = tau + e.axis_time_skew.as_ref().map_or(0.0, |s| s.skew_s[j]);
        let mut alpha = start + omega * tj;
        if let Some(r) = &e.rate_ripple {
            let psi = r.phase_deg.to_radians();
            alpha += r.relative * ((omega * tj + psi).sin() - psi.sin());
        }
        let mut f = gravity_direction(cond, alpha).map(|v| self.cfg.g_loc * v);
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
    pub fn recording(&self) -> anyhow::Result<Recording> {
        let (_, buf) = self.write(Vec::new())?;
        Ok(recording::read_from(&buf[..], "simulated")?)
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
    o += &format!(
        "noise σ = {:.6} {u} per sample (with quantisation {:.6})\n",
        t.noise_sigma,
        sim.noise_floor()
    );
    o
}
