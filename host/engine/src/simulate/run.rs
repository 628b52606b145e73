//! The experiment run sample by sample: the specific force, the analog output, rails and
//! quantisation, the timestamps, for each method (and the free method's path between
//! poses).

use super::config;
use super::noise::NoiseGen;
use super::{Simulation, Summary};
use crate::recording::{Method, Row};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rotacal_shared::{Channel, Condition};
use std::f64::consts::{PI, TAU};
use std::io;

impl Simulation {
    /// Temperature at session time t, °C (unrounded).
    pub fn temperature(&self, t: f64) -> f64 {
        let p = &self.cfg.temperature;
        p.t0_c + p.ramp_c_per_h * t / 3600.0 + p.swing_c * (TAU * t / p.period_s).sin()
    }

    /// The analog output of channel `ch` (before noise) for specific force `f` (m/s²,
    /// platter frame) at session time `t` and temperature `temp`.
    pub fn analog(&self, ch: Channel, f: [f64; 3], t: f64, temp: f64) -> f64 {
        let (row, sj) = (*ch.of(&self.s), *ch.of(&self.norm));
        let e = &self.cfg.effects;
        let a = row.iter().zip(f).map(|(s, f)| s * f).sum::<f64>() / sj;
        let mut resp = a;
        if let Some(n) = &e.nonlinearity_2nd {
            resp += ch.of(&n.k2) * a * a;
        }
        if let Some(n) = &e.nonlinearity_3rd {
            resp += ch.of(&n.k3) * a * a * a;
        }
        if let Some(n) = &e.nonlinearity_high {
            resp += ch.of(&n.k) * a.powf(f64::from(n.order));
        }
        let mut y = sj * resp + ch.of(&self.cfg.device.offsets);
        if let Some(s) = e.offset_step.as_ref().filter(|s| t >= s.at_s) {
            y += ch.of(&s.size);
        }
        if let Some(d) = &e.offset_drift {
            y += ch.of(&d.per_s) * t;
        }
        if let Some(c) = &e.temperature_offset {
            y += ch.of(&c.per_c) * (temp - self.cfg.temperature.t0_c);
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
    pub fn run(&self, sink: impl FnMut(&Row) -> io::Result<()>) -> io::Result<Summary> {
        let c = &self.cfg;
        let noise = NoiseGen::new(&self.truth.noise_process, self.truth.noise_sd, c.seed);
        if self.truth.slow.is_none() {
            return self.run_with(noise, sink);
        }
        // The slow noise spans the session, gaps included: a first run without it gives
        // the session's length (the free method's depends on its draws).
        let blank = NoiseGen::new(&self.truth.noise_process, self.truth.noise_sd, c.seed);
        let duration = self.run_with(blank, |_| Ok(()))?.duration_s;
        let fs = c.timing.sample_rate_hz;
        let len = (duration * fs).ceil().max(0.0) as usize + 2;
        self.run_with(noise.with_slow(&self.truth.slow, len, fs, c.seed), sink)
    }

    /// [`Simulation::run`] with the noise generator `noise`.
    fn run_with(
        &self,
        mut noise: NoiseGen<'_>,
        mut sink: impl FnMut(&Row) -> io::Result<()>,
    ) -> io::Result<Summary> {
        let c = &self.cfg;
        let mut rng = ChaCha8Rng::seed_from_u64(c.seed);
        let mut sum = Summary::default();
        let fs = c.timing.sample_rate_hz;
        let mut seq: u64 = 0;
        let mut t0 = 0.0;
        // The slow noise summed over the rows written.
        let mut slow_sum = [0.0; 3];
        let mut emit =
            |row: &mut Row, t: f64, slow: [f64; 3], rng: &mut ChaCha8Rng, sum: &mut Summary| {
                row.seq = Some(seq);
                seq += 1;
                row.t_s = Some(self.timestamp(t, rng));
                row.temp_c = Some(self.temp_written(t));
                if c.timing.drop_probability > 0.0 && rng.gen::<f64>() < c.timing.drop_probability {
                    sum.dropped += 1;
                    return Ok(());
                }
                sum.rows += 1;
                for (a, b) in slow_sum.iter_mut().zip(slow) {
                    *a += b;
                }
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
                            Some(a) => cond.of(&a).to_radians(),
                            None => rng.gen::<f64>() * TAU,
                        };
                        for k in 0..n {
                            let tau = k as f64 / fs;
                            let t = t0 + tau;
                            let temp = self.temperature(t);
                            let mut y = noise.draw(&mut rng);
                            if let Some(nc) =
                                c.effects.noise_change.as_ref().filter(|nc| t >= nc.at_s)
                            {
                                y = y.map(|v| v * nc.factor);
                            }
                            let slow = noise.slow_at(t);
                            for (ch, yj) in Channel::ALL.into_iter().zip(&mut y) {
                                let f = self.specific_force(cond, omega, start, tau, ch);
                                let e = *yj + ch.of(&slow);
                                *yj =
                                    self.output(self.analog(ch, f, t, temp) + e, &mut sum.clipped);
                            }
                            let mut row = Row::new(cond, y[0], y[1], y[2]);
                            row.rate_hz = multi.then_some(rate);
                            emit(&mut row, t, slow, &mut rng, &mut sum)?;
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
                            let slow = noise.slow_at(t);
                            for (ch, yj) in Channel::ALL.into_iter().zip(&mut y) {
                                let e = *yj + ch.of(&slow);
                                *yj =
                                    self.output(self.analog(ch, f, t, temp) + e, &mut sum.clipped);
                            }
                            let mut row = Row::new(cond, y[0], y[1], y[2]);
                            row.angle_deg = Some(*deg);
                            emit(&mut row, t, slow, &mut rng, &mut sum)?;
                        }
                        // The table takes the rest of the dwell to the next angle.
                        let dwell_samples = (dwell * fs).round() as u64;
                        noise.idle(dwell_samples.saturating_sub(u64::from(readings)));
                    }
                    t0 += angles.len() as f64 * dwell + c.timing.gap_s;
                }
            }
        }
        sum.duration_s = (t0 - c.timing.gap_s).max(0.0);
        if sum.rows > 0 {
            sum.slow_mean = slow_sum.map(|a| a / sum.rows as f64);
        }
        Ok(sum)
    }

    /// Method free: the poses one after the other (docs/simulator.md), each row through
    /// `emit`; returns the session's length, s.
    fn run_free(
        &self,
        rng: &mut ChaCha8Rng,
        noise: &mut NoiseGen<'_>,
        sum: &mut Summary,
        emit: &mut impl FnMut(&mut Row, f64, [f64; 3], &mut ChaCha8Rng, &mut Summary) -> io::Result<()>,
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
                // The pose's spread scales the fast noise; the bias wanders regardless.
                let slow = noise.slow_at(t);
                for (ch, yj) in Channel::ALL.into_iter().zip(&mut y) {
                    let e = scale * *yj + ch.of(&slow);
                    *yj = self.output(self.analog(ch, f, t, temp) + e, &mut sum.clipped);
                }
                let mut row = Row::new(Condition::X, y[0], y[1], y[2]);
                emit(&mut row, t, slow, rng, sum)
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
            let mut tremor = Tremor::new(p.tremor_ms2 / c.g_loc, p.tremor_hz, fs, rng);
            for m in 0..n_still {
                let tau = m as f64 / fs;
                let mut g = *dir;
                if let Some(mv) = p.moved.filter(|mv| mv.pose == i) {
                    let a = mv.deg.to_radians() * m as f64 / n_still as f64;
                    g = rotate_about(*dir, axis, a);
                }
                end = g;
                let amp = p.settle_ms2 / c.g_loc * (-tau / 0.1).exp() * (TAU * 12.0 * tau).sin();
                let g = zip_map(g, ring, |g, r| g + amp * r);
                let g = match tremor.as_mut() {
                    Some(t) => zip_map(g, t.next(rng), |g, h| g + h),
                    None => g,
                };
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
        let tj = tau + e.axis_time_skew.as_ref().map_or(0.0, |s| *ch.of(&s.skew_s));
        let mut alpha = start + omega * tj;
        if let Some(r) = &e.rate_ripple {
            let psi = r.phase_deg.to_radians();
            alpha += r.relative * ((omega * tj + psi).sin() - psi.sin());
        }
        let mut g_hat = cond.gravity_direction(alpha);
        if let Some(w) = &e.axis_wobble {
            let theta = w.tilt_deg.to_radians()
                * (f64::from(w.per_rev) * alpha + w.phase_deg.to_radians()).sin();
            let (s, c) = theta.sin_cos();
            let axis = Condition::ALL.map(|a| f64::from(u8::from(a == cond)));
            g_hat = zip_map(g_hat, axis, |g, n| c * g + s * n);
        }
        let mut f = g_hat.map(|v| self.cfg.g_loc * v);
        if let Some(cp) = &e.centripetal {
            let a = omega * omega * cp.radius_m;
            for (fi, d) in f.iter_mut().zip(*cond.of(&self.outward)) {
                *fi -= a * d;
            }
        }
        f
    }
}

