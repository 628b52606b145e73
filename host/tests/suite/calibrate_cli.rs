//! `rotacal calibrate` end to end: recordings written with the recording writer, the
//! binary run on them, its JSON checked against formats.md and the truth.
use crate::common;
use common::run;
use rotacal::recording::{Columns, Metadata, Method, Row, Writer};
use rotacal::reference::{paper_run_spec, PAPER_DC_ANGLES_DEG, PAPER_DC_SENSITIVITY, PAPER_G_LOC};
use rotacal::simulate::geometry::sensitivity_from_intrinsic;
use rotacal_shared::synth::Synth;
use rotacal_shared::{Condition, PhaseStep, TickRate};
use serde_json::Value;
use std::path::PathBuf;

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("rotacal-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// A rotation recording of the Gaitan & Geist (2022) device; `rate_ppm` is how far the true rate is
/// off the nominal 10 mHz written in the metadata.
fn write_rotation(path: &PathBuf, rate_ppm: f64) {
    let clock = TickRate::MHZ_1;
    let s = sensitivity_from_intrinsic(PAPER_DC_SENSITIVITY, PAPER_DC_ANGLES_DEG);
    let meta = Metadata {
        method: Some(Method::Rotation),
        rate_hz: Some(0.01),
        g_loc: Some(PAPER_G_LOC),
        units: Some("counts".into()),
        ..Metadata::default()
    };
    let mut w = Writer::create(path, &meta, &Columns::ROTATION).unwrap();
    for (axis, cond) in Condition::ALL.into_iter().enumerate() {
        let step = PhaseStep::from_hz(0.01 * (1.0 + rate_ppm * 1e-6), clock).unwrap();
        let spec = paper_run_spec(&s, axis, step, 77 + axis as u64);
        for smp in Synth::new(spec) {
            let [u, v, ww] = smp.counts.map(f64::from);
            let mut row = Row::new(cond, u, v, ww);
            row.t_s = Some(smp.t.0 as f64 * 1e-6);
            w.write_row(&row).unwrap();
        }
    }
    w.flush().unwrap();
}

fn check_q(q: &Value, truth: f64) {
    let (v, u, big_u, k) = (
        q["value"].as_f64().unwrap(),
        q["std_unc"].as_f64().unwrap(),
        q["expanded_unc"].as_f64().unwrap(),
        q["k"].as_f64().unwrap(),
    );
    assert_eq!(k, 2.0);
    assert!((big_u - 2.0 * u).abs() <= 1e-12 * big_u);
    assert!(
        (v - truth).abs() <= big_u * 2.0,
        "{v} vs truth {truth} (U = {big_u})"
    );
}

#[test]
fn rotation_recording_to_json() {
    for (ppm, expect_fitted) in [(0.0, false), (300.0, true)] {
        let rec = tmp(&format!("rot-{ppm}.csv"));
        let json = tmp(&format!("rot-{ppm}.json"));
        write_rotation(&rec, ppm);
        let (ok, stdout, stderr) = run(&[
            "calibrate",
            rec.to_str().unwrap(),
            "--json",
            json.to_str().unwrap(),
        ]);
        assert!(ok, "{stderr}");
        assert!(stdout.contains("s_u") && stdout.contains("± "), "{stdout}");
        let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        assert_eq!(v["method"], "rotation");
        assert_eq!(v["units"], "counts");
        assert_eq!(v["g_loc"].as_f64(), Some(PAPER_G_LOC));
        let r = &v["by_rate"][0];
        assert_eq!(r["rate_hz"].as_f64(), Some(0.01));
        assert!(r["intrinsic"]["offset"].is_null());
        assert!(r["sensitivity_matrix"].is_null());
        for (name, t) in ["u", "v", "w"].iter().zip(PAPER_DC_SENSITIVITY) {
            check_q(&r["intrinsic"]["sensitivity"][name], t);
        }
        for (name, t) in ["uv", "vw", "wu"].iter().zip(PAPER_DC_ANGLES_DEG) {
            check_q(&r["intrinsic"]["angle_deg"][name], t);
            assert!(r["angle_deg_phase_method"][name]["value"].is_f64());
        }
        let fits = r["fits"].as_array().unwrap();
        assert_eq!(fits.len(), 9);
        for f in fits {
            for key in [
                "condition",
                "channel",
                "A",
                "B",
                "C",
                "se_A",
                "se_B",
                "se_C",
                "n",
                "rms_residual",
                "rate_hz_fitted",
            ] {
                assert!(f.get(key).is_some(), "fit lacks {key}");
            }
            assert_eq!(f["n"].as_u64(), Some(4200));
            assert_eq!(
                f["rate_hz_fitted"].is_f64(),
                expect_fitted,
                "{ppm} ppm: {f}"
            );
            if expect_fitted {
                let fitted = f["rate_hz_fitted"].as_f64().unwrap();
                assert!(
                    (fitted / 0.01 - 1.0 - 300e-6).abs() < 20e-6,
                    "fitted rate {fitted}"
                );
            }
        }
    }
}

/// GUM S1 check: on the paper run the model is close to linear, so the Monte Carlo
/// standard uncertainties equal the linear ones within the sampling error of 20 000 trials
/// (0.5 %) plus a little nonlinearity: 5 % is asserted.
#[test]
fn monte_carlo_agrees_with_linear_propagation() {
    let rec = tmp("mc.csv");
    let json = tmp("mc.json");
    write_rotation(&rec, 0.0);
    let (ok, stdout, stderr) = run(&[
        "calibrate",
        rec.to_str().unwrap(),
        "--json",
        json.to_str().unwrap(),
        "--monte-carlo",
        "20000",
    ]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("Monte Carlo"), "{stdout}");
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let r = &v["by_rate"][0];
    let linear = [
        &r["intrinsic"]["sensitivity"]["u"],
        &r["intrinsic"]["sensitivity"]["v"],
        &r["intrinsic"]["sensitivity"]["w"],
        &r["intrinsic"]["angle_deg"]["uv"],
        &r["intrinsic"]["angle_deg"]["vw"],
        &r["intrinsic"]["angle_deg"]["wu"],
    ];
    for (key, lin) in ["s_u", "s_v", "s_w", "phi_uv", "phi_vw", "phi_wu"]
        .iter()
        .zip(linear)
    {
        let mc = r["monte_carlo"][key]["std_unc"].as_f64().unwrap();
        let l = lin["std_unc"].as_f64().unwrap();
        assert!(
            (mc / l - 1.0).abs() < 0.05,
            "{key}: Monte Carlo {mc} vs linear {l}"
        );
        let (lo, hi) = (
            r["monte_carlo"][key]["low_95"].as_f64().unwrap(),
            r["monte_carlo"][key]["high_95"].as_f64().unwrap(),
        );
        let value = lin["value"].as_f64().unwrap();
        assert!(
            lo < value && value < hi,
            "{key}: {value} outside [{lo}, {hi}]"
        );
    }
}

#[test]
fn static_recording_to_json() {
    let rec = tmp("static.csv");
    let json = tmp("static.json");
    let s = sensitivity_from_intrinsic([0.2013, 0.2016, 0.2024], [90.99, 90.75, 90.30]);
    let meta = Metadata {
        g_loc: Some(9.801018),
        units: Some("V".into()),
        ..Metadata::default()
    };
    let mut w = Writer::create(&rec, &meta, &Columns::STATIC).unwrap();
    for c in Condition::ALL {
        for i in 0..72usize {
            let a = i as f64 * 5.0;
            let gd = c.gravity_direction(a.to_radians());
            let y = [0, 1, 2].map(|j| {
                9.801018 * (s[j][0] * gd[0] + s[j][1] * gd[1] + s[j][2] * gd[2])
                    + 0.001 * j as f64
                    + 1e-4 * ((i * 7 + j * 3) % 5) as f64
            });
            let mut row = Row::new(c, y[0], y[1], y[2]);
            row.angle_deg = Some(a);
            w.write_row(&row).unwrap();
        }
    }
    w.flush().unwrap();
    let (ok, _, stderr) = run(&[
        "calibrate",
        rec.to_str().unwrap(),
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["method"], "static");
    let r = &v["by_rate"][0];
    assert!(r["rate_hz"].is_null());
    assert!(r["angle_deg_phase_method"].is_null());
    assert!(r["intrinsic"]["offset"]["u"]["value"].is_f64());
    assert_eq!(
        r["sensitivity_matrix"]["value"].as_array().unwrap().len(),
        3
    );
    assert_eq!(r["fits"].as_array().unwrap().len(), 9);
    let su = r["intrinsic"]["sensitivity"]["u"]["value"]
        .as_f64()
        .unwrap();
    assert!((su - 0.2013).abs() < 1e-4, "{su}");
}

#[test]
fn bad_input_names_file_and_line() {
    let rec = tmp("short.csv");
    std::fs::write(&rec, "# g_loc=9.8\n# rate_hz=0.01\ncondition,t_s,u,v,w\nx,0,1,2,3\nx,1,1,2,3\nx,2,1,2,3\nx,3,1,2,3\nx,4,1,2,3\ny,0,1,2,3\ny,1,1,2,3\ny,2,1,2,3\ny,3,1,2,3\ny,4,1,2,3\nz,0,1,2,3\nz,1,1,2,3\nz,2,1,2,3\nz,3,1,2,3\nz,4,1,2,3\n").unwrap();
    let (ok, _, stderr) = run(&["calibrate", rec.to_str().unwrap()]);
    assert!(!ok);
    assert!(
        stderr.contains("short.csv:4") && stderr.contains("periods"),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"));
    let (ok, _, stderr) = run(&["calibrate", "/nonexistent/file.csv"]);
    assert!(
        !ok && stderr.contains("/nonexistent/file.csv") && !stderr.contains("panicked"),
        "{stderr}"
    );
    // An input that cannot be read is named once, with its cause once (the traceability
    // block's digest reads it first for `apply`).
    let out = tmp("applied-nothing.csv");
    let (ok, _, stderr) = run(&[
        "apply",
        "/nonexistent/cal.json",
        rec.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let cause = std::io::Error::from(std::io::ErrorKind::NotFound).to_string();
    assert!(!ok, "{stderr}");
    assert_eq!(
        stderr.matches("/nonexistent/cal.json").count(),
        1,
        "{stderr}"
    );
    assert_eq!(
        stderr.matches("No such file").count(),
        1,
        "{stderr} ({cause})"
    );
}
