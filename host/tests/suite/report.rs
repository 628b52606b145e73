//! `rotacal report`: every preset gives a Markdown report whose table is the calibration's,
//! with its plots; the residual spectrum finds a simulated second-order nonlinearity at
//! the second harmonic of the channel that has it; a bad file fails with its place; a
//! free session shows its intervals and poses.
use crate::common;
use common::run;
use rotacal::simulate::{Config, Simulation};
use std::path::PathBuf;

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("rotacal-report-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// `rotacal report REC --out OUT EXTRA…`, which must succeed: its Markdown.
fn run_report(rec: &std::path::Path, out: &std::path::Path, extra: &[String]) -> String {
    let mut a = vec![
        "report".to_string(),
        rec.display().to_string(),
        "--out".into(),
        out.display().to_string(),
    ];
    a.extend_from_slice(extra);
    let (ok, stdout, stderr) = run(&a);
    assert!(ok, "{stdout}\n{stderr}");
    std::fs::read_to_string(out.join("report.md")).unwrap()
}

fn report(cfg: Config, name: &str) -> (PathBuf, String) {
    let d = dir(name);
    let rec = d.join("rec.csv");
    Simulation::new(cfg).unwrap().write_file(&rec).unwrap();
    let out = d.join("report");
    let md = run_report(&rec, &out, &[]);
    // Every image the report names exists and is a whole SVG document.
    for img in md.split("](").skip(1).filter_map(|s| s.split(')').next()) {
        let svg = std::fs::read_to_string(out.join(img)).unwrap();
        assert!(
            svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"),
            "{img}"
        );
    }
    (out, md)
}

#[test]
fn every_preset_reports() {
    let (_, md) = report(Config::preset("paper-10mhz").unwrap(), "paper");
    assert!(md.contains("| s_u | 1669."), "{md}");
    assert_eq!(md.matches("![data and fit]").count(), 3);
    assert_eq!(md.matches("![residual spectrum]").count(), 3);
    let (out, md) = report(Config::preset("paper-multirate").unwrap(), "multi");
    assert_eq!(md.matches("## Rotation at").count(), 4);
    assert!(md.contains("![properties against rate](rates.svg)"));
    assert!(out.join("rates.svg").exists());
    let (_, md) = report(Config::preset("metrologia-static").unwrap(), "static");
    assert!(md.contains("Sensitivity matrix S"));
    assert!(md.contains("| O_u |"));
    assert!(!md.contains("residual spectrum"));
}

/// K2 = 2e-4 /(m/s²) on w: its second harmonic is s·K2·g²/2 ≈ 16 counts in condition x,
/// where w sees the whole of g; u (along the axis) and v (no K2) show only noise
/// (≈ 0.1 count).
#[test]
fn the_spectrum_finds_a_second_order_nonlinearity() {
    let mut cfg = Config::preset("paper-10mhz").unwrap();
    cfg.effects.nonlinearity_2nd = Some(rotacal::simulate::config::Nonlinearity2 {
        k2: [0.0, 0.0, 2e-4],
    });
    let (_, md) = report(cfg, "k2");
    let x = md.split("### condition x").nth(1).unwrap();
    let row = x.lines().find(|l| l.starts_with("| 2 |")).unwrap();
    let amps: Vec<f64> = row
        .split('|')
        .filter_map(|c| c.trim().parse::<f64>().ok())
        .skip(1)
        .collect();
    let expected = 1676.46 * 2e-4 * 9.80101f64.powi(2) / 2.0;
    assert!((amps[2] - expected).abs() < 0.05 * expected, "{row}");
    assert!(amps[0] < 0.5 && amps[1] < 0.5, "{row}");
}

#[test]
fn a_bad_recording_fails_with_its_place() {
    let d = dir("bad");
    let p = d.join("bad.csv");
    std::fs::write(&p, "condition,t_s,u,v,w\nx,0,1,2,3\nq,1,1,2,3\n").unwrap();
    let (ok, _, err) = run(&[
        "report".to_string(),
        p.display().to_string(),
        "--out".into(),
        d.join("r").display().to_string(),
    ]);
    assert!(!ok);
    assert!(err.contains("bad.csv:3"), "{err}");
}

/// `rotacal report` takes `calibrate`'s options and shows the same numbers as its JSON:
/// here a stepped file with equal pose weights and a stated g_loc uncertainty, which
/// change U against the defaults (so a report that ignored them would fail).
#[test]
fn the_report_and_the_json_agree_for_the_same_options() {
    let d = dir("options");
    let rec = d.join("rec.csv");
    let mut cfg = Config::preset("metrologia-static").unwrap();
    cfg.table.angle_step_deg = Some(30.0);
    cfg.table.readings_per_angle = Some(20);
    cfg.sensor.noise = common::unstated(None, None);
    Simulation::new(cfg).unwrap().write_file(&rec).unwrap();
    let options = ["--pose-weights", "equal", "--u-g-loc", "1e-4"].map(String::from);
    let table = |args: &[String], name: &str| -> Vec<(f64, f64)> {
        let md = run_report(&rec, &d.join(name), args);
        [
            "s_u", "s_v", "s_w", "φ_uv", "φ_vw", "φ_wu", "O_u", "O_v", "O_w",
        ]
        .iter()
        .map(|q| {
            let row = md
                .lines()
                .find(|l| l.starts_with(&format!("| {q} |")))
                .unwrap();
            let cell = row.split('|').nth(2).unwrap();
            let nums: Vec<f64> = cell
                .split_whitespace()
                .filter_map(|t| t.parse().ok())
                .collect();
            (nums[0], nums[1])
        })
        .collect()
    };
    let json = d.join("cal.json");
    let mut a = vec![
        "calibrate".to_string(),
        rec.display().to_string(),
        "--json".into(),
        json.display().to_string(),
    ];
    a.extend_from_slice(&options);
    let (ok, _, stderr) = run(&a);
    assert!(ok, "{stderr}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let intrinsic = &v["by_rate"][0]["intrinsic"];
    let expected: Vec<(f64, f64)> = common::PROPERTY_KEYS
        .iter()
        .map(|(g, k)| {
            let q = &intrinsic[*g][*k];
            (
                q["value"].as_f64().unwrap(),
                q["expanded_unc"].as_f64().unwrap(),
            )
        })
        .collect();
    let agree = |md: &[(f64, f64)]| {
        md.iter().zip(&expected).all(|((vm, um), (vj, uj))| {
            // The report rounds U to two significant digits and the value to match.
            let d = rotacal::calibrate::table::decimals(*uj);
            let tol = 0.5001 * 10f64.powi(-(d as i32));
            (vm - vj).abs() <= tol && (um - uj).abs() <= tol
        })
    };
    let with = table(&options, "with");
    assert!(agree(&with), "{with:?}\n{expected:?}");
    let without = table(&[], "without");
    assert!(
        !agree(&without),
        "the options made no difference: {without:?}"
    );
}

/// Method free: the report shows the JSON's properties with U, every interval the
/// detection found (a pose that turns is marked rejected), the poses, and its three plots.
#[test]
fn a_free_session_reports_its_intervals_and_poses() {
    let d = dir("free");
    let cfg = d.join("free.toml");
    std::fs::write(
        &cfg,
        r#"seed = 7
method = "free"
g_loc = 9.80101
units = "counts"
[device]
sensitivity = [1669.32, 1669.10, 1676.46]
angles_deg = [90.077, 90.095, 89.910]
offsets = [525.1, 99.6, 442.4]
[sensor]
lsb = 1.0
full_scale = [-32768.0, 32767.0]
[sensor.noise]
ar = [0.6]
sd = [10.6, 8.5, 12.5]
[timing]
sample_rate_hz = 104.0
[poses]
count = 12
still_s = 4.0
move_s = 2.0
[poses.moved]
pose = 3
deg = 1.0
"#,
    )
    .unwrap();
    let rec = d.join("F.csv");
    let out = d.join("report");
    let json = d.join("cal.json");
    let path = |p: &PathBuf| p.display().to_string();
    for args in [
        vec![
            "simulate".to_string(),
            path(&cfg),
            "--out".into(),
            path(&rec),
        ],
        vec!["report".to_string(), path(&rec), "--out".into(), path(&out)],
        vec![
            "calibrate".to_string(),
            path(&rec),
            "--json".into(),
            path(&json),
        ],
    ] {
        let (ok, stdout, stderr) = run(&args);
        assert!(ok, "{args:?}\n{stdout}\n{stderr}");
    }
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let entry = &v["by_rate"][0];
    assert!(md.contains("## Free poses (unknown orientation)"), "{md}");
    let names = rotacal::calibrate::json::PROPERTY_NAMES_WITH_OFFSETS;
    for (name, (g, k)) in names.iter().zip(common::PROPERTY_KEYS) {
        let q = &entry["intrinsic"][g][k];
        let (x, u) = (
            q["value"].as_f64().unwrap(),
            q["expanded_unc"].as_f64().unwrap(),
        );
        let dp = rotacal::calibrate::table::decimals(u);
        let cell = format!("| {name} | {x:.dp$} ± {u:.dp$} ");
        assert!(md.contains(&cell), "{cell}\n{md}");
    }
    for svg in ["magnitude.svg", "directions.svg", "pose_residuals.svg"] {
        let text = std::fs::read_to_string(out.join(svg)).unwrap();
        assert!(text.starts_with("<svg") && text.contains("</svg>"), "{svg}");
        assert!(md.contains(&format!("]({svg})")), "{svg}\n{md}");
    }
    let free = &entry["free"];
    let intervals: Vec<&serde_json::Value> = free["detection"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|d| d["intervals"].as_array().unwrap())
        .collect();
    let table = |header: &str| -> Vec<String> {
        md.lines()
            .skip_while(|l| !l.starts_with(header))
            .skip(2)
            .take_while(|l| l.starts_with('|'))
            .map(String::from)
            .collect()
    };
    let rows = table("| interval |");
    assert_eq!(rows.len(), intervals.len(), "{md}");
    for (row, i) in rows.iter().zip(&intervals) {
        let name = i["name"].as_str().unwrap();
        assert!(row.starts_with(&format!("| {name} |")), "{row}");
        assert!(row.contains(&format!("| {} |", i["n"])), "{row}");
        let verdict = i["verdict"].as_str().unwrap();
        assert!(
            row.contains(&format!("| {}", verdict.replace('-', " "))),
            "{row}"
        );
    }
    // The pose that turned is found, rejected and marked as such in the plot.
    assert!(intervals.iter().any(|i| i["verdict"] == "moved"), "{md}");
    let magnitude = std::fs::read_to_string(out.join("magnitude.svg")).unwrap();
    assert!(magnitude.contains("rejected: moved") && magnitude.contains("kept"));
    let poses = free["poses"].as_array().unwrap();
    assert_eq!(table("| # | pose |").len(), poses.len(), "{md}");
    let dof = free["dof"].as_u64().unwrap();
    assert!(md.contains(&format!("on {dof} degrees of freedom")), "{md}");
}

/// `--slow-noise`: the report draws each fit's residual Allan deviation against the model's
/// lines (one panel per condition and channel) and tables each channel's slow levels as
/// the JSON gives them; the JSON's points are the model's terms summed, at τ = m/f_s.
/// Without the option there is no such section.
#[test]
fn slow_noise_report_draws_the_residual_allan_deviation() {
    let d = dir("slow");
    let rec = d.join("rec.csv");
    let mut cfg = Config::preset("paper-10mhz").unwrap();
    cfg.seed = 12;
    let mut noise = common::unstated(None, None).unwrap();
    noise.flicker_floor_ug = Some(rotacal::simulate::NoiseSd::All(50.0));
    cfg.sensor.noise = Some(noise);
    Simulation::new(cfg).unwrap().write_file(&rec).unwrap();
    let report = |extra: &[&str], name: &str| -> (PathBuf, String) {
        let out = d.join(name);
        let extra: Vec<String> = extra.iter().map(|s| s.to_string()).collect();
        let md = run_report(&rec, &out, &extra);
        (out, md)
    };
    let (out, md) = report(&["--slow-noise"], "with");
    assert!(
        md.contains("## Allan deviation of the residuals at 0.01 Hz"),
        "{md}"
    );
    let svg = std::fs::read_to_string(out.join("allan_residuals_10mhz.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
    for c in ["x", "y", "z"] {
        for ch in ["u", "v", "w"] {
            assert!(
                svg.contains(&format!("condition {c}, channel {ch}")),
                "{c}{ch}"
            );
        }
    }
    assert!(svg.contains("model, through the fit"));

    let json = d.join("cal.json");
    let (ok, _, stderr) = run(&[
        "calibrate",
        rec.to_str().unwrap(),
        "--slow-noise",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let noise = v["by_rate"][0]["noise"].as_array().unwrap();
    assert_eq!(noise.len(), 9);
    for n in noise {
        let points = n["slow"]["residual_allan"].as_array().unwrap();
        assert!(points.len() >= 8, "{n}");
        for p in points {
            let f = |k: &str| p[k].as_f64().unwrap();
            assert_eq!(f("tau_s"), p["m"].as_f64().unwrap() / 16.0);
            let sum = f("short_range_avar") + f("flicker_avar") + f("walk_avar");
            assert!((f("expected_avar") - sum).abs() <= 1e-12 * sum.abs());
            assert!(f("observed_avar") > 0.0);
        }
    }
    // The table's floors are the JSON's, rounded.
    for (i, ch) in ["u", "v", "w"].iter().enumerate() {
        let row = md
            .lines()
            .find(|l| l.starts_with(&format!("| {ch} | ")) && l.contains("(u = "))
            .unwrap();
        let floor = &noise[i]["slow"]["flicker_floor"];
        let want = format!(
            "{:.4} (u = {:.4})",
            floor["value"].as_f64().unwrap(),
            floor["u"].as_f64().unwrap()
        );
        assert!(row.contains(&want), "{row} lacks {want}");
    }

    let (out, md) = report(&[], "without");
    assert!(!md.contains("Allan deviation of the residuals"));
    assert!(!out.join("allan_residuals_10mhz.svg").exists());
}

/// Issue 34: "for the same static O_u, u is 0.078 in the budget and 0.116 in the correction
/// table". An offset has one standard uncertainty: the intrinsic property's, the budget's
/// combined, the correction's in either frame, and the report's correction table, which
/// prints u, where the property table prints U = k·u. Checked on each method whose budget
/// has offsets (poses of known orientation, with each pose weighting and offset estimator,
/// and free poses). The first case failed: the correction kept the readings' noise where
/// the offsets took the poses' smaller scatter (0.00057 against 0.00027).
#[test]
fn an_offset_has_one_u_wherever_it_is_printed() {
    let d = dir("one-u");
    let six = crate::imucal::import("one-u-six.csv");
    let steps = d.join("steps.csv");
    let cfg = Config::preset("metrologia-static").unwrap();
    Simulation::new(cfg).unwrap().write_file(&steps).unwrap();
    let free = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/imutk-xsens/xsens_acc_free.csv");
    // Six poses whose scatter is below their noise (χ²/dof < 1, no tilt estimated): the
    // joint fit then takes the offsets' variance from the scatter (Knapp–Hartung), and the
    // correction gave the noise's, twice as large, before it took the same.
    let quiet = d.join("quiet.csv");
    six_poses(&quiet, 11);
    let cases: [(&std::path::Path, &[&str]); 6] = [
        (&quiet, &[]),
        (&six, &[]),
        (&six, &["--offsets", "axis-pairs"]),
        (&six, &["--pose-weights", "equal"]),
        (&steps, &[]),
        (&free, &[]),
    ];
    for (n, (rec, extra)) in cases.into_iter().enumerate() {
        let json = d.join(format!("cal{n}.json"));
        let mut a = vec![
            "calibrate".to_string(),
            rec.display().to_string(),
            "--json".into(),
            json.display().to_string(),
        ];
        a.extend(extra.iter().map(|s| s.to_string()));
        let (ok, o, e) = run(&a);
        assert!(ok, "{o}{e}");
        let cal: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        let entry = &cal["by_rate"][0];
        if n == 0 {
            let q = entry["poses"]["chi2_dof_joint"].as_f64().unwrap();
            assert!(q < 0.5 && entry["poses"]["tau"][0] == 0.0, "χ²/dof {q}");
        }
        let extra: Vec<String> = extra.iter().map(|s| s.to_string()).collect();
        let md = run_report(rec, &d.join(format!("report{n}")), &extra);
        for (j, c) in ["u", "v", "w"].into_iter().enumerate() {
            let property = &entry["intrinsic"]["offset"][c];
            let u = property["std_unc"].as_f64().unwrap();
            let combined = entry["uncertainty_budget"]["combined"]
                .as_array()
                .unwrap()
                .iter()
                .find(|q| q["quantity"] == format!("O_{c}"))
                .unwrap();
            let mut all = vec![
                ("budget", combined["std_unc"].as_f64().unwrap()),
                (
                    "device-frame correction",
                    entry["correction"]["device_frame"]["offset_std_unc"][j]
                        .as_f64()
                        .unwrap(),
                ),
            ];
            if let Some(p) = entry["correction"]["platter_frame"]["offset_std_unc"][j].as_f64() {
                all.push(("platter-frame correction", p));
            }
            for (place, x) in all {
                assert!(
                    x == u,
                    "case {n} {extra:?}: O_{c}'s u is {u} as a property, {x} in the {place}"
                );
            }
            println!("case {n} O_{c}: u = {u:.3e}");
            // The report's correction table prints u; its property table U = k·u.
            let row = format!("| {}′ |", ["x", "y", "z"][j]);
            let line = md.lines().find(|l| l.starts_with(&row)).unwrap();
            assert!(line.ends_with(&format!("± {u:.1e} |")), "{line}: u = {u}");
            let k = property["k"].as_f64().unwrap();
            let line = md
                .lines()
                .find(|l| l.starts_with(&format!("| O_{c} |")))
                .unwrap();
            let printed: f64 = line
                .split('±')
                .nth(1)
                .and_then(|s| s.split_whitespace().next())
                .unwrap()
                .parse()
                .unwrap();
            // Printed to two significant digits.
            assert!(
                ((printed - k * u) / (k * u)).abs() < 0.05,
                "{line}: U should be k·u = {}",
                k * u
            );
        }
    }
    std::fs::remove_dir_all(&d).ok();
}

/// A six-position session in m/s² at `path`: 200 readings at each pose of S = I + small
/// cross terms, offsets (0.1, −0.05, 0.2), white noise 0.02 m/s² from `seed`.
fn six_poses(path: &std::path::Path, seed: u64) {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut normal = move || {
        let (a, b): (f64, f64) = (rng.gen(), rng.gen());
        (-2.0 * (1.0 - a).ln()).sqrt() * (std::f64::consts::TAU * b).cos()
    };
    let s = [[1.02, 0.01, -0.02], [0.0, 0.98, 0.015], [0.01, -0.01, 1.01]];
    let o = [0.1, -0.05, 0.2];
    let mut text = String::from(
        "# rotacal recording v1\n# method=static\n# g_loc=9.81\n# units=m/s^2\ngx,gy,gz,u,v,w,pose\n",
    );
    for (k, sign) in [
        (0, 1.0),
        (0, -1.0),
        (1, 1.0),
        (1, -1.0),
        (2, 1.0),
        (2, -1.0),
    ] {
        let mut g = [0.0; 3];
        g[k] = sign;
        for _ in 0..200 {
            let y: Vec<f64> = (0..3)
                .map(|j| {
                    9.81 * (s[j][0] * g[0] + s[j][1] * g[1] + s[j][2] * g[2])
                        + o[j]
                        + 0.02 * normal()
                })
                .collect();
            text += &format!(
                "{},{},{},{:.6},{:.6},{:.6},{}{}\n",
                g[0],
                g[1],
                g[2],
                y[0],
                y[1],
                y[2],
                ["x", "y", "z"][k],
                if sign > 0.0 { "+" } else { "-" }
            );
        }
    }
    std::fs::write(path, text).unwrap();
}
