//! `rotacal record`: drive a device through one condition and record what it sends.
//!
//! Connect, check the device-info value (protocol and firmware version), set the sample
//! rate, start the condition, and until the duration is up: append every value to the
//! capture, decode it, and hand it to the [`Recorder`], which writes rows in seq order.
//! Gaps (lost notifications, link outages) are asked for again from the device's ring
//! buffer (`Command::Backfill`); what the ring no longer holds, or what doesn't come within
//! `backfill_wait`, is reported lost. A lost link is reconnected automatically for up to
//! `reconnect_for`. Files are flushed, and with `sync` synced, every second. Then stop,
//! wait for the final fit report and any tail gap, and finish.

pub mod capture;

use crate::link::{Channel, Link, LinkError};
use crate::record::capture::{CaptureWriter, Entry};
use crate::recording::from_device::{RecordSummary, Recorder, Resume};
use rotacal_shared::packet::{
    ClockSource, Command, CommandError, DeviceInfo, Packet, RunState, SensorStatus, Status, VERSION,
};
use rotacal_shared::Condition;
use std::fs::File;
use std::io::{self, Write};
use std::time::Duration;
use tokio::time::Instant;

/// The firmware major version this rotacal works with.
pub const FIRMWARE_MAJOR: u8 = 0;

/// What to record.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plan {
    /// The platter axis the table turns about.
    pub condition: Condition,
    /// Nominal rotation rate, µHz.
    pub rate_uhz: u32,
    /// How long to record.
    pub duration: Duration,
    /// Sample rate to set before starting, mHz (None: the device's).
    pub sample_rate_mhz: Option<u32>,
    /// Stop a condition the device is already running before starting.
    pub restart: bool,
}

/// How hard to try.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Options {
    /// Sync files to disk every second (off only for in-memory runs).
    pub sync: bool,
    /// Give up when the link stays down this long.
    pub reconnect_for: Duration,
    /// How long a requested replay may take before its samples are reported lost.
    pub backfill_wait: Duration,
    /// How long to wait for a command's status reply.
    pub reply_wait: Duration,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            sync: true,
            reconnect_for: Duration::from_secs(60),
            backfill_wait: Duration::from_secs(3),
            reply_wait: Duration::from_secs(5),
        }
    }
}

/// Something that can be made durable.
pub trait Durable: Write {
    /// Put written data on stable storage.
    fn sync(&self) -> io::Result<()>;
}

impl Durable for File {
    fn sync(&self) -> io::Result<()> {
        self.sync_data()
    }
}

impl Durable for Vec<u8> {
    fn sync(&self) -> io::Result<()> {
        Ok(())
    }
}

/// The link as the progress display shows it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinkState {
    /// Up.
    Connected,
    /// Down; reconnecting (attempt number).
    Reconnecting(u32),
}

/// What the progress display shows.
#[derive(Clone, Debug, PartialEq)]
pub struct Progress {
    /// Time since the condition started.
    pub elapsed: Duration,
    /// The planned duration.
    pub duration: Duration,
    /// Rows written.
    pub rows: u64,
    /// Samples missing and not (yet) recovered.
    pub missing: u64,
    /// Samples recovered by replay.
    pub recovered: u64,
    /// Samples given up.
    pub lost: u64,
    /// Values that did not decode.
    pub undecodable: u64,
    /// The link.
    pub link: LinkState,
}

/// Receives progress and messages.
pub trait Observer {
    /// About once a second, and when the link changes.
    fn progress(&mut self, p: &Progress);
    /// Something the user should read (a warning or an event).
    fn message(&mut self, m: &str);
}

/// An observer that keeps messages (tests, the demo).
#[derive(Debug, Default)]
pub struct Quiet {
    /// Messages received.
    pub messages: Vec<String>,
}

impl Observer for Quiet {
    fn progress(&mut self, _: &Progress) {}
    fn message(&mut self, m: &str) {
        self.messages.push(m.to_string());
    }
}

/// How a recording ended.
#[derive(Clone, Debug, PartialEq)]
pub struct Outcome {
    /// The recorder's summary.
    pub summary: RecordSummary,
    /// Values that did not decode.
    pub undecodable: u64,
    /// Of those, the values on the results characteristic (fit reports, the quick-look,
    /// status replies), whose content is not asked for again; a sample batch that did not
    /// decode leaves a gap in the seqs, asked for again or reported lost.
    pub undecodable_results: u64,
    /// Times the link was lost.
    pub link_drops: u32,
    /// The condition's final fit report arrived.
    pub final_fit: bool,
    /// Conversions lost on the device during the recording (not read in time, or dropped
    /// from its event queue), from its status: also counted per sample in `conv_missed`.
    pub device_lost: u32,
    /// Times the device restarted (a watchdog, a panic, its power) and the condition was
    /// started again: the recording's rows are in boots 0 to this.
    pub restarts: u32,
}

