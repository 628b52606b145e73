//! A recording held as columns in memory (a DataFrame's, numpy arrays): read with the same
//! metadata, header and row checks as a file ([`super::read_as`]), numbers taken as numbers
//! (no text between), and each problem named by its column and row.

use super::csv::Collected;
use super::head::{ColumnIndex, Parser};
use super::row::{parse_row, Fields};
use super::{shrink, GroupSink, Parse, PartRow, Router, Stretch};
use crate::recording::{Group, Metadata, Method, Recording, RecordingError, RecordingErrorKind};
use rotacal_shared::Condition;

/// One column's values, a value per row.
#[derive(Clone, Copy, Debug)]
pub enum Values<'a> {
    /// Numbers.
    Numbers(&'a [f64]),
    /// Text (a condition, a pose name, `conv_gaps`; numbers written as text are read as a
    /// file's are).
    Texts(&'a [String]),
    /// One byte of text per row (a condition's letter, as numpy's `S1` holds it).
    Letters(&'a [u8]),
}

impl Values<'_> {
    fn len(&self) -> usize {
        match self {
            Values::Numbers(x) => x.len(),
            Values::Texts(x) => x.len(),
            Values::Letters(x) => x.len(),
        }
    }
}

/// A named column (names as in a file's header, docs/formats.md).
#[derive(Clone, Copy, Debug)]
pub struct Column<'a> {
    /// The column's name.
    pub name: &'a str,
    /// Its values.
    pub values: Values<'a>,
}

/// Row `row` of `columns`, as the row reader takes a record's fields.
pub(super) struct RowOf<'a> {
    pub(super) columns: &'a [Column<'a>],
    pub(super) row: usize,
}

impl Fields for RowOf<'_> {
    fn raw(&self, i: usize) -> Option<&[u8]> {
        match self.columns.get(i)?.values {
            Values::Texts(t) => t.get(self.row).map(String::as_bytes),
            Values::Letters(x) => x.get(self.row).map(std::slice::from_ref),
            Values::Numbers(_) => None,
        }
    }

    fn number(&self, i: usize) -> Option<f64> {
        match self.columns.get(i)?.values {
            Values::Numbers(x) => x.get(self.row).copied(),
            Values::Texts(_) | Values::Letters(_) => None,
        }
    }
}

/// The columns' metadata, method and header, each checked as a file's, and their length.
/// A file's place is its line; columns have only rows.
fn no_line(mut e: RecordingError) -> RecordingError {
    e.line = None;
    e
}

/// Columns' head, checked as a file's: the parser that read it (for the checks at the
/// end), the metadata, the method, the header and the number of rows.
struct Head<'s> {
    parser: Parser<'s>,
    meta: Metadata,
    method: Method,
    cols: ColumnIndex,
    rows: usize,
}

fn head<'s>(
    columns: &[Column<'_>],
    meta: &[(&str, &str)],
    source: &'s str,
    method: Option<Method>,
) -> Result<Head<'s>, RecordingError> {
    let mut parser = Parser {
        source,
        complete: true,
        line_offset: 0,
        method,
    };
    let err = |kind| RecordingError {
        source_name: source.to_string(),
        line: None,
        row: None,
        kind,
    };
    let n = columns.first().map_or(0, |c| c.values.len());
    for c in columns {
        if c.values.len() != n {
            return Err(err(RecordingErrorKind::ColumnLength {
                column: c.name.to_string(),
                expected: n,
                got: c.values.len(),
            }));
        }
    }
    // The metadata through the preamble's reader, as `# key=value` lines.
    let mut preamble = String::new();
    for (key, value) in meta {
        if [key, value].iter().any(|s| s.contains(['\n', '\r'])) {
            return Err(err(RecordingErrorKind::MetadataLineBreak {
                key: key.to_string(),
            }));
        }
        preamble.push_str(&format!("# {key}={value}\n"));
    }
    let meta = parser.preamble(&mut preamble.as_bytes()).map_err(no_line)?;
    let header = ::csv::ByteRecord::from(columns.iter().map(|c| c.name).collect::<Vec<_>>());
    let (cols, method) = parser.header(&header, 0, &meta).map_err(no_line)?;
    Ok(Head {
        parser,
        meta,
        method,
        cols,
        rows: n,
    })
}

