//! A recording held as columns in memory (a DataFrame's, numpy arrays): read with the same
//! metadata, header and row checks as a file ([`super::read_as`]), numbers taken as numbers
//! (no text between), and each problem named by its column and row.

use super::csv::Collected;
use super::head::{ColumnIndex, Parser};
use super::row::{parse_row, Fields};
use super::{shrink, GroupSink, Parse, Router};
use crate::recording::{Group, Metadata, Method, Recording, RecordingError, RecordingErrorKind};

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
