//! A recording held as columns (`recording::read_columns`, what the Python package hands
//! over from a DataFrame) reads as the same file does: the same recording, row for row, on
//! every kind of file; and each problem is named by its column and its 0-based row.

use rotacal_engine::recording::{
    self, read_columns, Column, Recording, RecordingError, RecordingErrorKind as K, Values,
};
use rotacal_engine::simulate::{Config, Simulation};
use std::path::{Path, PathBuf};

/// A column as a file has it: numbers if every field is one, else text.
enum Held {
    Numbers(Vec<f64>),
    Texts(Vec<String>),
}

/// A recording's `# key=value` pairs, and its named columns.
type Meta = Vec<(String, String)>;
type Cols = Vec<(String, Held)>;

/// The metadata and columns of the recording CSV `text`.
fn columns_of(text: &str) -> (Meta, Cols) {
    let mut meta = Vec::new();
    let mut lines = text.lines();
    let header = loop {
        let line = lines.next().unwrap();
        match line.strip_prefix('#').and_then(|l| l.split_once('=')) {
            Some((k, v)) => meta.push((k.trim().to_string(), v.trim().to_string())),
            None if line.starts_with('#') || line.trim().is_empty() => {}
            None => break line,
        }
    };
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    let mut fields: Vec<Vec<String>> = vec![Vec::new(); names.len()];
    for line in lines.filter(|l| !l.trim().is_empty() && !l.starts_with('#')) {
        for (i, f) in line.split(',').enumerate() {
            fields[i].push(f.trim().to_string());
        }
    }
    let cols = names
        .iter()
        .zip(fields)
        .map(|(n, f)| {
            let numbers: Option<Vec<f64>> = f.iter().map(|x| x.parse().ok()).collect();
            let held = match numbers {
                Some(x) if !f.is_empty() => Held::Numbers(x),
                _ => Held::Texts(f),
            };
            (n.to_string(), held)
        })
        .collect();
    (meta, cols)
}

/// The engine's view of held columns and metadata.
fn borrowed<'a>(
    meta: &'a [(String, String)],
    cols: &'a [(String, Held)],
) -> (Vec<(&'a str, &'a str)>, Vec<Column<'a>>) {
    let columns = cols
        .iter()
        .map(|(name, h)| Column {
            name,
            values: match h {
                Held::Numbers(x) => Values::Numbers(x),
                Held::Texts(t) => Values::Texts(t),
            },
        })
        .collect();
    let meta = meta.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect();
    (meta, columns)
}

fn read_held(
    meta: &[(String, String)],
    cols: &[(String, Held)],
) -> Result<Recording, RecordingError> {
    let (meta, columns) = borrowed(meta, cols);
    read_columns(&columns, &meta, "the DataFrame", None)
}

/// The file's recording with its place in the file replaced by the row's number, as
/// columns have it.
fn as_rows(mut rec: Recording, header_line: u64) -> Recording {
    rec.source = "the DataFrame".into();
    let row = |line: u64| line - header_line - 1;
    for g in &mut rec.groups {
        g.first_line = row(g.first_line);
    }
    if let Some(o) = &mut rec.oriented {
        o.line.iter_mut().for_each(|l| *l = row(*l));
    }
    if let Some(s) = &mut rec.series {
        s.line.iter_mut().for_each(|l| *l = row(*l));
    }
    rec
}

fn temp(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("rotacal-columns-{}-{name}", std::process::id()))
}

fn same_as_the_file(path: &Path) {
    let text = std::fs::read_to_string(path).unwrap();
    let header_line = text
        .lines()
        .position(|l| !l.starts_with('#') && !l.trim().is_empty())
        .unwrap() as u64
        + 1;
    let from_file = as_rows(recording::read(path).unwrap(), header_line);
    let (meta, cols) = columns_of(&text);
    let from_columns = read_held(&meta, &cols).unwrap();
    assert!(from_file.rows() > 0);
    assert_eq!(from_columns, from_file, "{}", path.display());
}

