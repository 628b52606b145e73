//! A stand-in for BlueZ, the Linux Bluetooth daemon, on a private D-Bus system bus: the
//! subset of `org.bluez` that btleplug (through bluez-async) uses, with rotacal devices
//! behind it that run the firmware's logic (`rotacal_engine::simulate::emulated`, the
//! `Device` of `rotacal-shared`) fed by the simulator. So `rotacal record`, unchanged and
//! through btleplug's real BlueZ backend, records from it as from a board: every line
//! of rotacal's BLE code and btleplug's above the radio runs (docs/recording.md, "The
//! BlueZ stand-in", lists what it cannot show).
//!
//! - [`bus`]: a private `dbus-daemon`;
//! - [`tree`]: the exported objects and the signals their changes emit;
//! - [`gatt`]: the device's GATT database;
//! - `server`: the loop that answers methods and runs the devices on the wall clock.
//!
//! What it implements, from bluez-async 0.9 and btleplug 0.13: ObjectManager
//! `GetManagedObjects` and `InterfacesAdded`; `Introspect` (bluez-async finds services,
//! characteristics and descriptors as child nodes); Properties `Get`, `GetAll`, `Set`
//! (Adapter1.Powered) and `PropertiesChanged`; Adapter1 `SetDiscoveryFilter`,
//! `StartDiscovery`, `StopDiscovery`; Device1 `Connect`, `Disconnect`; GattCharacteristic1
//! `ReadValue`, `WriteValue`, `StartNotify`, `StopNotify`, with notifications as
//! `PropertiesChanged` of `Value`; GattDescriptor1 `ReadValue`. Behaviour as BlueZ's:
//! devices appear while discovering and stay; services are cached across disconnections
//! (BlueZ's default `Cache = always`); a lost link is noticed after the supervision
//! timeout, failing requests left without an ATT response; notifications need a
//! subscription and must fit the MTU.
// A test stand-in, never shipped: it reads and writes D-Bus messages and GATT values of
// fixed layout, where an index out of range is a bug of the stand-in that its tests show.
#![allow(clippy::indexing_slicing)]

pub mod bus;
pub mod gatt;
mod server;
pub mod tree;

use rotacal_engine::simulate::emulated::EmulatedDevice;
use std::collections::BTreeMap;
use std::io;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::thread::JoinHandle;
use std::time::Duration;

pub use server::ADAPTER;

/// One device unit: its Bluetooth address and the emulated device.
pub struct Unit {
    /// e.g. `F1:23:45:67:89:AB` (a random static address, as the Feather's).
    pub address: String,
    /// The firmware's logic with its sensor and faults.
    pub device: EmulatedDevice,
}

/// How the stand-in behaves.
#[derive(Clone, Debug)]
pub struct Options {
    /// The advertised name of every unit.
    pub name: String,
    /// The ATT MTU BlueZ negotiates (the firmware grants 247).
    pub mtu: u16,
    /// How long after the device's radio goes silent BlueZ declares it disconnected.
    pub supervision: Duration,
    /// How long a connection attempt to a silent device takes to fail.
    pub connect_timeout: Duration,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            name: "rotacal".into(),
            mtu: 247,
            supervision: Duration::from_secs(2),
            connect_timeout: Duration::from_secs(2),
        }
    }
}

/// What went over the bus.
#[derive(Clone, Debug, Default)]
pub struct Report {
    /// Method calls received, by `interface.member`.
    pub calls: BTreeMap<String, u64>,
    /// Notifications delivered.
    pub notifications: u64,
    /// The longest notification, bytes.
    pub longest: usize,
    /// Notifications longer than the MTU allows (never delivered).
    pub oversize: u64,
    /// Notifications the device had while the client was not subscribed.
    pub unsubscribed: u64,
    /// Commands written to the control characteristic.
    pub writes: u64,
    /// Connections made (Connect calls that reached a device).
    pub connections: u64,
    /// Connect calls, including those that failed.
    pub connect_attempts: u64,
    /// Links declared lost (or closed by the client).
    pub disconnections: u64,
    /// Notifications the units delivered with a bit flipped (their `flip` faults).
    pub flipped: u64,
}

/// A running stand-in: it owns `org.bluez` on the bus until [`Standin::stop`] or drop.
pub struct Standin {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<io::Result<Report>>>,
}

impl Standin {
    /// Start the stand-in on the bus at `bus` with `units`: the first advertises from the
    /// start; each next one replaces the one before when that one's link first breaks (a
    /// different unit at another address, advertising the same name). Returns when
    /// `org.bluez` is owned.
    pub fn spawn(bus: &str, units: Vec<Unit>, options: Options) -> io::Result<Standin> {
        let stop = Arc::new(AtomicBool::new(false));
        let (ready_tx, ready_rx) = mpsc::channel();
        let bus = bus.to_string();
        let flag = stop.clone();
        let thread = std::thread::spawn(move || {
            let server = match server::Server::new(&bus, units, options) {
                Ok(s) => {
                    let _ = ready_tx.send(Ok(()));
                    s
                }
                Err(e) => {
                    let _ = ready_tx.send(Err(e.to_string()));
                    return Err(e);
                }
            };
            server.run(flag)
        });
        match ready_rx.recv() {
            Ok(Ok(())) => Ok(Standin {
                stop,
                thread: Some(thread),
            }),
            Ok(Err(e)) => Err(io::Error::other(e)),
            Err(_) => Err(io::Error::other(
                "the stand-in's thread ended before it was ready",
            )),
        }
    }

    /// Stop it; what went over the bus.
    pub fn stop(mut self) -> io::Result<Report> {
        self.stop.store(true, Ordering::Relaxed);
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err(io::Error::other("the stand-in's thread panicked")),
            None => Err(io::Error::other("the stand-in was already stopped")),
        }
    }
}

impl Drop for Standin {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
