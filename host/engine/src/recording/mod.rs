//! The recording CSV (`../shared/docs/formats.md`, "Recording CSV"): reader and writer.
//!
//! A recording is an optional preamble of `#` comment lines, some of them `# key=value`
//! metadata, then a header line and one row per sample:
//!
//! ```text
//! # rotacal recording v1
//! # method=rotation
//! # rate_hz=0.01
//! condition,t_s,u,v,w,temp_c
//! x,0.0,-12.0,16377.0,-231.0,24.91
//! ```
//!
//! [`read`] / [`read_from`] stream the file through the `csv` crate, reusing one
//! [`csv::ByteRecord`] and parsing numbers straight from its bytes, and keep only the
//! numeric columns, grouped by (condition, nominal rate) for rotation and by condition for
//! static files. Every problem is a [`RecordingError`] whose message names the file, the
//! 1-based physical line (comment and blank lines count) and the problem; no input makes
//! the reader panic.
//!
//! [`Writer`] writes files that the reader reads back exactly (floats are written with
//! the shortest representation that reads back exactly, by ryu).
//!
//! How rows get here: [`from_device`] (the device's packets and fit reports) and
//! [`import`] (other tools' text logs).
//!
//! Extensions to formats.md, all of them lenient:
//! - upper-case conditions (`X`, `Y`, `Z`) are accepted;
//! - spaces around fields and column names are ignored, and so is a UTF-8 byte-order mark;
//! - blank lines (also whitespace-only ones) are skipped anywhere;
//! - `#` lines after the header are comments too (ignored, not metadata);
//! - unknown columns are ignored; LF and CRLF line endings are both accepted.
//!
//! Checks beyond formats.md: the rate (`rate_hz` metadata or column), `g_loc` and
//! `sample_rate_hz` must be positive, `noise_sigma` non-negative; a known metadata key given
//! twice with different values is an error; `seq` must be a non-negative integer; the
//! uncertainty keys `u_g_loc`, `u_time_s` and `u_angle_deg` must be numbers ≥ 0.

pub mod from_device;
pub mod import;

use std::collections::BTreeMap;
use std::fmt;
use std::fs::File;
use std::io::{self, BufRead, BufReader, BufWriter, Read, Write};
use std::path::Path;

use rotacal_shared::{Aperture, Condition, Ticks, MAX_CONVERSIONS};

/// How the data were taken (formats.md `method`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Constant rotation (seed 000): rows carry device time `t_s`.
    Rotation,
    /// Static steps (seed 001): rows carry the table angle `angle_deg`.
    Static,
    /// Still poses of unknown orientation (docs/formats.md): the poses are found in the
    /// readings (`t_s`), and only |a| = g is used.
    Free,
}

impl Method {
    /// `rotation` or `static`, as in files.
    pub const fn as_str(self) -> &'static str {
        match self {
            Method::Rotation => "rotation",
            Method::Static => "static",
            Method::Free => "free",
        }
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for Method {
    type Err = String;
    /// `rotation`, `static` or `free` (any case, surrounding spaces ignored).
    fn from_str(s: &str) -> Result<Self, String> {
        let t = s.trim();
        if t.eq_ignore_ascii_case("rotation") {
            Ok(Method::Rotation)
        } else if t.eq_ignore_ascii_case("static") {
            Ok(Method::Static)
        } else if t.eq_ignore_ascii_case("free") {
            Ok(Method::Free)
        } else {
            Err(format!(
                "expected 'rotation' or 'static', got '{}' (or 'free': still poses of unknown \
                 orientation)",
                snippet(t.as_bytes())
            ))
        }
    }
}

/// The `# key=value` lines before the header. Command-line flags override these.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Metadata {
    /// `method`.
    pub method: Option<Method>,
    /// `rate_hz`: nominal rotation rate (positive).
    pub rate_hz: Option<f64>,
    /// `g_loc`: local gravity in m/s² (positive).
    pub g_loc: Option<f64>,
    /// `units`: free text, e.g. `counts` or `V`.
    pub units: Option<String>,
    /// `sample_rate_hz` (positive).
    pub sample_rate_hz: Option<f64>,
    /// `noise_sigma`: white-noise standard deviation per sample, output units (≥ 0).
    pub noise_sigma: Option<f64>,
    /// `device`: free text.
    pub device: Option<String>,
    /// Unknown keys, kept as read (values trimmed).
    pub other: BTreeMap<String, String>,
}

/// The metadata keys that formats.md defines, in the order the writer puts them.
pub const KNOWN_KEYS: [&str; 7] = [
    "method",
    "rate_hz",
    "g_loc",
    "units",
    "sample_rate_hz",
    "noise_sigma",
    "device",
];

/// Metadata keys rotacal adds (docs/formats.md): standard uncertainties of type-B inputs,
/// checked when read (a finite number ≥ 0) and kept with the other keys.
/// `u_g_loc` (m/s²), `u_time_s` (each timestamp, seconds, beyond its resolution: jitter),
/// `u_angle_deg` (each stepped table angle, degrees).
pub const UNCERTAINTY_KEYS: [&str; 3] = ["u_g_loc", "u_time_s", "u_angle_deg"];

impl Metadata {
    /// One of [`UNCERTAINTY_KEYS`], as checked when read.
    pub fn uncertainty(&self, key: &str) -> Option<f64> {
        self.other.get(key).and_then(|v| v.parse().ok())
    }
}

/// The rows of a file with `gx, gy, gz` columns (static data from any known orientations):
/// each row carries the direction of gravity's reading in the platter frame, and no
/// condition is needed. Poses are named by the `pose` column, or else by their direction.
#[derive(Clone, Debug, PartialEq)]
pub struct Oriented {
    /// ĝ of each row: a unit vector in the platter frame (normalised when read).
    pub gravity: Vec<[f64; 3]>,
    /// The `pose` column, if the file has one.
    pub pose: Option<Vec<String>>,
    /// Readings u, v, w of each row, output units.
    pub y: Vec<[f64; 3]>,
    /// `t_s` of each row, if the file has that column.
    pub t_s: Option<Vec<f64>>,
    /// `seq` of each row, if the file has that column.
    pub seq: Option<Vec<u64>>,
    /// `temp_c` of each row, if the file has that column.
    pub temp_c: Option<Vec<f64>>,
    /// `u_unc, v_unc, w_unc` of each row, if the file has them.
    pub unc: Option<Vec<[f64; 3]>>,
    /// 1-based file line of each row (for messages).
    pub line: Vec<u64>,
}

/// The rows of a recording without conditions or orientations (`# method=free`): a
/// continuous record in which the device was held still in several orientations.
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    /// Device time of each row, s (non-decreasing).
    pub t_s: Vec<f64>,
    /// Readings u, v, w of each row, output units.
    pub y: Vec<[f64; 3]>,
    /// The `pose` column, if the file has one: the poses are then these names, not found.
    pub pose: Option<Vec<String>>,
    /// `seq` of each row, if the file has that column.
    pub seq: Option<Vec<u64>>,
    /// `temp_c` of each row, if the file has that column.
    pub temp_c: Option<Vec<f64>>,
    /// 1-based file line of each row (for messages).
    pub line: Vec<u64>,
}