#[test]
fn every_kind_of_recording_reads_as_its_file() {
    // Rotation (three conditions, t_s, seq, temp_c), stepped (angle_deg), poses of known
    // orientation (gx, gy, gz), and a free series from another tool.
    for (i, preset) in ["paper-10mhz", "metrologia-static"].into_iter().enumerate() {
        let mut cfg = Config::preset(preset).unwrap();
        if i == 0 {
            // A short session: the reading, not the length, is under test.
            cfg.table.duration_s = None;
            cfg.table.samples_per_condition = Some(3000);
        }
        let path = temp(&format!("{preset}.csv"));
        Simulation::new(cfg).unwrap().write_file(&path).unwrap();
        same_as_the_file(&path);
        std::fs::remove_file(&path).ok();
    }
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/data");
    same_as_the_file(&data.join("imutk-xsens/xsens_acc_free.csv"));
    for good in ["rotation", "multirate", "static", "odd_order_extra_column"] {
        same_as_the_file(&data.join(format!("recording/good/{good}.csv")));
    }
}

/// `text`'s columns read with `edit` applied: the error.
fn error(text: &str, edit: impl FnOnce(&mut Cols)) -> RecordingError {
    let (meta, mut cols) = columns_of(text);
    edit(&mut cols);
    read_held(&meta, &cols).unwrap_err()
}

const ROTATION: &str = "# method=rotation\n# rate_hz=0.01\n# g_loc=9.8\ncondition,t_s,u,v,w\n\
    x,0,1,2,3\nx,1,1,2,3\nx,2,1,2,3\ny,0,1,2,3\ny,1,1,2,3\nz,0,1,2,3\nz,1,1,2,3\n";

fn numbers<'a>(cols: &'a mut [(String, Held)], name: &str) -> &'a mut Vec<f64> {
    match &mut cols.iter_mut().find(|(n, _)| n == name).unwrap().1 {
        Held::Numbers(x) => x,
        Held::Texts(_) => panic!("{name} is text"),
    }
}

#[test]
fn each_problem_names_its_column_and_row() {
    // NaN.
    let e = error(ROTATION, |c| numbers(c, "v")[4] = f64::NAN);
    assert_eq!((e.row, e.line, e.kind.column()), (Some(4), None, Some("v")));
    assert_eq!(
        e.to_string(),
        "the DataFrame: row 4: column v: value is not finite (NaN or infinity)"
    );
    // Time going backwards within a condition.
    let e = error(ROTATION, |c| numbers(c, "t_s")[2] = 0.5);
    assert_eq!((e.row, e.kind.column()), (Some(2), Some("t_s")));
    assert!(matches!(e.kind, K::TimeWentBackwards { .. }), "{e}");
    // Text where a number belongs.
    let e = error(ROTATION, |c| {
        let mut w: Vec<String> = numbers(c, "w").iter().map(|x| x.to_string()).collect();
        w[6] = "3,5".into();
        c.iter_mut().find(|(n, _)| n == "w").unwrap().1 = Held::Texts(w);
    });
    assert_eq!((e.row, e.kind.column()), (Some(6), Some("w")));
    assert_eq!(
        e.to_string(),
        "the DataFrame: row 6: column w: '3,5' is not a number"
    );
    // A missing column, a condition that is none, columns of two lengths.
    let e = error(ROTATION, |c| c.retain(|(n, _)| n != "u"));
    assert_eq!((e.row, e.kind.column()), (None, Some("u")));
    assert!(matches!(e.kind, K::MissingColumn("u")), "{e}");
    let e = error(ROTATION, |c| match &mut c[0].1 {
        Held::Texts(t) => t[3] = "q".into(),
        Held::Numbers(_) => panic!(),
    });
    assert_eq!((e.row, e.kind.column()), (Some(3), Some("condition")));
    let e = error(ROTATION, |c| {
        numbers(c, "u").pop();
    });
    assert_eq!(
        e.to_string(),
        "the DataFrame: column u: 6 values, but the first column has 7"
    );
    // Metadata is checked as a file's.
    let (mut meta, cols) = columns_of(ROTATION);
    meta.push(("g_loc".into(), "-1".into()));
    let e = read_held(&meta, &cols).unwrap_err();
    assert!(matches!(e.kind, K::BadMetadata(_)), "{e}");
    assert_eq!((e.line, e.row), (None, None));
    meta.pop();
    meta.push(("device".into(), "two\nlines".into()));
    let e = read_held(&meta, &cols).unwrap_err();
    assert!(matches!(e.kind, K::MetadataLineBreak { .. }), "{e}");
    // Integer columns: a whole number is one, a fraction is not.
    let (meta, mut cols) = columns_of(ROTATION);
    cols.push(("seq".into(), Held::Numbers((0..7).map(f64::from).collect())));
    assert!(read_held(&meta, &cols).is_ok());
    numbers(&mut cols, "seq")[5] = 2.5;
    let e = read_held(&meta, &cols).unwrap_err();
    assert_eq!(
        e.to_string(),
        "the DataFrame: row 5: column seq: '2.5' is not a non-negative integer"
    );
}

