//! The real device over Bluetooth LE (btleplug: BlueZ on Linux, CoreBluetooth on macOS,
//! WinRT on Windows). On Linux btleplug talks to BlueZ over D-Bus; libdbus is built from
//! its vendored source (the `vendored` feature of libdbus-sys), so building needs no
//! system package, only a running BlueZ when recording.

use super::{Channel, Link, LinkError};
use btleplug::api::{
    BDAddr, Central, CentralEvent, Characteristic, Manager as _, Peripheral as _, ScanFilter,
    ValueNotification, WriteType,
};
use btleplug::platform::{Adapter, Manager, Peripheral};
use futures::stream::{Stream, StreamExt};
use std::pin::Pin;
use std::time::Duration;
use uuid::Uuid;

/// The rotacal GATT service and its characteristics (docs/protocol.md).
pub const SERVICE: Uuid = Uuid::from_u128(0x7f1e0001_52a1_4b8e_9c3d_5ad1c0ca1e00);
/// Samples and temperatures (notify).
pub const STREAM: Uuid = Uuid::from_u128(0x7f1e0002_52a1_4b8e_9c3d_5ad1c0ca1e00);
/// Commands (write).
pub const CONTROL: Uuid = Uuid::from_u128(0x7f1e0003_52a1_4b8e_9c3d_5ad1c0ca1e00);
/// Fit reports, quick-look, status (notify, read).
pub const RESULTS: Uuid = Uuid::from_u128(0x7f1e0004_52a1_4b8e_9c3d_5ad1c0ca1e00);
/// Device info (read).
pub const INFO: Uuid = Uuid::from_u128(0x7f1e0005_52a1_4b8e_9c3d_5ad1c0ca1e00);

/// Which device to connect to.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Target {
    /// The advertised name (the firmware's is `rotacal`).
    Name(String),
    /// The Bluetooth address, e.g. `F1:23:45:67:89:AB`.
    Address(BDAddr),
}

impl Target {
    /// An address if `s` parses as one, else a name.
    pub fn parse(s: &str) -> Target {
        match BDAddr::from_str_delim(s) {
            Ok(a) => Target::Address(a),
            Err(_) => Target::Name(s.to_string()),
        }
    }
}

type Notifications = Pin<Box<dyn Stream<Item = ValueNotification> + Send>>;
type Events = Pin<Box<dyn Stream<Item = CentralEvent> + Send>>;

/// A connection to a rotacal device over BLE.
pub struct BleLink {
    target: Target,
    scan_timeout: Duration,
    adapter: Option<Adapter>,
    events: Option<Events>,
    peripheral: Option<Peripheral>,
    control: Option<Characteristic>,
    notifications: Option<Notifications>,
}

fn lost(e: impl std::fmt::Display) -> LinkError {
    LinkError::Disconnected(e.to_string())
}

impl BleLink {
    /// A link to `target`, scanning at most `scan_timeout` per connection attempt.
    pub fn new(target: Target, scan_timeout: Duration) -> Self {
        BleLink {
            target,
            scan_timeout,
            adapter: None,
            events: None,
            peripheral: None,
            control: None,
            notifications: None,
        }
    }

    async fn adapter(&mut self) -> Result<Adapter, LinkError> {
        if let Some(a) = &self.adapter {
            return Ok(a.clone());
        }
        let manager = Manager::new().await.map_err(|e| {
            LinkError::Fatal(format!(
                "no Bluetooth stack: {e} (on Linux, BlueZ must be running: bluetoothd and \
                 the D-Bus system bus)"
            ))
        })?;
        let adapter = manager
            .adapters()
            .await
            .map_err(|e| LinkError::Fatal(format!("cannot list Bluetooth adapters: {e}")))?
            .into_iter()
            .next()
            .ok_or_else(|| LinkError::Fatal("no Bluetooth adapter found".into()))?;
        self.events = Some(
            adapter
                .events()
                .await
                .map_err(|e| LinkError::Fatal(format!("adapter events: {e}")))?,
        );
        self.adapter = Some(adapter.clone());
        Ok(adapter)
    }

    async fn matches(&self, p: &Peripheral) -> bool {
        let Ok(Some(props)) = p.properties().await else {
            return false;
        };
        match &self.target {
            Target::Address(a) => props.address == *a,
            Target::Name(n) => {
                props.local_name.as_deref() == Some(n)
                    || props.advertisement_name.as_deref() == Some(n)
            }
        }
    }

