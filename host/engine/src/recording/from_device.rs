//! From the device's decoded packets to a recording (formats.md CSV) and its fit log (one
//! JSON object per line: the device's fit reports and quick-look). Used by the demo,
//! which feeds it the packets of the device logic run on the host; the BLE recorder will
//! feed it the same packets from the air.
//!
//! Temperatures arrive about once a second, tagged with the seq of the sample they were
//! read with. Each row gets the latest temperature at or before its seq; rows before the
//! first temperature wait (about a second) and get the first one.
//!
//! Gaps: see [`Recorder`]. The BLE recorder (`record`) asks the device to replay what
//! [`Recorder::missing`] lists and gives up what its ring no longer holds.
//!
//! Restarts: a status of an idle device whose newest sample is older than the newest
//! received in this boot shows that the device restarted (its sequence numbers and clock count from power-up).
//! What was missing is given up, and the rows that follow are in the next `boot`, whose
//! time starts afresh (docs/recording.md).

use crate::recording::{Columns, Metadata, Row, Writer, TICK_HZ_KEY};
use rotacal_shared::device::route::Characteristic;
use rotacal_shared::packet::{FitReport, Packet, QuickLook, RunState, SampleFlags, Status};
use rotacal_shared::{Aperture, Condition, Ticks};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::io::{self, Write};

/// The GATT characteristic a value came from or goes to (docs/protocol.md, GATT).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Channel {
    /// Samples and temperatures (notify).
    Stream,
    /// Fit reports, the quick-look and status (notify, read).
    Results,
    /// The device-info value (read on connect).
    Info,
}

impl Channel {
    /// The characteristic on which the device sends `p` (none for a command, which the
    /// host writes to the control characteristic): the firmware's routing
    /// ([`Characteristic::of`]), so the host's emulated device and the BlueZ stand-in send
    /// what the board would.
    pub fn of(p: &Packet) -> Option<Channel> {
        Characteristic::of(p).map(|c| match c {
            Characteristic::Stream => Channel::Stream,
            Characteristic::Results => Channel::Results,
            Characteristic::Info => Channel::Info,
        })
    }

    /// One letter, for the capture file.
    pub fn letter(self) -> char {
        match self {
            Channel::Stream => 's',
            Channel::Results => 'r',
            Channel::Info => 'i',
        }
    }

    /// From [`Channel::letter`].
    pub fn from_letter(c: char) -> Option<Self> {
        match c {
            's' => Some(Channel::Stream),
            'r' => Some(Channel::Results),
            'i' => Some(Channel::Info),
            _ => None,
        }
    }
}

/// One line of the fit log: a device fit report. It mirrors `packet::FitReport` field by
/// field (the packet types have no serde), with the standard errors widened to f64 and
/// the device's tick rate added, so that the line stands alone.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FitLine {
    /// x, y or z.
    pub condition: Condition,
    /// At stop (true) or periodic.
    pub is_final: bool,
    /// Samples fitted.
    pub n: u32,
    /// First sample's seq.
    pub first_seq: u32,
    /// Last sample's seq.
    pub last_seq: u32,
    /// Nominal rate, µHz.
    pub rate_uhz: u32,
    /// Rotation per tick, 2⁻⁶⁴ turns (the device's regressors).
    pub step: u64,
    /// Device clock, ticks per second.
    pub tick_hz: u32,
    /// A, B, C per channel u, v, w, counts.
    pub coef: [[f64; 3]; 3],
    /// Their standard errors.
    pub se: [[f64; 3]; 3],
    /// Residual RMS per channel, counts.
    pub rms: [f64; 3],
    /// The device's boot the window is in (the recording's `boot`); absent for the first.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub boot: u32,
}

fn is_zero(x: &u32) -> bool {
    *x == 0
}

impl FitLine {
    /// From a report, with the device's tick rate, in the device's first boot.
    pub fn new(f: &FitReport, tick_hz: u32) -> Self {
        FitLine {
            condition: f.condition,
            is_final: f.is_final,
            n: f.n,
            first_seq: f.first_seq,
            last_seq: f.last_seq,
            rate_uhz: f.rate_uhz,
            step: f.step,
            tick_hz,
            coef: f.coef,
            se: f.se.map(|r| r.map(f64::from)),
            rms: f.rms.map(f64::from),
            boot: 0,
        }
    }
}

