//! The BLE packet protocol between the device and the host (docs/protocol.md).
//!
//! Every packet is one GATT value: a 4-byte header (protocol version, kind, and two bytes
//! that depend on the kind), then a fixed layout per kind, little-endian, then a CRC-16 of
//! all the bytes before it (version 3), so that a packet corrupted anywhere between the
//! device's memory and the host's decoder is refused, not recorded. Packets are
//! self-contained, so a lost notification loses only its own samples, which the host
//! fetches again from the device's ring buffer by sequence number. Versions 1 and 2 (no
//! CRC) are still decoded, for captures made with firmware 0.1 and 0.2.
//!
//! [`Packet::decode`] accepts exactly the bytes [`Packet::encode`] writes and refuses
//! everything else with a [`DecodeError`]; it never panics, on any input (property tests
//! in `shared/tests/packet.rs`, and the fuzz target in `fuzz/`).

use crate::time::{Aperture, Ticks, MAX_CONVERSIONS};
use crate::Condition;

/// The protocol version of every packet the device sends now: version 2's layouts (sample
/// batches averaged) and a CRC-16 after them.
pub const VERSION: u8 = 3;

/// Version 1: the layouts without a CRC, sample batches of single conversions (firmware
/// 0.1). Decoded, for old captures; [`SampleBatch`] is still encoded so.
pub const VERSION_1: u8 = 1;

/// Version 2: version 1 with averaged sample batches (firmware 0.2). Decoded, for old
/// captures.
pub const VERSION_AVERAGES: u8 = 2;

/// Bytes of the CRC at the end of a version 3 packet. Two, not four: a status (17 bytes)
/// must still fit the 20 bytes a notification carries at BLE's default MTU of 23, so that
/// the refusal naming a too-small MTU reaches the host (docs/protocol.md, "Integrity").
pub const CRC_LEN: usize = 2;

/// The CRC: CRC-16/IBM-SDLC (X.25: polynomial 0x1021 reflected, initial value and final
/// XOR 0xFFFF), little-endian.
const CRC16: crc::Crc<u16> = crc::Crc::<u16>::new(&crc::CRC_16_IBM_SDLC);

/// The CRC a version 3 packet carries after `layout` (its bytes before the CRC).
pub fn checksum(layout: &[u8]) -> u16 {
    CRC16.checksum(layout)
}

/// Averaged samples per [`AverageBatch`]: 16 + 30·7 + 2 = 228 bytes, inside one
/// notification.
pub const MAX_AVERAGES: usize = 7;

/// Samples per [`SampleBatch`]: 16 + 11·20 = 236 bytes, inside one notification at the
/// ATT MTU of 247 the device asks for (244 bytes of value).
pub const MAX_SAMPLES: usize = 20;

/// Largest packet, bytes.
pub const MAX_PACKET: usize = 16 + 11 * MAX_SAMPLES;

/// Bytes of an [`AverageBatch`] of `n` samples, its CRC included.
pub const fn averages_len(n: usize) -> usize {
    size::SAMPLES_HEAD + size::AVERAGE * n + CRC_LEN
}

/// Largest packet the device notifies other than a sample batch: a fit report.
pub const MAX_RESULT: usize = {
    const fn max(a: usize, b: usize) -> usize {
        if a > b {
            a
        } else {
            b
        }
    }
    max(
        max(size::FIT, size::QUICK_LOOK),
        max(size::STATUS, size::TEMPERATURE),
    ) + CRC_LEN
};

/// One accelerometer sample as the device sends it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Sample {
    /// Ticks from the batch's `t0` to this sample's data-ready edge.
    pub dt: u32,
    /// Raw counts u, v, w.
    pub counts: [i16; 3],
    /// [`SampleFlags`] bits.
    pub flags: u8,
}

/// Bits of [`Sample::flags`].
pub struct SampleFlags;

impl SampleFlags {
    /// A channel read the rail (i16::MIN or i16::MAX): the sample is clipped.
    pub const CLIPPED: u8 = 1 << 0;
    /// The data-ready edge was not captured for this sample (the timestamp is the
    /// read time and may be up to one sensor period late: docs/method.md §7).
    pub const LATE_TIMESTAMP: u8 = 1 << 1;
    /// Bits 2–4: conversions the sensor made in this sample's slot that the device did
    /// not read (0 to 7; [`SampleFlags::missed`]). The sample averages the others.
    pub const MISSED: u8 = 0b111 << 2;
    /// Every defined bit.
    pub const ALL: u8 = Self::CLIPPED | Self::LATE_TIMESTAMP | Self::MISSED;

    /// The missed conversions a flags byte counts.
    pub const fn missed(flags: u8) -> u8 {
        (flags & Self::MISSED) >> 2
    }

    /// `flags` counting `n` missed conversions (at most 7).
    pub const fn with_missed(flags: u8, n: u8) -> u8 {
        let n = if n > 7 { 7 } else { n };
        (flags & !Self::MISSED) | (n << 2)
    }
}

/// A sample kind a [`Batch`] holds.
pub trait BatchSample: Copy {
    /// The filler of unused slots.
    const EMPTY: Self;
}

impl BatchSample for Sample {
    const EMPTY: Sample = Sample {
        dt: 0,
        counts: [0; 3],
        flags: 0,
    };
}

