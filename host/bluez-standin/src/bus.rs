//! A private system bus: `dbus-daemon` started on a socket in a folder of the caller's,
//! with a policy that lets the stand-in own `org.bluez` and anyone call it (the machine's
//! system bus, if any, is not touched). A client finds it through
//! `DBUS_SYSTEM_BUS_ADDRESS`, as btleplug (libdbus) does.

use std::io::{self, BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};

/// See the module documentation. The daemon is killed on drop.
pub struct PrivateBus {
    child: Child,
    /// The address to put in `DBUS_SYSTEM_BUS_ADDRESS`.
    pub address: String,
}

const CONFIG: &str = r#"<!DOCTYPE busconfig PUBLIC "-//freedesktop//DTD D-Bus Bus Configuration 1.0//EN"
 "http://www.freedesktop.org/standards/dbus/1.0/busconfig.dtd">
<busconfig>
  <type>system</type>
  <listen>unix:path=SOCKET</listen>
  <auth>EXTERNAL</auth>
  <policy context="default">
    <allow user="*"/>
    <allow own="*"/>
    <allow send_type="method_call"/>
    <allow send_type="signal"/>
    <allow send_type="method_return"/>
    <allow send_type="error"/>
    <allow receive_type="method_call"/>
    <allow receive_type="signal"/>
    <allow receive_type="method_return"/>
    <allow receive_type="error"/>
  </policy>
</busconfig>
"#;

impl PrivateBus {
    /// Start `dbus-daemon` with its socket and configuration in `dir`.
    pub fn start(dir: &Path) -> io::Result<PrivateBus> {
        std::fs::create_dir_all(dir)?;
        let socket = dir.join("system_bus_socket");
        let config = dir.join("bus.conf");
        std::fs::write(&config, CONFIG.replace("SOCKET", &socket.to_string_lossy()))?;
        let log = dir.join("dbus-daemon.log");
        let mut child = Command::new("dbus-daemon")
            .arg(format!("--config-file={}", config.display()))
            .args(["--nofork", "--nopidfile", "--print-address=1"])
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&log)?)
            .spawn()
            .map_err(|e| {
                io::Error::new(
                    e.kind(),
                    format!(
                        "cannot start dbus-daemon ({e}): it is in Debian's package dbus-daemon \
                         (scripts/test-all installs it)"
                    ),
                )
            })?;
        let mut line = String::new();
        if let Some(out) = child.stdout.take() {
            BufReader::new(out).read_line(&mut line)?;
        }
        let address = line.trim().to_string();
        if address.is_empty() {
            let _ = child.kill();
            let _ = child.wait();
            return Err(io::Error::other(format!(
                "dbus-daemon printed no address: {}",
                std::fs::read_to_string(&log).unwrap_or_default().trim()
            )));
        }
        Ok(PrivateBus { child, address })
    }
}

impl Drop for PrivateBus {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
