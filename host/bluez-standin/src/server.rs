//! The stand-in's loop: answer BlueZ's methods, run the emulated devices on the wall
//! clock, and turn what they send into the signals BlueZ emits.

use crate::gatt::{self, Gatt};
use crate::tree::{Interfaces, Props, Tree, Value};
use crate::{Options, Report, Unit};
use dbus::arg::{cast, PropMap, RefArg, Variant};
use dbus::channel::Channel;
use dbus::message::MessageType;
use dbus::strings::ErrorName;
use dbus::Message;
use rotacal_engine::recording::from_device::Channel as Characteristic;
use std::ffi::CString;
use std::io;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The adapter's object path.
pub const ADAPTER: &str = "/org/bluez/hci0";
const ADAPTER1: &str = "org.bluez.Adapter1";
const DEVICE1: &str = "org.bluez.Device1";
const CHAR1: &str = "org.bluez.GattCharacteristic1";
const PROPERTIES: &str = "org.freedesktop.DBus.Properties";

/// The radio link of one unit, as BlueZ sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Radio {
    Down,
    Up,
    /// Gone on the device's side since then; BlueZ notices after the supervision timeout.
    Breaking(Instant),
}

struct Live {
    unit: Unit,
    path: String,
    /// Device time runs from the first connection.
    epoch: Option<Instant>,
    radio: Radio,
    /// Replaced by the next unit: never reachable again.
    gone: bool,
    info: Vec<u8>,
    results: Vec<u8>,
    notifying_stream: bool,
    notifying_results: bool,
    /// The bus name of the client that subscribed: BlueZ ends its notify sessions when
    /// it leaves the bus.
    subscriber: Option<String>,
    /// Writes with no ATT response yet (the radio broke): failed when BlueZ notices.
    stalled: Vec<Message>,
}

impl Live {
    fn time(&self, now: Instant) -> Duration {
        self.epoch.map_or(Duration::ZERO, |e| now.duration_since(e))
    }

    fn reachable(&self, now: Instant) -> bool {
        !self.gone && self.unit.device.reachable(self.time(now))
    }
}

pub(crate) struct Server {
    channel: Channel,
    tree: Tree,
    units: Vec<Live>,
    options: Options,
    discovering: bool,
    /// Replies due later: (when, reply).
    later: Vec<(Instant, Message)>,
    report: Report,
}

fn error(m: &Message, name: &str, text: &str) -> Message {
    // Every name passed here is a literal valid error name.
    let name = ErrorName::from(name.to_string());
    let text = CString::new(text).unwrap_or_default();
    m.error(&name, &text)
}

fn failed(m: &Message, text: &str) -> Message {
    error(m, "org.bluez.Error.Failed", text)
}