/// A line of the fit log.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LogLine {
    /// A fit report.
    Fit(FitLine),
    /// The quick-look: s (counts per m/s²), φ (deg), their standard uncertainties, g.
    QuickLook {
        /// s_u, s_v, s_w.
        sensitivity: [f64; 3],
        /// Their standard uncertainties.
        sensitivity_u: [f64; 3],
        /// φ_uv, φ_vw, φ_wu.
        angle_deg: [f64; 3],
        /// Their standard uncertainties.
        angle_u: [f64; 3],
        /// g used, m/s².
        g_loc: f64,
    },
}

impl LogLine {
    fn quick_look(q: &QuickLook) -> Self {
        LogLine::QuickLook {
            sensitivity: q.sensitivity,
            sensitivity_u: q.sensitivity_u.map(f64::from),
            angle_deg: q.angle_deg,
            angle_u: q.angle_u.map(f64::from),
            g_loc: q.g_loc,
        }
    }
}

/// What was recorded.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct RecordSummary {
    /// Rows written.
    pub rows: u64,
    /// Fit-log lines written.
    pub fit_lines: u64,
    /// Rows that arrived in replay batches and filled a gap.
    pub recovered: u64,
    /// Samples that arrived twice (a replay overlapping live data); the first copy is kept.
    pub duplicates: u64,
    /// Seq ranges [first, last] that never arrived (lost on the link and not recovered).
    pub lost: Vec<(u32, u32)>,
}

impl RecordSummary {
    /// Samples in the `lost` ranges.
    pub fn lost_samples(&self) -> u64 {
        self.lost
            .iter()
            .map(|&(a, b)| u64::from(b.wrapping_sub(a)) + 1)
            .sum()
    }
}

/// See the module documentation.
///
/// Rows are written in seq order. A sample that arrives after a gap is held until the gap
/// is filled by replayed samples ([`Recorder::missing`] says what to ask the device for)
/// or given up ([`Recorder::give_up_before`]); so the recording is always a file that
/// `calibrate` reads (time increasing within a condition), and whatever was received but
/// not yet written is in the raw capture (`capture`).
pub struct Recorder<W: Write, F: Write> {
    rows: Writer<W>,
    fits: F,
    tick_hz: u32,
    /// Rows waiting for the first temperature (in seq order).
    pending: Vec<Row<'static>>,
    /// Temperatures by the seq they were read with, °C.
    temps: BTreeMap<u32, f64>,
    /// The next seq to write; None before the first sample.
    next_seq: Option<u32>,
    /// Rows after a gap, waiting for it to be filled or given up.
    held: BTreeMap<u32, Row<'static>>,
    /// Samples known to exist up to this seq (from the device's status), so that a gap at
    /// the end of the stream shows in `missing`.
    expected_through: Option<u32>,
    /// The device's boot the rows are in (0 the first), written when the file has the
    /// `boot` column.
    boot: u32,
    boot_column: bool,
    /// The newest seq received in this boot.
    boot_newest: Option<u32>,
    /// A Start was written for this condition: its status reply says where it starts.
    await_start: Option<Condition>,
    summary: RecordSummary,
}

/// Where an appended recording left off.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Resume {
    /// The header has the `conv_missed` column (recordings before rotacal 0.3 do not).
    pub missed: bool,
    /// The header has the `boot` column (recordings before rotacal 0.4 do not), and the
    /// last row's boot.
    pub boot: Option<u32>,
    /// The last row's seq: a device whose newest sample is older has restarted since.
    pub newest: Option<u32>,
}

/// The recording's columns.
pub const COLUMNS: Columns = Columns {
    t_s: true,
    angle_deg: false,
    seq: true,
    temp_c: true,
    rate_hz: false,
    gravity: false,
    pose: false,
    unc: false,
    conv_gaps: true,
    conv_missed: true,
    boot: true,
};