/// Why recording failed. What was received up to then is in the files.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The link could not be (re)established, or the adapter failed.
    #[error(transparent)]
    Link(#[from] LinkError),
    /// The device is not one this rotacal can talk to.
    #[error("{0}")]
    Device(String),
    /// No status reply to a command in time.
    #[error("no status reply to {command:?} within {wait_s:.0} s")]
    NoReply {
        /// The command.
        command: Command,
        /// How long the recorder waited, s.
        wait_s: f64,
    },
    /// The device refused a command.
    #[error("the device refused {command}: {reason}")]
    Refused {
        /// The command.
        command: String,
        /// Its reason.
        reason: String,
    },
    /// Writing the files failed.
    #[error("writing the recording: {0}")]
    Io(io::Error),
}

// Not `#[from]`: that would make the io::Error the source too, and `{:#}` would print it
// twice.
impl From<io::Error> for RecordError {
    fn from(e: io::Error) -> Self {
        RecordError::Io(e)
    }
}

fn refusal(e: CommandError, mtu: u16) -> String {
    match e {
        CommandError::Busy => {
            "busy: it is already running a condition (another host, or a recording that was \
             interrupted); use --restart to stop it first"
                .into()
        }
        CommandError::NotRunning => "not running".into(),
        CommandError::BadRate => "the rate is zero or too high for its clock".into(),
        CommandError::SensorFault => "its accelerometer is absent or failing".into(),
        CommandError::NotInRing => "the samples have left its ring buffer".into(),
        CommandError::FitFailed => "too few samples or periods for a fit".into(),
        CommandError::MtuTooSmall => format!(
            "the link's ATT MTU is {mtu} bytes and the device needs at least {} (a fit report \
             in one notification); the central must ask for a larger MTU: BlueZ and \
             CoreBluetooth do so themselves, on Android call requestMtu(247)",
            rotacal_shared::device::route::MIN_MTU
        ),
    }
}

/// Why the device is no longer running when it did not restart (a restart shows as its
/// newest sample going back: [`Recorder`] starts a new boot): another host stopped it.
pub fn stopped(st: &Status) -> String {
    format!(
        "the device stopped running (state {:?}, sensor {:?}): stopped by another host",
        st.state, st.sensor
    )
}

/// What the recorder says when the device restarted: `st` the status that showed it,
/// `newest` the newest seq received before, `boot` the boot the rows go on in.
pub fn restarted(st: &Status, newest: Option<u32>, boot: u32) -> String {
    let before = newest.map_or(String::new(), |n| format!(", ours {n}"));
    format!(
        "the device restarted (its newest sample is seq {}{before}: it counts from a new \
         power-up; a watchdog, a panic or its power reset it). The rows before are kept; \
         the condition is started again and its rows go on in boot {boot}, whose time \
         starts afresh (calibrate joins the boots)",
        st.ring_newest
    )
}

/// Check the device-info value.
pub fn check_info(bytes: &[u8]) -> Result<DeviceInfo, RecordError> {
    match Packet::decode(bytes) {
        Ok(Packet::Info(i)) => {
            if i.firmware[0] != FIRMWARE_MAJOR {
                return Err(RecordError::Device(format!(
                    "the device runs firmware {}.{}.{}; this rotacal works with firmware \
                     {FIRMWARE_MAJOR}.x: flash the firmware from this repository (README, \
                     Flashing)",
                    i.firmware[0], i.firmware[1], i.firmware[2]
                )));
            }
            if i.tick_hz == 0 {
                return Err(RecordError::Device(
                    "the device reports a tick rate of 0 Hz".into(),
                ));
            }
            Ok(i)
        }
        Ok(other) => Err(RecordError::Device(format!(
            "the device-info value is not device info but {other:?}"
        ))),
        Err(e) => match bytes.first() {
            Some(&v) if v != VERSION => Err(RecordError::Device(format!(
                "the device speaks protocol version {v}; this rotacal speaks version {VERSION}: \
                 use matching firmware and host"
            ))),
            _ => Err(RecordError::Device(format!(
                "the device-info value does not decode ({e}): {} bytes {:02x?}",
                bytes.len(),
                bytes
            ))),
        },
    }
}

/// A warning when the device's timestamps do not run on its crystal (as its device info
/// says), so that the rate and the times of a recording are less certain than the
/// documented timing assumes (docs/recording.md).
pub fn clock_warning(info: &DeviceInfo) -> Option<String> {
    match info.clock {
        ClockSource::TimerHfxo => None,
        ClockSource::TimerHfint => Some(
            "warning: the device's crystal did not start, so its timestamps run on its \
             internal RC oscillator: the rate and the times are far less certain than with \
             the crystal; power-cycle the board and record again"
                .into(),
        ),
        ClockSource::RtcLfrc => Some(
            "warning: the device's timestamps run on its RTC and the low-frequency RC \
             oscillator (±500 ppm), not on its crystal"
                .into(),
        ),
    }
}

fn encode(cmd: Command) -> Vec<u8> {
    crate::recording::from_device::encode(&Packet::Command(cmd))
}

/// The files a recording writes.
pub struct Files<W: Durable, F: Durable, C: Durable> {
    /// The recorder (recording and fit log).
    pub recorder: Recorder<W, F>,
    /// The capture.
    pub capture: CaptureWriter<C>,
}