/// All rows of one condition (and, for rotation, one nominal rate), in file order.
#[derive(Clone, Debug, PartialEq)]
pub struct Group {
    /// The platter axis of rotation.
    pub condition: Condition,
    /// The rows' `rate_hz` column, or `None` when the file has none (then the metadata or
    /// command-line rate applies). Always `None` for static files.
    pub rate_hz: Option<f64>,
    /// Device time in seconds; empty when the file has no `t_s` column (static files).
    pub t_s: Vec<f64>,
    /// Table angle in degrees; empty when the file has no `angle_deg` column.
    pub angle_deg: Vec<f64>,
    /// Channel U, output units.
    pub u: Vec<f64>,
    /// Channel V, output units.
    pub v: Vec<f64>,
    /// Channel W, output units.
    pub w: Vec<f64>,
    /// `seq` column, if the file has one.
    pub seq: Option<Vec<u64>>,
    /// `temp_c` column, if the file has one.
    pub temp_c: Option<Vec<f64>>,
    /// `u_unc, v_unc, w_unc` columns (written by `rotacal apply`), if the file has them.
    pub unc: Option<Vec<[f64; 3]>>,
    /// `conv_gaps` column, if the file has one: the conversions each row averages, in
    /// device ticks (`tick_hz`) with the first at tick 0 (it is `t_s`).
    pub conversions: Option<Vec<Aperture>>,
    /// 1-based file line of the group's first row (for messages).
    pub first_line: u64,
}

impl Group {
    fn new(condition: Condition, rate_hz: Option<f64>, cols: &ColumnIndex, line: u64) -> Self {
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
            first_line: line,
        }
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.u.len()
    }

    /// Row `i`'s conversions with the first at `first`, their gaps counted in a clock
    /// `scale` times as fast as the file's `tick_hz` (1 for the file's own ticks): one
    /// conversion without a `conv_gaps` column. `None` when a scaled gap leaves 1 to 65535.
    pub fn aperture(&self, i: usize, first: Ticks, scale: f64) -> Option<Aperture> {
        scaled_aperture(
            first,
            self.conversions.as_ref().and_then(|c| c.get(i)),
            scale,
        )
    }

    /// True if the group has no rows (never the case for a group the reader returns).
    pub fn is_empty(&self) -> bool {
        self.u.is_empty()
    }
}

/// A whole recording, read and checked.
#[derive(Clone, Debug, PartialEq)]
pub struct Recording {
    /// The path or name used in messages.
    pub source: String,
    /// The preamble's metadata.
    pub meta: Metadata,
    /// The method: the metadata's, else rotation if there is a `t_s` column, else static.
    pub method: Method,
    /// The groups, in order of first appearance in the file (empty when the file has
    /// `gx, gy, gz` columns: then its rows are in `oriented`).
    pub groups: Vec<Group>,
    /// The rows of a file with `gx, gy, gz` columns.
    pub oriented: Option<Oriented>,
    /// The rows of a file with neither conditions nor orientations (`method=free`).
    pub series: Option<Series>,
}

impl Recording {
    /// The distinct nominal rates of the groups, in order of first appearance (`[None]`
    /// for a single-rate file or a static file).
    pub fn rates(&self) -> Vec<Option<f64>> {
        let mut out: Vec<Option<f64>> = Vec::new();
        for g in &self.groups {
            if !out.iter().any(|r| same_rate(*r, g.rate_hz)) {
                out.push(g.rate_hz);
            }
        }
        out
    }

    /// The group of `condition` at `rate_hz` (`None` for single-rate and static files).
    pub fn group(&self, condition: Condition, rate_hz: Option<f64>) -> Option<&Group> {
        self.groups
            .iter()
            .find(|g| g.condition == condition && same_rate(g.rate_hz, rate_hz))
    }

    /// The nominal rate that applies to `group`: its `rate_hz` column, else the metadata's
    /// (command-line flags, which override both, are the caller's business).
    pub fn nominal_rate(&self, group: &Group) -> Option<f64> {
        group.rate_hz.or(self.meta.rate_hz)
    }

    /// Total number of data rows.
    pub fn rows(&self) -> usize {
        self.groups.iter().map(Group::len).sum::<usize>()
            + self.oriented.as_ref().map_or(0, |o| o.y.len())
            + self.series.as_ref().map_or(0, |s| s.y.len())
    }

    /// An error unless the file has conditions (rotation, or static with `angle_deg`):
    /// for the commands that need them. `what` names the command.
    pub fn require_conditions(&self, what: &str) -> Result<(), RecordingError> {
        let kind = match (&self.oriented, &self.series) {
            (Some(_), _) => RecordingErrorKind::NeedsConditions(what.to_string()),
            (None, Some(_)) => RecordingErrorKind::NeedsConditionsFree(what.to_string()),
            (None, None) => return Ok(()),
        };
        Err(RecordingError {
            source_name: self.source.clone(),
            line: None,
            kind,
        })
    }
}

fn same_rate(a: Option<f64>, b: Option<f64>) -> bool {
    a.map(f64::to_bits) == b.map(f64::to_bits)
}

/// A problem with a recording: which file, which line (if one applies) and what.
#[derive(Debug)]
pub struct RecordingError {
    /// The path or name of the file.
    pub source_name: String,
    /// 1-based physical line in the file, counting comment and blank lines.
    pub line: Option<u64>,
    /// The problem.
    pub kind: RecordingErrorKind,
}

impl fmt::Display for RecordingError {
    /// `FILE:LINE: problem`, or `FILE: problem` when no line applies.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.line {
            Some(line) => write!(f, "{}:{}: {}", self.source_name, line, self.kind),
            None => write!(f, "{}: {}", self.source_name, self.kind),
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
    /// A `# key=value` line with a bad value for a known key, or a known key given twice.
    BadMetadata(String),
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

/// The column names formats.md defines.
pub const COLUMN_NAMES: [&str; 17] = [
    "condition",
    "t_s",
    "angle_deg",
    "u",
    "v",
    "w",
    "seq",
    "temp_c",
    "rate_hz",
    "gx",
    "gy",
    "gz",
    "pose",
    "u_unc",
    "v_unc",
    "w_unc",
    "conv_gaps",
];

/// The metadata key giving the device clock's ticks per second, which `conv_gaps` counts
/// (a positive integer; required with that column).
pub const TICK_HZ_KEY: &str = "tick_hz";

/// How far |(gx, gy, gz)| may be from 1 (rounding of written unit vectors).
pub const UNIT_TOLERANCE: f64 = 1e-3;

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
    let parser = || Parser {
        source: &source,
        complete,
        line_offset: 0,
        method,
    };
    let mut groups: Vec<Group> = Vec::new();
    if let Some(Some(mut rec)) = parser().run_fast(open(path)?, &mut groups, false, Parse::All)? {
        shrink(&mut groups);
        rec.groups = groups;
        return Ok(rec);
    }
    parser().run(open(path)?)
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
        self.push(Group::new(condition, rate_hz, cols, line));
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
        kind: RecordingErrorKind::Io(e),
    })
}

