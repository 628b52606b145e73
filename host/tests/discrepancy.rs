//! The discrepancy workflow on simulated data in which effects are hidden, the workflow
//! not told which (docs/discrepancy.md). The magnitudes are multiples of each effect's
//! detection limit, read from bench/discrepancy.json (scripts/bench-discrepancy).
use rotacal::discrepancy::model::Effect;
use rotacal::discrepancy::{trials, Analysis};
use std::collections::BTreeMap;

fn limits() -> BTreeMap<String, f64> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../bench/discrepancy.json");
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    doc["effects"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| {
            (
                e["effect"].as_str().unwrap().to_string(),
                e["detection_limit"].as_f64().unwrap(),
            )
        })
        .collect()
}

fn limit(e: Effect) -> f64 {
    limits()[e.name()]
}

/// Final χ²/dof within 1 ± 3√(2/dof).
fn chi2_ok(a: &Analysis) -> bool {
    (a.final_.chi2_dof - 1.0).abs() <= 3.0 * (2.0 / a.final_.dof).sqrt()
}

#[test]
fn clean_data_names_nothing_in_at_least_95_percent_of_100_seeds() {
    let mut alarms = Vec::new();
    for seed in 1..=100 {
        let a = trials::trial(&[], seed).unwrap();
        assert!(chi2_ok(&a), "seed {seed}: χ²/dof {}", a.final_.chi2_dof);
        if !a.named_effects.is_empty() {
            alarms.push((seed, a.named_effects.clone()));
        }
    }
    println!(
        "single rate: {} false alarms in 100 seeds: {alarms:?}",
        alarms.len()
    );
    assert!(alarms.len() <= 5, "{alarms:?}");
    // Several rates, where centripetal is tested too.
    let mut alarms = Vec::new();
    for seed in 1..=20 {
        let a = trials::analyse(trials::MULTI_RATE, seed).unwrap();
        if !a.named_effects.is_empty() {
            alarms.push((seed, a.named_effects.clone()));
        }
    }
    println!(
        "two rates: {} false alarms in 20 seeds: {alarms:?}",
        alarms.len()
    );
    assert!(alarms.len() <= 1, "{alarms:?}");
}

/// (|estimate − truth| ≤ 2σ) over the runs, for the coverage check.
fn within_2_sigma(a: &Analysis, e: Effect, truth: f64, tally: &mut (usize, usize)) {
    if let Some((v, u)) = trials::estimate(a, e) {
        tally.1 += 1;
        if (v - truth).abs() <= 2.0 * u {
            tally.0 += 1;
        }
    }
}

#[test]
fn each_effect_at_five_times_its_limit_is_named_alone_in_95_percent_of_seeds() {
    let mut tally = (0, 0);
    for e in Effect::ALL {
        let m = 5.0 * limit(e);
        let mut alone = 0;
        for seed in 1..=20 {
            let a = trials::trial(&[(e, m)], seed).unwrap();
            if a.named_effects == [e.name()] {
                alone += 1;
            }
            assert!(
                chi2_ok(&a),
                "{} seed {seed}: χ²/dof {}",
                e.name(),
                a.final_.chi2_dof
            );
            within_2_sigma(&a, e, m, &mut tally);
        }
        println!("{} at {m:.3e}: named alone in {alone}/20", e.name());
        assert!(alone >= 19, "{}: {alone}/20", e.name());
    }
    println!("estimates within 2σ of the truth: {}/{}", tally.0, tally.1);
    // 95.4 % expected; 90 % is 3 standard deviations below it for ~120 estimates.
    assert!(tally.0 as f64 >= 0.9 * tally.1 as f64, "{tally:?}");
}