/// Consecutive samples of one condition, up to `N`: sample i has sequence number
/// `first_seq + i`, and its time is `t0` plus its own `dt`, ticks of the device clock
/// ([`DeviceInfo::tick_hz`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Batch<S, const N: usize> {
    /// The condition the device was running when it took them.
    pub condition: Condition,
    /// Sent again from the ring buffer on request (not live).
    pub replay: bool,
    /// Sequence number of the first sample.
    pub first_seq: u32,
    /// Timestamp of the batch's reference, device ticks (64-bit, extended).
    pub t0: u64,
    len: u8,
    samples: [S; N],
}

/// Single conversions (protocol version 1).
pub type SampleBatch = Batch<Sample, MAX_SAMPLES>;

/// Averaged samples (protocol version 2).
pub type AverageBatch = Batch<Average, MAX_AVERAGES>;

impl<S: BatchSample, const N: usize> Batch<S, N> {
    /// An empty batch.
    pub const fn new(condition: Condition, replay: bool, first_seq: u32, t0: u64) -> Self {
        Batch {
            condition,
            replay,
            first_seq,
            t0,
            len: 0,
            samples: [S::EMPTY; N],
        }
    }

    /// The samples.
    pub fn samples(&self) -> &[S] {
        self.samples.get(..usize::from(self.len)).unwrap_or(&[])
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        usize::from(self.len)
    }

    /// True if there are none.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// True if no more fit.
    pub fn is_full(&self) -> bool {
        usize::from(self.len) >= N
    }

    /// Append the sample `make(dt)` for absolute tick `t`; refused when the batch is full
    /// or `t` is before `t0` or more than u32::MAX ticks after it (then start a new batch).
    fn push_at(&mut self, t: u64, make: impl FnOnce(u32) -> S) -> Result<(), BatchRefused> {
        let dt = t.checked_sub(self.t0).ok_or(BatchRefused::TimeOutOfRange)?;
        let dt = u32::try_from(dt).map_err(|_| BatchRefused::TimeOutOfRange)?;
        let slot = self
            .samples
            .get_mut(usize::from(self.len))
            .ok_or(BatchRefused::Full)?;
        *slot = make(dt);
        self.len += 1;
        Ok(())
    }
}

impl SampleBatch {
    /// Append a sample taken at absolute tick `t` (refused when the batch is full or `t` is out of its range).
    pub fn push(&mut self, t: u64, counts: [i16; 3], flags: u8) -> Result<(), BatchRefused> {
        self.push_at(t, |dt| Sample { dt, counts, flags })
    }

    /// Sequence number and absolute tick of each sample.
    pub fn iter(&self) -> impl Iterator<Item = (u32, u64, &Sample)> + '_ {
        self.samples().iter().zip(0u32..).map(move |(s, i)| {
            (
                self.first_seq.wrapping_add(i),
                self.t0.wrapping_add(u64::from(s.dt)),
                s,
            )
        })
    }
}

/// One averaged sample as the device sends it (protocol version 2): the sums of the raw
/// counts of the conversions in one slot and the conversions' instants.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Average {
    /// Ticks from the batch's `t0` to the first conversion's data-ready edge.
    pub dt: u32,
    /// Ticks from each conversion to the next (`count − 1` entries used, the rest 0).
    pub gaps: [u16; MAX_CONVERSIONS - 1],
    /// Conversions summed, 1 to [`MAX_CONVERSIONS`].
    pub count: u8,
    /// Sums of the raw counts u, v, w.
    pub sums: [i32; 3],
    /// [`SampleFlags`] bits, set when any conversion has them.
    pub flags: u8,
}

impl Average {
    /// The mean of the conversions' raw counts u, v, w: the exact sums over the count.
    pub fn mean(&self) -> [f64; 3] {
        let n = f64::from(self.count.max(1));
        self.sums.map(|x| f64::from(x) / n)
    }
}

impl BatchSample for Average {
    const EMPTY: Average = Average {
        dt: 0,
        gaps: [0; MAX_CONVERSIONS - 1],
        count: 1,
        sums: [0; 3],
        flags: 0,
    };
}

impl AverageBatch {
    /// Append the average of the conversions at `ap`, timed by its first conversion;
    /// refused when the batch is full or that is out of the batch's range.
    pub fn push(&mut self, ap: &Aperture, sums: [i32; 3], flags: u8) -> Result<(), BatchRefused> {
        let mut gaps = [0; MAX_CONVERSIONS - 1];
        for (g, a) in gaps.iter_mut().zip(ap.gaps()) {
            *g = *a;
        }
        let count = u8::try_from(ap.len()).unwrap_or(u8::MAX);
        self.push_at(ap.first().0, |dt| Average {
            dt,
            gaps,
            count,
            sums,
            flags,
        })
    }

    /// Sequence number, conversion instants and sample of each sample.
    pub fn iter(&self) -> impl Iterator<Item = (u32, Aperture, &Average)> + '_ {
        self.samples().iter().zip(0u32..).map(move |(s, i)| {
            let first = Ticks(self.t0.wrapping_add(u64::from(s.dt)));
            let used = usize::from(s.count).saturating_sub(1);
            let ap = Aperture::new(first, s.gaps.get(..used).unwrap_or(&[]))
                .unwrap_or(Aperture::point(first));
            (self.first_seq.wrapping_add(i), ap, s)
        })
    }
}

/// Why [`SampleBatch::push`] or [`AverageBatch::push`] refused a sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BatchRefused {
    /// It holds [`MAX_SAMPLES`] already.
    Full,
    /// Before the batch's `t0`, or more than u32::MAX ticks after it.
    TimeOutOfRange,
}

