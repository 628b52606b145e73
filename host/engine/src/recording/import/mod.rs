//! `rotacal import`: logs (a timestamp and three readings per line, as the papers' set-ups
//! wrote them, a logger's CSV, a German spreadsheet's export, an Excel workbook) into the
//! recording format.
//!
//! A column map names which field holds what, by its 0-based number or by its name in the
//! header line: `t=0,u=1,v=2,w=3` or `t=time,u=ax,v=ay,w=az`, optionally `condition=`,
//! `angle=`, `temp=`, `seq=`. A text input's delimiter is found on its first data line
//! (a semicolon, else a tab, else a comma, else runs of spaces), and where it is not a
//! comma, a comma in a number is a decimal comma. Empty lines and lines starting with `#`
//! are skipped, as are the first `skip` lines. Lines before the first line with a number
//! are a preamble (a logger's banner), whose last line is the header. Readings are
//! multiplied by `scale` (LSB to g, say). Lines are read and written one at a time. Every
//! problem names the file and line.
//!
//! Static sessions from known orientations (six-position and the like) come with a section
//! list (imucal's JSON: `{"x_p": {"start": 540, "end": 1271}, ...}`, data-row positions
//! counted from 0 after the skipped lines and the header, `start` inclusive and `end`
//! exclusive) and a pose map that gives each section's gravity direction
//! (`x_p=+x,x_a=-x,...`). Rows in mapped sections are written with `pose, gx, gy, gz`;
//! other rows are left out.
//!
//! Problems are [`ImportError`]s (`error`): the input, the line, and the field and its
//! text as fields of an [`ImportErrorKind`].

mod error;
mod table;
#[cfg(test)]
mod tests;

pub use error::{ColumnMapError, ImportError, ImportErrorKind, PoseMapError, SpecError};
pub use table::{is_spreadsheet, sheet, Input, Rows};

use crate::recording::{Columns, Metadata, Method, Row, Writer};
use rotacal_shared::Condition;
use std::io::Write;
use ImportErrorKind as K;

/// A field of the input: by its 0-based number, or by its name in the header line
/// (matched without regard to case).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Col {
    /// The field's number, from 0.
    At(usize),
    /// The header's name of it.
    Named(String),
}

/// Which field holds what.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ColumnMap {
    /// Time.
    pub t: Option<Col>,
    /// Channels.
    pub u: Col,
    /// See `u`.
    pub v: Col,
    /// See `u`.
    pub w: Col,
    /// Condition letter per line.
    pub condition: Option<Col>,
    /// Table angle, degrees (static logs).
    pub angle: Option<Col>,
    /// Temperature, °C.
    pub temp: Option<Col>,
    /// Sample sequence number.
    pub seq: Option<Col>,
}

impl ColumnMap {
    /// The fields' numbers, names looked up in `header` (`None`: no header line).
    fn resolve(&self, header: Option<&[String]>) -> Result<Fields, ImportErrorKind> {
        let find = |column: &'static str, c: &Col| -> Result<usize, ImportErrorKind> {
            match c {
                Col::At(i) => Ok(*i),
                Col::Named(name) => {
                    let header = header.ok_or_else(|| K::NoHeader {
                        column,
                        name: name.clone(),
                    })?;
                    header
                        .iter()
                        .position(|h| h.eq_ignore_ascii_case(name))
                        .ok_or_else(|| K::NoSuchColumn {
                            column,
                            name: name.clone(),
                            header: header.join(" | "),
                        })
                }
            }
        };
        let opt = |column, c: &Option<Col>| c.as_ref().map(|c| find(column, c)).transpose();
        Ok(Fields {
            t: opt("t", &self.t)?,
            u: find("u", &self.u)?,
            v: find("v", &self.v)?,
            w: find("w", &self.w)?,
            condition: opt("condition", &self.condition)?,
            angle: opt("angle", &self.angle)?,
            temp: opt("temp", &self.temp)?,
            seq: opt("seq", &self.seq)?,
        })
    }
}

