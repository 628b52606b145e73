//! Writing a recording that the reader reads back exactly.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::Path;

use super::{
    check_meta_number, is_key, pose_name_ok, Columns, Metadata, Method, Row, KNOWN_KEYS,
    UNIT_TOLERANCE,
};

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
                check_meta_number(key, x)
                    .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
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
        if c.conv_missed {
            line.push(',');
            if let Some(m) = row.conv_missed {
                let _ = write!(line, "{m}");
            }
        }
        if let Some(s) = opt(c.boot, "boot", row.boot)? {
            let _ = write!(line, ",{s}");
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

/// Write the whole recording `rec` to `w`: its metadata, then its rows (the groups in
/// order of first appearance, or its poses, or its series) with the columns it was read
/// with. A file the writer wrote comes back byte for byte when read and written again.
pub fn write_recording<W: Write>(rec: &super::Recording, w: W) -> io::Result<W> {
    let mut meta = rec.meta.clone();
    // A free series needs its method said: nothing else marks it.
    if rec.method == Method::Free && meta.method.is_none() {
        meta.method = Some(Method::Free);
    }
    let missing = || invalid("a row shorter than its recording's columns".into());
    if let Some(o) = &rec.oriented {
        let cols = Columns {
            gravity: true,
            pose: o.pose.is_some(),
            t_s: o.t_s.is_some(),
            seq: o.seq.is_some(),
            temp_c: o.temp_c.is_some(),
            unc: o.unc.is_some(),
            ..Columns::default()
        };
        let mut out = Writer::new(w, &meta, &cols)?;
        for (i, (y, g)) in o.y.iter().zip(&o.gravity).enumerate() {
            let at = |c: &Option<Vec<f64>>| c.as_ref().and_then(|v| v.get(i).copied());
            let row = Row {
                gravity: Some(*g),
                pose: o.pose.as_ref().and_then(|p| p.get(i)).map(String::as_str),
                t_s: at(&o.t_s),
                seq: o.seq.as_ref().and_then(|v| v.get(i).copied()),
                temp_c: at(&o.temp_c),
                unc: o.unc.as_ref().and_then(|v| v.get(i).copied()),
                ..Row::new(super::Condition::X, y[0], y[1], y[2])
            };
            out.write_row(&row)?;
        }
        return out.into_inner();
    }
    if let Some(s) = &rec.series {
        let cols = Columns {
            t_s: true,
            pose: s.pose.is_some(),
            seq: s.seq.is_some(),
            temp_c: s.temp_c.is_some(),
            ..Columns::default()
        };
        let mut out = Writer::new(w, &meta, &cols)?;
        for (i, (y, t)) in s.y.iter().zip(&s.t_s).enumerate() {
            let row = Row {
                t_s: Some(*t),
                pose: s.pose.as_ref().and_then(|p| p.get(i)).map(String::as_str),
                seq: s.seq.as_ref().and_then(|v| v.get(i).copied()),
                temp_c: s.temp_c.as_ref().and_then(|v| v.get(i).copied()),
                ..Row::new(super::Condition::X, y[0], y[1], y[2])
            };
            out.write_row(&row)?;
        }
        return out.into_inner();
    }
    let first = rec.groups.first();
    let has = |f: &dyn Fn(&super::Group) -> bool| first.is_some_and(f);
    let cols = Columns {
        t_s: has(&|g| !g.t_s.is_empty()),
        angle_deg: has(&|g| !g.angle_deg.is_empty()),
        seq: has(&|g| g.seq.is_some()),
        temp_c: has(&|g| g.temp_c.is_some()),
        rate_hz: rec.groups.iter().any(|g| g.rate_hz.is_some()),
        unc: has(&|g| g.unc.is_some()),
        conv_gaps: has(&|g| g.conversions.is_some()),
        conv_missed: has(&|g| g.missed.is_some()),
        boot: has(&|g| g.boot.is_some()),
        ..Columns::default()
    };
    let mut out = Writer::new(w, &meta, &cols)?;
    for g in &rec.groups {
        for i in 0..g.len() {
            let (Some(u), Some(v), Some(w)) = (g.u.get(i), g.v.get(i), g.w.get(i)) else {
                return Err(missing());
            };
            let row = Row {
                t_s: g.t_s.get(i).copied(),
                angle_deg: g.angle_deg.get(i).copied(),
                seq: g.seq.as_ref().and_then(|v| v.get(i).copied()),
                temp_c: g.temp_c.as_ref().and_then(|v| v.get(i).copied()),
                rate_hz: g.rate_hz,
                unc: g.unc.as_ref().and_then(|v| v.get(i).copied()),
                conv_gaps: g.conversions.as_ref().and_then(|v| v.get(i).cloned()),
                conv_missed: g.missed.as_ref().and_then(|v| v.get(i).copied()).flatten(),
                boot: g.boot.as_ref().and_then(|v| v.get(i).copied()),
                ..Row::new(g.condition, *u, *v, *w)
            };
            out.write_row(&row)?;
        }
    }
    out.into_inner()
}
