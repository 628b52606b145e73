//! A file with conditions read in byte ranges, one thread each.

use std::io::{self, Read};
use std::path::Path;

use rotacal_shared::{Aperture, Condition};

use super::columns::{Column, PlainColumns};
use super::fast::fast_rows;
use super::head::{ColumnIndex, Parser};
use super::{open, Parse};
use crate::recording::{Metadata, Method, RecordingError, RecordingErrorKind, Row};

/// A recording with conditions read in parts, each on a thread of its own (the streaming
/// calibration, on every core): a file in ranges of whole lines, or columns held in memory
/// (the Python package's DataFrames) in ranges of rows. Only files the fast reader takes
/// (no quotes) are read this way; the rows of a part come without the checks that span
/// rows (the caller makes them across parts, or reads the file with [`scan`] to have the
/// reader name a problem). Columns are checked whole when they are opened.
pub struct Parts<'a> {
    meta: Metadata,
    method: Method,
    cols: ColumnIndex,
    src: Source<'a>,
}

/// Where a [`Parts`]' rows are.
enum Source<'a> {
    File {
        path: std::path::PathBuf,
        /// Byte offset and line number of the line after the header; the file's length.
        offset: u64,
        line: u64,
        len: u64,
    },
    Columns {
        columns: &'a [Column<'a>],
        rows: usize,
    },
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

/// Rows of one group in a row, as the columns hold them: a stretch of a part of columns
/// whose rows share their condition and `rate_hz` and are each plainly fine (what
/// [`PartRow`] would say of each).
#[derive(Clone, Copy, Debug)]
pub struct Stretch<'a> {
    pub condition: Condition,
    pub rate_hz: Option<f64>,
    pub t_s: Option<&'a [f64]>,
    /// u, v, w.
    pub y: [&'a [f64]; 3],
}

impl PartRow {
    /// What a part needs of a row the field reader read.
    pub(super) fn of(r: &Row<'_>) -> PartRow {
        PartRow {
            condition: r.condition,
            rate_hz: r.rate_hz,
            t_s: r.t_s,
            y: [r.u, r.v, r.w],
            conv_gaps: r.conv_gaps,
        }
    }
}

impl Stretch<'_> {
    /// Its rows.
    pub fn len(&self) -> usize {
        let [u, ..] = self.y;
        u.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Its rows one at a time, as [`Parts::rows`] gives them.
    pub fn rows(&self) -> impl Iterator<Item = PartRow> + '_ {
        let [u, v, w] = self.y;
        let t = self.t_s;
        u.iter()
            .zip(v)
            .zip(w)
            .enumerate()
            .map(move |(i, ((u, v), w))| PartRow {
                condition: self.condition,
                rate_hz: self.rate_hz,
                t_s: t.and_then(|t| t.get(i).copied()),
                y: [*u, *v, *w],
                conv_gaps: None,
            })
    }
}

impl Parts<'static> {
    /// The file at `path` for reading in parts: its preamble and header read and checked
    /// (an error as [`read_as`] gives it), or `None` when it is not a file with
    /// conditions or its header needs the csv reader.
    pub fn open(path: &Path, method: Option<Method>) -> Result<Option<Self>, RecordingError> {
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
            meta: head.meta,
            method: head.method,
            cols: head.cols,
            src: Source::File {
                path: path.to_path_buf(),
                offset: head.offset,
                line: head.line,
                len,
            },
        }))
    }
}

