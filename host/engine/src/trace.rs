//! The traceability block every JSON, report and export carries (docs/formats.md,
//! "Traceability"): which rotacal made it, when, from which input (its SHA-256), on which
//! device and firmware, over which temperatures, with which local gravity, by which
//! command line.
//!
//! The engine has no build script: which build made the output ([`Build`]) is the caller's
//! to say (the application's and the Python package's build scripts read the commit).

use crate::recording::{self, Parse, RecordingError, Scanned};
use serde::Serialize;
use sha2::{Digest, Sha256};
use std::io::Read;
use std::path::Path;

/// Which rotacal made an output: its version and the commit it was built from.
#[derive(Clone, Copy, Debug)]
pub struct Build {
    /// The version.
    pub version: &'static str,
    /// `git describe --always --dirty` of the build ("unknown" outside a checkout).
    pub commit: &'static str,
}

/// Why a traceability block could not be made. The message says the file and why, once:
/// the cause is part of it, not a source that a chain of causes would print again.
#[derive(Debug, thiserror::Error)]
pub enum TraceError {
    /// A file could not be read or written.
    #[error("{path}: {error}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        error: std::io::Error,
    },
    /// A calibration JSON that is not JSON.
    #[error("{path}: {error}")]
    Json {
        /// The file.
        path: String,
        /// Why.
        error: serde_json::Error,
    },
    /// The recording could not be read.
    #[error(transparent)]
    Recording(#[from] RecordingError),
}

fn io_at(path: &Path) -> impl Fn(std::io::Error) -> TraceError + '_ {
    move |error| TraceError::Io {
        path: path.display().to_string(),
        error,
    }
}

/// See the module documentation.
#[derive(Clone, Debug, Serialize)]
pub struct Traceability {
    /// rotacal's version.
    pub rotacal: String,
    /// The commit it was built from (`git describe`; "-dirty": with changes not
    /// committed; "unknown" outside a checkout).
    pub commit: String,
    /// When the output was made, UTC, ISO 8601.
    pub date_utc: String,
    /// The command line, its arguments as given.
    pub command_line: Vec<String>,
    /// The input files.
    pub inputs: Vec<Input>,
    /// The recording's `# device=` (which for `rotacal record` names the chip, the
    /// firmware and the BLE address).
    pub device: Option<String>,
    /// The firmware version, from `device` ("firmware A.B.C").
    pub firmware: Option<String>,
    /// The range of the recording's `temp_c`, °C.
    pub temperature_c: Option<Range>,
    /// Local gravity, where it came from and its standard uncertainty.
    pub g_loc: Option<Gravity>,
    /// For an output made from a calibration (an export): that calibration's own block,
    /// which names the recording it was made from.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub calibration: Option<serde_json::Value>,
}

/// An input file.
#[derive(Clone, Debug, Serialize)]
pub struct Input {
    /// As given on the command line.
    pub path: String,
    /// Bytes.
    pub bytes: u64,
    /// SHA-256 of its bytes, hex.
    pub sha256: String,
}

/// A closed range.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Range {
    /// Smallest.
    pub min: f64,
    /// Largest.
    pub max: f64,
}

/// Local gravity.
#[derive(Clone, Debug, Serialize)]
pub struct Gravity {
    /// m/s².
    pub value: f64,
    /// "--g-loc" or "the recording's g_loc".
    pub source: String,
    /// Standard uncertainty, m/s² (`None`: not given, and not in the budget).
    pub std_unc: Option<f64>,
    /// "--u-g-loc", "the recording's u_g_loc" or "not given".
    pub std_unc_source: String,
}

/// A SHA-256 fed in pieces: small ones gathered into blocks (one update per value costs
/// more than the hash), large ones hashed where they are.
#[derive(Default)]
struct Hashing {
    hash: Sha256,
    block: Vec<u8>,
    bytes: u64,
}

