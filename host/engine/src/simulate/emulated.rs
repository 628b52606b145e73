//! A rotacal device on the host: the firmware's logic (`rotacal_shared::device::Device`,
//! the same code the Feather runs) fed by the simulator's sensor stream at the sensor's
//! output rate, on an explicit device clock. The link shells drive it: the recorder's
//! simulated [`Link`](../../../rotacal/link/trait.Link.html) on tokio's clock, and the
//! BlueZ stand-in (`host/bluez-standin`) on the wall clock behind D-Bus.
//!
//! Packets leave through the firmware's own routing and queues (`rotacal_shared::device::
//! route`): as deep as the board's, drained one notification at a time at the link's pace,
//! kept while the link is down, and a backfill and its status reply offered only the room
//! there is ([`Device::pump`]). As the firmware's BLE task does, a notification waits in
//! its queue until the host has subscribed to its characteristic on the current link, and
//! one longer than the link's MTU allows is dropped (its samples are fetched again); the
//! device logic sizes batches to the MTU of each connection ([`Device::set_link_mtu`]).
//!
//! The sensor is an LSM6DS33, whose data-ready line is latched: a read that comes late
//! (faults `late=P`, `stuck=AT:MS`) finds newer conversions in the registers, and goes
//! through the firmware's own pairing (`rotacal_shared::device::pairing`) and counting of
//! the conversions not read.
//!
//! Faults on demand: link outages (the device keeps sampling; what it sends meanwhile waits
//! in the queues while they have room, and the rest is dropped), dropped notifications (one at
//! a time or in bursts), garbage notifications, a wrong firmware or protocol version, a
//! different unit after the first outage, and a device that stops answering commands.

use crate::recording::from_device::{encode, Channel};
use crate::simulate::device::Conversion;
use crate::simulate::Simulation;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rotacal_shared::device::pairing::{pair, Read};
use rotacal_shared::device::route::{self, Room, RESULTS_QUEUE, STREAM_QUEUE};
use rotacal_shared::device::sampler::Conversion as ConversionRead;
use rotacal_shared::device::{Config, Device, RING, WATCHDOG_MS};
use rotacal_shared::packet::{kind, Chip, Command, Packet, RunState};
use rotacal_shared::Condition;
use std::collections::VecDeque;
use std::io;
use std::time::Duration;

/// What goes wrong, and when.
#[derive(Clone, Debug, PartialEq)]
pub struct Faults {
    /// Link outages (start, length), seconds after the first connection.
    pub outages: Vec<(f64, f64)>,
    /// Fraction of stream notifications lost while connected.
    pub drop_probability: f64,
    /// Mean length of a run of lost notifications (1: each lost on its own).
    pub burst: Option<f64>,
    /// After every this many notifications, one of random bytes.
    pub garbage_every: Option<u32>,
    /// The firmware version the device-info value reports.
    pub firmware: [u8; 3],
    /// Byte 0 (the protocol version) of every packet, if not the real one.
    pub protocol_version: Option<u8>,
    /// After the first outage, a different unit answers: this firmware version.
    pub replaced: Option<[u8; 3]>,
    /// The device answers this many commands, then none (it takes no more either).
    pub mute_after: Option<u32>,
    /// Seed of the drops and the garbage.
    pub seed: u64,
    /// The ATT MTU the central agrees with the device (247 unless it asks for less).
    pub mtu: u16,
    /// Fraction of the sensor's conversions whose read comes after the next conversion
    /// (each such conversion is overwritten, never read).
    pub late_probability: f64,
    /// Reads stuck (start, length): no conversion in the window is read, seconds after the
    /// first connection.
    pub stuck: Vec<(f64, f64)>,
    /// The board resets (a watchdog or a panic) at these times, seconds after the first
    /// connection: its logic starts afresh, idle, and its radio is silent for a second.
    pub resets: Vec<f64>,
    /// The firmware's executor hangs at these times (start, length): no event is handled,
    /// no notification sent, no command taken, while the SoftDevice keeps the link; the
    /// watchdog then resets the board.
    pub hangs: Vec<(f64, f64)>,
    /// The first status notification at each of these is lost on the air: a command's
    /// reply that never comes.
    pub lost_statuses: Vec<When>,
    /// The first sample batch at each of these is lost on the air.
    pub lost_batches: Vec<When>,
    /// Fraction of sample batches (live and replayed) delivered with one bit flipped (a
    /// corruption past the link layer's CRC).
    pub flip_probability: f64,
    /// The first sample batch at each of these is delivered with this bit flipped (bit
    /// `8 k + j` is bit j of byte k, the protocol version's byte being byte 0).
    pub flipped_bits: Vec<(When, usize)>,
    /// The first notification on the results characteristic (a fit report, the
    /// quick-look or a status) at each of these is delivered with a bit flipped.
    pub flipped_results: Vec<When>,
    /// The first sample batch at each of these is delivered twice.
    pub twice_batches: Vec<When>,
    /// The first sample batch at each of these is delivered after the next.
    pub late_batches: Vec<When>,
    /// One notification leaves the firmware's queues this often: a slower link (a longer
    /// connection interval, fewer notifications an event) replays more slowly.
    pub notify_every: Duration,
}