/// A column map with every field by number: an input's, once its header is read.
#[derive(Clone, Copy, Debug)]
struct Fields {
    t: Option<usize>,
    u: usize,
    v: usize,
    w: usize,
    condition: Option<usize>,
    angle: Option<usize>,
    temp: Option<usize>,
    seq: Option<usize>,
}

impl std::str::FromStr for ColumnMap {
    type Err = ColumnMapError;
    /// `t=0,u=1,v=2,w=3[,condition=4][,angle=5][,temp=6][,seq=7]`, each field a number
    /// from 0 or a header's name.
    fn from_str(s: &str) -> Result<Self, ColumnMapError> {
        let mut slots: [Option<Col>; 8] = Default::default();
        const NAMES: [&str; 8] = ["t", "u", "v", "w", "condition", "angle", "temp", "seq"];
        for part in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let (k, f) = part
                .split_once('=')
                .ok_or_else(|| ColumnMapError::NoIndex {
                    part: part.to_string(),
                })?;
            let f = f.trim();
            let col = if f.starts_with(|c: char| c.is_ascii_digit() || c == '-' || c == '+') {
                Col::At(f.parse().map_err(|_| ColumnMapError::BadIndex {
                    part: part.to_string(),
                })?)
            } else if f.is_empty() {
                return Err(ColumnMapError::BadIndex {
                    part: part.to_string(),
                });
            } else {
                Col::Named(f.to_string())
            };
            let slot = NAMES
                .iter()
                .position(|n| *n == k.trim())
                .and_then(|i| slots.get_mut(i))
                .ok_or_else(|| ColumnMapError::UnknownColumn {
                    name: k.trim().to_string(),
                })?;
            if slot.replace(col).is_some() {
                return Err(ColumnMapError::Twice {
                    name: k.trim().to_string(),
                });
            }
        }
        let [t, u, v, w, condition, angle, temp, seq] = slots;
        let (Some(u), Some(v), Some(w)) = (u, v, w) else {
            return Err(ColumnMapError::NoChannels);
        };
        if t.is_none() && angle.is_none() {
            return Err(ColumnMapError::NoTimeOrAngle);
        }
        Ok(ColumnMap {
            t,
            u,
            v,
            w,
            condition,
            angle,
            temp,
            seq,
        })
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
    /// What the readings are multiplied by (1: as they are).
    pub scale: f64,
    /// Metadata to write.
    pub meta: Metadata,
    /// Sections and their gravity directions (static data from known orientations).
    pub poses: Option<PoseSections>,
}

/// A section list with a pose map: which data rows belong to which pose, and the pose's
/// gravity direction (of the reading, in the platter frame).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PoseSections {
    /// (name, first data row, one past the last), sorted by name.
    pub sections: Vec<(String, usize, usize)>,
    /// (section name, ĝ) for the sections to import.
    pub map: Vec<(String, [f64; 3])>,
}

