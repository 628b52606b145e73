//! `rotacal import`: generic text logs (a timestamp and three readings per line, as the
//! papers' set-ups wrote them, or any delimited columns) into the recording format.
//!
//! A column map names which field holds what (0-based): `t=0,u=1,v=2,w=3`, optionally
//! `condition=`, `angle=`, `temp=`, `seq=`. Fields are split on commas, semicolons, tabs
//! or runs of spaces (detected per line). Empty lines and lines starting with `#` are
//! skipped, as are the first `skip` lines (headers). Lines are read and written one at a
//! time. Every problem names the file and line.

use crate::recording::{Columns, Metadata, Method, Row, Writer};
use rotacal_shared::Condition;
use std::io::{BufRead, Write};

/// Which field holds what.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ColumnMap {
    /// Time.
    pub t: Option<usize>,
    /// Channels.
    pub u: usize,
    /// See `u`.
    pub v: usize,
    /// See `u`.
    pub w: usize,
    /// Condition letter per line.
    pub condition: Option<usize>,
    /// Table angle, degrees (static logs).
    pub angle: Option<usize>,
    /// Temperature, °C.
    pub temp: Option<usize>,
    /// Sample sequence number.
    pub seq: Option<usize>,
}

impl std::str::FromStr for ColumnMap {
    type Err = String;
    /// `t=0,u=1,v=2,w=3[,condition=4][,angle=5][,temp=6][,seq=7]`.
    fn from_str(s: &str) -> Result<Self, String> {
        let mut m = ColumnMap::default();
        let (mut u, mut v, mut w) = (None, None, None);
        for part in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let (k, i) = part
                .split_once('=')
                .ok_or_else(|| format!("'{part}': expected NAME=INDEX"))?;
            let i: usize = i
                .trim()
                .parse()
                .map_err(|_| format!("'{part}': the index must be a whole number (0-based)"))?;
            let slot = match k.trim() {
                "t" => &mut m.t,
                "u" => &mut u,
                "v" => &mut v,
                "w" => &mut w,
                "condition" => &mut m.condition,
                "angle" => &mut m.angle,
                "temp" => &mut m.temp,
                "seq" => &mut m.seq,
                other => {
                    return Err(format!(
                        "unknown column '{other}' (known: t, u, v, w, condition, angle, temp, seq)"
                    ))
                }
            };
            if slot.replace(i).is_some() {
                return Err(format!("'{}' given twice", k.trim()));
            }
        }
        match (u, v, w) {
            (Some(u), Some(v), Some(w)) => {
                m.u = u;
                m.v = v;
                m.w = w;
            }
            _ => return Err("u, v and w are all required".into()),
        }
        if m.t.is_none() && m.angle.is_none() {
            return Err("give t (rotation) or angle (static)".into());
        }
        Ok(m)
    }
}

/// What to import.
#[derive(Clone, Debug)]
pub struct ImportSpec {
    /// The column map.
    pub columns: ColumnMap,
    /// The condition of each input, when there is no condition column.
    pub conditions: Vec<Condition>,
    /// Leading lines to skip in each input (headers).
    pub skip: usize,
    /// Seconds per unit of the time column.
    pub time_scale: f64,
    /// Metadata to write.
    pub meta: Metadata,
}

/// A problem, naming the place.
#[derive(Debug, thiserror::Error)]
#[error("{source_name}{}: {message}", line.map(|l| format!(":{l}")).unwrap_or_default())]
pub struct ImportError {
    /// The input.
    pub source_name: String,
    /// Its line, if one.
    pub line: Option<usize>,
    /// What is wrong.
    pub message: String,
}

fn split(line: &str) -> Vec<&str> {
    if line.contains(',') {
        line.split(',').map(str::trim).collect()
    } else if line.contains(';') {
        line.split(';').map(str::trim).collect()
    } else {
        line.split_whitespace().collect()
    }
}

/// Rows written per input.
pub type Counts = Vec<usize>;