/// When a one-off fault strikes: at the first notification of its kind from a time, or
/// from a condition's first start (whose first sample batch it then strikes).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum When {
    /// Seconds after the first connection.
    From(f64),
    /// The condition, from its first start.
    In(Condition),
}

impl When {
    fn due(self, now: f64, running: Option<Condition>) -> bool {
        match self {
            When::From(at) => now >= at,
            When::In(c) => running == Some(c),
        }
    }
}

impl Default for Faults {
    fn default() -> Self {
        Faults {
            outages: Vec::new(),
            drop_probability: 0.0,
            burst: None,
            garbage_every: None,
            firmware: FIRMWARE,
            protocol_version: None,
            replaced: None,
            mute_after: None,
            seed: 1,
            mtu: route::MAX_MTU,
            late_probability: 0.0,
            stuck: Vec::new(),
            resets: Vec::new(),
            hangs: Vec::new(),
            lost_statuses: Vec::new(),
            lost_batches: Vec::new(),
            flip_probability: 0.0,
            flipped_bits: Vec::new(),
            flipped_results: Vec::new(),
            twice_batches: Vec::new(),
            late_batches: Vec::new(),
            notify_every: NOTIFY_EVERY,
        }
    }
}

/// The firmware version the simulated device reports by default (the firmware crate's).
pub const FIRMWARE: [u8; 3] = [0, 2, 0];

/// The counter value at the first connection: near 2³² so the 32-bit TIMER wraps early.
const COUNTER_START: u64 = 0xFFF0_0000;
const COUNTER_MASK: u64 = 0xFFFF_FFFF;
/// Seconds from a reset until the board advertises again.
const BOOT_S: f64 = 1.0;

/// How long after a conversion the firmware's read of it begins (task latency).
const READ_LATENCY: Duration = Duration::from_micros(150);
/// How often the firmware reads the die temperature, and polls for aged batches.
const TEMPERATURE_EVERY: Duration = Duration::from_secs(1);
const POLL_EVERY: Duration = Duration::from_millis(100);
/// One notification leaves the firmware's queues this often while connected, unless
/// [`Faults::notify_every`] says otherwise: a 30 ms connection interval (BlueZ's and
/// Apple's usual) with three notifications an event. The live stream needs about 2.3 a
/// second; a 20 s backfill (46 batches) about half a second.
const NOTIFY_EVERY: Duration = Duration::from_millis(10);
/// The firmware's notification queues, in the order its BLE task serves them, with their
/// depths: [`EmulatedDevice::queues`] holds them in this order.
const QUEUES: [(Channel, usize); 2] = [
    (Channel::Stream, STREAM_QUEUE),
    (Channel::Results, RESULTS_QUEUE),
];