/// A temperature reading from the sensor, sent at a lower rate than the samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Temperature {
    /// Sequence number of the sample it was read with.
    pub seq: u32,
    /// Hundredths of a degree Celsius.
    pub centi_c: i16,
}

/// What the device's streaming f32 fit found for one condition, with what the host needs
/// to re-fit exactly the same samples: the window (first and last seq) and the rotation
/// step per tick (the regressors are sin/cos of `step·t mod 2⁶⁴`, docs/method.md §6).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FitReport {
    /// The condition.
    pub condition: Condition,
    /// Sent at stop (the condition's final result) rather than periodically.
    pub is_final: bool,
    /// Samples fitted.
    pub n: u32,
    /// Sequence numbers of the first and last sample fitted (those between that reached
    /// the fit; samples lost on the sensor side are absent from both).
    pub first_seq: u32,
    /// See `first_seq`.
    pub last_seq: u32,
    /// Nominal rotation rate, µHz.
    pub rate_uhz: u32,
    /// Rotation per tick as a fraction of a turn, 2⁻⁶⁴ units ([`crate::PhaseStep`]).
    pub step: u64,
    /// A, B, C per channel u, v, w, counts: the fit's double-word (hi + lo) result,
    /// exact in f64, so that rounding to f32 costs no accuracy on the wire.
    pub coef: [[f64; 3]; 3],
    /// Standard errors of A, B, C per channel, counts.
    pub se: [[f32; 3]; 3],
    /// Residual RMS per channel, counts.
    pub rms: [f32; 3],
}

/// The quick-look calibration after x, y and z: intrinsic properties from the exact Gram
/// form (docs/method.md §2) in f32.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct QuickLook {
    /// s_u, s_v, s_w, counts per m/s².
    pub sensitivity: [f64; 3],
    /// Their standard uncertainties.
    pub sensitivity_u: [f32; 3],
    /// φ_uv, φ_vw, φ_wu, degrees.
    pub angle_deg: [f64; 3],
    /// Their standard uncertainties.
    pub angle_u: [f32; 3],
    /// The g_loc used, m/s².
    pub g_loc: f64,
}

/// Which accelerometer the device found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Chip {
    /// None answered.
    None,
    /// LSM6DS33 (WHO_AM_I 0x69).
    Lsm6ds33,
    /// LSM6DS3TR-C (WHO_AM_I 0x6A).
    Lsm6ds3trc,
}

/// What stamps the samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ClockSource {
    /// A TIMER on the 64 MHz crystal (HFXO), data-ready edge captured by GPIOTE → PPI.
    TimerHfxo,
    /// The RTC on the low-frequency RC oscillator (±500 ppm).
    RtcLfrc,
    /// A TIMER on the internal 64 MHz RC oscillator (HFINT): the crystal did not start, so
    /// the timestamps' rate is far less certain than the crystal's tens of ppm.
    TimerHfint,
}

/// Static facts about the device (the device-info value).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DeviceInfo {
    /// Firmware version major, minor, patch.
    pub firmware: [u8; 3],
    /// The accelerometer fitted.
    pub chip: Chip,
    /// The timestamp clock.
    pub clock: ClockSource,
    /// Timestamp ticks per second.
    pub tick_hz: u32,
    /// The sensor's own output data rate, mHz.
    pub sensor_odr_mhz: u32,
    /// The rate samples are sent at, mHz.
    pub sample_rate_mhz: u32,
    /// Full scale, ±g.
    pub full_scale_g: u8,
    /// Samples the ring buffer holds.
    pub ring_capacity: u16,
}

/// The device's state machine.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RunState {
    /// Not sampling.
    Idle,
    /// Sampling and fitting a condition.
    Running,
    /// x, y and z done; the quick-look is published.
    Complete,
}

/// The sensor's health.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SensorStatus {
    /// Answering, data-ready edges arriving.
    Ok,
    /// No chip answered at 0x6A or 0x6B (SA0 high or low).
    Absent,
    /// A chip answered with an unknown WHO_AM_I.
    UnknownChip,
    /// I²C transfers fail.
    BusError,
    /// No data-ready edge for longer than two sensor periods.
    NoDataReady,
}

/// The device's status, notified on change.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Status {
    /// Run state.
    pub state: RunState,
    /// Sensor health.
    pub sensor: SensorStatus,
    /// Active (or last) condition, if any.
    pub condition: Option<Condition>,
    /// Conversions lost on the device since start: read too late or not at all (a late or
    /// stuck read, counted from the hardware edge count and the time between reads), or
    /// dropped from a full event queue.
    pub lost: u32,
    /// Oldest and newest sequence numbers in the ring buffer (equal when empty).
    pub ring_oldest: u32,
    /// See `ring_oldest`.
    pub ring_newest: u32,
    /// The last command refused, if any.
    pub last_error: Option<CommandError>,
}

/// Commands written to the control characteristic.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Command {
    /// Start sampling and fitting `condition` at the nominal rotation rate.
    Start {
        /// The platter axis.
        condition: Condition,
        /// Nominal rotation rate, µHz (non-zero).
        rate_uhz: u32,
    },
    /// Stop: publish the condition's final fit.
    Stop,
    /// Change the sample rate (only while idle), mHz.
    SetSampleRate {
        /// mHz, non-zero.
        mhz: u32,
    },
    /// Forget the fits of every condition and the quick-look.
    Reset,
    /// Send again the samples from `from_seq` on, at most `count`, from the ring buffer.
    Backfill {
        /// First sequence number wanted.
        from_seq: u32,
        /// How many.
        count: u16,
    },
}

