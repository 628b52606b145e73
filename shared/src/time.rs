//! Device time: integer ticks of a known clock, extended to 64 bits.
//!
//! Timestamps stay integers end to end, so host and device agree on them exactly and the
//! rotation phase can be computed without rounding (see [`crate::phase`]).

/// A point in device time, in ticks of a [`TickRate`] clock, counted from device start.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Ticks(pub u64);

impl Ticks {
    /// Ticks elapsed from `earlier` to `self`, or `None` if `earlier` is later.
    pub fn since(self, earlier: Ticks) -> Option<u64> {
        self.0.checked_sub(earlier.0)
    }
}

/// Frequency of the tick clock, in hertz (never zero).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TickRate(u32);

impl TickRate {
    /// The nRF52840's TIMER at 1 MHz, clocked from the 32 MHz crystal.
    pub const MHZ_1: TickRate = TickRate(1_000_000);
    /// The nRF52840's RTC at 32 768 Hz (on the Feather Sense: the RC oscillator).
    pub const RTC_32K: TickRate = TickRate(32_768);

    /// A clock of `hz` ticks per second; `None` for 0.
    pub const fn new(hz: u32) -> Option<TickRate> {
        if hz == 0 {
            None
        } else {
            Some(TickRate(hz))
        }
    }

    /// Ticks per second.
    pub const fn hz(self) -> u32 {
        self.0
    }
}

/// Extends a free-running counter of `bits` bits (24 for the RTC, 32 for a TIMER) to
/// 64-bit [`Ticks`]. It must see every wrap: read it at least once per wrap period
/// (512 s for the 24-bit RTC at 32 768 Hz, 71 min for a 32-bit TIMER at 1 MHz).
#[derive(Clone, Copy, Debug)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TickExtender {
    mask: u64,
    last: u64,
}

impl TickExtender {
    /// For a counter of `bits` bits (1 to 64; larger values are taken as 64).
    pub const fn new(bits: u32) -> TickExtender {
        let mask = if bits >= 64 {
            u64::MAX
        } else {
            (1u64 << bits) - 1
        };
        TickExtender { mask, last: 0 }
    }

    /// The 64-bit time of a raw counter reading taken no earlier than the previous one.
    pub fn extend(&mut self, raw: u64) -> Ticks {
        let delta = raw.wrapping_sub(self.last) & self.mask;
        self.last = self.last.wrapping_add(delta);
        Ticks(self.last)
    }
}