/// See the module documentation. Device time runs from the first connection.
pub struct EmulatedDevice {
    device: Device<RING>,
    /// The sensor's conversions per condition (x, y, z), from the simulator.
    streams: [Vec<Conversion>; 3],
    faults: Faults,
    rng: ChaCha8Rng,
    connected: bool,
    /// Device time processed up to.
    now: Duration,
    /// The running condition's stream, its start time and the next conversion.
    running: Option<(Condition, Duration, usize)>,
    next_temperature: Duration,
    next_poll: Duration,
    /// The firmware's notification queues ([`QUEUES`]), as deep as its own: kept while the
    /// link is down, a packet offered to a full one is dropped.
    queues: [VecDeque<(Channel, Vec<u8>)>; 2],
    /// Whether the host has subscribed to each queue's characteristic on this link.
    subscribed: [bool; 2],
    /// The link's MTU.
    mtu: u16,
    /// Notifications dropped for being longer than the link's MTU allows.
    oversize: u64,
    /// The first conversion not read since the last read: where the latched data-ready
    /// line rose.
    unread_since: Option<Duration>,
    /// Conversions the sensor made that the firmware did not read (late or stuck reads).
    unread: u64,
    /// Draws the late reads (apart from the link's faults, so that they do not move).
    read_rng: ChaCha8Rng,
    /// The one-off faults taken so far, by their index in [`Faults::lost_statuses`],
    /// [`Faults::lost_batches`], [`Faults::flipped_bits`], [`Faults::twice_batches`] and
    /// [`Faults::late_batches`].
    statuses_lost: Vec<usize>,
    batches_lost: Vec<usize>,
    bits_flipped: Vec<usize>,
    results_flipped: Vec<usize>,
    twice_done: Vec<usize>,
    late_done: Vec<usize>,
    /// Notifications delivered with a bit flipped ([`Faults::flip_probability`],
    /// [`Faults::flipped_bits`], [`Faults::flipped_results`]).
    flipped: u64,
    /// The batch held back to go after the next ([`Faults::late_batches`]).
    held_back: Option<(Channel, Vec<u8>)>,
    /// Resets done so far ([`Faults::resets`]), and when the last one was.
    resets_done: usize,
    boot_at: Duration,
    /// The condition the table turns, since when: it turns on through a reset, so a
    /// condition started again after one goes on where the table is.
    table: Option<(Condition, Duration)>,
    reset_since_start: bool,
    /// When the next notification may leave them.
    next_notify: Duration,
    /// Delivered to the host, in order.
    out: VecDeque<(Channel, Vec<u8>)>,
    notifications: u64,
    /// In a burst of lost notifications.
    losing: bool,
    commands: u32,
}

impl EmulatedDevice {
    /// A device whose sensor sees what `sim` simulates. `sim` should run at the sensor's
    /// output rate (104 Hz for the Feather's LSM6DS33), in counts, within i16.
    pub fn new(sim: &Simulation, faults: Faults) -> io::Result<Self> {
        let streams = crate::simulate::device::conversions(sim)?;
        Ok(EmulatedDevice {
            device: Device::new(Config::FEATHER),
            streams,
            rng: ChaCha8Rng::seed_from_u64(faults.seed),
            read_rng: ChaCha8Rng::seed_from_u64(faults.seed ^ 0x1A7E_5EAD),
            faults,
            connected: false,
            now: Duration::ZERO,
            running: None,
            next_temperature: Duration::ZERO,
            next_poll: Duration::ZERO,
            queues: [VecDeque::new(), VecDeque::new()],
            subscribed: [false; 2],
            mtu: route::MAX_MTU,
            oversize: 0,
            unread_since: None,
            unread: 0,
            resets_done: 0,
            statuses_lost: Vec::new(),
            batches_lost: Vec::new(),
            bits_flipped: Vec::new(),
            results_flipped: Vec::new(),
            twice_done: Vec::new(),
            late_done: Vec::new(),
            flipped: 0,
            held_back: None,
            boot_at: Duration::ZERO,
            table: None,
            reset_since_start: false,
            next_notify: Duration::ZERO,
            out: VecDeque::new(),
            notifications: 0,
            losing: false,
            commands: 0,
        })
    }

    /// The outage covering device time `t`, if any.
    fn outage_at(&self, t: Duration) -> Option<usize> {
        let s = t.as_secs_f64();
        self.faults
            .outages
            .iter()
            .position(|&(a, len)| s >= a && s < a + len)
    }

    /// Whether the device can be reached (advertises, accepts a connection) at `t`.
    pub fn reachable(&self, t: Duration) -> bool {
        self.outage_at(t).is_none()
    }

    /// Whether the link is up (as of the last [`advance`](Self::advance)).
    pub fn connected(&self) -> bool {
        self.connected
    }

    /// The next instant the device does something by itself (a poll of its batches): a
    /// link shell need not look before it.
    pub fn next_wake(&self) -> Duration {
        self.next_poll
    }

    /// The firmware version the device reports at `t`.
    fn firmware_at(&self, t: Duration) -> [u8; 3] {
        let s = t.as_secs_f64();
        match self.faults.replaced {
            Some(f) if self.faults.outages.iter().any(|&(a, len)| s >= a + len) => f,
            _ => self.faults.firmware,
        }
    }

    /// The TIMER's count at `t`: it starts afresh at each boot, as the board's does.
    fn capture(&self, t: Duration) -> u64 {
        let since_boot = t.saturating_sub(self.boot_at);
        (COUNTER_START + since_boot.as_micros() as u64) & COUNTER_MASK
    }

