//! `rotacal._rotacal`, the Python package's extension: the engine's reader, calibration and
//! traceability, called by the package's Python code (python/rotacal). Nothing here
//! computes: it hands columns to `recording::read_columns` and options to the engine's
//! `calibrate`, gives back the calibration JSON the command line writes, and turns the
//! engine's errors into exceptions that carry their place (docs/python.md).

use numpy::{IntoPyArray, PyReadonlyArray1, PyUntypedArrayMethods};
use pyo3::create_exception;
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyString};
use rotacal_engine::calibrate;
use rotacal_engine::recording::{self, Column, Method, Recording, Values};
use rotacal_engine::trace::{self, Traceability};
use std::path::PathBuf;
use std::str::FromStr;

create_exception!(
    rotacal,
    RecordingError,
    PyValueError,
    "A recording that cannot be read: its `source`, and `line` (a file's, 1-based) or `row` (a DataFrame's, 0-based), and `column` where one applies."
);
create_exception!(
    rotacal,
    DiscrepancyError,
    PyValueError,
    "A recording that was read but that the discrepancy workflow cannot analyse (not a rotation recording, too short, a fit that fails)."
);
create_exception!(
    rotacal,
    CalibrationError,
    PyValueError,
    "A recording that was read but cannot be calibrated: its `source`, and the first `line` (a file's) or `row` (a DataFrame's) of the data concerned, where one applies."
);

/// This build, for the traceability block.
const BUILD: trace::Build = trace::Build {
    version: env!("CARGO_PKG_VERSION"),
    commit: env!("ROTACAL_COMMIT"),
};

/// The exception for a recording's problem, with its place as attributes.
fn recording_error(py: Python<'_>, e: &recording::RecordingError) -> PyErr {
    let err = RecordingError::new_err(e.to_string());
    let v = err.value(py);
    let set = [
        v.setattr("source", e.source_name.as_str()),
        v.setattr("line", e.line),
        v.setattr("row", e.row),
        v.setattr("column", e.kind.column()),
    ];
    match set.into_iter().find_map(Result::err) {
        Some(failed) => failed,
        None => err,
    }
}

/// The exception for a calibration's problem; `held`: its lines are rows of columns.
fn calibration_error(py: Python<'_>, e: &calibrate::CalibrateError, held: bool) -> PyErr {
    let err = CalibrationError::new_err(e.to_string());
    let v = err.value(py);
    let (line, row) = if held { (None, e.line) } else { (e.line, None) };
    let set = [
        v.setattr("source", e.source_name.as_str()),
        v.setattr("line", line),
        v.setattr("row", row),
    ];
    match set.into_iter().find_map(Result::err) {
        Some(failed) => failed,
        None => err,
    }
}