#[test]
fn pairs_of_effects_are_both_named() {
    let pairs = [
        (Effect::RateError, Effect::Nonlinearity2nd),
        (Effect::OffsetDrift, Effect::Nonlinearity3rd),
        (Effect::TemperatureOffset, Effect::Saturation),
        (Effect::Centripetal, Effect::Nonlinearity2nd),
    ];
    let mut tally = (0, 0);
    for (e1, e2) in pairs {
        let (m1, m2) = (5.0 * limit(e1), 5.0 * limit(e2));
        for seed in 1..=10 {
            let a = trials::trial(&[(e1, m1), (e2, m2)], seed).unwrap();
            let mut named = a.named_effects.clone();
            named.sort();
            let mut want = vec![e1.name().to_string(), e2.name().to_string()];
            want.sort();
            assert_eq!(named, want, "seed {seed}");
            assert!(
                chi2_ok(&a),
                "{want:?} seed {seed}: χ²/dof {}",
                a.final_.chi2_dof
            );
            within_2_sigma(&a, e1, m1, &mut tally);
            within_2_sigma(&a, e2, m2, &mut tally);
        }
    }
    println!(
        "pairs: estimates within 2σ of the truth: {}/{}",
        tally.0, tally.1
    );
    assert!(tally.0 as f64 >= 0.9 * tally.1 as f64, "{tally:?}");
}

#[test]
fn the_papers_puzzle_centripetal_and_a_second_order_nonlinearity() {
    let toml = "preset = \"paper-multirate\"\n[effects.nonlinearity_2nd]\nk2 = [0.0, 0.0, 2e-4]\n";
    let a = trials::analyse(toml, 2022).unwrap();
    assert_eq!(a.named_effects, ["centripetal", "nonlinearity_2nd"]);
    assert!(chi2_ok(&a), "χ²/dof {}", a.final_.chi2_dof);
    // The paper's analysis: each rate fitted on its own (rotacal calibrate). s_w at
    // 0.5 Hz against 10 mHz, in units of their combined U.
    let mut cfg = rotacal::simulate::Config::from_toml(toml).unwrap();
    cfg.seed = 2022;
    let rec = rotacal::simulate::Simulation::new(cfg)
        .unwrap()
        .recording()
        .unwrap();
    let cal = rotacal::calibrate_recording::calibrate(&rec, &Default::default()).unwrap();
    let sw = |r: usize| cal.by_rate[r].intrinsic.sensitivity.w;
    let (lo, hi) = (sw(0), sw(3));
    let before = (hi.value - lo.value) / lo.expanded_unc.hypot(hi.expanded_unc);
    let f = &a.intrinsic_final;
    let (lo2, hi2) = (&f[0].sensitivity[2], &f[3].sensitivity[2]);
    let after = (hi2.value - lo2.value) / lo2.expanded_unc.hypot(hi2.expanded_unc);
    println!(
        "s_w(0.5 Hz) − s_w(10 mHz): per-rate fits {:+.4} ({before:+.1} U); modelled {:+.4} ({after:+.2} U)",
        hi.value - lo.value,
        hi2.value - lo2.value
    );
    assert!(before.abs() > 5.0, "{before}");
    assert!(after.abs() <= 1.0, "{after}");
    let k2 = &a.final_parameters["nonlinearity_2nd"]["k2"]["w"];
    let (v, u) = (
        k2["value"].as_f64().unwrap(),
        k2["std_unc"].as_f64().unwrap(),
    );
    assert!((v - 2e-4).abs() <= 2.0 * u, "K2_w {v} ± {u}");
    for c in ["x", "y", "z"] {
        let r = &a.final_parameters["centripetal"]["radius_m"][c];
        let (v, u) = (r["value"].as_f64().unwrap(), r["std_unc"].as_f64().unwrap());
        assert!((v - 0.22).abs() <= 2.0 * u, "radius {c}: {v} ± {u}");
    }
}