/// Why the device refused a command ([`Status::last_error`]; the discriminant is its code
/// on the wire).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CommandError {
    /// Start while running, or a sample-rate change while running.
    Busy = 1,
    /// Stop while idle.
    NotRunning = 2,
    /// The rate is unusable (zero, or the phase step overflows).
    BadRate = 3,
    /// The sensor is absent or failing.
    SensorFault = 4,
    /// The wanted samples have left the ring buffer.
    NotInRing = 5,
    /// Stop found no fit result (too few samples or periods); nothing was recorded.
    FitFailed = 6,
    /// The link's ATT MTU is below [`crate::device::route::MIN_MTU`]: a fit report would
    /// not fit one notification (BLE's default of 23 when the central never asked for more).
    MtuTooSmall = 7,
}

/// Everything that travels between device and host.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Packet {
    /// Stream characteristic: single conversions (protocol version 1).
    Samples(SampleBatch),
    /// Stream characteristic: averaged samples (protocol version 2).
    Averages(AverageBatch),
    /// Stream characteristic.
    Temperature(Temperature),
    /// Fit-results characteristic.
    Fit(FitReport),
    /// Fit-results characteristic.
    QuickLook(QuickLook),
    /// Device-info characteristic.
    Info(DeviceInfo),
    /// Status (on the fit-results characteristic, and readable).
    Status(Status),
    /// Control characteristic (host → device).
    Command(Command),
}

/// Why bytes are not a packet. Offsets count from the packet's first byte.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecodeError {
    /// Shorter than its kind's layout.
    TooShort {
        /// Bytes the layout needs.
        need: usize,
        /// Bytes given.
        got: usize,
    },
    /// Longer than its kind's layout.
    TooLong {
        /// Bytes the layout has.
        want: usize,
        /// Bytes given.
        got: usize,
    },
    /// A protocol version this decoder does not speak.
    Version(u8),
    /// The CRC at the end of a version 3 packet is not that of its bytes: corrupted.
    Checksum {
        /// The CRC of the bytes.
        computed: u16,
        /// The CRC the packet carries.
        carried: u16,
    },
    /// An unknown packet kind.
    Kind(u8),
    /// A field holds a value outside its range.
    Field {
        /// Byte offset of the field.
        offset: usize,
        /// The field's name.
        name: &'static str,
    },
}

impl core::fmt::Display for DecodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            DecodeError::TooShort { need, got } => {
                write!(f, "packet too short: {got} bytes, its kind needs {need}")
            }
            DecodeError::TooLong { want, got } => {
                write!(f, "packet too long: {got} bytes, its kind has {want}")
            }
            DecodeError::Version(v) => {
                write!(
                    f,
                    "protocol version {v}, this decoder speaks {VERSION} (and 1 and 2 of old captures)"
                )
            }
            DecodeError::Checksum { computed, carried } => write!(
                f,
                "corrupted: its CRC-16 is {carried:04x}, its bytes' {computed:04x}"
            ),
            DecodeError::Kind(k) => write!(f, "unknown packet kind 0x{k:02x}"),
            DecodeError::Field { offset, name } => {
                write!(f, "byte {offset}: {name} out of range")
            }
        }
    }
}

/// The output buffer is too small.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BufferTooSmall {
    /// Bytes the packet needs.
    pub need: usize,
}

/// The kind byte (byte 1) of each packet: what a packet is can be told without decoding it.
pub mod kind {
    /// Sample batches (averaged or single).
    pub const SAMPLES: u8 = 0x01;
    /// Temperature.
    pub const TEMPERATURE: u8 = 0x02;
    /// Fit report.
    pub const FIT: u8 = 0x03;
    /// Quick-look.
    pub const QUICK_LOOK: u8 = 0x04;
    /// Device info.
    pub const INFO: u8 = 0x05;
    /// Status.
    pub const STATUS: u8 = 0x06;
    /// Command Start.
    pub const START: u8 = 0x10;
    /// Command Stop.
    pub const STOP: u8 = 0x11;
    /// Command SetSampleRate.
    pub const SET_SAMPLE_RATE: u8 = 0x12;
    /// Command Reset.
    pub const RESET: u8 = 0x13;
    /// Command Backfill.
    pub const BACKFILL: u8 = 0x14;
}

fn cond_code(c: Condition) -> u8 {
    c.index() as u8 + 1
}

fn cond_from(code: u8) -> Option<Condition> {
    match code {
        1 => Some(Condition::X),
        2 => Some(Condition::Y),
        3 => Some(Condition::Z),
        _ => None,
    }
}

/// Little-endian writer over a slice; it has been sized before it is used.
struct Out<'a> {
    buf: &'a mut [u8],
    at: usize,
}