/// Puts the rows of a file with conditions into their groups, with the checks that span
/// rows: a group per (condition, nominal rate) in order of first appearance; rotation
/// rows do not go back in time within a group; every rate has all three conditions.
struct Router {
    rotation: bool,
    /// Each group's (condition, rate bits), and the time of its last row.
    keys: Vec<(Condition, Option<u64>)>,
    last_t: Vec<Option<f64>>,
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
                        self.last_t.push(None);
                        self.keys.len() - 1
                    }
                };
                self.last = Some((row.condition, key, i));
                i
            }
        };
        if let (Some(t), Some(prev)) = (row.t_s, self.last_t.get_mut(gi)) {
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
struct Head<R> {
    meta: Metadata,
    cols: ColumnIndex,
    method: Method,
    /// At the first line after the header.
    reader: BufReader<Counted<R>>,
    /// The header's line number.
    line: u64,
    /// The byte offset of the line after the header.
    offset: u64,
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
fn fast_rows<R: Read>(
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
            Plain::Gaps | Plain::Skip => {
                let len = field_end(rest);
                if *part == Plain::Gaps {
                    row.conv_gaps = Some(parse_gaps(rest.get(..len)?.trim_ascii()).ok()?);
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

/// A record's fields, from the csv reader or from the fast line reader.
trait Fields {
    /// Field `i`, untrimmed (`None` past the last).
    fn raw(&self, i: usize) -> Option<&[u8]>;
}

impl Fields for csv::ByteRecord {
    fn raw(&self, i: usize) -> Option<&[u8]> {
        self.get(i)
    }
}

/// A line split at its commas: the fast reader's record.
struct SplitLine<'a> {
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

    /// The header's line number: the first part's lines follow it.
    pub fn header_line(&self) -> u64 {
        self.line
    }

    /// The data cut into `n` byte ranges of about equal size, each from a line's start.
    pub fn split(&self, n: usize) -> Result<Vec<(u64, u64)>, RecordingError> {
        let io = |e: io::Error| RecordingError {
            source_name: self.path.display().to_string(),
            line: None,
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

/// Where each known column is in the header.
#[derive(Debug)]
struct ColumnIndex {
    n: usize,
    /// Absent only in files with `gx, gy, gz`.
    condition: Option<usize>,
    /// `gx, gy, gz`: all three or none.
    gravity: Option<[usize; 3]>,
    pose: Option<usize>,
    /// `u_unc, v_unc, w_unc`: all three or none.
    unc: Option<[usize; 3]>,
    u: usize,
    v: usize,
    w: usize,
    t_s: Option<usize>,
    angle_deg: Option<usize>,
    seq: Option<usize>,
    temp_c: Option<usize>,
    rate_hz: Option<usize>,
    conv_gaps: Option<usize>,
}

struct Parser<'a> {
    source: &'a str,
    /// Require all three conditions for every rate.
    complete: bool,
    /// Physical lines consumed before the csv reader took over.
    line_offset: u64,
    /// The method to read as, overriding the file's (a command line's `--method`).
    method: Option<Method>,
}

type Res<T> = Result<T, RecordingError>;

impl Parser<'_> {
    fn err(&self, line: Option<u64>, kind: RecordingErrorKind) -> RecordingError {
        RecordingError {
            source_name: self.source.to_string(),
            line,
            kind,
        }
    }

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

    fn run<R: Read>(mut self, reader: R) -> Res<Recording> {
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
    fn run_into<R: Read, S: GroupSink>(
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
        let mut series = free.then(|| Series {
            t_s: Vec::new(),
            y: Vec::new(),
            pose: cols.pose.map(|_| Vec::new()),
            seq: cols.seq.map(|_| Vec::new()),
            temp_c: cols.temp_c.map(|_| Vec::new()),
            line: Vec::new(),
        });
        let mut oriented = cols.gravity.map(|_| Oriented {
            gravity: Vec::new(),
            pose: cols.pose.map(|_| Vec::new()),
            y: Vec::new(),
            t_s: cols.t_s.map(|_| Vec::new()),
            seq: cols.seq.map(|_| Vec::new()),
            temp_c: cols.temp_c.map(|_| Vec::new()),
            unc: cols.unc.map(|_| Vec::new()),
            line: Vec::new(),
        });
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
            let row = match parse_row(&rec, &cols, Parse::All) {
                Ok(row) => row,
                Err(kind) => return Err(self.err(Some(self.line_of(&rdr, &rec)), kind)),
            };
            if let (Some(o), Some(g)) = (oriented.as_mut(), row.gravity) {
                o.gravity.push(g);
                o.y.push([row.u, row.v, row.w]);
                o.line.push(self.line_of(&rdr, &rec));
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
                continue;
            }
            if let Some(s) = series.as_mut() {
                let line = self.line_of(&rdr, &rec);
                let t = row.t_s.unwrap_or(f64::NAN);
                if let Some(&prev) = s.t_s.last() {
                    if t < prev {
                        return Err(self.err(
                            Some(line),
                            RecordingErrorKind::TimeWentBackwardsFree {
                                previous: prev,
                                got: t,
                            },
                        ));
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
                continue;
            }
            let line = self.line_of(&rdr, &rec);
            router
                .route(&row, line, &cols, sink)
                .map_err(|kind| self.err(Some(line), kind))?;
        }

        // Poses or a continuous series, when read as such, are the recording.
        let series = series.filter(|_| oriented.is_none());
        let rows = oriented
            .as_ref()
            .map(|o| o.y.len())
            .or(series.as_ref().map(|s| s.y.len()));
        if let Some(n) = rows {
            if n == 0 {
                return Err(self.err(None, RecordingErrorKind::NoData));
            }
            return Ok(Some(Recording {
                source: self.source.to_string(),
                meta,
                method,
                groups: Vec::new(),
                oriented,
                series,
            }));
        }
        router
            .finish(self.complete)
            .map_err(|kind| self.err(None, kind))?;
        Ok(Some(self.without_rows(meta, method)))
    }

    /// The recording of a file with conditions whose rows went to a sink.
    fn without_rows(&self, meta: Metadata, method: Method) -> Recording {
        Recording {
            source: self.source.to_string(),
            meta,
            method,
            groups: Vec::new(),
            oriented: None,
            series: None,
        }
    }

    /// The fast reader: lines split at their commas, for files without quotes. It gives
    /// exactly what [`Parser::run_into`] gives (the same preamble, header and row
    /// functions, on the same fields); on anything it does not handle (a quote, a
    /// comment after the header, any problem in a row) it stops with `Ok(None)`, and the
    /// caller reads the file again with the csv reader, which names the problem.
    fn run_fast<R: Read, S: GroupSink>(
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
    fn fast_head<R: Read>(&mut self, reader: R) -> Res<Option<Head<R>>> {
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

    fn next<R: Read>(&self, rdr: &mut csv::Reader<R>, rec: &mut csv::ByteRecord) -> Res<bool> {
        rdr.read_byte_record(rec).map_err(|e| {
            let kind = match e.into_kind() {
                csv::ErrorKind::Io(io) => io,
                other => io::Error::other(format!("{other:?}")),
            };
            self.err(None, RecordingErrorKind::Io(kind))
        })
    }

    /// Read the `#` and blank lines before the header, leaving the reader at the header.
    fn preamble<R: BufRead>(&mut self, br: &mut R) -> Res<Metadata> {
        let io_err = |s: &Self, e: io::Error| s.err(None, RecordingErrorKind::Io(e));
        // A UTF-8 byte-order mark.
        {
            let buf = br.fill_buf().map_err(|e| io_err(self, e))?;
            if buf.starts_with(b"\xEF\xBB\xBF") {
                br.consume(3);
            }
        }
        let mut meta = Metadata::default();
        // Line of each known key, for duplicate messages.
        let mut seen: BTreeMap<&'static str, u64> = BTreeMap::new();
        let mut line = Vec::new();
        loop {
            let buf = br.fill_buf().map_err(|e| io_err(self, e))?;
            let first = buf.iter().find(|&&b| !matches!(b, b' ' | b'\t' | b'\r'));
            let comment = match first {
                Some(b'#') => true,
                Some(b'\n') => false,
                // The header (or a whitespace-only buffer: the csv stage skips blank lines).
                _ => break,
            };
            line.clear();
            br.read_until(b'\n', &mut line)
                .map_err(|e| io_err(self, e))?;
            self.line_offset += 1;
            let body = line.strip_suffix(b"\n").unwrap_or(&line);
            let body = body.strip_suffix(b"\r").unwrap_or(body);
            if body.contains(&b'\r') {
                let kind = RecordingErrorKind::BadLineEndings;
                return Err(self.err(Some(self.line_offset), kind));
            }
            if comment {
                self.metadata_line(&line, &mut meta, &mut seen)?;
            }
        }
        Ok(meta)
    }

    fn metadata_line(
        &self,
        raw: &[u8],
        meta: &mut Metadata,
        seen: &mut BTreeMap<&'static str, u64>,
    ) -> Res<()> {
        let lineno = self.line_offset;
        let text = String::from_utf8_lossy(raw);
        let Some(body) = text.trim().strip_prefix('#') else {
            return Ok(());
        };
        let Some((key, value)) = body.split_once('=') else {
            return Ok(());
        };
        let (key, value) = (key.trim(), value.trim());
        if !is_key(key) {
            return Ok(()); // a plain comment that happens to hold '='
        }
        let bad = |m: String| self.err(Some(lineno), RecordingErrorKind::BadMetadata(m));
        let Some(&known) = KNOWN_KEYS.iter().find(|k| **k == key) else {
            if let Some(&ukey) = UNCERTAINTY_KEYS.iter().find(|k| **k == key) {
                if let (Some(&first), Some(before)) = (seen.get(ukey), meta.other.get(ukey)) {
                    if before != value {
                        return Err(bad(format!(
                            "{key} given twice with different values (first on line {first})"
                        )));
                    }
                }
                seen.insert(ukey, lineno);
                let x: f64 = value.parse().map_err(|_| {
                    bad(format!(
                        "{key}: '{}' is not a number",
                        snippet(value.as_bytes())
                    ))
                })?;
                if !(x.is_finite() && x >= 0.0) {
                    return Err(bad(format!(
                        "{key}: {x} is not a standard uncertainty (a finite number ≥ 0)"
                    )));
                }
            }
            meta.other.insert(key.to_string(), value.to_string());
            return Ok(());
        };
        let before = meta.clone();
        match known {
            "method" => {
                meta.method = Some(
                    value
                        .parse::<Method>()
                        .map_err(|m| bad(format!("method: {m}")))?,
                )
            }
            "units" => meta.units = Some(value.to_string()),
            "device" => meta.device = Some(value.to_string()),
            _ => {
                let x: f64 = value.parse().map_err(|_| {
                    bad(format!(
                        "{known}: '{}' is not a number",
                        snippet(value.as_bytes())
                    ))
                })?;
                check_meta_number(known, x).map_err(bad)?;
                match known {
                    "rate_hz" => meta.rate_hz = Some(x),
                    "g_loc" => meta.g_loc = Some(x),
                    "sample_rate_hz" => meta.sample_rate_hz = Some(x),
                    _ => meta.noise_sigma = Some(x),
                }
            }
        }
        if let Some(&first) = seen.get(known) {
            if before != *meta {
                return Err(bad(format!(
                    "{known} given twice with different values (first on line {first})"
                )));
            }
        } else {
            seen.insert(known, lineno);
        }
        Ok(())
    }

    fn header(
        &self,
        rec: &csv::ByteRecord,
        line: u64,
        meta: &Metadata,
    ) -> Res<(ColumnIndex, Method)> {
        let at = |kind| self.err(Some(line), kind);
        let names: Vec<String> = rec
            .iter()
            .map(|f| String::from_utf8_lossy(f.trim_ascii()).into_owned())
            .collect();
        if names.iter().any(|n| n.contains('\r')) {
            return Err(at(RecordingErrorKind::BadLineEndings));
        }
        let mut found: [Option<usize>; COLUMN_NAMES.len()] = [None; COLUMN_NAMES.len()];
        for (i, name) in names.iter().enumerate() {
            if let Some(k) = COLUMN_NAMES.iter().position(|c| c == name) {
                if let Some(slot) = found.get_mut(k) {
                    if slot.is_some() {
                        return Err(at(RecordingErrorKind::DuplicateColumn(name.clone())));
                    }
                    *slot = Some(i);
                }
            }
        }
        if found.iter().all(Option::is_none) {
            return Err(at(RecordingErrorKind::NoHeader));
        }
        let idx = |name: &str| {
            COLUMN_NAMES
                .iter()
                .position(|c| *c == name)
                .and_then(|k| found.get(k).copied().flatten())
        };
        let require = |name: &'static str| -> Res<usize> {
            idx(name).ok_or_else(
                || match names.iter().find(|n| n.eq_ignore_ascii_case(name)) {
                    Some(n) => at(RecordingErrorKind::WrongCaseColumn {
                        expected: name,
                        found: n.clone(),
                    }),
                    None => at(RecordingErrorKind::MissingColumn(name)),
                },
            )
        };
        // Gravity directions: all three columns or none.
        let gravity = if ["gx", "gy", "gz"].iter().any(|n| idx(n).is_some()) {
            Some([require("gx")?, require("gy")?, require("gz")?])
        } else {
            None
        };
        let free = self.method.or(meta.method) == Some(Method::Free);
        let condition = match gravity {
            Some(_) => idx("condition"),
            // A free recording needs no condition; one that is there is used (each
            // condition's rows are searched for poses on their own).
            None if free => idx("condition"),
            None => Some(require("condition")?),
        };
        if gravity.is_some() {
            if let Some(c) = ["angle_deg", "rate_hz"].iter().find(|c| idx(c).is_some()) {
                return Err(at(RecordingErrorKind::BadMetadata(format!(
                    "column {c} with gx, gy, gz: the gravity direction replaces it"
                ))));
            }
        }
        let unc = if ["u_unc", "v_unc", "w_unc"].iter().any(|n| idx(n).is_some()) {
            Some([require("u_unc")?, require("v_unc")?, require("w_unc")?])
        } else {
            None
        };
        let u = require("u")?;
        let v = require("v")?;
        let w = require("w")?;
        let t_s = idx("t_s");
        let conv_gaps = idx("conv_gaps");
        if conv_gaps.is_some() && tick_hz(meta).is_none() {
            return Err(at(RecordingErrorKind::BadMetadata(format!(
                "column conv_gaps counts device ticks: it needs '# {TICK_HZ_KEY}=<ticks per \
                 second>' (a positive integer)"
            ))));
        }
        let method = self.method.or(meta.method).unwrap_or(if gravity.is_some() {
            Method::Static
        } else if t_s.is_some() {
            Method::Rotation
        } else {
            Method::Static
        });
        match method {
            Method::Rotation if gravity.is_some() => {
                return Err(at(RecordingErrorKind::BadMetadata(
                    "method rotation, but the file has gx, gy, gz columns (static poses)".into(),
                )));
            }
            Method::Rotation => {
                require("t_s")?;
            }
            Method::Static if gravity.is_none() => {
                require("angle_deg")?;
            }
            Method::Static => {}
            Method::Free if gravity.is_none() && condition.is_none() => {
                require("t_s")?;
            }
            Method::Free => {}
        }
        Ok((
            ColumnIndex {
                n: names.len(),
                condition,
                gravity,
                // A pose name means something only with a gravity direction, or in a free
                // recording (then the names are the poses).
                pose: if gravity.is_some() || (free && condition.is_none()) {
                    idx("pose")
                } else {
                    None
                },
                unc,
                u,
                v,
                w,
                t_s,
                angle_deg: idx("angle_deg"),
                seq: idx("seq"),
                temp_c: idx("temp_c"),
                rate_hz: idx("rate_hz"),
                conv_gaps,
            },
            method,
        ))
    }
}

fn is_key(key: &str) -> bool {
    !key.is_empty()
        && key
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'-' | b'.'))
}

/// Check a known numeric metadata value; the message names the key.
fn check_meta_number(key: &str, x: f64) -> Result<(), String> {
    if !x.is_finite() {
        return Err(format!("{key}: {x} is not finite"));
    }
    match key {
        "noise_sigma" if x < 0.0 => Err(format!("{key}: {x} is negative")),
        "rate_hz" | "g_loc" | "sample_rate_hz" if x <= 0.0 => {
            Err(format!("{key}: {x} is not positive"))
        }
        _ => Ok(()),
    }
}

fn is_blank(rec: &csv::ByteRecord) -> bool {
    rec.iter().all(|f| f.trim_ascii().is_empty())
}

/// A field as text for messages: lossy UTF-8, at most 40 characters.
fn snippet(bytes: &[u8]) -> String {
    let s = String::from_utf8_lossy(bytes);
    let mut out: String = s.chars().take(40).collect();
    if s.chars().nth(40).is_some() {
        out.push('…');
    }
    out
}

fn field<F: Fields + ?Sized>(rec: &F, i: usize) -> &[u8] {
    rec.raw(i).unwrap_or(b"").trim_ascii()
}

fn parse_f64<F: Fields + ?Sized>(
    rec: &F,
    i: usize,
    column: &'static str,
) -> Result<f64, RecordingErrorKind> {
    let f = field(rec, i);
    let x = parse_number(f).ok_or_else(|| RecordingErrorKind::NotANumber {
        column,
        text: snippet(f),
    })?;
    if x.is_finite() {
        Ok(x)
    } else {
        Err(RecordingErrorKind::NotFinite { column })
    }
}

/// A decimal number as `str::parse::<f64>` reads it (correctly rounded): plain decimals
/// by [`plain_decimal`], anything else by fast-float2.
fn parse_number(f: &[u8]) -> Option<f64> {
    plain_decimal(f).or_else(|| fast_float2::parse::<f64, _>(f).ok())
}

/// The exact powers of ten in f64, and as integers.
const POW10: [f64; 16] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15,
];
const POW10_INT: [u64; 16] = {
    let mut p = [1u64; 16];
    let mut i = 1;
    while i < 16 {
        p[i] = p[i - 1] * 10;
        i += 1;
    }
    p
};

/// A plain decimal of at most 15 significant digits (`-12.5`, `0.009615`, `541`), which
/// are nearly all a recording holds, as `str::parse::<f64>` reads it; `None` for anything
/// else. Its digits are an integer below 2⁵³ and the power of ten is exact, so one
/// division rounds correctly (Clinger's fast path).
fn plain_decimal(f: &[u8]) -> Option<f64> {
    leading_decimal(f)
        .filter(|(_, len)| *len == f.len())
        .map(|(x, _)| x)
}

/// The digits of `rest` from byte `i` on into `mant` (wrapping past 19 digits: callers
/// refuse so many), and the byte after them.
fn leading_digits(rest: &[u8], mut i: usize, mant: &mut u64) -> usize {
    // Two at a time while there are two (half the steps, half the dependent
    // multiplications), then one.
    while let Some(&[a, b]) = rest.get(i..i + 2) {
        let (a, b) = (a.wrapping_sub(b'0'), b.wrapping_sub(b'0'));
        if a > 9 {
            return i;
        }
        if b > 9 {
            *mant = mant.wrapping_mul(10).wrapping_add(u64::from(a));
            return i + 1;
        }
        *mant = mant
            .wrapping_mul(100)
            .wrapping_add(u64::from(a) * 10 + u64::from(b));
        i += 2;
    }
    while let Some(d) = rest
        .get(i)
        .map(|b| b.wrapping_sub(b'0'))
        .filter(|d| *d <= 9)
    {
        *mant = mant.wrapping_mul(10).wrapping_add(u64::from(d));
        i += 1;
    }
    i
}

/// Where the field that starts `rest` ends: its comma or newline, or the end (two bytes
/// a step, as [`leading_digits`]).
fn field_end(rest: &[u8]) -> usize {
    let ends = |b: u8| b == b',' || b == b'\n';
    let mut i = 0;
    while let Some(&[a, b]) = rest.get(i..i + 2) {
        if ends(a) {
            return i;
        }
        if ends(b) {
            return i + 1;
        }
        i += 2;
    }
    i + usize::from(rest.get(i).is_some_and(|b| !ends(*b)))
}

/// The plain decimal that starts `rest` (see [`plain_decimal`]) and its length: the digits
/// are read in the walk that finds the number's end (the byte after it is the caller's to
/// check). `None` when what starts `rest` is not one.
// Inlined into plain_row's loop: a call per number was 5 % more instructions per calibration.
#[inline(always)]
fn leading_decimal(rest: &[u8]) -> Option<(f64, usize)> {
    let neg = rest.first() == Some(&b'-');
    let start = usize::from(neg);
    let mut mant = 0;
    let point = leading_digits(rest, start, &mut mant);
    let (int, whole) = (mant, point - start);
    let (len, frac) = if rest.get(point) == Some(&b'.') {
        let end = leading_digits(rest, point + 1, &mut mant);
        // A digit on each side of a point ("5." and ".5" go the long way).
        if whole == 0 || end == point + 1 {
            return None;
        }
        (end, end - point - 1)
    } else {
        (point, 0)
    };
    if whole + frac == 0 || whole + frac > 15 {
        return None;
    }
    // Exact digits, an exact power of ten, one rounding; no division when the digits
    // after the point are all 0 ("541.0"), the value then the integer part's (which the
    // quotient would be, exactly).
    let v = if mant == int.wrapping_mul(*POW10_INT.get(frac)?) {
        int as f64
    } else {
        mant as f64 / POW10.get(frac)?
    };
    Some((if neg { -v } else { v }, len))
}

fn parse_opt<F: Fields + ?Sized>(
    rec: &F,
    i: Option<usize>,
    column: &'static str,
) -> Result<Option<f64>, RecordingErrorKind> {
    i.map(|i| parse_f64(rec, i, column)).transpose()
}

fn parse_row<'r, F: Fields + ?Sized>(
    rec: &'r F,
    cols: &ColumnIndex,
    columns: Parse,
) -> Result<Row<'r>, RecordingErrorKind> {
    let all = columns == Parse::All;
    // Files with gravity directions need no condition; one that is there is ignored.
    let condition = match (cols.condition, cols.gravity) {
        (Some(i), None) => {
            let c = field(rec, i);
            match c {
                [b] => Condition::from_letter(char::from(*b)),
                _ => None,
            }
            .ok_or_else(|| RecordingErrorKind::UnknownCondition(snippet(c)))?
        }
        _ => Condition::X,
    };
    let gravity = match cols.gravity {
        Some([x, y, z]) => {
            let g = [
                parse_f64(rec, x, "gx")?,
                parse_f64(rec, y, "gy")?,
                parse_f64(rec, z, "gz")?,
            ];
            let norm = g.iter().map(|c| c * c).sum::<f64>().sqrt();
            if (norm - 1.0).abs() > UNIT_TOLERANCE {
                return Err(RecordingErrorKind::NotUnitVector { norm });
            }
            Some(g.map(|c| c / norm))
        }
        None => None,
    };
    let pose = match cols.pose {
        Some(i) => {
            let f = field(rec, i);
            let text = std::str::from_utf8(f)
                .map_err(|_| RecordingErrorKind::BadPose("not UTF-8 text"))?;
            if text.is_empty() {
                return Err(RecordingErrorKind::BadPose("empty pose name"));
            }
            if !pose_name_ok(text) {
                return Err(RecordingErrorKind::BadPose(
                    "a pose name may not hold commas, quotes, '#' or line breaks",
                ));
            }
            Some(text)
        }
        None => None,
    };
    let t_s = parse_opt(rec, cols.t_s, "t_s")?;
    let angle_deg = match all {
        true => parse_opt(rec, cols.angle_deg, "angle_deg")?,
        false => None,
    };
    let u = parse_f64(rec, cols.u, "u")?;
    let v = parse_f64(rec, cols.v, "v")?;
    let w = parse_f64(rec, cols.w, "w")?;
    let seq = match cols.seq.filter(|_| all) {
        Some(i) => {
            let f = field(rec, i);
            let s = std::str::from_utf8(f)
                .ok()
                .and_then(|s| s.parse::<u64>().ok())
                .ok_or_else(|| RecordingErrorKind::NotAnInteger {
                    column: "seq",
                    text: snippet(f),
                })?;
            Some(s)
        }
        None => None,
    };
    let temp_c = parse_opt(rec, cols.temp_c.filter(|_| all), "temp_c")?;
    let rate_hz = parse_opt(rec, cols.rate_hz, "rate_hz")?;
    let conv_gaps = match cols.conv_gaps {
        Some(i) => Some(parse_gaps(field(rec, i))?),
        None => None,
    };
    if let Some(r) = rate_hz {
        if r <= 0.0 {
            return Err(RecordingErrorKind::NotPositive {
                column: "rate_hz",
                value: r,
            });
        }
    }
    Ok(Row {
        condition,
        t_s,
        angle_deg,
        u,
        v,
        w,
        seq,
        temp_c,
        rate_hz,
        gravity,
        pose,
        conv_gaps,
        unc: match cols.unc.filter(|_| all) {
            Some([a, b, c]) => Some([
                parse_f64(rec, a, "u_unc")?,
                parse_f64(rec, b, "v_unc")?,
                parse_f64(rec, c, "w_unc")?,
            ]),
            None => None,
        },
    })
}

/// A `conv_gaps` field: tick counts separated by single spaces (empty: one conversion).
fn parse_gaps(f: &[u8]) -> Result<Aperture, RecordingErrorKind> {
    let bad = |why: &str| RecordingErrorKind::BadConversions(format!("'{}': {why}", snippet(f)));
    let text = std::str::from_utf8(f).map_err(|_| bad("not text"))?;
    let mut gaps = Vec::new();
    if !text.is_empty() {
        for g in text.split(' ') {
            let v: u16 = g
                .parse()
                .map_err(|_| bad("each gap is a whole number of ticks, 1 to 65535"))?;
            gaps.push(v);
        }
    }
    Aperture::new(Ticks(0), &gaps).ok_or_else(|| {
        bad(&format!(
            "at most {} gaps (conversions {MAX_CONVERSIONS}), none 0",
            MAX_CONVERSIONS - 1
        ))
    })
}

/// Conversions from `first` with the gaps of `gaps` (device ticks) counted in a clock
/// `scale` times as fast; `None` when a scaled gap leaves 1 to 65535.
fn scaled_aperture(first: Ticks, gaps: Option<&Aperture>, scale: f64) -> Option<Aperture> {
    let mut ap = Aperture::point(first);
    for d in gaps.map_or(&[][..], Aperture::gaps) {
        let scaled = (f64::from(*d) * scale).round();
        let gap = u16::try_from(scaled as u64).ok()?;
        ap.push_gap(gap).ok()?;
    }
    Some(ap)
}

/// A row's conversions as an [`Aperture`] in ticks of `clock` from its group's first row:
/// the row's time `t_s` against the group's first `t0_s`, and its `conv_gaps` (in device
/// ticks; `scale` from [`tick_scale`]). The message says what is out of range.
pub fn row_aperture(
    t_s: f64,
    t0_s: f64,
    gaps: Option<&Aperture>,
    scale: f64,
    clock: rotacal_shared::TickRate,
) -> Result<Aperture, &'static str> {
    let ticks = round_ticks((t_s - t0_s) * f64::from(clock.hz())).ok_or("t_s out of range")?;
    scaled_aperture(Ticks(ticks), gaps, scale).ok_or("conv_gaps beyond 65 ms at 1 MHz")
}

/// `x.round()` (half away from zero) as a tick count, if in 0 … 1.8·10¹⁹: by truncation
/// and the exact fraction it leaves, without the call to libm's round that the baseline
/// x86-64 target makes (twice a row in a streaming calibration).
fn round_ticks(x: f64) -> Option<u64> {
    // round(x) < 0 exactly when x ≤ −0.5; at 1.8·10¹⁹ every f64 is a whole number.
    if !(x > -0.5 && x < 1.8e19) {
        return None;
    }
    let whole = x as u64; // truncation: floor for x ≥ 0, 0 for −0.5 < x < 0
                          // Exact: x and its whole part share their binade's grid, or x is whole.
    let frac = x - whole as f64;
    Some(whole + u64::from(frac >= 0.5))
}

/// Ticks of `clock` per device tick of a file with metadata `meta` (its `tick_hz`; 1 when
/// it has none, the rows then being single conversions).
pub fn tick_scale(meta: &Metadata, clock: rotacal_shared::TickRate) -> f64 {
    f64::from(clock.hz()) / f64::from(tick_hz(meta).unwrap_or(clock.hz()))
}

/// The `tick_hz` metadata value, if it is a positive integer.
pub fn tick_hz(meta: &Metadata) -> Option<u32> {
    meta.other
        .get(TICK_HZ_KEY)
        .and_then(|v| v.parse::<u32>().ok())
        .filter(|v| *v > 0)
}

/// The names the writer can write and the reader reads back unchanged.
fn pose_name_ok(p: &str) -> bool {
    !p.is_empty() && !p.contains([',', '"', '\n', '\r', '#']) && p.trim() == p
}

// ---------------------------------------------------------------------------------------
// Writer

/// Which optional columns a written file has (`u`, `v`, `w` always; `condition` unless
/// the file has gravity directions).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Columns {
    /// `t_s` (rotation needs it).
    pub t_s: bool,
    /// `angle_deg` (static needs it).
    pub angle_deg: bool,
    /// `seq`.
    pub seq: bool,
    /// `temp_c`.
    pub temp_c: bool,
    /// `rate_hz` (multi-rate files).
    pub rate_hz: bool,
    /// `gx, gy, gz` instead of `condition` (static data from any known orientations).
    pub gravity: bool,
    /// `pose` (with `gravity`).
    pub pose: bool,
    /// `u_unc, v_unc, w_unc` after `w`: standard uncertainties of calibrated readings
    /// (`rotacal apply`; other readers ignore them).
    pub unc: bool,
    /// `conv_gaps`, last: the conversions each row averages (needs `tick_hz` metadata).
    pub conv_gaps: bool,
}

impl Columns {
    /// A plain rotation file: `condition,t_s,u,v,w`.
    pub const ROTATION: Columns = Columns {
        t_s: true,
        angle_deg: false,
        seq: false,
        temp_c: false,
        rate_hz: false,
        gravity: false,
        pose: false,
        unc: false,
        conv_gaps: false,
    };
    /// A plain static file: `condition,angle_deg,u,v,w`.
    pub const STATIC: Columns = Columns {
        t_s: false,
        angle_deg: true,
        seq: false,
        temp_c: false,
        rate_hz: false,
        gravity: false,
        pose: false,
        unc: false,
        conv_gaps: false,
    };

    /// The header line's names, in the order the writer puts them.
    pub fn names(&self) -> Vec<&'static str> {
        self.names_of(false)
    }

    /// The header's names; `free`: a free recording's (no `condition`, a `pose` column
    /// allowed without gravity directions).
    pub fn names_of(&self, free: bool) -> Vec<&'static str> {
        let mut out = if self.gravity || free {
            vec![]
        } else {
            vec!["condition"]
        };
        let opt = [
            ((self.gravity || free) && self.pose, "pose"),
            (self.rate_hz, "rate_hz"),
            (self.seq, "seq"),
            (self.t_s, "t_s"),
            (self.angle_deg, "angle_deg"),
            (self.gravity, "gx"),
            (self.gravity, "gy"),
            (self.gravity, "gz"),
        ];
        out.extend(opt.iter().filter(|(on, _)| *on).map(|(_, n)| *n));
        out.extend(["u", "v", "w"]);
        if self.unc {
            out.extend(["u_unc", "v_unc", "w_unc"]);
        }
        if self.temp_c {
            out.push("temp_c");
        }
        if self.conv_gaps {
            out.push("conv_gaps");
        }
        out
    }
}

