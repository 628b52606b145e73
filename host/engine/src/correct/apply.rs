//! `rotacal apply CAL.json RECORDING --out OUT.csv`: readings to acceleration in m/s².
//!
//! The output is a recording (formats.md) with the input's rows and columns, u, v, w
//! replaced by the corrected acceleration along the chosen frame's axes (x′ y′ z′, or the
//! platter's x y z), `# units=m/s^2`, `# frame=` and `# calibration=` lines, and the
//! columns `u_unc, v_unc, w_unc`: each value's standard uncertainty from the calibration.
//! So `rotacal calibrate OUT.csv` checks the result: sensitivities 1 and angles 90°.

use crate::calibrate::correction::{Correction, Frame};
use crate::calibrate::json::CorrectionJson;
use crate::recording::{Columns, Metadata, Recording, RecordingError, Row, Scanned, Writer};
use std::fmt::Write as _;
use std::io::Write;
use std::path::Path;

/// A problem reading a calibration file or applying it, naming the file concerned.
#[derive(Debug, thiserror::Error)]
#[error("{source_name}: {kind}")]
pub struct ApplyError {
    /// The file concerned.
    pub source_name: String,
    /// What is wrong.
    pub kind: ApplyErrorKind,
}

/// What is wrong; `entry` is the place in the calibration file's `by_rate` list.
#[derive(Debug, thiserror::Error)]
pub enum ApplyErrorKind {
    /// Reading or writing the file.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// The calibration file is not JSON.
    #[error("line {}: not JSON: {}", .0.line(), .0)]
    NotJson(serde_json::Error),
    /// JSON without a `by_rate` list.
    #[error("not a calibration file: no 'by_rate' list")]
    NoByRate,
    /// An empty `by_rate` list.
    #[error("'by_rate' is empty")]
    EmptyByRate,
    /// An entry without a correction (written by an older rotacal).
    #[error("by_rate[{entry}] has no 'correction': calibrate again with this version of rotacal")]
    NoCorrection {
        /// The entry.
        entry: usize,
    },
    /// A correction that does not read as one.
    #[error("by_rate[{entry}].correction: {cause}")]
    BadCorrection {
        /// The entry.
        entry: usize,
        /// The JSON reader's complaint.
        cause: serde_json::Error,
    },
    /// A frame's matrix or offset with a value that is not finite.
    #[error(
        "by_rate[{entry}].correction: {} frame: a matrix or offset value is not finite",
        frame.as_str()
    )]
    NotFinite {
        /// The entry.
        entry: usize,
        /// The frame.
        frame: Frame,
    },
    /// A frame's covariance that is not 12×12.
    #[error(
        "by_rate[{entry}].correction: {} frame: the covariance must be 12×12",
        frame.as_str()
    )]
    CovarianceShape {
        /// The entry.
        entry: usize,
        /// The frame.
        frame: Frame,
    },
    /// Several calibrations and no `--rate-hz` to choose.
    #[error(
        "{} calibrations (rates {}): choose one with --rate-hz",
        rates.len(),
        rate_list(rates)
    )]
    RateNeeded {
        /// Each entry's rate (None: static).
        rates: Vec<Option<f64>>,
    },
    /// No calibration at the rate asked for.
    #[error("no calibration at rate {rate_hz} Hz")]
    NoRate {
        /// The rate asked for, Hz.
        rate_hz: f64,
    },
    /// The platter frame asked of a calibration that has none.
    #[error(
        "no platter-frame correction: the rotation method does not fix how the device sat on \
         the platter; use --frame device"
    )]
    NoPlatterFrame,
    /// A recording that is `apply`'s output.
    #[error("already corrected (by {by}): apply a calibration to raw readings")]
    AlreadyCorrected {
        /// Its `# calibration=`.
        by: String,
    },
    /// A recording in other units than the calibration's readings.
    #[error("units '{units}', but the calibration {cal_name} is for readings in '{units_in}'")]
    WrongUnits {
        /// The recording's units.
        units: String,
        /// The calibration file.
        cal_name: String,
        /// The calibration's readings units.
        units_in: String,
    },
}

