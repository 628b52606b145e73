//! From the device's decoded packets to a recording (formats.md CSV) and its fit log (one
//! JSON object per line: the device's fit reports and quick-look). Used by the demo,
//! which feeds it the packets of the device logic run on the host; the BLE recorder will
//! feed it the same packets from the air.
//!
//! Temperatures arrive about once a second, tagged with the seq of the sample they were
//! read with. Each row gets the latest temperature at or before its seq; rows before the
//! first temperature wait (about a second) and get the first one.

use crate::recording::{Columns, Metadata, Row, Writer};
use rotacal_shared::packet::{FitReport, Packet, QuickLook};
use serde::{Deserialize, Serialize};
use std::io::{self, Write};

/// One line of the fit log: a device fit report. It mirrors `packet::FitReport` field by
/// field (rotacal-shared is no_std, without serde), with the standard errors widened to
/// f64 and the device's tick rate added, so that the line stands alone.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FitLine {
    /// x, y or z.
    pub condition: char,
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
}

impl FitLine {
    /// From a report, with the device's tick rate.
    pub fn new(f: &FitReport, tick_hz: u32) -> Self {
        FitLine {
            condition: f.condition.letter(),
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
    /// Missing seq ranges [first, last] (lost on the link and not recovered).
    pub gaps: Vec<(u32, u32)>,
}

/// See the module documentation.
pub struct Recorder<W: Write, F: Write> {
    rows: Writer<W>,
    fits: F,
    tick_hz: u32,
    /// Rows waiting for the first temperature.
    pending: Vec<Row>,
    /// Latest temperature, °C.
    temp: Option<f64>,
    next_seq: Option<u32>,
    summary: RecordSummary,
}

/// The recording's columns.
pub const COLUMNS: Columns = Columns {
    t_s: true,
    angle_deg: false,
    seq: true,
    temp_c: true,
    rate_hz: false,
};

impl<W: Write, F: Write> Recorder<W, F> {
    /// Start a recording with `meta`, timestamps in ticks of `tick_hz`.
    pub fn new(rows: W, fits: F, meta: &Metadata, tick_hz: u32) -> io::Result<Self> {
        if tick_hz == 0 {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "device tick rate 0",
            ));
        }
        Ok(Recorder {
            rows: Writer::new(rows, meta, &COLUMNS)?,
            fits,
            tick_hz,
            pending: Vec::new(),
            temp: None,
            next_seq: None,
            summary: RecordSummary::default(),
        })
    }

    fn write_row(&mut self, mut row: Row) -> io::Result<()> {
        match self.temp {
            Some(t) => {
                row.temp_c = Some(t);
                self.rows.write_row(&row)?;
                self.summary.rows += 1;
            }
            None => self.pending.push(row),
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
            Packet::Samples(b) if !b.replay => {
                for (seq, t, s) in b.iter() {
                    if let Some(next) = self.next_seq {
                        if seq != next {
                            self.summary.gaps.push((next, seq.wrapping_sub(1)));
                        }
                    }
                    self.next_seq = Some(seq.wrapping_add(1));
                    let [u, v, w] = s.counts.map(f64::from);
                    let mut row = Row::new(b.condition, u, v, w);
                    row.seq = Some(u64::from(seq));
                    row.t_s = Some(t as f64 / f64::from(self.tick_hz));
                    self.write_row(row)?;
                }
            }
            Packet::Temperature(t) => {
                let c = f64::from(t.centi_c) / 100.0;
                self.temp = Some(c);
                for mut row in std::mem::take(&mut self.pending) {
                    row.temp_c = Some(c);
                    self.rows.write_row(&row)?;
                    self.summary.rows += 1;
                }
            }
            Packet::Fit(f) => self.log(&LogLine::Fit(FitLine::new(f, self.tick_hz)))?,
            Packet::QuickLook(q) => self.log(&LogLine::quick_look(q))?,
            // Replays fill gaps after a reconnect; the BLE recorder merges them.
            Packet::Samples(_) | Packet::Info(_) | Packet::Status(_) | Packet::Command(_) => {}
        }
        Ok(())
    }

    /// Flush everything and say what was recorded. Rows still waiting for their first
    /// temperature are an error: the device sent none, and none is invented.
    pub fn finish(mut self) -> io::Result<RecordSummary> {
        if !self.pending.is_empty() {
            return Err(io::Error::new(
                io::ErrorKind::InvalidData,
                format!(
                    "{} samples arrived but no temperature: the device sent none",
                    self.pending.len()
                ),
            ));
        }
        self.rows.flush()?;
        self.fits.flush()?;
        Ok(self.summary)
    }
}

/// Read a fit log: one JSON object per line; errors name the line.
pub fn read_fit_log(text: &str, source: &str) -> Result<Vec<LogLine>, String> {
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| serde_json::from_str(l).map_err(|e| format!("{source}:{}: {e}", i + 1)))
        .collect()
}
