//! The exported object tree: BlueZ's objects, their interfaces and properties, as
//! `GetManagedObjects`, `Properties.Get/GetAll` and `Introspect` show them. Every change
//! goes through [`Tree::set`], [`Tree::add`] or [`Tree::remove`], which return the signal
//! BlueZ would emit (PropertiesChanged, InterfacesAdded, InterfacesRemoved).

use dbus::arg::{PropMap, RefArg, Variant};
use dbus::blocking::stdintf::org_freedesktop_dbus::{
    ObjectManagerInterfacesAdded, ObjectManagerInterfacesRemoved, PropertiesPropertiesChanged,
};
use dbus::message::SignalArgs;
use dbus::{Message, Path};
use std::collections::{BTreeMap, HashMap};

/// A property value, of the D-Bus types BlueZ's properties use here.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    /// `s`
    Str(String),
    /// `b`
    Bool(bool),
    /// `n`
    I16(i16),
    /// `q`
    U16(u16),
    /// `o`
    Path(String),
    /// `as`
    Strs(Vec<String>),
    /// `ay`
    Bytes(Vec<u8>),
}

impl Value {
    fn signature(&self) -> &'static str {
        match self {
            Value::Str(_) => "s",
            Value::Bool(_) => "b",
            Value::I16(_) => "n",
            Value::U16(_) => "q",
            Value::Path(_) => "o",
            Value::Strs(_) => "as",
            Value::Bytes(_) => "ay",
        }
    }

    /// As a D-Bus variant. A path that is not a valid object path (none is built so)
    /// goes as a string rather than panicking.
    pub fn variant(&self) -> Variant<Box<dyn RefArg>> {
        Variant(match self {
            Value::Str(s) => Box::new(s.clone()),
            Value::Bool(b) => Box::new(*b),
            Value::I16(n) => Box::new(*n),
            Value::U16(n) => Box::new(*n),
            Value::Path(p) => match Path::new(p.clone()) {
                Ok(p) => Box::new(p),
                Err(s) => Box::new(s),
            },
            Value::Strs(v) => Box::new(v.clone()),
            Value::Bytes(v) => Box::new(v.clone()),
        })
    }
}

/// An interface's properties by name.
pub type Props = BTreeMap<&'static str, Value>;

/// The interfaces of one object by name.
pub type Interfaces = BTreeMap<&'static str, Props>;

fn prop_map(props: &Props) -> PropMap {
    props
        .iter()
        .map(|(k, v)| (k.to_string(), v.variant()))
        .collect()
}

fn path(p: &str) -> Path<'static> {
    Path::new(p.to_string()).unwrap_or_default()
}

/// The objects, by path.
#[derive(Default)]
pub struct Tree {
    objects: BTreeMap<String, Interfaces>,
}

impl Tree {
    /// Export an object; the InterfacesAdded signal.
    pub fn add(&mut self, at: &str, interfaces: Interfaces) -> Message {
        let signal = ObjectManagerInterfacesAdded {
            object: path(at),
            interfaces: interfaces
                .iter()
                .map(|(k, v)| (k.to_string(), prop_map(v)))
                .collect(),
        };
        self.objects.insert(at.to_string(), interfaces);
        signal.to_emit_message(&path("/"))
    }

    /// Remove an object and those below it; their InterfacesRemoved signals.
    pub fn remove(&mut self, at: &str) -> Vec<Message> {
        let below = format!("{at}/");
        let gone: Vec<String> = self
            .objects
            .keys()
            .filter(|k| *k == at || k.starts_with(&below))
            .cloned()
            .collect();
        gone.into_iter()
            .rev()
            .filter_map(|k| {
                let ifaces = self.objects.remove(&k)?;
                let signal = ObjectManagerInterfacesRemoved {
                    object: path(&k),
                    interfaces: ifaces.keys().map(|s| s.to_string()).collect(),
                };
                Some(signal.to_emit_message(&path("/")))
            })
            .collect()
    }

    /// Whether an object is exported.
    pub fn has(&self, at: &str) -> bool {
        self.objects.contains_key(at)
    }

    /// A property.
    pub fn get(&self, at: &str, iface: &str, name: &str) -> Option<&Value> {
        self.objects.get(at)?.get(iface)?.get(name)
    }

    /// An interface's properties.
    pub fn get_all(&self, at: &str, iface: &str) -> Option<PropMap> {
        Some(prop_map(self.objects.get(at)?.get(iface)?))
    }

    /// Change a property; the PropertiesChanged signal if it changed (a characteristic's
    /// `Value` is signalled every time: a notification of the same bytes is news).
    pub fn set(&mut self, at: &str, iface: &str, name: &'static str, v: Value) -> Option<Message> {
        let props = self.objects.get_mut(at)?.get_mut(iface)?;
        if props.get(name) == Some(&v) && name != "Value" {
            return None;
        }
        let mut changed = Props::new();
        changed.insert(name, v.clone());
        props.insert(name, v);
        let signal = PropertiesPropertiesChanged {
            interface_name: iface.to_string(),
            changed_properties: prop_map(&changed),
            invalidated_properties: Vec::new(),
        };
        Some(signal.to_emit_message(&path(at)))
    }

    /// `GetManagedObjects`: every object with its interfaces and properties.
    pub fn managed_objects(&self) -> HashMap<Path<'static>, HashMap<String, PropMap>> {
        self.objects
            .iter()
            .map(|(p, ifaces)| {
                let i = ifaces
                    .iter()
                    .map(|(k, v)| (k.to_string(), prop_map(v)))
                    .collect();
                (path(p), i)
            })
            .collect()
    }

    /// `Introspect`: the object's interfaces (properties only: methods are BlueZ's, and
    /// btleplug reads none from here) and its direct children, which is what bluez-async
    /// walks to find services, characteristics and descriptors.
    pub fn introspect(&self, at: &str) -> String {
        let mut xml = String::from(
            "<!DOCTYPE node PUBLIC \"-//freedesktop//DTD D-BUS Object Introspection 1.0//EN\" \
             \"http://www.freedesktop.org/standards/dbus/1.0/introspect.dtd\">\n<node>\n\
             <interface name=\"org.freedesktop.DBus.Introspectable\"><method name=\"Introspect\">\
             <arg name=\"xml\" type=\"s\" direction=\"out\"/></method></interface>\n",
        );
        if let Some(ifaces) = self.objects.get(at) {
            for (name, props) in ifaces {
                xml.push_str(&format!("<interface name=\"{name}\">"));
                for (p, v) in props {
                    xml.push_str(&format!(
                        "<property name=\"{p}\" type=\"{}\" access=\"read\"/>",
                        v.signature()
                    ));
                }
                xml.push_str("</interface>\n");
            }
        }
        let prefix = if at == "/" {
            "/".to_string()
        } else {
            format!("{at}/")
        };
        let mut children: Vec<&str> = self
            .objects
            .keys()
            .filter_map(|k| k.strip_prefix(&prefix))
            .filter_map(|rest| rest.split('/').next())
            .filter(|c| !c.is_empty())
            .collect();
        children.dedup();
        for c in children {
            xml.push_str(&format!("<node name=\"{c}\"/>\n"));
        }
        xml.push_str("</node>\n");
        xml
    }
}
