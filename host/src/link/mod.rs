//! The connection to a device, as the recorder needs it: connect (again), write a command,
//! take the next notification. Two kinds: [`ble`] (btleplug, the real device) and
//! [`simulated`] (the device logic of `rotacal-shared` on the host, fed by the simulator,
//! with faults on demand), so the recorder's handling of drops, reconnects and garbage is
//! tested without a radio.

pub mod ble;
pub mod simulated;

use std::fmt;
use std::time::Duration;

pub use rotacal_engine::recording::from_device::Channel;

/// Why a link operation failed.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum LinkError {
    /// The connection is gone (or never came up); reconnecting may help.
    Disconnected(String),
    /// Nothing to be done by retrying: no adapter, no such device, no rotacal service.
    Fatal(String),
}

impl fmt::Display for LinkError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LinkError::Disconnected(m) => write!(f, "link lost: {m}"),
            LinkError::Fatal(m) => write!(f, "{m}"),
        }
    }
}

impl std::error::Error for LinkError {}

/// A connection to a rotacal device.
// The recorder runs on a single-threaded runtime, so the futures need not be Send.
#[allow(async_fn_in_trait)]
pub trait Link {
    /// Connect (or reconnect) and subscribe; returns the device-info value's bytes.
    async fn connect(&mut self) -> Result<Vec<u8>, LinkError>;
    /// Write an encoded command to the control characteristic.
    async fn write(&mut self, command: &[u8]) -> Result<(), LinkError>;
    /// The next notification, or `Ok(None)` if none came within `timeout`.
    async fn next(&mut self, timeout: Duration) -> Result<Option<(Channel, Vec<u8>)>, LinkError>;
    /// Close the connection at the end of a session, so that the device advertises
    /// again (BlueZ keeps a link up after the client that made it has exited).
    async fn close(&mut self);
    /// What the link is, for messages (name and address).
    fn describe(&self) -> String;
    /// The current connection's ATT MTU, as the central agreed it with the device.
    fn mtu(&self) -> u16;
}