#[test]
fn the_model_is_the_simulators_physics() {
    // Noise-free, every effect the model has at once (but saturation): the fitted model
    // reproduces the simulator's readings and recovers every parameter.
    use rotacal::discrepancy::model::{fit, Effect};
    let toml = "preset = \"paper-multirate\"\n[table]\nrates_hz = [0.05, 0.5]\n\
        samples_per_condition = 2000\n[sensor]\nnoise_sigma = 0.0\nlsb = 0.0\n\
        [temperature]\nswing_c = 1.0\nperiod_s = 600.0\nresolution_c = 0.0\n\
        [effects.rate_error]\nrelative = 3e-5\n[effects.offset_drift]\nper_s = [0.01, -0.02, 0.005]\n\
        [effects.temperature_offset]\nper_c = [2.0, 0.0, -1.0]\n\
        [effects.nonlinearity_2nd]\nk2 = [1e-4, 0.0, 2e-4]\n[effects.nonlinearity_3rd]\nk3 = [0.0, 1e-5, 0.0]\n";
    let mut cfg = rotacal::simulate::Config::from_toml(toml).unwrap();
    cfg.seed = 4;
    let rec = rotacal::simulate::Simulation::new(cfg)
        .unwrap()
        .recording()
        .unwrap();
    let mut rec = rec;
    rec.meta.noise_sigma = Some(1.0);
    let (data, _) = rotacal::discrepancy::data_from(&rec, &Default::default()).unwrap();
    let all = [
        Effect::RateError,
        Effect::OffsetDrift,
        Effect::TemperatureOffset,
        Effect::Nonlinearity2nd,
        Effect::Nonlinearity3rd,
        Effect::Centripetal,
    ];
    let f = fit(&data, &all, None).unwrap();
    let worst = f
        .residuals
        .iter()
        .flatten()
        .flatten()
        .fold(0.0f64, |m, r| m.max(r.abs()));
    println!("largest |measured − predicted| = {worst:.2e} counts");
    // Samples at k/16 s lie exactly on the 1 µs timestamp grid, so nothing but rounding
    // separates the two (measured: 1e-9 counts).
    assert!(worst < 1e-6, "{worst}");
    let p = &f.params;
    let close = |a: f64, b: f64, tol: f64| assert!((a - b).abs() <= tol, "{a} vs {b}");
    close(p.delta.unwrap(), 3e-5, 1e-9);
    for (got, want) in p.drift.unwrap().iter().zip([0.01, -0.02, 0.005]) {
        close(*got, want, 1e-6);
    }
    for (got, want) in p.temp.unwrap().iter().zip([2.0, 0.0, -1.0]) {
        close(*got, want, 1e-4);
    }
    for (got, want) in p.k2.unwrap().iter().zip([1e-4, 0.0, 2e-4]) {
        close(*got, want, 1e-8);
    }
    for (got, want) in p.k3.unwrap().iter().zip([0.0, 1e-5, 0.0]) {
        close(*got, want, 1e-9);
    }
    let radius = &rotacal::discrepancy::parameters(Effect::Centripetal, &f, &data)["radius_m"];
    for c in ["x", "y", "z"] {
        close(radius[c]["value"].as_f64().unwrap(), 0.22, 1e-4);
    }
}

#[test]
fn the_noise_floor_is_estimated_without_the_model() {
    // No noise_sigma in the file: estimated from second differences of a generic fit's
    // residuals, with effects present that the generic fit doesn't know.
    let toml = format!(
        "{}[effects.rate_error]\nrelative = 1e-4\n[effects.nonlinearity_2nd]\nk2 = [0.0, 0.0, 1e-4]\n",
        trials::SINGLE_RATE
    );
    let mut cfg = rotacal::simulate::Config::from_toml(&toml).unwrap();
    cfg.seed = 9;
    let sim = rotacal::simulate::Simulation::new(cfg).unwrap();
    let truth = sim.noise_floor();
    let mut rec = sim.recording().unwrap();
    rec.meta.noise_sigma = None;
    let (_, noise) = rotacal::discrepancy::data_from(&rec, &Default::default()).unwrap();
    println!(
        "σ estimated {:.4} {:.4} {:.4}, truth {truth:.4} ({})",
        noise.u, noise.v, noise.w, noise.source
    );
    assert!(noise.source.starts_with("estimated: second differences"));
    for s in [noise.u, noise.v, noise.w] {
        // 12 600 second differences: the estimate's relative standard error is ~1 %.
        assert!((s / truth - 1.0).abs() < 0.03, "{s} vs {truth}");
    }
}