/// Every row of `columns` through the reader's checks, into `sink` (a file with
/// conditions) or `rows` (poses, a series); the error at the row that fails.
fn each_row<S: GroupSink>(
    columns: &[Column<'_>],
    cols: &ColumnIndex,
    n: usize,
    router: &mut Router,
    rows: &mut Collected,
    sink: &mut S,
    source: &str,
) -> Result<(), RecordingError> {
    for row in 0..n {
        let at = |kind| RecordingError {
            source_name: source.to_string(),
            line: None,
            row: Some(row as u64),
            kind,
        };
        let fields = RowOf { columns, row };
        let parsed = parse_row(&fields, cols, Parse::All).map_err(at)?;
        if !rows.take(&parsed, row as u64).map_err(at)? {
            router.route(&parsed, row as u64, cols, sink).map_err(at)?;
        }
    }
    Ok(())
}

/// The recording held in `columns` with the metadata `meta` (`key`, `value`: a file's
/// `# key=value` lines), read as `method` if given, named `source` in messages. The rows'
/// "lines" (a group's `first_line`, a pose's lines) are their 0-based row numbers.
pub fn read_columns(
    columns: &[Column<'_>],
    meta: &[(&str, &str)],
    source: &str,
    method: Option<Method>,
) -> Result<Recording, RecordingError> {
    let Head {
        parser,
        meta,
        method,
        cols,
        rows: n,
    } = head(columns, meta, source, method)?;
    let free = cols.condition.is_none() && cols.gravity.is_none();
    let mut groups: Vec<Group> = Vec::new();
    groups.start(&meta, method, &cols);
    let mut router = Router::new(method);
    let mut rows = Collected::new(&cols, free);
    each_row(
        columns,
        &cols,
        n,
        &mut router,
        &mut rows,
        &mut groups,
        source,
    )?;
    let mut rec = parser
        .finish(meta, method, rows, &router)
        .map_err(no_line)?;
    shrink(&mut groups);
    rec.groups = groups;
    Ok(rec)
}

/// The metadata, method, header and length of columns with conditions, checked as a
/// file's head is, for reading in parts (whose rows the reader checks as it goes); `None`
/// for poses or a series (read them with [`read_columns`]).
#[allow(clippy::type_complexity)]
pub(super) fn columns_head(
    columns: &[Column<'_>],
    meta: &[(&str, &str)],
    source: &str,
    method: Option<Method>,
) -> Result<Option<(Metadata, Method, ColumnIndex, usize)>, RecordingError> {
    let Head {
        meta,
        method,
        cols,
        rows,
        ..
    } = head(columns, meta, source, method)?;
    if cols.condition.is_none() || cols.gravity.is_some() {
        return Ok(None);
    }
    Ok(Some((meta, method, cols, rows)))
}

/// The columns a part of a rotation reads, as slices, when each is plain: the condition a
/// letter a row, every other column it reads numbers, and none that needs parsing
/// (gravity, poses, uncertainties, conversions, boots). A row read here is the row
/// [`parse_row`] reads, to the bit; one that is not plainly fine is left to it, which
/// then reads it or names its problem. Without the per-field dispatch of [`parse_row`]
/// (a fifth of a DataFrame's calibration, issue 35's speed).
pub(super) struct PlainColumns<'a> {
    condition: &'a [u8],
    t_s: Option<&'a [f64]>,
    u: &'a [f64],
    v: &'a [f64],
    w: &'a [f64],
    rate_hz: Option<&'a [f64]>,
    /// Read, and so checked, in [`Parse::All`] only, as [`parse_row`] does.
    angle_deg: Option<&'a [f64]>,
    seq: Option<&'a [f64]>,
    temp_c: Option<&'a [f64]>,
}

impl<'a> PlainColumns<'a> {
    /// The plain view of `columns` (whose header is `cols`) for reading `parse`'s
    /// columns, or `None` when one of them is not plain.
    pub(super) fn of(columns: &'a [Column<'a>], cols: &ColumnIndex, parse: Parse) -> Option<Self> {
        if cols.gravity.is_some()
            || cols.pose.is_some()
            || cols.unc.is_some()
            || cols.conv_gaps.is_some()
            || cols.conv_missed.is_some()
            || cols.boot.is_some()
        {
            return None;
        }
        let numbers = |i: usize| match columns.get(i)?.values {
            Values::Numbers(x) => Some(x),
            Values::Texts(_) | Values::Letters(_) => None,
        };
        // A column that is there must be numbers; one that is not is None.
        let opt = |i: Option<usize>| -> Option<Option<&'a [f64]>> {
            match i {
                Some(i) => numbers(i).map(Some),
                None => Some(None),
            }
        };
        let all = parse == Parse::All;
        let condition = match columns.get(cols.condition?)?.values {
            Values::Letters(x) => x,
            Values::Numbers(_) | Values::Texts(_) => return None,
        };
        Some(PlainColumns {
            condition,
            t_s: opt(cols.t_s)?,
            u: numbers(cols.u)?,
            v: numbers(cols.v)?,
            w: numbers(cols.w)?,
            rate_hz: opt(cols.rate_hz)?,
            angle_deg: opt(cols.angle_deg.filter(|_| all))?,
            seq: opt(cols.seq.filter(|_| all))?,
            temp_c: opt(cols.temp_c.filter(|_| all))?,
        })
    }

    /// The end of the stretch of rows from `start` (before `end`) that share row
    /// `start`'s condition letter and `rate_hz` (at least `start + 1`).
    fn stretch_end(&self, start: usize, end: usize) -> usize {
        let (Some(letter), Some(cond)) =
            (self.condition.get(start), self.condition.get(start..end))
        else {
            return start + 1;
        };
        let same = |r: &[f64]| -> Option<usize> {
            let first = r.get(start)?.to_bits();
            let run = r.get(start..end)?;
            Some(
                run.iter()
                    .position(|x| x.to_bits() != first)
                    .unwrap_or(run.len()),
            )
        };
        let by_letter = cond.iter().position(|c| c != letter).unwrap_or(cond.len());
        let by_rate = self.rate_hz.and_then(same).unwrap_or(by_letter);
        (start + by_letter.min(by_rate)).max(start + 1)
    }

    /// The stretch of one group's rows from `start` (before `end`): where it stops, and
    /// its rows when every one of them is plainly fine, checked column by column as
    /// [`parse_row`] checks each field (a condition letter, finite numbers, a whole `seq`,
    /// a positive `rate_hz`); `None` for anything else, which [`parse_row`] then reads or
    /// names.
    pub(super) fn stretch(&self, start: usize, end: usize) -> (usize, Option<Stretch<'a>>) {
        let stop = self.stretch_end(start, end);
        (stop, self.checked(start, stop))
    }

    /// Rows `start..stop` of one condition and rate as a stretch, if each is plainly fine.
    fn checked(&self, start: usize, stop: usize) -> Option<Stretch<'a>> {
        let condition = Condition::from_letter(char::from(*self.condition.get(start)?))?;
        let part = |c: &'a [f64]| c.get(start..stop);
        // Folds, not `all`, which stops at the first and so is not vectorised.
        let all_finite = |x: &[f64]| x.iter().fold(true, |ok, v| ok & v.is_finite());
        let finite = |c: Option<&'a [f64]>| -> Option<Option<&'a [f64]>> {
            match c {
                Some(c) => {
                    let x = part(c)?;
                    all_finite(x).then_some(Some(x))
                }
                None => Some(None),
            }
        };
        let y = [part(self.u)?, part(self.v)?, part(self.w)?];
        if !y.iter().all(|c| all_finite(c)) {
            return None;
        }
        let t_s = finite(self.t_s)?;
        // One rate for the stretch (stretch_end).
        let rate_hz = match finite(self.rate_hz)? {
            Some(r) => {
                let first = *r.first()?;
                (first > 0.0).then_some(Some(first))?
            }
            None => None,
        };
        finite(self.angle_deg)?;
        finite(self.temp_c)?;
        // As the integer reader takes a number: whole, from 0 to below 2⁶⁴.
        if let Some(seq) = finite(self.seq)? {
            if !seq
                .iter()
                .all(|s| *s >= 0.0 && s.fract() == 0.0 && *s < u64::MAX as f64)
            {
                return None;
            }
        }
        Some(Stretch {
            condition,
            rate_hz,
            t_s,
            y,
        })
    }

    /// Row `i`, when it is plainly fine: a stretch of one row.
    pub(super) fn row(&self, i: usize) -> Option<PartRow> {
        self.checked(i, i + 1)?.rows().next()
    }
}