    /// The firmware's read of the conversion made at `t`, or `None` when it comes too
    /// late (a newer conversion overwrites it) or reads are stuck.
    fn read(&mut self, t: Duration, counts: [i16; 3]) -> Option<ConversionRead> {
        let s = t.as_secs_f64();
        let stuck = self
            .faults
            .stuck
            .iter()
            .any(|&(a, len)| s >= a && s < a + len);
        let late = self.faults.late_probability > 0.0
            && self.read_rng.gen::<f64>() < self.faults.late_probability;
        if stuck || late {
            self.unread += 1;
            self.unread_since.get_or_insert(t);
            return None;
        }
        // The latched line rose at the first conversion since the last read.
        let edge = self.unread_since.take().unwrap_or(t);
        let raw = |t: Duration| self.capture(t) as u32;
        let read = Read {
            capture: raw(edge),
            capture_after: raw(edge),
            read_start: raw(t + READ_LATENCY),
            edges: 0,
            edges_after: 0,
            counts,
            latched: true,
        };
        Some(pair(&read, Config::FEATHER.conversion_ticks()))
    }

    /// Whether the firmware's executor is hung at `t` ([`Faults::hangs`]).
    fn hung_at(&self, t: Duration) -> bool {
        let s = t.as_secs_f64();
        self.faults
            .hangs
            .iter()
            .any(|&(a, len)| s >= a && s < a + len)
    }

    /// The board's reset, if one is due by `t`: the device logic starts afresh (idle,
    /// sequence numbers and device time from zero, an empty ring) and what waited in the
    /// queues is gone.
    fn reset_if_due(&mut self, t: Duration) {
        if !take_due(&self.faults.resets, &mut self.resets_done, t.as_secs_f64()) {
            return;
        }
        self.boot_at = t;
        self.reset_since_start = true;
        self.device = Device::new(Config::FEATHER);
        let mut packets = Vec::new();
        self.device.set_link_mtu(self.mtu, &mut |p| packets.push(p));
        self.queues = [VecDeque::new(), VecDeque::new()];
        self.running = None;
        self.unread_since = None;
        self.connected = false;
    }

    /// Conversions the sensor made that the firmware did not read.
    pub fn unread(&self) -> u64 {
        self.unread
    }

    /// Notifications delivered with a bit flipped.
    pub fn flipped(&self) -> u64 {
        self.flipped
    }

    fn lost(&mut self) -> bool {
        let p = self.faults.drop_probability;
        if p <= 0.0 {
            return false;
        }
        match self.faults.burst {
            None => self.rng.gen::<f64>() < p,
            // Gilbert's two states: a burst ends with probability 1/L per notification, and
            // one starts with the probability that makes the long-run fraction lost p.
            Some(len) => {
                let len = len.max(1.0);
                let (stay, start) = (1.0 - 1.0 / len, p / (len * (1.0 - p)));
                let u = self.rng.gen::<f64>();
                self.losing = if self.losing { u < stay } else { u < start };
                self.losing
            }
        }
    }

    /// A packet from the device logic into its characteristic's queue, as the firmware
    /// routes it (a full queue drops it; the info value is set, not queued).
    fn send(&mut self, p: Packet) {
        let Some(ch) = Channel::of(&p) else {
            return;
        };
        let Some(queue) = QUEUES.iter().position(|(c, _)| *c == ch) else {
            return;
        };
        if self.queued() == 0 {
            self.next_notify = self.next_notify.max(self.now);
        }
        if self.free(queue) > 0 {
            let v = self.encode(&p);
            if let Some(q) = self.queues.get_mut(queue) {
                q.push_back((ch, v));
            }
        }
    }

    /// Free places in queue `i` of [`QUEUES`].
    fn free(&self, i: usize) -> usize {
        let depth = QUEUES.get(i).map_or(0, |(_, d)| *d);
        depth.saturating_sub(self.queues.get(i).map_or(depth, VecDeque::len))
    }

    /// Packets waiting in the queues.
    fn queued(&self) -> usize {
        self.queues.iter().map(VecDeque::len).sum()
    }

    /// Packets waiting in the queues whose characteristic the host subscribed to.
    fn deliverable(&self) -> usize {
        self.queues
            .iter()
            .zip(self.subscribed)
            .filter(|(_, on)| *on)
            .map(|(q, _)| q.len())
            .sum()
    }

    /// The queues' free places.
    fn room(&self) -> Room {
        Room {
            stream: self.free(0),
            results: self.free(1),
        }
    }