impl Out<'_> {
    fn bytes(&mut self, b: &[u8]) {
        if let Some(dst) = self.buf.get_mut(self.at..self.at + b.len()) {
            dst.copy_from_slice(b);
        }
        self.at += b.len();
    }
    fn u8(&mut self, v: u8) {
        self.bytes(&[v]);
    }
    fn u16(&mut self, v: u16) {
        self.bytes(&v.to_le_bytes());
    }
    fn i16(&mut self, v: i16) {
        self.bytes(&v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.bytes(&v.to_le_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.bytes(&v.to_le_bytes());
    }
    fn f32(&mut self, v: f32) {
        self.bytes(&v.to_le_bytes());
    }
    fn f64s(&mut self, v: &[f64]) {
        for x in v {
            self.bytes(&x.to_le_bytes());
        }
    }
    /// Kind, count, condition and replay, `first_seq`, `t0`: both sample layouts.
    fn batch_head<S, const N: usize>(&mut self, b: &Batch<S, N>) {
        self.u8(kind::SAMPLES);
        self.u8(b.len);
        self.u8(cond_code(b.condition) | if b.replay { 0x80 } else { 0 });
        self.u32(b.first_seq);
        self.u64(b.t0);
    }
    fn f32s(&mut self, v: &[f32]) {
        for x in v {
            self.f32(*x);
        }
    }
}

/// Little-endian reader; the length has been checked against the layout first, and a
/// short read yields zeros rather than a panic (it cannot happen after that check).
struct In<'a> {
    buf: &'a [u8],
    at: usize,
}

impl In<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        if let Some(src) = self.buf.get(self.at..self.at + N) {
            out.copy_from_slice(src);
        }
        self.at += N;
        out
    }
    fn u8(&mut self) -> u8 {
        self.take::<1>()[0]
    }
    fn u16(&mut self) -> u16 {
        u16::from_le_bytes(self.take())
    }
    fn i16(&mut self) -> i16 {
        i16::from_le_bytes(self.take())
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }
    fn f32(&mut self) -> f32 {
        f32::from_le_bytes(self.take())
    }
    fn f64(&mut self) -> f64 {
        f64::from_le_bytes(self.take())
    }
    fn f64x3(&mut self) -> [f64; 3] {
        [self.f64(), self.f64(), self.f64()]
    }
    fn f32x3(&mut self) -> [f32; 3] {
        [self.f32(), self.f32(), self.f32()]
    }
    fn field(&self, name: &'static str) -> DecodeError {
        DecodeError::Field {
            offset: self.at.saturating_sub(1),
            name,
        }
    }
}

/// Bytes of each fixed layout (header included).
mod size {
    pub const HEADER: usize = 4;
    pub const SAMPLES_HEAD: usize = 16;
    pub const SAMPLE: usize = 11;
    pub const AVERAGE: usize = 4 + 1 + 1 + 3 * 4 + 2 * (super::MAX_CONVERSIONS - 1);
    pub const TEMPERATURE: usize = HEADER + 4 + 2;
    pub const FIT: usize = HEADER + 4 + 4 + 4 + 4 + 8 + 3 * (3 * 8 + 3 * 4) + 3 * 4;
    pub const QUICK_LOOK: usize = HEADER + 3 * 8 + 3 * 4 + 3 * 8 + 3 * 4 + 8;
    pub const INFO: usize = HEADER + 3 + 1 + 1 + 4 + 4 + 4 + 1 + 2;
    pub const STATUS: usize = HEADER + 1 + 4 + 4 + 4;
    pub const START: usize = HEADER + 4;
    pub const STOP: usize = HEADER;
    pub const SET_SAMPLE_RATE: usize = HEADER + 4;
    pub const RESET: usize = HEADER;
    pub const BACKFILL: usize = HEADER + 4 + 2;
}

impl Packet {
    /// Bytes [`Packet::encode`] writes: the layout, and the CRC but for version 1 sample
    /// batches.
    pub fn encoded_len(&self) -> usize {
        match self {
            Packet::Samples(_) => self.layout_len(),
            _ => self.layout_len() + CRC_LEN,
        }
    }

    /// Bytes of the packet's layout, without a CRC.
    fn layout_len(&self) -> usize {
        match self {
            Packet::Samples(b) => size::SAMPLES_HEAD + size::SAMPLE * b.len(),
            Packet::Averages(b) => size::SAMPLES_HEAD + size::AVERAGE * b.len(),
            Packet::Temperature(_) => size::TEMPERATURE,
            Packet::Fit(_) => size::FIT,
            Packet::QuickLook(_) => size::QUICK_LOOK,
            Packet::Info(_) => size::INFO,
            Packet::Status(_) => size::STATUS,
            Packet::Command(c) => match c {
                Command::Start { .. } => size::START,
                Command::Stop => size::STOP,
                Command::SetSampleRate { .. } => size::SET_SAMPLE_RATE,
                Command::Reset => size::RESET,
                Command::Backfill { .. } => size::BACKFILL,
            },
        }
    }

    /// Write the packet to the front of `buf`; returns the bytes written.
    pub fn encode(&self, buf: &mut [u8]) -> Result<usize, BufferTooSmall> {
        let need = self.encoded_len();
        let layout = self.layout_len();
        let buf = buf.get_mut(..need).ok_or(BufferTooSmall { need })?;
        self.encode_layout(buf.get_mut(..layout).unwrap_or(&mut []));
        if need > layout {
            let crc = CRC16.checksum(buf.get(..layout).unwrap_or(&[]));
            if let Some(tail) = buf.get_mut(layout..) {
                tail.copy_from_slice(&crc.to_le_bytes());
            }
        }
        Ok(need)
    }