impl Hashing {
    fn take(&mut self, b: &[u8]) {
        self.block.extend_from_slice(b);
        self.bytes += b.len() as u64;
        if self.block.len() >= 1 << 16 {
            self.hash.update(&self.block);
            self.block.clear();
        }
    }

    /// `b` after what waits, without a copy.
    fn whole(&mut self, b: &[u8]) {
        self.hash.update(&self.block);
        self.block.clear();
        self.hash.update(b);
        self.bytes += b.len() as u64;
    }
}

/// Columns held in memory, described as `path` (what they came from): SHA-256 of their
/// names and values in order (each name's UTF-8 and a 0 byte; each number's 8
/// little-endian bytes; each text's UTF-8 and a 0 byte), `bytes` the length digested.
pub fn input_of_columns(path: &str, columns: &[recording::Column<'_>]) -> Input {
    let mut d = Hashing::default();
    for c in columns {
        d.take(c.name.as_bytes());
        d.take(&[0]);
        match c.values {
            // The numbers' own memory is their little-endian bytes: hashed where it is.
            recording::Values::Numbers(x) if cfg!(target_endian = "little") => {
                d.whole(bytemuck::cast_slice(x));
            }
            recording::Values::Numbers(x) => x.iter().for_each(|v| d.take(&v.to_le_bytes())),
            recording::Values::Texts(t) => t.iter().for_each(|v| {
                d.take(v.as_bytes());
                d.take(&[0]);
            }),
            // As texts of one letter each, so that the digest does not depend on how the
            // column was handed over.
            recording::Values::Letters(x) => x.iter().for_each(|v| d.take(&[*v, 0])),
        }
    }
    let Hashing {
        mut hash,
        block,
        bytes,
    } = d;
    hash.update(&block);
    let sha256 = hash.finalize().iter().map(|b| format!("{b:02x}")).collect();
    Input {
        path: path.to_string(),
        bytes,
        sha256,
    }
}

/// Bytes held in memory (a calibration's JSON handed over as text), described as `path`:
/// their size and SHA-256, as [`input`] gives them for a file of these bytes.
pub fn input_of_bytes(path: &str, bytes: &[u8]) -> Input {
    let sha256 = Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    Input {
        path: path.to_string(),
        bytes: bytes.len() as u64,
        sha256,
    }
}

/// The file at `path`: its size and SHA-256.
pub fn input(path: &Path) -> Result<Input, TraceError> {
    let at = io_at(path);
    let mut f = std::fs::File::open(path).map_err(&at)?;
    let mut hash = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    let mut bytes = 0u64;
    loop {
        let n = f.read(&mut buf).map_err(&at)?;
        if n == 0 {
            break;
        }
        hash.update(buf.get(..n).unwrap_or(&[]));
        bytes += n as u64;
    }
    let sha256 = hash.finalize().iter().map(|b| format!("{b:02x}")).collect();
    Ok(Input {
        path: path.display().to_string(),
        bytes,
        sha256,
    })
}

impl Traceability {
    /// For outputs of `build` made from `inputs` (files of any kind), without a
    /// recording's facts.
    pub fn new(build: Build, inputs: &[&Path]) -> Result<Self, TraceError> {
        Ok(Traceability {
            inputs: inputs.iter().map(|p| input(p)).collect::<Result<_, _>>()?,
            ..Traceability::empty(build)
        })
    }

    /// For outputs made from the recording at `path` (read as `method`), with local
    /// gravity and its uncertainty as the command line gave them, if it did.
    pub fn of_recording(
        build: Build,
        path: &Path,
        method: Option<recording::Method>,
        g_loc: Option<f64>,
        u_g_loc: Option<f64>,
    ) -> Result<Self, TraceError> {
        let input = input(path)?;
        let given = (g_loc, u_g_loc);
        let names = ("--g-loc", "--u-g-loc");
        let mut meta = None;
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        let scanned = recording::scan(path, method, Parse::All, |ev| match ev {
            Scanned::Start { meta: m, .. } => meta = Some(*m),
            Scanned::Row {
                temp_c: Some(x), ..
            } => (lo, hi) = (lo.min(x), hi.max(x)),
            _ => {}
        })?;
        if scanned.is_none() {
            // Poses and free series are not scanned (scan stops at their header): read
            // whole, their facts are a held recording's.
            let rec = recording::read_as(path, method)?;
            return Ok(Traceability::of_held(build, &rec, input, given, names));
        }
        let mut t = Traceability {
            inputs: vec![input],
            ..Traceability::empty(build)
        };
        t.facts(
            &meta.unwrap_or_default(),
            (lo <= hi).then_some(Range { min: lo, max: hi }),
            given,
            names,
        );
        Ok(t)
    }

    /// For outputs made from `rec`, a recording held in memory (columns handed to
    /// [`recording::read_columns`]) described as `input`, with local gravity and its
    /// uncertainty as given by the arguments named `names`, if they were.
    pub fn of_held(
        build: Build,
        rec: &recording::Recording,
        input: Input,
        given: (Option<f64>, Option<f64>),
        names: (&str, &str),
    ) -> Self {
        let mut t = Traceability {
            inputs: vec![input],
            ..Traceability::empty(build)
        };
        let groups = rec.groups.iter().filter_map(|g| g.temp_c.as_ref());
        let poses = rec.oriented.as_ref().and_then(|o| o.temp_c.as_ref());
        let series = rec.series.as_ref().and_then(|s| s.temp_c.as_ref());
        let (lo, hi) = groups
            .chain(poses)
            .chain(series)
            .flatten()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
                (lo.min(*x), hi.max(*x))
            });
        t.facts(
            &rec.meta,
            (lo <= hi).then_some(Range { min: lo, max: hi }),
            given,
            names,
        );
        t
    }

    /// For outputs made from columns held in memory and not kept as a recording (the
    /// Python package's DataFrames, calibrated in parts): the facts from their metadata
    /// `meta` (`# key=value` pairs) and their `temp_c` column, `input` their digest.
    pub fn of_columns(
        build: Build,
        columns: &[recording::Column<'_>],
        meta: &[(&str, &str)],
        input: Input,
        given: (Option<f64>, Option<f64>),
        names: (&str, &str),
    ) -> Result<Self, TraceError> {
        let text: String = meta.iter().map(|(k, v)| format!("# {k}={v}\n")).collect();
        let meta = recording::read_preamble(&text, &input.path, 0)?;
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for c in columns.iter().filter(|c| c.name == "temp_c") {
            let mut take = |x: f64| (lo, hi) = (lo.min(x), hi.max(x));
            match c.values {
                recording::Values::Numbers(x) => x.iter().for_each(|x| take(*x)),
                recording::Values::Texts(t) => t
                    .iter()
                    .filter_map(|x| x.trim().parse::<f64>().ok())
                    .for_each(take),
                recording::Values::Letters(_) => {}
            }
        }
        let mut t = Traceability {
            inputs: vec![input],
            ..Traceability::empty(build)
        };
        t.facts(
            &meta,
            (lo <= hi).then_some(Range { min: lo, max: hi }),
            given,
            names,
        );
        Ok(t)
    }

    /// The block without inputs or facts.
    fn empty(build: Build) -> Self {
        Traceability {
            rotacal: build.version.into(),
            commit: build.commit.into(),
            date_utc: utc_now(),
            command_line: std::env::args().collect(),
            inputs: Vec::new(),
            device: None,
            firmware: None,
            temperature_c: None,
            g_loc: None,
            calibration: None,
        }
    }

    /// The recording's facts: device and firmware from `meta`, the temperature range, and
    /// local gravity with its uncertainty (`given` by the arguments `names`, else `meta`'s).
    fn facts(
        &mut self,
        meta: &recording::Metadata,
        temperature_c: Option<Range>,
        given: (Option<f64>, Option<f64>),
        names: (&str, &str),
    ) {
        self.firmware = meta.device.as_deref().and_then(firmware);
        self.device = meta.device.clone();
        self.temperature_c = temperature_c;
        let value = given
            .0
            .map(|g| (g, names.0))
            .or(meta.g_loc.map(|g| (g, "the recording's g_loc")));
        let unc = given.1.map(|u| (u, names.1)).or(meta
            .other
            .get("u_g_loc")
            .and_then(|u| u.parse().ok())
            .map(|u| (u, "the recording's u_g_loc")));
        self.g_loc = value.map(|(value, source)| Gravity {
            value,
            source: source.into(),
            std_unc: unc.map(|u| u.0),
            std_unc_source: unc.map_or("not given".into(), |u| u.1.into()),
        });
    }

    /// For outputs made from the calibration JSON at `path`: its facts of the device,
    /// temperature and gravity, and its own block.
    pub fn of_calibration(build: Build, path: &Path) -> Result<Self, TraceError> {
        let mut t = Traceability::new(build, &[path])?;
        let text = std::fs::read_to_string(path).map_err(io_at(path))?;
        let json: serde_json::Value =
            serde_json::from_str(&text).map_err(|error| TraceError::Json {
                path: path.display().to_string(),
                error,
            })?;
        if let Some(c) = json.get("traceability") {
            let s = |k: &str| c.get(k).and_then(|v| v.as_str()).map(String::from);
            t.device = s("device");
            t.firmware = s("firmware");
            t.temperature_c = c.get("temperature_c").and_then(|r| {
                Some(Range {
                    min: r.get("min")?.as_f64()?,
                    max: r.get("max")?.as_f64()?,
                })
            });
            t.g_loc = c.get("g_loc").and_then(|g| {
                Some(Gravity {
                    value: g.get("value")?.as_f64()?,
                    source: g.get("source")?.as_str()?.into(),
                    std_unc: g.get("std_unc").and_then(serde_json::Value::as_f64),
                    std_unc_source: g.get("std_unc_source")?.as_str()?.into(),
                })
            });
            t.calibration = Some(c.clone());
        }
        Ok(t)
    }

    /// For outputs calibrated from the recording at `path` with `opts`: its method, and
    /// the local gravity and uncertainty the command line gave, if it did.
    pub fn of_calibrating(
        build: Build,
        path: &Path,
        opts: &crate::calibrate::Options,
    ) -> Result<Self, TraceError> {
        Traceability::of_recording(build, path, opts.method, opts.g_loc, opts.inputs.u_g_loc)
    }

    /// The block as a recording's `# key=value` metadata, each input named by its label
    /// in `labels` (in order): `rotacal`, `rotacal_commit`, `date_utc`, `command_line`,
    /// then `LABEL_sha256` per input (docs/formats.md).
    pub fn as_metadata(&self, labels: &[&str]) -> Vec<(String, String)> {
        let mut m = vec![
            ("rotacal".into(), self.rotacal.clone()),
            ("rotacal_commit".into(), self.commit.clone()),
            ("date_utc".into(), self.date_utc.clone()),
            ("command_line".into(), self.command_line.join(" ")),
        ];
        for (label, i) in labels.iter().zip(&self.inputs) {
            m.push((format!("{label}_sha256"), i.sha256.clone()));
        }
        m
    }

    /// The Markdown file at `path` with this block added at its end (written whole).
    pub fn append_to(&self, path: &Path) -> Result<(), TraceError> {
        let md = std::fs::read_to_string(path).map_err(io_at(path))?;
        crate::atomic::write(path, md + "\n" + &self.markdown()).map_err(io_at(path))
    }

    /// The block as Markdown: a heading and a table.
    pub fn markdown(&self) -> String {
        let mut rows = vec![
            ("rotacal", format!("{} ({})", self.rotacal, self.commit)),
            ("date (UTC)", self.date_utc.clone()),
            ("command line", format!("`{}`", self.command_line.join(" "))),
        ];
        for i in &self.inputs {
            rows.push((
                "input",
                format!("{} ({} bytes, SHA-256 {})", i.path, i.bytes, i.sha256),
            ));
        }
        if let Some(c) = &self.calibration {
            let s = |k: &str| c.get(k).and_then(|v| v.as_str()).unwrap_or("?").to_string();
            let recording = c
                .get("inputs")
                .and_then(|i| i.get(0))
                .map_or("?".into(), |i| {
                    format!(
                        "{} (SHA-256 {})",
                        i.get("path").and_then(|v| v.as_str()).unwrap_or("?"),
                        i.get("sha256").and_then(|v| v.as_str()).unwrap_or("?")
                    )
                });
            rows.push((
                "calibration",
                format!(
                    "made by rotacal {} ({}) on {} from {recording}",
                    s("rotacal"),
                    s("commit"),
                    s("date_utc")
                ),
            ));
        }
        rows.push(("device", self.device.clone().unwrap_or("not stated".into())));
        rows.push((
            "firmware",
            self.firmware.clone().unwrap_or("not stated".into()),
        ));
        rows.push((
            "temperature",
            self.temperature_c.map_or("not recorded".into(), |r| {
                format!("{} to {} °C", r.min, r.max)
            }),
        ));
        rows.push((
            "g_loc",
            self.g_loc.as_ref().map_or("not given".into(), |g| {
                let u = g.std_unc.map_or("not given".into(), |u| {
                    format!("{u} m/s² ({})", g.std_unc_source)
                });
                format!("{} m/s² ({}), standard uncertainty {u}", g.value, g.source)
            }),
        ));
        let mut md = String::from("## Traceability\n\n| | |\n| --- | --- |\n");
        for (k, v) in rows {
            md.push_str(&format!("| {k} | {} |\n", v.replace('|', "\\|")));
        }
        md
    }

    /// The block as comment lines, each starting with `prefix`.
    pub fn comment(&self, prefix: &str) -> String {
        self.markdown()
            .lines()
            .skip(4)
            .map(|l| {
                let cells: Vec<&str> = l.trim_matches('|').splitn(2, " | ").collect();
                format!(
                    "{prefix}{}: {}\n",
                    cells.first().unwrap_or(&"").trim(),
                    cells.get(1).unwrap_or(&"").trim().trim_matches('`')
                )
            })
            .collect()
    }

    /// `value` (which serialises as a JSON object) as pretty JSON with this block added
    /// last, under `traceability`: the object's own keys keep their order.
    pub fn json<T: Serialize>(&self, value: &T) -> serde_json::Result<String> {
        #[derive(Serialize)]
        struct With<'a, T: Serialize> {
            #[serde(flatten)]
            value: &'a T,
            traceability: &'a Traceability,
        }
        Ok(serde_json::to_string_pretty(&With {
            value,
            traceability: self,
        })? + "\n")
    }
}

/// "A.B.C" from a device description "… firmware A.B.C …".
fn firmware(device: &str) -> Option<String> {
    let rest = device.split("firmware ").nth(1)?;
    let v: String = rest
        .chars()
        .take_while(|c| c.is_ascii_digit() || *c == '.')
        .collect();
    (!v.is_empty()).then_some(v)
}

/// Now, UTC, as `YYYY-MM-DDTHH:MM:SSZ`.
fn utc_now() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    utc(secs)
}

/// `secs` since 1970 as `YYYY-MM-DDTHH:MM:SSZ` (the proleptic Gregorian calendar; days to
/// a civil date by H. Hinnant's algorithm).
fn utc(secs: u64) -> String {
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dates_and_firmware() {
        assert_eq!(utc(0), "1970-01-01T00:00:00Z");
        assert_eq!(utc(951_782_400), "2000-02-29T00:00:00Z");
        assert_eq!(utc(1_795_824_000 + 3723), "2026-11-28T01:02:03Z");
        assert_eq!(
            firmware("LSM6DS33 firmware 0.2.0 (BLE device F1:23:45:67:89:AB)").as_deref(),
            Some("0.2.0")
        );
        assert_eq!(firmware("simulated LSM6DS33"), None);
    }
}