/// One row to write.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Row<'a> {
    /// The condition (not written in files with gravity directions).
    pub condition: Condition,
    /// Device time, s (the file must have the `t_s` column exactly when this is `Some`).
    pub t_s: Option<f64>,
    /// Table angle, degrees.
    pub angle_deg: Option<f64>,
    /// Channel U.
    pub u: f64,
    /// Channel V.
    pub v: f64,
    /// Channel W.
    pub w: f64,
    /// Sample sequence number.
    pub seq: Option<u64>,
    /// Temperature, °C.
    pub temp_c: Option<f64>,
    /// Nominal rate of this row, Hz.
    pub rate_hz: Option<f64>,
    /// ĝ, the direction of gravity's reading in the platter frame (a unit vector).
    pub gravity: Option<[f64; 3]>,
    /// The pose's name.
    pub pose: Option<&'a str>,
    /// Standard uncertainties of u, v, w (calibrated readings).
    pub unc: Option<[f64; 3]>,
    /// The conversions the row averages (only the gaps are written: the first is `t_s`),
    /// in device ticks of the file's `tick_hz`.
    pub conv_gaps: Option<Aperture>,
}

impl Row<'static> {
    /// A row with only the channels; set the optional fields as needed.
    pub fn new(condition: Condition, u: f64, v: f64, w: f64) -> Self {
        Row {
            condition,
            t_s: None,
            angle_deg: None,
            u,
            v,
            w,
            seq: None,
            temp_c: None,
            rate_hz: None,
            gravity: None,
            pose: None,
            unc: None,
            conv_gaps: None,
        }
    }
}

