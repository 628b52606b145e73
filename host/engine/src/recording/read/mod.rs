//! Reading a recording: [`read`] and its variants hold the rows in memory, [`scan`] hands
//! them on one at a time, [`Parts`] reads ranges of a file on several threads.
//!
//! Two readers give the same rows: the fast one (`fast`, lines split at their commas) for
//! plain files, and the csv crate's (`csv`) for anything else, which also names any
//! problem; [`read_columns`] gives them from columns held in memory. Both read the preamble and header with `head` and each row's fields with
//! `row` (numbers by `number`); the rows go through [`Router`] to a [`GroupSink`].

mod columns;
mod csv;
mod fast;
mod head;
mod number;
mod parts;
mod row;

pub use columns::{read_columns, Column, Values};
pub use parts::{PartRow, Parts, Stretch};

use std::fs::File;
use std::io::{BufReader, Read};
use std::path::Path;

use rotacal_shared::{Aperture, Condition};

use super::{Columns, Group, Metadata, Method, Recording, RecordingError, RecordingErrorKind, Row};
use head::{ColumnIndex, Parser};

/// Read the recording at `path`.
pub fn read(path: &Path) -> Result<Recording, RecordingError> {
    read_path(path, true)
}

/// Read the recording at `path` as `method` (a command line's `--method`, which overrides
/// the file's): with [`Method::Free`], a file without a `condition` column is read as a
/// free recording.
pub fn read_as(path: &Path, method: Option<Method>) -> Result<Recording, RecordingError> {
    read_file(path, true, method)
}

fn read_path(path: &Path, complete: bool) -> Result<Recording, RecordingError> {
    read_file(path, complete, None)
}

/// A file by the fast reader, or (a quote, a free or pose file, any problem) the csv one.
fn read_file(
    path: &Path,
    complete: bool,
    method: Option<Method>,
) -> Result<Recording, RecordingError> {
    let source = path.display().to_string();
    read_fast_or_csv(|| open(path), &source, complete, method)
}

/// What `open` gives, by the fast reader or, failing that (a quote, a free or pose file,
/// any problem), read again by the csv one.
fn read_fast_or_csv<R: Read>(
    open: impl Fn() -> Result<R, RecordingError>,
    source: &str,
    complete: bool,
    method: Option<Method>,
) -> Result<Recording, RecordingError> {
    let parser = || Parser {
        source,
        complete,
        line_offset: 0,
        method,
    };
    let mut groups: Vec<Group> = Vec::new();
    if let Some(Some(mut rec)) = parser().run_fast(open()?, &mut groups, false, Parse::All)? {
        shrink(&mut groups);
        rec.groups = groups;
        return Ok(rec);
    }
    parser().run(open()?)
}

/// Read a recording held in memory as [`read`] reads a file: by the fast reader, or (a
/// quote, a free or pose file, any problem) the csv one. `source` names it in messages.
pub fn read_bytes(bytes: &[u8], source: &str) -> Result<Recording, RecordingError> {
    read_fast_or_csv(|| Ok(bytes), source, true, None)
}

/// Read a recording from `reader`; `source` names it in messages.
pub fn read_from<R: Read>(reader: R, source: &str) -> Result<Recording, RecordingError> {
    Parser {
        source,
        complete: true,
        line_offset: 0,
        method: None,
    }
    .run(reader)
}

/// Read a recording in progress (`rotacal record` adds one condition at a time): every
/// check of [`read`] except that all three conditions be present.
pub fn read_in_progress(path: &Path) -> Result<Recording, RecordingError> {
    read_path(path, false)
}

/// Parse only the `#` lines at the start of `text` (the preamble) into metadata, with the
/// reader's checks; used to carry a recording's metadata in other files (the capture).
/// `lines_before` counts the lines of the enclosing file before `text`, for messages.
pub fn read_preamble(
    text: &str,
    source: &str,
    lines_before: u64,
) -> Result<Metadata, RecordingError> {
    let mut p = Parser {
        source,
        complete: false,
        line_offset: lines_before,
        method: None,
    };
    p.preamble(&mut BufReader::new(text.as_bytes()))
}

