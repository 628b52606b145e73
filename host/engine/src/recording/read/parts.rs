//! A file with conditions read in byte ranges, one thread each.

use std::io::{self, Read};
use std::path::Path;

use rotacal_shared::{Aperture, Condition};

use super::fast::fast_rows;
use super::head::{ColumnIndex, Parser};
use super::{open, Parse};
use crate::recording::{Metadata, Method, RecordingError, RecordingErrorKind};

/// A file with conditions read in parts, each a range of whole lines that a thread of
/// its own can read (the streaming calibration, on every core). Only files the fast
/// reader takes (no quotes) are read this way; the rows of a part come without the
/// checks that span rows (the caller makes them across parts, or reads the file with
/// [`scan`] to have the reader name a problem).
pub struct Parts {
    path: std::path::PathBuf,
    meta: Metadata,
    method: Method,
    cols: ColumnIndex,
    /// Byte offset and line number of the line after the header; the file's length.
    offset: u64,
    line: u64,
    len: u64,
}

/// A row of a part.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PartRow {
    /// Its condition.
    pub condition: Condition,
    /// Its `rate_hz` column, if the file has one.
    pub rate_hz: Option<f64>,
    /// Its time, s (`None` without a `t_s` column).
    pub t_s: Option<f64>,
    /// u, v, w.
    pub y: [f64; 3],
    /// Its `conv_gaps`, in the file's device ticks.
    pub conv_gaps: Option<Aperture>,
}

impl Parts {
    /// The file at `path` for reading in parts: its preamble and header read and checked
    /// (an error as [`read_as`] gives it), or `None` when it is not a file with
    /// conditions or its header needs the csv reader.
    pub fn open(path: &Path, method: Option<Method>) -> Result<Option<Parts>, RecordingError> {
        let source = path.display().to_string();
        let mut parser = Parser {
            source: &source,
            complete: true,
            line_offset: 0,
            method,
        };
        let file = open(path)?;
        let len = file
            .metadata()
            .map(|m| m.len())
            .map_err(|e| parser.err(None, RecordingErrorKind::Io(e)))?;
        let Some(head) = parser.fast_head(file)? else {
            return Ok(None);
        };
        if head.cols.condition.is_none() || head.cols.gravity.is_some() {
            return Ok(None);
        }
        Ok(Some(Parts {
            path: path.to_path_buf(),
            meta: head.meta,
            method: head.method,
            cols: head.cols,
            offset: head.offset,
            line: head.line,
            len,
        }))
    }

    /// The preamble's metadata.
    pub fn meta(&self) -> &Metadata {
        &self.meta
    }

    /// The method (the file's, or the one it is read as).
    pub fn method(&self) -> Method {
        self.method
    }

    /// Whether the file has a `boot` column (its conditions may be in several runs of
    /// the device's clock, which a fit joins with their rows in hand).
    pub fn segmented(&self) -> bool {
        self.cols.boot.is_some()
    }

    /// The header's line number: the first part's lines follow it.
    pub fn header_line(&self) -> u64 {
        self.line
    }

    /// The data cut into `n` byte ranges of about equal size, each from a line's start.
    pub fn split(&self, n: usize) -> Result<Vec<(u64, u64)>, RecordingError> {
        let io = |e: io::Error| RecordingError {
            source_name: self.path.display().to_string(),
            line: None,
            row: None,
            kind: RecordingErrorKind::Io(e),
        };
        let mut cuts = vec![self.offset];
        let mut f = open(&self.path)?;
        let span = self.len.saturating_sub(self.offset);
        for i in 1..n.max(1) {
            let at = self.offset + span * i as u64 / n as u64;
            std::io::Seek::seek(&mut f, io::SeekFrom::Start(at)).map_err(io)?;
            let mut buf = vec![0u8; 1 << 16];
            let mut cut = self.len;
            let mut read = 0u64;
            loop {
                let k = f.read(&mut buf).map_err(io)?;
                if k == 0 {
                    break;
                }
                if let Some(p) = memchr::memchr(b'\n', buf.get(..k).unwrap_or(&[])) {
                    cut = at + read + p as u64 + 1;
                    break;
                }
                read += k as u64;
            }
            let last = cuts.last().copied().unwrap_or(self.offset);
            cuts.push(cut.max(last));
        }
        cuts.push(self.len);
        Ok(cuts
            .windows(2)
            .filter_map(|w| Some((*w.first()?, *w.get(1)?)))
            .collect())
    }

    /// The rows of byte range `range` (from [`Parts::split`]), each with its line number
    /// counted from the range's first line (1), to `each`, which returns false to stop.
    /// `None` when a line needs the csv reader (a quote, a wrong number of fields, a field
    /// that does not parse) or `each` stopped; else the number of lines in the range.
    pub fn rows(
        &self,
        range: (u64, u64),
        parse: Parse,
        mut each: impl FnMut(u64, PartRow) -> bool,
    ) -> Result<Option<u64>, RecordingError> {
        let io = |e: io::Error| RecordingError {
            source_name: self.path.display().to_string(),
            line: None,
            row: None,
            kind: RecordingErrorKind::Io(e),
        };
        let mut f = open(&self.path)?;
        std::io::Seek::seek(&mut f, io::SeekFrom::Start(range.0)).map_err(io)?;
        let mut part = f.take(range.1.saturating_sub(range.0));
        fast_rows(&mut part, &self.cols, parse, 0, |line, row| {
            each(
                line,
                PartRow {
                    condition: row.condition,
                    rate_hz: row.rate_hz,
                    t_s: row.t_s,
                    y: [row.u, row.v, row.w],
                    conv_gaps: row.conv_gaps,
                },
            )
        })
        .map_err(io)
    }
}
