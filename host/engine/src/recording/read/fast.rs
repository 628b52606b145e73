//! The fast reader: whole lines from a large buffer, split at their commas, and plain rows
//! read in one walk over their bytes. It reads files without quotes and gives exactly the
//! rows the csv reader gives; on anything else it stops, and the csv reader reads the file.

use std::io::{self, BufRead, BufReader, Read};

use rotacal_shared::Condition;

use super::head::{ColumnIndex, Parser, Res};
use super::number::{field_end, leading_decimal, leading_digits};
use super::row::{parse_boot, parse_gaps, parse_missed, parse_row, Fields};
use super::{GroupSink, Parse, Router};
use crate::recording::{Metadata, Method, Recording, RecordingErrorKind, Row};

/// A reader that counts the bytes it hands out.
struct Counted<R> {
    inner: R,
    n: u64,
}

impl<R: Read> Read for Counted<R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let k = self.inner.read(buf)?;
        self.n += k as u64;
        Ok(k)
    }
}

/// What the fast reader knows after the header.
pub(super) struct Head<R> {
    pub(super) meta: Metadata,
    pub(super) cols: ColumnIndex,
    pub(super) method: Method,
    /// At the first line after the header.
    reader: BufReader<Counted<R>>,
    /// The header's line number.
    pub(super) line: u64,
    /// The byte offset of the line after the header.
    pub(super) offset: u64,
}

/// `line`'s fields: where each starts and ends, at its commas.
fn split_commas(line: &[u8], bounds: &mut Vec<(usize, usize)>) {
    bounds.clear();
    let mut start = 0;
    // A plain loop: the fields are short, too short for memchr's set-up to pay.
    for (i, b) in line.iter().enumerate() {
        if *b == b',' {
            bounds.push((start, i));
            start = i + 1;
        }
    }
    bounds.push((start, line.len()));
}

/// Whether every field of a split line is blank (the csv reader's blank record).
fn is_blank_line(line: &[u8], bounds: &[(usize, usize)]) -> bool {
    bounds
        .iter()
        .all(|(a, b)| line.get(*a..*b).is_none_or(|f| f.trim_ascii().is_empty()))
}

