//! The uncertainty budget's arithmetic (docs/uncertainty.md): the g_loc line, its absence
//! stated, the combination (quadrature, Welch–Satterthwaite, k per property), and the
//! metadata key against the flag.
// Per-property index loops read more plainly over parallel lists.
#![allow(clippy::needless_range_loop)]
use crate::common;

use rotacal::calibrate::json::RateJson;
use rotacal::calibrate::{calibrate, Options, TypeB};
use rotacal::simulate::{Config, Simulation};

fn rotation_file() -> rotacal::recording::Recording {
    Simulation::new(Config::preset("paper-10mhz").unwrap())
        .unwrap()
        .recording()
        .unwrap()
}

fn with_u_g(rec: &rotacal::recording::Recording, u: Option<f64>) -> RateJson {
    let opts = Options {
        inputs: TypeB {
            u_g_loc: u,
            ..TypeB::default()
        },
        ..Options::default()
    };
    calibrate(rec, &opts).unwrap().by_rate.remove(0)
}

/// Checks every combined line of a budget against its sources, and the result's
/// quantities against the combined lines.
fn check_combination(r: &RateJson) {
    let b = r.uncertainty_budget.as_ref().unwrap();
    let qs = r.intrinsic.quantities();
    assert_eq!(qs.len(), b.quantities.len());
    for (i, (q, c)) in qs.iter().zip(&b.combined).enumerate() {
        let var: f64 = b.sources.iter().map(|s| s.contribution[i].powi(2)).sum();
        assert!((c.std_unc - var.sqrt()).abs() <= 1e-12 * c.std_unc);
        let denom: f64 = b
            .sources
            .iter()
            .filter_map(|s| s.dof[i].map(|nu| s.contribution[i].powi(4) / nu))
            .sum();
        let nu = c.nu_eff.unwrap_or(f64::INFINITY);
        assert!((nu - var * var / denom).abs() <= 1e-9 * nu, "{nu}");
        assert!(c.k >= 2.0 && (c.expanded_unc - c.k * c.std_unc).abs() <= 1e-12 * c.expanded_unc);
        assert_eq!(
            (q.std_unc, q.expanded_unc, q.k),
            (c.std_unc, c.expanded_unc, c.k)
        );
        let largest = b
            .sources
            .iter()
            .max_by(|a, b| a.contribution[i].total_cmp(&b.contribution[i]))
            .unwrap();
        assert_eq!(c.dominant, largest.source);
    }
}

#[test]
fn g_loc_scales_every_sensitivity_and_no_angle() {
    let rec = rotation_file();
    let g = rec.meta.g_loc.unwrap();
    let without = with_u_g(&rec, None);
    let with = with_u_g(&rec, Some(1e-4));
    for r in [&without, &with] {
        check_combination(r);
    }
    let b = with.uncertainty_budget.as_ref().unwrap();
    let line = b.source("g_loc").unwrap();
    assert_eq!(line.std_unc, Some(1e-4));
    let qs = with.intrinsic.quantities();
    for i in 0..3 {
        // u(s)/s = 1e-4/g_loc exactly.
        let rel = line.contribution[i] / qs[i].value;
        assert!((rel - 1e-4 / g).abs() <= 1e-15, "{rel}");
        // Combined: the type-A part of the budget without g, and g in quadrature.
        let a = without.intrinsic.quantities()[i].std_unc;
        let expect = a.hypot(1e-4 / g * qs[i].value);
        assert!((qs[i].std_unc - expect).abs() <= 1e-9 * expect);
    }
    for i in 3..6 {
        assert_eq!(line.contribution[i], 0.0);
        assert_eq!(qs[i].std_unc, without.intrinsic.quantities()[i].std_unc);
    }
    assert_eq!(
        b.combined[0].dominant, "g_loc",
        "1e-4/g is about 6e-6·s here"
    );
    assert!(b.notes.is_empty());
    // Without it: a line of zero that says so, and a note.
    let b0 = without.uncertainty_budget.as_ref().unwrap();
    let l0 = b0.source("g_loc").unwrap();
    assert_eq!(l0.std_unc, Some(0.0));
    assert!(l0.description.contains("NOT GIVEN"));
    assert_eq!(b0.notes.len(), 1);
}

#[test]
fn static_budget_g_loc_leaves_offsets_and_angles() {
    let rec = Simulation::new(Config::preset("metrologia-static").unwrap())
        .unwrap()
        .recording()
        .unwrap();
    let g = rec.meta.g_loc.unwrap();
    let opts = |u| Options {
        inputs: TypeB {
            u_g_loc: u,
            ..TypeB::default()
        },
        ..Options::default()
    };
    let with = calibrate(&rec, &opts(Some(2e-4)))
        .unwrap()
        .by_rate
        .remove(0);
    let without = calibrate(&rec, &opts(None)).unwrap().by_rate.remove(0);
    check_combination(&with);
    check_combination(&without);
    let line = with
        .uncertainty_budget
        .as_ref()
        .unwrap()
        .source("g_loc")
        .unwrap();
    let qs = with.intrinsic.quantities();
    assert_eq!(qs.len(), 9);
    for i in 0..9 {
        let expect = if i < 3 { qs[i].value * 2e-4 / g } else { 0.0 };
        assert!((line.contribution[i] - expect).abs() <= 1e-15 * qs[i].value.abs().max(1.0));
    }
}