/// What `write_recording` writes of a recording: byte for byte the file the writer wrote
/// it from (simulated rotation and stepped sessions, poses of known orientation), and a
/// recording that reads back equal for the device-averaged rows (conv_gaps, conv_missed,
/// boot) and for imu_tk's free series.
#[test]
fn a_recording_is_written_back_as_it_was_read() {
    for preset in ["paper-10mhz", "metrologia-static"] {
        let mut cfg = Config::preset(preset).unwrap();
        cfg.table.duration_s = None;
        cfg.table.samples_per_condition = Some(2000);
        let (_, bytes) = Simulation::new(cfg).unwrap().write(Vec::new()).unwrap();
        let rec = recording::read_bytes(&bytes, preset).unwrap();
        let again = recording::write_recording(&rec, Vec::new()).unwrap();
        assert_eq!(
            String::from_utf8(again).unwrap(),
            String::from_utf8(bytes).unwrap()
        );
    }
    // Poses of known orientation, with names and times.
    let meta = recording::Metadata {
        method: Some(recording::Method::Static),
        g_loc: Some(9.81),
        units: Some("m/s^2".into()),
        ..Default::default()
    };
    let cols = recording::Columns {
        gravity: true,
        pose: true,
        t_s: true,
        ..Default::default()
    };
    let mut w = recording::Writer::new(Vec::new(), &meta, &cols).unwrap();
    for (i, (name, g)) in [("x_p", [1.0, 0.0, 0.0]), ("z_a", [0.0, 0.0, -1.0])]
        .into_iter()
        .enumerate()
    {
        for k in 0..3 {
            let t = (10 * i + k) as f64 * 0.01;
            let row = recording::Row {
                gravity: Some(g),
                pose: Some(name),
                t_s: Some(t),
                ..recording::Row::new(
                    rotacal_shared::Condition::X,
                    9.81 * g[0] + 0.1 * t,
                    0.01,
                    9.81 * g[2] - 0.02,
                )
            };
            w.write_row(&row).unwrap();
        }
    }
    let bytes = w.into_inner().unwrap();
    let rec = recording::read_bytes(&bytes, "poses").unwrap();
    assert!(rec.oriented.is_some());
    let again = recording::write_recording(&rec, Vec::new()).unwrap();
    assert_eq!(
        String::from_utf8(again).unwrap(),
        String::from_utf8(bytes).unwrap()
    );
    let mut cfg = Config::preset("paper-10mhz").unwrap();
    cfg.table.duration_s = None;
    cfg.table.samples_per_condition = Some(3000);
    let averaged = Simulation::new(cfg)
        .unwrap()
        .recording_through_device()
        .unwrap();
    assert!(averaged.groups[0].conversions.is_some());
    let free = recording::read(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/data/imutk-xsens/xsens_acc_free.csv"),
    )
    .unwrap();
    for rec in [averaged, free] {
        let bytes = recording::write_recording(&rec, Vec::new()).unwrap();
        let mut back = recording::read_bytes(&bytes, "again").unwrap();
        back.source = rec.source.clone();
        // The same rows and metadata; lines may move (a file from another tool had other
        // comment lines).
        let strip = |mut r: Recording| {
            r.groups.iter_mut().for_each(|g| g.first_line = 0);
            if let Some(s) = &mut r.series {
                s.line.clear();
            }
            r
        };
        assert_eq!(strip(back), strip(rec));
    }
}

