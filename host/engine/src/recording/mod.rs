//! The recording CSV (docs/formats.md, "Recording CSV"): the model of a recording, and
//! its reader and writer.
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
//! The folder, one kind a file:
//! - `mod.rs` (here): the model, [`Recording`] and its [`Group`]s, [`Oriented`] and
//!   [`Series`] rows, [`Metadata`], the rows and columns a file has ([`Row`], [`Columns`])
//!   and the format's rules that reader and writer share;
//! - `error`: [`RecordingError`], which names the file, the 1-based physical line
//!   (comment and blank lines count) and the problem, a bad metadata value a
//!   [`MetadataError`] naming the key; no input makes the reader panic;
//! - `read/`: [`read`] and its variants (held in memory, grouped by condition and
//!   nominal rate), [`scan`] (row by row) and [`Parts`] (byte ranges on several threads),
//!   by a fast line reader or, for anything it does not take, the `csv` crate's;
//! - `write`: [`Writer`], whose files the reader reads back exactly (floats in the
//!   shortest form that reads back exactly, by ryu).
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

mod error;
pub mod from_device;
pub mod import;
mod read;
mod write;

pub use error::{MetadataError, RecordingError, RecordingErrorKind, UnknownMethod};
pub use read::{
    read, read_as, read_bytes, read_columns, read_from, read_in_progress, read_preamble, scan,
    Column, Parse, PartRow, Parts, Scanned, Stretch, Values,
};
pub use write::{write_recording, Writer};

use std::collections::BTreeMap;
use std::fmt;

use rotacal_shared::{Aperture, Condition, Ticks};

/// How the data were taken (formats.md `method`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Constant rotation (Gaitan & Geist (2022)): rows carry device time `t_s`.
    Rotation,
    /// Static steps (Gaitan et al. (2021)): rows carry the table angle `angle_deg`.
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
    type Err = UnknownMethod;
    /// `rotation`, `static` or `free` (any case, surrounding spaces ignored).
    fn from_str(s: &str) -> Result<Self, UnknownMethod> {
        let t = s.trim();
        if t.eq_ignore_ascii_case("rotation") {
            Ok(Method::Rotation)
        } else if t.eq_ignore_ascii_case("static") {
            Ok(Method::Static)
        } else if t.eq_ignore_ascii_case("free") {
            Ok(Method::Free)
        } else {
            Err(UnknownMethod {
                text: snippet(t.as_bytes()),
            })
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
    /// `conv_missed` column, if the file has one: conversions in each row's slot that the
    /// device did not read (`None` for a row that does not say: an empty field).
    pub missed: Option<Vec<Option<u8>>>,
    /// `boot` column, if the file has one: rows of different boots have time origins of
    /// their own (the device restarted between them).
    pub boot: Option<Vec<u32>>,
    /// 1-based file line of the group's first row (for messages).
    pub first_line: u64,
}

impl Group {
    /// Number of rows.
    pub fn len(&self) -> usize {
        self.u.len()
    }

    /// Whether the rows are in more than one boot of the device (`boot`).
    pub fn in_several_boots(&self) -> bool {
        self.boot
            .as_ref()
            .is_some_and(|b| b.first().is_some_and(|f| b.iter().any(|x| x != f)))
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
            row: None,
            kind,
        })
    }
}

/// Whether two `rate_hz` values name the same nominal rate (bit for bit, `None` alike).
pub(crate) fn same_rate(a: Option<f64>, b: Option<f64>) -> bool {
    a.map(f64::to_bits) == b.map(f64::to_bits)
}

/// The column names formats.md defines.
pub const COLUMN_NAMES: [&str; 19] = [
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
    "conv_missed",
    "boot",
];

/// The metadata key giving the device clock's ticks per second, which `conv_gaps` counts
/// (a positive integer; required with that column).
pub const TICK_HZ_KEY: &str = "tick_hz";

/// How far |(gx, gy, gz)| may be from 1 (rounding of written unit vectors).
pub const UNIT_TOLERANCE: f64 = 1e-3;

fn is_key(key: &str) -> bool {
    !key.is_empty()
        && key
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'-' | b'.'))
}

