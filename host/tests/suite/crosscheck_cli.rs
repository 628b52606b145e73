//! The device logic's packets (the simulated session, run on the host) recorded into a
//! recording and a fit log, then `rotacal crosscheck` on them: it passes on the true
//! files, fails on a changed or missing sample, and names the line of a bad fit log.
use crate::common;
use common::run;
use rotacal::recording::from_device::Recorder;
use rotacal::recording::{Metadata, Method};
use rotacal_shared::device::simulated::SessionSpec;
use rotacal_shared::device::{Config, Device, RING};
use std::path::{Path, PathBuf};

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("rotacal-xc-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Record the simulated session; returns (recording, fit log) paths.
fn record(d: &Path) -> (PathBuf, PathBuf) {
    let (rec, fits) = (d.join("session.csv"), d.join("session.fits.jsonl"));
    let meta = Metadata {
        method: Some(Method::Rotation),
        rate_hz: Some(0.01),
        g_loc: Some(9.80665),
        units: Some("counts".into()),
        sample_rate_hz: Some(16.0),
        ..Metadata::default()
    };
    let new_recorder = || {
        Recorder::new(
            std::fs::File::create(&rec).unwrap(),
            std::fs::File::create(&fits).unwrap(),
            &meta,
            1_000_000,
        )
        .unwrap()
    };
    let mut r = new_recorder();
    let mut dev = Device::<RING>::new(Config::FEATHER);
    let mut err = None;
    SessionSpec::PAPER.run(&mut dev, &mut |p| {
        if let Err(e) = r.packet(&p) {
            err = Some(e);
        }
    });
    assert!(err.is_none(), "{err:?}");
    let s = r.finish().unwrap_err();
    // The simulated session sends no temperature (the QEMU run has no sensor die), so
    // the recorder refuses to invent one: checked here, then a temperature is supplied.
    assert!(s.to_string().contains("no temperature"), "{s}");
    let mut r = new_recorder();
    let mut dev = Device::<RING>::new(Config::FEATHER);
    r.packet(&rotacal_shared::packet::Packet::Temperature(
        rotacal_shared::packet::Temperature {
            seq: 0,
            centi_c: 2450,
        },
    ))
    .unwrap();
    SessionSpec::PAPER.run(&mut dev, &mut |p| r.packet(&p).unwrap());
    let sum = r.finish().unwrap();
    // 4199 averaged samples per condition (the slot open at Stop is dropped).
    assert_eq!(sum.rows, 12_597);
    assert!(sum.lost.is_empty());
    assert_eq!(sum.fit_lines, 36 + 1, "36 fit reports and the quick-look");
    (rec, fits)
}

#[test]
fn the_devices_fits_match_the_recording() {
    let d = dir("match");
    let (rec, fits) = record(&d);
    let json = d.join("xc.json");
    let (ok, out, err) = run(&[
        Path::new("crosscheck"),
        &rec,
        &fits,
        Path::new("--json"),
        &json,
    ]);
    assert!(ok, "{out}\n{err}");
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(v["passed"], true);
    assert_eq!(v["fits"].as_array().unwrap().len(), 36);
    assert!(
        v["max_delta_crlb"].as_f64().unwrap() < 1e-5,
        "{}",
        v["max_delta_crlb"]
    );
    // The recording is an ordinary recording: it calibrates.
    let (ok, out, err) = run(&[Path::new("calibrate"), &rec]);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("s_u"));

    // One count changed in one conversion of one sample (the row's mean moves by 1/n for
    // its n conversions), at the first, a middle and the last sample of each condition and
    // in each channel: the default threshold (1e-5 σ_CRLB) sees every one.
    let text = std::fs::read_to_string(&rec).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    for (cond, col) in [("x,", 3), ("y,", 4), ("z,", 5)] {
        let rows: Vec<usize> = (0..lines.len())
            .filter(|i| lines[*i].starts_with(cond))
            .collect();
        for at in [rows[0], rows[rows.len() / 2], rows[rows.len() - 1]] {
            let mut f: Vec<String> = lines[at].split(',').map(String::from).collect();
            let n = f[7].split(' ').filter(|g| !g.is_empty()).count() + 1;
            let y: f64 = f[col].parse().unwrap();
            f[col] = format!("{:?}", y + 1.0 / n as f64);
            let mut changed: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
            changed[at] = f.join(",");
            let changed = changed.join("\n") + "\n";
            let prefix = &lines[at][..12];
            assert_ne!(changed, text);
            let bad = d.join("changed.csv");
            std::fs::write(&bad, &changed).unwrap();
            let (ok, out, err) = run(&[Path::new("crosscheck"), &bad, &fits]);
            assert!(!ok, "{prefix}: passed\n{out}");
            assert!(
                out.contains("FAIL") && err.contains("do not match"),
                "{out}\n{err}"
            );
        }
    }

    // A missing row: the window is incomplete.
    let dropped: String = text
        .lines()
        .filter(|l| !l.starts_with("y,5000,"))
        .map(|l| format!("{l}\n"))
        .collect();
    let bad = d.join("dropped.csv");
    std::fs::write(&bad, dropped).unwrap();
    let (ok, out, _) = run(&[Path::new("crosscheck"), &bad, &fits]);
    assert!(!ok);
    assert!(out.contains("FAIL"), "{out}");
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn a_bad_fit_log_names_its_line() {
    let d = dir("badlog");
    let (rec, fits) = record(&d);
    let mut text = std::fs::read_to_string(&fits).unwrap();
    text.push_str("{\"fit\": {\"condition\": \"x\"}}\n");
    let lines = text.lines().count();
    std::fs::write(&fits, text).unwrap();
    let (ok, _, err) = run(&[Path::new("crosscheck"), &rec, &fits]);
    assert!(!ok);
    assert!(
        err.contains(&format!("session.fits.jsonl:{lines}:")),
        "{err}"
    );
    std::fs::remove_dir_all(&d).ok();
}
