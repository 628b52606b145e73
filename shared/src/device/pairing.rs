//! Which instant a conversion read belongs to. The firmware captures each data-ready edge
//! in hardware (GPIOTE → PPI → a TIMER's CAPTURE register, and on a fork of the same PPI
//! channel a second TIMER in counter mode counts the edges), then reads the output
//! registers over I²C. What it saw around the read decides the pairing:
//!
//! - **Pulsed data-ready** (LSM6DS3TR-C): an edge for every conversion, so the capture
//!   register holds the latest conversion's instant and the registers hold its data; the
//!   count says how many edges came since the last read. An edge during the read means the
//!   registers may hold either conversion: the sample is flagged `late`.
//! - **Latched data-ready** (LSM6DS33): the line rises at the first conversion after a
//!   read and stays high until the next read, so the capture is that conversion's instant.
//!   If the read began more than one conversion period after it, newer conversions have
//!   overwritten the registers: the data are the latest of them, whose instant is estimated
//!   from the capture and the period, and the sample is flagged `late`. The edge count
//!   sees one edge per read and says nothing of what was skipped.
//!
//! Conversions skipped either way are counted by the sampler
//! ([`super::sampler::missed_between`]).

use super::sampler::Conversion;

/// What the firmware saw around one read of the output registers (raw 32-bit counter
/// values).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Read {
    /// The timestamp TIMER's capture of the latest data-ready edge, before the read.
    pub capture: u32,
    /// The same register after the read.
    pub capture_after: u32,
    /// The timestamp TIMER as the read began.
    pub read_start: u32,
    /// The edge counter before the read.
    pub edges: u32,
    /// The edge counter after the read.
    pub edges_after: u32,
    /// The counts read.
    pub counts: [i16; 3],
    /// The sensor holds data-ready high until read (LSM6DS33), rather than pulsing it.
    pub latched: bool,
}

/// The conversion a read gives, with `conversion_ticks` the sensor's conversion period in
/// timestamp ticks: see the module documentation.
pub fn pair(r: &Read, conversion_ticks: u32) -> Conversion {
    let during = r.capture_after != r.capture || r.edges_after != r.edges;
    if !r.latched {
        return Conversion {
            capture: u64::from(r.capture),
            counts: r.counts,
            late: during,
            edges: Some(r.edges),
        };
    }
    let waited = r.read_start.wrapping_sub(r.capture);
    let newer = waited / conversion_ticks.max(1);
    Conversion {
        capture: u64::from(
            r.capture
                .wrapping_add(newer.wrapping_mul(conversion_ticks.max(1))),
        ),
        counts: r.counts,
        late: newer > 0 || during,
        edges: None,
    }
}