/// Check a known numeric metadata value `x` of `key`.
fn check_meta_number(key: &'static str, x: f64) -> Result<(), MetadataError> {
    if !x.is_finite() {
        return Err(MetadataError::NotFinite { key, value: x });
    }
    match key {
        "noise_sigma" if x < 0.0 => Err(MetadataError::Negative { key, value: x }),
        "rate_hz" | "g_loc" | "sample_rate_hz" if x <= 0.0 => {
            Err(MetadataError::NotPositive { key, value: x })
        }
        _ => Ok(()),
    }
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
    /// `conv_gaps`: the conversions each row averages (needs `tick_hz` metadata).
    pub conv_gaps: bool,
    /// `conv_missed`: conversions in each row's slot the device did not read.
    pub conv_missed: bool,
    /// `boot`, last: the device's power-up a row was recorded in (its clock restarts).
    pub boot: bool,
}

impl Columns {
    /// None of the optional columns: `condition,u,v,w` (what `Default` gives, as a const).
    const BARE: Columns = Columns {
        t_s: false,
        angle_deg: false,
        seq: false,
        temp_c: false,
        rate_hz: false,
        gravity: false,
        pose: false,
        unc: false,
        conv_gaps: false,
        conv_missed: false,
        boot: false,
    };
    /// A plain rotation file: `condition,t_s,u,v,w`.
    pub const ROTATION: Columns = Columns {
        t_s: true,
        ..Columns::BARE
    };
    /// A plain static file: `condition,angle_deg,u,v,w`.
    pub const STATIC: Columns = Columns {
        angle_deg: true,
        ..Columns::BARE
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
        if self.conv_missed {
            out.push("conv_missed");
        }
        if self.boot {
            out.push("boot");
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
    /// Conversions in the row's slot the device did not read; `None` writes an empty
    /// field (a device that does not count them).
    pub conv_missed: Option<u8>,
    /// The device's power-up the row was recorded in (`boot`).
    pub boot: Option<u32>,
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
            conv_missed: None,
            boot: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{check_meta_number, Columns, Metadata, MetadataError, Method, Writer};
    use proptest::prelude::*;

    #[test]
    fn an_unknown_method_keeps_its_text() {
        let e = " Spin ".parse::<Method>().unwrap_err();
        assert_eq!(e.text, "Spin");
        assert_eq!(
            e.to_string(),
            "expected 'rotation' or 'static', got 'Spin' (or 'free': still poses of unknown \
             orientation)"
        );
        let long = "q".repeat(41);
        let e = long.parse::<Method>().unwrap_err();
        assert_eq!(e.text, format!("{}…", "q".repeat(40)));
        assert_eq!(" FREE ".parse::<Method>(), Ok(Method::Free));
    }

    #[test]
    fn metadata_numbers_are_checked_by_key() {
        let cases = [
            ("g_loc", f64::NAN, "g_loc: NaN is not finite"),
            ("noise_sigma", -1.5, "noise_sigma: -1.5 is negative"),
            ("sample_rate_hz", 0.0, "sample_rate_hz: 0 is not positive"),
            ("rate_hz", -0.01, "rate_hz: -0.01 is not positive"),
        ];
        for (key, x, want) in cases {
            let e = check_meta_number(key, x).unwrap_err();
            assert_eq!(e.to_string(), want);
        }
        assert_eq!(
            check_meta_number("rate_hz", -2.0),
            Err(MetadataError::NotPositive {
                key: "rate_hz",
                value: -2.0
            })
        );
        assert_eq!(check_meta_number("noise_sigma", 0.0), Ok(()));
        assert_eq!(check_meta_number("units", -1.0), Ok(()));
    }

    #[test]
    fn the_writer_refuses_a_bad_number_with_its_key() {
        let meta = Metadata {
            sample_rate_hz: Some(-100.0),
            ..Metadata::default()
        };
        let Err(e) = Writer::new(Vec::new(), &meta, &Columns::ROTATION) else {
            panic!("written");
        };
        assert_eq!(e.kind(), std::io::ErrorKind::InvalidInput);
        assert_eq!(e.to_string(), "sample_rate_hz: -100 is not positive");
        assert_eq!(
            e.get_ref().and_then(|e| e.downcast_ref::<MetadataError>()),
            Some(&MetadataError::NotPositive {
                key: "sample_rate_hz",
                value: -100.0
            })
        );
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
    }
}
