//! The raw capture: every value received from the device and every command written to it,
//! in arrival order, with milliseconds since the recording (or the appended condition)
//! started. The recorder appends to it before
//! it decodes anything, and syncs it with the recording, so what was received is on disk
//! even when the recording itself still holds rows back (waiting for a gap to be filled)
//! or the host crashes. `rotacal decode` rebuilds the recording and the fit log from it.
//!
//! ```text
//! # rotacal capture v1
//! # rate_hz=0.01            (the recording's metadata, as in its preamble)
//! 12 i 0105…                (ms, what, hex: i info, s stream, r results, w written)
//! 15 +                      (link up; - link down)
//! ```
//!
//! A last line without its newline (the host was killed while writing it) is ignored.

use crate::link::Channel;
use crate::recording::from_device::{RecordSummary, Recorder, COLUMNS};
use crate::recording::{self, Metadata, Writer};
use rotacal_shared::packet::Packet;
use std::fmt::Write as _;
use std::io::{self, BufWriter, Write};
use tokio::time::Instant;

/// First line of a capture.
pub const MAGIC: &str = "# rotacal capture v1";

/// One line of a capture.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Entry {
    /// A value from the device.
    Value(Channel, Vec<u8>),
    /// A command written to the device.
    Written(Vec<u8>),
    /// The link came up.
    Up,
    /// The link went down.
    Down,
}

/// Appends entries.
pub struct CaptureWriter<W: Write> {
    out: BufWriter<W>,
    start: Instant,
    line: String,
}

impl<W: Write> CaptureWriter<W> {
    /// Start a capture whose recording has `meta`.
    pub fn new(w: W, meta: &Metadata) -> io::Result<Self> {
        let mut pre = Vec::new();
        Writer::new(&mut pre, meta, &COLUMNS)?.flush()?;
        let pre = String::from_utf8_lossy(&pre).into_owned();
        let mut out = BufWriter::with_capacity(1 << 16, w);
        writeln!(out, "{MAGIC}")?;
        // The recording's metadata lines (not its magic line or header).
        for l in pre.lines().skip(1).filter(|l| l.starts_with('#')) {
            writeln!(out, "{l}")?;
        }
        Ok(CaptureWriter {
            out,
            start: Instant::now(),
            line: String::with_capacity(512),
        })
    }

    /// Continue a capture (no header).
    pub fn append(w: W) -> Self {
        CaptureWriter {
            out: BufWriter::with_capacity(1 << 16, w),
            start: Instant::now(),
            line: String::with_capacity(512),
        }
    }

    /// Append one entry.
    pub fn entry(&mut self, e: &Entry) -> io::Result<()> {
        let ms = self.start.elapsed().as_millis();
        let l = &mut self.line;
        l.clear();
        let (what, bytes): (char, &[u8]) = match e {
            Entry::Value(ch, b) => (ch.letter(), b),
            Entry::Written(b) => ('w', b),
            Entry::Up => ('+', &[]),
            Entry::Down => ('-', &[]),
        };
        let _ = write!(l, "{ms} {what}");
        if !bytes.is_empty() {
            l.push(' ');
            for b in bytes {
                let _ = write!(l, "{b:02x}");
            }
        }
        l.push('\n');
        self.out.write_all(l.as_bytes())
    }

    /// Flush to the underlying writer.
    pub fn flush(&mut self) -> io::Result<()> {
        self.out.flush()
    }

    /// The underlying writer.
    pub fn get_ref(&self) -> &W {
        self.out.get_ref()
    }
}

/// A capture read back.
#[derive(Clone, Debug, PartialEq)]
pub struct Capture {
    /// The recording's metadata.
    pub meta: Metadata,
    /// (line, ms, entry) in file order.
    pub entries: Vec<(u64, u64, Entry)>,
    /// The last line had no newline and was ignored.
    pub truncated: bool,
}

