//! Streamed samples into [`AverageBatch`]es: a batch holds consecutive samples of one
//! condition, and goes out when full, when the next sample can't join it, or when it
//! has waited long enough.

use super::sampler::StreamSample;
use crate::packet::{AverageBatch, Packet};
use crate::time::Ticks;
use crate::Condition;

/// See the module documentation.
#[derive(Clone, Copy, Debug)]
pub struct Packetiser {
    replay: bool,
    batch: Option<AverageBatch>,
}

impl Packetiser {
    /// Live batches, or replay batches (flagged as such) for backfill.
    pub const fn new(replay: bool) -> Self {
        Packetiser {
            replay,
            batch: None,
        }
    }

    /// Add a sample, sending the batch it closes.
    pub fn push(&mut self, s: &StreamSample, condition: Condition, out: &mut impl FnMut(Packet)) {
        if let Some(b) = &mut self.batch {
            let next_seq = b.first_seq.wrapping_add(b.len() as u32);
            let joins = b.condition == condition
                && next_seq == s.seq
                && b.push(&s.aperture, s.sums, s.flags).is_ok();
            if joins {
                if b.is_full() {
                    self.flush(out);
                }
                return;
            }
            self.flush(out);
        }
        let mut b = AverageBatch::new(condition, self.replay, s.seq, s.t().0);
        // A fresh batch always takes its first sample (dt = 0).
        let _ = b.push(&s.aperture, s.sums, s.flags);
        self.batch = Some(b);
    }

    /// Send the part-filled batch, if any.
    pub fn flush(&mut self, out: &mut impl FnMut(Packet)) {
        if let Some(b) = self.batch.take() {
            if !b.is_empty() {
                out(Packet::Averages(b));
            }
        }
    }

    /// Send the batch if its first sample is older than `max_age` ticks at `now`.
    pub fn flush_if_older(&mut self, now: Ticks, max_age: u64, out: &mut impl FnMut(Packet)) {
        if let Some(b) = &self.batch {
            if now.0.saturating_sub(b.t0) >= max_age {
                self.flush(out);
            }
        }
    }
}
