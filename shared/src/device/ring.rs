//! The most recent streamed samples, so that after a short disconnect the host can fetch
//! what it missed by sequence number (`Command::Backfill`).

use super::packetiser::Packetiser;
use super::sampler::StreamSample;
use crate::packet::{CommandError, Packet};
use crate::Condition;

/// One stored sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Entry {
    /// The sample.
    pub sample: StreamSample,
    /// The condition it was taken in.
    pub condition: Condition,
}

/// A ring of the last `N` samples.
#[derive(Clone, Debug)]
pub struct Ring<const N: usize> {
    buf: [Option<Entry>; N],
    /// Index the next entry goes to.
    head: usize,
    len: usize,
}

impl<const N: usize> Default for Ring<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> Ring<N> {
    /// Empty.
    pub const fn new() -> Self {
        Ring {
            buf: [None; N],
            head: 0,
            len: 0,
        }
    }

    /// Store a sample, dropping the oldest when full.
    pub fn push(&mut self, e: Entry) {
        if let Some(slot) = self.buf.get_mut(self.head) {
            *slot = Some(e);
            self.head = (self.head + 1) % N.max(1);
            self.len = (self.len + 1).min(N);
        }
    }

    /// Entries oldest first.
    pub fn iter(&self) -> impl Iterator<Item = &Entry> + '_ {
        let start = (self.head + N - self.len) % N.max(1);
        (0..self.len).filter_map(move |i| self.buf.get((start + i) % N.max(1))?.as_ref())
    }

    /// Oldest and newest sequence numbers held (0, 0 when empty).
    pub fn span(&self) -> (u32, u32) {
        let mut it = self.iter();
        let first = it.next().map_or(0, |e| e.sample.seq);
        let last = self.iter().last().map_or(first, |e| e.sample.seq);
        (first, last)
    }

    /// A replay of samples `from_seq ..` (at most `count`), sent by [`Replay::send`] as the
    /// link has room; and whether the ring still holds the first wanted sample (refused
    /// with `NotInRing` if not; what is still held is sent all the same).
    pub fn replay(&self, from_seq: u32, count: u16) -> (Replay, Result<(), CommandError>) {
        let replay = Replay {
            next: from_seq,
            end: from_seq.wrapping_add(u32::from(count)),
            batches: Packetiser::new(true),
        };
        let held = self.iter().any(|e| e.sample.seq == from_seq);
        let result = if held || count == 0 {
            Ok(())
        } else {
            Err(CommandError::NotInRing)
        };
        (replay, result)
    }
}

/// A backfill being sent, batch by batch: the samples still to go are those from `next`
/// up to `end` that the ring holds when their turn comes.
#[derive(Clone, Copy, Debug)]
pub struct Replay {
    next: u32,
    end: u32,
    batches: Packetiser,
}

impl Replay {
    /// Send at most `room` packets of the replay; true once it is all sent.
    pub fn send<const N: usize>(
        &mut self,
        ring: &Ring<N>,
        mut room: usize,
        out: &mut impl FnMut(Packet),
    ) -> bool {
        let (start, end) = (self.next, self.end);
        let wanted = |seq: u32| seq.wrapping_sub(start) < end.wrapping_sub(start);
        let mut pending = ring.iter().filter(|e| wanted(e.sample.seq));
        while room > 0 {
            let mut sent = 0usize;
            let mut count = |p: Packet| {
                sent += 1;
                out(p);
            };
            // Each sample closes at most one batch, so this never sends beyond the room.
            match pending.next() {
                Some(e) => {
                    self.batches.push(&e.sample, e.condition, &mut count);
                    self.next = e.sample.seq.wrapping_add(1);
                }
                None => {
                    self.batches.flush(&mut count);
                    self.next = self.end;
                    return true;
                }
            }
            room = room.saturating_sub(sent);
        }
        false
    }
}