struct Session<'a, L: Link, W: Durable, F: Durable, C: Durable, O: Observer> {
    link: &'a mut L,
    files: Files<W, F, C>,
    obs: &'a mut O,
    opts: Options,
    undecodable: u64,
    undecodable_results: u64,
    link_drops: u32,
    connected: bool,
    last_status: Option<Status>,
    /// The device's `lost` count at the first and the latest status of its boot, and
    /// what its earlier boots lost.
    device_lost: Option<(u32, u32)>,
    lost_before: u32,
    /// The recorder's boot at the last status: one more means the device restarted.
    boot_seen: u32,
    /// The status that showed a restart, until the condition is started again.
    rebooted: Option<(Status, Option<u32>)>,
    restarts: u32,
    /// A status that found the device not running after our Start (whatever command it
    /// answered): the device was stopped or reset.
    idle: Option<Status>,
    /// Reconnected: ask the device for its status (a board that reset streams nothing, so
    /// no gap would ever show it).
    ask_status: bool,
    /// The sensor was OK at the last status (to report a change once).
    sensor_ok: bool,
    final_fit: bool,
    plan: Plan,
    /// The device at the first connection (a reconnection must find the same).
    info: DeviceInfo,
    /// The device acknowledged our Start: from then on its samples are this recording's.
    started: bool,
    /// The backfill asked for: (first, last, when, how many times).
    asked: Option<(u32, u32, Instant, u32)>,
    last_flush: Instant,
    start_time: Instant,
}