/// Writes a recording: `# rotacal recording v1`, the metadata, the header, then rows.
///
/// Output is buffered: call [`Writer::flush`] (or [`Writer::sync`] for a file) at the end
/// and check its result. Rows and metadata that the reader would reject are refused with
/// [`io::ErrorKind::InvalidInput`], so every file it writes reads back.
pub struct Writer<W: Write> {
    out: BufWriter<W>,
    columns: Columns,
    /// A free recording: no `condition` column.
    free: bool,
    line: String,
}

fn invalid(msg: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, msg)
}

fn check_value(key: &str, value: &str) -> io::Result<()> {
    if value.contains(['\n', '\r']) {
        return Err(invalid(format!(
            "metadata {key}: value contains a line break"
        )));
    }
    Ok(())
}

impl Writer<File> {
    /// Create (or truncate) the file at `path` and write the preamble and header.
    pub fn create(path: impl AsRef<Path>, meta: &Metadata, columns: &Columns) -> io::Result<Self> {
        Writer::new(File::create(path)?, meta, columns)
    }

    /// Flush and ask the OS to put the data on disk (`File::sync_data`).
    pub fn sync(&mut self) -> io::Result<()> {
        self.out.flush()?;
        self.out.get_ref().sync_data()
    }
}

impl<W: Write> Writer<W> {
    /// Write the preamble (`# rotacal recording v1`, then `# key=value` for every metadata
    /// value set, known keys first, values trimmed) and the header to `w`.
    pub fn new(w: W, meta: &Metadata, columns: &Columns) -> io::Result<Self> {
        let method = meta.method.unwrap_or(if columns.t_s && !columns.gravity {
            Method::Rotation
        } else {
            Method::Static
        });
        let free = method == Method::Free && !columns.gravity;
        match method {
            Method::Rotation if !columns.t_s => {
                return Err(invalid("method rotation needs the t_s column".into()))
            }
            Method::Free if free && !columns.t_s => {
                return Err(invalid("a free recording needs the t_s column".into()))
            }
            Method::Free if free && (columns.angle_deg || columns.rate_hz) => {
                return Err(invalid(
                    "a free recording has neither angle_deg nor rate_hz".into(),
                ))
            }
            _ if columns.pose && !columns.gravity && !free => {
                return Err(invalid("a pose column needs the gx, gy, gz columns".into()))
            }
            _ if columns.gravity && (columns.angle_deg || columns.rate_hz) => {
                return Err(invalid(
                    "angle_deg and rate_hz cannot go with gx, gy, gz columns".into(),
                ))
            }
            Method::Rotation if columns.gravity => {
                return Err(invalid(
                    "method rotation cannot have gx, gy, gz columns".into(),
                ))
            }
            Method::Static if !columns.angle_deg && !columns.gravity => {
                return Err(invalid("method static needs the angle_deg column".into()))
            }
            _ => {}
        }
        let mut pre = String::from("# rotacal recording v1\n");
        let mut kv = |key: &str, value: &str| -> io::Result<()> {
            check_value(key, value)?;
            pre.push_str(&format!("# {key}={}\n", value.trim()));
            Ok(())
        };
        if let Some(m) = meta.method {
            kv("method", m.as_str())?;
        }
        let nums = [
            ("rate_hz", meta.rate_hz),
            ("g_loc", meta.g_loc),
            ("units", None),
            ("sample_rate_hz", meta.sample_rate_hz),
            ("noise_sigma", meta.noise_sigma),
        ];
        for (key, x) in nums {
            if key == "units" {
                if let Some(u) = &meta.units {
                    kv("units", u)?;
                }
            } else if let Some(x) = x {
                check_meta_number(key, x).map_err(invalid)?;
                kv(key, &format!("{x:?}"))?;
            }
        }
        if let Some(d) = &meta.device {
            kv("device", d)?;
        }
        for (key, value) in &meta.other {
            if !is_key(key) {
                return Err(invalid(format!(
                    "metadata key '{key}': use letters, digits, '_', '-' and '.'"
                )));
            }
            if KNOWN_KEYS.contains(&key.as_str()) {
                return Err(invalid(format!(
                    "metadata key '{key}' is a known key: set the field, not `other`"
                )));
            }
            kv(key, value)?;
        }
        pre.push_str(&columns.names_of(free).join(","));
        pre.push('\n');
        let mut out = BufWriter::with_capacity(1 << 16, w);
        out.write_all(pre.as_bytes())?;
        Ok(Writer {
            out,
            columns: *columns,
            free,
            line: String::with_capacity(128),
        })
    }