impl PoseSections {
    /// Read a section list (imucal's JSON) from `text`; `source` names it in messages.
    pub fn sections_from_json(
        text: &str,
        source: &str,
    ) -> Result<Vec<(String, usize, usize)>, ImportError> {
        let bad = |kind: ImportErrorKind| ImportError::at(source, None, kind);
        let v: serde_json::Value = serde_json::from_str(text)
            .map_err(|e| ImportError::at(source, Some(e.line()), K::NotJson(e)))?;
        let obj = v.as_object().ok_or_else(|| bad(K::NotSections))?;
        let mut out = Vec::new();
        for (name, sec) in obj {
            let idx = |key: &'static str| -> Result<usize, ImportError> {
                let x = sec.get(key).ok_or_else(|| {
                    bad(K::NoBound {
                        section: name.clone(),
                        key,
                    })
                })?;
                x.as_u64()
                    .and_then(|n| usize::try_from(n).ok())
                    .ok_or_else(|| {
                        bad(K::NotRowIndex {
                            section: name.clone(),
                            key,
                            text: x.to_string(),
                        })
                    })
            };
            let (start, end) = (idx("start")?, idx("end")?);
            if end <= start {
                return Err(bad(K::EmptySection {
                    section: name.clone(),
                    start,
                    end,
                }));
            }
            out.push((name.clone(), start, end));
        }
        if out.is_empty() {
            return Err(bad(K::NoSections));
        }
        let mut sorted = out.clone();
        sorted.sort_by_key(|s| s.1);
        for w in sorted.windows(2) {
            if let [a, b] = w {
                if b.1 < a.2 {
                    return Err(bad(K::Overlap {
                        first: a.0.clone(),
                        second: b.0.clone(),
                    }));
                }
            }
        }
        Ok(out)
    }

    /// Parse a pose map: `NAME=DIR,...` where DIR is `+x`, `-x`, `+y`, `-y`, `+z`, `-z`
    /// (the axis that reads +g or −g) or a unit vector `gx:gy:gz`.
    pub fn map_from_str(s: &str) -> Result<Vec<(String, [f64; 3])>, PoseMapError> {
        let mut out: Vec<(String, [f64; 3])> = Vec::new();
        for part in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let (name, dir) = part
                .split_once('=')
                .ok_or_else(|| PoseMapError::NoDirection {
                    part: part.to_string(),
                })?;
            let (name, dir) = (name.trim(), dir.trim());
            let g = match dir {
                "+x" | "x" => [1.0, 0.0, 0.0],
                "-x" => [-1.0, 0.0, 0.0],
                "+y" | "y" => [0.0, 1.0, 0.0],
                "-y" => [0.0, -1.0, 0.0],
                "+z" | "z" => [0.0, 0.0, 1.0],
                "-z" => [0.0, 0.0, -1.0],
                v => {
                    let c: Vec<f64> = v
                        .split(':')
                        .map(|x| x.trim().parse::<f64>())
                        .collect::<Result<_, _>>()
                        .map_err(|_| PoseMapError::BadDirection {
                            part: part.to_string(),
                        })?;
                    let [x, y, z] = c.as_slice() else {
                        return Err(PoseMapError::NotThree {
                            part: part.to_string(),
                        });
                    };
                    let norm = (x * x + y * y + z * z).sqrt();
                    if (norm - 1.0).abs().is_nan()
                        || (norm - 1.0).abs() > crate::recording::UNIT_TOLERANCE
                    {
                        return Err(PoseMapError::NotUnit {
                            part: part.to_string(),
                            norm,
                        });
                    }
                    [x / norm, y / norm, z / norm]
                }
            };
            if out.iter().any(|(n, _)| n == name) {
                return Err(PoseMapError::Twice {
                    name: name.to_string(),
                });
            }
            out.push((name.to_string(), g));
        }
        if out.is_empty() {
            return Err(PoseMapError::Empty);
        }
        Ok(out)
    }
}

/// What was written.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Counts {
    /// Rows per input.
    pub rows: Vec<usize>,
    /// With a section list: rows per pose of the map, in map order.
    pub poses: Vec<(String, usize)>,
    /// With a section list: the sections left out (not in the pose map).
    pub skipped_sections: Vec<String>,
}

/// Convert `inputs` into one recording written to `out`.
pub fn import<W: Write>(
    inputs: Vec<Input<'_>>,
    spec: &ImportSpec,
    out: W,
) -> Result<Counts, ImportError> {
    let c = &spec.columns;
    let whole = |kind: ImportErrorKind| ImportError::at("import", None, kind);
    // Neither conditions nor a section list: a free recording (still poses of unknown
    // orientation, found by `calibrate --method free`).
    let free = c.condition.is_none()
        && spec.poses.is_none()
        && spec.conditions.is_empty()
        && c.angle.is_none();
    check_spec(spec, inputs.len(), free).map_err(|e| whole(K::Spec(e)))?;
    let mut meta = spec.meta.clone();
    meta.method = meta.method.or(Some(method(spec, free)));
    let mut w = Writer::new(out, &meta, &columns(spec)).map_err(|e| whole(K::Write(e)))?;
    let mut importer = Importer {
        spec,
        free,
        last_t: Vec::new(),
        per_pose: vec![0usize; spec.poses.as_ref().map_or(0, |p| p.map.len())],
        data_row: 0,
    };
    let mut counts = Counts::default();
    for (k, input) in inputs.into_iter().enumerate() {
        let n = importer.input(k, &input.name, input.rows, &mut w)?;
        counts.rows.push(n);
    }
    w.flush().map_err(|e| whole(K::Write(e)))?;
    if let Some(p) = &spec.poses {
        counts.poses = p
            .map
            .iter()
            .map(|m| m.0.clone())
            .zip(importer.per_pose)
            .collect();
        counts.skipped_sections = p
            .sections
            .iter()
            .filter(|s| !p.map.iter().any(|m| m.0 == s.0))
            .map(|s| s.0.clone())
            .collect();
    }
    Ok(counts)
}