    /// The layout, version byte first, into `buf` (exactly its length).
    fn encode_layout(&self, buf: &mut [u8]) {
        let mut o = Out { buf, at: 0 };
        o.u8(match self {
            Packet::Samples(_) => VERSION_1,
            _ => VERSION,
        });
        match self {
            Packet::Averages(b) => {
                o.batch_head(b);
                for s in b.samples() {
                    o.u32(s.dt);
                    o.u8(s.count);
                    o.u8(s.flags);
                    for v in s.sums {
                        o.u32(v as u32);
                    }
                    for g in s.gaps {
                        o.u16(g);
                    }
                }
            }
            Packet::Samples(b) => {
                o.batch_head(b);
                for s in b.samples() {
                    o.u32(s.dt);
                    for c in s.counts {
                        o.i16(c);
                    }
                    o.u8(s.flags);
                }
            }
            Packet::Temperature(t) => {
                o.bytes(&[kind::TEMPERATURE, 0, 0]);
                o.u32(t.seq);
                o.i16(t.centi_c);
            }
            Packet::Fit(f) => {
                o.bytes(&[kind::FIT, cond_code(f.condition), u8::from(f.is_final)]);
                o.u32(f.n);
                o.u32(f.first_seq);
                o.u32(f.last_seq);
                o.u32(f.rate_uhz);
                o.u64(f.step);
                for ch in 0..3 {
                    if let (Some(c), Some(s)) = (f.coef.get(ch), f.se.get(ch)) {
                        o.f64s(c);
                        o.f32s(s);
                    }
                }
                o.f32s(&f.rms);
            }
            Packet::QuickLook(q) => {
                o.bytes(&[kind::QUICK_LOOK, 0, 0]);
                o.f64s(&q.sensitivity);
                o.f32s(&q.sensitivity_u);
                o.f64s(&q.angle_deg);
                o.f32s(&q.angle_u);
                o.f64s(&[q.g_loc]);
            }
            Packet::Info(i) => {
                o.bytes(&[kind::INFO, 0, 0]);
                o.bytes(&i.firmware);
                o.u8(match i.chip {
                    Chip::None => 0,
                    Chip::Lsm6ds33 => 1,
                    Chip::Lsm6ds3trc => 2,
                });
                o.u8(match i.clock {
                    ClockSource::TimerHfxo => 0,
                    ClockSource::RtcLfrc => 1,
                    ClockSource::TimerHfint => 2,
                });
                o.u32(i.tick_hz);
                o.u32(i.sensor_odr_mhz);
                o.u32(i.sample_rate_mhz);
                o.u8(i.full_scale_g);
                o.u16(i.ring_capacity);
            }
            Packet::Status(s) => {
                o.u8(kind::STATUS);
                o.u8(match s.state {
                    RunState::Idle => 0,
                    RunState::Running => 1,
                    RunState::Complete => 2,
                });
                o.u8(match s.sensor {
                    SensorStatus::Ok => 0,
                    SensorStatus::Absent => 1,
                    SensorStatus::UnknownChip => 2,
                    SensorStatus::BusError => 3,
                    SensorStatus::NoDataReady => 4,
                });
                o.u8(s.condition.map_or(0, cond_code) | (s.last_error.map_or(0, |e| e as u8) << 4));
                o.u32(s.lost);
                o.u32(s.ring_oldest);
                o.u32(s.ring_newest);
            }
            Packet::Command(c) => match c {
                Command::Start {
                    condition,
                    rate_uhz,
                } => {
                    o.bytes(&[kind::START, cond_code(*condition), 0]);
                    o.u32(*rate_uhz);
                }
                Command::Stop => o.bytes(&[kind::STOP, 0, 0]),
                Command::SetSampleRate { mhz } => {
                    o.bytes(&[kind::SET_SAMPLE_RATE, 0, 0]);
                    o.u32(*mhz);
                }
                Command::Reset => o.bytes(&[kind::RESET, 0, 0]),
                Command::Backfill { from_seq, count } => {
                    o.bytes(&[kind::BACKFILL, 0, 0]);
                    o.u32(*from_seq);
                    o.u16(*count);
                }
            },
        }
    }

    /// Read one packet: exactly the bytes of one GATT value. A version 3 packet's CRC is
    /// checked before anything else is read.
    pub fn decode(bytes: &[u8]) -> Result<Packet, DecodeError> {
        if bytes.first() != Some(&VERSION) {
            return Self::decode_layout(bytes);
        }
        let Some(split) = bytes
            .len()
            .checked_sub(CRC_LEN)
            .filter(|n| *n >= size::HEADER)
        else {
            return Err(DecodeError::TooShort {
                need: size::HEADER + CRC_LEN,
                got: bytes.len(),
            });
        };
        let (layout, tail) = bytes.split_at(split);
        let carried = match tail.first_chunk::<CRC_LEN>() {
            Some(t) => u16::from_le_bytes(*t),
            None => 0,
        };
        let computed = CRC16.checksum(layout);
        if computed != carried {
            return Err(DecodeError::Checksum { computed, carried });
        }
        Self::decode_layout(layout)
    }