    /// Continue a file whose preamble and header (with these `columns`) are already
    /// written: rows only.
    pub fn append(w: W, columns: &Columns) -> Self {
        Writer {
            out: BufWriter::with_capacity(1 << 16, w),
            columns: *columns,
            free: false,
            line: String::with_capacity(128),
        }
    }

    /// The columns this writer writes.
    pub fn columns(&self) -> &Columns {
        &self.columns
    }

    /// Write one row. Its optional fields must be set exactly for the file's optional
    /// columns, and its numbers finite (`rate_hz` positive).
    pub fn write_row(&mut self, row: &Row<'_>) -> io::Result<()> {
        use std::fmt::Write as _;
        let c = self.columns;
        fn num(line: &mut String, name: &str, x: f64) -> io::Result<()> {
            if !x.is_finite() {
                return Err(invalid(format!("{name}={x} is not finite")));
            }
            if !line.is_empty() {
                line.push(',');
            }
            // The shortest decimal that reads back as the same f64 (ryu: the digits of
            // `{x:?}`, several times faster, which matters to the simulator's long records).
            line.push_str(ryu::Buffer::new().format_finite(x));
            Ok(())
        }
        fn opt<T>(on: bool, name: &str, x: Option<T>) -> io::Result<Option<T>> {
            match (on, x) {
                (true, Some(x)) => Ok(Some(x)),
                (false, None) => Ok(None),
                (true, None) => Err(invalid(format!(
                    "row has no {name}, but the file has a {name} column"
                ))),
                (false, Some(_)) => Err(invalid(format!(
                    "row has {name}, but the file has no {name} column"
                ))),
            }
        }
        let line = &mut self.line;
        line.clear();
        if !c.gravity && !self.free {
            line.push(row.condition.letter());
        }
        if let Some(p) = opt((c.gravity || self.free) && c.pose, "pose", row.pose)? {
            if !pose_name_ok(p) {
                return Err(invalid(format!(
                    "pose name '{p}': use a non-empty name without commas, quotes, '#', line \
                     breaks or surrounding spaces"
                )));
            }
            line.push_str(p);
        }
        if let Some(r) = opt(c.rate_hz, "rate_hz", row.rate_hz)? {
            if r.is_finite() && r <= 0.0 {
                return Err(invalid(format!("rate_hz={r} is not positive")));
            }
            num(line, "rate_hz", r)?;
        }
        if let Some(s) = opt(c.seq, "seq", row.seq)? {
            if !line.is_empty() {
                line.push(',');
            }
            let _ = write!(line, "{s}");
        }
        if let Some(t) = opt(c.t_s, "t_s", row.t_s)? {
            num(line, "t_s", t)?;
        }
        if let Some(a) = opt(c.angle_deg, "angle_deg", row.angle_deg)? {
            num(line, "angle_deg", a)?;
        }
        if let Some(g) = opt(c.gravity, "gx, gy, gz", row.gravity)? {
            let norm = g.iter().map(|x| x * x).sum::<f64>().sqrt();
            if (norm - 1.0).abs() > UNIT_TOLERANCE {
                return Err(invalid(format!("gx, gy, gz: length {norm}, not 1")));
            }
            // Written normalised, as the reader would read it.
            for (name, x) in ["gx", "gy", "gz"].iter().zip(g) {
                num(line, name, x / norm)?;
            }
        }
        num(line, "u", row.u)?;
        num(line, "v", row.v)?;
        num(line, "w", row.w)?;
        if let Some(u) = opt(c.unc, "u_unc, v_unc, w_unc", row.unc)? {
            for (name, x) in ["u_unc", "v_unc", "w_unc"].iter().zip(u) {
                num(line, name, x)?;
            }
        }
        if let Some(t) = opt(c.temp_c, "temp_c", row.temp_c)? {
            num(line, "temp_c", t)?;
        }
        if let Some(a) = opt(c.conv_gaps, "conv_gaps", row.conv_gaps)? {
            line.push(',');
            for (i, g) in a.gaps().iter().enumerate() {
                if i > 0 {
                    line.push(' ');
                }
                let _ = write!(line, "{g}");
            }
        }
        line.push('\n');
        self.out.write_all(line.as_bytes())
    }

