//! A run's outputs: the recording written to a file or to memory and read back (directly
//! or through the device's logic), and the summary for the terminal.

use super::device;
use super::{ReadBackError, Simulation, Summary};
use crate::recording::{self, Recording, Writer};
use std::io::{self, Write};
use std::path::Path;

impl Simulation {
    /// Write the recording to `w`.
    pub fn write<W: Write>(&self, w: W) -> io::Result<(Summary, W)> {
        let mut out = Writer::new(w, &self.metadata(), &self.columns())?;
        let sum = self.run(|row| out.write_row(row))?;
        Ok((sum, out.into_inner()?))
    }

    /// Write the recording to a file, synced to disk, whole or not at all.
    pub fn write_file(&self, path: &Path) -> io::Result<Summary> {
        crate::atomic::write_with(path, |w| {
            let mut out = Writer::new(w, &self.metadata(), &self.columns())?;
            let sum = self.run(|row| out.write_row(row))?;
            out.into_inner()?;
            Ok(sum)
        })
    }

    /// The recording as `calibrate` would read it from the file (written to memory and
    /// read back by the readers `calibrate FILE` uses, so tests go through the same parser
    /// as users).
    pub fn recording(&self) -> Result<Recording, ReadBackError> {
        let (_, buf) = self.write(Vec::new())?;
        Ok(recording::read_bytes(&buf, "simulated")?)
    }

    /// The recording the device would stream of this simulation, its conversions averaged
    /// by the firmware's logic ([`device::record`]), read back as `calibrate` reads it.
    pub fn recording_through_device(&self) -> Result<Recording, ReadBackError> {
        let (mut rows, mut fits) = (Vec::new(), Vec::new());
        device::record(self, &mut rows, &mut fits)?;
        Ok(recording::read_bytes(
            &rows,
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
    if let Some(n) = c.sensor.noise.as_ref().filter(|_| !t.slow.is_none()) {
        let level = |l: &Option<crate::simulate::NoiseSd>| {
            let [a, b, c] = l.as_ref().map_or([0.0; 3], |l| l.per_channel());
            format!("{a}, {b}, {c}")
        };
        o += &format!(
            "slow noise in session time: flicker with an Allan floor of u, v, w = {} µg, bias random walk {} µg/√s\n",
            level(&n.flicker_floor_ug),
            level(&n.random_walk_ug_per_sqrt_s)
        );
    }
    o
}