/// Read a capture; errors name `source`, the line and the problem.
pub fn read(text: &str, source: &str) -> Result<Capture, String> {
    let truncated = !text.is_empty() && !text.ends_with('\n');
    let complete = match text.rfind('\n') {
        Some(i) => text.get(..=i).unwrap_or(""),
        None => "",
    };
    let mut lines = complete.lines().enumerate();
    match lines.next() {
        Some((_, l)) if l.trim_end() == MAGIC => {}
        _ => {
            return Err(format!(
                "{source}:1: not a rotacal capture (no '{MAGIC}' line)"
            ))
        }
    }
    let pre: String = complete
        .lines()
        .skip(1)
        .take_while(|l| l.starts_with('#'))
        .map(|l| format!("{l}\n"))
        .collect();
    // The preamble starts on line 2, after the magic line.
    let meta = recording::read_preamble(&pre, source, 1).map_err(|e| e.to_string())?;
    let mut entries = Vec::new();
    for (i, l) in lines {
        if l.starts_with('#') || l.trim().is_empty() {
            continue;
        }
        let at = |what: &str| format!("{source}:{}: {what}: '{l}'", i + 1);
        let mut f = l.split(' ');
        let ms = f
            .next()
            .and_then(|x| x.parse::<u64>().ok())
            .ok_or_else(|| at("no time (ms) at the start"))?;
        let what = f.next().ok_or_else(|| at("no entry kind"))?;
        let data = f.next();
        if f.next().is_some() {
            return Err(at("more than three fields"));
        }
        let bytes = || {
            data.and_then(crate::recording::from_device::from_hex)
                .filter(|b| !b.is_empty())
                .ok_or_else(|| at("bad or missing hex bytes"))
        };
        let e = match what {
            "+" | "-" if data.is_some() => return Err(at("link entries take no bytes")),
            "+" => Entry::Up,
            "-" => Entry::Down,
            "w" => Entry::Written(bytes()?),
            w => match w.chars().next().and_then(Channel::from_letter) {
                Some(ch) if w.len() == 1 => Entry::Value(ch, bytes()?),
                _ => return Err(at("unknown entry kind (s, r, i, w, + or -)")),
            },
        };
        entries.push((i as u64 + 1, ms, e));
    }
    Ok(Capture {
        meta,
        entries,
        truncated,
    })
}

/// What rebuilding found besides the recording.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Rebuilt {
    /// The recorder's summary.
    pub summary: RecordSummary,
    /// Values that did not decode: (line, why).
    pub undecodable: Vec<(u64, String)>,
}

/// Rebuild the recording and fit log from a capture.
pub fn rebuild<W: Write, F: Write>(cap: &Capture, rows: W, fits: F) -> Result<Rebuilt, String> {
    let tick_hz = cap
        .entries
        .iter()
        .find_map(|(_, _, e)| match e {
            Entry::Value(Channel::Info, b) => match Packet::decode(b) {
                Ok(Packet::Info(i)) => Some(i.tick_hz),
                _ => None,
            },
            _ => None,
        })
        .ok_or(
            "the capture holds no device-info value that decodes (it gives the device's tick \
             rate)",
        )?;
    let mut rec =
        Recorder::new(rows, fits, &cap.meta, tick_hz).map_err(|e| format!("writing: {e}"))?;
    let mut undecodable = Vec::new();
    for (line, _, e) in &cap.entries {
        match e {
            Entry::Value(Channel::Stream | Channel::Results, b) => match Packet::decode(b) {
                Ok(p) => rec.packet(&p).map_err(|e| format!("writing: {e}"))?,
                Err(e) => undecodable.push((*line, e.to_string())),
            },
            // Each condition recorded (appended) starts with a Start.
            Entry::Written(b) => {
                if let Ok(Packet::Command(rotacal_shared::packet::Command::Start {
                    condition,
                    ..
                })) = Packet::decode(b)
                {
                    rec.restart_sequence()
                        .map_err(|e| format!("writing: {e}"))?;
                    rec.start_written(condition);
                }
            }
            _ => {}
        }
    }
    let summary = rec.finish().map_err(|e| format!("writing: {e}"))?;
    Ok(Rebuilt {
        summary,
        undecodable,
    })
}
