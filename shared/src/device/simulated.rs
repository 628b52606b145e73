//! A simulated session for tests: an operator who starts and stops x, y and z, and a
//! sensor that converts at its own output rate with LSM6DS33 noise, on a device clock
//! whose 32-bit counter wraps during the session. The same stream on the host and on the
//! emulated Cortex-M4F (tests/qemu `session`), so their packets can be compared byte
//! for byte.

use super::Device;
use crate::packet::{Command, Packet};
use crate::synth::{crosscheck, Synth, SynthSpec};
use crate::time::TickRate;
use crate::{Condition, PhaseStep};

/// What to simulate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SessionSpec {
    /// Nominal (and true) rotation rate, µHz.
    pub rate_uhz: u32,
    /// The sensor's output data rate, mHz.
    pub sensor_odr_mhz: u32,
    /// Sensor samples per condition.
    pub sensor_samples: u32,
    /// Ticks from one condition's start to the next.
    pub condition_spacing: u64,
    /// Counter value at the first sample (near 2³² so that it wraps).
    pub counter_start: u64,
    /// Width of the counter, bits.
    pub counter_bits: u32,
    /// Seed of the noise.
    pub seed: u64,
}

impl SessionSpec {
    /// Gaitan & Geist's (2022) 10 mHz run through the Feather's pipeline: 262.5 s per condition of the
    /// sensor at 104 Hz (16 Hz streamed: 4200 samples), 1 MHz counter wrapping in the
    /// first condition.
    pub const PAPER: SessionSpec = SessionSpec {
        rate_uhz: 10_000,
        sensor_odr_mhz: 104_000,
        sensor_samples: 27_300,
        condition_spacing: 300_000_000,
        counter_start: 0xFFFF_0000,
        counter_bits: 32,
        seed: 0x5E55_1017,
    };

    /// The sensor stream of one condition: synthetic counts at the sensor's rate.
    pub fn sensor(&self, condition: Condition) -> Option<Synth> {
        let clock = TickRate::MHZ_1;
        let axis = condition.index();
        Some(Synth::new(SynthSpec {
            coef: crosscheck::coefficients(axis),
            noise_sigma: crosscheck::noise_sigma(self.sensor_odr_mhz),
            step: PhaseStep::from_micro_hz(u64::from(self.rate_uhz), clock)?,
            clock,
            sample_rate_mhz: self.sensor_odr_mhz,
            n_samples: self.sensor_samples,
            drop_per_million: 0,
            seed: self.seed.wrapping_add(axis as u64),
        }))
    }

    /// Run the session through `device`, handing every packet it sends to `out`:
    /// for x, y, z: Start, the sensor's samples (with a poll after each), Stop.
    pub fn run<const N: usize>(&self, device: &mut Device<N>, out: &mut impl FnMut(Packet)) {
        let mask = if self.counter_bits >= 64 {
            u64::MAX
        } else {
            (1u64 << self.counter_bits) - 1
        };
        for (i, cond) in Condition::ALL.into_iter().enumerate() {
            device.on_command(
                Command::Start {
                    condition: cond,
                    rate_uhz: self.rate_uhz,
                },
                out,
            );
            let base = self
                .counter_start
                .wrapping_add(self.condition_spacing.wrapping_mul(i as u64));
            if let Some(sensor) = self.sensor(cond) {
                for s in sensor {
                    let capture = base.wrapping_add(s.t.0) & mask;
                    device.on_sample(capture, s.counts, false, out);
                    device.poll(capture, out);
                }
            }
            device.on_command(Command::Stop, out);
        }
    }
}
