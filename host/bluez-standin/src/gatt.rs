//! The device's GATT database as BlueZ exports it after service discovery: the Generic
//! Attribute service BlueZ always shows, and the rotacal service of docs/protocol.md with
//! its four characteristics and the notifying ones' CCCDs. Handles (the numbers in the
//! object paths) are what a Feather's SoftDevice would assign in that order.

use crate::tree::{Interfaces, Props, Value};

/// The rotacal service (docs/protocol.md, GATT).
pub const SERVICE: &str = "7f1e0001-52a1-4b8e-9c3d-5ad1c0ca1e00";
const GENERIC_ATTRIBUTE: &str = "00001801-0000-1000-8000-00805f9b34fb";
const SERVICE_CHANGED: &str = "00002a05-0000-1000-8000-00805f9b34fb";
const CCCD: &str = "00002902-0000-1000-8000-00805f9b34fb";

/// A characteristic of the rotacal service.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Gatt {
    /// Samples and temperatures (notify).
    Stream,
    /// Commands (write).
    Control,
    /// Fit reports, quick-look, status (notify, read).
    Results,
    /// Device info (read).
    Info,
}

const ROTACAL: &str = "service000a";

impl Gatt {
    const ALL: [Gatt; 4] = [Gatt::Stream, Gatt::Control, Gatt::Results, Gatt::Info];

    fn node(self) -> &'static str {
        match self {
            Gatt::Stream => "char000b",
            Gatt::Control => "char000e",
            Gatt::Results => "char0010",
            Gatt::Info => "char0013",
        }
    }

    fn uuid(self) -> &'static str {
        match self {
            Gatt::Stream => "7f1e0002-52a1-4b8e-9c3d-5ad1c0ca1e00",
            Gatt::Control => "7f1e0003-52a1-4b8e-9c3d-5ad1c0ca1e00",
            Gatt::Results => "7f1e0004-52a1-4b8e-9c3d-5ad1c0ca1e00",
            Gatt::Info => "7f1e0005-52a1-4b8e-9c3d-5ad1c0ca1e00",
        }
    }

    fn flags(self) -> &'static [&'static str] {
        match self {
            Gatt::Stream => &["notify"],
            Gatt::Control => &["write"],
            Gatt::Results => &["read", "notify"],
            Gatt::Info => &["read"],
        }
    }

    /// Its CCCD's node, for the notifying ones.
    fn cccd(self) -> Option<&'static str> {
        match self {
            Gatt::Stream => Some("desc000d"),
            Gatt::Results => Some("desc0012"),
            Gatt::Control | Gatt::Info => None,
        }
    }
}

/// The object path of characteristic `g` of the device at `device`.
pub fn path(device: &str, g: Gatt) -> String {
    format!("{device}/{ROTACAL}/{}", g.node())
}

/// Which rotacal characteristic `path` is, under the device at `device`.
pub fn which(device: &str, path: &str) -> Option<Gatt> {
    Gatt::ALL
        .into_iter()
        .find(|g| self::path(device, *g) == path)
}

/// The advertised-and-discovered service UUIDs (Device1.UUIDs once resolved).
pub fn service_uuids() -> Vec<String> {
    vec![GENERIC_ATTRIBUTE.to_string(), SERVICE.to_string()]
}

fn one(iface: &'static str, props: Vec<(&'static str, Value)>) -> Interfaces {
    [(iface, props.into_iter().collect::<Props>())]
        .into_iter()
        .collect()
}

fn characteristic(service: &str, uuid: &str, flags: &[&str], mtu: u16) -> Interfaces {
    let mut p = vec![
        ("UUID", Value::Str(uuid.into())),
        ("Service", Value::Path(service.into())),
        (
            "Flags",
            Value::Strs(flags.iter().map(|f| f.to_string()).collect()),
        ),
        ("MTU", Value::U16(mtu)),
    ];
    if flags.contains(&"notify") || flags.contains(&"indicate") {
        p.push(("Notifying", Value::Bool(false)));
    }
    if flags.contains(&"read") || flags.contains(&"notify") {
        p.push(("Value", Value::Bytes(Vec::new())));
    }
    one("org.bluez.GattCharacteristic1", p)
}

fn descriptor(characteristic: &str) -> Interfaces {
    one(
        "org.bluez.GattDescriptor1",
        vec![
            ("UUID", Value::Str(CCCD.into())),
            ("Characteristic", Value::Path(characteristic.into())),
        ],
    )
}

fn service(device: &str, uuid: &str) -> Interfaces {
    one(
        "org.bluez.GattService1",
        vec![
            ("UUID", Value::Str(uuid.into())),
            ("Primary", Value::Bool(true)),
            ("Device", Value::Path(device.into())),
        ],
    )
}

/// Every object of the device's GATT database, parents first, with `mtu` as the MTU
/// BlueZ negotiated.
pub fn objects(device: &str, mtu: u16) -> Vec<(String, Interfaces)> {
    let ga = format!("{device}/service0001");
    let sc = format!("{ga}/char0002");
    let rc = format!("{device}/{ROTACAL}");
    let mut out = vec![
        (ga.clone(), service(device, GENERIC_ATTRIBUTE)),
        (
            sc.clone(),
            characteristic(&ga, SERVICE_CHANGED, &["indicate"], mtu),
        ),
        (format!("{sc}/desc0004"), descriptor(&sc)),
        (rc.clone(), service(device, SERVICE)),
    ];
    for g in Gatt::ALL {
        let at = path(device, g);
        out.push((at.clone(), characteristic(&rc, g.uuid(), g.flags(), mtu)));
        if let Some(d) = g.cccd() {
            out.push((format!("{at}/{d}"), descriptor(&at)));
        }
    }
    out
}