fn props(list: Vec<(&'static str, Value)>) -> Props {
    list.into_iter().collect()
}

impl Server {
    pub(crate) fn new(bus: &str, units: Vec<Unit>, options: Options) -> io::Result<Server> {
        let bad = |e: dbus::Error| io::Error::other(format!("D-Bus at {bus}: {e}"));
        let mut channel = Channel::open_private(bus).map_err(bad)?;
        channel.register().map_err(bad)?;
        let request = Message::call_with_args(
            "org.freedesktop.DBus",
            "/org/freedesktop/DBus",
            "org.freedesktop.DBus",
            "RequestName",
            ("org.bluez", 4u32),
        );
        let reply = channel
            .send_with_reply_and_block(request, Duration::from_secs(5))
            .map_err(bad)?;
        if reply.get1::<u32>() != Some(1) {
            return Err(io::Error::other(format!(
                "D-Bus at {bus}: org.bluez is already owned"
            )));
        }
        // To hear of clients leaving the bus.
        let watch = Message::call_with_args(
            "org.freedesktop.DBus",
            "/org/freedesktop/DBus",
            "org.freedesktop.DBus",
            "AddMatch",
            (
                "type='signal',sender='org.freedesktop.DBus',interface='org.freedesktop.DBus',\
              member='NameOwnerChanged'",
            ),
        );
        channel
            .send_with_reply_and_block(watch, Duration::from_secs(5))
            .map_err(bad)?;
        let mut tree = Tree::default();
        let _ = tree.add("/org/bluez", Interfaces::new());
        let _ = tree.add(
            ADAPTER,
            [(
                ADAPTER1,
                props(vec![
                    ("Address", Value::Str("00:1A:7D:DA:71:13".into())),
                    ("AddressType", Value::Str("public".into())),
                    ("Name", Value::Str("rotacal-standin".into())),
                    ("Alias", Value::Str("rotacal-standin".into())),
                    ("Modalias", Value::Str("usb:v1D6Bp0246d0548".into())),
                    ("Powered", Value::Bool(false)),
                    ("Discovering", Value::Bool(false)),
                    ("Discoverable", Value::Bool(false)),
                    ("Pairable", Value::Bool(false)),
                    ("UUIDs", Value::Strs(Vec::new())),
                ]),
            )]
            .into_iter()
            .collect(),
        );
        let units = units
            .into_iter()
            .map(|unit| Live {
                path: format!("{ADAPTER}/dev_{}", unit.address.replace(':', "_")),
                unit,
                epoch: None,
                radio: Radio::Down,
                gone: false,
                info: Vec::new(),
                results: Vec::new(),
                notifying_stream: false,
                notifying_results: false,
                subscriber: None,
                stalled: Vec::new(),
            })
            .collect();
        Ok(Server {
            channel,
            tree,
            units,
            options,
            discovering: false,
            later: Vec::new(),
            report: Report::default(),
        })
    }

    fn send(&mut self, m: Option<Message>) {
        if let Some(m) = m {
            // A send fails only when the bus is gone; the loop then ends on its own.
            let _ = self.channel.send(m);
        }
    }

    fn set(&mut self, at: &str, iface: &str, name: &'static str, v: Value) {
        let m = self.tree.set(at, iface, name, v);
        self.send(m);
    }

    pub(crate) fn run(mut self, stop: Arc<AtomicBool>) -> io::Result<Report> {
        while !stop.load(Ordering::Relaxed) {
            if self
                .channel
                .read_write(Some(Duration::from_millis(5)))
                .is_err()
            {
                return Err(io::Error::other("the private bus closed"));
            }
            while let Some(m) = self.channel.pop_message() {
                match m.msg_type() {
                    MessageType::MethodCall => {
                        let reply = self.call(&m);
                        self.send(reply);
                    }
                    MessageType::Signal => self.signal(&m),
                    _ => {}
                }
            }
            self.step(Instant::now());
            self.channel.flush();
        }
        self.report.flipped = self.units.iter().map(|u| u.unit.device.flipped()).sum();
        Ok(self.report)
    }

    /// A client that left the bus loses its notify sessions.
    fn signal(&mut self, m: &Message) {
        if m.member().as_deref() != Some("NameOwnerChanged") {
            return;
        }
        let Ok((name, _, new)) = m.read3::<&str, &str, &str>() else {
            return;
        };
        if !new.is_empty() {
            return;
        }
        let left: Vec<usize> = (0..self.units.len())
            .filter(|i| {
                self.units
                    .get(*i)
                    .is_some_and(|u| u.subscriber.as_deref() == Some(name))
            })
            .collect();
        for i in left {
            self.end_notify(i);
        }
    }

    /// End unit `i`'s notify sessions (its client left, or the link went down).
    fn end_notify(&mut self, i: usize) {
        let Some(u) = self.units.get_mut(i) else {
            return;
        };
        u.subscriber = None;
        u.notifying_stream = false;
        u.notifying_results = false;
        let path = u.path.clone();
        for g in [Gatt::Stream, Gatt::Results] {
            self.set(
                &gatt::path(&path, g),
                CHAR1,
                "Notifying",
                Value::Bool(false),
            );
        }
    }

    /// The devices up to now: what they sent, links that broke, units that appeared.
    fn step(&mut self, now: Instant) {
        for i in 0..self.units.len() {
            self.step_unit(i, now);
        }
        let (due, rest): (Vec<_>, Vec<_>) = std::mem::take(&mut self.later)
            .into_iter()
            .partition(|(at, _)| *at <= now);
        self.later = rest;
        for (_, m) in due {
            self.send(Some(m));
        }
        if self.discovering {
            for i in 0..self.units.len() {
                let advertising = self.units.get(i).is_some_and(|u| {
                    u.reachable(now) && (i == 0 || self.units.get(i - 1).is_some_and(|p| p.gone))
                });
                if advertising {
                    self.export_device(i);
                }
            }
        }
    }

    fn step_unit(&mut self, i: usize, now: Instant) {
        let has_successor = i + 1 < self.units.len();
        let Some(u) = self.units.get_mut(i) else {
            return;
        };
        if u.epoch.is_some() {
            // The firmware notifies only what the client has subscribed to (CCCD) on this
            // link, and keeps the rest queued until it does.
            u.unit
                .device
                .subscribe(Characteristic::Stream, u.notifying_stream);
            u.unit
                .device
                .subscribe(Characteristic::Results, u.notifying_results);
            let t = u.time(now);
            u.unit.device.advance(t);
        }
        let mut out = Vec::new();
        while let Some(v) = u.unit.device.pop() {
            out.push(v);
        }
        let path = u.path.clone();
        match u.radio {
            Radio::Up if !u.unit.device.connected() => {
                u.radio = Radio::Breaking(now);
                if has_successor {
                    u.gone = true;
                }
            }
            Radio::Breaking(since) if now.duration_since(since) >= self.options.supervision => {
                self.declare_down(i);
            }
            _ => {}
        }
        for (ch, bytes) in out {
            self.notify(i, &path, ch, bytes);
        }
    }

    fn notify(&mut self, i: usize, path: &str, ch: Characteristic, bytes: Vec<u8>) {
        let Some(u) = self.units.get_mut(i) else {
            return;
        };
        let (char_path, on) = match ch {
            Characteristic::Stream => (gatt::path(path, Gatt::Stream), u.notifying_stream),
            Characteristic::Results => {
                u.results = bytes.clone();
                (gatt::path(path, Gatt::Results), u.notifying_results)
            }
            Characteristic::Info => return,
        };
        // The SoftDevice refuses a notification longer than the MTU's value (and the
        // firmware drops it): it never reaches BlueZ.
        if bytes.len() > usize::from(self.options.mtu.saturating_sub(3)) {
            self.report.oversize += 1;
            return;
        }
        // Without the client's subscription (CCCD) the device cannot notify.
        if !on {
            self.report.unsubscribed += 1;
            return;
        }
        self.report.notifications += 1;
        self.report.longest = self.report.longest.max(bytes.len());
        self.set(&char_path, CHAR1, "Value", Value::Bytes(bytes));
    }

    fn declare_down(&mut self, i: usize) {
        let Some(u) = self.units.get_mut(i) else {
            return;
        };
        u.radio = Radio::Down;
        u.unit.device.disconnect();
        let stalled = std::mem::take(&mut u.stalled);
        let path = u.path.clone();
        self.report.disconnections += 1;
        for m in stalled {
            self.send(Some(failed(&m, "Not connected")));
        }
        self.end_notify(i);
        self.set(&path, DEVICE1, "ServicesResolved", Value::Bool(false));
        self.set(&path, DEVICE1, "Connected", Value::Bool(false));
    }

    fn export_device(&mut self, i: usize) {
        let Some(u) = self.units.get(i) else {
            return;
        };
        if self.tree.has(&u.path) {
            return;
        }
        let name = self.options.name.clone();
        let ifaces: Interfaces = [(
            DEVICE1,
            props(vec![
                ("Address", Value::Str(u.unit.address.clone())),
                ("AddressType", Value::Str("random".into())),
                ("Name", Value::Str(name.clone())),
                ("Alias", Value::Str(name)),
                ("Paired", Value::Bool(false)),
                ("Bonded", Value::Bool(false)),
                ("Trusted", Value::Bool(false)),
                ("Blocked", Value::Bool(false)),
                ("LegacyPairing", Value::Bool(false)),
                ("Connected", Value::Bool(false)),
                ("ServicesResolved", Value::Bool(false)),
                ("RSSI", Value::I16(-58)),
                ("UUIDs", Value::Strs(Vec::new())),
                ("Adapter", Value::Path(ADAPTER.into())),
            ]),
        )]
        .into_iter()
        .collect();
        let path = u.path.clone();
        let m = self.tree.add(&path, ifaces);
        self.send(Some(m));
    }

    fn unit_at(&self, path: &str) -> Option<(usize, Option<Gatt>)> {
        self.units.iter().enumerate().find_map(|(i, u)| {
            if path == u.path {
                Some((i, None))
            } else {
                gatt::which(&u.path, path).map(|g| (i, Some(g)))
            }
        })
    }

    fn call(&mut self, m: &Message) -> Option<Message> {
        let path = m.path()?.to_string();
        let iface = m.interface().map(|i| i.to_string()).unwrap_or_default();
        let member = m.member()?.to_string();
        *self
            .report
            .calls
            .entry(format!("{iface}.{member}"))
            .or_default() += 1;
        let known = path == "/" || self.tree.has(&path) || path == "/org";
        Some(match (iface.as_str(), member.as_str()) {
            ("org.freedesktop.DBus.Introspectable", "Introspect") => {
                m.method_return().append1(self.tree.introspect(&path))
            }
            ("org.freedesktop.DBus.ObjectManager", "GetManagedObjects") if path == "/" => {
                m.method_return().append1(self.tree.managed_objects())
            }
            _ if !known => error(
                m,
                "org.freedesktop.DBus.Error.UnknownObject",
                &format!("no object {path}"),
            ),
            (PROPERTIES, "Get") => match m.read2::<&str, &str>() {
                Ok((i, n)) => match self.tree.get(&path, i, n) {
                    Some(v) => m.method_return().append1(v.variant()),
                    None => error(
                        m,
                        "org.freedesktop.DBus.Error.InvalidArgs",
                        &format!("no property {i}.{n}"),
                    ),
                },
                Err(e) => error(m, "org.freedesktop.DBus.Error.InvalidArgs", &e.to_string()),
            },
            (PROPERTIES, "GetAll") => match m.read1::<&str>() {
                Ok(i) => match self.tree.get_all(&path, i) {
                    Some(all) => m.method_return().append1(all),
                    None => error(
                        m,
                        "org.freedesktop.DBus.Error.InvalidArgs",
                        &format!("No such interface '{i}'"),
                    ),
                },
                Err(e) => error(m, "org.freedesktop.DBus.Error.InvalidArgs", &e.to_string()),
            },
            (PROPERTIES, "Set") => self.set_property(m, &path),
            (ADAPTER1, "SetDiscoveryFilter") => m.method_return(),
            (ADAPTER1, "StartDiscovery") => {
                self.discovering = true;
                self.set(ADAPTER, ADAPTER1, "Discovering", Value::Bool(true));
                m.method_return()
            }
            (ADAPTER1, "StopDiscovery") if self.discovering => {
                self.discovering = false;
                self.set(ADAPTER, ADAPTER1, "Discovering", Value::Bool(false));
                m.method_return()
            }
            (ADAPTER1, "StopDiscovery") => failed(m, "No discovery started"),
            (DEVICE1, "Connect") => return self.connect(m, &path),
            (DEVICE1, "Disconnect") => {
                if let Some((i, _)) = self.unit_at(&path) {
                    if self.units.get(i).is_some_and(|u| u.radio != Radio::Down) {
                        self.declare_down(i);
                    }
                }
                m.method_return()
            }
            (CHAR1, member) => return self.characteristic(m, &path, member),
            ("org.bluez.GattDescriptor1", "ReadValue") => {
                // The CCCD: notifications or indications enabled.
                m.method_return().append1(vec![0u8, 0])
            }
            _ => error(
                m,
                "org.freedesktop.DBus.Error.UnknownMethod",
                &format!("{iface}.{member} is not implemented by the stand-in"),
            ),
        })
    }

    fn set_property(&mut self, m: &Message, path: &str) -> Message {
        let Ok((i, n, v)) = m.read3::<&str, &str, Variant<Box<dyn RefArg>>>() else {
            return error(
                m,
                "org.freedesktop.DBus.Error.InvalidArgs",
                "expected (s, s, v)",
            );
        };
        match (path, i, n, cast::<bool>(&*v.0)) {
            (ADAPTER, ADAPTER1, "Powered", Some(on)) => {
                self.set(ADAPTER, ADAPTER1, "Powered", Value::Bool(*on));
                m.method_return()
            }
            _ => error(
                m,
                "org.freedesktop.DBus.Error.PropertyReadOnly",
                &format!("{i}.{n} cannot be set here"),
            ),
        }
    }

    fn connect(&mut self, m: &Message, path: &str) -> Option<Message> {
        let now = Instant::now();
        let (i, _) = self.unit_at(path)?;
        let u = self.units.get_mut(i)?;
        if u.radio != Radio::Down {
            return Some(m.method_return());
        }
        self.report.connect_attempts += 1;
        if !u.reachable(now) {
            // The controller's connection attempt runs out without an answer.
            let reply = failed(m, "le-connection-abort-by-local");
            self.later.push((now + self.options.connect_timeout, reply));
            return None;
        }
        if u.epoch.is_none() {
            u.epoch = Some(now);
        }
        let t = u.time(now);
        u.unit.device.advance(t);
        let info = u.unit.device.connect(t, self.options.mtu)?;
        u.info = info;
        u.radio = Radio::Up;
        let path = u.path.clone();
        self.report.connections += 1;
        self.set(&path, DEVICE1, "Connected", Value::Bool(true));
        if !self.tree.has(&gatt::path(&path, Gatt::Stream)) {
            for (at, ifaces) in gatt::objects(&path, self.options.mtu) {
                let m = self.tree.add(&at, ifaces);
                self.send(Some(m));
            }
        }
        self.set(&path, DEVICE1, "UUIDs", Value::Strs(gatt::service_uuids()));
        self.set(&path, DEVICE1, "ServicesResolved", Value::Bool(true));
        Some(m.method_return())
    }

    fn characteristic(&mut self, m: &Message, path: &str, member: &str) -> Option<Message> {
        let now = Instant::now();
        let (i, g) = self.unit_at(path)?;
        let mtu = self.options.mtu;
        let u = self.units.get_mut(i)?;
        if u.epoch.is_some() {
            let t = u.time(now);
            u.unit.device.advance(t);
        }
        let up = u.radio == Radio::Up && u.unit.device.connected();
        let breaking = matches!(u.radio, Radio::Breaking(_))
            || (u.radio == Radio::Up && !u.unit.device.connected());
        let reply = match (member, g) {
            (_, None) => return Some(failed(m, "not a characteristic")),
            ("ReadValue" | "WriteValue" | "StartNotify", _) if breaking => {
                // No ATT response: BlueZ fails the request when it notices the link is gone.
                u.stalled.push(m.duplicate().ok()?);
                return None;
            }
            ("ReadValue" | "WriteValue" | "StartNotify", _) if !up => failed(m, "Not connected"),
            ("ReadValue", Some(Gatt::Info)) => m.method_return().append1(u.info.clone()),
            ("ReadValue", Some(Gatt::Results)) => m.method_return().append1(u.results.clone()),
            ("ReadValue", _) => error(m, "org.bluez.Error.NotPermitted", "Read not permitted"),
            ("WriteValue", Some(Gatt::Control)) => {
                let Ok((bytes, _)) = m.read2::<Vec<u8>, PropMap>() else {
                    return Some(error(
                        m,
                        "org.bluez.Error.InvalidArguments",
                        "expected (ay, a{sv})",
                    ));
                };
                if bytes.len() > usize::from(mtu.saturating_sub(3)) {
                    error(m, "org.bluez.Error.InvalidValueLength", "Invalid Length")
                } else {
                    self.report.writes += 1;
                    u.unit.device.write(&bytes);
                    m.method_return()
                }
            }
            ("WriteValue", _) => error(m, "org.bluez.Error.NotPermitted", "Write not permitted"),
            ("StartNotify", Some(Gatt::Stream)) => {
                u.notifying_stream = true;
                u.subscriber = m.sender().map(|s| s.to_string());
                return self.notifying(m, path, true);
            }
            ("StartNotify", Some(Gatt::Results)) => {
                u.notifying_results = true;
                u.subscriber = m.sender().map(|s| s.to_string());
                return self.notifying(m, path, true);
            }
            ("StartNotify", _) => error(
                m,
                "org.bluez.Error.NotSupported",
                "Operation is not supported",
            ),
            ("StopNotify", Some(Gatt::Stream)) => {
                u.notifying_stream = false;
                return self.notifying(m, path, false);
            }
            ("StopNotify", Some(Gatt::Results)) => {
                u.notifying_results = false;
                return self.notifying(m, path, false);
            }
            ("StopNotify", _) => failed(m, "No notify session started"),
            _ => error(
                m,
                "org.freedesktop.DBus.Error.UnknownMethod",
                &format!("{CHAR1}.{member} is not implemented by the stand-in"),
            ),
        };
        Some(reply)
    }

    fn notifying(&mut self, m: &Message, path: &str, on: bool) -> Option<Message> {
        self.set(path, CHAR1, "Notifying", Value::Bool(on));
        Some(m.method_return())
    }
}
