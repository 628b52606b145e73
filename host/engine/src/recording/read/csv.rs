//! The csv crate's reader: any file formats.md allows, quotes included, with every check;
//! the one that names a problem.

use std::io::{self, BufReader, Read};

use super::head::{ColumnIndex, Parser, Res};
use super::row::parse_row;
use super::{shrink, GroupSink, Parse, Router};
use crate::recording::{
    Group, Metadata, Method, Oriented, Recording, RecordingErrorKind, Row, Series,
};

// ---------------------------------------------------------------------------------------
// Reader internals

/// Appends a `\n` to a stream that doesn't end in one, so that every csv record ends with
/// a consumed `\n` and its line number can be worked out from the reader's position.
struct FinalNewline<R> {
    inner: R,
    last: Option<u8>,
    done: bool,
}

impl<R: Read> Read for FinalNewline<R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        if self.done || buf.is_empty() {
            return Ok(0);
        }
        let n = self.inner.read(buf)?;
        if n > 0 {
            if let Some(&b) = buf.get(..n).and_then(<[u8]>::last) {
                self.last = Some(b);
            }
            return Ok(n);
        }
        self.done = true;
        match (self.last, buf.first_mut()) {
            (Some(b), Some(slot)) if b != b'\n' => {
                *slot = b'\n';
                Ok(1)
            }
            _ => Ok(0),
        }
    }
}

/// The rows of a file without conditions, as read: its poses (a `gx, gy, gz` file) or its
/// continuous series (a free file). A file with conditions has neither.
pub(super) struct Collected {
    oriented: Option<Oriented>,
    series: Option<Series>,
}

impl Collected {
    /// Nothing yet, with the optional columns `cols` has (`free`: a file without
    /// conditions or orientations).
    pub(super) fn new(cols: &ColumnIndex, free: bool) -> Collected {
        Collected {
            series: free.then(|| Series {
                t_s: Vec::new(),
                y: Vec::new(),
                pose: cols.pose.map(|_| Vec::new()),
                seq: cols.seq.map(|_| Vec::new()),
                temp_c: cols.temp_c.map(|_| Vec::new()),
                line: Vec::new(),
            }),
            oriented: cols.gravity.map(|_| Oriented {
                gravity: Vec::new(),
                pose: cols.pose.map(|_| Vec::new()),
                y: Vec::new(),
                t_s: cols.t_s.map(|_| Vec::new()),
                seq: cols.seq.map(|_| Vec::new()),
                temp_c: cols.temp_c.map(|_| Vec::new()),
                unc: cols.unc.map(|_| Vec::new()),
                line: Vec::new(),
            }),
        }
    }

    /// Keeps `row`, of file line `line`, when the file's rows are poses or a series, and
    /// says whether it did; a series' time must not go backwards.
    pub(super) fn take(&mut self, row: &Row<'_>, line: u64) -> Result<bool, RecordingErrorKind> {
        if let (Some(o), Some(g)) = (self.oriented.as_mut(), row.gravity) {
            o.gravity.push(g);
            o.y.push([row.u, row.v, row.w]);
            o.line.push(line);
            if let (Some(v), Some(p)) = (o.pose.as_mut(), row.pose) {
                v.push(p.to_string());
            }
            if let (Some(v), Some(t)) = (o.t_s.as_mut(), row.t_s) {
                v.push(t);
            }
            if let (Some(v), Some(s)) = (o.seq.as_mut(), row.seq) {
                v.push(s);
            }
            if let (Some(v), Some(t)) = (o.temp_c.as_mut(), row.temp_c) {
                v.push(t);
            }
            if let (Some(v), Some(u)) = (o.unc.as_mut(), row.unc) {
                v.push(u);
            }
            return Ok(true);
        }
        if let Some(s) = self.series.as_mut() {
            let t = row.t_s.unwrap_or(f64::NAN);
            if let Some(&prev) = s.t_s.last() {
                if t < prev {
                    return Err(RecordingErrorKind::TimeWentBackwardsFree {
                        previous: prev,
                        got: t,
                    });
                }
            }
            s.t_s.push(t);
            s.y.push([row.u, row.v, row.w]);
            s.line.push(line);
            if let (Some(v), Some(p)) = (s.pose.as_mut(), row.pose) {
                v.push(p.to_string());
            }
            if let (Some(v), Some(x)) = (s.seq.as_mut(), row.seq) {
                v.push(x);
            }
            if let (Some(v), Some(x)) = (s.temp_c.as_mut(), row.temp_c) {
                v.push(x);
            }
            return Ok(true);
        }
        Ok(false)
    }
}

fn is_blank(rec: &csv::ByteRecord) -> bool {
    rec.iter().all(|f| f.trim_ascii().is_empty())
}