/// Why [`run`] failed: the calibration or the output, or the recording.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The calibration file, applying it, or writing the output.
    #[error(transparent)]
    Apply(#[from] ApplyError),
    /// Reading the recording.
    #[error(transparent)]
    Recording(#[from] RecordingError),
}

/// Rates for a message: `0.1, 0.5`, `static` for a static entry.
fn rate_list(rates: &[Option<f64>]) -> String {
    let rates: Vec<String> = rates
        .iter()
        .map(|r| r.map_or("static".into(), |r| format!("{r}")))
        .collect();
    rates.join(", ")
}

fn bad(source: &str, kind: impl Into<ApplyErrorKind>) -> ApplyError {
    ApplyError {
        source_name: source.to_string(),
        kind: kind.into(),
    }
}

/// The corrections of a calibration file: one per `by_rate` entry, with its rate.
pub fn read_corrections(
    text: &str,
    source: &str,
) -> Result<Vec<(Option<f64>, CorrectionJson)>, ApplyError> {
    corrections_of(&parse(text, source)?, source)
}

fn parse(text: &str, source: &str) -> Result<serde_json::Value, ApplyError> {
    serde_json::from_str(text).map_err(|e| bad(source, ApplyErrorKind::NotJson(e)))
}

/// A calibration file's chosen correction, with the file's `g_loc`.
#[derive(Clone, Debug)]
pub struct Loaded {
    /// The whole `correction` entry (convention, units, k, offset source).
    pub json: CorrectionJson,
    /// The chosen frame's correction.
    pub correction: Correction,
    /// `g_loc`, m/s².
    pub g_loc: Option<f64>,
}

/// Read the calibration file at `cal` and choose its correction for `rate_hz` and
/// `frame` (`rotacal apply` and `rotacal export`).
pub fn load(cal: &Path, rate_hz: Option<f64>, frame: Frame) -> Result<Loaded, ApplyError> {
    let name = cal.display().to_string();
    let text = std::fs::read_to_string(cal).map_err(|e| bad(&name, e))?;
    load_text(&text, &name, rate_hz, frame)
}

/// [`load`] of a calibration's JSON `text`, named `name` in messages.
pub fn load_text(
    text: &str,
    name: &str,
    rate_hz: Option<f64>,
    frame: Frame,
) -> Result<Loaded, ApplyError> {
    let v = parse(text, name)?;
    let (json, correction) = choose(&corrections_of(&v, name)?, rate_hz, frame, name)?;
    Ok(Loaded {
        json,
        correction,
        g_loc: v.get("g_loc").and_then(serde_json::Value::as_f64),
    })
}

fn corrections_of(
    v: &serde_json::Value,
    source: &str,
) -> Result<Vec<(Option<f64>, CorrectionJson)>, ApplyError> {
    let entries = v
        .get("by_rate")
        .and_then(|b| b.as_array())
        .ok_or_else(|| bad(source, ApplyErrorKind::NoByRate))?;
    let mut out = Vec::new();
    for (entry, e) in entries.iter().enumerate() {
        let rate = e.get("rate_hz").and_then(serde_json::Value::as_f64);
        let c = e
            .get("correction")
            .ok_or_else(|| bad(source, ApplyErrorKind::NoCorrection { entry }))?;
        let c: CorrectionJson = serde_json::from_value(c.clone())
            .map_err(|cause| bad(source, ApplyErrorKind::BadCorrection { entry, cause }))?;
        for f in std::iter::once(&c.device_frame).chain(c.platter_frame.as_ref()) {
            check(f, entry).map_err(|kind| bad(source, kind))?;
        }
        out.push((rate, c));
    }
    if out.is_empty() {
        return Err(bad(source, ApplyErrorKind::EmptyByRate));
    }
    Ok(out)
}

/// Entry `entry`'s correction `c` has finite values and a 12×12 covariance.
fn check(c: &Correction, entry: usize) -> Result<(), ApplyErrorKind> {
    let frame = c.frame;
    let finite = c
        .matrix
        .iter()
        .flatten()
        .chain(&c.offset)
        .all(|x| x.is_finite());
    if !finite {
        return Err(ApplyErrorKind::NotFinite { entry, frame });
    }
    if c.covariance.len() != crate::calibrate::correction::PARAMS
        || c.covariance
            .iter()
            .any(|r| r.len() != crate::calibrate::correction::PARAMS)
    {
        return Err(ApplyErrorKind::CovarianceShape { entry, frame });
    }
    Ok(())
}

/// Pick the correction for `rate_hz` (needed when the file has several) and `frame`.
pub fn choose(
    all: &[(Option<f64>, CorrectionJson)],
    rate_hz: Option<f64>,
    frame: Frame,
    source: &str,
) -> Result<(CorrectionJson, Correction), ApplyError> {
    let entry = match (rate_hz, all) {
        (None, [one]) => one,
        (None, _) => {
            return Err(bad(
                source,
                ApplyErrorKind::RateNeeded {
                    rates: all.iter().map(|(r, _)| *r).collect(),
                },
            ));
        }
        (Some(r), _) => all
            .iter()
            .find(|(x, _)| x.is_some_and(|x| (x - r).abs() <= 1e-12 * r.abs()))
            .ok_or_else(|| bad(source, ApplyErrorKind::NoRate { rate_hz: r }))?,
    };
    let c = match frame {
        Frame::Device => entry.1.device_frame.clone(),
        Frame::Platter => entry
            .1
            .platter_frame
            .clone()
            .ok_or_else(|| bad(source, ApplyErrorKind::NoPlatterFrame))?,
    };
    Ok((entry.1.clone(), c))
}

/// Per pose (static data): |a| against g.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct PoseNorm {
    /// The pose.
    pub name: String,
    /// Readings.
    pub n: usize,
    /// Mean of |y| − g over the raw readings (file units: meaningful when they are m/s²).
    pub before: f64,
    /// Mean of |a| − g after correction, m/s².
    pub after: f64,
    /// Standard deviation of |a| within the pose, m/s².
    pub std_after: f64,
}

