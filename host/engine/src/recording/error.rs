//! What can be wrong with a recording, and where: [`RecordingError`] names the file, the
//! line and the problem ([`RecordingErrorKind`]); a bad metadata value or combination is a
//! [`MetadataError`], naming the key.

use std::fmt;
use std::io;

use rotacal_shared::Condition;

use super::{COLUMN_NAMES, TICK_HZ_KEY};

/// A problem with a recording: which file, which line (if one applies) and what.
#[derive(Debug)]
pub struct RecordingError {
    /// The path or name of the file.
    pub source_name: String,
    /// 1-based physical line in the file, counting comment and blank lines.
    pub line: Option<u64>,
    /// 0-based row of a recording held as columns in memory (no file, so no line).
    pub row: Option<u64>,
    /// The problem.
    pub kind: RecordingErrorKind,
}

impl fmt::Display for RecordingError {
    /// `FILE:LINE: problem`, `SOURCE: row N: problem` for columns held in memory, or
    /// `FILE: problem` when no place applies.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match (self.line, self.row) {
            (Some(line), _) => write!(f, "{}:{}: {}", self.source_name, line, self.kind),
            (None, Some(row)) => write!(f, "{}: row {}: {}", self.source_name, row, self.kind),
            (None, None) => write!(f, "{}: {}", self.source_name, self.kind),
        }
    }
}

impl std::error::Error for RecordingError {}