impl<W: Write, F: Write> Recorder<W, F> {
    /// Start a recording with `meta`, timestamps in ticks of `tick_hz`.
    pub fn new(rows: W, fits: F, meta: &Metadata, tick_hz: u32) -> io::Result<Self> {
        // `conv_gaps` counts ticks of this clock.
        let mut meta = meta.clone();
        meta.other
            .insert(TICK_HZ_KEY.to_string(), tick_hz.to_string());
        Self::with_writer(Writer::new(rows, &meta, &COLUMNS)?, fits, tick_hz)
    }

    /// Continue a recording whose preamble and header `rows` already hold, from where
    /// `resume` says it left off.
    pub fn append(rows: W, fits: F, tick_hz: u32, resume: Resume) -> io::Result<Self> {
        let columns = Columns {
            conv_missed: resume.missed,
            boot: resume.boot.is_some(),
            ..COLUMNS
        };
        let mut r = Self::with_writer(Writer::append(rows, &columns), fits, tick_hz)?;
        r.boot = resume.boot.unwrap_or(0);
        r.boot_column = resume.boot.is_some();
        r.boot_newest = resume.newest;
        Ok(r)
    }

    fn with_writer(rows: Writer<W>, fits: F, tick_hz: u32) -> io::Result<Self> {
        if tick_hz == 0 {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "device tick rate 0",
            ));
        }
        Ok(Recorder {
            rows,
            fits,
            tick_hz,
            pending: Vec::new(),
            temps: BTreeMap::new(),
            next_seq: None,
            held: BTreeMap::new(),
            expected_through: None,
            boot: 0,
            boot_column: true,
            boot_newest: None,
            await_start: None,
            summary: RecordSummary::default(),
        })
    }

    /// What has been recorded so far.
    pub fn summary(&self) -> &RecordSummary {
        &self.summary
    }

    /// The temperature for a row: the latest read at or before its seq, else the first.
    fn temp_for(&self, seq: u32) -> Option<f64> {
        self.temps
            .range(..=seq)
            .next_back()
            .or_else(|| self.temps.iter().next())
            .map(|(_, &t)| t)
    }

    fn emit(&mut self, seq: u32, mut row: Row<'static>) -> io::Result<()> {
        match self.temp_for(seq) {
            Some(t) => {
                row.temp_c = Some(t);
                self.rows.write_row(&row)?;
                self.summary.rows += 1;
            }
            None => self.pending.push(row),
        }
        Ok(())
    }

    /// Write the held rows that are now in order.
    fn drain(&mut self) -> io::Result<()> {
        while let Some(next) = self.next_seq {
            let Some(row) = self.held.remove(&next) else {
                break;
            };
            self.emit(next, row)?;
            self.next_seq = Some(next.wrapping_add(1));
        }
        self.prune_temperatures();
        Ok(())
    }

    /// Forget the temperatures no row can take any more: every row still to come has a seq
    /// of at least `next_seq` and takes the latest temperature at or before it, so none
    /// before that latest one is needed (the map would otherwise grow by one entry a
    /// second for as long as the recording runs).
    fn prune_temperatures(&mut self) {
        let Some(next) = self.next_seq else {
            return;
        };
        if !self.pending.is_empty() {
            return;
        }
        if let Some(keep) = self.temps.range(..=next).next_back().map(|(k, _)| *k) {
            if self.temps.keys().next().is_some_and(|first| *first < keep) {
                self.temps = self.temps.split_off(&keep);
            }
        }
    }

    /// Entries held besides the rows written: temperatures, rows after a gap and rows
    /// waiting for the first temperature. What the recorder's memory grows with.
    pub fn held_entries(&self) -> usize {
        self.temps.len() + self.held.len() + self.pending.len()
    }

    fn sample(&mut self, seq: u32, mut row: Row<'static>, replay: bool) -> io::Result<()> {
        row.boot = self.boot_column.then_some(self.boot);
        self.boot_newest = Some(self.boot_newest.map_or(seq, |n| n.max(seq)));
        let next = *self.next_seq.get_or_insert(seq);
        // Sequence numbers are u32 from the device's start: 8.5 years at 16 Hz, so
        // "before" is a plain comparison within one recording.
        if seq < next || self.held.contains_key(&seq) {
            self.summary.duplicates += 1;
            return Ok(());
        }
        if replay {
            self.summary.recovered += 1;
        }
        self.held.insert(seq, row);
        self.drain()
    }

    /// The newest sequence number received (written or held), if any.
    pub fn newest(&self) -> Option<u32> {
        let held = self.held.keys().next_back().copied();
        let written = self.next_seq.map(|n| n.wrapping_sub(1));
        held.max(written)
            .filter(|_| self.summary.rows > 0 || !self.held.is_empty())
    }

    /// The seq ranges [first, last] not yet received before the newest sample held (or
    /// the newest the device said it has): what to ask the device to replay.
    pub fn missing(&self) -> Vec<(u32, u32)> {
        let Some(mut next) = self.next_seq else {
            return Vec::new();
        };
        let mut out = Vec::new();
        for &s in self.held.keys() {
            if s > next {
                out.push((next, s - 1));
            }
            next = s.saturating_add(1);
        }
        if let Some(end) = self.expected_through {
            if end >= next {
                out.push((next, end));
            }
        }
        out
    }

    /// The device holds samples up to `seq` (its status's newest ring entry).
    pub fn expect_through(&mut self, seq: u32) {
        if self.next_seq.is_some() {
            self.expected_through = Some(self.expected_through.map_or(seq, |e| e.max(seq)));
        }
    }

    /// Give up the missing samples before `seq` (they have left the device's ring, or the
    /// replay didn't come): they are reported lost, and the held rows after them written.
    pub fn give_up_before(&mut self, seq: u32) -> io::Result<()> {
        for (a, b) in self.missing() {
            if a >= seq {
                break;
            }
            let b = b.min(seq - 1);
            self.summary.lost.push((a, b));
            if self.next_seq == Some(a) {
                self.next_seq = Some(b.wrapping_add(1));
                self.drain()?;
            }
        }
        if self.expected_through.is_some_and(|e| e < seq) {
            self.expected_through = None;
        }
        Ok(())
    }

    fn log(&mut self, line: &LogLine) -> io::Result<()> {
        let text = serde_json::to_string(line).map_err(io::Error::other)?;
        writeln!(self.fits, "{text}")?;
        self.summary.fit_lines += 1;
        Ok(())
    }

    /// Take one packet from the device.
    pub fn packet(&mut self, p: &Packet) -> io::Result<()> {
        match p {
            Packet::Samples(b) => {
                for (seq, t, s) in b.iter() {
                    let [u, v, w] = s.counts.map(f64::from);
                    let mut row = Row::new(b.condition, u, v, w);
                    row.seq = Some(u64::from(seq));
                    row.t_s = Some(t as f64 / f64::from(self.tick_hz));
                    row.conv_gaps = Some(Aperture::point(Ticks(0)));
                    self.sample(seq, row, b.replay)?;
                }
            }
            Packet::Averages(b) => {
                for (seq, ap, s) in b.iter() {
                    // The shortest decimal of the mean reads back as the same f64.
                    let [u, v, w] = s.mean();
                    let mut row = Row::new(b.condition, u, v, w);
                    row.seq = Some(u64::from(seq));
                    row.t_s = Some(ap.first().0 as f64 / f64::from(self.tick_hz));
                    row.conv_gaps = Some(ap);
                    row.conv_missed = Some(SampleFlags::missed(s.flags));
                    self.sample(seq, row, b.replay)?;
                }
            }
            Packet::Temperature(t) => {
                self.temps.insert(t.seq, f64::from(t.centi_c) / 100.0);
                for row in std::mem::take(&mut self.pending) {
                    let seq = row.seq.map_or(t.seq, |s| s as u32);
                    self.emit(seq, row)?;
                }
            }
            Packet::Fit(f) => {
                let line = FitLine {
                    boot: self.boot,
                    ..FitLine::new(f, self.tick_hz)
                };
                self.log(&LogLine::Fit(line))?
            }
            Packet::QuickLook(q) => self.log(&LogLine::quick_look(q))?,
            Packet::Status(s) => {
                // A running device's status may be older than the samples streamed after
                // it (another queue); one that restarted is idle and makes none.
                let idle = s.state != RunState::Running;
                if idle && self.boot_newest.is_some_and(|n| s.ring_newest < n) {
                    self.new_boot()?;
                }
                if let Some(c) = self.await_start.take() {
                    self.start_status(c, s);
                }
            }
            Packet::Info(_) | Packet::Command(_) => {}
        }
        Ok(())
    }

    /// Flush rows and fit-log lines to the underlying writers.
    pub fn flush(&mut self) -> io::Result<()> {
        self.rows.flush()?;
        self.fits.flush()
    }

    /// The underlying writers (to sync files).
    pub fn writers(&self) -> (&W, &F) {
        (self.rows.get_ref(), &self.fits)
    }

    /// A new run of the device starts (a Start command): what is still missing is given
    /// up, and sequence numbers are followed afresh (a device that restarted counts from 0).
    pub fn restart_sequence(&mut self) -> io::Result<()> {
        self.give_up_before(u32::MAX)?;
        self.next_seq = None;
        self.expected_through = None;
        Ok(())
    }

    /// A Start for `condition` was written: the status that answers it says which seq the
    /// condition starts at, so that a first batch lost or late is seen as a gap.
    pub fn start_written(&mut self, condition: Condition) {
        self.await_start = Some(condition);
    }

    /// The status after a Start: accepted (not a refusal, nor the "busy" answer to a
    /// repeat), running `condition`, and sent before its first sample, its ring's newest
    /// sample is the last one before the condition. An empty ring reads (0, 0): the device
    /// has made no sample since power-up, and the condition starts at 0. (A ring holding
    /// only seq 0 reads the same: a condition stopped within its first 62.5 ms slot. Its
    /// sample would then be asked for and reported lost.)
    fn start_status(&mut self, condition: Condition, s: &Status) {
        let accepted = s.last_error.is_none()
            && s.state == RunState::Running
            && s.condition == Some(condition);
        if !accepted || self.next_seq.is_some() {
            return;
        }
        let first = match (s.ring_oldest, s.ring_newest) {
            (0, 0) => 0,
            (_, newest) => newest.wrapping_add(1),
        };
        self.next_seq = Some(first);
    }

    /// The device restarted: what is missing of its last boot is given up (its ring went
    /// with it), and sequence numbers, temperatures and time are followed afresh, in the
    /// next boot.
    fn new_boot(&mut self) -> io::Result<()> {
        self.restart_sequence()?;
        self.temps.clear();
        self.boot = self.boot.saturating_add(1);
        self.boot_newest = None;
        Ok(())
    }

    /// The device's boot the rows are in now (0 the first of this recording).
    pub fn boot(&self) -> u32 {
        self.boot
    }

    /// Samples missing now.
    pub fn missing_samples(&self) -> u64 {
        self.missing()
            .iter()
            .map(|&(a, b)| u64::from(b.wrapping_sub(a)) + 1)
            .sum()
    }

    /// Give up whatever is still missing, flush everything and say what was recorded.
    /// Rows still waiting for their first temperature are an error: the device sent
    /// none, and none is invented.
    pub fn finish(mut self) -> io::Result<RecordSummary> {
        self.give_up_before(u32::MAX)?;
        if !self.pending.is_empty() {
            return Err(io::Error::new(
                io::ErrorKind::InvalidData,
                format!(
                    "{} samples arrived but no temperature: the device sent none",
                    self.pending.len()
                ),
            ));
        }
        self.flush()?;
        Ok(self.summary)
    }
}

