//! `rotacal demo` can fail: a clean run passes every check and its sentences agree with
//! its numbers; a corrupted device fit fails it with status 1, naming the cross-check; a
//! property moved 4 U from the truth fails its 3 U check.
use crate::common;
use common::run;
use rotacal::calibrate::json::{IntrinsicJson, Quantity, PROPERTY_NAMES};
use rotacal::demo::{self, Check};
use std::path::PathBuf;
use std::process::Command;

/// A fresh folder for one test's demo.
fn out_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("rotacal-demo-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// The number just before `marker` in `line` (its last whitespace-separated token).
fn number_before(line: &str, marker: &str) -> f64 {
    let head = &line[..line.find(marker).unwrap()];
    head.split_whitespace().last().unwrap().parse().unwrap()
}

/// The demo's table row of each property, split into tokens.
fn table_rows(out: &str) -> Vec<Vec<&str>> {
    PROPERTY_NAMES
        .iter()
        .map(|n| {
            let row = out.lines().find(|l| l.starts_with(n)).unwrap();
            row.split_whitespace().collect()
        })
        .collect()
}

#[test]
fn clean_demo_passes_and_its_sentences_agree_with_its_numbers() {
    let dir = out_dir("clean");
    let (ok, out, err) = run(&["demo", "--out", dir.to_str().unwrap()]);
    assert!(ok, "{out}\n{err}");
    let checks: Vec<&str> = out.lines().filter(|l| l.starts_with("  ok ")).collect();
    assert_eq!(checks.len(), 13, "{out}");
    assert!(!out.contains("FAIL"), "{out}");
    assert_eq!(out.lines().last(), Some("All 13 checks passed."));

    // The device's fits are the firmware's, run on this host.
    assert!(
        out.contains("(the firmware's f32 fit, run on this host)"),
        "{out}"
    );
    assert!(!out.contains("on board") && !out.contains("~50"), "{out}");

    // The U ratio sentence: the range of the table's column, and "smaller" as every
    // ratio is above 1.
    let rows = table_rows(&out);
    let ratios: Vec<(&str, f64)> = rows
        .iter()
        .map(|r| {
            let t = r.iter().find(|t| t.ends_with('×')).unwrap();
            let t = t.trim_end_matches('×');
            (t, t.parse::<f64>().unwrap())
        })
        .collect();
    let lo = ratios.iter().min_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
    let hi = ratios.iter().max_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
    assert!(lo.1 > 1.0 && hi.1 > lo.1, "{ratios:?}");
    let sentence = format!(
        "U is {}–{} times smaller than the stated uncertainties of Gaitan & Geist (2022)",
        lo.0, hi.0
    );
    assert!(out.contains(&sentence), "{sentence}\n{out}");

    // The |err|/U column is what the 3 U checks measured, with the k they state.
    let mut ks = Vec::new();
    for (name, row) in PROPERTY_NAMES.iter().zip(&rows) {
        let claim = format!("  ok   {name} within 3 U of the truth: ");
        let line = out.lines().find(|l| l.starts_with(&claim)).unwrap();
        let err_u: f64 = row[5].parse().unwrap();
        assert_eq!(number_before(line, " U (U = "), err_u, "{line}");
        assert!(err_u <= 3.0);
        ks.push(line.rsplit("k = ").next().unwrap().trim_end_matches(')'));
    }
    assert!(ks.iter().all(|k| *k == ks[0]), "{ks:?}");
    assert!(out.contains(&format!("± is U, k = {};", ks[0])), "{out}");

    // The applied calibration: the ratio printed is that of the two RMS printed.
    let line = out
        .lines()
        .find(|l| l.contains("applied: RMS of |a| − g"))
        .unwrap();
    let measured = line.rsplit(": ").next().unwrap();
    let nums: Vec<f64> = measured
        .split([' ', ','])
        .filter_map(|t| t.parse().ok())
        .collect();
    let [after, noise, ratio, one, tolerance] = nums[..] else {
        panic!("{line}")
    };
    assert!((ratio - after / noise).abs() <= 2e-3 * ratio, "{line}");
    assert!(one == 1.0 && (ratio - 1.0).abs() <= tolerance, "{line}");
    assert!(out.contains(&format!("{ratio:.3} times the\nnoise of one reading")));

    // The puzzle: "within its U" exactly when |deviation| ≤ U, for both deviations.
    let puzzle = &out[out.find("The paper's puzzle").unwrap()..out.find("Checks (").unwrap()];
    let label = "s_w(0.5 Hz) − s_w(10 mHz) = ";
    let found: Vec<(f64, f64, bool)> = puzzle
        .match_indices(label)
        .map(|(i, _)| {
            let rest = &puzzle[i + label.len()..];
            let mut t = rest.split_whitespace();
            let v: f64 = t.next().unwrap().parse().unwrap();
            assert_eq!(t.next(), Some("±"));
            let u: f64 = t.next().unwrap().trim_end_matches(',').parse().unwrap();
            (v, u, t.next() == Some("within"))
        })
        .collect();
    assert_eq!(found.len(), 2, "{puzzle}");
    for (v, u, within) in &found {
        assert_eq!(v.abs() <= *u, *within, "{puzzle}");
    }
    assert!(!found[0].2 && found[1].2, "{puzzle}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_corrupted_device_fit_fails_the_demo_naming_the_crosscheck() {
    let dir = out_dir("corrupt");
    // common::run gives only success or not; the status must be 1.
    let o = Command::new(env!("CARGO_BIN_EXE_rotacal"))
        .args(["demo", "--inject", "corrupt-device-fit", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    let (out, err) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    assert_eq!(o.status.code(), Some(1), "{out}\n{err}");
    assert!(
        err.starts_with("rotacal: the demo failed 1 of 13 checks:\n  cross-check: "),
        "{err}"
    );
    assert!(err.contains("1 of 36 fits outside the threshold"), "{err}");
    // The whole output still came first, ending with the verdict.
    assert!(
        out.contains("Fault injected on purpose: corrupt-device-fit"),
        "{out}"
    );
    assert!(out.contains("The paper's puzzle"), "{out}");
    assert!(out.contains("  FAIL cross-check: "), "{out}");
    let last = out.lines().last().unwrap();
    assert!(
        last.starts_with("FAILED 1 of 13 checks: cross-check"),
        "{last}"
    );
    let xc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("crosscheck.json")).unwrap())
            .unwrap();
    assert_eq!(xc["passed"], false);
    let _ = std::fs::remove_dir_all(&dir);
}

/// The six properties, in `PROPERTY_NAMES` order, to edit.
fn property_mut(i: &mut IntrinsicJson, k: usize) -> &mut Quantity {
    let (s, a) = (&mut i.sensitivity, &mut i.angle_deg);
    [
        &mut s.u, &mut s.v, &mut s.w, &mut a.uv, &mut a.vw, &mut a.wu,
    ]
    .into_iter()
    .nth(k)
    .unwrap()
}

fn failed(checks: &[Check]) -> Vec<String> {
    checks
        .iter()
        .filter(|c| !c.passed)
        .map(|c| c.claim.clone())
        .collect()
}

#[test]
fn a_property_4u_from_the_truth_fails_its_3u_check() {
    let dir = out_dir("checks");
    let d = demo::run(2022, &dir, None).unwrap();
    let clean = demo::checks(&d);
    assert_eq!(failed(&clean), Vec::<String>::new());
    assert_eq!(demo::verdict(&clean), Ok(()));

    for (k, name) in PROPERTY_NAMES.iter().enumerate() {
        for (by, passes) in [(4.0, false), (-4.0, false), (2.9, true)] {
            let mut e = d.clone();
            let q = property_mut(&mut e.calibration.by_rate[0].intrinsic, k);
            q.value = d.truth[k] + by * q.expanded_unc;
            let checks = demo::checks(&e);
            if passes {
                assert_eq!(failed(&checks), Vec::<String>::new(), "{name} {by} U");
                continue;
            }
            let claim = format!("{name} within 3 U of the truth");
            assert_eq!(failed(&checks), vec![claim.clone()], "{name} {by} U");
            let err = demo::verdict(&checks).unwrap_err();
            assert!(err.contains(&format!("{claim}: |")), "{err}");
            assert!(err.contains(&format!("= {:.2} U", by.abs())), "{err}");
            let text = demo::render(&e);
            assert!(text.contains(&format!("  FAIL {claim}")), "{text}");
            assert!(text.ends_with(&format!("FAILED 1 of 13 checks: {claim}.\n")));
        }
    }

    // The modelled deviation at 1.5 U: said to be outside its U, and a failed check.
    let mut e = d.clone();
    let u = e.puzzle.deviation_modelled.1;
    e.puzzle.deviation_modelled = (1.5 * u, u);
    let claim = "puzzle: the deviation modelled is within its U";
    assert_eq!(failed(&demo::checks(&e)), vec![claim.to_string()]);
    let text = demo::render(&e);
    assert!(
        text.contains(&format!("± {u:.4}, not within its U (1.5 U).")),
        "{text}"
    );

    // A coverage factor other than 2 is printed as it is.
    let mut e = d.clone();
    let q = property_mut(&mut e.calibration.by_rate[0].intrinsic, 4);
    q.k = 2.5;
    q.expanded_unc = q.std_unc * 2.5;
    assert!(demo::render(&e).contains("± is U, k = 2–2.5 by quantity;"));
    assert!(demo::checks(&e)[6].measured.ends_with("k = 2.5)"));
    let _ = std::fs::remove_dir_all(&dir);
}
