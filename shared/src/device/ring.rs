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

    /// Send samples `from_seq ..` (at most `count`) again as replay batches. Refused with
    /// `NotInRing` when the first wanted sample has left the ring (what is still held is
    /// sent all the same).
    pub fn replay(
        &self,
        from_seq: u32,
        count: u16,
        out: &mut impl FnMut(Packet),
    ) -> Result<(), CommandError> {
        let end = from_seq.wrapping_add(u32::from(count));
        let wanted = |seq: u32| seq.wrapping_sub(from_seq) < end.wrapping_sub(from_seq);
        let mut p = Packetiser::new(true);
        let mut first_sent = None;
        for e in self.iter().filter(|e| wanted(e.sample.seq)) {
            first_sent.get_or_insert(e.sample.seq);
            p.push(&e.sample, e.condition, out);
        }
        p.flush(out);
        match first_sent {
            Some(s) if s == from_seq => Ok(()),
            _ if count == 0 => Ok(()),
            _ => Err(CommandError::NotInRing),
        }
    }
}