/// What `apply` did.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Summary {
    /// Rows written.
    pub rows: usize,
    /// The frame.
    pub frame: Frame,
    /// g used for |a| − g, m/s².
    pub g_loc: Option<f64>,
    /// RMS over rows of |y| − g, in the input's units.
    pub rms_before: Option<f64>,
    /// RMS over rows of |a| − g, m/s².
    pub rms_after: Option<f64>,
    /// Static data: per pose.
    pub poses: Vec<PoseNorm>,
}

fn norm(x: &[f64; 3]) -> f64 {
    x.iter().map(|v| v * v).sum::<f64>().sqrt()
}

/// What to apply and how to label the output.
#[derive(Clone, Debug)]
pub struct Job<'a> {
    /// The correction.
    pub correction: &'a Correction,
    /// The calibration's readings units (`units_in`): the recording's must match.
    pub units_in: &'a str,
    /// The calibration's coverage factor, written as `# coverage_factor=`.
    pub k: f64,
    /// The calibration file's name, written as `# calibration=`.
    pub cal_name: &'a str,
    /// g for |a| − g, m/s² (else the recording's).
    pub g_loc: Option<f64>,
    /// The output's name, for messages.
    pub out_name: &'a str,
    /// Further metadata for the output (the shell's traceability: version, date, inputs'
    /// SHA-256, command line), written as `# key=value` lines.
    pub provenance: &'a [(String, String)],
}

/// The recording must hold raw readings (not `apply`'s output, which carries a
/// `# calibration=` line) in the calibration's units: anything else would be corrected into
/// nonsense.
pub fn check_units(rec: &Recording, job: &Job<'_>) -> Result<(), ApplyError> {
    check_meta(&rec.meta, &rec.source, job)
}

fn check_meta(meta: &Metadata, source: &str, job: &Job<'_>) -> Result<(), ApplyError> {
    if let Some(cal) = meta.other.get("calibration") {
        return Err(bad(
            source,
            ApplyErrorKind::AlreadyCorrected { by: cal.clone() },
        ));
    }
    match &meta.units {
        Some(u) if u.trim() != job.units_in.trim() => Err(bad(
            source,
            ApplyErrorKind::WrongUnits {
                units: u.clone(),
                cal_name: job.cal_name.to_string(),
                units_in: job.units_in.to_string(),
            },
        )),
        _ => Ok(()),
    }
}

/// |y| − g and |a| − g of one pose's rows, gathered one at a time (Welford's mean and
/// sum of squares for |a|).
struct PoseTally {
    name: String,
    n: usize,
    before: f64,
    after: f64,
    m2: f64,
}

