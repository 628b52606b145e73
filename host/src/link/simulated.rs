//! A rotacal device on the host: the firmware's logic (`rotacal_shared::device::Device`,
//! the same code the Feather runs) fed by the simulator's sensor stream at the sensor's
//! output rate, behind the [`Link`] trait. It runs on tokio's clock, so under a paused
//! runtime (the demo, the tests) a 15-minute session takes seconds of CPU.
//!
//! Faults on demand, for the recorder's tests and for dry runs: link outages (the device
//! keeps sampling; what it sends meanwhile is lost, as when the firmware's queue finds no
//! connection), dropped notifications, garbage notifications, and a wrong firmware or
//! protocol version.

use super::{Channel, Link, LinkError};
use crate::simulate::device::Conversion;
use crate::simulate::Simulation;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rotacal_shared::device::{Config, Device, RING};
use rotacal_shared::packet::{Chip, Packet};
use rotacal_shared::Condition;
use std::collections::VecDeque;
use std::time::Duration;
use tokio::time::Instant;

/// What goes wrong, and when.
#[derive(Clone, Debug, PartialEq)]
pub struct Faults {
    /// Link outages (start, length), seconds after the first connection.
    pub outages: Vec<(f64, f64)>,
    /// Probability that a stream notification is lost while connected.
    pub drop_probability: f64,
    /// After every this many notifications, one of random bytes.
    pub garbage_every: Option<u32>,
    /// The firmware version the device-info value reports.
    pub firmware: [u8; 3],
    /// Byte 0 (the protocol version) of every packet, if not the real one.
    pub protocol_version: Option<u8>,
    /// Seed of the drops and the garbage.
    pub seed: u64,
}

impl Default for Faults {
    fn default() -> Self {
        Faults {
            outages: Vec::new(),
            drop_probability: 0.0,
            garbage_every: None,
            firmware: FIRMWARE,
            protocol_version: None,
            seed: 1,
        }
    }
}

/// The firmware version the simulated device reports by default (the firmware crate's).
pub const FIRMWARE: [u8; 3] = [0, 2, 0];

/// The counter value at the first connection: near 2³² so the 32-bit TIMER wraps early.
const COUNTER_START: u64 = 0xFFF0_0000;
const COUNTER_MASK: u64 = 0xFFFF_FFFF;
/// How often the firmware reads the die temperature, and polls for aged batches.
const TEMPERATURE_EVERY: Duration = Duration::from_secs(1);
const POLL_EVERY: Duration = Duration::from_millis(100);
/// How long a connection attempt takes to fail while the device is out of reach.
const CONNECT_ATTEMPT: Duration = Duration::from_secs(2);

/// See the module documentation.
pub struct SimulatedDevice {
    device: Device<RING>,
    /// The sensor's conversions per condition (x, y, z), from the simulator.
    streams: [Vec<Conversion>; 3],
    faults: Faults,
    rng: ChaCha8Rng,
    /// Set at the first connection; device time runs from it.
    epoch: Option<Instant>,
    connected: bool,
    /// Device time processed up to.
    now: Duration,
    /// The running condition's stream, its start time and the next conversion.
    running: Option<(usize, Duration, usize)>,
    next_temperature: Duration,
    next_poll: Duration,
    out: VecDeque<(Channel, Vec<u8>)>,
    notifications: u64,
}

impl SimulatedDevice {
    /// A device whose sensor sees what `sim` simulates. `sim` should run at the sensor's
    /// output rate (104 Hz for the Feather's LSM6DS33), in counts, within i16.
    pub fn new(sim: &Simulation, faults: Faults) -> anyhow::Result<Self> {
        let streams = crate::simulate::device::conversions(sim)?;
        Ok(SimulatedDevice {
            device: Device::new(Config::FEATHER),
            streams,
            rng: ChaCha8Rng::seed_from_u64(faults.seed),
            faults,
            epoch: None,
            connected: false,
            now: Duration::ZERO,
            running: None,
            next_temperature: Duration::ZERO,
            next_poll: Duration::ZERO,
            out: VecDeque::new(),
            notifications: 0,
        })
    }