/// What is wrong with a recording.
#[derive(Debug)]
pub enum RecordingErrorKind {
    /// The file could not be opened or read.
    Io(io::Error),
    /// Nothing but comments and blank lines: no header, no data.
    Empty,
    /// The first line that is not a comment names none of the known columns.
    NoHeader,
    /// A header but no data rows.
    NoData,
    /// A required column is absent from the header.
    MissingColumn(&'static str),
    /// A required column is absent, but a column differing only in case is there (names
    /// are case-sensitive).
    WrongCaseColumn {
        /// The name formats.md defines.
        expected: &'static str,
        /// The name found in the header.
        found: String,
    },
    /// A known column appears twice in the header.
    DuplicateColumn(String),
    /// Lines end in a bare carriage return (old Mac line endings).
    BadLineEndings,
    /// A `# key=value` line with a bad value for a known key, a known key given twice, or
    /// columns the metadata or one another rule out.
    BadMetadata(MetadataError),
    /// A row with a different number of fields than the header.
    WrongFieldCount {
        /// Fields in the header.
        expected: usize,
        /// Fields in the row.
        got: usize,
    },
    /// A condition other than `x`, `y` or `z`.
    UnknownCondition(String),
    /// A field that is not a number.
    NotANumber {
        /// The column.
        column: &'static str,
        /// The field (possibly shortened).
        text: String,
    },
    /// Columns held in memory: one with another length than the first.
    ColumnLength {
        /// The column.
        column: String,
        /// The first column's length.
        expected: usize,
        /// This one's.
        got: usize,
    },
    /// Metadata given with a recording held in memory: a key or value with a line break
    /// (a file's `# key=value` line could not hold it).
    MetadataLineBreak {
        /// The key.
        key: String,
    },
    /// NaN or an infinity (including a number too large for f64).
    NotFinite {
        /// The column.
        column: &'static str,
    },
    /// A field that must be a non-negative integer (`seq`) and is not.
    NotAnInteger {
        /// The column.
        column: &'static str,
        /// The field (possibly shortened).
        text: String,
    },
    /// A field that must be positive (`rate_hz`) and is not.
    NotPositive {
        /// The column.
        column: &'static str,
        /// The value.
        value: f64,
    },
    /// A free recording: `t_s` decreased.
    TimeWentBackwardsFree {
        /// The previous row's time.
        previous: f64,
        /// This row's time.
        got: f64,
    },
    /// Rotation: `t_s` decreased within one (condition, rate) group.
    TimeWentBackwards {
        /// The group's condition.
        condition: Condition,
        /// The group's rate (`None`: no `rate_hz` column).
        rate_hz: Option<f64>,
        /// The group's previous time.
        previous: f64,
        /// This row's time.
        got: f64,
    },
    /// Rotation: `boot` decreased within one condition's rows.
    BootWentBackwards {
        /// The group's condition.
        condition: Condition,
        /// The previous row's boot.
        previous: u32,
        /// This row's.
        got: u32,
    },
    /// `gx, gy, gz` that are not a unit vector.
    NotUnitVector {
        /// Their length.
        norm: f64,
    },
    /// A `pose` field that is empty or not UTF-8 text.
    BadPose(&'static str),
    /// The file has `gx, gy, gz` columns, which only static calibration and `apply` use.
    NeedsConditions(String),
    /// The file is a free recording (no conditions, no orientations).
    NeedsConditionsFree(String),
    /// A `conv_gaps` field that is not a list of up to six tick counts from 1 to 65535.
    BadConversions(String),
    /// A `conv_missed` field that is neither empty nor a whole number from 0 to 7.
    BadMissed(String),
    /// A condition has no rows (at some rate, for a multi-rate file).
    MissingCondition {
        /// The missing condition.
        condition: Condition,
        /// The rate it is missing at (`None`: no `rate_hz` column, or static).
        rate_hz: Option<f64>,
    },
}

fn rate_suffix(rate_hz: Option<f64>) -> String {
    match rate_hz {
        Some(r) => format!(" at rate_hz={r}"),
        None => String::new(),
    }
}

impl RecordingErrorKind {
    /// The column the problem is in, where it is in one.
    pub fn column(&self) -> Option<&str> {
        use RecordingErrorKind as K;
        match self {
            K::MissingColumn(c)
            | K::NotANumber { column: c, .. }
            | K::NotFinite { column: c }
            | K::NotAnInteger { column: c, .. }
            | K::NotPositive { column: c, .. } => Some(c),
            K::WrongCaseColumn { expected, .. } => Some(expected),
            K::ColumnLength { column, .. } => Some(column),
            K::UnknownCondition(_) => Some("condition"),
            K::TimeWentBackwards { .. } | K::TimeWentBackwardsFree { .. } => Some("t_s"),
            _ => None,
        }
    }
}

impl fmt::Display for RecordingErrorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        use RecordingErrorKind as K;
        match self {
            K::Io(e) => write!(f, "cannot read: {e}"),
            K::Empty => f.write_str(
                "empty recording: no header line and no data (only comments or blank lines)",
            ),
            K::NoHeader => write!(
                f,
                "no header line: the first line that is not a comment names none of the \
                 columns {}",
                COLUMN_NAMES.join(", ")
            ),
            K::NoData => f.write_str("no data rows after the header"),
            K::MissingColumn(c) => {
                write!(f, "missing column '{c}'")?;
                match *c {
                    "condition" => f.write_str(
                        " (or, for still poses of unknown orientation, '# method=free' or \
                         --method free)",
                    ),
                    "t_s" => f.write_str(" (method rotation and method free need it)"),
                    "angle_deg" => f.write_str(
                        " (method static needs it; without a t_s column the method is static)",
                    ),
                    _ => Ok(()),
                }
            }
            K::WrongCaseColumn { expected, found } => write!(
                f,
                "missing column '{expected}': found '{found}', but column names are \
                 case-sensitive"
            ),
            K::DuplicateColumn(c) => write!(f, "column '{c}' appears twice in the header"),
            K::BadLineEndings => {
                f.write_str("lines end in a bare carriage return (CR); use LF or CRLF line endings")
            }
            K::BadMetadata(m) => write!(f, "bad metadata: {m}"),
            K::WrongFieldCount { expected, got } => {
                write!(
                    f,
                    "wrong number of fields: {got}, but the header has {expected}"
                )
            }
            K::UnknownCondition(c) => {
                write!(f, "unknown condition '{c}' (expected x, y or z)")
            }
            K::NotANumber { column, text } => {
                write!(f, "column {column}: '{text}' is not a number")
            }
            K::ColumnLength {
                column,
                expected,
                got,
            } => write!(
                f,
                "column {column}: {got} values, but the first column has {expected}"
            ),
            K::MetadataLineBreak { key } => {
                write!(
                    f,
                    "metadata '{key}': a key or value may not hold a line break"
                )
            }
            K::NotFinite { column } => {
                write!(f, "column {column}: value is not finite (NaN or infinity)")
            }
            K::NotAnInteger { column, text } => {
                write!(f, "column {column}: '{text}' is not a non-negative integer")
            }
            K::NotPositive { column, value } => {
                write!(f, "column {column}: {value} is not positive")
            }
            K::TimeWentBackwards {
                condition,
                rate_hz,
                previous,
                got,
            } => write!(
                f,
                "time went backwards in condition {}{}: t_s={got} after t_s={previous}",
                condition.letter(),
                rate_suffix(*rate_hz)
            ),
            K::BootWentBackwards {
                condition,
                previous,
                got,
            } => write!(
                f,
                "boot went backwards in condition {}: {got} after {previous} (a condition's \
                 boots follow each other in the file)",
                condition.letter()
            ),
            K::TimeWentBackwardsFree { previous, got } => {
                write!(f, "time went backwards: t_s={got} after t_s={previous}")
            }
            K::NotUnitVector { norm } => write!(
                f,
                "gx, gy, gz must be a unit vector (the direction of gravity's reading); its \
                 length is {norm}"
            ),
            K::BadPose(why) => write!(f, "column pose: {why}"),
            K::BadConversions(what) => write!(f, "conv_gaps {what}"),
            K::BadMissed(text) => write!(
                f,
                "conv_missed {text:?}: expected a whole number of conversions from 0 to 7, \
                 or nothing"
            ),
            K::NeedsConditions(what) => write!(
                f,
                "{what} needs conditions x, y, z; this file gives gravity directions (gx, gy, \
                 gz columns), which only static calibration and apply use"
            ),
            K::NeedsConditionsFree(what) => write!(
                f,
                "{what} needs conditions x, y, z; this file is a free recording (method free: \
                 still poses of unknown orientation), which only 'calibrate --method free' and \
                 apply use"
            ),
            K::MissingCondition { condition, rate_hz } => write!(
                f,
                "condition {} missing: no rows for it{} (need all of x, y, z)",
                condition.letter(),
                rate_suffix(*rate_hz)
            ),
        }
    }
}