/// Corrects rows one at a time into a writer, keeping only the summary's sums: memory
/// does not grow with the recording.
struct Corrector<'a, W: Write> {
    job: &'a Job<'a>,
    w: Writer<W>,
    g: Option<f64>,
    /// Static conditions: tally each (condition, angle) as a pose.
    stat: bool,
    ss_before: f64,
    ss_after: f64,
    rows: usize,
    poses: Vec<PoseTally>,
}

/// One row to correct.
struct RowIn<'r> {
    condition: rotacal_shared::Condition,
    y: [f64; 3],
    t_s: Option<f64>,
    angle_deg: Option<f64>,
    seq: Option<u64>,
    temp_c: Option<f64>,
    rate_hz: Option<f64>,
    gravity: Option<[f64; 3]>,
    pose: Option<&'r str>,
}

impl<'a, W: Write> Corrector<'a, W> {
    /// The output's metadata from the input's, then its header with `cols` (the input's
    /// columns, with uncertainties).
    fn new(
        meta_in: &Metadata,
        method: crate::recording::Method,
        job: &'a Job<'a>,
        cols: Columns,
        out: W,
    ) -> Result<Self, ApplyError> {
        let corr = job.correction;
        let mut meta = meta_in.clone();
        meta.units = Some("m/s^2".into());
        meta.noise_sigma = None;
        meta.g_loc = job.g_loc.or(meta.g_loc);
        meta.other
            .insert("frame".into(), corr.frame.as_str().into());
        meta.other.insert(
            "calibration".into(),
            job.cal_name.replace(['\n', '\r'], " "),
        );
        meta.other
            .insert("coverage_factor".into(), format!("{}", job.k));
        for (key, value) in job.provenance {
            meta.other
                .insert(key.clone(), value.replace(['\n', '\r'], " "));
        }
        meta.method = Some(method);
        let w = Writer::new(out, &meta, &Columns { unc: true, ..cols })
            .map_err(|e| bad(job.out_name, e))?;
        Ok(Corrector {
            job,
            w,
            g: meta.g_loc,
            stat: method == crate::recording::Method::Static,
            ss_before: 0.0,
            ss_after: 0.0,
            rows: 0,
            poses: Vec::new(),
        })
    }

    fn row(&mut self, r: &RowIn<'_>) -> Result<(), ApplyError> {
        let (a, u) = self.job.correction.apply(r.y);
        let mut row = Row::new(r.condition, a[0], a[1], a[2]);
        row.unc = Some(u);
        row.t_s = r.t_s;
        row.angle_deg = r.angle_deg;
        row.seq = r.seq;
        row.temp_c = r.temp_c;
        row.rate_hz = r.rate_hz;
        row.gravity = r.gravity;
        row.pose = r.pose;
        self.w
            .write_row(&row)
            .map_err(|e| bad(self.job.out_name, e))?;
        self.rows += 1;
        let Some(g) = self.g else {
            return Ok(());
        };
        let (b, c) = (norm(&r.y) - g, norm(&a) - g);
        self.ss_before += b * b;
        self.ss_after += c * c;
        let key = match (r.gravity, r.pose) {
            (Some(_), Some(name)) => Some(name.to_string()),
            (Some(gdir), None) => Some(crate::calibrate::poses::direction_name(&gdir)),
            (None, _) if self.stat => Some(format!(
                "{} {}°",
                r.condition.letter(),
                r.angle_deg.unwrap_or(f64::NAN)
            )),
            _ => None,
        };
        if let Some(name) = key {
            let i = match self.poses.iter().position(|p| p.name == name) {
                Some(i) => i,
                None => {
                    self.poses.push(PoseTally {
                        name,
                        n: 0,
                        before: 0.0,
                        after: 0.0,
                        m2: 0.0,
                    });
                    self.poses.len() - 1
                }
            };
            if let Some(p) = self.poses.get_mut(i) {
                p.n += 1;
                let n = p.n as f64;
                p.before += (b - p.before) / n;
                let d = c - p.after;
                p.after += d / n;
                p.m2 += d * (c - p.after);
            }
        }
        Ok(())
    }

