//! From captured data-ready edges to the sample stream: 64-bit timestamps, averaging of
//! the sensor's conversions into the sample rate's slots, sequence numbers, flags.
//!
//! The LSM6DS33 has no 16 Hz output rate (method.md §7), so the sensor converts at a
//! native rate (104 Hz) behind its anti-alias filter, and each streamed sample is the sum
//! of every conversion whose data-ready edge falls in its slot of the sample-rate grid
//! (6 or 7 at 104 Hz into 16 Hz), with the instants of those conversions
//! ([`Aperture`]). The sum is exact in integers; the host divides by the count. Its
//! expected value is the model summed over those instants, which the device's fit and
//! the host's fits rebuild from the same ticks (docs/protocol.md), so the averaging costs
//! no accuracy at any rotation rate and every conversion's noise is averaged.

use super::Config;
use crate::packet::{CommandError, SampleFlags};
use crate::time::{Aperture, TickExtender, Ticks, MAX_CONVERSIONS};

/// A sample of the stream: the sum of the conversions in one slot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StreamSample {
    /// Sequence number: consecutive over every sample streamed since power-up.
    pub seq: u32,
    /// The instants of the conversions summed (data-ready edges).
    pub aperture: Aperture,
    /// Sums of the raw counts u, v, w over those conversions.
    pub sums: [i32; 3],
    /// [`SampleFlags`] bits: set when any of the conversions has it.
    pub flags: u8,
}

impl StreamSample {
    /// Time of the first conversion.
    pub fn t(&self) -> Ticks {
        self.aperture.first()
    }
}

/// The slot being filled.
#[derive(Clone, Copy, Debug)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct Open {
    aperture: Aperture,
    sums: [i32; 3],
    flags: u8,
    /// End of the slot, ticks × 1000.
    end_milli: u64,
}

/// See the module documentation.
#[derive(Clone, Copy, Debug)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Sampler {
    clock_hz: u64,
    extender: TickExtender,
    sample_rate_mhz: u32,
    /// Slot length, ticks × 1000 (to keep mHz rates exact).
    period_milli: u64,
    open: Option<Open>,
    /// End of the last slot closed, ticks × 1000: the next slot starts there unless the
    /// stream paused.
    last_end_milli: Option<u64>,
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
            open: None,
            last_end_milli: None,
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

    /// Samples streamed since power-up (the next sequence number).
    pub fn streamed(&self) -> u32 {
        self.next_seq
    }

    /// The streamed sample rate, mHz.
    pub fn sample_rate_mhz(&self) -> u32 {
        self.sample_rate_mhz
    }

    /// Change the sample rate: positive, at most the sensor's rate, and high enough that
    /// a slot holds at most [`MAX_CONVERSIONS`] conversions (at 104 Hz: ≥ 14.86 Hz).
    pub fn set_sample_rate(&mut self, mhz: u32, sensor_odr_mhz: u32) -> Result<(), CommandError> {
        if mhz == 0 || sensor_odr_mhz == 0 || mhz > sensor_odr_mhz {
            return Err(CommandError::BadRate);
        }
        if u64::from(sensor_odr_mhz) > MAX_CONVERSIONS as u64 * u64::from(mhz) {
            return Err(CommandError::BadRate);
        }
        // ticks per sample × 1000 = clock_hz · 10⁶ / mHz.
        self.period_milli = self.clock_hz * 1_000_000 / u64::from(mhz);
        self.sample_rate_mhz = mhz;
        self.discard();
        Ok(())
    }

    /// Forget the slot being filled (at stop: its conversions are not streamed, and no
    /// sequence number is spent on them) and restart the grid at the next conversion.
    pub fn discard(&mut self) {
        self.open = None;
        self.last_end_milli = None;
    }

    /// The 64-bit time of a raw counter value read now (for timeouts); it also keeps the
    /// extension going through wraps when no sample arrives.
    pub fn peek_time(&mut self, raw: u64) -> Ticks {
        self.extender.extend(raw)
    }

    /// A sensor conversion. It joins the open slot if its edge falls in it; otherwise it
    /// closes that slot, which is returned as a stream sample, and opens the next. While
    /// not `streaming` nothing is kept (sequence numbers advance only for streamed
    /// samples, so the host sees a gap only where a sample was lost).
    pub fn accept(
        &mut self,
        capture: u64,
        counts: [i16; 3],
        late: bool,
        streaming: bool,
    ) -> Option<StreamSample> {
        let t = self.extender.extend(capture);
        if !streaming {
            self.discard();
            return None;
        }
        let mut flags = 0;
        if counts.iter().any(|c| *c == i16::MIN || *c == i16::MAX) {
            flags |= SampleFlags::CLIPPED;
        }
        if late {
            flags |= SampleFlags::LATE_TIMESTAMP;
        }
        let t_milli = t.0.saturating_mul(1000);
        if let Some(o) = &mut self.open {
            if t_milli < o.end_milli {
                let gap = t
                    .since(o.aperture.last())
                    .and_then(|d| u16::try_from(d).ok());
                if let Some(Ok(())) = gap.map(|g| o.aperture.push_gap(g)) {
                    for (s, c) in o.sums.iter_mut().zip(counts) {
                        *s = s.saturating_add(i32::from(c));
                    }
                    o.flags |= flags;
                    return None;
                }
            }
        }
        // A new slot: the next of the grid, or, after a pause (or a conversion the open
        // slot could not take), a grid restarted here.
        let closed = self.open.take();
        let start = match closed.map(|o| o.end_milli).or(self.last_end_milli) {
            Some(end) if t_milli >= end && t_milli < end.saturating_add(self.period_milli) => end,
            _ => t_milli,
        };
        self.open = Some(Open {
            aperture: Aperture::point(t),
            sums: counts.map(i32::from),
            flags,
            end_milli: start.saturating_add(self.period_milli),
        });
        let o = closed?;
        self.last_end_milli = Some(o.end_milli);
        let seq = self.next_seq;
        self.next_seq = self.next_seq.wrapping_add(1);
        Some(StreamSample {
            seq,
            aperture: o.aperture,
            sums: o.sums,
            flags: o.flags,
        })
    }
}