    fn elapsed(&self) -> Duration {
        self.epoch.map_or(Duration::ZERO, |e| Instant::now() - e)
    }

    /// The outage covering device time `t`, if any.
    fn outage_at(&self, t: Duration) -> Option<usize> {
        let s = t.as_secs_f64();
        self.faults
            .outages
            .iter()
            .position(|&(a, len)| s >= a && s < a + len)
    }

    fn capture(t: Duration) -> u64 {
        (COUNTER_START + t.as_micros() as u64) & COUNTER_MASK
    }

    fn send(&mut self, p: Packet) {
        if !self.connected {
            return;
        }
        let ch = match p {
            Packet::Samples(_) | Packet::Averages(_) | Packet::Temperature(_) => Channel::Stream,
            Packet::Info(_) => Channel::Info,
            _ => Channel::Results,
        };
        if ch == Channel::Stream
            && self.faults.drop_probability > 0.0
            && self.rng.gen::<f64>() < self.faults.drop_probability
        {
            return;
        }
        self.out.push_back((ch, self.encode(&p)));
        self.notifications += 1;
        if let Some(n) = self.faults.garbage_every {
            if n > 0 && self.notifications % u64::from(n) == 0 {
                let len = self.rng.gen_range(1..40);
                let junk = (0..len).map(|_| self.rng.gen()).collect();
                self.out.push_back((Channel::Stream, junk));
            }
        }
    }

    fn encode(&self, p: &Packet) -> Vec<u8> {
        let mut v = crate::recording::from_device::encode(p);
        if let (Some(b), Some(ver)) = (v.first_mut(), self.faults.protocol_version) {
            *b = ver;
        }
        v
    }

    /// Run the device up to device time `t`: conversions, temperatures, polls.
    fn advance_to(&mut self, t: Duration) {
        loop {
            let conv = self.running.and_then(|(c, start, k)| {
                let x = self.streams.get(c)?.get(k)?;
                Some(start + Duration::from_secs_f64(x.t))
            });
            let next = [Some(self.next_poll), conv]
                .into_iter()
                .flatten()
                .chain(self.running.map(|_| self.next_temperature))
                .min()
                .unwrap_or(t);
            if next > t {
                break;
            }
            self.now = next;
            self.connected &= self.outage_at(next).is_none();
            let mut packets = Vec::new();
            if conv == Some(next) {
                if let Some((c, start, k)) = self.running {
                    if let Some(x) = self.streams.get(c).and_then(|s| s.get(k)).copied() {
                        self.device
                            .on_sample(Self::capture(next), x.counts, false, &mut |p| {
                                packets.push(p)
                            });
                        self.running = Some((c, start, k + 1));
                    }
                }
            } else if next == self.next_poll {
                self.device
                    .poll(Self::capture(next), &mut |p| packets.push(p));
                self.next_poll += POLL_EVERY;
            } else {
                if let Some((c, _, k)) = self.running {
                    if let Some(x) = self.streams.get(c).and_then(|s| s.get(k.saturating_sub(1))) {
                        let centi = (x.temp_c * 100.0).round() as i16;
                        self.device.on_temperature(centi, &mut |p| packets.push(p));
                    }
                }
                self.next_temperature += TEMPERATURE_EVERY;
            }
            for p in packets {
                self.send(p);
            }
        }
        self.now = self.now.max(t);
    }

    fn sync(&mut self) {
        let t = self.elapsed();
        self.advance_to(t);
        if self.connected && self.outage_at(t).is_some() {
            self.connected = false;
        }
    }

    fn command(&mut self, bytes: &[u8]) {
        // The firmware ignores (and logs) a write that isn't a command.
        let Ok(Packet::Command(cmd)) = Packet::decode(bytes) else {
            return;
        };
        let before = self.device.status().state;
        let mut packets = Vec::new();
        self.device.on_command(cmd, &mut |p| packets.push(p));
        let status = self.device.status();
        if let rotacal_shared::packet::Command::Start { condition, .. } = cmd {
            if status.state != before && status.last_error.is_none() {
                self.start(condition);
            }
        }
        if status.state != rotacal_shared::packet::RunState::Running {
            self.running = None;
        }
        for p in packets {
            self.send(p);
        }
    }