    fn finish(mut self) -> Result<Summary, ApplyError> {
        self.w.flush().map_err(|e| bad(self.job.out_name, e))?;
        let (rows, g) = (self.rows, self.g);
        let rms = |ss: f64| (rows > 0 && g.is_some()).then(|| (ss / rows as f64).sqrt());
        Ok(Summary {
            rows,
            frame: self.job.correction.frame,
            g_loc: g,
            rms_before: rms(self.ss_before),
            rms_after: rms(self.ss_after),
            poses: self
                .poses
                .into_iter()
                .map(|p| PoseNorm {
                    std_after: if p.n > 1 {
                        (p.m2 / (p.n - 1) as f64).sqrt()
                    } else {
                        f64::NAN
                    },
                    name: p.name,
                    n: p.n,
                    before: p.before,
                    after: p.after,
                })
                .collect(),
        })
    }
}

/// Correct every row of `rec` and write the result to `out`.
pub fn apply<W: Write>(rec: &Recording, job: &Job<'_>, out: W) -> Result<Summary, ApplyError> {
    check_units(rec, job)?;
    if let Some(o) = &rec.oriented {
        let cols = Columns {
            t_s: o.t_s.is_some(),
            seq: o.seq.is_some(),
            temp_c: o.temp_c.is_some(),
            gravity: true,
            pose: o.pose.is_some(),
            ..Columns::default()
        };
        let mut c = Corrector::new(&rec.meta, rec.method, job, cols, out)?;
        for (i, (y, gdir)) in o.y.iter().zip(&o.gravity).enumerate() {
            c.row(&RowIn {
                condition: rotacal_shared::Condition::X,
                y: *y,
                t_s: o.t_s.as_ref().and_then(|t| t.get(i).copied()),
                angle_deg: None,
                seq: o.seq.as_ref().and_then(|t| t.get(i).copied()),
                temp_c: o.temp_c.as_ref().and_then(|t| t.get(i).copied()),
                rate_hz: None,
                gravity: Some(*gdir),
                pose: o.pose.as_ref().and_then(|p| p.get(i)).map(String::as_str),
            })?;
        }
        return c.finish();
    }
    let first = rec.groups.first();
    let cols = Columns {
        t_s: first.is_some_and(|g| !g.t_s.is_empty()),
        angle_deg: first.is_some_and(|g| !g.angle_deg.is_empty()),
        seq: first.is_some_and(|g| g.seq.is_some()),
        temp_c: first.is_some_and(|g| g.temp_c.is_some()),
        rate_hz: rec.groups.iter().any(|g| g.rate_hz.is_some()),
        ..Columns::default()
    };
    let mut c = Corrector::new(&rec.meta, rec.method, job, cols, out)?;
    for grp in &rec.groups {
        let readings = grp.u.iter().zip(&grp.v).zip(&grp.w);
        for (i, ((&u, &v), &w)) in readings.enumerate() {
            c.row(&RowIn {
                condition: grp.condition,
                y: [u, v, w],
                t_s: grp.t_s.get(i).copied().filter(|_| cols.t_s),
                angle_deg: grp.angle_deg.get(i).copied().filter(|_| cols.angle_deg),
                seq: grp.seq.as_ref().and_then(|s| s.get(i).copied()),
                temp_c: grp.temp_c.as_ref().and_then(|s| s.get(i).copied()),
                rate_hz: grp.rate_hz.filter(|_| cols.rate_hz),
                gravity: None,
                pose: None,
            })?;
        }
    }
    c.finish()
}

