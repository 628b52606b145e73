//! `rotacal allan` on a small still recording: the table, the JSON keys, the plot; a
//! file with dropped samples exits non-zero naming the line and time of the gap; a file
//! in counts is reported in counts, saying so.
use crate::common::run;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::fmt::Write as _;
use std::path::PathBuf;

fn dir() -> PathBuf {
    let d = std::env::temp_dir().join(format!("rotacal-allan-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A free recording of `n` still samples at 104 Hz in `units`, white noise σ = 1e-3;
/// rows `skip` (file rows after the header) left out.
fn still(units: &str, n: usize, skip: std::ops::Range<usize>) -> String {
    let mut rng = ChaCha8Rng::seed_from_u64(952);
    let noise = Normal::new(0.0, 1e-3).unwrap();
    let mut s = format!("# rotacal recording v1\n# method=free\n# units={units}\nt_s,u,v,w\n");
    for i in (0..n).filter(|i| !skip.contains(i)) {
        let [u, v, w]: [f64; 3] = std::array::from_fn(|_| noise.sample(&mut rng));
        writeln!(s, "{},{u},{v},{}", i as f64 / 104.0, 9.81 + w).unwrap();
    }
    s
}

#[test]
fn allan_cli_json_and_plot() {
    let d = dir();
    let (csv, json, svg) = (d.join("still.csv"), d.join("a.json"), d.join("a.svg"));
    std::fs::write(&csv, still("m/s^2", 3000, 0..0)).unwrap();
    let (ok, out, err) = run(&[
        "allan".as_ref(),
        csv.as_os_str(),
        "--json".as_ref(),
        json.as_os_str(),
        "--plot".as_ref(),
        svg.as_os_str(),
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("results in µg"), "{out}");
    assert!(out.contains("channel w") && out.contains("N = "), "{out}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    for k in ["file", "units", "micro_g_per_unit", "groups"] {
        assert!(v.get(k).is_some(), "missing {k}");
    }
    assert_eq!(v["units"], "µg");
    let g = &v["groups"][0];
    for k in [
        "name",
        "rate_hz",
        "samples",
        "t_first_s",
        "t_last_s",
        "channels",
    ] {
        assert!(g.get(k).is_some(), "missing groups[0].{k}");
    }
    assert_eq!(g["samples"], 3000);
    let c = &g["channels"][2];
    assert_eq!(c["channel"], "w");
    let p = &c["points"][0];
    for k in ["tau_s", "m", "n", "adev", "naive_err", "interval"] {
        assert!(p.get(k).is_some(), "missing points[0].{k}");
    }
    for k in ["lo", "hi", "alpha", "edf"] {
        assert!(p["interval"].get(k).is_some(), "missing interval.{k}");
    }
    let white = &c["terms"]["terms"][0];
    assert_eq!(white["kind"], "white");
    for k in [
        "resolved",
        "theta_u2",
        "theta_se_u2",
        "ieee",
        "ieee_se",
        "h",
        "h_se",
    ] {
        assert!(white.get(k).is_some(), "missing terms.{k}");
    }
    // White noise of 1e-3 m/s² per sample at 104 Hz: N = σ/√fs in µg/√Hz, within 5 %.
    let n_true = 1e-3 / 9.80665 * 1e6 / 104f64.sqrt();
    let n = white["ieee"].as_f64().unwrap();
    assert!(
        (n / n_true - 1.0).abs() < 0.05,
        "N = {n}, expected {n_true}"
    );
    let svg = std::fs::read_to_string(&svg).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("random walk (K)"));
}

#[test]
fn allan_cli_window() {
    let d = dir();
    let (csv, json) = (d.join("window.csv"), d.join("window.json"));
    std::fs::write(&csv, still("g", 2000, 0..0)).unwrap();
    let (ok, _, err) = run(&[
        "allan".as_ref(),
        csv.as_os_str(),
        "--from".as_ref(),
        "5".as_ref(),
        "--to".as_ref(),
        "15".as_ref(),
        "--json".as_ref(),
        json.as_os_str(),
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    // Samples i/104 in [5, 15]: i = 520 … 1560.
    assert_eq!(v["groups"][0]["samples"], 1041);
    assert_eq!(v["micro_g_per_unit"], 1e6);
    let (ok, _, err) = run(&[
        "allan".as_ref(),
        csv.as_os_str(),
        "--from".as_ref(),
        "9".as_ref(),
        "--to".as_ref(),
        "3".as_ref(),
    ]);
    assert!(
        !ok && err.contains("window.csv") && err.contains("--from 9 is after --to 3"),
        "{err}"
    );
}

#[test]
fn allan_cli_gap_is_an_error_naming_line_and_time() {
    let d = dir();
    let csv = d.join("gap.csv");
    // Rows 1000..1006 dropped: the gap follows t_s = 999/104 s, at file line 5 + 1000.
    std::fs::write(&csv, still("m/s^2", 3000, 1000..1006)).unwrap();
    let (ok, _, err) = run(&["allan".as_ref(), csv.as_os_str()]);
    assert!(!ok);
    assert!(err.contains("gap.csv") && err.contains("gap"), "{err}");
    assert!(err.contains("line 1005"), "{err}");
    assert_eq!(err.matches("a gap").count(), 1, "said once: {err}");
    assert!(err.contains(&format!("t_s = {}", 999.0 / 104.0)), "{err}");
}

#[test]
fn allan_cli_counts_stay_counts() {
    let d = dir();
    let csv = d.join("counts.csv");
    std::fs::write(&csv, still("counts", 500, 0..0)).unwrap();
    let (ok, out, err) = run(&["allan".as_ref(), csv.as_os_str()]);
    assert!(ok, "{err}");
    assert!(out.contains("results in counts (the file's units"), "{out}");
}

#[test]
fn allan_cli_stepped_file_one_record_per_angle() {
    let d = dir();
    let (csv, json) = (d.join("stepped.csv"), d.join("stepped.json"));
    let mut rng = ChaCha8Rng::seed_from_u64(1554);
    let noise = Normal::new(0.0, 3.0).unwrap();
    let mut s = String::from(
        "# rotacal recording v1\n# method=static\n# units=counts\n# sample_rate_hz=16\ncondition,angle_deg,u,v,w\n",
    );
    for c in ["x", "y", "z"] {
        for angle in [0.0, 90.0] {
            for _ in 0..300 {
                let [u, v, w]: [f64; 3] = std::array::from_fn(|_| noise.sample(&mut rng));
                writeln!(s, "{c},{angle},{u},{v},{}", 16384.0 + w).unwrap();
            }
        }
    }
    std::fs::write(&csv, s).unwrap();
    let (ok, out, err) = run(&[
        "allan".as_ref(),
        csv.as_os_str(),
        "--json".as_ref(),
        json.as_os_str(),
    ]);
    assert!(ok, "{err}");
    assert!(!out.contains("method=rotation"), "{out}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let groups = v["groups"].as_array().unwrap();
    assert_eq!(groups.len(), 6, "{out}");
    assert_eq!(groups[0]["name"], "condition x at 0°");
    assert_eq!(groups[1]["name"], "condition x at 90°");
    assert_eq!(groups[1]["samples"], 300);
    assert_eq!(groups[1]["rate_hz"], 16.0);
}