impl<'a> Parts<'a> {
    /// Columns held in memory for reading in parts, their metadata and header checked as
    /// [`super::read_columns`] checks them (an error as it gives it), or `None` when they
    /// are not a recording with conditions (poses, a free series). Their rows are checked
    /// as the parts are read, as a file's are (a part that meets a problem stops, and
    /// [`super::read_columns`] names it). A part's lines are its rows, counted from 0.
    pub fn of_columns(
        columns: &'a [Column<'a>],
        meta: &[(&str, &str)],
        source: &str,
        method: Option<Method>,
    ) -> Result<Option<Self>, RecordingError> {
        let Some((meta, method, cols, rows)) =
            super::columns::columns_head(columns, meta, source, method)?
        else {
            return Ok(None);
        };
        Ok(Some(Parts {
            meta,
            method,
            cols,
            src: Source::Columns { columns, rows },
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

    /// The header's line number: the first part's lines follow it (0 for columns, whose
    /// parts count rows from 0).
    pub fn header_line(&self) -> u64 {
        match &self.src {
            Source::File { line, .. } => *line,
            Source::Columns { .. } => 0,
        }
    }

    /// Whether the rows are columns held in memory (no file to read again).
    pub fn in_memory(&self) -> bool {
        matches!(self.src, Source::Columns { .. })
    }

    /// The data cut into `n` ranges of about equal size: of bytes, each from a line's
    /// start, for a file; of rows for columns.
    pub fn split(&self, n: usize) -> Result<Vec<(u64, u64)>, RecordingError> {
        let (path, offset, len) = match &self.src {
            Source::File {
                path, offset, len, ..
            } => (path, *offset, *len),
            Source::Columns { rows, .. } => {
                let (rows, n) = (*rows as u64, n.max(1) as u64);
                return Ok((0..n).map(|i| (rows * i / n, rows * (i + 1) / n)).collect());
            }
        };
        let io = |e: io::Error| RecordingError {
            source_name: path.display().to_string(),
            line: None,
            row: None,
            kind: RecordingErrorKind::Io(e),
        };
        let mut cuts = vec![offset];
        let mut f = open(path)?;
        let span = len.saturating_sub(offset);
        for i in 1..n.max(1) {
            let at = offset + span * i as u64 / n as u64;
            std::io::Seek::seek(&mut f, io::SeekFrom::Start(at)).map_err(io)?;
            let mut buf = vec![0u8; 1 << 16];
            let mut cut = len;
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
            let last = cuts.last().copied().unwrap_or(offset);
            cuts.push(cut.max(last));
        }
        cuts.push(len);
        Ok(cuts
            .windows(2)
            .filter_map(|w| Some((*w.first()?, *w.get(1)?)))
            .collect())
    }

    /// [`Parts::rows`], but columns' rows in stretches of one group each where they are
    /// plainly fine (`each_stretch`, with the line of its first row): the same rows, without
    /// a call per row. A file's rows, and rows of columns that are not plainly fine, go to
    /// `each` one at a time.
    pub fn stretches(
        &self,
        range: (u64, u64),
        parse: Parse,
        mut each: impl FnMut(u64, PartRow) -> bool,
        mut each_stretch: impl FnMut(u64, Stretch<'_>) -> bool,
    ) -> Result<Option<u64>, RecordingError> {
        let Source::Columns { columns, .. } = &self.src else {
            return self.rows(range, parse, each);
        };
        let Some(plain) = PlainColumns::of(columns, &self.cols, parse) else {
            return self.rows(range, parse, each);
        };
        let (Ok(start), Ok(end)) = (usize::try_from(range.0), usize::try_from(range.1)) else {
            return self.rows(range, parse, each);
        };
        let mut at = start;
        while at < end {
            let (stop, stretch) = plain.stretch(at, end);
            let line = (at - start) as u64;
            if let Some(st) = stretch {
                if !each_stretch(line, st) {
                    return Ok(None);
                }
            } else if self
                .rows((at as u64, stop as u64), parse, |l, row| {
                    each(line + l, row)
                })?
                .is_none()
            {
                return Ok(None);
            }
            at = stop;
        }
        Ok(Some(range.1 - range.0))
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
        let path = match &self.src {
            Source::File { path, .. } => path,
            Source::Columns { columns, .. } => {
                // A row that fails stops the part (`None`): the caller reads the columns
                // whole, and that reader names the problem.
                let plain = PlainColumns::of(columns, &self.cols, parse);
                let by_field = |row: usize| {
                    let fields = super::columns::RowOf { columns, row };
                    super::row::parse_row(&fields, &self.cols, parse)
                        .ok()
                        .map(|r| PartRow::of(&r))
                };
                for row in range.0..range.1 {
                    let i = row as usize;
                    let Some(part) = plain
                        .as_ref()
                        .and_then(|p| p.row(i))
                        .or_else(|| by_field(i))
                    else {
                        return Ok(None);
                    };
                    if !each(row - range.0, part) {
                        return Ok(None);
                    }
                }
                return Ok(Some(range.1 - range.0));
            }
        };
        let io = |e: io::Error| RecordingError {
            source_name: path.display().to_string(),
            line: None,
            row: None,
            kind: RecordingErrorKind::Io(e),
        };
        let mut f = open(path)?;
        std::io::Seek::seek(&mut f, io::SeekFrom::Start(range.0)).map_err(io)?;
        let mut part = f.take(range.1.saturating_sub(range.0));
        fast_rows(&mut part, &self.cols, parse, 0, |line, row| {
            each(line, PartRow::of(row))
        })
        .map_err(io)
    }
}
