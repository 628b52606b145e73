//! The most recent streamed samples, so that after a disconnect the host can fetch what it
//! missed by sequence number (`Command::Backfill`).
//!
//! RAM is what limits how long an outage the device bridges, so entries are packed: 28
//! bytes instead of the 48 of a [`StreamSample`] and its condition. Sequence numbers are
//! consecutive in the ring (only the newest is kept); a sample's first instant is kept as
//! its low 32 bits, with the oldest entry's full time as the base, so the ring never spans
//! 2³² ticks (71 minutes at 1 MHz: older entries are dropped); the sums, at most
//! [`MAX_CONVERSIONS`] × 2¹⁵ in size, fit 24 bits.

use super::packetiser::Packetiser;
use super::sampler::StreamSample;
use crate::packet::{CommandError, Packet};
use crate::time::{Aperture, Ticks, MAX_CONVERSIONS};
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

/// An entry as held: see the module documentation.
#[derive(Clone, Copy, Debug, Default)]
struct Packed {
    first_lo: u32,
    gaps: [u16; MAX_CONVERSIONS - 1],
    sums: [[u8; 3]; 3],
    len: u8,
    flags: u8,
    condition: u8,
}

/// Range of a 24-bit two's-complement sum.
const SUM_MIN: i32 = -(1 << 23);
const SUM_MAX: i32 = (1 << 23) - 1;

impl Packed {
    /// `None` for a sum beyond 24 bits, which no aperture of [`MAX_CONVERSIONS`] 16-bit
    /// conversions makes.
    fn of(e: &Entry) -> Option<Self> {
        let mut sums = [[0u8; 3]; 3];
        for (p, s) in sums.iter_mut().zip(e.sample.sums) {
            if !(SUM_MIN..=SUM_MAX).contains(&s) {
                return None;
            }
            let [b0, b1, b2, _] = s.to_le_bytes();
            *p = [b0, b1, b2];
        }
        let mut gaps = [0u16; MAX_CONVERSIONS - 1];
        for (g, v) in gaps.iter_mut().zip(e.sample.aperture.gaps()) {
            *g = *v;
        }
        Some(Packed {
            first_lo: e.sample.aperture.first().0 as u32,
            gaps,
            sums,
            len: e.sample.aperture.len() as u8,
            flags: e.sample.flags,
            condition: e.condition.index() as u8,
        })
    }

    /// The first instant, given a full time `base` no later than it and less than 2³²
    /// ticks before it.
    fn first(&self, base: Ticks) -> Ticks {
        let d = self.first_lo.wrapping_sub(base.0 as u32);
        Ticks(base.0.wrapping_add(u64::from(d)))
    }

    fn unpack(&self, seq: u32, base: Ticks) -> Option<Entry> {
        let gaps = self.gaps.get(..usize::from(self.len).saturating_sub(1))?;
        let aperture = Aperture::new(self.first(base), gaps)?;
        // Sign-extend the 24-bit sums.
        let sums = self
            .sums
            .map(|[b0, b1, b2]| i32::from_le_bytes([0, b0, b1, b2]) >> 8);
        Some(Entry {
            sample: StreamSample {
                seq,
                aperture,
                sums,
                flags: self.flags,
            },
            condition: *Condition::ALL.get(usize::from(self.condition))?,
        })
    }
}

