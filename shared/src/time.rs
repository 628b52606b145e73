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

/// Most sensor conversions one streamed sample averages. A 16 Hz slot holds 6 or 7 of the
/// sensor's 104 Hz conversions, and 7 still holds every one with the sensor's clock up to
/// 7 % fast; the sampler refuses sample rates whose slots could hold more.
pub const MAX_CONVERSIONS: usize = 7;

/// The instants of the conversions a streamed sample averages: the first one's tick and
/// the ticks from each to the next (each at least 1). A plain sample is an aperture of one.
///
/// The expected value of an average is the average of the model over these instants, so
/// the fit's regressors are rebuilt from them exactly (method: docs/protocol.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Aperture {
    first: Ticks,
    len: u8,
    gaps: [u16; MAX_CONVERSIONS - 1],
}

impl Aperture {
    /// One conversion at `t`.
    #[inline]
    pub const fn point(t: Ticks) -> Self {
        Aperture {
            first: t,
            len: 1,
            gaps: [0; MAX_CONVERSIONS - 1],
        }
    }

    /// Conversions at `first`, then `gaps` ticks apart; `None` when there are more than
    /// [`MAX_CONVERSIONS`] or a gap is 0 (two conversions at one tick).
    pub fn new(first: Ticks, gaps: &[u16]) -> Option<Self> {
        let mut a = Aperture::point(first);
        for g in gaps {
            a.push_gap(*g).ok()?;
        }
        Some(a)
    }

    /// The first conversion's tick.
    #[inline]
    pub const fn first(&self) -> Ticks {
        self.first
    }

    /// Number of conversions (1 to [`MAX_CONVERSIONS`]).
    #[inline]
    pub const fn len(&self) -> usize {
        self.len as usize
    }

    /// Never true: an aperture holds at least one conversion.
    pub const fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Ticks from each conversion to the next (`len − 1` of them).
    #[inline]
    pub fn gaps(&self) -> &[u16] {
        self.gaps.get(..self.len().saturating_sub(1)).unwrap_or(&[])
    }

    /// The tick of every conversion, in order.
    #[inline]
    pub fn ticks(&self) -> impl Iterator<Item = Ticks> + '_ {
        let mut t = self.first.0;
        core::iter::once(self.first).chain(self.gaps().iter().map(move |g| {
            t = t.saturating_add(u64::from(*g));
            Ticks(t)
        }))
    }

    /// The last conversion's tick.
    #[inline]
    pub fn last(&self) -> Ticks {
        let span: u64 = self.gaps().iter().map(|g| u64::from(*g)).sum();
        Ticks(self.first.0.saturating_add(span))
    }

    /// Add a conversion `gap` ticks after the last. Refused (and nothing changed) when
    /// the aperture is full or `gap` is 0.
    pub fn push_gap(&mut self, gap: u16) -> Result<(), ApertureRefused> {
        if gap == 0 {
            return Err(ApertureRefused);
        }
        let i = self.len().saturating_sub(1);
        let slot = self.gaps.get_mut(i).ok_or(ApertureRefused)?;
        *slot = gap;
        self.len += 1;
        Ok(())
    }
}

/// [`Aperture::push_gap`] refused a conversion: the aperture is full, or the gap is 0.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ApertureRefused;