/// Convert `inputs` (name, reader) into one recording written to `out`.
pub fn import<W: Write>(
    inputs: Vec<(String, Box<dyn BufRead + '_>)>,
    spec: &ImportSpec,
    out: W,
) -> Result<Counts, ImportError> {
    let c = &spec.columns;
    let whole = |message: String| ImportError {
        source_name: "import".into(),
        line: None,
        message,
    };
    if c.condition.is_none() && spec.conditions.len() != inputs.len() {
        return Err(whole(format!(
            "{} input(s) but {} condition(s): give one --condition per input, or a condition column",
            inputs.len(),
            spec.conditions.len()
        )));
    }
    if !(spec.time_scale.is_finite() && spec.time_scale > 0.0) {
        return Err(whole("--time-scale must be positive".into()));
    }
    let columns = Columns {
        t_s: c.t.is_some(),
        angle_deg: c.angle.is_some(),
        seq: c.seq.is_some(),
        temp_c: c.temp.is_some(),
        rate_hz: false,
    };
    let mut meta = spec.meta.clone();
    meta.method = meta.method.or(Some(if c.t.is_some() {
        Method::Rotation
    } else {
        Method::Static
    }));
    let mut w = Writer::new(out, &meta, &columns).map_err(|e| whole(e.to_string()))?;
    let mut counts = Vec::new();
    let mut last_t: Vec<(Condition, f64)> = Vec::new();
    for (k, (name, reader)) in inputs.into_iter().enumerate() {
        let mut n = 0;
        for (i, line) in reader.lines().enumerate() {
            let lineno = i + 1;
            let err = |message: String| ImportError {
                source_name: name.clone(),
                line: Some(lineno),
                message,
            };
            let line = line.map_err(|e| err(format!("cannot read: {e}")))?;
            let trimmed = line.trim();
            if i < spec.skip || trimmed.is_empty() || trimmed.starts_with('#') {
                continue;
            }
            let fields = split(trimmed);
            let field = |idx: usize, what: &str| -> Result<&str, ImportError> {
                fields.get(idx).copied().ok_or_else(|| {
                    err(format!(
                        "no field {idx} for {what}: the line has {} fields",
                        fields.len()
                    ))
                })
            };
            let num = |idx: usize, what: &str| -> Result<f64, ImportError> {
                let f = field(idx, what)?;
                match f.parse::<f64>() {
                    Ok(x) if x.is_finite() => Ok(x),
                    _ => Err(err(format!(
                        "{what} (field {idx}) '{f}' is not a finite number"
                    ))),
                }
            };
            let condition = match c.condition {
                Some(idx) => {
                    let f = field(idx, "condition")?;
                    let mut chars = f.chars();
                    match (chars.next().and_then(Condition::from_letter), chars.next()) {
                        (Some(c), None) => c,
                        _ => return Err(err(format!("condition '{f}': expected x, y or z"))),
                    }
                }
                None => *spec
                    .conditions
                    .get(k)
                    .ok_or_else(|| err("no condition for this input".into()))?,
            };
            let mut row = Row::new(condition, num(c.u, "u")?, num(c.v, "v")?, num(c.w, "w")?);
            if let Some(idx) = c.t {
                let t = num(idx, "t")? * spec.time_scale;
                match last_t.iter_mut().find(|(cd, _)| *cd == condition) {
                    Some((_, prev)) if t < *prev => {
                        return Err(err(format!(
                            "time went backwards in condition {}: {t} s after {prev} s",
                            condition.letter()
                        )))
                    }
                    Some((_, prev)) => *prev = t,
                    None => last_t.push((condition, t)),
                }
                row.t_s = Some(t);
            }
            if let Some(idx) = c.angle {
                row.angle_deg = Some(num(idx, "angle")?);
            }
            if let Some(idx) = c.temp {
                row.temp_c = Some(num(idx, "temp")?);
            }
            if let Some(idx) = c.seq {
                let f = field(idx, "seq")?;
                row.seq =
                    Some(f.parse().map_err(|_| {
                        err(format!("seq (field {idx}) '{f}' is not a whole number"))
                    })?);
            }
            w.write_row(&row).map_err(|e| err(e.to_string()))?;
            n += 1;
        }
        if n == 0 {
            return Err(ImportError {
                source_name: name,
                line: None,
                message: "no data lines".into(),
            });
        }
        counts.push(n);
    }
    w.flush().map_err(|e| whole(e.to_string()))?;
    Ok(counts)
}
