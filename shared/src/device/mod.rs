//! The firmware's logic, without hardware: everything between "the sensor's data-ready
//! edge was captured at timer value c and the sample read" and "these packets go out".
//! The firmware crate only wires drivers, BLE and tasks to a [`Device`]; the same code
//! runs in the host's tests and on the emulated Cortex-M4F (tests/qemu `session`).
//!
//! Data path: [`sampler`] (64-bit timestamps, every conversion summed into the sample
//! rate's slots, sequence numbers) → [`ring`] (recent samples, for backfill) and [`packetiser`] (sample batches)
//! → [`session`] (the condition's streaming fit, fit reports, the quick-look).
//! Output goes through a callback, so nothing here allocates or blocks.

pub mod bus_recovery;
pub mod packetiser;
pub mod pairing;
pub mod ring;
pub mod route;
pub mod sampler;
pub mod session;
pub mod simulated;

use crate::packet::{
    Chip, ClockSource, Command, CommandError, DeviceInfo, Packet, RunState, SensorStatus, Status,
    Temperature,
};
use crate::time::TickRate;
use packetiser::Packetiser;
use ring::{Replay, Ring};
use route::{Room, MAX_MTU};
use sampler::{Conversion, Sampler, StreamSample};
use session::Session;

/// Samples the Feather keeps for backfill: 40 s at 16 Hz, 17.5 KiB of RAM (28 bytes
/// each, [`ring`]). An outage loses nothing when the ring still holds its first sample as
/// the host asks again: the outage, plus the link's supervision timeout, the reconnection
/// and the batches in flight as the link dropped (docs/recording.md).
pub const RING: usize = 640;

/// The firmware's watchdog resets the board when its logic has taken no event for this
/// long, ms. The sensor sends 104 events a second while converting, a poll every 100 ms
/// while its data-ready line is quiet and a status every second while it is missing, so a
/// silence this long means the executor is stuck.
pub const WATCHDOG_MS: u32 = 4000;

/// How the device is set up.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Config {
    /// The timestamp clock.
    pub clock: TickRate,
    /// What drives it.
    pub clock_source: ClockSource,
    /// Width of the hardware counter the captures come from (32 for a TIMER, 24 for the RTC).
    pub counter_bits: u32,
    /// The sensor's output data rate, mHz.
    pub sensor_odr_mhz: u32,
    /// The rate samples are streamed and fitted at, mHz (at most the ODR).
    pub sample_rate_mhz: u32,
    /// Publish a periodic fit report every this many samples of a condition (0: never).
    pub publish_every: u32,
    /// Longest a sample waits in a part-filled batch, ticks.
    pub max_batch_age: u64,
    /// Gravity for the quick-look, m/s² (the host's calibration uses the lab's value).
    pub g_loc: f64,
    /// Full scale, ±g (reported in the device info).
    pub full_scale_g: u8,
}

impl Config {
    /// The sensor's conversion period in ticks of the timestamp clock, × 1000 (0 for a
    /// rate of 0).
    pub const fn conversion_milli(&self) -> u64 {
        if self.sensor_odr_mhz == 0 {
            0
        } else {
            self.clock.hz() as u64 * 1_000_000 / self.sensor_odr_mhz as u64
        }
    }

    /// The sensor's conversion period in whole ticks (9615 at 104 Hz and 1 MHz).
    pub const fn conversion_ticks(&self) -> u32 {
        let t = self.conversion_milli() / 1000;
        if t > u32::MAX as u64 {
            u32::MAX
        } else {
            t as u32
        }
    }

    /// The Feather nRF52840 Sense: TIMER at 1 MHz on the crystal, sensor at 104 Hz,
    /// 16 Hz stream, a fit report every 10 s, batches at most 1 s old, ±2 g.
    pub const FEATHER: Config = Config {
        clock: TickRate::MHZ_1,
        clock_source: ClockSource::TimerHfxo,
        counter_bits: 32,
        sensor_odr_mhz: 104_000,
        sample_rate_mhz: 16_000,
        publish_every: 160,
        max_batch_age: 1_000_000,
        g_loc: 9.80665,
        full_scale_g: 2,
    };
}

/// The device's logic. `RING` is the number of recent samples kept for backfill.
#[derive(Clone, Debug)]
pub struct Device<const RING: usize> {
    cfg: Config,
    sampler: Sampler,
    ring: Ring<RING>,
    live: Packetiser,
    session: Session,
    sensor: SensorStatus,
    lost: u32,
    last_error: Option<CommandError>,
    latest: Option<StreamSample>,
    /// A backfill still being sent ([`Device::pump`]).
    replay: Option<Replay>,
    /// A command's status reply is owed: it goes once any replay is sent.
    reply_owed: bool,
    /// The link's ATT MTU ([`Device::set_link_mtu`]).
    mtu: u16,
}