#[cfg(test)]
#[allow(clippy::indexing_slicing, clippy::unwrap_used)]
mod tests {
    use super::super::{Parse, PartRow, Parts};
    use super::{columns_head, Column, PlainColumns, RowOf, Values};
    use crate::recording::read::row::parse_row;
    use proptest::prelude::*;

    /// A number as a column may hold one: mostly ordinary, sometimes not finite, negative,
    /// fractional or huge.
    fn number() -> impl Strategy<Value = f64> {
        prop_oneof![
            8 => (0u32..200).prop_map(f64::from),
            2 => -10.0..10.0f64,
            1 => Just(f64::NAN),
            1 => Just(f64::INFINITY),
            1 => Just(-0.0),
            1 => Just(1e300),
        ]
    }

    /// What [`parse_row`] reads of row `i`, as a part row (`None`: it names a problem).
    fn by_field(
        columns: &[Column<'_>],
        cols: &super::ColumnIndex,
        parse: Parse,
        i: usize,
    ) -> Option<PartRow> {
        let fields = RowOf { columns, row: i };
        parse_row(&fields, cols, parse)
            .ok()
            .map(|r| PartRow::of(&r))
    }

    proptest! {
        /// A row the plain view takes is the row the field reader reads, to the bit, and a
        /// stretch is its rows; the parts reader's stretches give the rows its rows give.
        #[test]
        fn plain_columns_read_as_parse_row_reads_them(
            letters in prop::collection::vec(prop::sample::select(b"xxxxyyyzzZq ".to_vec()), 1..40),
            numbers in prop::collection::vec(number(), 7 * 40),
            rates in prop::collection::vec(prop::sample::select(vec![0.01, 0.01, 0.02, 0.0, -1.0, f64::NAN]), 40),
            with_rate in proptest::bool::ANY,
            all in proptest::bool::ANY,
        ) {
            let n = letters.len();
            let col = |k: usize| numbers[k * 40..k * 40 + n].to_vec();
            let (t, u, v, w, seq, temp, angle) = (col(0), col(1), col(2), col(3), col(4), col(5), col(6));
            let rate = rates[..n].to_vec();
            let mut columns = vec![
                Column { name: "condition", values: Values::Letters(&letters) },
                Column { name: "t_s", values: Values::Numbers(&t) },
                Column { name: "u", values: Values::Numbers(&u) },
                Column { name: "v", values: Values::Numbers(&v) },
                Column { name: "w", values: Values::Numbers(&w) },
                Column { name: "seq", values: Values::Numbers(&seq) },
                Column { name: "temp_c", values: Values::Numbers(&temp) },
                Column { name: "angle_deg", values: Values::Numbers(&angle) },
            ];
            if with_rate {
                columns.push(Column { name: "rate_hz", values: Values::Numbers(&rate) });
            }
            let meta = [("g_loc", "9.8"), ("rate_hz", "0.01")];
            let (_, _, cols, rows) = columns_head(&columns, &meta, "test", None).unwrap().unwrap();
            prop_assert_eq!(rows, n);
            let parse = if all { Parse::All } else { Parse::Fit };
            let plain = PlainColumns::of(&columns, &cols, parse).unwrap();
            for i in 0..n {
                if let Some(row) = plain.row(i) {
                    prop_assert_eq!(Some(row), by_field(&columns, &cols, parse, i), "row {}", i);
                }
                let (end, st) = plain.stretch(i, n);
                prop_assert!(end > i);
                if let Some(st) = st {
                    let mine: Vec<_> = st.rows().collect();
                    let theirs: Vec<_> = (i..end).map(|j| by_field(&columns, &cols, parse, j)).collect();
                    prop_assert_eq!(mine.into_iter().map(Some).collect::<Vec<_>>(), theirs);
                }
            }
            // The parts reader: the same rows, whole or stopped at the same problem.
            let parts = Parts::of_columns(&columns, &meta, "test", None).unwrap().unwrap();
            let mut one = Vec::new();
            let a = parts.rows((0, n as u64), parse, |l, r| { one.push((l, r)); true }).unwrap();
            let mut two = Vec::new();
            let cell = std::cell::RefCell::new(&mut two);
            let b = parts
                .stretches(
                    (0, n as u64),
                    parse,
                    |l, r| { cell.borrow_mut().push((l, r)); true },
                    |l, st| {
                        cell.borrow_mut().extend(st.rows().enumerate().map(|(k, r)| (l + k as u64, r)));
                        true
                    },
                )
                .unwrap();
            prop_assert_eq!(a, b);
            if a.is_some() {
                prop_assert_eq!(one, two);
            }
        }
    }

    #[test]
    fn a_plain_recording_is_read_in_stretches() {
        // The common columns must not fall back row by row (which would be correct, and slow).
        let letters = [b'x'; 100]
            .iter()
            .chain(&[b'y'; 50])
            .copied()
            .collect::<Vec<_>>();
        let t: Vec<f64> = (0..150).map(|i| f64::from(i) * 0.01).collect();
        let y = vec![1.0; 150];
        let numbers = |name, values| Column {
            name,
            values: Values::Numbers(values),
        };
        let columns = [
            Column {
                name: "condition",
                values: Values::Letters(&letters),
            },
            numbers("t_s", &t),
            numbers("u", &y),
            numbers("v", &y),
            numbers("w", &y),
        ];
        let meta = [("g_loc", "9.8"), ("rate_hz", "0.01")];
        let parts = Parts::of_columns(&columns, &meta, "test", None)
            .unwrap()
            .unwrap();
        let mut stretches = Vec::new();
        let lines = parts
            .stretches(
                (0, 150),
                Parse::All,
                |_, _| false,
                |l, st| {
                    stretches.push((l, st.len()));
                    true
                },
            )
            .unwrap();
        assert_eq!(lines, Some(150));
        assert_eq!(stretches, [(0, 100), (100, 50)]);
    }
}
