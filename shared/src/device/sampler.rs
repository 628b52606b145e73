//! From captured data-ready edges to the sample stream: 64-bit timestamps, decimation
//! from the sensor's output rate to the sample rate, sequence numbers, flags.
//!
//! The LSM6DS33 has no 16 Hz output rate (method.md §7), so the sensor runs at a native
//! rate with its anti-alias filter and this keeps, for each point of a grid at the sample
//! rate, the sample whose edge is nearest it (within half a sensor period). Each kept
//! sample carries its own conversion time, so the stream is not exactly uniform, and the
//! fit doesn't need it to be.

use super::Config;
use crate::packet::{CommandError, SampleFlags};
use crate::time::{TickExtender, Ticks};

/// A sample of the stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StreamSample {
    /// Sequence number: consecutive over every sample streamed since power-up.
    pub seq: u32,
    /// Time of the data-ready edge.
    pub t: Ticks,
    /// Raw counts u, v, w.
    pub counts: [i16; 3],
    /// [`SampleFlags`] bits.
    pub flags: u8,
}

/// See the module documentation.
#[derive(Clone, Copy, Debug)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Sampler {
    clock_hz: u64,
    extender: TickExtender,
    sample_rate_mhz: u32,
    /// Grid period and half a sensor period, in ticks × 1000 (to keep mHz rates exact).
    period_milli: u64,
    half_sensor_milli: u64,
    /// The next grid point, ticks × 1000; `None` until the first sample.
    next_due_milli: Option<u64>,
    next_seq: u32,
}

impl Sampler {
    /// For `cfg`'s clock and rates.
    pub fn new(cfg: &Config) -> Self {
        let clock_hz = u64::from(cfg.clock.hz());
        let mut s = Sampler {
            clock_hz,
            extender: TickExtender::new(cfg.counter_bits),
            sample_rate_mhz: 0,
            period_milli: 0,
            half_sensor_milli: 0,
            next_due_milli: None,
            next_seq: 0,
        };
        if s.set_sample_rate(cfg.sample_rate_mhz, cfg.sensor_odr_mhz)
            .is_err()
        {
            // An unusable configured rate falls back to the sensor's own rate.
            let _ = s.set_sample_rate(cfg.sensor_odr_mhz, cfg.sensor_odr_mhz);
        }
        s
    }

    /// The streamed sample rate, mHz.
    pub fn sample_rate_mhz(&self) -> u32 {
        self.sample_rate_mhz
    }

    /// Change the sample rate (must be positive and at most the sensor's rate).
    pub fn set_sample_rate(&mut self, mhz: u32, sensor_odr_mhz: u32) -> Result<(), CommandError> {
        if mhz == 0 || sensor_odr_mhz == 0 || mhz > sensor_odr_mhz {
            return Err(CommandError::BadRate);
        }
        // ticks per sample × 1000 = clock_hz · 10⁶ / mHz.
        self.period_milli = self.clock_hz * 1_000_000 / u64::from(mhz);
        self.half_sensor_milli = self.clock_hz * 1_000_000 / u64::from(sensor_odr_mhz) / 2;
        self.sample_rate_mhz = mhz;
        self.next_due_milli = None;
        Ok(())
    }

    /// The 64-bit time of a raw counter value read now (for timeouts); it also keeps the
    /// extension going through wraps when no sample arrives.
    pub fn peek_time(&mut self, raw: u64) -> Ticks {
        self.extender.extend(raw)
    }

    /// A sensor sample; returns it as a stream sample if it is the one nearest the next
    /// grid point and `streaming` is on (sequence numbers advance only for streamed
    /// samples, so the host sees a gap only where a sample was lost).
    pub fn accept(
        &mut self,
        capture: u64,
        counts: [i16; 3],
        late: bool,
        streaming: bool,
    ) -> Option<StreamSample> {
        let t = self.extender.extend(capture);
        let t_milli = t.0.saturating_mul(1000);
        let due = *self.next_due_milli.get_or_insert(t_milli);
        if t_milli.saturating_add(self.half_sensor_milli) < due {
            return None;
        }
        // Next grid point; after a pause (idle, or edges missing) restart from here
        // rather than emit a burst to catch up.
        let mut next = due.saturating_add(self.period_milli);
        if next <= t_milli {
            next = t_milli.saturating_add(self.period_milli);
        }
        self.next_due_milli = Some(next);
        if !streaming {
            return None;
        }
        let mut flags = 0;
        if counts.iter().any(|c| *c == i16::MIN || *c == i16::MAX) {
            flags |= SampleFlags::CLIPPED;
        }
        if late {
            flags |= SampleFlags::LATE_TIMESTAMP;
        }
        let seq = self.next_seq;
        self.next_seq = self.next_seq.wrapping_add(1);
        Some(StreamSample {
            seq,
            t,
            counts,
            flags,
        })
    }
}