    fn start(&mut self, condition: Condition) {
        self.running = Some((condition.index(), self.now, 0));
        self.next_temperature = self.now + TEMPERATURE_EVERY / 2;
    }
}

impl Link for SimulatedDevice {
    async fn connect(&mut self) -> Result<Vec<u8>, LinkError> {
        if self.epoch.is_none() {
            self.epoch = Some(Instant::now());
        }
        self.sync();
        if self.outage_at(self.elapsed()).is_some() {
            tokio::time::sleep(CONNECT_ATTEMPT).await;
            self.sync();
            return Err(LinkError::Disconnected(
                "no advertisement from the device".into(),
            ));
        }
        self.connected = true;
        self.out.clear();
        let info = self.device.info(Chip::Lsm6ds33, self.faults.firmware);
        Ok(self.encode(&Packet::Info(info)))
    }

    async fn write(&mut self, command: &[u8]) -> Result<(), LinkError> {
        self.sync();
        if !self.connected {
            return Err(LinkError::Disconnected(
                "write failed: not connected".into(),
            ));
        }
        self.command(command);
        Ok(())
    }

    async fn next(&mut self, timeout: Duration) -> Result<Option<(Channel, Vec<u8>)>, LinkError> {
        let deadline = self.elapsed() + timeout;
        loop {
            self.sync();
            if let Some(v) = self.out.pop_front() {
                return Ok(Some(v));
            }
            if !self.connected {
                return Err(LinkError::Disconnected("supervision timeout".into()));
            }
            let now = self.elapsed();
            if now >= deadline {
                return Ok(None);
            }
            // Packets go out at conversions and polls; waking at each poll (100 ms) is
            // enough, since the notification time carries no data (the samples carry
            // their own timestamps).
            let wake = self.next_poll.min(deadline).max(now);
            tokio::time::sleep(wake - now).await;
        }
    }

    fn describe(&self) -> String {
        "simulated device (the firmware's logic on this host)".into()
    }
}

impl std::str::FromStr for Faults {
    type Err = String;

    /// `outage=AT:LEN` (seconds; repeatable), `drop=P`, `garbage=N`, `firmware=A.B.C`,
    /// `protocol=V`, `seed=N`, comma-separated.
    fn from_str(s: &str) -> Result<Self, String> {
        let mut f = Faults::default();
        for item in s.split(',').map(str::trim).filter(|i| !i.is_empty()) {
            let (k, v) = item
                .split_once('=')
                .ok_or_else(|| format!("'{item}': expected key=value"))?;
            let bad = |what: &str| format!("'{item}': {what}");
            let num = |x: &str| -> Result<f64, String> {
                x.parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite() && *x >= 0.0)
                    .ok_or_else(|| bad("not a non-negative number"))
            };
            match k {
                "outage" => {
                    let (a, l) = v.split_once(':').ok_or_else(|| bad("expected AT:LEN"))?;
                    f.outages.push((num(a)?, num(l)?));
                }
                "drop" => {
                    let p = num(v)?;
                    if p >= 1.0 {
                        return Err(bad("a probability below 1"));
                    }
                    f.drop_probability = p;
                }
                "garbage" => {
                    f.garbage_every = Some(
                        v.parse()
                            .ok()
                            .filter(|n| *n > 0)
                            .ok_or_else(|| bad("a positive whole number of notifications"))?,
                    )
                }
                "firmware" => {
                    let parts: Vec<u8> = v
                        .split('.')
                        .map(|p| p.parse().map_err(|_| bad("expected A.B.C")))
                        .collect::<Result<_, _>>()?;
                    f.firmware = parts
                        .try_into()
                        .map_err(|_| bad("expected three numbers A.B.C"))?;
                }
                "protocol" => {
                    f.protocol_version = Some(v.parse().map_err(|_| bad("expected 0–255"))?)
                }
                "seed" => f.seed = v.parse().map_err(|_| bad("expected a whole number"))?,
                _ => {
                    return Err(format!(
                        "'{k}': unknown fault (outage, drop, garbage, firmware, protocol, seed)"
                    ))
                }
            }
        }
        Ok(f)
    }
}