impl<L: Link, W: Durable, F: Durable, C: Durable, O: Observer> Session<'_, L, W, F, C, O> {
    fn progress(&mut self, link: LinkState) {
        let s = self.files.recorder.summary();
        let p = Progress {
            elapsed: self.start_time.elapsed(),
            duration: self.plan.duration,
            rows: s.rows,
            missing: self.files.recorder.missing_samples(),
            recovered: s.recovered,
            lost: s.lost_samples(),
            undecodable: self.undecodable,
            link,
        };
        self.obs.progress(&p);
    }

    fn flush(&mut self) -> io::Result<()> {
        self.files.recorder.flush()?;
        self.files.capture.flush()?;
        if self.opts.sync {
            let (w, f) = self.files.recorder.writers();
            w.sync()?;
            f.sync()?;
            self.files.capture.get_ref().sync()?;
        }
        self.last_flush = Instant::now();
        Ok(())
    }

    fn tick(&mut self) -> io::Result<()> {
        if self.last_flush.elapsed() >= Duration::from_secs(1) {
            self.flush()?;
            self.progress(LinkState::Connected);
        }
        Ok(())
    }

    /// Take one value from the link (or time out after `wait`).
    async fn receive(&mut self, wait: Duration) -> Result<(), RecordError> {
        match self.link.next(wait).await {
            Ok(Some((ch, bytes))) => {
                self.files.capture.entry(&Entry::Value(ch, bytes.clone()))?;
                self.handle(ch, &bytes)?;
            }
            Ok(None) => {}
            Err(LinkError::Disconnected(why)) => self.link_lost(&why).await?,
            Err(e) => return Err(e.into()),
        }
        self.tick()?;
        Ok(())
    }

    fn handle(&mut self, ch: Channel, bytes: &[u8]) -> Result<(), RecordError> {
        let p = match Packet::decode(bytes) {
            Ok(p) => p,
            Err(e) => {
                self.undecodable += 1;
                if ch == Channel::Results {
                    self.undecodable_results += 1;
                }
                // The first few in full; then every thousandth, so a babbling device can't
                // flood the terminal.
                if self.undecodable <= 3 || self.undecodable % 1000 == 0 {
                    self.obs.message(&format!(
                        "ignored a {}-byte value on the {ch:?} characteristic that is not a \
                         rotacal packet ({e}); {} so far",
                        bytes.len(),
                        self.undecodable
                    ));
                }
                return Ok(());
            }
        };
        // Before our Start is acknowledged (e.g. the tail of a condition stopped with
        // --restart), or of another condition, data are not this recording's; they stay in
        // the capture.
        // The newest sample before a status that may show a restart (which clears it).
        let newest = match &p {
            Packet::Status(_) => self.files.recorder.newest(),
            _ => None,
        };
        let ours = match &p {
            Packet::Samples(b) => self.started && b.condition == self.plan.condition,
            Packet::Averages(b) => self.started && b.condition == self.plan.condition,
            Packet::Fit(f) => self.started && f.condition == self.plan.condition,
            Packet::Temperature(_) | Packet::QuickLook(_) => self.started,
            Packet::Info(_) | Packet::Status(_) | Packet::Command(_) => true,
        };
        if ours {
            self.files.recorder.packet(&p)?;
        }
        match p {
            Packet::Status(s) => {
                if s.sensor != SensorStatus::Ok && self.sensor_ok {
                    self.obs.message(&format!(
                        "the device reports its accelerometer {:?}: no samples until it recovers",
                        s.sensor
                    ));
                }
                self.sensor_ok = s.sensor == SensorStatus::Ok;
                if s.last_error == Some(CommandError::NotInRing) {
                    self.files.recorder.give_up_before(s.ring_oldest)?;
                }
                if self.files.recorder.boot() != self.boot_seen {
                    // A new boot counts its losses afresh.
                    self.boot_seen = self.files.recorder.boot();
                    self.lost_before = self
                        .lost_before
                        .saturating_add(self.device_lost.map_or(0, |(a, b)| b.saturating_sub(a)));
                    self.device_lost = None;
                    self.rebooted = Some((s, newest));
                }
                let first = self.device_lost.map_or(s.lost, |(f, _)| f);
                self.device_lost = Some((first, s.lost));
                if self.started && s.state != RunState::Running {
                    self.idle.get_or_insert(s);
                }
                self.last_status = Some(s);
            }
            Packet::Fit(f) if f.is_final && f.condition == self.plan.condition => {
                self.final_fit = true;
            }
            _ => {}
        }
        Ok(())
    }

    /// Write a command and wait for the status that answers it. If the link drops before
    /// the answer, the command is written again after reconnecting, and if no answer comes
    /// within the reply wait it is written again, [`COMMAND_WRITES`] times in all; a repeat
    /// that the device refuses only because the first one took effect (Start: busy running
    /// this condition; Stop: not running) counts as answered.
    async fn command(&mut self, cmd: Command) -> Result<Status, RecordError> {
        let bytes = encode(cmd);
        let mut repeated = false;
        let mut writes = 0;
        'send: loop {
            self.files.capture.entry(&Entry::Written(bytes.clone()))?;
            self.last_status = None;
            match self.link.write(&bytes).await {
                Ok(()) => {}
                // A write can fail after the device acted on it: write it again, as a repeat.
                Err(LinkError::Disconnected(why)) => {
                    self.link_lost(&why).await?;
                    repeated = true;
                    continue 'send;
                }
                Err(e) => return Err(e.into()),
            }
            let drops = self.link_drops;
            let mut deadline = Instant::now() + self.opts.reply_wait;
            while Instant::now() < deadline {
                let recovered = self.files.recorder.summary().recovered;
                self.receive(Duration::from_millis(200)).await?;
                // A backfill's reply follows its replay: while replayed samples come, the
                // device is answering, however slow the link.
                if matches!(cmd, Command::Backfill { .. })
                    && self.files.recorder.summary().recovered > recovered
                {
                    deadline = Instant::now() + self.opts.reply_wait;
                }
                if self.link_drops != drops {
                    repeated = true;
                    continue 'send;
                }
                if let Some(mut st) = self.last_status {
                    let took_effect = match (cmd, st.last_error) {
                        (Command::Start { condition, .. }, Some(CommandError::Busy)) => {
                            st.state == RunState::Running && st.condition == Some(condition)
                        }
                        (Command::Stop, Some(CommandError::NotRunning)) => true,
                        _ => false,
                    };
                    if repeated && took_effect {
                        st.last_error = None;
                    }
                    return Ok(st);
                }
            }
            // The reply may have been lost (or corrupted) on its way: written again, as a
            // repeat, before the device is taken to be deaf.
            writes += 1;
            if writes < COMMAND_WRITES {
                self.obs.message(&format!(
                    "no status reply to {cmd:?} within {:.0} s; writing it again",
                    self.opts.reply_wait.as_secs_f64()
                ));
                repeated = true;
                continue 'send;
            }
            return Err(RecordError::NoReply {
                command: cmd,
                wait_s: self.opts.reply_wait.as_secs_f64() * f64::from(COMMAND_WRITES),
            });
        }
    }

    async fn link_lost(&mut self, why: &str) -> Result<(), RecordError> {
        self.connected = false;
        self.link_drops += 1;
        self.files.capture.entry(&Entry::Down)?;
        self.obs
            .message(&format!("link lost ({why}); reconnecting"));
        self.reconnect().await
    }

    async fn reconnect(&mut self) -> Result<(), RecordError> {
        let since = Instant::now();
        let mut attempt = 0u32;
        loop {
            attempt += 1;
            self.progress(LinkState::Reconnecting(attempt));
            match self.link.connect().await {
                Ok(info) => {
                    let again = check_info(&info)?;
                    if (again.chip, again.firmware, again.tick_hz, again.clock)
                        != (
                            self.info.chip,
                            self.info.firmware,
                            self.info.tick_hz,
                            self.info.clock,
                        )
                    {
                        return Err(RecordError::Device(
                            "reconnected to a different device (chip, firmware or clock \
                             differ): use --device with its address"
                                .into(),
                        ));
                    }
                    self.files
                        .capture
                        .entry(&Entry::Value(Channel::Info, info))?;
                    self.files.capture.entry(&Entry::Up)?;
                    self.connected = true;
                    self.obs.message(&format!(
                        "reconnected after {:.1} s",
                        since.elapsed().as_secs_f64()
                    ));
                    self.asked = None;
                    self.ask_status = true;
                    return Ok(());
                }
                Err(LinkError::Disconnected(why)) => {
                    if since.elapsed() >= self.opts.reconnect_for {
                        return Err(RecordError::Link(LinkError::Disconnected(format!(
                            "{}: {why}; gave up after {:.0} s",
                            self.link.describe(),
                            since.elapsed().as_secs_f64()
                        ))));
                    }
                    self.flush()?;
                    tokio::time::sleep(Duration::from_millis(500)).await;
                }
                Err(e) => return Err(e.into()),
            }
        }
    }

    /// Ask for the first missing range again; ask once more when the replay is overdue
    /// (replays can be lost too), and give the range up after [`BACKFILL_TRIES`] requests
    /// that brought nothing: a request that brought samples (the first missing one moved
    /// on) starts a fresh budget. A request whose status reply does not come counts as one
    /// that brought nothing, and is asked again.
    async fn backfill(&mut self) -> Result<(), RecordError> {
        let Some((a, b)) = self.files.recorder.missing().into_iter().next() else {
            self.asked = None;
            return Ok(());
        };
        let previous = self
            .asked
            .map(|(qa, qb, at, tries)| (qa, qb, at.elapsed() >= self.opts.backfill_wait, tries));
        let tries = match next_request(previous, a, b) {
            Request::Wait => return Ok(()),
            Request::Ask { tries } => tries,
            Request::GiveUp { through } => {
                let tries = previous.map_or(0, |p| p.3);
                self.obs.message(&format!(
                    "samples {a}–{through} did not come back after {tries} requests; \
                     reported lost"
                ));
                self.files.recorder.give_up_before(through + 1)?;
                self.asked = None;
                return Ok(());
            }
        };
        let count = u16::try_from(b - a + 1).unwrap_or(u16::MAX);
        self.asked = Some((a, a + u32::from(count) - 1, Instant::now(), tries));
        let lost = self.files.recorder.summary().lost_samples();
        let s = match self.command(Command::Backfill { from_seq: a, count }).await {
            Ok(s) => s,
            Err(e @ RecordError::NoReply { .. }) => {
                self.obs.message(&format!("{e}; it will be asked again"));
                return Ok(());
            }
            Err(e) => return Err(e),
        };
        if s.last_error == Some(CommandError::MtuTooSmall) {
            // A reconnection to a central that did not ask for a large MTU: nothing can
            // be fetched or streamed over it.
            return Err(RecordError::Refused {
                command: "backfill".into(),
                reason: refusal(CommandError::MtuTooSmall, self.link.mtu()),
            });
        }
        // The reply gave up what is still missing below the ring (a request written
        // again after a link drop may ask for samples that came meanwhile).
        let given_up = self
            .files
            .recorder
            .summary()
            .lost_samples()
            .saturating_sub(lost);
        if s.last_error == Some(CommandError::NotInRing) && given_up > 0 {
            self.obs.message(&format!(
                "samples from {a} have left the device's ring (it holds {}–{}): the {given_up} \
                 not received before {} are lost",
                s.ring_oldest, s.ring_newest, s.ring_oldest
            ));
        }
        Ok(())
    }
}