/// A ring of the last `N` samples.
#[derive(Clone, Debug)]
pub struct Ring<const N: usize> {
    buf: [Packed; N],
    /// Index the next entry goes to.
    head: usize,
    len: usize,
    /// Sequence number of the newest entry.
    newest_seq: u32,
    /// Full first instant of the oldest entry.
    base: Ticks,
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
            buf: [Packed {
                first_lo: 0,
                gaps: [0; MAX_CONVERSIONS - 1],
                sums: [[0; 3]; 3],
                len: 0,
                flags: 0,
                condition: 0,
            }; N],
            head: 0,
            len: 0,
            newest_seq: 0,
            base: Ticks(0),
        }
    }

    /// Number of samples held.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when nothing is held.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    fn slot(&self, i: usize) -> Option<&Packed> {
        let start = (self.head + N - self.len) % N.max(1);
        self.buf.get((start + i) % N.max(1))
    }

    fn drop_oldest(&mut self) {
        self.len = self.len.saturating_sub(1);
        if let Some(next) = self.slot(0) {
            self.base = next.first(self.base);
        }
    }

    /// Store a sample, dropping the oldest when full. A sample that does not follow the
    /// newest (its seq is not the next, or its time went backwards after a counter fault)
    /// starts the ring afresh, as does one that cannot be packed.
    pub fn push(&mut self, e: Entry) {
        let Some(p) = Packed::of(&e) else {
            self.len = 0;
            return;
        };
        let t = e.sample.t();
        let follows = self
            .newest()
            .is_some_and(|n| n.sample.seq.wrapping_add(1) == e.sample.seq && n.sample.t() <= t);
        if !follows {
            self.len = 0;
        }
        if self.len == N {
            self.drop_oldest();
        }
        while self.len > 0 && t.0.saturating_sub(self.base.0) > u64::from(u32::MAX) {
            self.drop_oldest();
        }
        if self.len == 0 {
            self.base = t;
        }
        if let Some(slot) = self.buf.get_mut(self.head) {
            *slot = p;
            self.head = (self.head + 1) % N.max(1);
            self.len = (self.len + 1).min(N);
            self.newest_seq = e.sample.seq;
        }
    }

    /// The newest entry.
    fn newest(&self) -> Option<Entry> {
        self.slot(self.len.checked_sub(1)?)?
            .unpack(self.newest_seq, self.base)
    }

    /// Entries oldest first.
    pub fn iter(&self) -> impl Iterator<Item = Entry> + '_ {
        self.iter_skip(0)
    }

    /// Entries oldest first, less the `skip` oldest (only those are unpacked).
    fn iter_skip(&self, skip: usize) -> impl Iterator<Item = Entry> + '_ {
        let first_seq = self
            .newest_seq
            .wrapping_sub((self.len as u32).wrapping_sub(1));
        (skip.min(self.len)..self.len).filter_map(move |i| {
            self.slot(i)?
                .unpack(first_seq.wrapping_add(i as u32), self.base)
        })
    }

    /// Oldest and newest sequence numbers held (0, 0 when empty).
    pub fn span(&self) -> (u32, u32) {
        if self.len == 0 {
            return (0, 0);
        }
        let first = self
            .newest_seq
            .wrapping_sub((self.len as u32).wrapping_sub(1));
        (first, self.newest_seq)
    }

    /// A replay of samples `from_seq ..` (at most `count`), sent by [`Replay::send`] as the
    /// link has room; and whether the ring still holds the first wanted sample (refused
    /// with `NotInRing` if not; what is still held is sent all the same). Batches hold at most `batch` samples.
    pub fn replay(
        &self,
        from_seq: u32,
        count: u16,
        batch: usize,
    ) -> (Replay, Result<(), CommandError>) {
        let replay = Replay {
            next: from_seq,
            end: from_seq.wrapping_add(u32::from(count)),
            batches: Packetiser::new(true, batch),
        };
        let (oldest, newest) = self.span();
        let held = self.len > 0 && from_seq.wrapping_sub(oldest) <= newest.wrapping_sub(oldest);
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
    /// Batches of at most `max` samples from now on (the link's MTU changed).
    pub fn set_max(&mut self, max: usize, out: &mut impl FnMut(Packet)) {
        self.batches.set_max(max, out);
    }

    /// Send at most `room` packets of the replay; true once it is all sent.
    pub fn send<const N: usize>(
        &mut self,
        ring: &Ring<N>,
        mut room: usize,
        out: &mut impl FnMut(Packet),
    ) -> bool {
        let (start, end) = (self.next, self.end);
        let wanted = |seq: u32| seq.wrapping_sub(start) < end.wrapping_sub(start);
        // Seqs are consecutive in the ring: start at the first wanted one rather than
        // unpacking the whole ring at every pump of a replay.
        let oldest = ring.span().0;
        let skip = if wanted(oldest) {
            0
        } else {
            usize::try_from(start.wrapping_sub(oldest)).unwrap_or(usize::MAX)
        };
        let mut pending = ring.iter_skip(skip).filter(|e| wanted(e.sample.seq));
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
