//! An input's lines as fields: delimited text (the delimiter found on its first data line,
//! and with it whether a comma can be a decimal comma), or a spreadsheet's rows (xlsx,
//! xls, xlsb or ods, read by calamine: the first sheet, or the one named).

use super::error::{ImportError, ImportErrorKind as K};
use calamine::{Data, Reader};
use std::io::{BufRead, Cursor};

/// Where an input's lines come from.
pub enum Rows<'a> {
    /// Delimited text, read a line at a time.
    Text(Box<dyn BufRead + 'a>),
    /// A sheet's rows, each with its 1-based row number, its cells as text.
    Sheet(Vec<(usize, Vec<String>)>),
}

/// One input: its name (for messages) and its lines.
pub struct Input<'a> {
    /// The path or name.
    pub name: String,
    /// Its lines.
    pub rows: Rows<'a>,
}

impl<'a> Input<'a> {
    /// Delimited text from `reader`.
    pub fn text(name: impl Into<String>, reader: Box<dyn BufRead + 'a>) -> Self {
        Input {
            name: name.into(),
            rows: Rows::Text(reader),
        }
    }
}

/// How a text line's fields are separated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Delimiter {
    Semicolon,
    Tab,
    Comma,
    Spaces,
}

impl Delimiter {
    /// The delimiter of `line`: a semicolon, else a tab, else a comma, else runs of spaces
    /// (a semicolon first: a German spreadsheet's CSV has decimal commas between them).
    pub(super) fn of(line: &str) -> Delimiter {
        if line.contains(';') {
            Delimiter::Semicolon
        } else if line.contains('\t') {
            Delimiter::Tab
        } else if line.contains(',') {
            Delimiter::Comma
        } else {
            Delimiter::Spaces
        }
    }

    /// `line`'s fields, trimmed and without surrounding double quotes.
    pub(super) fn split(self, line: &str) -> Vec<String> {
        let fields: Vec<&str> = match self {
            Delimiter::Semicolon => line.split(';').collect(),
            Delimiter::Tab => line.split('\t').collect(),
            Delimiter::Comma => line.split(',').collect(),
            Delimiter::Spaces => line.split_whitespace().collect(),
        };
        fields.into_iter().map(unquote).collect()
    }

    /// Whether a comma in a field can be a decimal comma.
    pub(super) fn decimal_comma(self) -> bool {
        self != Delimiter::Comma
    }
}

fn unquote(field: &str) -> String {
    let f = field.trim();
    f.strip_prefix('"')
        .and_then(|g| g.strip_suffix('"'))
        .unwrap_or(f)
        .trim()
        .to_string()
}

/// `text` as a number; with `decimal_comma`, one comma and no point reads as a point.
pub(super) fn number(text: &str, decimal_comma: bool) -> Option<f64> {
    let t = text.trim();
    let parsed = if decimal_comma && t.contains(',') && !t.contains('.') {
        t.replacen(',', ".", 1).parse::<f64>()
    } else {
        t.parse::<f64>()
    };
    parsed.ok()
}

/// Whether `bytes` begin as a spreadsheet does: a zip archive (xlsx, xlsb, ods) or an OLE
/// compound file (xls).
pub fn is_spreadsheet(bytes: &[u8]) -> bool {
    bytes.starts_with(b"PK\x03\x04") || bytes.starts_with(&[0xD0, 0xCF, 0x11, 0xE0])
}

/// A spreadsheet's rows, from its bytes: the sheet named `sheet`, else the first.
pub fn sheet(
    name: &str,
    bytes: Vec<u8>,
    sheet: Option<&str>,
) -> Result<Input<'static>, ImportError> {
    let fail = |kind| ImportError::at(name, None, kind);
    let mut book = calamine::open_workbook_auto_from_rs(Cursor::new(bytes))
        .map_err(|e| fail(K::Spreadsheet(e.to_string())))?;
    let names = book.sheet_names();
    let chosen = match sheet {
        Some(s) => names
            .iter()
            .find(|n| n.as_str() == s)
            .cloned()
            .ok_or_else(|| {
                fail(K::NoSheet {
                    sheet: s.to_string(),
                    sheets: names.join(", "),
                })
            })?,
        None => names
            .first()
            .cloned()
            .ok_or_else(|| fail(K::Spreadsheet("the workbook has no sheets".into())))?,
    };
    let range = book
        .worksheet_range(&chosen)
        .map_err(|e| fail(K::Spreadsheet(e.to_string())))?;
    // Row numbers as the spreadsheet shows them, from 1.
    let first = range.start().map_or(0, |(r, _)| r as usize);
    let rows = range
        .rows()
        .enumerate()
        .map(|(i, cells)| (first + i + 1, cells.iter().map(cell).collect()))
        .collect();
    Ok(Input {
        name: format!("{name} (sheet '{chosen}')"),
        rows: Rows::Sheet(rows),
    })
}

/// A cell as text: numbers as the shortest text that reads back the same; a date or time
/// as Excel's serial number (days since 1899-12-30).
fn cell(c: &Data) -> String {
    match c {
        Data::Int(i) => i.to_string(),
        Data::Float(f) => f.to_string(),
        Data::String(s) => unquote(s),
        Data::Bool(b) => b.to_string(),
        Data::DateTime(d) => d.as_f64().to_string(),
        Data::DateTimeIso(s) | Data::DurationIso(s) => s.clone(),
        Data::Error(e) => format!("#{e:?}"),
        Data::Empty => String::new(),
    }
}

/// An input's non-blank, non-comment lines after the first `skip`: (1-based line, the
/// line's text, or a sheet row's cells).
pub(super) enum Line {
    Text(usize, String),
    Cells(usize, Vec<String>),
}

/// The lines of `rows` to read, in order.
pub(super) fn lines<'a>(
    name: &'a str,
    rows: Rows<'a>,
    skip: usize,
) -> Box<dyn Iterator<Item = Result<Line, ImportError>> + 'a> {
    match rows {
        Rows::Text(reader) => Box::new(reader.split(b'\n').enumerate().filter_map(
            move |(i, bytes)| {
                let lineno = i + 1;
                let bytes = match bytes {
                    Ok(b) => b,
                    Err(e) => return Some(Err(ImportError::at(name, Some(lineno), K::Read(e)))),
                };
                if bytes.contains(&0) {
                    return Some(Err(ImportError::at(name, Some(lineno), K::Binary)));
                }
                // Not UTF-8 (a Windows code page's °, µ or umlaut in a header): the text
                // around them is kept.
                let text = String::from_utf8_lossy(&bytes);
                let t = text.trim();
                (i >= skip && !t.is_empty() && !t.starts_with('#'))
                    .then(|| Ok(Line::Text(lineno, t.to_string())))
            },
        )),
        Rows::Sheet(rows) => Box::new(rows.into_iter().enumerate().filter_map(
            move |(i, (row, cells))| {
                let blank = cells.iter().all(|c| c.is_empty());
                let comment = cells.first().is_some_and(|c| c.starts_with('#'));
                (i >= skip && !blank && !comment).then_some(Ok(Line::Cells(row, cells)))
            },
        )),
    }
}