/// A column handed over: a contiguous float64 array or one of single bytes (a condition's
/// letters), borrowed; letters read from Python texts; or texts.
enum Held<'py> {
    Numbers(PyReadonlyArray1<'py, f64>),
    Letters(PyReadonlyArray1<'py, u8>),
    OwnLetters(Vec<u8>),
    Texts(Vec<String>),
}

/// A numpy array of Python objects (pandas' `str` and `object` columns) as their letters,
/// when each is a text of one ASCII byte; `None` otherwise. A column of conditions holds
/// the same few objects over and over (a CSV reader makes one "x"), so each object is read
/// once and then known by its address: 1.12 M rows in about a millisecond, not the 13 ms
/// of reading each.
fn letters_of_objects(py: Python<'_>, objects: &[Py<PyAny>]) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(objects.len());
    // The objects met last, newest first (the array holds them all: an address met again
    // is the same object).
    let mut known: [(usize, u8); 4] = [(0, 0); 4];
    for o in objects {
        let at = o.as_ptr() as usize;
        let letter = match known.iter().find(|(a, _)| *a == at) {
            Some((_, l)) => *l,
            None => {
                let text = o.bind(py).cast::<PyString>().ok()?.to_cow().ok()?;
                let [b] = text.as_bytes() else {
                    return None;
                };
                if !b.is_ascii() {
                    return None;
                }
                known.rotate_right(1);
                if let Some(first) = known.first_mut() {
                    *first = (at, *b);
                }
                *b
            }
        };
        out.push(letter);
    }
    Some(out)
}

/// The texts of a numpy array of Python objects, as the Python side writes them (`None`
/// as "", anything else by `str`), for the engine to read and name.
fn texts_of_objects(objects: &[Py<PyAny>], py: Python<'_>) -> PyResult<Vec<String>> {
    objects
        .iter()
        .map(|o| {
            let o = o.bind(py);
            if o.is_none() {
                Ok(String::new())
            } else {
                Ok(o.str()?.to_cow()?.into_owned())
            }
        })
        .collect()
}

impl<'py> Held<'py> {
    fn of(name: &str, values: &Bound<'py, PyAny>) -> PyResult<Self> {
        if let Ok(a) = values.extract::<PyReadonlyArray1<'py, f64>>() {
            if !a.is_c_contiguous() {
                return Err(PyValueError::new_err(format!(
                    "column {name}: the array is not contiguous (numpy.ascontiguousarray)"
                )));
            }
            return Ok(Held::Numbers(a));
        }
        if let Ok(a) = values.extract::<PyReadonlyArray1<'py, u8>>() {
            if !a.is_c_contiguous() {
                return Err(PyValueError::new_err(format!(
                    "column {name}: the array is not contiguous (numpy.ascontiguousarray)"
                )));
            }
            return Ok(Held::Letters(a));
        }
        if let Ok(a) = values.extract::<PyReadonlyArray1<'py, Py<PyAny>>>() {
            let py = values.py();
            let objects = a.as_slice()?;
            let letters = (name == "condition")
                .then(|| letters_of_objects(py, objects))
                .flatten();
            return Ok(match letters {
                Some(l) => Held::OwnLetters(l),
                None => Held::Texts(texts_of_objects(objects, py)?),
            });
        }
        values
            .extract::<Vec<String>>()
            .map(Held::Texts)
            .map_err(|_| {
                PyTypeError::new_err(format!(
                    "column {name}: a 1-D float64 or uint8 numpy array or a list of str is needed"
                ))
            })
    }

    fn values(&self) -> PyResult<Values<'_>> {
        Ok(match self {
            Held::Numbers(a) => Values::Numbers(a.as_slice()?),
            Held::Letters(a) => Values::Letters(a.as_slice()?),
            Held::OwnLetters(l) => Values::Letters(l),
            Held::Texts(t) => Values::Texts(t),
        })
    }
}

fn number(key: &str, v: &Bound<'_, PyAny>) -> PyResult<f64> {
    v.extract::<f64>()
        .map_err(|_| PyTypeError::new_err(format!("{key}: a number is needed")))
}

fn text(key: &str, v: &Bound<'_, PyAny>) -> PyResult<String> {
    v.extract::<String>()
        .map_err(|_| PyTypeError::new_err(format!("{key}: a str is needed")))
}