/// The data lines after a header at line `line`, by the fast reader: each row (with its
/// line number) to `each`, which returns false to stop. `Ok(None)` when a line needs
/// the csv reader (a quote, a wrong number of fields, a field that does not parse) or
/// `each` stopped; else the number of the last line read.
pub(super) fn fast_rows<R: Read>(
    reader: &mut R,
    cols: &ColumnIndex,
    columns: Parse,
    line: u64,
    mut each: impl FnMut(u64, &Row<'_>) -> bool,
) -> io::Result<Option<u64>> {
    let mut line_no = line;
    let mut bounds: Vec<(usize, usize)> = Vec::with_capacity(16);
    let plan = plain_plan(cols, columns);
    // The plain rows' row: each sets the same fields (the plan's), so it is reused.
    let mut row = Row::new(Condition::X, 0.0, 0.0, 0.0);
    // Whole lines from a large buffer: a line cut by the buffer's end is moved to its
    // front before the next read.
    let mut chunk: Vec<u8> = vec![0; 1 << 20];
    let mut filled = 0;
    loop {
        let got = reader.read(chunk.get_mut(filled..).unwrap_or(&mut []))?;
        filled += got;
        let data = chunk.get(..filled).unwrap_or(&[]);
        // At the end the last line needs no newline; otherwise only whole lines.
        let whole = if got == 0 {
            filled
        } else {
            match memchr::memrchr(b'\n', data) {
                Some(i) => i + 1,
                None if filled < chunk.len() => continue,
                None => return Ok(None), // a line longer than the buffer
            }
        };
        let lines = data.get(..whole).unwrap_or(&[]);
        if memchr::memchr(b'"', lines).is_some() {
            return Ok(None);
        }
        let mut at = 0;
        while at < lines.len() {
            line_no += 1;
            // A plain row in one walk over its bytes; anything else line by line below.
            if let Some(next) = plan
                .as_deref()
                .and_then(|p| plain_row(p, lines, at, &mut row))
            {
                if !each(line_no, &row) {
                    return Ok(None);
                }
                at = next;
                continue;
            }
            let rest = lines.get(at..).unwrap_or(&[]);
            let end = memchr::memchr(b'\n', rest).unwrap_or(rest.len());
            let line = rest.get(..end).unwrap_or(&[]);
            at += end + 1;
            let keep = if line.is_empty() || line.first() == Some(&b'#') {
                true // the csv reader skips empty lines and comments
            } else {
                split_commas(line, &mut bounds);
                if bounds.len() != cols.n {
                    is_blank_line(line, &bounds)
                } else {
                    let fields = SplitLine {
                        line,
                        bounds: &bounds,
                    };
                    match parse_row(&fields, cols, columns) {
                        Ok(row) => each(line_no, &row),
                        Err(_) => false,
                    }
                }
            };
            if !keep {
                return Ok(None);
            }
        }
        if got == 0 {
            return Ok(Some(line_no));
        }
        chunk.copy_within(whole..filled, 0);
        filled -= whole;
    }
}

/// What [`plain_row`] does with a column.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Plain {
    Condition,
    /// A plain decimal into a slot of the row.
    Number(Slot),
    Seq,
    Gaps,
    Missed,
    Boot,
    /// A column this reading does not use.
    Skip,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Slot {
    T,
    Angle,
    U,
    V,
    W,
    Temp,
    Rate,
}

/// Each column's part in a plain row, for [`plain_row`]; `None` for a file it does not
/// read (gravity directions, poses or uncertainties: those rows go field by field).
fn plain_plan(cols: &ColumnIndex, columns: Parse) -> Option<Vec<Plain>> {
    if cols.gravity.is_some() || cols.pose.is_some() || cols.unc.is_some() {
        return None;
    }
    let all = columns == Parse::All;
    let mut plan = vec![Plain::Skip; cols.n];
    let mut set = |i: Option<usize>, p: Plain| {
        if let Some(slot) = i.and_then(|i| plan.get_mut(i)) {
            *slot = p;
        }
    };
    set(cols.condition, Plain::Condition);
    set(cols.t_s, Plain::Number(Slot::T));
    set(cols.angle_deg.filter(|_| all), Plain::Number(Slot::Angle));
    set(Some(cols.u), Plain::Number(Slot::U));
    set(Some(cols.v), Plain::Number(Slot::V));
    set(Some(cols.w), Plain::Number(Slot::W));
    set(cols.seq.filter(|_| all), Plain::Seq);
    set(cols.temp_c.filter(|_| all), Plain::Number(Slot::Temp));
    set(cols.rate_hz, Plain::Number(Slot::Rate));
    set(cols.conv_gaps, Plain::Gaps);
    set(cols.conv_missed, Plain::Missed);
    set(cols.boot, Plain::Boot);
    plan.contains(&Plain::Condition).then_some(plan)
}

/// The row that starts at byte `at` of `data`, into `row` (the fields `plan` names), and the
/// byte after its newline, read in one walk over its fields when it is plain: `plan`'s
/// number of fields, a condition letter, plain decimals ([`plain_decimal`]) and whole
/// numbers with nothing around them. `None` for anything else (a comment, spaces, an
/// exponent, a problem), which [`parse_row`] then reads, or names: a row read here is the
/// row it would read, to the bit.
fn plain_row(plan: &[Plain], data: &[u8], at: usize, row: &mut Row<'static>) -> Option<usize> {
    if data.get(at) == Some(&b'#') {
        return None;
    }
    let last = plan.len().checked_sub(1)?;
    let mut pos = at;
    for (i, part) in plan.iter().enumerate() {
        let rest = data.get(pos..)?;
        // Each field read in the walk that finds its end (the bytes after it are left).
        let len = match part {
            Plain::Condition => {
                let c = rest.first()?;
                row.condition = Condition::from_letter(char::from(*c))?;
                1
            }
            Plain::Number(slot) => {
                let (x, len) = leading_decimal(rest)?;
                match slot {
                    Slot::T => row.t_s = Some(x),
                    Slot::Angle => row.angle_deg = Some(x),
                    Slot::U => row.u = x,
                    Slot::V => row.v = x,
                    Slot::W => row.w = x,
                    Slot::Temp => row.temp_c = Some(x),
                    Slot::Rate if x > 0.0 => row.rate_hz = Some(x),
                    Slot::Rate => return None,
                }
                len
            }
            Plain::Seq => {
                let mut seq = 0;
                let len = leading_digits(rest, 0, &mut seq);
                if len == 0 || len > 19 {
                    return None;
                }
                row.seq = Some(seq);
                len
            }
            Plain::Gaps | Plain::Missed | Plain::Boot | Plain::Skip => {
                let len = field_end(rest);
                let f = rest.get(..len)?;
                match part {
                    Plain::Gaps => row.conv_gaps = Some(parse_gaps(f.trim_ascii()).ok()?),
                    Plain::Missed => row.conv_missed = parse_missed(f).ok()?,
                    Plain::Boot => row.boot = Some(parse_boot(f).ok()?),
                    _ => {}
                }
                len
            }
        };
        // The field ends at a comma, the last one at a newline or the end of the file.
        let ends_line = match rest.get(len) {
            Some(b',') => false,
            Some(b'\n') | None => true,
            Some(_) => return None,
        };
        if ends_line != (i == last) {
            return None;
        }
        pos += len + 1;
    }
    Some(pos.min(data.len()))
}

/// A line split at its commas: the fast reader's record.
pub(super) struct SplitLine<'a> {
    line: &'a [u8],
    /// Each field's start and end in `line`.
    bounds: &'a [(usize, usize)],
}