    /// What the device logic owes (a backfill, a status reply), offered the free places.
    fn pump(&mut self) {
        let mut packets = Vec::new();
        self.device.pump(self.room(), &mut |p| packets.push(p));
        for p in packets {
            self.send(p);
        }
    }

    /// One notification leaves the queues (the stream's first, as the firmware's BLE task
    /// selects it first); a stream notification may be lost on the air.
    fn notify(&mut self) {
        let Some((ch, mut v)) = self
            .queues
            .iter_mut()
            .zip(self.subscribed)
            .filter(|(_, on)| *on)
            .find_map(|(q, _)| q.pop_front())
        else {
            return;
        };
        if v.len() > route::payload(self.mtu) {
            self.oversize += 1;
            return;
        }
        if ch == Channel::Stream && self.lost() {
            return;
        }
        // Told by the kind byte: no notification is decoded here.
        let now = self.now.as_secs_f64();
        let running = self.running.map(|(c, _, _)| c);
        let kind = v.get(1).copied();
        let batch = ch == Channel::Stream && kind == Some(kind::SAMPLES);
        if kind == Some(kind::STATUS)
            && take_when(
                &self.faults.lost_statuses,
                &mut self.statuses_lost,
                now,
                running,
            )
        {
            return;
        }
        if !batch {
            if ch == Channel::Results
                && take_when(
                    &self.faults.flipped_results,
                    &mut self.results_flipped,
                    now,
                    running,
                )
            {
                // A bit of the first field after the header.
                self.flipped += u64::from(flip(&mut v, 8 * 4));
            }
            self.deliver(ch, v, false);
            return;
        }
        if take_when(
            &self.faults.lost_batches,
            &mut self.batches_lost,
            now,
            running,
        ) {
            return;
        }
        let p = self.faults.flip_probability;
        if p > 0.0 && self.rng.gen::<f64>() < p {
            let bit = self.rng.gen_range(0..v.len().max(1) * 8);
            self.flipped += u64::from(flip(&mut v, bit));
        }
        let bits = &self.faults.flipped_bits;
        if let Some(i) = take_which(bits, |(w, _)| *w, &mut self.bits_flipped, now, running) {
            let bit = self.faults.flipped_bits.get(i).map_or(0, |(_, b)| *b);
            self.flipped += u64::from(flip(&mut v, bit));
        }
        if take_when(&self.faults.late_batches, &mut self.late_done, now, running) {
            self.held_back = Some((ch, v));
            return;
        }
        let twice = take_when(
            &self.faults.twice_batches,
            &mut self.twice_done,
            now,
            running,
        );
        self.deliver(ch, v, twice);
    }

    /// A notification goes on the air (twice if `twice`), then a batch held back behind
    /// a sample batch, and now and then one of garbage.
    fn deliver(&mut self, ch: Channel, v: Vec<u8>, twice: bool) {
        let batch = ch == Channel::Stream && v.get(1) == Some(&kind::SAMPLES);
        if twice {
            self.out.push_back((ch, v.clone()));
        }
        self.out.push_back((ch, v));
        if batch {
            if let Some(late) = self.held_back.take() {
                self.out.push_back(late);
            }
        }
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
        let mut v = encode(p);
        if let (Some(b), Some(ver)) = (v.first_mut(), self.faults.protocol_version) {
            *b = ver;
        }
        v
    }

    /// Run the device up to device time `t`: conversions, temperatures, polls. The link
    /// goes down where an outage starts.
    pub fn advance(&mut self, t: Duration) {
        loop {
            let conv = self.running.and_then(|(c, start, k)| {
                let x = self.streams.get(c.index())?.get(k)?;
                Some(start + Duration::from_secs_f64(x.t))
            });
            let notify = (self.connected && self.deliverable() > 0).then_some(self.next_notify);
            let next = [Some(self.next_poll), conv, notify]
                .into_iter()
                .flatten()
                .chain(self.running.map(|_| self.next_temperature))
                .min()
                .unwrap_or(t);
            if next > t {
                break;
            }
            self.now = next;
            self.reset_if_due(next);
            self.connected &= self.outage_at(next).is_none();
            let mut packets = Vec::new();
            let hung = self.hung_at(next);
            if notify == Some(next) {
                if self.connected && !hung {
                    self.notify();
                }
                self.next_notify = next + self.faults.notify_every;
            } else if conv == Some(next) {
                if let Some((c, start, k)) = self.running {
                    if let Some(x) = self.streams.get(c.index()).and_then(|s| s.get(k)).copied() {
                        if let Some(conv) = self.read(next, x.counts).filter(|_| !hung) {
                            self.device.on_conversion(&conv, &mut |p| packets.push(p));
                        }
                        self.running = Some((c, start, k + 1));
                    }
                }
            } else if next == self.next_poll {
                if !hung {
                    self.device
                        .poll(self.capture(next), &mut |p| packets.push(p));
                }
                self.next_poll += POLL_EVERY;
            } else {
                if let Some((c, _, k)) = self.running.filter(|_| !hung) {
                    if let Some(x) = self
                        .streams
                        .get(c.index())
                        .and_then(|s| s.get(k.saturating_sub(1)))
                    {
                        let centi = (x.temp_c * 100.0).round() as i16;
                        self.device.on_temperature(centi, &mut |p| packets.push(p));
                    }
                }
                self.next_temperature += TEMPERATURE_EVERY;
            }
            for p in packets {
                self.send(p);
            }
            if !hung {
                self.pump();
            }
        }
        self.now = self.now.max(t);
        self.connected &= self.outage_at(t).is_none();
    }