/// A hand's tremor on each axis: AR(2) with its poles at `hz`, 2 Hz wide, scaled to `rms`
/// (in g), started from its stationary state by a burn-in. Draws nothing without tremor,
/// so that sessions without it stay as they were.
struct Tremor {
    a1: f64,
    a2: f64,
    sd: f64,
    state: [[f64; 2]; 3],
}

impl Tremor {
    fn new(rms: f64, hz: f64, fs: f64, rng: &mut ChaCha8Rng) -> Option<Tremor> {
        if rms <= 0.0 {
            return None;
        }
        let r = (-PI * 2.0 / fs).exp();
        let (a1, a2) = (2.0 * r * (TAU * hz / fs).cos(), -r * r);
        // The stationary variance of AR(2) per unit innovation variance.
        let gain = (1.0 - a2) / ((1.0 + a2) * ((1.0 - a2).powi(2) - a1 * a1));
        let mut t = Tremor {
            a1,
            a2,
            sd: rms / gain.sqrt(),
            state: [[0.0; 2]; 3],
        };
        // Twenty time constants 1/(1 − r).
        for _ in 0..(20.0 / (1.0 - r)).ceil() as usize {
            t.next(rng);
        }
        Some(t)
    }

    fn next(&mut self, rng: &mut ChaCha8Rng) -> [f64; 3] {
        let mut out = [0.0; 3];
        for (o, [x1, x2]) in out.iter_mut().zip(self.state.iter_mut()) {
            let e: f64 = rng.sample(StandardNormal);
            let x = self.a1 * *x1 + self.a2 * *x2 + self.sd * e;
            *x2 = *x1;
            *x1 = x;
            *o = x;
        }
        out
    }
}