/// Refuse a spec that does not fit its `inputs` inputs (`free`: imported as a free
/// recording), before anything is written.
fn check_spec(spec: &ImportSpec, inputs: usize, free: bool) -> Result<(), SpecError> {
    let c = &spec.columns;
    if free && (inputs != 1 || c.t.is_none()) {
        return Err(SpecError::Free);
    }
    if !free && c.condition.is_none() && spec.poses.is_none() && spec.conditions.len() != inputs {
        return Err(SpecError::Conditions {
            inputs,
            conditions: spec.conditions.len(),
        });
    }
    if !(spec.time_scale.is_finite() && spec.time_scale > 0.0) {
        return Err(SpecError::TimeScale(spec.time_scale));
    }
    if !(spec.scale.is_finite() && spec.scale != 0.0) {
        return Err(SpecError::Scale(spec.scale));
    }
    if let Some(p) = &spec.poses {
        if inputs != 1 {
            return Err(SpecError::SectionsInputs { inputs });
        }
        if c.condition.is_some() || c.angle.is_some() || !spec.conditions.is_empty() {
            return Err(SpecError::PosesAndConditions);
        }
        if let Some((name, _)) = p
            .map
            .iter()
            .find(|(n, _)| !p.sections.iter().any(|s| &s.0 == n))
        {
            return Err(SpecError::UnknownSection { pose: name.clone() });
        }
    }
    Ok(())
}

/// The columns the recording gets from the column map and the section list.
fn columns(spec: &ImportSpec) -> Columns {
    let c = &spec.columns;
    Columns {
        t_s: c.t.is_some(),
        angle_deg: c.angle.is_some(),
        seq: c.seq.is_some(),
        temp_c: c.temp.is_some(),
        rate_hz: false,
        gravity: spec.poses.is_some(),
        pose: spec.poses.is_some(),
        unc: false,
        conv_gaps: false,
        conv_missed: false,
        boot: false,
    }
}

/// The recording's method when the metadata does not give one (`free`: imported as a
/// free recording).
fn method(spec: &ImportSpec, free: bool) -> Method {
    if free {
        Method::Free
    } else if spec.poses.is_some() {
        Method::Static
    } else if spec.columns.t.is_some() {
        Method::Rotation
    } else {
        Method::Static
    }
}

/// One data line's fields, and where the line is (for its errors).
struct Line<'a> {
    source: &'a str,
    /// 1-based.
    lineno: usize,
    fields: Vec<String>,
    /// A comma in a number is a decimal comma (the fields are not comma-separated).
    decimal_comma: bool,
}

impl<'a> Line<'a> {
    /// `line` of input `source`, its text split at `delimiter`.
    fn of(source: &'a str, line: &table::Line, delimiter: Option<table::Delimiter>) -> Self {
        match line {
            table::Line::Cells(lineno, cells) => Line {
                source,
                lineno: *lineno,
                fields: cells.clone(),
                decimal_comma: true,
            },
            table::Line::Text(lineno, text) => {
                let d = delimiter.unwrap_or_else(|| table::Delimiter::of(text));
                Line {
                    source,
                    lineno: *lineno,
                    fields: d.split(text),
                    decimal_comma: d.decimal_comma(),
                }
            }
        }
    }