    /// Connect at `t` (after [`advance`](Self::advance) to it) with ATT MTU `mtu`: the
    /// device-info value, or `None` while the device is out of reach. What was in flight
    /// on the old link is gone; what waits in the firmware's queues goes out on the new
    /// one once the host subscribes ([`subscribe`](Self::subscribe)).
    pub fn connect(&mut self, t: Duration, mtu: u16) -> Option<Vec<u8>> {
        if !self.reachable(t) {
            return None;
        }
        self.connected = true;
        self.subscribed = [false; 2];
        self.mtu = mtu;
        let mut packets = Vec::new();
        self.device.set_link_mtu(mtu, &mut |p| packets.push(p));
        for p in packets {
            self.send(p);
        }
        self.next_notify = self.next_notify.max(t);
        self.out.clear();
        let info = self.device.info(Chip::Lsm6ds33, self.firmware_at(t));
        Some(self.encode(&Packet::Info(info)))
    }

    /// The host subscribes to (or unsubscribes from) `ch`'s notifications on this link.
    pub fn subscribe(&mut self, ch: Channel, on: bool) {
        let Some(i) = QUEUES.iter().position(|(c, _)| *c == ch) else {
            return;
        };
        if self.deliverable() == 0 {
            // Nothing was waiting to go: the next notification may leave at once.
            self.next_notify = self.next_notify.max(self.now);
        }
        if let Some(s) = self.subscribed.get_mut(i) {
            *s = on;
        }
    }

    /// Notifications dropped because they were longer than the link's MTU allows.
    pub fn oversize(&self) -> u64 {
        self.oversize
    }

    /// The link closed by the host.
    pub fn disconnect(&mut self) {
        self.connected = false;
        self.out.clear();
    }

    /// A write to the control characteristic at the current time; false when not connected.
    pub fn write(&mut self, bytes: &[u8]) -> bool {
        if !self.connected {
            return false;
        }
        self.commands += 1;
        // A hung executor never takes the command the SoftDevice received.
        if self.faults.mute_after.is_some_and(|n| self.commands > n) || self.hung_at(self.now) {
            return true;
        }
        // The firmware ignores (and logs) a write that isn't a command.
        let Ok(Packet::Command(cmd)) = Packet::decode(bytes) else {
            return true;
        };
        let before = self.device.status().state;
        let mut packets = Vec::new();
        self.device.command(cmd, &mut |p| packets.push(p));
        let status = self.device.status();
        if let Command::Start { condition, .. } = cmd {
            if status.state != before && status.last_error.is_none() {
                self.start(condition);
            }
        }
        if status.state != RunState::Running {
            self.running = None;
            self.unread_since = None;
        }
        for p in packets {
            self.send(p);
        }
        self.pump();
        true
    }

    /// The next value the device sent, in order.
    pub fn pop(&mut self) -> Option<(Channel, Vec<u8>)> {
        self.out.pop_front()
    }

    fn start(&mut self, condition: Condition) {
        // The stream starts on a whole microsecond (a tick of the 1 MHz clock), so the
        // conversions' ticks relative to it do not depend on the moment the Start came.
        let start = Duration::from_micros(self.now.as_nanos().div_ceil(1000) as u64);
        self.next_temperature = start + TEMPERATURE_EVERY / 2;
        match self.table {
            Some((c, since)) if c == condition && self.reset_since_start => {
                let stream = self.streams.get(c.index()).map_or(&[][..], Vec::as_slice);
                let k = stream.partition_point(|x| since + Duration::from_secs_f64(x.t) < start);
                self.running = Some((condition, since, k));
            }
            _ => {
                self.running = Some((condition, start, 0));
                self.table = Some((condition, start));
            }
        }
        self.reset_since_start = false;
    }
}