/// What to do about the first missing range.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Request {
    /// The last request may still be under way.
    Wait,
    /// Ask for it: the `tries`-th request for what is missing from its first seq.
    Ask { tries: u32 },
    /// Report the samples up to `through` lost.
    GiveUp { through: u32 },
}

/// The decision of [`Session::backfill`] for the first missing range `a..=b`, given the
/// previous request (first, last, whether its wait is over, its count of requests): a
/// range the previous request covers is asked again once its wait is over, and given up
/// after [`BACKFILL_TRIES`] requests that brought nothing; a request that brought samples
/// (the first missing seq moved on within it) starts a fresh count.
fn next_request(previous: Option<(u32, u32, bool, u32)>, a: u32, b: u32) -> Request {
    match previous {
        Some((qa, qb, over, tries)) if qa <= a && a <= qb => {
            if !over {
                Request::Wait
            } else if a > qa {
                Request::Ask { tries: 1 }
            } else if tries >= BACKFILL_TRIES {
                Request::GiveUp { through: b.min(qb) }
            } else {
                Request::Ask { tries: tries + 1 }
            }
        }
        _ => Request::Ask { tries: 1 },
    }
}

/// `st`, or the refusal it reports of `cmd`.
fn check(cmd: &str, st: Status, mtu: u16) -> Result<Status, RecordError> {
    match st.last_error {
        Some(e) => Err(RecordError::Refused {
            command: cmd.into(),
            reason: refusal(e, mtu),
        }),
        None => Ok(st),
    }
}

/// Set the sample rate (if the plan says) and start the condition.
async fn start<L: Link, W: Durable, F: Durable, C: Durable, O: Observer>(
    s: &mut Session<'_, L, W, F, C, O>,
    plan: Plan,
) -> Result<(), RecordError> {
    if let Some(mhz) = plan.sample_rate_mhz {
        let st = s.command(Command::SetSampleRate { mhz }).await?;
        check("the sample rate", st, s.link.mtu())?;
    }
    s.files.recorder.start_written(plan.condition);
    let st = s
        .command(Command::Start {
            condition: plan.condition,
            rate_uhz: plan.rate_uhz,
        })
        .await?;
    check("start", st, s.link.mtu())?;
    s.started = true;
    // Running now: the replies before the Start (a device not yet started) say nothing.
    s.idle = None;
    Ok(())
}

/// Writes of a command whose status reply does not come before it is given up.
pub const COMMAND_WRITES: u32 = 3;

/// Requests for one missing range before it is reported lost.
pub const BACKFILL_TRIES: u32 = 3;