/// The engine's options from the keyword arguments of `rotacal.calibrate` (the command
/// line's flags, with `_` for `-`; the engine's defaults where one is not given).
fn options(py: Python<'_>, given: &Bound<'_, PyDict>) -> PyResult<calibrate::Options> {
    let mut o = calibrate::Options::default();
    for (k, v) in given.iter() {
        let key: String = k.extract()?;
        if v.is_none() {
            continue;
        }
        match key.as_str() {
            "method" => {
                let m = text(&key, &v)?;
                o.method =
                    Some(Method::from_str(&m).map_err(|e| PyValueError::new_err(format!("{e}")))?);
            }
            "rate_hz" => o.rate_hz = Some(number(&key, &v)?),
            "g_loc" => o.g_loc = Some(number(&key, &v)?),
            "u_g_loc" => o.inputs.u_g_loc = Some(number(&key, &v)?),
            "u_time_s" => o.inputs.u_time_s = Some(number(&key, &v)?),
            "u_angle_deg" => o.inputs.u_angle_deg = Some(number(&key, &v)?),
            "monte_carlo" => o.monte_carlo = Some(v.extract::<usize>()?),
            "slow_noise" => o.slow_noise = v.extract::<bool>()?,
            "still_window_s" => o.still.window_s = number(&key, &v)?,
            "still_threshold" => o.still.threshold = number(&key, &v)?,
            "min_still_s" => o.still.min_still_s = number(&key, &v)?,
            "pose_weights" => {
                o.poses.weights = match text(&key, &v)?.as_str() {
                    "random-effects" => calibrate::poses::Weights::RandomEffects,
                    "equal" => calibrate::poses::Weights::Equal,
                    other => {
                        return Err(PyValueError::new_err(format!(
                            "pose_weights: '{other}' is neither 'random-effects' nor 'equal'"
                        )))
                    }
                }
            }
            "offsets" => {
                o.poses.offsets = match text(&key, &v)?.as_str() {
                    "joint" => calibrate::poses::OffsetEstimator::Joint,
                    "axis-pairs" => calibrate::poses::OffsetEstimator::AxisPairs,
                    other => {
                        return Err(PyValueError::new_err(format!(
                            "offsets: '{other}' is neither 'joint' nor 'axis-pairs'"
                        )))
                    }
                }
            }
            "noise_from" => {
                let path: PathBuf = v.extract()?;
                let rec = recording::read(&path).map_err(|e| recording_error(py, &e))?;
                let prepared = calibrate::noise_from::NoiseFrom::new(&rec).map_err(|e| {
                    CalibrationError::new_err(format!("noise_from {}: {e}", path.display()))
                })?;
                o.noise_from = Some(std::sync::Arc::new(prepared));
                o.slow_noise = true;
            }
            other => {
                return Err(PyTypeError::new_err(format!(
                    "calibrate() got an unexpected keyword argument '{other}'"
                )))
            }
        }
    }
    Ok(o)
}

/// An output's JSON with the traceability block `t` naming `command`, as the command line
/// writes it.
fn with_trace<T: serde::Serialize>(
    value: &T,
    mut t: Traceability,
    command: Vec<String>,
) -> PyResult<String> {
    t.command_line = command;
    t.json(value)
        .map_err(|e| PyValueError::new_err(format!("the output as JSON: {e}")))
}

/// Calibrate the recording file at `path` exactly as `rotacal calibrate` does (its
/// streaming engine); the calibration JSON, whose traceability names `command`.
#[pyfunction]
fn calibrate_path(
    py: Python<'_>,
    path: PathBuf,
    options: &Bound<'_, PyDict>,
    command: Vec<String>,
) -> PyResult<String> {
    let opts = self::options(py, options)?;
    let cal = py
        .detach(|| calibrate::stream::calibrate_file(&path, &opts))
        .map_err(|e| match e {
            calibrate::stream::FileError::Read(e) => recording_error(py, &e),
            calibrate::stream::FileError::Calibrate(e) => calibration_error(py, &e, false),
        })?;
    let t = Traceability::of_calibrating(BUILD, &path, &opts)
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    with_trace(&cal, t, command)
}