    /// A packet's layout (without its CRC, for version 3).
    fn decode_layout(bytes: &[u8]) -> Result<Packet, DecodeError> {
        let got = bytes.len();
        let [version, k, b2, b3] = match bytes.first_chunk::<4>() {
            Some(h) => *h,
            None => {
                return Err(DecodeError::TooShort {
                    need: size::HEADER,
                    got,
                })
            }
        };
        // Versions 2 and 3 have the averaged samples' layout; every other layout is
        // version 1's.
        let averaged = k == kind::SAMPLES && (version == VERSION_AVERAGES || version == VERSION);
        let known = version == VERSION || version == VERSION_1 || averaged;
        if !known {
            return Err(DecodeError::Version(version));
        }
        let (sample_size, max_samples) = if averaged {
            (size::AVERAGE, MAX_AVERAGES)
        } else {
            (size::SAMPLE, MAX_SAMPLES)
        };
        let want = match k {
            kind::SAMPLES => size::SAMPLES_HEAD + sample_size * usize::from(b2),
            kind::TEMPERATURE => size::TEMPERATURE,
            kind::FIT => size::FIT,
            kind::QUICK_LOOK => size::QUICK_LOOK,
            kind::INFO => size::INFO,
            kind::STATUS => size::STATUS,
            kind::START => size::START,
            kind::STOP => size::STOP,
            kind::SET_SAMPLE_RATE => size::SET_SAMPLE_RATE,
            kind::RESET => size::RESET,
            kind::BACKFILL => size::BACKFILL,
            other => return Err(DecodeError::Kind(other)),
        };
        if got < want {
            return Err(DecodeError::TooShort { need: want, got });
        }
        if got > want {
            return Err(DecodeError::TooLong { want, got });
        }
        let h = Head { kind: k, b2, b3 };
        let mut i = In { buf: bytes, at: 4 };
        match k {
            kind::SAMPLES => decode_samples(&mut i, h, averaged, max_samples),
            kind::TEMPERATURE => {
                h.reserved()?;
                Ok(Packet::Temperature(Temperature {
                    seq: i.u32(),
                    centi_c: i.i16(),
                }))
            }
            kind::FIT => decode_fit(&mut i, h),
            kind::QUICK_LOOK => {
                h.reserved()?;
                Ok(Packet::QuickLook(QuickLook {
                    sensitivity: i.f64x3(),
                    sensitivity_u: i.f32x3(),
                    angle_deg: i.f64x3(),
                    angle_u: i.f32x3(),
                    g_loc: i.f64(),
                }))
            }
            kind::INFO => decode_info(&mut i, h),
            kind::STATUS => decode_status(&mut i, h),
            // The commands (every other kind returned above).
            _ => decode_command(&mut i, h).map(Packet::Command),
        }
    }
}

/// A packet's kind and its bytes 2 and 3, whose meaning depends on the kind.
#[derive(Clone, Copy)]
struct Head {
    kind: u8,
    b2: u8,
    b3: u8,
}

impl Head {
    /// `v`, at byte `offset`, must be zero.
    fn zero(offset: usize, v: u8, name: &'static str) -> Result<(), DecodeError> {
        if v == 0 {
            Ok(())
        } else {
            Err(DecodeError::Field { offset, name })
        }
    }

    /// Bytes 2 and 3, where a kind leaves them unused.
    fn reserved(self) -> Result<(), DecodeError> {
        Head::zero(2, self.b2, "reserved").and_then(|()| Head::zero(3, self.b3, "reserved"))
    }

    /// The condition code `v` at byte `offset`.
    fn cond(offset: usize, v: u8) -> Result<Condition, DecodeError> {
        cond_from(v).ok_or(DecodeError::Field {
            offset,
            name: "condition",
        })
    }
}

/// A batch of samples (version 1) or of averages (version 2).
fn decode_samples(
    i: &mut In<'_>,
    h: Head,
    averaged: bool,
    max_samples: usize,
) -> Result<Packet, DecodeError> {
    let Head { b2, b3, .. } = h;
    if b2 == 0 || usize::from(b2) > max_samples {
        return Err(DecodeError::Field {
            offset: 2,
            name: "sample count",
        });
    }
    Head::zero(3, b3 & 0x7C, "batch flags")?;
    let condition = Head::cond(3, b3 & 0x03)?;
    let (replay, first_seq, t0) = (b3 & 0x80 != 0, i.u32(), i.u64());
    if averaged {
        let b = AverageBatch::new(condition, replay, first_seq, t0);
        return read_averages(i, b, b2).map(Packet::Averages);
    }
    let mut b = SampleBatch::new(condition, replay, first_seq, t0);
    for slot in b.samples.iter_mut().take(usize::from(b2)) {
        let dt = i.u32();
        let counts = [i.i16(), i.i16(), i.i16()];
        let flags = i.u8();
        if flags & !SampleFlags::ALL != 0 {
            return Err(i.field("sample flags"));
        }
        *slot = Sample { dt, counts, flags };
    }
    b.len = b2;
    Ok(Packet::Samples(b))
}

/// A fit report.
fn decode_fit(i: &mut In<'_>, h: Head) -> Result<Packet, DecodeError> {
    let condition = Head::cond(2, h.b2)?;
    if h.b3 > 1 {
        return Err(DecodeError::Field {
            offset: 3,
            name: "final flag",
        });
    }
    let (n, first_seq, last_seq, rate_uhz, step) = (i.u32(), i.u32(), i.u32(), i.u32(), i.u64());
    let mut coef = [[0.0f64; 3]; 3];
    let mut se = [[0.0f32; 3]; 3];
    for (c, s) in coef.iter_mut().zip(se.iter_mut()) {
        *c = i.f64x3();
        *s = i.f32x3();
    }
    Ok(Packet::Fit(FitReport {
        condition,
        is_final: h.b3 == 1,
        n,
        first_seq,
        last_seq,
        rate_uhz,
        step,
        coef,
        se,
        rms: i.f32x3(),
    }))
}

