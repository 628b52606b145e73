//! `rotacal import`: a simulated session written as three plain text logs (one per
//! condition: a header, then "time_ms u v w" separated by spaces) imports into a recording
//! that calibrates exactly as the original; so does the same session as a German
//! spreadsheet's CSV export (semicolons, decimal commas, a Windows code page header, names
//! for the columns, a scale); a workbook, a logger's serial dump and a phyphox export
//! import; malformed logs name file and line, and a failed import leaves no file.
use crate::common;
use common::run;
use rotacal::simulate::{Config, Simulation};
use std::path::{Path, PathBuf};

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("rotacal-import-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn intrinsic(json: &Path) -> Vec<f64> {
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(json).unwrap()).unwrap();
    let i = &v["by_rate"][0]["intrinsic"];
    ["u", "v", "w"]
        .iter()
        .map(|k| i["sensitivity"][k]["value"].as_f64().unwrap())
        .chain(
            ["uv", "vw", "wu"]
                .iter()
                .map(|k| i["angle_deg"][k]["value"].as_f64().unwrap()),
        )
        .collect()
}

#[test]
fn text_logs_import_and_calibrate_like_the_original() {
    let d = dir("roundtrip");
    let sim = Simulation::new(Config::preset("paper-10mhz").unwrap()).unwrap();
    let original = d.join("original.csv");
    sim.write_file(&original).unwrap();
    let rec = sim.recording().unwrap();
    let mut logs = Vec::new();
    for g in &rec.groups {
        let path = d.join(format!("{}.txt", g.condition.letter()));
        let mut text = String::from("time(ms)  X  Y  Z\n");
        for i in 0..g.len() {
            text += &format!(
                "{:.3}   {} {} {}\n",
                g.t_s[i] * 1000.0,
                g.u[i],
                g.v[i],
                g.w[i]
            );
        }
        std::fs::write(&path, text).unwrap();
        logs.push(path);
    }
    let imported = d.join("imported.csv");
    let mut args: Vec<String> = vec!["import".into()];
    args.extend(logs.iter().map(|p| p.display().to_string()));
    args.extend(
        [
            "--columns",
            "t=0,u=1,v=2,w=3",
            "--condition",
            "x,y,z",
            "--skip",
            "1",
            "--time-scale",
            "0.001",
            "--rate-hz",
            "0.01",
            "--g-loc",
            "9.80101",
            "--units",
            "counts",
            "--out",
        ]
        .map(String::from),
    );
    args.push(imported.display().to_string());
    let (ok, out, err) = run(&args);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("12600 rows"), "{out}");
    let (a, b) = (d.join("a.json"), d.join("b.json"));
    for (rec, json) in [(&original, &a), (&imported, &b)] {
        let (ok, out, err) = run(&[
            "calibrate".to_string(),
            rec.display().to_string(),
            "--json".into(),
            json.display().to_string(),
        ]);
        assert!(ok, "{out}\n{err}");
    }
    let (x, y) = (intrinsic(&a), intrinsic(&b));
    for (p, q) in x.iter().zip(&y) {
        assert!((p - q).abs() <= 1e-12 * p.abs(), "{p} vs {q}");
    }
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn malformed_logs_name_file_and_line() {
    let d = dir("bad");
    let cases: &[(&str, &str, &str, &str)] = &[
        (
            "0 1 2 3\n1 1 x 3\n",
            "t=0,u=1,v=2,w=3",
            "x",
            ":2: v (field 2) 'x' is not a finite number",
        ),
        (
            "0 1 2 3\n1 1 2\n",
            "t=0,u=1,v=2,w=3",
            "x",
            ":2: no field 3 for w",
        ),
        (
            "0 1 2 3\n2 1 2 3\n1 1 2 3\n",
            "t=0,u=1,v=2,w=3",
            "x",
            ":3: time went backwards",
        ),
        (
            "0,1,2,3,q\n",
            "t=0,u=1,v=2,w=3,condition=4",
            "",
            ":1: condition 'q'",
        ),
        (
            "0 1 2 inf\n",
            "t=0,u=1,v=2,w=3",
            "x",
            "'inf' is not a finite number",
        ),
        (
            "# only a comment\n",
            "t=0,u=1,v=2,w=3",
            "x",
            "no data lines",
        ),
    ];
    for (i, (text, map, cond, want)) in cases.iter().enumerate() {
        let p = d.join(format!("case{i}.txt"));
        std::fs::write(&p, text).unwrap();
        let mut args = vec![
            "import".to_string(),
            p.display().to_string(),
            "--columns".into(),
            map.to_string(),
            "--out".into(),
            d.join("out.csv").display().to_string(),
        ];
        if !cond.is_empty() {
            args.extend(["--condition".to_string(), cond.to_string()]);
        }
        let (ok, _, err) = run(&args);
        assert!(!ok, "case {i} accepted");
        assert!(err.contains(want), "case {i}: {err}");
        assert!(
            err.contains(&format!("case{i}.txt")),
            "case {i} names no file: {err}"
        );
    }
    // Flag errors.
    for (map, want) in [
        ("t=0,u=1,v=2", "u, v and w are all required"),
        ("t=0,u=1,v=2,w=-1", "whole number"),
        ("t=0,u=1,v=2,w=3,q=4", "unknown column 'q'"),
        ("u=1,v=2,w=3", "give t (rotation) or angle (static)"),
    ] {
        let (ok, _, err) = run(&["import", "nofile", "--columns", map, "--out", "x.csv"]);
        assert!(!ok);
        assert!(err.contains(want), "{map}: {err}");
    }
    let p = d.join("two.txt");
    std::fs::write(&p, "0 1 2 3\n").unwrap();
    let (ok, _, err) = run(&[
        "import",
        &p.display().to_string(),
        "--columns",
        "t=0,u=1,v=2,w=3",
        "--condition",
        "x,y",
        "--out",
        &d.join("o.csv").display().to_string(),
    ]);
    assert!(!ok);
    assert!(err.contains("1 input(s) but 2 condition(s)"), "{err}");
    std::fs::remove_dir_all(&d).ok();
}