/// `f` of `a` and `b` element by element.
fn zip_map(a: [f64; 3], b: [f64; 3], f: impl Fn(f64, f64) -> f64) -> [f64; 3] {
    let ([a0, a1, a2], [b0, b1, b2]) = (a, b);
    [f(a0, b0), f(a1, b1), f(a2, b2)]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    let ([a0, a1, a2], [b0, b1, b2]) = (a, b);
    [a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0]
}

/// `v` turned by `angle` (rad) about the unit `axis` (Rodrigues).
fn rotate_about(v: [f64; 3], axis: [f64; 3], angle: f64) -> [f64; 3] {
    let (s, c) = angle.sin_cos();
    let k = cross(axis, v);
    let d: f64 = axis.iter().zip(v).map(|(a, v)| a * v).sum();
    let turned = zip_map(v, k, |v, k| v * c + k * s);
    zip_map(turned, axis, |t, a| t + a * d * (1.0 - c))
}

/// The unit vector a fraction `x` of the way from `a` to `b` along the great circle.
fn slerp(a: [f64; 3], b: [f64; 3], x: f64) -> [f64; 3] {
    let d: f64 = a
        .iter()
        .zip(b)
        .map(|(a, b)| a * b)
        .sum::<f64>()
        .clamp(-1.0, 1.0);
    let omega = d.acos();
    if omega < 1e-9 {
        return b;
    }
    let c = cross(a, b);
    let n = c.iter().map(|v| v * v).sum::<f64>().sqrt();
    // Opposite directions: any axis across a will do.
    let axis = if n < 1e-12 {
        let [a0, ..] = a;
        let t = if a0.abs() < 0.9 {
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