/// Calibrate the recording held in `columns` ((name, values) pairs: float64 arrays, not
/// copied, or lists of str) with the metadata `meta`, named `source` in messages; the
/// calibration JSON, whose traceability digests the columns and names `command`.
#[pyfunction]
fn calibrate_columns(
    py: Python<'_>,
    columns: Vec<(String, Bound<'_, PyAny>)>,
    meta: Vec<(String, String)>,
    source: String,
    options: &Bound<'_, PyDict>,
    command: Vec<String>,
) -> PyResult<String> {
    let opts = self::options(py, options)?;
    let held = hold(&columns)?;
    let cols = as_columns(&columns, &held)?;
    let meta = str_pairs(&meta);
    // The command line's engine for a file, on the columns where they are.
    let (cal, input) = py.detach(|| {
        beside_digest(&source, &cols, || {
            calibrate::stream::calibrate_columns(&cols, &meta, &source, &opts)
        })
    })?;
    let cal = cal.map_err(|e| match e {
        calibrate::stream::FileError::Read(e) => recording_error(py, &e),
        calibrate::stream::FileError::Calibrate(e) => calibration_error(py, &e, true),
    })?;
    let t = Traceability::of_columns(
        BUILD,
        &cols,
        &meta,
        input,
        (opts.g_loc, opts.inputs.u_g_loc),
        ("g_loc=", "u_g_loc="),
    )
    .map_err(|e| PyValueError::new_err(e.to_string()))?;
    with_trace(&cal, t, command)
}

/// The discrepancy workflow's options from `rotacal.discrepancy`'s keyword arguments.
fn discrepancy_options(
    given: &Bound<'_, PyDict>,
) -> PyResult<rotacal_engine::discrepancy::Options> {
    let mut o = rotacal_engine::discrepancy::Options::default();
    for (k, v) in given.iter() {
        let key: String = k.extract()?;
        if v.is_none() {
            continue;
        }
        match key.as_str() {
            "g_loc" => o.g_loc = Some(number(&key, &v)?),
            "rate_hz" => o.rate_hz = Some(number(&key, &v)?),
            "alpha" => {
                o.alpha = number(&key, &v)?;
                if !(o.alpha > 0.0 && o.alpha < 1.0) {
                    return Err(PyValueError::new_err(format!(
                        "alpha {}: a probability between 0 and 1 is needed",
                        o.alpha
                    )));
                }
            }
            "slow_noise" => o.slow_noise = v.extract::<bool>()?,
            other => {
                return Err(PyTypeError::new_err(format!(
                    "discrepancy() got an unexpected keyword argument '{other}'"
                )))
            }
        }
    }
    Ok(o)
}

/// The discrepancy workflow on `rec` (`rotacal discrepancy`): its JSON with `t`.
fn discrepancy_of(
    py: Python<'_>,
    rec: &Recording,
    opts: &rotacal_engine::discrepancy::Options,
    t: Traceability,
    command: Vec<String>,
) -> PyResult<String> {
    let analysis = py
        .detach(|| rotacal_engine::discrepancy::run(rec, opts))
        .map_err(|e| DiscrepancyError::new_err(e.to_string()))?;
    with_trace(&analysis, t, command)
}

/// `rotacal discrepancy FILE --json`: the analysis of the recording at `path`.
#[pyfunction]
fn discrepancy_path(
    py: Python<'_>,
    path: PathBuf,
    options: &Bound<'_, PyDict>,
    command: Vec<String>,
) -> PyResult<String> {
    let opts = discrepancy_options(options)?;
    let rec = py
        .detach(|| recording::read(&path))
        .map_err(|e| recording_error(py, &e))?;
    let t = Traceability::of_recording(BUILD, &path, None, opts.g_loc, None)
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    discrepancy_of(py, &rec, &opts, t, command)
}

/// The discrepancy workflow on the recording held in `columns`.
#[pyfunction]
fn discrepancy_columns(
    py: Python<'_>,
    columns: Vec<(String, Bound<'_, PyAny>)>,
    meta: Vec<(String, String)>,
    source: String,
    options: &Bound<'_, PyDict>,
    command: Vec<String>,
) -> PyResult<String> {
    let opts = discrepancy_options(options)?;
    let (rec, input) = read_held(py, &columns, &meta, &source)?;
    let t = Traceability::of_held(
        BUILD,
        &rec,
        input,
        (opts.g_loc, None),
        ("g_loc=", "u_g_loc="),
    );
    discrepancy_of(py, &rec, &opts, t, command)
}

/// `rotacal allan FILE --json` of a recording: from a file at `path`, or held in
/// `columns` (with `meta`, named `source`); samples at `from_s ≤ t_s ≤ to_s`.
#[pyfunction]
#[pyo3(signature = (path, columns, meta, source, from_s, to_s, command))]
#[allow(clippy::too_many_arguments)]
fn allan(
    py: Python<'_>,
    path: Option<PathBuf>,
    columns: Vec<(String, Bound<'_, PyAny>)>,
    meta: Vec<(String, String)>,
    source: String,
    from_s: Option<f64>,
    to_s: Option<f64>,
    command: Vec<String>,
) -> PyResult<String> {
    if let (Some(f), Some(t)) = (from_s, to_s) {
        if f > t {
            return Err(PyValueError::new_err(format!(
                "from_s {f} is after to_s {t}"
            )));
        }
    }
    let (rec, t, name) = match path {
        Some(p) => {
            let rec = py
                .detach(|| recording::read(&p))
                .map_err(|e| recording_error(py, &e))?;
            let t = Traceability::of_recording(BUILD, &p, None, None, None)
                .map_err(|e| PyValueError::new_err(e.to_string()))?;
            (rec, t, p.display().to_string())
        }
        None => {
            let (rec, input) = read_held(py, &columns, &meta, &source)?;
            let t = Traceability::of_held(BUILD, &rec, input, (None, None), ("g_loc=", "u_g_loc="));
            (rec, t, source)
        }
    };
    let out = py
        .detach(|| rotacal_engine::allan::analysis::analyse(&rec, &name, from_s, to_s))
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    with_trace(&out, t, command)
}

/// The recording held in `columns` (with `meta`, named `source`), read with the file
/// reader's checks; and beside the reading, the columns' digest as the traceability
/// block's input.
fn read_held(
    py: Python<'_>,
    columns: &[(String, Bound<'_, PyAny>)],
    meta: &[(String, String)],
    source: &str,
) -> PyResult<(Recording, trace::Input)> {
    let held = hold(columns)?;
    let cols = as_columns(columns, &held)?;
    let meta = str_pairs(meta);
    let (rec, input) = py.detach(|| {
        beside_digest(source, &cols, || {
            recording::read_columns(&cols, &meta, source, None)
        })
    })?;
    Ok((rec.map_err(|e| recording_error(py, &e))?, input))
}

/// `work` on this thread, and beside it on a thread of its own the digest of `cols` (named
/// `source`) that the traceability block takes as its input.
fn beside_digest<T>(
    source: &str,
    cols: &[Column<'_>],
    work: impl FnOnce() -> T,
) -> PyResult<(T, trace::Input)> {
    std::thread::scope(|scope| {
        let digest = scope.spawn(|| trace::input_of_columns(source, cols));
        let out = work();
        let input = digest
            .join()
            .map_err(|_| PyValueError::new_err("the columns' digest failed"))?;
        Ok((out, input))
    })
}

/// Metadata as the reader takes it.
fn str_pairs(meta: &[(String, String)]) -> Vec<(&str, &str)> {
    meta.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect()
}

/// Columns handed over, borrowed as the reader takes them.
fn hold<'py>(columns: &[(String, Bound<'py, PyAny>)]) -> PyResult<Vec<Held<'py>>> {
    columns.iter().map(|(n, v)| Held::of(n, v)).collect()
}

fn as_columns<'a>(
    columns: &'a [(String, Bound<'_, PyAny>)],
    held: &'a [Held<'_>],
) -> PyResult<Vec<Column<'a>>> {
    columns
        .iter()
        .zip(held)
        .map(|((name, _), h)| {
            Ok(Column {
                name,
                values: h.values()?,
            })
        })
        .collect()
}

