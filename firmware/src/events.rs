//! What the tasks tell each other: sensor and BLE events into the logic task, encoded
//! packets out of it.

use core::sync::atomic::{AtomicU16, AtomicU32, Ordering};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use heapless::Vec;
use rotacal_sensor::Chip;
use rotacal_shared::device::route::{MAX_MTU, RESULTS_QUEUE, STREAM_QUEUE};
use rotacal_shared::device::sampler::Conversion;
use rotacal_shared::packet::{Command, SensorStatus};

/// Into the logic task.
#[derive(Clone, Copy, defmt::Format)]
pub enum Event {
    /// A conversion read, paired with its instant (rotacal-shared's `pairing`).
    Sample(Conversion),
    /// Die temperature, hundredths of °C.
    Temperature(i16),
    /// Sensor health, and the chip once known.
    Sensor(SensorStatus, Option<Chip>),
    /// A command from the host.
    Command(Command),
    /// Time passes without samples (TIMER1 now).
    Poll(u32),
}

/// One encoded packet, for a notification.
pub type Encoded = Vec<u8, 244>;

/// Sensor and BLE → logic.
pub static EVENTS: Channel<CriticalSectionRawMutex, Event, 32> = Channel::new();
/// Logic → BLE: packets for the stream characteristic.
pub static STREAM: Channel<CriticalSectionRawMutex, Encoded, STREAM_QUEUE> = Channel::new();
/// Logic → BLE: packets for the fit-results characteristic.
pub static RESULTS: Channel<CriticalSectionRawMutex, Encoded, RESULTS_QUEUE> = Channel::new();

static OVERFLOWS: AtomicU32 = AtomicU32::new(0);

/// An event was dropped because the logic task fell behind.
pub fn note_overflow() {
    OVERFLOWS.fetch_add(1, Ordering::Relaxed);
}

/// Events dropped since the last call.
pub fn take_overflows() -> u32 {
    OVERFLOWS.swap(0, Ordering::Relaxed)
}

/// The current link's ATT MTU, as the BLE task last read it (the device logic sizes its
/// batches to it).
static LINK_MTU: AtomicU16 = AtomicU16::new(MAX_MTU);

/// Set the link's MTU.
pub fn set_link_mtu(mtu: u16) {
    LINK_MTU.store(mtu, Ordering::Relaxed);
}

/// The link's MTU.
pub fn link_mtu() -> u16 {
    LINK_MTU.load(Ordering::Relaxed)
}
