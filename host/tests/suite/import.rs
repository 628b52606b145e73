//! `rotacal import`: a simulated session written as three plain text logs (one per
//! condition: a header, then "time_ms u v w" separated by spaces) imports into a recording
//! that calibrates exactly as the original; and malformed logs name file and line.
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
        ("t=0,u=1,v=2,w=x", "whole number"),
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