impl FitLine {
    /// What makes the line unusable, if anything: the device clock, the window and the
    /// numbers (its condition is one by its type).
    pub fn check(&self) -> Result<(), FitLogProblem> {
        if self.tick_hz == 0 {
            return Err(FitLogProblem::NoTickRate);
        }
        if self.first_seq > self.last_seq {
            return Err(FitLogProblem::Window {
                first_seq: self.first_seq,
                last_seq: self.last_seq,
            });
        }
        let finite = self.coef.iter().chain(&self.se).flatten().chain(&self.rms);
        if finite.into_iter().any(|x| !x.is_finite()) {
            return Err(FitLogProblem::NotFinite);
        }
        Ok(())
    }
}

/// A packet's bytes on the wire.
pub fn encode(p: &Packet) -> Vec<u8> {
    let mut buf = [0u8; rotacal_shared::packet::MAX_PACKET];
    match p.encode(&mut buf) {
        Ok(n) => buf.get(..n).unwrap_or(&[]).to_vec(),
        Err(_) => Vec::new(),
    }
}

/// Bytes from hex digits (two per byte), None if any pair isn't hex.
pub fn from_hex(s: &str) -> Option<Vec<u8>> {
    if s.len() % 2 != 0 {
        return None;
    }
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(s.get(i..i + 2)?, 16).ok())
        .collect()
}