#[test]
fn the_file_key_and_the_flag() {
    let dir = std::env::temp_dir().join(format!("rotacal-budget-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let plain = dir.join("plain.csv");
    Simulation::new(Config::preset("paper-10mhz").unwrap())
        .unwrap()
        .write_file(&plain)
        .unwrap();
    let text = std::fs::read_to_string(&plain).unwrap();
    let keyed = dir.join("keyed.csv");
    std::fs::write(
        &keyed,
        text.replacen("# g_loc=", "# u_g_loc=3e-4\n# g_loc=", 1),
    )
    .unwrap();
    let json = |args: &[&str]| {
        let out = dir.join("out.json");
        let mut a = vec!["calibrate"];
        a.extend_from_slice(args);
        a.extend(["--json", out.to_str().unwrap()]);
        let (ok, stdout, stderr) = common::run(&a);
        assert!(ok, "{stderr}");
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
        (v, stdout)
    };
    let u_g = |v: &serde_json::Value| {
        v["by_rate"][0]["uncertainty_budget"]["sources"]
            .as_array()
            .unwrap()
            .iter()
            .find(|s| s["source"] == "g_loc")
            .unwrap()["std_unc"]
            .as_f64()
            .unwrap()
    };
    let (v, out) = json(&[keyed.to_str().unwrap()]);
    assert_eq!(u_g(&v), 3e-4);
    assert!(!out.contains("WARNING: g_loc"), "{out}");
    let (v, _) = json(&[keyed.to_str().unwrap(), "--u-g-loc", "1e-5"]);
    assert_eq!(u_g(&v), 1e-5, "the flag overrides the file");
    let (v, out) = json(&[plain.to_str().unwrap()]);
    assert_eq!(u_g(&v), 0.0);
    assert!(
        out.contains("WARNING: g_loc's uncertainty was not given"),
        "{out}"
    );
    assert!(out.contains("dominant"), "{out}");
    // A negative one is refused, by flag and by key (the key's line named).
    let (ok, _, err) = common::run(&["calibrate", plain.to_str().unwrap(), "--u-g-loc=-1"]);
    assert!(
        !ok && err.contains("--u-g-loc -1 is not a standard uncertainty"),
        "{err}"
    );
    let bad = dir.join("bad.csv");
    std::fs::write(&bad, text.replacen("# g_loc=", "# u_g_loc=-2\n# g_loc=", 1)).unwrap();
    let (ok, _, err) = common::run(&["calibrate", bad.to_str().unwrap()]);
    assert!(
        !ok && err.contains("bad.csv:") && err.contains("u_g_loc"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn the_table_angle_line_of_a_stepped_budget() {
    // 30° steps, 20 readings a step, no angle errors in the data: the stated u_angle_deg
    // is a type-B line with infinite degrees of freedom and a contribution to every
    // property. (Its U need not exceed the unstated one: stating it changes the weights,
    // and with them the scatter the poses' line reads.)
    let mut cfg = Config::preset("metrologia-static").unwrap();
    cfg.table.angle_step_deg = Some(30.0);
    cfg.table.readings_per_angle = Some(20);
    cfg.sensor.noise = common::unstated(None, None);
    let rec = Simulation::new(cfg).unwrap().recording().unwrap();
    let with = |u: Option<f64>| {
        let opts = Options {
            inputs: TypeB {
                u_angle_deg: u,
                ..TypeB::default()
            },
            ..Options::default()
        };
        calibrate(&rec, &opts).unwrap().by_rate.remove(0)
    };
    let (none, stated) = (with(None), with(Some(0.01)));
    assert!(none
        .uncertainty_budget
        .as_ref()
        .unwrap()
        .source("table_angle")
        .is_none());
    let b = stated.uncertainty_budget.as_ref().unwrap();
    let line = b.source("table_angle").unwrap();
    assert_eq!(line.kind, rotacal::calibrate::budget::Kind::B);
    assert!(line.dof.iter().all(Option::is_none));
    let (qn, qs) = (none.intrinsic.quantities(), stated.intrinsic.quantities());
    for (i, (n, q)) in qn.iter().zip(&qs).enumerate() {
        println!(
            "{}: table_angle {:.3e}, U {:.3e} (none stated: {:.3e})",
            b.quantities[i], line.contribution[i], q.expanded_unc, n.expanded_unc
        );
        assert!(line.contribution[i] > 0.0);
    }
    check_combination(&stated);
}