/// Record one condition. `files` are fresh or appended; `info` is the checked device info
/// from the first connection ([`connect`]).
pub async fn record<L: Link, W: Durable, F: Durable, C: Durable, O: Observer>(
    link: &mut L,
    info: DeviceInfo,
    files: Files<W, F, C>,
    plan: Plan,
    opts: Options,
    obs: &mut O,
) -> Result<Outcome, (RecordError, Option<RecordSummary>)> {
    let mut s = Session {
        link,
        files,
        obs,
        opts,
        undecodable: 0,
        undecodable_results: 0,
        link_drops: 0,
        connected: true,
        last_status: None,
        device_lost: None,
        lost_before: 0,
        boot_seen: 0,
        rebooted: None,
        restarts: 0,
        idle: None,
        ask_status: false,
        sensor_ok: true,
        final_fit: false,
        plan,
        info,
        started: false,
        asked: None,
        last_flush: Instant::now(),
        start_time: Instant::now(),
    };
    let result = run(&mut s, plan).await;
    let (undecodable, undecodable_results) = (s.undecodable, s.undecodable_results);
    let link_drops = s.link_drops;
    let final_fit = s.final_fit;
    let device_lost = s
        .lost_before
        .saturating_add(s.device_lost.map_or(0, |(a, b)| b.saturating_sub(a)));
    let restarts = s.restarts;
    let _ = s.flush();
    let summary = s.files.recorder.finish();
    match (result, summary) {
        (Ok(()), Ok(summary)) => Ok(Outcome {
            summary,
            undecodable,
            undecodable_results,
            link_drops,
            final_fit,
            device_lost,
            restarts,
        }),
        (Err(e), sum) => Err((e, sum.ok())),
        (Ok(()), Err(e)) => Err((e.into(), None)),
    }
}

async fn run<L: Link, W: Durable, F: Durable, C: Durable, O: Observer>(
    s: &mut Session<'_, L, W, F, C, O>,
    plan: Plan,
) -> Result<(), RecordError> {
    if plan.restart {
        // Refused (not running) is fine: the point is that it isn't running afterwards.
        s.command(Command::Stop).await?;
    }
    s.boot_seen = s.files.recorder.boot();
    start(s, plan).await?;
    s.start_time = Instant::now();
    s.obs.message(&format!(
        "recording condition {} for {:.0} s",
        plan.condition.letter(),
        plan.duration.as_secs_f64()
    ));
    while s.start_time.elapsed() < plan.duration {
        s.receive(Duration::from_millis(200)).await?;
        if s.ask_status && s.connected {
            s.ask_status = false;
            // A replay of nothing: its status reply says whether the device still runs
            // (every status goes through `packet`, which notes one that is not running).
            let from_seq = s.files.recorder.newest().map_or(0, |n| n.wrapping_add(1));
            match s.command(Command::Backfill { from_seq, count: 0 }).await {
                Ok(_) => {}
                // Asked again at the next turn: the reply, not the device, was lost.
                Err(e @ RecordError::NoReply { .. }) => {
                    s.obs.message(&format!("{e}; it will be asked again"));
                    s.ask_status = true;
                }
                Err(e) => return Err(e),
            }
        }
        if let Some(st) = s.idle.take() {
            let Some((at, newest)) = s.rebooted.take() else {
                return Err(RecordError::Device(stopped(&st)));
            };
            // The table turns on: so does the recording, in the next boot, to the end of
            // the planned duration.
            s.restarts += 1;
            s.obs
                .message(&restarted(&at, newest, s.files.recorder.boot()));
            s.asked = None;
            start(s, plan).await?;
            continue;
        }
        if s.connected {
            s.backfill().await?;
        }
    }
    let st = s.command(Command::Stop).await?;
    let fit_failed = st.last_error == Some(CommandError::FitFailed);
    if fit_failed {
        // Stopped all the same; the samples are recorded, only the device's own fit is
        // missing (the host fits them in `calibrate`).
        s.obs.message(
            "the device stopped but its fit failed (too few samples or periods): no final \
             fit report",
        );
    } else {
        check("stop", st, s.link.mtu())?;
    }
    // The tail: samples the device took but whose notifications were lost.
    s.files.recorder.expect_through(st.ring_newest);
    let deadline = Instant::now() + s.opts.reply_wait + s.opts.backfill_wait;
    while Instant::now() < deadline
        && ((!s.final_fit && !fit_failed) || !s.files.recorder.missing().is_empty())
    {
        s.receive(Duration::from_millis(200)).await?;
        s.backfill().await?;
    }
    if !s.final_fit && !fit_failed {
        s.obs
            .message("the device's final fit report did not arrive; the fit log lacks it");
    }
    Ok(())
}

/// Connect for the first time, retrying for `opts.reconnect_for`, and check the device.
pub async fn connect<L: Link>(
    link: &mut L,
    opts: &Options,
    obs: &mut impl Observer,
) -> Result<(DeviceInfo, Vec<u8>), RecordError> {
    let since = Instant::now();
    loop {
        match link.connect().await {
            Ok(bytes) => {
                let info = check_info(&bytes)?;
                if let Some(w) = clock_warning(&info) {
                    obs.message(&w);
                }
                return Ok((info, bytes));
            }
            Err(LinkError::Disconnected(why)) if since.elapsed() < opts.reconnect_for => {
                obs.message(&format!("{}: {why}; retrying", link.describe()));
                tokio::time::sleep(Duration::from_secs(1)).await;
            }
            Err(e) => return Err(e.into()),
        }
    }
}

