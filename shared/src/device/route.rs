//! Where each packet goes, and how much the link can take: the firmware's routing of
//! packets to its GATT characteristics and the depths of its notification queues. The
//! firmware, the host's emulated device and the BlueZ stand-in all route through this, so
//! a test of the host sees what the board would send (docs/protocol.md).

use crate::packet::{averages_len, Packet, MAX_AVERAGES, MAX_RESULT};

/// A characteristic the device notifies on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Characteristic {
    /// Samples (single conversions or averaged batches, live or replayed) and
    /// temperatures.
    Stream,
    /// Fit reports, the quick-look and status.
    Results,
    /// The device-info value (set, not queued).
    Info,
}

impl Characteristic {
    /// The characteristic `p` goes out on; `None` for a command (the host writes those to
    /// the control characteristic).
    pub fn of(p: &Packet) -> Option<Self> {
        match p {
            Packet::Samples(_) | Packet::Averages(_) | Packet::Temperature(_) => {
                Some(Characteristic::Stream)
            }
            Packet::Fit(_) | Packet::QuickLook(_) | Packet::Status(_) => {
                Some(Characteristic::Results)
            }
            Packet::Info(_) => Some(Characteristic::Info),
            Packet::Command(_) => None,
        }
    }
}

/// Packets the firmware's stream queue holds: live batches for about 5 s of a dropped link
/// (7 samples each at 16 Hz), and the replay's share ([`Room`]).
pub const STREAM_QUEUE: usize = 12;

/// Packets the firmware's results queue holds.
pub const RESULTS_QUEUE: usize = 6;

/// Free places in the notification queues: what [`super::Device::pump`] may send.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Room {
    /// In the stream queue.
    pub stream: usize,
    /// In the results queue.
    pub results: usize,
}

impl Room {
    /// No limit: everything owed goes at once (a host without queues, the tests).
    pub const UNLIMITED: Room = Room {
        stream: usize::MAX,
        results: usize::MAX,
    };
}

/// Bytes of an ATT notification that are not the value: a notification carries MTU − 3.
pub const ATT_OVERHEAD: u16 = 3;

/// The largest ATT MTU the device grants: a batch of [`MAX_AVERAGES`] (228 bytes) in one
/// notification.
pub const MAX_MTU: u16 = 247;

/// The smallest ATT MTU the device works over: a fit report (150 bytes with its CRC, the largest
/// packet but a sample batch) in one notification. Below it, Start and Backfill are
/// refused with [`crate::packet::CommandError::MtuTooSmall`].
pub const MIN_MTU: u16 = MAX_RESULT as u16 + ATT_OVERHEAD;

/// Bytes of value one notification carries at ATT MTU `mtu`.
pub const fn payload(mtu: u16) -> usize {
    mtu.saturating_sub(ATT_OVERHEAD) as usize
}

/// Samples per batch at ATT MTU `mtu`: as many as fit one notification, at most
/// [`MAX_AVERAGES`] (247: 7, 185: 5, 158: 4); `None` below [`MIN_MTU`].
pub fn batch_len(mtu: u16) -> Option<usize> {
    if mtu < MIN_MTU {
        return None;
    }
    (1..=MAX_AVERAGES)
        .rev()
        .find(|n| averages_len(*n) <= payload(mtu))
}

/// True when `p` fits one notification at ATT MTU `mtu`.
pub fn fits(p: &Packet, mtu: u16) -> bool {
    p.encoded_len() <= payload(mtu)
}