    async fn find(&mut self, adapter: &Adapter) -> Result<Peripheral, LinkError> {
        adapter
            .start_scan(ScanFilter::default())
            .await
            .map_err(|e| LinkError::Fatal(format!("cannot scan: {e}")))?;
        let deadline = tokio::time::Instant::now() + self.scan_timeout;
        let found = loop {
            let mut hit = None;
            for p in adapter.peripherals().await.map_err(lost)? {
                if self.matches(&p).await {
                    hit = Some(p);
                    break;
                }
            }
            if let Some(p) = hit {
                break Ok(p);
            }
            if tokio::time::Instant::now() >= deadline {
                break Err(LinkError::Disconnected(format!(
                    "{:?} not seen within {:.0} s of scanning",
                    self.target,
                    self.scan_timeout.as_secs_f64()
                )));
            }
            tokio::time::sleep(Duration::from_millis(250)).await;
        };
        let _ = adapter.stop_scan().await;
        found
    }
}

impl Link for BleLink {
    async fn connect(&mut self) -> Result<Vec<u8>, LinkError> {
        self.notifications = None;
        self.control = None;
        let adapter = self.adapter().await?;
        let p = match self.peripheral.take() {
            Some(p) => p,
            None => self.find(&adapter).await?,
        };
        if !p.is_connected().await.unwrap_or(false) {
            if let Err(e) = p.connect_with_timeout(Duration::from_secs(10)).await {
                // Keep the peripheral: it may be out of range for a while.
                self.peripheral = Some(p);
                return Err(lost(format!("connect: {e}")));
            }
        }
        p.discover_services().await.map_err(lost)?;
        let chars = p.characteristics();
        let get = |u: Uuid| chars.iter().find(|c| c.uuid == u).cloned();
        let (Some(stream), Some(control), Some(results), Some(info)) =
            (get(STREAM), get(CONTROL), get(RESULTS), get(INFO))
        else {
            return Err(LinkError::Fatal(format!(
                "{} has no rotacal service {SERVICE}: is it running the rotacal firmware?",
                p.address()
            )));
        };
        p.subscribe(&stream).await.map_err(lost)?;
        p.subscribe(&results).await.map_err(lost)?;
        self.notifications = Some(p.notifications().await.map_err(lost)?);
        let info = p.read(&info).await.map_err(lost)?;
        self.control = Some(control);
        self.peripheral = Some(p);
        Ok(info)
    }

    async fn write(&mut self, command: &[u8]) -> Result<(), LinkError> {
        let (Some(p), Some(c)) = (&self.peripheral, &self.control) else {
            return Err(lost("not connected"));
        };
        p.write(c, command, WriteType::WithResponse)
            .await
            .map_err(|e| lost(format!("write: {e}")))
    }

    async fn next(&mut self, timeout: Duration) -> Result<Option<(Channel, Vec<u8>)>, LinkError> {
        let id = self.peripheral.as_ref().map(|p| p.id());
        let Some(notes) = self.notifications.as_mut() else {
            return Err(lost("not connected"));
        };
        let sleep = tokio::time::sleep(timeout);
        tokio::pin!(sleep);
        loop {
            let event = async {
                match self.events.as_mut() {
                    Some(ev) => ev.next().await,
                    None => std::future::pending().await,
                }
            };
            tokio::select! {
                n = notes.next() => {
                    let Some(n) = n else {
                        self.notifications = None;
                        return Err(lost("notification stream ended"));
                    };
                    let ch = match n.uuid {
                        u if u == STREAM => Channel::Stream,
                        u if u == RESULTS => Channel::Results,
                        _ => continue,
                    };
                    return Ok(Some((ch, n.value)));
                }
                e = event => {
                    if let Some(CentralEvent::DeviceDisconnected(d)) = e {
                        if Some(d) == id {
                            self.notifications = None;
                            return Err(lost("the device disconnected"));
                        }
                    }
                }
                () = &mut sleep => return Ok(None),
            }
        }
    }

    async fn close(&mut self) {
        self.notifications = None;
        self.control = None;
        if let Some(p) = &self.peripheral {
            // Best effort: the session's outcome is already decided.
            let _ = p.disconnect().await;
        }
    }

    fn mtu(&self) -> u16 {
        // BlueZ's value for the connection (btleplug: 23 when it has none).
        self.peripheral.as_ref().map_or(23, |p| p.mtu())
    }

    fn describe(&self) -> String {
        match (&self.peripheral, &self.target) {
            (Some(p), _) => format!("BLE device {}", p.address()),
            (None, Target::Name(n)) => format!("BLE device named {n:?}"),
            (None, Target::Address(a)) => format!("BLE device {a}"),
        }
    }
}