/// Issue 34: a German Excel CSV export of a user's session, one file per condition:
/// "Zeit [ms];Beschl. X;…;Temp. [°C]" in Windows-1252, semicolons, decimal commas, the
/// readings written doubled (a logger's own scale), columns by name, no --skip. It imports
/// with --scale 0.5 into the original's numbers and calibrates exactly as the original.
#[test]
fn a_german_spreadsheets_csv_imports_by_name_and_calibrates_like_the_original() {
    let d = dir("german");
    let sim = Simulation::new(Config::preset("paper-10mhz").unwrap()).unwrap();
    let original = d.join("original.csv");
    sim.write_file(&original).unwrap();
    let rec = sim.recording().unwrap();
    let comma = |x: f64| format!("{x}").replace('.', ",");
    let mut logs = Vec::new();
    for g in &rec.groups {
        let path = d.join(format!("messung-{}.csv", g.condition.letter()));
        // "°" is 0xB0 in Windows-1252: not UTF-8.
        let mut bytes = b"Zeit [ms];Beschl. X;Beschl. Y;Beschl. Z;Temp. [\xB0C]\r\n".to_vec();
        for i in 0..g.len() {
            let line = format!(
                "{};{};{};{};21,5\r\n",
                comma(g.t_s[i] * 1000.0),
                comma(g.u[i] * 2.0),
                comma(g.v[i] * 2.0),
                comma(g.w[i] * 2.0)
            );
            bytes.extend_from_slice(line.as_bytes());
        }
        std::fs::write(&path, bytes).unwrap();
        logs.push(path);
    }
    let imported = d.join("imported.csv");
    let mut args: Vec<String> = vec!["import".into()];
    args.extend(logs.iter().map(|p| p.display().to_string()));
    args.extend(
        [
            "--columns",
            "t=Zeit [ms],u=Beschl. X,v=beschl. y,w=Beschl. Z,temp=4",
            "--condition",
            "x,y,z",
            "--time-scale",
            "0.001",
            "--scale",
            "0.5",
            "--rate-hz",
            "0.01",
            "--g-loc",
            "9.80101",
            "--units",
            "counts",
            "--out",
        ]
        .map(String::from),
    );
    args.push(imported.display().to_string());
    let (ok, out, err) = run(&args);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("12600 rows"), "{out}");
    let (a, b) = (d.join("a.json"), d.join("b.json"));
    for (rec, json) in [(&original, &a), (&imported, &b)] {
        let (ok, out, err) = run(&[
            "calibrate".to_string(),
            rec.display().to_string(),
            "--json".into(),
            json.display().to_string(),
        ]);
        assert!(ok, "{out}\n{err}");
    }
    let (x, y) = (intrinsic(&a), intrinsic(&b));
    for (p, q) in x.iter().zip(&y) {
        assert!((p - q).abs() <= 1e-12 * p.abs(), "{p} vs {q}");
    }
    // A name the header lacks is named, with the header's names.
    let (ok, _, err) = run(&[
        "import",
        &logs[0].display().to_string(),
        "--columns",
        "t=Zeit,u=Beschl. X,v=Beschl. Y,w=Beschl. Z",
        "--condition",
        "x",
        "--out",
        &d.join("no.csv").display().to_string(),
    ]);
    assert!(!ok);
    assert!(
        err.contains(
            "messung-x.csv:1: t=Zeit: the header has no such column (it has: Zeit [ms] | Beschl. X"
        ),
        "{err}"
    );
    assert!(!d.join("no.csv").exists());
    std::fs::remove_dir_all(&d).ok();
}