    /// `kind` at this line.
    fn err(&self, kind: ImportErrorKind) -> ImportError {
        ImportError::at(self.source, Some(self.lineno), kind)
    }

    /// Field `idx`, which holds `column`.
    fn field(&self, idx: usize, column: &'static str) -> Result<&str, ImportError> {
        self.fields.get(idx).map(String::as_str).ok_or_else(|| {
            self.err(K::NoField {
                field: idx,
                column,
                fields: self.fields.len(),
            })
        })
    }

    /// Field `idx`, which holds `column`, as a finite number.
    fn num(&self, idx: usize, column: &'static str) -> Result<f64, ImportError> {
        let f = self.field(idx, column)?;
        match table::number(f, self.decimal_comma) {
            Some(x) if x.is_finite() => Ok(x),
            _ => Err(self.err(K::NotFinite {
                field: idx,
                column,
                text: f.to_string(),
            })),
        }
    }

    /// Whether any field is a number: a data line, not a header or a banner.
    fn has_number(&self) -> bool {
        self.fields
            .iter()
            .any(|f| table::number(f, self.decimal_comma).is_some())
    }
}

/// Lines before the first data line that are kept to find the header among: a logger's
/// banner is a few lines.
const PREAMBLE: usize = 100;

/// Reads the inputs' lines into rows, carrying over what a line is checked against or
/// counted in.
struct Importer<'s> {
    spec: &'s ImportSpec,
    /// Imported as a free recording.
    free: bool,
    /// Each condition's last time: time must not go backwards.
    last_t: Vec<(Condition, f64)>,
    /// With a section list: rows per mapped section, in map order.
    per_pose: Vec<usize>,
    /// With a section list: the data-row position.
    data_row: usize,
}

impl<'s> Importer<'s> {
    /// Input `k`'s data lines, named `name`, written to `w`: how many there were.
    fn input<W: Write>(
        &mut self,
        k: usize,
        name: &str,
        rows: Rows<'_>,
        w: &mut Writer<W>,
    ) -> Result<usize, ImportError> {
        let spec = self.spec;
        let mut n = 0;
        // The lines before the first with a number (a banner, the header last), and the
        // input's delimiter and fields, found on its first data line.
        let mut preamble: Vec<table::Line> = Vec::new();
        let mut found: Option<(Option<table::Delimiter>, Fields)> = None;
        for line in table::lines(name, rows, spec.skip) {
            let line = line?;
            let delimiter = match (&found, &line) {
                (Some((d, _)), _) => *d,
                (None, table::Line::Text(_, text)) => Some(table::Delimiter::of(text)),
                (None, table::Line::Cells(..)) => None,
            };
            let data = Line::of(name, &line, delimiter);
            let cols = match found {
                Some((_, f)) => f,
                None if !data.has_number() => {
                    if preamble.len() >= PREAMBLE {
                        return Err(data.err(K::NoDataLine { lines: PREAMBLE }));
                    }
                    preamble.push(line);
                    continue;
                }
                None => {
                    let header = preamble.last().map(|h| Line::of(name, h, delimiter));
                    let f = spec
                        .columns
                        .resolve(header.as_ref().map(|h| h.fields.as_slice()))
                        .map_err(|kind| header.as_ref().unwrap_or(&data).err(kind))?;
                    found = Some((delimiter, f));
                    f
                }
            };
            // The pose of this data row, if a section list is given.
            let mut pose: Option<(&str, [f64; 3], usize)> = None;
            if let Some(p) = &spec.poses {
                let at = self.data_row;
                self.data_row += 1;
                let section = p.sections.iter().find(|s| (s.1..s.2).contains(&at));
                match section.and_then(|s| p.map.iter().enumerate().find(|(_, m)| m.0 == s.0)) {
                    Some((mi, (pname, g))) => pose = Some((pname.as_str(), *g, mi)),
                    None => continue,
                }
            }
            let row = self.row(k, &cols, &data, pose).map_err(|e| {
                if n == 0 {
                    first_line_hint(e, spec.skip)
                } else {
                    e
                }
            })?;
            w.write_row(&row).map_err(|e| data.err(K::Write(e)))?;
            n += 1;
        }
        if let Some(p) = &spec.poses {
            if let Some(s) = p.sections.iter().find(|s| s.2 > self.data_row) {
                return Err(ImportError::at(
                    name,
                    None,
                    K::SectionPastEnd {
                        section: s.0.clone(),
                        end: s.2,
                        rows: self.data_row,
                    },
                ));
            }
        }
        if n == 0 {
            return Err(ImportError::at(name, None, K::NoData));
        }
        Ok(n)
    }

