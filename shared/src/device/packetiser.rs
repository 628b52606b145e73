//! Streamed samples into [`AverageBatch`]es: a batch holds consecutive samples of one
//! condition, and goes out when full, when the next sample can't join it, or when it
//! has waited long enough.

use super::sampler::StreamSample;
use crate::packet::{AverageBatch, Packet, MAX_AVERAGES};
use crate::time::Ticks;
use crate::Condition;

/// See the module documentation.
#[derive(Clone, Copy, Debug)]
pub struct Packetiser {
    replay: bool,
    /// Samples per batch, 1 to [`MAX_AVERAGES`]: what one notification carries.
    max: usize,
    batch: Option<AverageBatch>,
}

impl Packetiser {
    /// Live batches, or replay batches (flagged as such) for backfill, of at most `max`
    /// samples (1 to [`MAX_AVERAGES`]; [`super::route::batch_len`]).
    pub const fn new(replay: bool, max: usize) -> Self {
        Packetiser {
            replay,
            max: clamp_len(max),
            batch: None,
        }
    }

    /// Change the batch length (the link's MTU changed): a part-filled batch longer than
    /// the new length is split, and what fills a batch is sent.
    pub fn set_max(&mut self, max: usize, out: &mut impl FnMut(Packet)) {
        self.max = clamp_len(max);
        let Some(b) = self.batch else {
            return;
        };
        if b.len() <= self.max {
            return;
        }
        self.batch = None;
        for (seq, aperture, a) in b.iter() {
            let s = StreamSample {
                seq,
                aperture,
                sums: a.sums,
                flags: a.flags,
            };
            self.push(&s, b.condition, out);
        }
    }

    /// Add a sample, sending the batch it closes.
    pub fn push(&mut self, s: &StreamSample, condition: Condition, out: &mut impl FnMut(Packet)) {
        if let Some(b) = &mut self.batch {
            let next_seq = b.first_seq.wrapping_add(b.len() as u32);
            let joins = b.condition == condition
                && next_seq == s.seq
                && b.len() < self.max
                && b.push(&s.aperture, s.sums, s.flags).is_ok();
            if joins {
                if b.len() >= self.max {
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
        if self.max == 1 {
            self.flush(out);
        }
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

const fn clamp_len(n: usize) -> usize {
    if n == 0 {
        1
    } else if n > MAX_AVERAGES {
        MAX_AVERAGES
    } else {
        n
    }
}