/// The rows of a recording as numbers: (t_s, u, v, w, temp_c).
fn rows(p: &Path) -> Vec<Vec<f64>> {
    let text = std::fs::read_to_string(p).unwrap();
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let cols: Vec<usize> = ["t_s", "u", "v", "w", "temp_c"]
        .iter()
        .map(|c| header.iter().position(|h| h == c).unwrap())
        .collect();
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            cols.iter().map(|&c| f[c].parse().unwrap()).collect()
        })
        .collect()
}

/// Issue 34: an Excel workbook (.xlsx, the data on its second sheet, "Messung", with a
/// header) imports cell for cell; the first sheet has no numbers, and a sheet it lacks is
/// named with those it has.
#[test]
fn an_excel_workbook_imports_cell_for_cell() {
    let d = dir("xlsx");
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/import");
    let book = data.join("workbook.xlsx").display().to_string();
    let out = d.join("rec.csv");
    let base = |sheet: Option<&str>| {
        let mut a = vec![
            "import".to_string(),
            book.clone(),
            "--columns".into(),
            "t=Zeit [s],u=ax [g],v=ay [g],w=az [g],temp=Temp [°C]".into(),
            "--condition".into(),
            "x".into(),
            "--units".into(),
            "g".into(),
            "--out".into(),
            out.display().to_string(),
        ];
        if let Some(s) = sheet {
            a.extend(["--sheet".to_string(), s.to_string()]);
        }
        a
    };
    let (ok, o, err) = run(&base(Some("Messung")));
    assert!(ok, "{o}\n{err}");
    assert!(o.contains("40 rows"), "{o}");
    let want: Vec<Vec<f64>> = std::fs::read_to_string(data.join("workbook-expected.csv"))
        .unwrap()
        .lines()
        .map(|l| l.split(',').map(|x| x.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows(&out), want);
    std::fs::remove_file(&out).unwrap();
    // The first sheet, "Info", has no line of numbers.
    let (ok, _, err) = run(&base(None));
    assert!(!ok);
    assert!(
        err.contains("workbook.xlsx (sheet 'Info'): no data lines"),
        "{err}"
    );
    let (ok, _, err) = run(&base(Some("Daten")));
    assert!(!ok);
    assert!(
        err.contains("no sheet 'Daten' (the workbook has: Info, Messung)"),
        "{err}"
    );
    assert!(!out.exists());
    std::fs::remove_dir_all(&d).ok();
}

/// Issue 34: what common loggers write. An Arduino sketch's serial dump (a banner, then
/// a comma-separated header and rows, milliseconds), and phyphox's CSV export (quoted
/// names with units) import without --skip, by the header's names.
#[test]
fn a_serial_dump_and_a_phyphox_export_import_by_name() {
    let d = dir("loggers");
    let cases = [
        (
            "serial.txt",
            "Adafruit LSM6DS33 test!\nLSM6DS33 Found!\nAccelerometer range set to: +-4G\n\
             millis,ax,ay,az\n0,0.12,-0.03,9.79\n62,0.13,-0.02,9.80\n125,0.11,-0.04,9.81\n",
            "t=millis,u=ax,v=ay,w=az",
            [0.125, 0.11, -0.04, 9.81],
        ),
        (
            "phyphox.csv",
            "\"Time (s)\",\"Acceleration x (m/s^2)\",\"Acceleration y (m/s^2)\",\
             \"Acceleration z (m/s^2)\"\n0.000000000E0,1.2E-1,-3.0E-2,9.79E0\n\
             6.25E-2,1.3E-1,-2.0E-2,9.8E0\n1.25E-1,1.1E-1,-4.0E-2,9.81E0\n",
            "t=Time (s),u=Acceleration x (m/s^2),v=Acceleration y (m/s^2),w=Acceleration z (m/s^2)",
            [0.125, 0.11, -0.04, 9.81],
        ),
    ];
    for (name, text, map, last) in cases {
        let p = d.join(name);
        std::fs::write(&p, text).unwrap();
        let out = d.join(format!("{name}.rec.csv"));
        let mut args = vec![
            "import".to_string(),
            p.display().to_string(),
            "--columns".into(),
            map.into(),
            "--condition".into(),
            "x".into(),
            "--out".into(),
            out.display().to_string(),
        ];
        if name == "serial.txt" {
            args.extend(["--time-scale".to_string(), "0.001".to_string()]);
        }
        let (ok, o, err) = run(&args);
        assert!(ok, "{name}: {o}\n{err}");
        assert!(o.contains("3 rows"), "{name}: {o}");
        let r = rows_without_temp(&out);
        assert_eq!(r.last().unwrap(), &last.to_vec(), "{name}");
    }
    std::fs::remove_dir_all(&d).ok();
}

fn rows_without_temp(p: &Path) -> Vec<Vec<f64>> {
    let text = std::fs::read_to_string(p).unwrap();
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .skip(1)
        .map(|l| l.split(',').skip(1).map(|x| x.parse().unwrap()).collect())
        .collect()
}

/// Issue 34: a failed import leaves no file, and an earlier file of the same name as it
/// was; a header read as data says what to do; a binary file is named as one.
#[test]
fn a_failed_import_leaves_nothing_and_says_what_to_do() {
    let d = dir("failed");
    let log = d.join("log.txt");
    let mut text = String::from("t u v w\n");
    for i in 0..500 {
        text += &format!("{i} 1 2 3\n");
    }
    text += "500 1 oops 3\n";
    std::fs::write(&log, &text).unwrap();
    let out = d.join("rec.csv");
    let import = |log: &Path| {
        run(&[
            "import",
            &log.display().to_string(),
            "--columns",
            "t=0,u=1,v=2,w=3",
            "--condition",
            "x",
            "--out",
            &out.display().to_string(),
        ])
    };
    let (ok, _, err) = import(&log);
    assert!(!ok);
    assert!(
        err.contains("log.txt:502: v (field 2) 'oops' is not a finite number"),
        "{err}"
    );
    assert!(!out.exists(), "a partial file was left");
    assert_eq!(
        std::fs::read_dir(&d).unwrap().count(),
        1,
        "a temporary file was left"
    );
    std::fs::write(&out, "kept\n").unwrap();
    let (ok, _, _) = import(&log);
    assert!(!ok);
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "kept\n");
    std::fs::remove_file(&out).unwrap();
    // A header with a number in it is taken for data: the message says how to skip it.
    std::fs::write(&log, "run 2 t u v w\n0 1 2 3\n").unwrap();
    let (ok, _, err) = import(&log);
    assert!(!ok);
    assert!(
        err.contains(
            "log.txt:1: v (field 2) 't' is not a finite number; if this line is not data, \
             skip the lines up to it with --skip 1"
        ),
        "{err}"
    );
    // A binary file.
    std::fs::write(&log, b"\x00\x01\x02 binary\n").unwrap();
    let (ok, _, err) = import(&log);
    assert!(!ok);
    assert!(err.contains("log.txt:1: a binary file, not text"), "{err}");
    assert!(!out.exists());
    std::fs::remove_dir_all(&d).ok();
}

