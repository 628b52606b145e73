//! The simulated sensor through the device's own logic: the simulator's conversions (at
//! the sensor's rate, with its noise, in counts) go into the firmware's `Device` from
//! `rotacal_shared`, which averages them into the 16 Hz stream and fits them in f32; its
//! packets go through the recorder, as from a board. The recording is what `rotacal record`
//! would write: averaged rows with their conversions (`conv_gaps`), and the device's fit log.
//!
//! One condition after another, the device clock at 1 MHz running from the session's
//! time (its 32-bit counter wraps after 71 min). A temperature every 104 conversions.

use crate::recording::from_device::{RecordSummary, Recorder};
use crate::recording::Method;
use crate::simulate::Simulation;
use rotacal_shared::device::{Config as DeviceConfig, Device, RING};
use rotacal_shared::packet::Command;
use rotacal_shared::Condition;
use std::io::{self, Write};

/// One sensor conversion as the device reads it.
#[derive(Clone, Copy, Debug)]
pub struct Conversion {
    /// Seconds from the start of its condition.
    pub t: f64,
    /// Session time, device ticks at 1 MHz.
    pub ticks: u64,
    /// Raw counts u, v, w (the simulated output rounded into i16).
    pub counts: [i16; 3],
    /// Die temperature, °C.
    pub temp_c: f64,
}

/// The conversions of `sim` (run at the sensor's rate, in counts) per condition x, y, z.
pub fn conversions(sim: &Simulation) -> io::Result<[Vec<Conversion>; 3]> {
    // Per condition: its conversions, and the time of its first.
    let mut streams: [(Vec<Conversion>, Option<f64>); 3] = Default::default();
    let count = |x: f64| x.round().clamp(-32768.0, 32767.0) as i16;
    sim.run(|row| {
        let [x, y, z] = &mut streams;
        let (s, t0) = match row.condition {
            Condition::X => x,
            Condition::Y => y,
            Condition::Z => z,
        };
        let t = row.t_s.unwrap_or(0.0);
        s.push(Conversion {
            t: t - *t0.get_or_insert(t),
            ticks: (t * 1e6).round().max(0.0) as u64,
            counts: [count(row.u), count(row.v), count(row.w)],
            temp_c: row.temp_c.unwrap_or(25.0),
        });
        Ok(())
    })?;
    Ok(streams.map(|(s, _)| s))
}

/// Why a simulation cannot go through the device.
fn unsupported(why: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, why)
}

/// Run `sim` (rotation, one rate, counts, at the sensor's output rate) through the device
/// logic, writing the recording to `rows` and the device's fit log to `fits`.
pub fn record<W: Write, F: Write>(sim: &Simulation, rows: W, fits: F) -> io::Result<RecordSummary> {
    let cfg = sim.config();
    let rates = cfg.rates_hz();
    let [rate] = rates.as_slice() else {
        return Err(unsupported(
            "the device runs one rotation rate per recording".into(),
        ));
    };
    if cfg.method != Method::Rotation {
        return Err(unsupported("the device streams rotation runs only".into()));
    }
    let rate_uhz = (rate * 1e6).round();
    if !(1.0..=f64::from(u32::MAX)).contains(&rate_uhz) {
        return Err(unsupported(format!("rotation rate {rate} Hz")));
    }
    let odr_mhz = (cfg.timing.sample_rate_hz * 1e3).round();
    let dev_cfg = DeviceConfig {
        sensor_odr_mhz: odr_mhz as u32,
        ..DeviceConfig::FEATHER
    };
    let streams = conversions(sim)?;
    let mut meta = sim.metadata();
    meta.sample_rate_hz = Some(f64::from(dev_cfg.sample_rate_mhz) / 1e3);
    // The stream's noise is not the conversions': nothing is stated.
    meta.noise_sigma = None;
    let mut rec = Recorder::new(rows, fits, &meta, dev_cfg.clock.hz())?;
    let mut device = Device::<RING>::new(dev_cfg);
    for (cond, stream) in Condition::ALL.into_iter().zip(&streams) {
        let mut out = Vec::new();
        device.on_command(
            Command::Start {
                condition: cond,
                rate_uhz: rate_uhz as u32,
            },
            &mut |p| out.push(p),
        );
        for (k, c) in stream.iter().enumerate() {
            let capture = c.ticks & 0xFFFF_FFFF;
            device.on_sample(capture, c.counts, false, &mut |p| out.push(p));
            if k % 104 == 0 {
                let centi_c = (c.temp_c * 100.0).round() as i16;
                device.on_temperature(centi_c, &mut |p| out.push(p));
            }
            device.poll(capture, &mut |p| out.push(p));
        }
        device.on_command(Command::Stop, &mut |p| out.push(p));
        for p in &out {
            rec.packet(p)?;
        }
    }
    rec.finish()
}