impl Parser<'_> {
    /// The 1-based physical line on which `rec`, just read, starts. Every record ends with
    /// a consumed `\n` (see [`FinalNewline`]), so the reader's line is one past its last
    /// line; newlines inside quoted fields make a record span several lines.
    fn line_of<R: Read>(&self, rdr: &csv::Reader<R>, rec: &csv::ByteRecord) -> u64 {
        let inner = rec.as_slice().iter().filter(|&&b| b == b'\n').count() as u64;
        self.line_offset
            .saturating_add(rdr.position().line())
            .saturating_sub(1)
            .saturating_sub(inner)
            .max(1)
    }

    pub(super) fn run<R: Read>(mut self, reader: R) -> Res<Recording> {
        let mut groups: Vec<Group> = Vec::new();
        let Some(mut rec) = self.run_into(reader, &mut groups, false)? else {
            return Err(self.err(None, RecordingErrorKind::NoData));
        };
        shrink(&mut groups);
        rec.groups = groups;
        Ok(rec)
    }

    /// Read the file, handing each row of a file with conditions to `sink`, with every
    /// check of [`read`]; the recording returned has no groups of its own. With
    /// `conditions_only`, a file without conditions (poses or a free series) is not read
    /// past its header: `Ok(None)`.
    pub(super) fn run_into<R: Read, S: GroupSink>(
        &mut self,
        reader: R,
        sink: &mut S,
        conditions_only: bool,
    ) -> Res<Option<Recording>> {
        let mut br = BufReader::with_capacity(
            1 << 16,
            FinalNewline {
                inner: reader,
                last: None,
                done: false,
            },
        );
        let meta = self.preamble(&mut br)?;

        let mut rdr = csv::ReaderBuilder::new()
            .has_headers(false)
            .flexible(true)
            .comment(Some(b'#'))
            .terminator(csv::Terminator::Any(b'\n'))
            .buffer_capacity(1 << 16)
            .from_reader(br);
        let mut rec = csv::ByteRecord::new();

        // The header: the first record that isn't blank.
        let header_line = loop {
            if !self.next(&mut rdr, &mut rec)? {
                return Err(self.err(None, RecordingErrorKind::Empty));
            }
            if !is_blank(&rec) {
                break self.line_of(&rdr, &rec);
            }
        };
        let (cols, method) = self.header(&rec, header_line, &meta)?;
        let free = cols.condition.is_none() && cols.gravity.is_none();
        if conditions_only && (free || cols.gravity.is_some()) {
            return Ok(None);
        }
        sink.start(&meta, method, &cols);
        let mut router = Router::new(method);
        let mut rows = Collected::new(&cols, free);
        while self.next(&mut rdr, &mut rec)? {
            if rec.len() != cols.n {
                if is_blank(&rec) {
                    continue;
                }
                let line = self.line_of(&rdr, &rec);
                return Err(self.err(
                    Some(line),
                    RecordingErrorKind::WrongFieldCount {
                        expected: cols.n,
                        got: rec.len(),
                    },
                ));
            }
            let line = self.line_of(&rdr, &rec);
            let at = |kind| self.err(Some(line), kind);
            let row = parse_row(&rec, &cols, Parse::All).map_err(at)?;
            if !rows.take(&row, line).map_err(at)? {
                router.route(&row, line, &cols, sink).map_err(at)?;
            }
        }
        self.finish(meta, method, rows, &router).map(Some)
    }

    /// The recording once every row is read: the poses or the series collected, else
    /// (the rows went to the sink) one without rows, once the router has checked its
    /// groups are complete.
    pub(super) fn finish(
        &self,
        meta: Metadata,
        method: Method,
        rows: Collected,
        router: &Router,
    ) -> Res<Recording> {
        // Poses or a continuous series, when read as such, are the recording.
        let Collected { oriented, series } = rows;
        let series = series.filter(|_| oriented.is_none());
        let rows = oriented
            .as_ref()
            .map(|o| o.y.len())
            .or(series.as_ref().map(|s| s.y.len()));
        if let Some(n) = rows {
            if n == 0 {
                return Err(self.err(None, RecordingErrorKind::NoData));
            }
            return Ok(Recording {
                oriented,
                series,
                ..self.without_rows(meta, method)
            });
        }
        router
            .finish(self.complete)
            .map_err(|kind| self.err(None, kind))?;
        Ok(self.without_rows(meta, method))
    }

    fn next<R: Read>(&self, rdr: &mut csv::Reader<R>, rec: &mut csv::ByteRecord) -> Res<bool> {
        rdr.read_byte_record(rec).map_err(|e| {
            let kind = match e.into_kind() {
                csv::ErrorKind::Io(io) => io,
                other => io::Error::other(format!("{other:?}")),
            };
            self.err(None, RecordingErrorKind::Io(kind))
        })
    }
}