impl Fields for SplitLine<'_> {
    fn raw(&self, i: usize) -> Option<&[u8]> {
        let (a, b) = *self.bounds.get(i)?;
        self.line.get(a..b)
    }
}

impl Parser<'_> {
    /// The fast reader: lines split at their commas, for files without quotes. It gives
    /// exactly what [`Parser::run_into`] gives (the same preamble, header and row
    /// functions, on the same fields); on anything it does not handle (a quote, a
    /// comment after the header, any problem in a row) it stops with `Ok(None)`, and the
    /// caller reads the file again with the csv reader, which names the problem.
    pub(super) fn run_fast<R: Read, S: GroupSink>(
        &mut self,
        reader: R,
        sink: &mut S,
        conditions_only: bool,
        columns: Parse,
    ) -> Res<Option<Option<Recording>>> {
        let Some(head) = self.fast_head(reader)? else {
            return Ok(None);
        };
        let Head {
            meta,
            cols,
            method,
            mut reader,
            line,
            ..
        } = head;
        let free = cols.condition.is_none() && cols.gravity.is_none();
        if free || cols.gravity.is_some() {
            return Ok(if conditions_only { Some(None) } else { None });
        }
        sink.start(&meta, method, &cols);
        let mut router = Router::new(method);
        let read = fast_rows(&mut reader, &cols, columns, line, |line, row| {
            router.route(row, line, &cols, sink).is_ok()
        })
        .map_err(|e| self.err(None, RecordingErrorKind::Io(e)))?;
        if read.is_none() || router.finish(self.complete).is_err() {
            return Ok(None);
        }
        Ok(Some(Some(self.without_rows(meta, method))))
    }

    /// The preamble and the header by the fast reader (`None`: the header needs the csv
    /// reader, or the file has none), leaving the reader at the first data line.
    pub(super) fn fast_head<R: Read>(&mut self, reader: R) -> Res<Option<Head<R>>> {
        let io = |s: &Self, e: io::Error| s.err(None, RecordingErrorKind::Io(e));
        let mut br = BufReader::with_capacity(
            1 << 16,
            Counted {
                inner: reader,
                n: 0,
            },
        );
        let meta = self.preamble(&mut br)?;
        let mut line_no = self.line_offset;
        let mut buf: Vec<u8> = Vec::with_capacity(256);
        let mut bounds: Vec<(usize, usize)> = Vec::with_capacity(16);
        // The header: the first line that isn't blank.
        let (cols, method) = loop {
            buf.clear();
            if br.read_until(b'\n', &mut buf).map_err(|e| io(self, e))? == 0 {
                return Ok(None);
            }
            line_no += 1;
            let line = buf.strip_suffix(b"\n").unwrap_or(&buf);
            if line.is_empty() {
                continue;
            }
            if line.first() == Some(&b'#') || line.contains(&b'"') {
                return Ok(None);
            }
            split_commas(line, &mut bounds);
            if is_blank_line(line, &bounds) {
                continue;
            }
            let rec = csv::ByteRecord::from(
                bounds
                    .iter()
                    .map(|(a, b)| line.get(*a..*b).unwrap_or(b""))
                    .collect::<Vec<_>>(),
            );
            break self.header(&rec, line_no, &meta)?;
        };
        let offset = br.get_ref().n - br.buffer().len() as u64;
        Ok(Some(Head {
            meta,
            cols,
            method,
            reader: br,
            line: line_no,
            offset,
        }))
    }
}

#[cfg(test)]
#[allow(clippy::indexing_slicing)]
mod tests {
    use super::{
        parse_row, plain_plan, plain_row, split_commas, ColumnIndex, Parse, Row, SplitLine,
    };
    use proptest::prelude::*;
    use rotacal_shared::Condition;

    /// The columns of a rotation recording (`condition,seq,t_s,u,v,w,temp_c`), with
    /// `rate_hz`, `conv_gaps`, `conv_missed`, `boot` and a column of no meaning after
    /// them when `more`.
    fn columns(more: bool) -> ColumnIndex {
        ColumnIndex {
            n: if more { 12 } else { 7 },
            condition: Some(0),
            gravity: None,
            pose: None,
            unc: None,
            u: 3,
            v: 4,
            w: 5,
            t_s: Some(2),
            angle_deg: None,
            seq: Some(1),
            temp_c: Some(6),
            rate_hz: more.then_some(7),
            conv_gaps: more.then_some(8),
            conv_missed: more.then_some(9),
            boot: more.then_some(10),
        }
    }