    /// The row of data line `line` of input `k` (`pose`: its pose's name, ĝ and place in
    /// the map, with a section list).
    fn row(
        &mut self,
        k: usize,
        c: &Fields,
        line: &Line<'_>,
        pose: Option<(&'s str, [f64; 3], usize)>,
    ) -> Result<Row<'s>, ImportError> {
        let condition = self.condition(k, c, line, pose.is_some())?;
        let scale = self.spec.scale;
        let mut row = Row::new(
            condition,
            line.num(c.u, "u")? * scale,
            line.num(c.v, "v")? * scale,
            line.num(c.w, "w")? * scale,
        );
        if let Some(idx) = c.t {
            let t = line.num(idx, "t")? * self.spec.time_scale;
            match self.last_t.iter_mut().find(|(cd, _)| *cd == condition) {
                Some((_, prev)) if t < *prev => {
                    return Err(line.err(K::TimeWentBackwards {
                        condition: pose.is_none().then_some(condition),
                        t_s: t,
                        previous: *prev,
                    }))
                }
                Some((_, prev)) => *prev = t,
                None => self.last_t.push((condition, t)),
            }
            row.t_s = Some(t);
        }
        if let Some(idx) = c.angle {
            row.angle_deg = Some(line.num(idx, "angle")?);
        }
        if let Some(idx) = c.temp {
            row.temp_c = Some(line.num(idx, "temp")?);
        }
        if let Some(idx) = c.seq {
            let f = line.field(idx, "seq")?;
            row.seq = Some(f.parse().map_err(|_| {
                line.err(K::NotWhole {
                    field: idx,
                    text: f.to_string(),
                })
            })?);
        }
        if let Some((pname, g, mi)) = pose {
            row.pose = Some(pname);
            row.gravity = Some(g);
            if let Some(c) = self.per_pose.get_mut(mi) {
                *c += 1;
            }
        }
        Ok(row)
    }

    /// The condition of data line `line` of input `k`: its column's letter, else the
    /// input's condition; x for poses (`posed`) and free recordings, which have none.
    fn condition(
        &self,
        k: usize,
        c: &Fields,
        line: &Line<'_>,
        posed: bool,
    ) -> Result<Condition, ImportError> {
        let spec = self.spec;
        Ok(match c.condition {
            _ if posed || self.free => Condition::X,
            Some(idx) => {
                let f = line.field(idx, "condition")?;
                let mut chars = f.chars();
                match (chars.next().and_then(Condition::from_letter), chars.next()) {
                    (Some(c), None) => c,
                    _ => {
                        return Err(line.err(K::BadCondition {
                            field: idx,
                            text: f.to_string(),
                        }))
                    }
                }
            }
            None => *spec
                .conditions
                .get(k)
                .ok_or_else(|| line.err(K::NoCondition))?,
        })
    }
}

/// An error on an input's first data line, with what to do if the line is not data.
fn first_line_hint(e: ImportError, skip: usize) -> ImportError {
    match e.kind {
        K::NotFinite { .. } | K::NoField { .. } => {
            let line = e.line.unwrap_or(0);
            ImportError {
                kind: K::FirstLine {
                    error: Box::new(e.kind),
                    skip: line.max(skip),
                },
                ..e
            }
        }
        _ => e,
    }
}