/// `out`, less what would not fit one notification at `mtu`: below [`route::MIN_MTU`]
/// nothing runs, and a batch sized for an earlier link is not sent truncated (the host
/// fetches its samples again).
fn link(mtu: u16, out: &mut impl FnMut(Packet)) -> impl FnMut(Packet) + '_ {
    move |p| {
        if route::fits(&p, mtu) {
            out(p);
        }
    }
}

impl<const RING: usize> Device<RING> {
    /// A device in the idle state.
    pub fn new(cfg: Config) -> Self {
        Device {
            cfg,
            sampler: Sampler::new(&cfg),
            ring: Ring::new(),
            live: Packetiser::new(false, route::batch_len(MAX_MTU).unwrap_or(1)),
            session: Session::new(cfg.clock, cfg.publish_every, cfg.g_loc),
            sensor: SensorStatus::Ok,
            lost: 0,
            last_error: None,
            latest: None,
            replay: None,
            reply_owed: false,
            mtu: MAX_MTU,
        }
    }

    /// The link's ATT MTU, as the central and the device agreed it (the device assumes
    /// [`MAX_MTU`], the most it grants, until told): batches are sized to it
    /// ([`route::batch_len`]), and below [`route::MIN_MTU`] Start and Backfill are refused
    /// with [`CommandError::MtuTooSmall`]. A part-filled batch too long for a smaller MTU
    /// is split.
    pub fn set_link_mtu(&mut self, mtu: u16, out: &mut impl FnMut(Packet)) {
        if mtu == self.mtu {
            return;
        }
        self.mtu = mtu;
        let out = &mut link(mtu, out);
        let n = route::batch_len(mtu).unwrap_or(1);
        self.live.set_max(n, out);
        if let Some(r) = &mut self.replay {
            r.set_max(n, out);
        }
    }

    /// The link's ATT MTU as last set.
    pub fn link_mtu(&self) -> u16 {
        self.mtu
    }

    /// The device-info value.
    pub fn info(&self, chip: Chip, firmware: [u8; 3]) -> DeviceInfo {
        DeviceInfo {
            firmware,
            chip,
            clock: self.cfg.clock_source,
            tick_hz: self.cfg.clock.hz(),
            sensor_odr_mhz: self.cfg.sensor_odr_mhz,
            sample_rate_mhz: self.sampler.sample_rate_mhz(),
            full_scale_g: self.cfg.full_scale_g,
            ring_capacity: u16::try_from(RING).unwrap_or(u16::MAX),
        }
    }

    /// The current status.
    pub fn status(&self) -> Status {
        let (ring_oldest, ring_newest) = self.ring.span();
        Status {
            state: self.session.state(),
            sensor: self.sensor,
            condition: self.session.condition(),
            lost: self.lost,
            ring_oldest,
            ring_newest,
            last_error: self.last_error,
        }
    }

    /// Samples streamed since power-up (the next sequence number).
    pub fn streamed(&self) -> u32 {
        self.sampler.streamed()
    }

    /// The quick-look, once x, y and z are done.
    pub fn quick_look(&self) -> Option<crate::packet::QuickLook> {
        self.session.quick_look()
    }

    /// A data-ready edge captured at raw counter value `capture`, and the conversion read
    /// after it. `late`: the edge was missed and `capture` is the read time. As
    /// [`Device::on_conversion`] without a hardware edge count.
    pub fn on_sample(
        &mut self,
        capture: u64,
        counts: [i16; 3],
        late: bool,
        out: &mut impl FnMut(Packet),
    ) {
        let c = Conversion {
            capture,
            counts,
            late,
            edges: None,
        };
        self.on_conversion(&c, out);
    }

    /// A conversion read. Every one goes in; a stream sample comes out when one closes a
    /// slot. Conversions the sensor made that were not read (a late or stuck read) are
    /// counted: in the status's `lost` and in the flags of the sample whose slot they fell
    /// in ([`crate::packet::SampleFlags::MISSED`]).
    pub fn on_conversion(&mut self, c: &Conversion, out: &mut impl FnMut(Packet)) {
        let out = &mut link(self.mtu, out);
        let running = self.session.state() == RunState::Running;
        let (sample, missed) = self.sampler.accept(c, running);
        self.lost = self.lost.saturating_add(missed);
        let Some(s) = sample else {
            return;
        };
        let Some(cond) = self.session.condition() else {
            return;
        };
        self.latest = Some(s);
        self.ring.push(ring::Entry {
            sample: s,
            condition: cond,
        });
        self.live.push(&s, cond, out);
        self.session.on_sample(&s, out);
    }