/// Where a recording goes: the recording, its fit log and its capture.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Paths {
    /// The recording CSV.
    pub recording: std::path::PathBuf,
    /// The fit log (JSON lines).
    pub fits: std::path::PathBuf,
    /// The capture.
    pub capture: std::path::PathBuf,
}

impl Paths {
    /// `rec.csv` → `rec.fits.jsonl` and `rec.capture` beside it.
    pub fn beside(recording: &std::path::Path) -> Self {
        Paths {
            recording: recording.to_path_buf(),
            fits: recording.with_extension("fits.jsonl"),
            capture: recording.with_extension("capture"),
        }
    }

    /// Remove the three files where they exist (a tool's own folder, whose previous run is
    /// replaced).
    pub fn remove(&self) -> io::Result<()> {
        for p in [&self.recording, &self.fits, &self.capture] {
            match std::fs::remove_file(p) {
                Err(e) if e.kind() != io::ErrorKind::NotFound => {
                    return Err(io::Error::new(e.kind(), format!("{}: {e}", p.display())))
                }
                _ => {}
            }
        }
        Ok(())
    }
}

/// Read the files back as `calibrate` and `crosscheck` read them: the recording (conditions
/// may still be missing) must hold `rows` rows of `condition`, and the fit log must read.
/// A recorder that says it is done has checked this (docs/recording.md).
pub fn check_reads_back(paths: &Paths, condition: Condition, rows: u64) -> Result<(), String> {
    let rec = crate::recording::read_in_progress(&paths.recording).map_err(|e| e.to_string())?;
    let found: u64 = rec
        .groups
        .iter()
        .filter(|g| g.condition == condition)
        .map(|g| g.len() as u64)
        .sum();
    if found != rows {
        return Err(format!(
            "{}: {found} rows of condition {} read back, {rows} were written",
            paths.recording.display(),
            condition.letter()
        ));
    }
    let text = std::fs::read_to_string(&paths.fits)
        .map_err(|e| format!("{}: {e}", paths.fits.display()))?;
    crate::recording::from_device::read_fit_log(&text, &paths.fits.display().to_string())
        .map_err(|e| e.to_string())?;
    Ok(())
}

fn named(p: &std::path::Path, e: io::Error) -> RecordError {
    RecordError::Io(io::Error::new(e.kind(), format!("{}: {e}", p.display())))
}

/// Cut a file back to its last complete line (a host killed mid-write leaves a partial
/// one), so that appending starts on a fresh line.
fn truncate_partial_line(p: &std::path::Path) -> Result<(), RecordError> {
    let bytes = std::fs::read(p).map_err(|e| named(p, e))?;
    let keep = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
    if keep < bytes.len() {
        let f = std::fs::OpenOptions::new()
            .write(true)
            .open(p)
            .map_err(|e| named(p, e))?;
        f.set_len(keep as u64).map_err(|e| named(p, e))?;
    }
    Ok(())
}