/// What is wrong with a line of the fit log.
#[derive(Debug, thiserror::Error)]
pub enum FitLogProblem {
    /// Not a fit report or quick-look as JSON.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// A device clock of 0 ticks per second.
    #[error("tick_hz is 0")]
    NoTickRate,
    /// A window that ends before it starts.
    #[error("first_seq {first_seq} is after last_seq {last_seq}")]
    Window {
        /// Its first sample's seq.
        first_seq: u32,
        /// Its last sample's seq.
        last_seq: u32,
    },
    /// A number that is not finite.
    #[error("a coefficient, standard error or rms is not finite")]
    NotFinite,
}

/// A fit log's problem, with the file and the 1-based line.
#[derive(Debug, thiserror::Error)]
#[error("{source_name}:{line}: {problem}")]
pub struct FitLogError {
    /// The file.
    pub source_name: String,
    /// The line.
    pub line: usize,
    /// What is wrong.
    pub problem: FitLogProblem,
}

/// Read a fit log: one JSON object per line; errors name the line.
pub fn read_fit_log(text: &str, source: &str) -> Result<Vec<LogLine>, FitLogError> {
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| {
            let at = |problem: FitLogProblem| FitLogError {
                source_name: source.to_string(),
                line: i + 1,
                problem,
            };
            let line: LogLine = serde_json::from_str(l).map_err(|e| at(e.into()))?;
            if let LogLine::Fit(f) = &line {
                f.check().map_err(at)?;
            }
            Ok(line)
        })
        .collect()
}