/// The device's description.
fn decode_info(i: &mut In<'_>, h: Head) -> Result<Packet, DecodeError> {
    h.reserved()?;
    let firmware = [i.u8(), i.u8(), i.u8()];
    let chip = match i.u8() {
        0 => Chip::None,
        1 => Chip::Lsm6ds33,
        2 => Chip::Lsm6ds3trc,
        _ => return Err(i.field("chip")),
    };
    let clock = match i.u8() {
        0 => ClockSource::TimerHfxo,
        1 => ClockSource::RtcLfrc,
        2 => ClockSource::TimerHfint,
        _ => return Err(i.field("clock source")),
    };
    Ok(Packet::Info(DeviceInfo {
        firmware,
        chip,
        clock,
        tick_hz: i.u32(),
        sensor_odr_mhz: i.u32(),
        sample_rate_mhz: i.u32(),
        full_scale_g: i.u8(),
        ring_capacity: i.u16(),
    }))
}

/// The device's state.
fn decode_status(i: &mut In<'_>, h: Head) -> Result<Packet, DecodeError> {
    let state = match h.b2 {
        0 => RunState::Idle,
        1 => RunState::Running,
        2 => RunState::Complete,
        _ => {
            return Err(DecodeError::Field {
                offset: 2,
                name: "run state",
            })
        }
    };
    let sensor = match h.b3 {
        0 => SensorStatus::Ok,
        1 => SensorStatus::Absent,
        2 => SensorStatus::UnknownChip,
        3 => SensorStatus::BusError,
        4 => SensorStatus::NoDataReady,
        _ => {
            return Err(DecodeError::Field {
                offset: 3,
                name: "sensor status",
            })
        }
    };
    // Byte 4: condition code in the low nibble, error code in the high one.
    let ce = i.u8();
    let condition = match ce & 0x0F {
        0 => None,
        c => Some(Head::cond(4, c)?),
    };
    let last_error = match ce >> 4 {
        0 => None,
        1 => Some(CommandError::Busy),
        2 => Some(CommandError::NotRunning),
        3 => Some(CommandError::BadRate),
        4 => Some(CommandError::SensorFault),
        5 => Some(CommandError::NotInRing),
        6 => Some(CommandError::FitFailed),
        7 => Some(CommandError::MtuTooSmall),
        _ => {
            return Err(DecodeError::Field {
                offset: 4,
                name: "error code",
            })
        }
    };
    Ok(Packet::Status(Status {
        state,
        sensor,
        condition,
        lost: i.u32(),
        ring_oldest: i.u32(),
        ring_newest: i.u32(),
        last_error,
    }))
}

/// A command from the host: Start, SetSampleRate, Stop, Reset or Backfill.
fn decode_command(i: &mut In<'_>, h: Head) -> Result<Command, DecodeError> {
    match h.kind {
        kind::START => {
            let condition = Head::cond(2, h.b2)?;
            Head::zero(3, h.b3, "reserved")?;
            let rate_uhz = i.u32();
            if rate_uhz == 0 {
                return Err(DecodeError::Field {
                    offset: 4,
                    name: "rate",
                });
            }
            Ok(Command::Start {
                condition,
                rate_uhz,
            })
        }
        kind::SET_SAMPLE_RATE => {
            h.reserved()?;
            let mhz = i.u32();
            if mhz == 0 {
                return Err(DecodeError::Field {
                    offset: 4,
                    name: "sample rate",
                });
            }
            Ok(Command::SetSampleRate { mhz })
        }
        kind::STOP => h.reserved().map(|()| Command::Stop),
        kind::RESET => h.reserved().map(|()| Command::Reset),
        _ => {
            // kind::BACKFILL (decode checked the kind).
            h.reserved()?;
            Ok(Command::Backfill {
                from_seq: i.u32(),
                count: i.u16(),
            })
        }
    }
}

/// The `n` samples of a version 2 batch (30 bytes each), after its header.
fn read_averages(i: &mut In<'_>, mut b: AverageBatch, n: u8) -> Result<AverageBatch, DecodeError> {
    for slot in b.samples.iter_mut().take(usize::from(n)) {
        let dt = i.u32();
        let count = i.u8();
        if count == 0 || usize::from(count) > MAX_CONVERSIONS {
            return Err(i.field("conversion count"));
        }
        let flags = i.u8();
        if flags & !SampleFlags::ALL != 0 {
            return Err(i.field("sample flags"));
        }
        let mut sums = [0i32; 3];
        for s in sums.iter_mut() {
            *s = i.u32() as i32;
            // A sum of `count` i16 readings.
            let n = i64::from(count);
            if !(n * i64::from(i16::MIN)..=n * i64::from(i16::MAX)).contains(&i64::from(*s)) {
                return Err(DecodeError::Field {
                    offset: i.at.saturating_sub(4),
                    name: "sum of counts",
                });
            }
        }
        let mut gaps = [0u16; MAX_CONVERSIONS - 1];
        for (k, g) in gaps.iter_mut().enumerate() {
            *g = i.u16();
            // Used gaps are at least one tick (conversions in order); unused ones are 0.
            if (*g == 0) == (k + 1 < usize::from(count)) {
                return Err(DecodeError::Field {
                    offset: i.at.saturating_sub(2),
                    name: "conversion gap",
                });
            }
        }
        *slot = Average {
            dt,
            gaps,
            count,
            sums,
            flags,
        };
    }
    b.len = n;
    Ok(b)
}