    /// Flush buffered rows to the underlying writer.
    pub fn flush(&mut self) -> io::Result<()> {
        self.out.flush()
    }

    /// The underlying writer.
    pub fn get_ref(&self) -> &W {
        self.out.get_ref()
    }

    /// Flush and return the underlying writer.
    pub fn into_inner(self) -> io::Result<W> {
        self.out
            .into_inner()
            .map_err(io::IntoInnerError::into_error)
    }
}

#[cfg(test)]
mod tests {
    use super::{
        parse_number, parse_row, plain_plan, plain_row, split_commas, ColumnIndex, Parse, Row,
        SplitLine,
    };
    use proptest::prelude::*;
    use rotacal_shared::Condition;

    /// The columns of a rotation recording (`condition,seq,t_s,u,v,w,temp_c`), with
    /// `rate_hz`, `conv_gaps` and a column of no meaning after them when `more`.
    fn columns(more: bool) -> ColumnIndex {
        ColumnIndex {
            n: if more { 10 } else { 7 },
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

    /// As `str::parse::<f64>` reads it, bit for bit (any NaN for a NaN).
    fn same(s: &str) {
        let ours = parse_number(s.as_bytes());
        let std = s.parse::<f64>().ok();
        match (ours, std) {
            (Some(a), Some(b)) if a.is_nan() && b.is_nan() => {}
            (a, b) => assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits), "{s:?}"),
        }
    }