#[cfg(test)]
#[allow(clippy::indexing_slicing)]
mod tests {
    use super::*;
    use rotacal_shared::packet::{AverageBatch, Temperature};

    /// Ten hours of device time at 16 Hz in batches of 7, a temperature a second, with a
    /// gap every 10 minutes filled by a replay a batch later: what the recorder holds
    /// besides the rows it wrote stays a few entries, as after the first minute.
    #[test]
    fn what_the_recorder_holds_does_not_grow_with_the_session() {
        let meta = crate::recording::Metadata::default();
        let mut r = Recorder::new(io::sink(), io::sink(), &meta, 1_000_000).unwrap();
        let batch = |first: u32, replay: bool| {
            let mut b = AverageBatch::new(Condition::X, replay, first, u64::from(first) * 62_500);
            for k in 0..7u32 {
                let t = u64::from(first + k) * 62_500;
                b.push(&Aperture::point(Ticks(t)), [1, 2, 3], 0).unwrap();
            }
            Packet::Averages(b)
        };
        let samples = 10 * 3600 * 16;
        let mut most_after_a_minute = 0;
        let mut most = 0;
        let mut lost_batch = None;
        for first in (0..samples).step_by(7) {
            if first % 16 < 7 {
                r.packet(&Packet::Temperature(Temperature {
                    seq: first,
                    centi_c: 2500,
                }))
                .unwrap();
            }
            if first % 9600 < 7 && first > 0 {
                lost_batch = Some(first);
                continue;
            }
            r.packet(&batch(first, false)).unwrap();
            if let Some(l) = lost_batch.take() {
                r.packet(&batch(l, true)).unwrap();
            }
            most = most.max(r.held_entries());
            if first < 16 * 60 {
                most_after_a_minute = most;
            }
        }
        let s = r.finish().unwrap();
        assert!(s.lost.is_empty());
        assert_eq!(s.rows, u64::from(samples.div_ceil(7) * 7));
        assert!(most_after_a_minute > 0);
        assert_eq!(most, most_after_a_minute, "held entries grew to {most}");
    }
}