    /// A line the plain reader reads is read as [`parse_row`] reads it, to the bit, and
    /// its end is found; one it refuses is left to `parse_row`.
    fn plain_reads_as_parse_row(cols: &ColumnIndex, parse: Parse, text: &str) {
        let Some(plan) = plain_plan(cols, parse) else {
            panic!("a plain plan for these columns");
        };
        let mut row = Row::new(Condition::X, 0.0, 0.0, 0.0);
        let data = text.as_bytes();
        let Some(next) = plain_row(&plan, data, 0, &mut row) else {
            return;
        };
        let end = memchr::memchr(b'\n', data).unwrap_or(data.len());
        assert_eq!(next, (end + 1).min(data.len()), "{text:?}");
        let line = &data[..end];
        let mut bounds = Vec::new();
        split_commas(line, &mut bounds);
        assert_eq!(bounds.len(), cols.n, "{text:?}");
        let fields = SplitLine {
            line,
            bounds: &bounds,
        };
        match parse_row(&fields, cols, parse) {
            Ok(want) => assert_eq!(format!("{row:?}"), format!("{want:?}"), "{text:?}"),
            Err(e) => panic!("plain read {text:?}, which parse_row refuses: {e}"),
        }
    }

    fn field() -> impl Strategy<Value = String> {
        prop_oneof![
            24 => "-?[0-9]{1,8}(\\.[0-9]{1,8})?",
            1 => "-?[0-9]{0,17}(\\.[0-9]{0,17})?",
            1 => prop::sample::select(vec![
                "", " 5", "5 ", "+2", "-", ".", ".5", "5.", "1.2.3", "1e3", "nan", "inf",
                "0x10", "--1", "1-", "12,5", "\r", "18446744073709551615", "-0.0", "0",
            ])
            .prop_map(str::to_string),
        ]
    }

    proptest! {
        // About one case in ten is a plain row from end to end: enough of them.
        #![proptest_config(ProptestConfig::with_cases(2000))]

        #[test]
        fn a_plain_row_reads_as_parse_row_reads_it(
            cond in prop::sample::select(vec!["x", "y", "z", "Z", "w", " x", "xx", "", "#"]),
            fields in prop::collection::vec(field(), 8),
            off in prop_oneof![6 => Just(0usize), 1 => Just(1usize), 1 => Just(2usize)],
            gaps in prop::sample::select(vec!["", "9600", "9600 9600", "0", "x", " 9600"]),
            missed in prop::sample::select(vec!["", "0", "3", "7", "8", " 1", "x", "-1"]),
            boot in prop::sample::select(vec!["0", "1", "4294967295", "4294967296", "", " 2", "-1"]),
            end in prop::sample::select(vec!["\n", "\r\n", "", "\nx,1,2,3,4,5,6\n"]),
            more in proptest::bool::ANY,
            all in proptest::bool::ANY,
        ) {
            // Mostly the right number of fields (off = 1: one fewer, 2: one more).
            let numbers = if more { 7 } else { 6 };
            let numbers = match off {
                1 => numbers - 1,
                2 => numbers + 1,
                _ => numbers,
            };
            let mut parts = vec![cond.to_string()];
            parts.extend(fields.into_iter().take(numbers));
            if more {
                parts.push(gaps.to_string());
                parts.push(missed.to_string());
                parts.push(boot.to_string());
                parts.push("note".to_string());
            }
            let text = parts.join(",") + end;
            let parse = if all { Parse::All } else { Parse::Fit };
            plain_reads_as_parse_row(&columns(more), parse, &text);
        }
    }

    #[test]
    fn plain_rows_are_read_by_the_plain_reader() {
        // The common rows must not all fall back (which would be correct, and slow).
        let Some(plan) = plain_plan(&columns(false), Parse::All) else {
            panic!("a plain plan");
        };
        let mut row = Row::new(Condition::X, 0.0, 0.0, 0.0);
        for text in [
            "x,0,0.0,541.0,-9558.0,-12827.0,25.0\n",
            "y,123456,3599.990385,-1.5,0.009615,7,-0.0",
        ] {
            let got = plain_row(&plan, text.as_bytes(), 0, &mut row);
            assert_eq!(got, Some(text.len()), "{text:?}");
            plain_reads_as_parse_row(&columns(false), Parse::All, text);
        }
        assert_eq!(row.t_s, Some(3599.990385));
        assert_eq!(row.seq, Some(123456));
        // An exponent goes the long way.
        assert_eq!(plain_row(&plan, b"z,1,1e0,1,2,3,4\n", 0, &mut row), None);
    }
}