/// What is wrong with the metadata: the key (or column) and the value.
#[derive(Debug, Clone, PartialEq)]
pub enum MetadataError {
    /// `method` names none of the methods.
    Method(UnknownMethod),
    /// A numeric key's value is not a number.
    NotANumber {
        /// The key.
        key: &'static str,
        /// The value (possibly shortened).
        text: String,
    },
    /// A numeric key's value is NaN or an infinity.
    NotFinite {
        /// The key.
        key: &'static str,
        /// The value.
        value: f64,
    },
    /// A key that must be ≥ 0 (`noise_sigma`) is negative.
    Negative {
        /// The key.
        key: &'static str,
        /// The value.
        value: f64,
    },
    /// A key that must be positive (`rate_hz`, `g_loc`, `sample_rate_hz`) is not.
    NotPositive {
        /// The key.
        key: &'static str,
        /// The value.
        value: f64,
    },
    /// An uncertainty key (`u_g_loc` and the like) that is not a finite number ≥ 0.
    NotUncertainty {
        /// The key.
        key: &'static str,
        /// The value.
        value: f64,
    },
    /// A key given twice with different values.
    Twice {
        /// The key.
        key: &'static str,
        /// 1-based line of its first value.
        first_line: u64,
    },
    /// `angle_deg` or `rate_hz` beside `gx, gy, gz`.
    ReplacedByGravity {
        /// The column.
        column: &'static str,
    },
    /// A `conv_gaps` column without a `tick_hz` to count its ticks in.
    NoTickRate,
    /// `method=rotation` in a file with `gx, gy, gz` columns.
    RotationWithGravity,
}

impl fmt::Display for MetadataError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        use MetadataError as M;
        match self {
            M::Method(e) => write!(f, "method: {e}"),
            M::NotANumber { key, text } => write!(f, "{key}: '{text}' is not a number"),
            M::NotFinite { key, value } => write!(f, "{key}: {value} is not finite"),
            M::Negative { key, value } => write!(f, "{key}: {value} is negative"),
            M::NotPositive { key, value } => write!(f, "{key}: {value} is not positive"),
            M::NotUncertainty { key, value } => write!(
                f,
                "{key}: {value} is not a standard uncertainty (a finite number ≥ 0)"
            ),
            M::Twice { key, first_line } => write!(
                f,
                "{key} given twice with different values (first on line {first_line})"
            ),
            M::ReplacedByGravity { column } => write!(
                f,
                "column {column} with gx, gy, gz: the gravity direction replaces it"
            ),
            M::NoTickRate => write!(
                f,
                "column conv_gaps counts device ticks: it needs '# {TICK_HZ_KEY}=<ticks per \
                 second>' (a positive integer)"
            ),
            M::RotationWithGravity => {
                f.write_str("method rotation, but the file has gx, gy, gz columns (static poses)")
            }
        }
    }
}

impl std::error::Error for MetadataError {}

/// A method name that is none of `rotation`, `static` and `free`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UnknownMethod {
    /// The name given (trimmed, possibly shortened).
    pub text: String,
}

impl fmt::Display for UnknownMethod {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "expected 'rotation' or 'static', got '{}' (or 'free': still poses of unknown \
             orientation)",
            self.text
        )
    }
}

impl std::error::Error for UnknownMethod {}