    /// A temperature reading, hundredths of °C: streamed with the latest sample's seq.
    pub fn on_temperature(&mut self, centi_c: i16, out: &mut impl FnMut(Packet)) {
        if self.session.state() != RunState::Running {
            return;
        }
        if let Some(s) = self.latest {
            link(self.mtu, out)(Packet::Temperature(Temperature {
                seq: s.seq,
                centi_c,
            }));
        }
    }

    /// Conversions lost before they reached the device logic (a full event queue).
    pub fn on_lost(&mut self, n: u32) {
        self.lost = self.lost.saturating_add(n);
    }

    /// The sensor's health changed.
    pub fn on_sensor_status(&mut self, s: SensorStatus, out: &mut impl FnMut(Packet)) {
        if s != self.sensor {
            self.sensor = s;
            out(Packet::Status(self.status()));
        }
    }

    /// Call now and then (every ~100 ms) with the current raw counter value: sends a
    /// part-filled batch once its oldest sample is `max_batch_age` old.
    pub fn poll(&mut self, now_capture: u64, out: &mut impl FnMut(Packet)) {
        let now = self.sampler.peek_time(now_capture);
        let out = &mut link(self.mtu, out);
        self.live.flush_if_older(now, self.cfg.max_batch_age, out);
    }

    /// A command from the host, with its replay and its status reply sent at once (a link
    /// without queues; the firmware uses [`Device::command`] and [`Device::pump`]).
    pub fn on_command(&mut self, cmd: Command, out: &mut impl FnMut(Packet)) {
        self.command(cmd, out);
        self.pump(Room::UNLIMITED, out);
    }

    /// Send what is owed, as the link has room: a backfill's batches, then the status reply
    /// to the last command (after the batches it answers for, so the host has them when
    /// it reads the reply). Call after every event, with the queues' free places. True when
    /// nothing is owed any more.
    pub fn pump(&mut self, room: Room, out: &mut impl FnMut(Packet)) -> bool {
        let out = &mut link(self.mtu, out);
        if let Some(r) = &mut self.replay {
            if r.send(&self.ring, room.stream, out) {
                self.replay = None;
            }
        }
        if self.replay.is_none() && self.reply_owed && room.results > 0 {
            self.reply_owed = false;
            out(Packet::Status(self.status()));
        }
        self.replay.is_none() && !self.reply_owed
    }

    /// A command from the host: it acts at once (a Stop's last batch and final fit go out
    /// through `out`); a backfill's replay and the status reply are owed, for
    /// [`Device::pump`]. Refusals set `last_error` and are reported in the status. A
    /// backfill replaces one still being sent (the host asks again when a reply is late).
    pub fn command(&mut self, cmd: Command, out: &mut impl FnMut(Packet)) {
        let out = &mut link(self.mtu, out);
        let batch = route::batch_len(self.mtu);
        let result = match cmd {
            Command::Start {
                condition,
                rate_uhz,
            } => {
                if self.sensor != SensorStatus::Ok {
                    Err(CommandError::SensorFault)
                } else if batch.is_none() {
                    Err(CommandError::MtuTooSmall)
                } else {
                    self.session.start(condition, rate_uhz)
                }
            }
            Command::Stop => {
                // The slot being filled is incomplete and dropped; the condition's last
                // samples go out before its final fit.
                self.sampler.discard();
                self.live.flush(out);
                self.session.stop(out)
            }
            Command::SetSampleRate { mhz } => {
                if self.session.state() == RunState::Running {
                    Err(CommandError::Busy)
                } else {
                    self.sampler.set_sample_rate(mhz, self.cfg.sensor_odr_mhz)
                }
            }
            Command::Reset => {
                self.live.flush(out);
                self.session.reset();
                self.lost = 0;
                Ok(())
            }
            Command::Backfill { from_seq, count } => match batch {
                Some(n) => {
                    let (replay, result) = self.ring.replay(from_seq, count, n);
                    self.replay = Some(replay);
                    result
                }
                None => Err(CommandError::MtuTooSmall),
            },
        };
        self.last_error = result.err();
        self.reply_owed = true;
    }
}