/// Issue 34: a user's log in g. Imported as "counts", calibrate warns that the readings look
/// like g (the sensitivities are 1/g_loc per m/s²); imported as "g", it does not. Given
/// twice the rate the table turned at, the fit fails and says what rate the data show.
#[test]
fn readings_in_g_and_a_wrong_rate_are_named_with_what_to_do() {
    let d = dir("plausible");
    let sim = Simulation::new(Config::preset("paper-10mhz").unwrap()).unwrap();
    let rec = sim.recording().unwrap();
    let mut logs = Vec::new();
    for g in &rec.groups {
        let path = d.join(format!("{}.csv", g.condition.letter()));
        let mut text = String::from("t,ax,ay,az\n");
        for i in 0..g.len() {
            let to_g = |c: f64| c / 16384.0;
            text += &format!(
                "{},{},{},{}\n",
                g.t_s[i],
                to_g(g.u[i]),
                to_g(g.v[i]),
                to_g(g.w[i])
            );
        }
        std::fs::write(&path, text).unwrap();
        logs.push(path.display().to_string());
    }
    let import = |units: &str, out: &Path| {
        let mut args: Vec<String> = vec!["import".into()];
        args.extend(logs.iter().cloned());
        args.extend(
            [
                "--columns",
                "t=t,u=ax,v=ay,w=az",
                "--condition",
                "x,y,z",
                "--rate-hz",
                "0.01",
                "--g-loc",
                "9.80101",
                "--units",
                units,
                "--out",
            ]
            .map(String::from),
        );
        args.push(out.display().to_string());
        let (ok, o, err) = run(&args);
        assert!(ok, "{o}\n{err}");
    };
    let (counts, in_g) = (d.join("counts.csv"), d.join("g.csv"));
    import("counts", &counts);
    import("g", &in_g);
    let calibrate = |p: &Path, extra: &[&str]| {
        let mut args = vec!["calibrate".to_string(), p.display().to_string()];
        args.extend(extra.iter().map(|s| s.to_string()));
        run(&args)
    };
    let (ok, out, err) = calibrate(&counts, &[]);
    assert!(ok, "{out}\n{err}");
    assert!(
        err.contains("are about 1/g_loc = 0.1020: the readings look like g, not 'counts'"),
        "{err}"
    );
    let (ok, out, err) = calibrate(&in_g, &[]);
    assert!(ok, "{out}\n{err}");
    assert!(!err.contains("warning"), "{err}");
    // Twice the rate: the fit fails, and the data's own rate is named.
    let (ok, _, err) = calibrate(&in_g, &["--rate-hz", "0.02"]);
    assert!(!ok);
    assert!(
        err.contains(
            "the data look like 0.0101 Hz (conditions x, y, z), not the nominal 0.0200 Hz: \
             check --rate-hz"
        ),
        "{err}"
    );
    // A report that fails so leaves no folder behind, not even its first plots.
    let rep_dir = d.join("report");
    let (ok, _, err) = run(&[
        "report",
        &in_g.display().to_string(),
        "--rate-hz",
        "0.02",
        "--out",
        &rep_dir.display().to_string(),
    ]);
    assert!(!ok);
    assert!(err.contains("the data look like 0.0101 Hz"), "{err}");
    assert!(!rep_dir.exists());
    // Half of it: too few periods at that rate, and the same hint.
    let (ok, _, err) = calibrate(&in_g, &["--rate-hz", "0.005"]);
    assert!(!ok);
    assert!(err.contains("the data look like 0.0101 Hz"), "{err}");
    // The right rate: no hint.
    let (ok, _, err) = calibrate(&in_g, &["--rate-hz", "0.01"]);
    assert!(ok && !err.contains("look like"), "{err}");
    std::fs::remove_dir_all(&d).ok();
}