/// Read `cal`, correct `recording` into `out`. A file with conditions streams through,
/// row by row in file order, in constant memory; a file of poses is read whole. The output
/// is written beside `out` and renamed to it at the end: a failure leaves no file behind.
pub fn run(
    cal: &Path,
    recording: &Path,
    out: &Path,
    frame: Frame,
    rate_hz: Option<f64>,
    provenance: &[(String, String)],
) -> Result<(Summary, String), RunError> {
    let Loaded {
        json,
        correction: corr,
        g_loc: g,
    } = load(cal, rate_hz, frame)?;
    let (out_name, cal_name) = (out.display().to_string(), cal.display().to_string());
    let job = Job {
        correction: &corr,
        units_in: &json.units_in,
        k: json.k,
        cal_name: &cal_name,
        g_loc: g,
        out_name: &out_name,
        provenance,
    };
    let partial = std::path::PathBuf::from(format!("{out_name}.partial"));
    let source = recording.display().to_string();
    let mut groups: Vec<(rotacal_shared::Condition, Option<f64>)> = Vec::new();
    let mut rate_col = false;
    let mut state: Result<Option<Corrector<'_, std::fs::File>>, ApplyError> = Ok(None);
    let scanned = crate::recording::scan(recording, None, crate::recording::Parse::All, |ev| {
        match ev {
            Scanned::Start {
                meta,
                method,
                columns,
            } => {
                // A second reading (the csv reader's, to name a problem) starts afresh.
                groups.clear();
                rate_col = columns.rate_hz;
                state = check_meta(&meta, &source, &job).and_then(|()| {
                    let file = std::fs::File::create(&partial).map_err(|e| bad(&out_name, e))?;
                    let cols = Columns {
                        t_s: columns.t_s,
                        angle_deg: columns.angle_deg,
                        seq: columns.seq,
                        temp_c: columns.temp_c,
                        rate_hz: columns.rate_hz,
                        ..Columns::default()
                    };
                    Ok(Some(Corrector::new(&meta, method, &job, cols, file)?))
                });
            }
            Scanned::Group {
                condition, rate_hz, ..
            } => groups.push((condition, rate_hz)),
            Scanned::Row {
                group,
                t_s,
                y,
                angle_deg,
                seq,
                temp_c,
                ..
            } => {
                let (Ok(Some(c)), Some((condition, rate))) = (state.as_mut(), groups.get(group))
                else {
                    return;
                };
                let row = RowIn {
                    condition: *condition,
                    y,
                    t_s,
                    angle_deg,
                    seq,
                    temp_c,
                    rate_hz: rate.filter(|_| rate_col),
                    gravity: None,
                    pose: None,
                };
                if let Err(e) = c.row(&row) {
                    state = Err(e);
                }
            }
        }
    });
    let discard = || {
        let _ = std::fs::remove_file(&partial); // nothing to keep of a failed run
    };
    let s = match (scanned, state) {
        (Err(e), _) => {
            discard();
            return Err(e.into());
        }
        (Ok(Some(_)), Ok(Some(c))) => {
            let s = c.finish().inspect_err(|_| discard())?;
            std::fs::rename(&partial, out).map_err(|e| {
                discard();
                bad(&out_name, e)
            })?;
            s
        }
        (Ok(Some(_)), Err(e)) => {
            discard();
            return Err(e.into());
        }
        (Ok(_), _) => {
            // Poses, or a free series: read whole.
            discard();
            let rec = crate::recording::read(recording)?;
            // Checked before the output is created: a refused input leaves no file.
            check_units(&rec, &job)?;
            // Whole or not at all: a failure part way leaves no file.
            enum Failed {
                Apply(ApplyError),
                Io(std::io::Error),
            }
            impl From<std::io::Error> for Failed {
                fn from(e: std::io::Error) -> Self {
                    Failed::Io(e)
                }
            }
            crate::atomic::write_with(out, |w| apply(&rec, &job, w).map_err(Failed::Apply))
                .map_err(|f| match f {
                    Failed::Apply(e) => e,
                    Failed::Io(e) => bad(&out_name, e),
                })?
        }
    };
    Ok((s.clone(), render(&s, &json.units_in)))
}

/// The terminal summary.
pub fn render(s: &Summary, units_in: &str) -> String {
    let mut o = String::new();
    let _ = writeln!(
        o,
        "{} rows corrected to m/s² in the {} frame",
        s.rows,
        s.frame.as_str()
    );
    if let (Some(g), Some(b), Some(a)) = (s.g_loc, s.rms_before, s.rms_after) {
        let _ = writeln!(o, "RMS of |a| − g (g = {g} m/s²): before {b:.3e} {units_in} (raw readings), after {a:.3e} m/s²");
    }
    if !s.poses.is_empty() {
        let _ = writeln!(
            o,
            "per pose: mean |y| − g before ({units_in}), mean |a| − g after and std of |a| (m/s²)"
        );
        for p in &s.poses {
            let _ = writeln!(
                o,
                "  {:<12} n {:>6}  before {:+.4e}  after {:+.4e}  std {:.2e}",
                p.name, p.n, p.before, p.after, p.std_after
            );
        }
    }
    o
}