/// Open the files for a new recording (refusing to overwrite one) or, with `append`,
/// for another condition of an existing one (which must read back, have the recorder's
/// columns and not hold `condition` yet).
pub fn open_files(
    paths: &Paths,
    meta: &crate::recording::Metadata,
    info_bytes: &[u8],
    tick_hz: u32,
    condition: Condition,
    append: bool,
) -> Result<Files<File, File, File>, RecordError> {
    use std::fs::OpenOptions;
    if append {
        // Nothing is cut before the files are known to be a recording and its capture.
        for (p, magic) in [
            (&paths.recording, "# rotacal recording v1"),
            (&paths.capture, crate::record::capture::MAGIC),
        ] {
            let text = std::fs::read(p).map_err(|e| named(p, e))?;
            if !text.starts_with(magic.as_bytes()) {
                return Err(RecordError::Device(format!(
                    "cannot append: {} does not start with '{magic}'",
                    p.display()
                )));
            }
        }
        for p in [&paths.recording, &paths.fits, &paths.capture] {
            truncate_partial_line(p)?;
        }
        let rec = crate::recording::read_in_progress(&paths.recording)
            .map_err(|e| RecordError::Device(format!("cannot append: {e}")))?;
        let ours = rec.oriented.is_none()
            && rec.groups.iter().all(|g| {
                g.seq.is_some()
                    && g.temp_c.is_some()
                    && g.conversions.is_some()
                    && !g.t_s.is_empty()
                    && g.rate_hz.is_none()
            });
        if !ours {
            return Err(RecordError::Device(format!(
                "cannot append: {} does not have the recorder's columns \
                 (condition, seq, t_s, u, v, w, temp_c, conv_gaps; recordings of rotacal 0.1 \
                 have no conv_gaps)",
                paths.recording.display()
            )));
        }
        let same = [
            ("rate_hz", rec.meta.rate_hz, meta.rate_hz),
            (
                "sample_rate_hz",
                rec.meta.sample_rate_hz,
                meta.sample_rate_hz,
            ),
        ];
        for (key, was, now) in same {
            if was != now {
                return Err(RecordError::Device(format!(
                    "cannot append: {} has {key}={was:?}, this recording {now:?}; record \
                     another rate or sample rate into a new file",
                    paths.recording.display()
                )));
            }
        }
        let was = crate::recording::tick_hz(&rec.meta);
        if was != Some(tick_hz) {
            return Err(RecordError::Device(format!(
                "cannot append: {} counts conv_gaps in ticks of {was:?} Hz, this device's clock \
                 is {tick_hz} Hz; record into a new file",
                paths.recording.display()
            )));
        }
        if rec.groups.iter().any(|g| g.condition == condition) {
            return Err(RecordError::Device(format!(
                "cannot append: {} already holds condition {}; record it into a new file",
                paths.recording.display(),
                condition.letter()
            )));
        }
        let open = |p: &std::path::Path| {
            OpenOptions::new()
                .append(true)
                .open(p)
                .map_err(|e| named(p, e))
        };
        let mut capture = CaptureWriter::append(open(&paths.capture)?);
        capture.entry(&Entry::Value(Channel::Info, info_bytes.to_vec()))?;
        // Conditions are appended one after another: the last group holds the last row.
        let last = rec.groups.last();
        Ok(Files {
            recorder: Recorder::append(
                open(&paths.recording)?,
                open(&paths.fits)?,
                tick_hz,
                Resume {
                    missed: rec.groups.iter().all(|g| g.missed.is_some()),
                    boot: match rec.groups.iter().all(|g| g.boot.is_some()) {
                        true => Some(
                            last.and_then(|g| g.boot.as_ref()?.last().copied())
                                .unwrap_or(0),
                        ),
                        false => None,
                    },
                    newest: last
                        .and_then(|g| g.seq.as_ref()?.last().copied())
                        .and_then(|s| u32::try_from(s).ok()),
                },
            )?,
            capture,
        })
    } else {
        let create = |p: &std::path::Path| {
            OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(p)
                .map_err(|e| {
                    if e.kind() == io::ErrorKind::AlreadyExists {
                        RecordError::Io(io::Error::new(
                            e.kind(),
                            format!(
                                "{}: exists; use --append to add a condition to it, or \
                                 another name",
                                p.display()
                            ),
                        ))
                    } else {
                        named(p, e)
                    }
                })
        };
        let (rec, fits, cap) = (
            create(&paths.recording)?,
            create(&paths.fits)?,
            create(&paths.capture)?,
        );
        let mut capture = CaptureWriter::new(cap, meta)?;
        capture.entry(&Entry::Value(Channel::Info, info_bytes.to_vec()))?;
        Ok(Files {
            recorder: Recorder::new(rec, fits, meta, tick_hz)?,
            capture,
        })
    }
}

/// A duration such as `300s`, `5min`, `1.5h` or `300` (seconds).
pub fn parse_duration(s: &str) -> Result<Duration, String> {
    let s = s.trim();
    let (num, unit) = match s.find(|c: char| c.is_ascii_alphabetic()) {
        Some(i) => (s.get(..i).unwrap_or(""), s.get(i..).unwrap_or("")),
        None => (s, "s"),
    };
    let scale = match unit {
        "s" => 1.0,
        "min" | "m" => 60.0,
        "h" => 3600.0,
        _ => return Err(format!("'{s}': unknown unit '{unit}' (use s, min or h)")),
    };
    let x: f64 = num
        .trim()
        .parse()
        .map_err(|_| format!("'{s}': not a number of seconds, minutes or hours"))?;
    if !(x.is_finite() && x > 0.0 && x * scale < 1e9) {
        return Err(format!("'{s}': must be positive and below 10⁹ s"));
    }
    Ok(Duration::from_secs_f64(x * scale))
}

#[cfg(test)]
mod tests {
    use super::{next_request, Request, BACKFILL_TRIES};

    #[test]
    fn a_range_is_asked_for_and_waited_for() {
        assert_eq!(next_request(None, 10, 20), Request::Ask { tries: 1 });
        assert_eq!(
            next_request(Some((10, 20, false, 1)), 10, 20),
            Request::Wait
        );
        // Another range than the one asked for: its own first request.
        assert_eq!(
            next_request(Some((10, 20, true, 3)), 30, 40),
            Request::Ask { tries: 1 }
        );
    }

    #[test]
    fn a_request_that_brought_nothing_counts_and_the_range_is_given_up() {
        let mut tries = 1;
        loop {
            match next_request(Some((10, 20, true, tries)), 10, 20) {
                Request::Ask { tries: t } => tries = t,
                Request::GiveUp { through } => {
                    assert_eq!(through, 20);
                    break;
                }
                Request::Wait => unreachable!(),
            }
        }
        assert_eq!(tries, BACKFILL_TRIES);
        // What lies beyond the request is not given up with it.
        assert_eq!(
            next_request(Some((10, 20, true, BACKFILL_TRIES)), 10, 25),
            Request::GiveUp { through: 20 }
        );
    }

    #[test]
    fn a_request_that_brought_samples_starts_a_fresh_count() {
        // Issue 33: a replay cut short (a slow link, a link drop) moved the first missing
        // seq on: what is left is asked for afresh, however many requests came before.
        for tries in 1..=BACKFILL_TRIES {
            assert_eq!(
                next_request(Some((10, 20, true, tries)), 15, 20),
                Request::Ask { tries: 1 }
            );
        }
    }
}