/// Whether the first of `times` (sorted, seconds) after the `done` already taken has come
/// by `now`; if so it is taken (`done` counts it).
fn take_due(times: &[f64], done: &mut usize, now: f64) -> bool {
    let due = times.get(*done).is_some_and(|at| now >= *at);
    if due {
        *done += 1;
    }
    due
}

/// Whether one of `whens` not yet `taken` (indices) is due; if so it is taken.
fn take_when(whens: &[When], taken: &mut Vec<usize>, now: f64, running: Option<Condition>) -> bool {
    take_which(whens, |w| *w, taken, now, running).is_some()
}

/// The index of the first of `faults` not yet `taken` whose time (`when`) is due, now
/// taken.
fn take_which<T>(
    faults: &[T],
    when: impl Fn(&T) -> When,
    taken: &mut Vec<usize>,
    now: f64,
    running: Option<Condition>,
) -> Option<usize> {
    let i = faults
        .iter()
        .enumerate()
        .position(|(i, f)| !taken.contains(&i) && when(f).due(now, running))?;
    taken.push(i);
    Some(i)
}

/// Flips bit `bit` of `v` (bit j of byte k is `8 k + j`); whether it was inside.
fn flip(v: &mut [u8], bit: usize) -> bool {
    v.get_mut(bit / 8).map(|b| *b ^= 1 << (bit % 8)).is_some()
}

/// Why a `--faults` list is refused; `item` is the `key=value` concerned.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum FaultsError {
    /// No `=` in the item.
    #[error("'{item}': expected key=value")]
    NotKeyValue {
        /// The item.
        item: String,
    },
    /// A known key with a value it does not take.
    #[error("'{item}': {expected}")]
    BadValue {
        /// The item.
        item: String,
        /// What the value must be.
        expected: &'static str,
    },
    /// A key that names no fault.
    #[error(
        "'{key}': unknown fault (outage, drop, burst, garbage, firmware, protocol, replaced, \
         mute_after, seed, mtu, late, stuck, reset, panic, hang, lost_status, lost_batch, flip, \
         flip_bit, flip_result, twice_batch, late_batch, notify_every)"
    )]
    UnknownFault {
        /// The key.
        key: String,
    },
}