/// A recording as columns and metadata for Python, read back from the text the command
/// line would have written (so that its numbers are the command line's, bit for bit).
#[allow(clippy::type_complexity)]
fn from_text<'py>(
    py: Python<'py>,
    text: &[u8],
    name: &str,
) -> PyResult<(Vec<(String, Bound<'py, PyAny>)>, Vec<(String, String)>)> {
    let rec = recording::read_bytes(text, name).map_err(|e| recording_error(py, &e))?;
    Ok((columns_of(py, &rec)?, metadata_of(&rec.meta)))
}

/// Correct the recording held in `columns` (with `meta`, named `source`) by the
/// calibration JSON `calibration` (named `cal_name`) in `frame` ("device" or "platter"):
/// the corrected recording, as `rotacal apply` writes it, as columns and metadata (its
/// traceability lines name the calibration's and the columns' SHA-256 and `command`).
#[pyfunction]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn apply_columns<'py>(
    py: Python<'py>,
    calibration: String,
    cal_name: String,
    columns: Vec<(String, Bound<'py, PyAny>)>,
    meta: Vec<(String, String)>,
    source: String,
    frame: String,
    rate_hz: Option<f64>,
    command: Vec<String>,
) -> PyResult<(Vec<(String, Bound<'py, PyAny>)>, Vec<(String, String)>)> {
    use rotacal_engine::calibrate::correction::Frame;
    use rotacal_engine::correct::apply;
    let frame = match frame.as_str() {
        "device" => Frame::Device,
        "platter" => Frame::Platter,
        other => {
            return Err(PyValueError::new_err(format!(
                "frame: '{other}' is neither 'device' nor 'platter'"
            )))
        }
    };
    let loaded = apply::load_text(&calibration, &cal_name, rate_hz, frame)
        .map_err(|e| CalibrationError::new_err(e.to_string()))?;
    let (rec, input) = read_held(py, &columns, &meta, &source)?;
    let mut t = Traceability::new(BUILD, &[]).map_err(|e| PyValueError::new_err(e.to_string()))?;
    t.inputs = vec![
        trace::input_of_bytes(&cal_name, calibration.as_bytes()),
        input,
    ];
    t.command_line = command;
    let provenance = t.as_metadata(&["calibration", "recording"]);
    let out_name = format!("{source}, corrected");
    let job = apply::Job {
        correction: &loaded.correction,
        units_in: &loaded.json.units_in,
        k: loaded.json.k,
        cal_name: &cal_name,
        g_loc: loaded.g_loc,
        out_name: &out_name,
        provenance: &provenance,
    };
    let mut text = Vec::new();
    py.detach(|| apply::apply(&rec, &job, &mut text))
        .map_err(|e| CalibrationError::new_err(e.to_string()))?;
    from_text(py, &text, &out_name)
}

/// The simulated recording of `config` (a preset's name, a TOML file's path, or TOML
/// text) with its seed replaced by `seed` if given, as `rotacal simulate` writes it, as
/// columns and metadata.
#[pyfunction]
#[pyo3(signature = (config, seed=None))]
#[allow(clippy::type_complexity)]
fn simulate<'py>(
    py: Python<'py>,
    config: String,
    seed: Option<u64>,
) -> PyResult<(Vec<(String, Bound<'py, PyAny>)>, Vec<(String, String)>)> {
    use rotacal_engine::simulate::{Config, Simulation};
    let text = config.contains('=') || config.contains('\n');
    let cfg = if text {
        Config::from_toml(&config)
    } else {
        Config::load(&config)
    };
    let mut cfg = cfg.map_err(|e| PyValueError::new_err(format!("{config}: {e}")))?;
    if let Some(s) = seed {
        cfg.seed = s;
    }
    let name = if text {
        "the configuration"
    } else {
        config.as_str()
    };
    let sim = Simulation::new(cfg).map_err(|e| PyValueError::new_err(format!("{name}: {e}")))?;
    let (_, bytes) = py
        .detach(|| sim.write(Vec::new()))
        .map_err(|e| PyValueError::new_err(format!("{name}: {e}")))?;
    from_text(py, &bytes, name)
}

/// Write the recording held in `columns` (with `meta`, named `source`) to `path` as a
/// recording CSV, checked as the reader checks it, whole or not at all.
#[pyfunction]
fn write_columns(
    py: Python<'_>,
    columns: Vec<(String, Bound<'_, PyAny>)>,
    meta: Vec<(String, String)>,
    source: String,
    path: PathBuf,
) -> PyResult<()> {
    // Read with the reader's checks; no digest: the file written has its own.
    let held = hold(&columns)?;
    let cols = as_columns(&columns, &held)?;
    let meta = str_pairs(&meta);
    let rec = py
        .detach(|| recording::read_columns(&cols, &meta, &source, None))
        .map_err(|e| recording_error(py, &e))?;
    py.detach(|| {
        rotacal_engine::atomic::write_with(&path, |w| {
            recording::write_recording(&rec, w).map(|_| ())
        })
    })
    .map_err(|e: std::io::Error| {
        let message = format!("{}: {e}", path.display());
        // What the writer refuses to write is the data's fault, not the disk's.
        match e.kind() {
            std::io::ErrorKind::InvalidInput => PyValueError::new_err(message),
            _ => pyo3::exceptions::PyOSError::new_err(message),
        }
    })
}

/// The recording file at `path`, checked, as columns ((name, values): float64 arrays or
/// lists of str, rows in the order of the groups) with its metadata ((key, value)) and
/// method.
#[pyfunction]
#[allow(clippy::type_complexity)]
fn read_recording<'py>(
    py: Python<'py>,
    path: PathBuf,
) -> PyResult<(
    Vec<(String, Bound<'py, PyAny>)>,
    Vec<(String, String)>,
    String,
)> {
    let rec = py
        .detach(|| recording::read(&path))
        .map_err(|e| recording_error(py, &e))?;
    let columns = columns_of(py, &rec)?;
    Ok((columns, metadata_of(&rec.meta), rec.method.as_str().into()))
}

/// A recording's metadata as `# key=value` pairs (numbers in their shortest exact form).
fn metadata_of(m: &recording::Metadata) -> Vec<(String, String)> {
    let mut out: Vec<(String, String)> = Vec::new();
    let mut put = |k: &str, v: Option<String>| {
        if let Some(v) = v {
            out.push((k.into(), v));
        }
    };
    put("method", m.method.map(|x| x.as_str().into()));
    put("rate_hz", m.rate_hz.map(|x| format!("{x}")));
    put("g_loc", m.g_loc.map(|x| format!("{x}")));
    put("units", m.units.clone());
    put("sample_rate_hz", m.sample_rate_hz.map(|x| format!("{x}")));
    put("noise_sigma", m.noise_sigma.map(|x| format!("{x}")));
    put("device", m.device.clone());
    for (k, v) in &m.other {
        out.push((k.clone(), v.clone()));
    }
    out
}

/// Columns being made for Python.
struct Out<'py> {
    py: Python<'py>,
    cols: Vec<(String, Bound<'py, PyAny>)>,
}

impl<'py> Out<'py> {
    fn numbers(&mut self, name: &str, x: Vec<f64>) {
        self.cols
            .push((name.into(), x.into_pyarray(self.py).into_any()));
    }

    /// Three columns from rows of three (ĝ, readings, their uncertainties).
    fn triple(&mut self, names: [&str; 3], rows: &[[f64; 3]]) {
        for (k, name) in names.into_iter().enumerate() {
            let x = rows
                .iter()
                .map(|r| r.get(k).copied().unwrap_or(f64::NAN))
                .collect();
            self.numbers(name, x);
        }
    }

    fn texts(&mut self, name: &str, x: &[String]) -> PyResult<()> {
        self.cols
            .push((name.into(), PyList::new(self.py, x)?.into_any()));
        Ok(())
    }
}

/// The recording's rows as columns, named as in its file.
fn columns_of<'py>(py: Python<'py>, rec: &Recording) -> PyResult<Vec<(String, Bound<'py, PyAny>)>> {
    let mut out = Out {
        py,
        cols: Vec::new(),
    };
    if let Some(o) = &rec.oriented {
        out.triple(["gx", "gy", "gz"], &o.gravity);
        out.triple(["u", "v", "w"], &o.y);
        if let Some(t) = &o.t_s {
            out.numbers("t_s", t.clone());
        }
        if let Some(s) = &o.seq {
            out.numbers("seq", s.iter().map(|x| *x as f64).collect());
        }
        if let Some(t) = &o.temp_c {
            out.numbers("temp_c", t.clone());
        }
        if let Some(u) = &o.unc {
            out.triple(["u_unc", "v_unc", "w_unc"], u);
        }
        if let Some(p) = &o.pose {
            out.texts("pose", p)?;
        }
        return Ok(out.cols);
    }
    if let Some(s) = &rec.series {
        out.numbers("t_s", s.t_s.clone());
        out.triple(["u", "v", "w"], &s.y);
        if let Some(x) = &s.seq {
            out.numbers("seq", x.iter().map(|x| *x as f64).collect());
        }
        if let Some(t) = &s.temp_c {
            out.numbers("temp_c", t.clone());
        }
        if let Some(p) = &s.pose {
            out.texts("pose", p)?;
        }
        return Ok(out.cols);
    }
    let g = &rec.groups;
    let all =
        |f: &dyn Fn(&recording::Group) -> Vec<f64>| -> Vec<f64> { g.iter().flat_map(f).collect() };
    // The condition as its letters' bytes, which the Python side makes a Categorical.
    let condition: Vec<u8> = g
        .iter()
        .flat_map(|x| std::iter::repeat_n(x.condition.letter() as u8, x.len()))
        .collect();
    out.cols
        .push(("condition".into(), condition.into_pyarray(py).into_any()));
    if g.iter().any(|x| x.rate_hz.is_some()) {
        out.numbers(
            "rate_hz",
            all(&|x| vec![x.rate_hz.unwrap_or(f64::NAN); x.len()]),
        );
    }
    if g.iter().any(|x| !x.t_s.is_empty()) {
        out.numbers("t_s", all(&|x| x.t_s.clone()));
    }
    if g.iter().any(|x| !x.angle_deg.is_empty()) {
        out.numbers("angle_deg", all(&|x| x.angle_deg.clone()));
    }
    out.numbers("u", all(&|x| x.u.clone()));
    out.numbers("v", all(&|x| x.v.clone()));
    out.numbers("w", all(&|x| x.w.clone()));
    let some = |f: &dyn Fn(&recording::Group) -> bool| g.first().is_some_and(f);
    if some(&|x| x.seq.is_some()) {
        out.numbers(
            "seq",
            all(&|x| x.seq.iter().flatten().map(|s| *s as f64).collect()),
        );
    }
    if some(&|x| x.temp_c.is_some()) {
        out.numbers("temp_c", all(&|x| x.temp_c.clone().unwrap_or_default()));
    }
    if some(&|x| x.unc.is_some()) {
        let unc: Vec<[f64; 3]> = g
            .iter()
            .flat_map(|x| x.unc.iter().flatten().copied())
            .collect();
        out.triple(["u_unc", "v_unc", "w_unc"], &unc);
    }
    if some(&|x| x.conversions.is_some()) {
        let gaps: Vec<String> = g
            .iter()
            .flat_map(|x| x.conversions.iter().flatten())
            .map(|a| {
                a.gaps()
                    .iter()
                    .map(u16::to_string)
                    .collect::<Vec<_>>()
                    .join(" ")
            })
            .collect();
        out.texts("conv_gaps", &gaps)?;
    }
    if some(&|x| x.missed.is_some()) {
        out.numbers(
            "conv_missed",
            all(&|x| {
                x.missed
                    .iter()
                    .flatten()
                    .map(|m| m.map_or(f64::NAN, f64::from))
                    .collect()
            }),
        );
    }
    if some(&|x| x.boot.is_some()) {
        out.numbers(
            "boot",
            all(&|x| x.boot.iter().flatten().map(|b| f64::from(*b)).collect()),
        );
    }
    Ok(out.cols)
}

/// The module.
#[pymodule]
fn _rotacal(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("RecordingError", m.py().get_type::<RecordingError>())?;
    m.add("CalibrationError", m.py().get_type::<CalibrationError>())?;
    m.add("DiscrepancyError", m.py().get_type::<DiscrepancyError>())?;
    m.add("__version__", BUILD.version)?;
    m.add("__commit__", BUILD.commit)?;
    m.add_function(wrap_pyfunction!(calibrate_path, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate_columns, m)?)?;
    m.add_function(wrap_pyfunction!(read_recording, m)?)?;
    m.add_function(wrap_pyfunction!(apply_columns, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(write_columns, m)?)?;
    m.add_function(wrap_pyfunction!(allan, m)?)?;
    m.add_function(wrap_pyfunction!(discrepancy_path, m)?)?;
    m.add_function(wrap_pyfunction!(discrepancy_columns, m)?)?;
    Ok(())
}