    #[test]
    fn numbers_read_as_the_standard_library_reads_them() {
        for s in [
            "0",
            "-0",
            "-0.0",
            "541.0",
            "0.009615",
            "3599.990385",
            "+1.5",
            ".5",
            "5.",
            "1e3",
            "1E-3",
            "-1e-300",
            "nan",
            "inf",
            "-",
            "",
            ".",
            "1.2.3",
            "00012.500",
            "999999999999999",
            "9999999999999999",
            "0.000000000000001",
            "123456789012345.6",
            "1_0",
            " 1",
            "1 ",
        ] {
            same(s);
        }
    }

    /// round_ticks is f64::round, bounds included.
    fn same_round(x: f64) {
        let std = x.round();
        let want = (0.0..1.8e19).contains(&std).then_some(std as u64);
        assert_eq!(super::round_ticks(x), want, "{x:e}");
    }

    #[test]
    fn ticks_round_as_the_standard_library_rounds() {
        for x in [
            0.0,
            -0.0,
            0.49999999999999994,
            0.5,
            1.5,
            2.5,
            -0.4,
            -0.5,
            -0.500_000_000_000_000_1,
            4503599627370495.5,
            4503599627370496.0,
            9007199254740993.0,
            1.8e19,
            1.7999999999999998e19,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ] {
            same_round(x);
        }
    }

    proptest! {
        #[test]
        fn any_tick_count_rounds_as_the_standard_library_rounds(
            m in 0.0f64..1.0, e in -3i32..66, half in proptest::bool::ANY
        ) {
            let x = m * 2f64.powi(e);
            same_round(if half { x.floor() + 0.5 } else { x });
            same_round(-x);
        }

        #[test]
        fn any_decimal_reads_as_the_standard_library_reads_it(
            s in "-?[0-9]{0,18}(\\.[0-9]{0,18})?([eE][-+]?[0-9]{1,3})?"
        ) {
            same(&s);
        }
    }
}