fn version(v: &str, bad: &dyn Fn(&'static str) -> FaultsError) -> Result<[u8; 3], FaultsError> {
    let parts: Vec<u8> = v
        .split('.')
        .map(|p| p.parse().map_err(|_| bad("expected A.B.C")))
        .collect::<Result<_, _>>()?;
    parts
        .try_into()
        .map_err(|_| bad("expected three numbers A.B.C"))
}

impl std::str::FromStr for Faults {
    type Err = FaultsError;

    /// `outage=AT:LEN` (seconds; repeatable), `drop=P`, `burst=L`, `garbage=N`,
    /// `firmware=A.B.C`, `protocol=V`, `replaced=A.B.C`, `mute_after=N`, `seed=N`,
    /// `mtu=N` (the ATT MTU of the simulated link, 23 to 517), `late=P` (a fraction of
    /// the sensor's conversions read too late, so never read), `stuck=AT:MS` (reads stuck
    /// for MS milliseconds from AT seconds; repeatable), `reset=AT` (the board resets at AT
    /// seconds; repeatable; `panic=AT` the same, from a panic), `hang=AT` (the logic stops
    /// at AT and the watchdog resets the board [`WATCHDOG_MS`] later), `lost_status=AT` (the
    /// first status notification from AT is lost; repeatable), `lost_batch=AT` (the same
    /// for a sample batch), `flip=P` (a fraction of sample batches with one bit flipped),
    /// `flip_bit=AT:BIT` (the first sample batch from AT with bit BIT flipped, bit j of byte
    /// k being 8 k + j), `flip_result=AT` (the same for the first notification on the
    /// results characteristic, a bit of its first field), `twice_batch=AT` and
    /// `late_batch=AT` (the first sample batch from AT delivered twice, or after the next
    /// one); comma-separated. For the one-off faults
    /// from `lost_status` on, AT is seconds or a condition's letter (from its first start,
    /// so `lost_batch=y` is y's first batch) and each is repeatable; `notify_every=MS`, one
    /// notification leaves the queues every MS milliseconds (10 unless said: a slower link).
    fn from_str(s: &str) -> Result<Self, FaultsError> {
        let mut f = Faults::default();
        for item in s.split(',').map(str::trim).filter(|i| !i.is_empty()) {
            let (k, v) = item
                .split_once('=')
                .ok_or_else(|| FaultsError::NotKeyValue { item: item.into() })?;
            let bad = |expected: &'static str| FaultsError::BadValue {
                item: item.into(),
                expected,
            };
            let num = |x: &str| -> Result<f64, FaultsError> {
                x.parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite() && *x >= 0.0)
                    .ok_or_else(|| bad("not a non-negative number"))
            };
            // A condition's letter, or seconds after the first connection.
            let when = |x: &str| -> Result<When, FaultsError> {
                let mut letters = x.chars();
                match (
                    letters.next().and_then(Condition::from_letter),
                    letters.next(),
                ) {
                    (Some(c), None) => Ok(When::In(c)),
                    _ => num(x).map(When::From),
                }
            };
            let probability = |x: &str| -> Result<f64, FaultsError> {
                num(x).and_then(|p| {
                    if p < 1.0 {
                        Ok(p)
                    } else {
                        Err(bad("a probability below 1"))
                    }
                })
            };
            match k {
                "outage" => {
                    let (a, l) = v.split_once(':').ok_or_else(|| bad("expected AT:LEN"))?;
                    f.outages.push((num(a)?, num(l)?));
                }
                "drop" => f.drop_probability = probability(v)?,
                "burst" => {
                    let l = num(v)?;
                    if l < 1.0 {
                        return Err(bad("a mean burst length of at least 1 notification"));
                    }
                    f.burst = Some(l);
                }
                "garbage" => {
                    f.garbage_every = Some(
                        v.parse()
                            .ok()
                            .filter(|n| *n > 0)
                            .ok_or_else(|| bad("a positive whole number of notifications"))?,
                    )
                }
                "firmware" => f.firmware = version(v, &bad)?,
                "replaced" => f.replaced = Some(version(v, &bad)?),
                "protocol" => {
                    f.protocol_version = Some(v.parse().map_err(|_| bad("expected 0–255"))?)
                }
                "mute_after" => {
                    f.mute_after = Some(v.parse().map_err(|_| bad("expected a whole number"))?)
                }
                "seed" => f.seed = v.parse().map_err(|_| bad("expected a whole number"))?,
                "lost_status" => f.lost_statuses.push(when(v)?),
                "lost_batch" => f.lost_batches.push(when(v)?),
                "flip" => f.flip_probability = probability(v)?,
                "flip_bit" => {
                    let (w, b) = v.split_once(':').ok_or_else(|| bad("expected AT:BIT"))?;
                    let bit = b.parse().map_err(|_| bad("a bit number: 8 × byte + bit"))?;
                    f.flipped_bits.push((when(w)?, bit));
                }
                "notify_every" => {
                    let ms = num(v)?;
                    if !(1.0..=4000.0).contains(&ms) {
                        return Err(bad("milliseconds from 1 to 4000"));
                    }
                    f.notify_every = Duration::from_secs_f64(ms / 1000.0);
                }
                "flip_result" => f.flipped_results.push(when(v)?),
                "twice_batch" => f.twice_batches.push(when(v)?),
                "late_batch" => f.late_batches.push(when(v)?),
                "late" => f.late_probability = probability(v)?,
                // A panic resets the board at once (the build for boards without a probe).
                "reset" | "panic" => {
                    let at = num(v)?;
                    f.resets.push(at);
                    // Booting and advertising again take about a second.
                    f.outages.push((at, BOOT_S));
                }
                // The logic stops taking events, and the watchdog, no longer petted, resets
                // the board WATCHDOG_MS later.
                "hang" => {
                    let at = num(v)?;
                    let watchdog = f64::from(WATCHDOG_MS) / 1000.0;
                    f.hangs.push((at, watchdog));
                    f.resets.push(at + watchdog);
                    f.outages.push((at + watchdog, BOOT_S));
                }
                "stuck" => {
                    let (a, l) = v.split_once(':').ok_or_else(|| bad("expected AT:MS"))?;
                    f.stuck.push((num(a)?, num(l)? / 1000.0));
                }
                "mtu" => {
                    f.mtu = v
                        .parse()
                        .ok()
                        .filter(|m| (23..=517).contains(m))
                        .ok_or_else(|| bad("an ATT MTU from 23 to 517"))?
                }
                _ => return Err(FaultsError::UnknownFault { key: k.into() }),
            }
        }
        f.resets.sort_by(f64::total_cmp);
        Ok(f)
    }
}
