//! From captured data-ready edges to the sample stream: 64-bit timestamps, averaging of
//! the sensor's conversions into the sample rate's slots, sequence numbers, flags.
//!
//! The LSM6DS33 has no 16 Hz output rate (docs/method.md §7), so the sensor converts at a
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

/// A sensor conversion as the firmware read it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Conversion {
    /// Raw counter value at its data-ready edge (the read time when `late`).
    pub capture: u64,
    /// Raw counts u, v, w.
    pub counts: [i16; 3],
    /// The timestamp may not be this conversion's: its edge was not captured, or another
    /// edge came while it was being read.
    pub late: bool,
    /// Data-ready edges counted in hardware up to this one (a TIMER in counter mode on a
    /// PPI fork of the edge), when the board counts them.
    pub edges: Option<u32>,
}

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
    /// [`SampleFlags`], the missed conversions among them.
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
    /// The sensor's conversion period, ticks × 1000: nominal at first, then measured from
    /// the gaps between consecutive conversions (its oscillator is good to a few %).
    conversion_milli: u64,
    /// The previous conversion streamed: its time and its hardware edge count.
    previous: Option<(Ticks, Option<u32>)>,
}

/// Conversions the sensor made between two that were read: from the hardware edge count
/// when there is one, and from the time between them (`gap_milli`, ticks × 1000) over the
/// conversion period, rounded, whichever is larger (a latched data-ready line gives one
/// edge per read, so its count cannot see what was skipped; the time can). The instants
/// are the conversions' own, or estimated to well within half a period
/// ([`super::pairing`]).
pub fn missed_between(gap_milli: u64, conversion_milli: u64, edges: Option<(u32, u32)>) -> u32 {
    let p = conversion_milli.max(1);
    let periods = (gap_milli + p / 2) / p;
    let by_time = u32::try_from(periods.saturating_sub(1)).unwrap_or(u32::MAX);
    // A count that ran backwards or jumped by more than a minute of conversions is a
    // fault of the counter, not conversions: the time decides.
    let by_count = edges
        .map(|(now, before)| now.wrapping_sub(before).saturating_sub(1))
        .filter(|n| *n < 1 << 16)
        .unwrap_or(0);
    by_time.max(by_count)
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
            conversion_milli: cfg.conversion_milli(),
            previous: None,
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
        self.previous = None;
    }

    /// The 64-bit time of a raw counter value read now (for timeouts); it also keeps the
    /// extension going through wraps when no sample arrives.
    pub fn peek_time(&mut self, raw: u64) -> Ticks {
        self.extender.extend(raw)
    }

    /// A sensor conversion. It joins the open slot if its edge falls in it; otherwise it
    /// closes that slot, which is returned as a stream sample, and opens the next. While
    /// not `streaming` nothing is kept (sequence numbers advance only for streamed
    /// samples, so the host sees a gap only where a sample was lost). Also returned: the
    /// conversions the sensor made since the previous one that were not read
    /// ([`missed_between`]); each is counted in the flags of the sample whose slot it
    /// fell in (one in a slot that no read conversion opened is counted only here).
    pub fn accept(&mut self, c: &Conversion, streaming: bool) -> (Option<StreamSample>, u32) {
        let t = self.extender.extend(c.capture);
        if !streaming {
            self.discard();
            return (None, 0);
        }
        let mut flags = 0;
        if c.counts.iter().any(|v| *v == i16::MIN || *v == i16::MAX) {
            flags |= SampleFlags::CLIPPED;
        }
        if c.late {
            flags |= SampleFlags::LATE_TIMESTAMP;
        }
        let t_milli = t.0.saturating_mul(1000);
        // Conversions skipped since the previous one, at evenly spaced instants between.
        let (missed, previous_milli) = match self.previous {
            Some((tp, ep)) if tp <= t => {
                let gap = (t.0 - tp.0).saturating_mul(1000);
                let n = missed_between(gap, self.conversion_milli, c.edges.zip(ep));
                if n == 0 && !c.late && gap < self.conversion_milli.saturating_mul(3) / 2 {
                    // One period: the measured conversion period follows it (1/16).
                    self.conversion_milli =
                        self.conversion_milli - self.conversion_milli / 16 + gap / 16;
                }
                (n, tp.0.saturating_mul(1000))
            }
            _ => (0, t_milli),
        };
        self.previous = Some((t, c.edges));
        let missed_at = |j: u32| {
            let span = t_milli.saturating_sub(previous_milli);
            previous_milli + span * u64::from(j) / (u64::from(missed) + 1)
        };
        if let Some(o) = &mut self.open {
            if t_milli < o.end_milli {
                let gap = t
                    .since(o.aperture.last())
                    .and_then(|d| u16::try_from(d).ok());
                if let Some(Ok(())) = gap.map(|g| o.aperture.push_gap(g)) {
                    for (s, v) in o.sums.iter_mut().zip(c.counts) {
                        *s = s.saturating_add(i32::from(v));
                    }
                    // Every skipped conversion was before this one, so in this slot.
                    let m = SampleFlags::missed(o.flags).saturating_add(clamp_u8(missed));
                    o.flags = SampleFlags::with_missed(o.flags | flags, m);
                    return (None, missed);
                }
            }
        }
        // A new slot: the next of the grid, or, after a pause (or a conversion the open
        // slot could not take), a grid restarted here.
        let mut closed = self.open.take();
        let start = match closed.map(|o| o.end_milli).or(self.last_end_milli) {
            Some(end) if t_milli >= end && t_milli < end.saturating_add(self.period_milli) => end,
            _ => t_milli,
        };
        let (mut in_closed, mut in_new) = (0u32, 0u32);
        for j in 1..=missed {
            let tj = missed_at(j);
            match &closed {
                Some(o) if tj < o.end_milli => in_closed += 1,
                _ if tj >= start => in_new += 1,
                _ => {}
            }
        }
        if let Some(o) = &mut closed {
            let m = SampleFlags::missed(o.flags).saturating_add(clamp_u8(in_closed));
            o.flags = SampleFlags::with_missed(o.flags, m);
        }
        self.open = Some(Open {
            aperture: Aperture::point(t),
            sums: c.counts.map(i32::from),
            flags: SampleFlags::with_missed(flags, clamp_u8(in_new)),
            end_milli: start.saturating_add(self.period_milli),
        });
        let Some(o) = closed else {
            return (None, missed);
        };
        self.last_end_milli = Some(o.end_milli);
        let seq = self.next_seq;
        self.next_seq = self.next_seq.wrapping_add(1);
        let sample = StreamSample {
            seq,
            aperture: o.aperture,
            sums: o.sums,
            flags: o.flags,
        };
        (Some(sample), missed)
    }
}

fn clamp_u8(n: u32) -> u8 {
    u8::try_from(n).unwrap_or(u8::MAX)
}