/// Where the reader puts the rows of a file with conditions: kept as [`Group`]s in
/// memory ([`read`]), or handed on one at a time ([`scan`]).
trait GroupSink {
    /// The file's metadata, method and columns, once its header is read (before any row).
    fn start(&mut self, _meta: &Metadata, _method: Method, _cols: &ColumnIndex) {}
    /// A new group, at file line `line`.
    fn open(&mut self, condition: Condition, rate_hz: Option<f64>, cols: &ColumnIndex, line: u64);
    /// A row of group `group` (in order of first appearance), at file line `line`.
    fn push(&mut self, group: usize, row: &Row<'_>, line: u64);
}

/// A group with no rows yet, with the optional columns the file has.
fn empty_group(condition: Condition, rate_hz: Option<f64>, cols: &ColumnIndex, line: u64) -> Group {
    Group {
        condition,
        rate_hz,
        t_s: Vec::new(),
        angle_deg: Vec::new(),
        u: Vec::new(),
        v: Vec::new(),
        w: Vec::new(),
        seq: cols.seq.map(|_| Vec::new()),
        temp_c: cols.temp_c.map(|_| Vec::new()),
        unc: cols.unc.map(|_| Vec::new()),
        conversions: cols.conv_gaps.map(|_| Vec::new()),
        missed: cols.conv_missed.map(|_| Vec::new()),
        boot: cols.boot.map(|_| Vec::new()),
        first_line: line,
    }
}

/// Give back what the groups' columns grew beyond their rows.
fn shrink(groups: &mut [Group]) {
    for g in groups {
        g.t_s.shrink_to_fit();
        g.angle_deg.shrink_to_fit();
        g.u.shrink_to_fit();
        g.v.shrink_to_fit();
        g.w.shrink_to_fit();
    }
}

impl GroupSink for Vec<Group> {
    fn start(&mut self, _meta: &Metadata, _method: Method, _cols: &ColumnIndex) {
        self.clear(); // a second reading starts afresh
    }

    fn open(&mut self, condition: Condition, rate_hz: Option<f64>, cols: &ColumnIndex, line: u64) {
        self.push(empty_group(condition, rate_hz, cols, line));
    }

    fn push(&mut self, group: usize, row: &Row<'_>, _line: u64) {
        let Some(g) = self.get_mut(group) else {
            return; // cannot happen: the reader opens a group before its rows
        };
        if let Some(t) = row.t_s {
            g.t_s.push(t);
        }
        if let Some(a) = row.angle_deg {
            g.angle_deg.push(a);
        }
        g.u.push(row.u);
        g.v.push(row.v);
        g.w.push(row.w);
        if let (Some(s), Some(v)) = (row.seq, g.seq.as_mut()) {
            v.push(s);
        }
        if let (Some(t), Some(v)) = (row.temp_c, g.temp_c.as_mut()) {
            v.push(t);
        }
        if let (Some(u), Some(v)) = (row.unc, g.unc.as_mut()) {
            v.push(u);
        }
        if let (Some(a), Some(v)) = (row.conv_gaps, g.conversions.as_mut()) {
            v.push(a);
        }
        if let Some(v) = g.missed.as_mut() {
            v.push(row.conv_missed);
        }
        if let (Some(s), Some(v)) = (row.boot, g.boot.as_mut()) {
            v.push(s);
        }
    }
}

/// What [`scan`] hands on, in file order.
#[derive(Clone, Debug, PartialEq)]
pub enum Scanned {
    /// The preamble's metadata and the method, before any group.
    Start {
        /// The metadata.
        meta: Box<Metadata>,
        /// The method (the file's, or the one it is read as).
        method: Method,
        /// The known columns the file has (`rate_hz` only in a rotation file, where it
        /// is read).
        columns: Columns,
    },
    /// A new group: its condition, its `rate_hz` column (if the file has one) and the
    /// file line of its first row.
    Group {
        /// The platter axis.
        condition: Condition,
        /// The rows' `rate_hz`, if the file has that column.
        rate_hz: Option<f64>,
        /// 1-based file line of its first row.
        first_line: u64,
    },
    /// A row of group `group` (groups numbered in order of first appearance).
    Row {
        /// The row's group.
        group: usize,
        /// Device time, s (`None` in a file without `t_s`).
        t_s: Option<f64>,
        /// u, v, w.
        y: [f64; 3],
        /// The conversions it averages, in the file's device ticks (`conv_gaps`).
        conv_gaps: Option<Aperture>,
        /// Its `angle_deg`, `seq` and `temp_c`, when the file has them (and they were
        /// read: [`Parse::All`]).
        angle_deg: Option<f64>,
        /// `seq`.
        seq: Option<u64>,
        /// `temp_c`.
        temp_c: Option<f64>,
    },
}

/// Which columns a reading parses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Parse {
    /// Every column, with every check.
    All,
    /// Only those a fit uses (a second reading of a checked file).
    Fit,
}

struct ScanSink<F>(F);

impl<F: FnMut(Scanned)> GroupSink for ScanSink<F> {
    fn start(&mut self, meta: &Metadata, method: Method, cols: &ColumnIndex) {
        (self.0)(Scanned::Start {
            meta: Box::new(meta.clone()),
            method,
            columns: Columns {
                t_s: cols.t_s.is_some(),
                angle_deg: cols.angle_deg.is_some(),
                seq: cols.seq.is_some(),
                temp_c: cols.temp_c.is_some(),
                rate_hz: cols.rate_hz.is_some() && method == Method::Rotation,
                gravity: cols.gravity.is_some(),
                pose: cols.pose.is_some(),
                unc: cols.unc.is_some(),
                conv_gaps: cols.conv_gaps.is_some(),
                conv_missed: cols.conv_missed.is_some(),
                boot: cols.boot.is_some(),
            },
        });
    }

    fn open(&mut self, condition: Condition, rate_hz: Option<f64>, _: &ColumnIndex, line: u64) {
        (self.0)(Scanned::Group {
            condition,
            rate_hz,
            first_line: line,
        });
    }