/// Numbers of two calibration JSONs: equal (`tol` 0) or within `tol` relative, all but
/// the places (`first_line`, a file's line and a column's row).
fn agree(a: &serde_json::Value, b: &serde_json::Value, tol: f64, at: &str) {
    use serde_json::Value as V;
    match (a, b) {
        (V::Object(x), V::Object(y)) => {
            let keys: Vec<_> = x.keys().filter(|k| *k != "first_line").collect();
            assert_eq!(
                keys,
                y.keys().filter(|k| *k != "first_line").collect::<Vec<_>>(),
                "{at}"
            );
            for k in keys {
                agree(&x[k], &y[k], tol, &format!("{at}/{k}"));
            }
        }
        (V::Array(x), V::Array(y)) => {
            assert_eq!(x.len(), y.len(), "{at}");
            for (i, (p, q)) in x.iter().zip(y).enumerate() {
                agree(p, q, tol, &format!("{at}[{i}]"));
            }
        }
        (V::Number(p), V::Number(q)) if tol > 0.0 => {
            // A value to its bound, an uncertainty (u, U, k) to U's.
            let tol = if at.ends_with("/value") { 1e-10 } else { tol };
            let (p, q) = (p.as_f64().unwrap(), q.as_f64().unwrap());
            assert!(
                (p - q).abs() <= tol * p.abs().max(q.abs()),
                "{at}: {p} vs {q}"
            );
        }
        _ => assert_eq!(a, b, "{at}"),
    }
}

/// `stream::calibrate_columns` (the Python package's DataFrames) calibrates as
/// `calibrate_file` does the same recording's file: bit for bit where each group is fitted
/// from its rows (four rates, 4200 rows a condition); where a group is summed in two parts
/// (over 65 536 rows), which the file cuts at a byte and the columns at a row, the
/// properties within the streaming engine's bounds (docs/streaming.md: values 10⁻¹⁰, U
/// 10⁻⁸ relative).
#[test]
fn columns_calibrate_as_their_file() {
    use rotacal_engine::calibrate::{stream, Options};
    for (preset, rows, tol) in [
        ("paper-multirate", None, 0.0),
        ("paper-10mhz", Some(80_000), 1e-8),
    ] {
        let mut cfg = Config::preset(preset).unwrap();
        if let Some(n) = rows {
            cfg.table.duration_s = None;
            cfg.table.samples_per_condition = Some(n);
        }
        let path = temp(&format!("cal-{preset}.csv"));
        Simulation::new(cfg).unwrap().write_file(&path).unwrap();
        let opts = Options::default();
        let file = stream::calibrate_file(&path, &opts).unwrap();
        let (meta, cols) = columns_of(&std::fs::read_to_string(&path).unwrap());
        std::fs::remove_file(&path).ok();
        let (meta, columns) = borrowed(&meta, &cols);
        let held = stream::calibrate_columns(&columns, &meta, "the DataFrame", &opts).unwrap();
        let (a, b) = (
            serde_json::to_value(&held).unwrap(),
            serde_json::to_value(&file).unwrap(),
        );
        let (x, y) = (
            a["by_rate"].as_array().unwrap(),
            b["by_rate"].as_array().unwrap(),
        );
        assert!(!x.is_empty() && x.len() == y.len());
        if tol == 0.0 {
            agree(&a, &b, tol, preset);
        } else {
            // The properties: the values and their uncertainties.
            for (i, (p, q)) in x.iter().zip(y).enumerate() {
                agree(
                    &p["intrinsic"],
                    &q["intrinsic"],
                    tol,
                    &format!("{preset}[{i}]"),
                );
            }
        }
    }
}
