//! Where in a recording something lies: a group's channel, a condition across rates, the
//! rates together, or every reading.

use rotacal_shared::{Channel, Condition};
use serde::Serialize;
use std::fmt;

/// Where a finding lies. Written (and serialised) as text: "x at 0.1 Hz, channel u".
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Place {
    /// One group's channel.
    Group {
        /// The group's condition.
        condition: Condition,
        /// Its nominal rate, Hz.
        rate_hz: f64,
        /// The channel.
        channel: Channel,
    },
    /// A condition's channel, over its groups at every rate.
    AcrossRatesOf {
        /// The condition.
        condition: Condition,
        /// The channel.
        channel: Channel,
    },
    /// The intrinsic properties over the rates.
    AcrossRates,
    /// Every reading of the file (the rails).
    AllChannels,
}

impl fmt::Display for Place {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Place::Group {
                condition,
                rate_hz,
                channel,
            } => write!(
                f,
                "{} at {rate_hz} Hz, channel {}",
                condition.letter(),
                channel.letter()
            ),
            Place::AcrossRatesOf { condition, channel } => write!(
                f,
                "{} across rates, channel {}",
                condition.letter(),
                channel.letter()
            ),
            Place::AcrossRates => f.write_str("across rates"),
            Place::AllChannels => f.write_str("all channels"),
        }
    }
}

impl Serialize for Place {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}