    fn push(&mut self, group: usize, row: &Row<'_>, _line: u64) {
        (self.0)(Scanned::Row {
            group,
            t_s: row.t_s,
            y: [row.u, row.v, row.w],
            conv_gaps: row.conv_gaps,
            angle_deg: row.angle_deg,
            seq: row.seq,
            temp_c: row.temp_c,
        });
    }
}

/// Read a file with conditions one row at a time, with every check of [`read_as`], handing
/// its groups and rows to `each` in file order: for a recording too long to hold in
/// memory. Returns the recording without its rows (its metadata and method), or `None`
/// for a file without conditions (poses or a free series), which is read no further than
/// its header. `each` may already have seen rows when an error is returned. With
/// [`Parse::Fit`] (a second reading of a checked file) only the columns a fit uses are
/// parsed.
pub fn scan(
    path: &Path,
    method: Option<Method>,
    parse: Parse,
    each: impl FnMut(Scanned),
) -> Result<Option<Recording>, RecordingError> {
    let mut sink = ScanSink(each);
    let source = path.display().to_string();
    let parser = || Parser {
        source: &source,
        complete: true,
        line_offset: 0,
        method,
    };
    if let Some(done) = parser().run_fast(open(path)?, &mut sink, true, parse)? {
        return Ok(done);
    }
    // Read again by the csv reader (it starts with Scanned::Start again).
    parser().run_into(open(path)?, &mut sink, true)
}

fn open(path: &Path) -> Result<File, RecordingError> {
    File::open(path).map_err(|e| RecordingError {
        source_name: path.display().to_string(),
        line: None,
        row: None,
        kind: RecordingErrorKind::Io(e),
    })
}

/// Puts the rows of a file with conditions into their groups, with the checks that span
/// rows: a group per (condition, nominal rate) in order of first appearance; rotation
/// rows do not go back in time within a group; every rate has all three conditions.
struct Router {
    rotation: bool,
    /// Each group's (condition, rate bits), and the boot and time of its last row.
    keys: Vec<(Condition, Option<u64>)>,
    last_t: Vec<(Option<u32>, Option<f64>)>,
    /// (condition, rate bits) of the group the previous row went to, and its index.
    last: Option<(Condition, Option<u64>, usize)>,
}

impl Router {
    fn new(method: Method) -> Self {
        Router {
            rotation: method == Method::Rotation,
            keys: Vec::new(),
            last_t: Vec::new(),
            last: None,
        }
    }

    /// Hand `row`, at file line `line`, to its group in `sink` (opening it if new).
    fn route<S: GroupSink>(
        &mut self,
        row: &Row<'_>,
        line: u64,
        cols: &ColumnIndex,
        sink: &mut S,
    ) -> Result<(), RecordingErrorKind> {
        let rate = if self.rotation { row.rate_hz } else { None };
        let key = rate.map(f64::to_bits);
        let gi = match self.last {
            Some((c, k, i)) if c == row.condition && k == key => i,
            _ => {
                let found = self.keys.iter().position(|g| *g == (row.condition, key));
                let i = match found {
                    Some(i) => i,
                    None => {
                        sink.open(row.condition, rate, cols, line);
                        self.keys.push((row.condition, key));
                        self.last_t.push((None, None));
                        self.keys.len() - 1
                    }
                };
                self.last = Some((row.condition, key, i));
                i
            }
        };
        if let Some((boot, prev)) = self.last_t.get_mut(gi) {
            // A new boot restarts the time (the device's clock started afresh).
            if let (Some(s), Some(before)) = (row.boot, *boot) {
                if s < before {
                    return Err(RecordingErrorKind::BootWentBackwards {
                        condition: row.condition,
                        previous: before,
                        got: s,
                    });
                }
                if s > before {
                    *prev = None;
                }
            }
            *boot = row.boot.or(*boot);
        }
        if let (Some(t), Some((_, prev))) = (row.t_s, self.last_t.get_mut(gi)) {
            if self.rotation {
                if let Some(p) = *prev {
                    if t < p {
                        return Err(RecordingErrorKind::TimeWentBackwards {
                            condition: row.condition,
                            rate_hz: rate,
                            previous: p,
                            got: t,
                        });
                    }
                }
            }
            *prev = Some(t);
        }
        sink.push(gi, row, line);
        Ok(())
    }

    /// The checks at the end: some data, and (if `complete`) all three conditions at
    /// every rate.
    fn finish(&self, complete: bool) -> Result<(), RecordingErrorKind> {
        if self.keys.is_empty() {
            return Err(RecordingErrorKind::NoData);
        }
        let mut rates: Vec<Option<u64>> = Vec::new();
        for (_, k) in &self.keys {
            if !rates.contains(k) {
                rates.push(*k);
            }
        }
        for k in rates.into_iter().filter(|_| complete) {
            for c in Condition::ALL {
                if !self.keys.contains(&(c, k)) {
                    return Err(RecordingErrorKind::MissingCondition {
                        condition: c,
                        rate_hz: k.map(f64::from_bits),
                    });
                }
            }
        }
        Ok(())
    }
}
