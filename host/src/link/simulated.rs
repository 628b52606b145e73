//! The emulated device (`rotacal::simulate::emulated`: the firmware's logic, the same code
//! the Feather runs, fed by the simulator's sensor stream) behind the [`Link`] trait, on
//! tokio's clock: under a paused runtime (the demo, the tests) a 15-minute session takes
//! seconds of CPU. Faults on demand ([`Faults`]), for the recorder's tests and dry runs.

use super::{Channel, Link, LinkError};
use crate::simulate::emulated::EmulatedDevice;
pub use crate::simulate::emulated::{Faults, FIRMWARE};
use crate::simulate::Simulation;
use std::time::Duration;
use tokio::time::Instant;

/// How long a connection attempt takes to fail while the device is out of reach.
const CONNECT_ATTEMPT: Duration = Duration::from_secs(2);

/// See the module documentation.
pub struct SimulatedDevice {
    device: EmulatedDevice,
    /// The ATT MTU each connection gets ([`Faults::mtu`]).
    mtu: u16,
    /// Set at the first connection; device time runs from it.
    epoch: Option<Instant>,
}

impl SimulatedDevice {
    /// A device whose sensor sees what `sim` simulates. `sim` should run at the sensor's
    /// output rate (104 Hz for the Feather's LSM6DS33), in counts, within i16.
    pub fn new(sim: &Simulation, faults: Faults) -> anyhow::Result<Self> {
        Ok(SimulatedDevice {
            mtu: faults.mtu,
            device: EmulatedDevice::new(sim, faults)?,
            epoch: None,
        })
    }

    /// Conversions the emulated sensor made that its firmware did not read (faults `late`,
    /// `stuck`): what the device must count.
    pub fn unread(&self) -> u64 {
        self.device.unread()
    }

    /// Sample batches the device delivered with a bit flipped.
    pub fn flipped(&self) -> u64 {
        self.device.flipped()
    }

    fn elapsed(&self) -> Duration {
        self.epoch.map_or(Duration::ZERO, |e| Instant::now() - e)
    }

    /// Run the device up to now.
    fn sync(&mut self) -> Duration {
        let t = self.elapsed();
        self.device.advance(t);
        t
    }
}

impl Link for SimulatedDevice {
    async fn connect(&mut self) -> Result<Vec<u8>, LinkError> {
        if self.epoch.is_none() {
            self.epoch = Some(Instant::now());
        }
        let t = self.sync();
        match self.device.connect(t, self.mtu) {
            Some(info) => {
                self.device.subscribe(Channel::Stream, true);
                self.device.subscribe(Channel::Results, true);
                Ok(info)
            }
            None => {
                tokio::time::sleep(CONNECT_ATTEMPT).await;
                self.sync();
                Err(LinkError::Disconnected(
                    "no advertisement from the device".into(),
                ))
            }
        }
    }

    async fn write(&mut self, command: &[u8]) -> Result<(), LinkError> {
        self.sync();
        if self.device.write(command) {
            Ok(())
        } else {
            Err(LinkError::Disconnected(
                "write failed: not connected".into(),
            ))
        }
    }

    async fn next(&mut self, timeout: Duration) -> Result<Option<(Channel, Vec<u8>)>, LinkError> {
        let deadline = self.elapsed() + timeout;
        loop {
            let now = self.sync();
            if let Some(v) = self.device.pop() {
                return Ok(Some(v));
            }
            if !self.device.connected() {
                return Err(LinkError::Disconnected("supervision timeout".into()));
            }
            if now >= deadline {
                return Ok(None);
            }
            // Packets go out at conversions and polls; waking at each poll (100 ms) is
            // enough, since the notification time carries no data (the samples carry
            // their own timestamps).
            let wake = self.device.next_wake().min(deadline).max(now);
            tokio::time::sleep(wake - now).await;
        }
    }

    async fn close(&mut self) {
        self.sync();
        self.device.disconnect();
    }

    fn describe(&self) -> String {
        "simulated device (the firmware's logic on this host)".into()
    }

    fn mtu(&self) -> u16 {
        self.mtu
    }
}
