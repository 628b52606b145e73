//! The discrepancy workflow on simulated data in which effects are hidden, the workflow
//! not told which, nor the noise: no file here states `noise_sigma` (white noise is
//! written with `[sensor.noise] state = false`), but for the paper's puzzle, whose
//! statement is checked and not used (docs/discrepancy.md). The magnitudes are multiples
//! of each effect's detection limit under the same noise, read from bench/discrepancy.json
//! (scripts/bench-discrepancy): key `effects` for white noise, `effects_ar1` for AR(1).
use rotacal::discrepancy::model::Effect;
use rotacal::discrepancy::trials::{self, Noise};
use rotacal::discrepancy::{Analysis, Options};
use rotacal_proof::prove;
use rotacal_shared::Channel;
use std::collections::BTreeMap;

fn limits(key: &str) -> BTreeMap<String, f64> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../bench/discrepancy.json");
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    doc[key]
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

/// The white-noise detection limit.
fn limit(e: Effect) -> f64 {
    limits("effects")[e.name()]
}

/// Final χ²/dof within 1 ± 3√(2/ν_eff), ν_eff the whitened residual degrees of freedom
/// (rows × 3 less each group's first p rows per channel and those next to a modelled
/// rail, less the parameters): with the residuals whitened by the noise model, χ² is a
/// sum of ν_eff squared unit innovations.
fn chi2_ok(a: &Analysis) -> bool {
    (a.final_.chi2_dof - 1.0).abs() <= 3.0 * (2.0 / a.final_.dof).sqrt()
}

/// The white clean runs must be told nothing: the noise is estimated.
fn estimated(a: &Analysis) -> bool {
    a.noise_sigma.source.starts_with("estimated: AR(p)") && a.noise_sigma_stated.is_none()
}

#[test]
fn clean_data_names_nothing_in_at_least_95_percent_of_100_seeds() {
    let name = "discrepancy::clean_data_names_nothing_in_at_least_95_percent_of_100_seeds";
    clean_sessions(
        &format!("{name}#one_rate"),
        Noise::White,
        false,
        100,
        false,
        5,
    );
    // Several rates, where centripetal is tested too.
    clean_sessions(
        &format!("{name}#two_rates"),
        Noise::White,
        true,
        20,
        false,
        1,
    );
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
    // White noise: named alone in at least 19 of 20 seeds.
    effects_at_five_times(
        "discrepancy::each_effect_at_five_times_its_limit_is_named_alone_in_95_percent_of_seeds",
        (Noise::White, "effects"),
        (20, 19),
        None,
        &Options::default(),
    );
}

#[test]
fn pairs_of_effects_are_both_named() {
    const SEEDS: usize = 10;
    let pairs = [
        (Effect::RateError, Effect::Nonlinearity2nd),
        (Effect::OffsetDrift, Effect::Nonlinearity3rd),
        (Effect::TemperatureOffset, Effect::Saturation),
        (Effect::Centripetal, Effect::Nonlinearity2nd),
    ];
    let trial = |t: usize| {
        let (e1, e2) = pairs[t / SEEDS];
        let seed = (t % SEEDS) as u64 + 1;
        trials::trial(&[(e1, 5.0 * limit(e1)), (e2, 5.0 * limit(e2))], seed).unwrap()
    };
    prove(
        "discrepancy::pairs_of_effects_are_both_named",
        pairs.len() * SEEDS,
        trial,
        |runs| {
            let mut failures = Vec::new();
            let mut tally = (0, 0);
            for ((e1, e2), runs) in pairs.into_iter().zip(runs.chunks(SEEDS)) {
                let (m1, m2) = (5.0 * limit(e1), 5.0 * limit(e2));
                let mut want = vec![e1.name().to_string(), e2.name().to_string()];
                want.sort();
                for (i, a) in runs.iter().enumerate() {
                    let mut named = a.named_effects.clone();
                    named.sort();
                    if named != want || !chi2_ok(a) {
                        failures.push(format!(
                            "{want:?} seed {}: named {named:?}, χ²/dof {}",
                            i + 1,
                            a.final_.chi2_dof
                        ));
                    }
                    within_2_sigma(a, e1, m1, &mut tally);
                    within_2_sigma(a, e2, m2, &mut tally);
                }
            }
            println!(
                "pairs: estimates within 2σ of the truth: {}/{}",
                tally.0, tally.1
            );
            if (tally.0 as f64) < 0.9 * tally.1 as f64 {
                failures.push(format!("estimates within 2σ: {tally:?}"));
            }
            failures
        },
    );
}

/// Readings of channel u left out of its noise estimate (on a rail), over all groups.
fn u_left_out(a: &rotacal::discrepancy::Analysis) -> usize {
    a.noise_model
        .iter()
        .filter(|m| m.channel == Channel::U)
        .map(|m| m.n_excluded)
        .sum()
}

#[test]
fn the_papers_puzzle_centripetal_and_a_second_order_nonlinearity() {
    let toml = rotacal::demo::PUZZLE;
    let a = trials::analyse(toml, 2022).unwrap();
    // The file states no noise level: the workflow estimated it.
    assert!(a.noise_sigma_stated.is_none());
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
    let cal = rotacal::calibrate::calibrate(&rec, &Default::default()).unwrap();
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
    // Noise-free: whatever the generic fit leaves is deterministic, so the fit is weighted
    // as white noise of 1 count.
    let (mut data, _) = rotacal::discrepancy::data_from(&rec, &Default::default()).unwrap();
    data.set_white([1.0; 3]);
    let all = [
        Effect::RateError,
        Effect::OffsetDrift,
        Effect::TemperatureOffset,
        Effect::Nonlinearity2nd,
        Effect::Nonlinearity3rd,
        Effect::Centripetal,
    ];
    let f = fit(&data, &all, None).unwrap();
    let worst = (0..data.groups.len())
        .flat_map(|gi| Channel::ALL.map(|ch| f.residuals(&data, gi, ch)))
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
    let radius =
        &rotacal::discrepancy::parameters(Effect::Centripetal, &f, &data, None)["radius_m"];
    for c in ["x", "y", "z"] {
        close(radius[c]["value"].as_f64().unwrap(), 0.22, 1e-4);
    }
}

/// The noise model of `toml` (with a rate error and K2 the generic fit does not know),
/// against the simulator's truth: each channel's pooled variance within 4 standard errors
/// (√(2·Σρ_k²/N) relative), each group's lag-1 autocorrelation within 4 Bartlett standard
/// errors (√((1 − ρ²)/n)). `extra` is added to the configuration. Returns the analysis.
fn noise_model_matches(noise: Noise, rho: f64, seed: u64, extra: &str) -> Analysis {
    let toml = format!(
        "{}[effects.rate_error]\nrelative = 1e-4\n[effects.nonlinearity_2nd]\nk2 = [0.0, 0.0, 1e-4]\n{}{extra}",
        trials::SINGLE_RATE,
        noise.toml()
    );
    let mut cfg = rotacal::simulate::Config::from_toml(&toml).unwrap();
    cfg.seed = seed;
    let sim = rotacal::simulate::Simulation::new(cfg).unwrap();
    let sd = sim.truth().noise_sd;
    let rec = sim.recording().unwrap();
    assert_eq!(
        rec.meta.noise_sigma, None,
        "the file must not state the noise"
    );
    let a = rotacal::discrepancy::run(&rec, &Default::default()).unwrap();
    assert!(estimated(&a));
    let est = [a.noise_sigma.u, a.noise_sigma.v, a.noise_sigma.w];
    // Quantisation (1 count) adds 1/12 count² of white noise, lowering lag 1 a little.
    let q = 1.0 / 12.0;
    for j in 0..3 {
        let var = sd[j].powi(2) + q;
        let rho1 = rho * sd[j].powi(2) / var;
        let sum_rho2 = (1.0 + rho1 * rho1) / (1.0 - rho1 * rho1);
        let n = a.data.rows() as f64;
        let bound = 4.0 * (2.0 * sum_rho2 / n).sqrt();
        let ratio = est[j].powi(2) / var;
        println!(
            "{} channel {j}: sd {:.4} (truth {:.4}), variance ratio {ratio:.4} (bound 1 ± {bound:.4})",
            noise.name(),
            est[j],
            var.sqrt()
        );
        assert!((ratio - 1.0).abs() <= bound, "channel {j}: {ratio}");
        for m in a
            .noise_model
            .iter()
            .filter(|m| m.channel == Channel::ALL[j])
        {
            let r1 = m.lag1_autocorrelation;
            let se = ((1.0 - rho1 * rho1) / m.n as f64).sqrt();
            assert!(
                (r1 - rho1).abs() <= 4.0 * se,
                "{} {}: lag-1 {r1} against {rho1} ± {se}",
                m.condition.letter(),
                m.channel.letter()
            );
        }
    }
    a
}

#[test]
fn the_noise_model_is_estimated_without_the_model() {
    // No noise_sigma in the file, effects present that the generic fit doesn't know, so a
    // missing effect must not read as noise. Before (second differences of the generic
    // fit's residuals), AR(1) noise of sd 4 read as 2.3 counts.
    let a = noise_model_matches(Noise::White, 0.0, 9, "");
    assert!(
        a.noise_model.iter().all(|m| m.ar.is_empty()),
        "white taken as AR(0)"
    );
    let a = noise_model_matches(Noise::Ar1, 0.5, 9, "");
    assert!(
        a.noise_model.iter().all(|m| !m.ar.is_empty()),
        "AR(1) found"
    );
    // u's peaks clipped: its readings at the rail are left out, and its level holds.
    let clip = trials::injection(Effect::Saturation, CLIP_DEPTH).0;
    let a = noise_model_matches(Noise::Levels345, 0.0, 9, &clip);
    let out = u_left_out(&a);
    println!(
        "levels 3, 4, 5, u clipped: {out} readings of u left out; named {:?}, χ²/dof {:.4}",
        a.named_effects, a.final_.chi2_dof
    );
    assert!(out > 0);
    assert!(chi2_ok(&a), "χ²/dof {}", a.final_.chi2_dof);
}

/// The single-rate base under `noise`, simulated with `seed`.
fn single_rate_recording(noise: Noise, seed: u64) -> rotacal::recording::Recording {
    let toml = format!("{}{}", trials::SINGLE_RATE, noise.toml());
    let mut cfg = rotacal::simulate::Config::from_toml(&toml).unwrap();
    cfg.seed = seed;
    rotacal::simulate::Simulation::new(cfg)
        .unwrap()
        .recording()
        .unwrap()
}

#[test]
fn a_stated_noise_sigma_is_checked_and_never_used() {
    // The AR(1) recording with a (false) white-noise statement of its level: the data
    // contradict it, and the analysis is exactly the one without it.
    let mut rec = single_rate_recording(Noise::Ar1, 3);
    let without = rotacal::discrepancy::run(&rec, &Default::default()).unwrap();
    rec.meta.noise_sigma = Some(4.0);
    let with = rotacal::discrepancy::run(&rec, &Default::default()).unwrap();
    let s = with.noise_sigma_stated.as_ref().unwrap();
    println!("stated 4.0 on AR(1) noise: {}", s.why);
    assert!(s.contradicted && s.why.contains("correlated"), "{s:?}");
    assert_eq!(with.final_, without.final_);
    assert_eq!(with.noise_sigma, without.noise_sigma);
    // A wrong level on white noise is caught too.
    let mut rec = single_rate_recording(Noise::White, 3);
    rec.meta.noise_sigma = Some(3.0);
    let a = rotacal::discrepancy::run(&rec, &Default::default()).unwrap();
    let s = a.noise_sigma_stated.as_ref().unwrap();
    println!("stated 3.0 on white noise of 4.17: {}", s.why);
    assert!(s.contradicted && s.why.contains("variance"), "{s:?}");
}

/// The rail of the clipped-channel sessions: `CLIP_DEPTH` counts below u's peak reading,
/// which clips u's peaks in the two conditions where u sees ±g.
const CLIP_DEPTH: f64 = 15.0;

/// The runs (by seed, from 1) that name anything but `want`, with what they name.
fn alarms(runs: &[Analysis], want: &[String]) -> Vec<(usize, Vec<String>)> {
    runs.iter()
        .enumerate()
        .filter(|(_, a)| a.named_effects != want)
        .map(|(i, a)| (i + 1, a.named_effects.clone()))
        .collect()
}

/// The runs (seed, what) whose verdict is "unexplained", with the verdict's first place.
fn unexplained(runs: &[Analysis]) -> Vec<(usize, String)> {
    runs.iter()
        .enumerate()
        .filter(|(_, a)| !a.verdict.explained)
        .map(|(i, a)| (i + 1, a.verdict.summary.clone()))
        .collect()
}

/// The least and the greatest final χ²/dof of `runs`.
fn chi2_range(runs: &[Analysis]) -> (f64, f64) {
    runs.iter()
        .map(|a| a.final_.chi2_dof)
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
            (lo.min(x), hi.max(x))
        })
}

/// Clean sessions under `noise` (`clip`: with u's peaks clipped, so saturation, and only
/// it, is to be named), the proof `name`: the runs that name anything else, or miss the
/// clip, are alarms, and at most `bound` may. Each run's χ²/dof must lie in its band.
fn clean_sessions(name: &str, noise: Noise, multi: bool, seeds: u64, clip: bool, bound: usize) {
    let want: Vec<String> = if clip {
        vec!["saturation".to_string()]
    } else {
        Vec::new()
    };
    let trial = |t: usize| {
        let seed = t as u64 + 1;
        let a = if multi {
            let toml = format!("{}{}", trials::MULTI_RATE, noise.toml());
            trials::analyse(&toml, seed).unwrap()
        } else if clip {
            trials::trial_in(noise, &[(Effect::Saturation, CLIP_DEPTH)], seed).unwrap()
        } else {
            trials::trial_in(noise, &[], seed).unwrap()
        };
        assert!(estimated(&a));
        if clip {
            // The clipped readings are left out of u's noise estimate.
            assert!(
                u_left_out(&a) > 0,
                "seed {seed}: no clipped reading left out"
            );
        }
        a
    };
    prove(name, seeds as usize, trial, |runs| {
        let mut failures: Vec<String> = runs
            .iter()
            .enumerate()
            .filter(|(_, a)| !chi2_ok(a))
            .map(|(i, a)| {
                format!(
                    "{} seed {}: χ²/dof {} (ν_eff {})",
                    noise.name(),
                    i + 1,
                    a.final_.chi2_dof,
                    a.final_.dof
                )
            })
            .collect();
        let alarms = alarms(runs, &want);
        let unexplained = unexplained(runs);
        let (lo, hi) = chi2_range(runs);
        let dof = runs.last().map_or(0.0, |a| a.final_.dof);
        println!(
            "{}{}{}: {} alarms in {seeds} seeds {alarms:?}; {} unexplained {unexplained:?}; \
             final χ²/dof {lo:.4} … {hi:.4} (band 1 ± {:.4})",
            noise.name(),
            if multi { ", two rates" } else { "" },
            if clip { ", u clipped" } else { "" },
            alarms.len(),
            unexplained.len(),
            3.0 * (2.0 / dof).sqrt()
        );
        if alarms.len() > bound {
            failures.push(format!(
                "{} alarms, at most {bound}: {alarms:?}",
                alarms.len()
            ));
        }
        // The verdict "explained" in at least 95 %: the same bound (its tests are at
        // α = 1e-3 each, a handful a session).
        if unexplained.len() > bound {
            failures.push(format!(
                "{} unexplained, at most {bound}: {unexplained:?}",
                unexplained.len()
            ));
        }
        failures
    });
}

// The false-alarm bound. Each step tests at most seven effects at α = 1e-3, so a clean
// session names something with probability at most about 0.7 % (Bonferroni). Over 100
// seeds the count of alarms is binomial: with p = 0.007, P(X ≥ 6) ≈ 1e-5, so 5 alarms
// (the 95 % the workflow promises) is a bound a correct workflow does not reach by chance,
// while a workflow alarming in 10 % of sessions exceeds it with probability 0.94.

#[test]
fn ar1_noise_clean_sessions_name_nothing_in_at_least_95_percent() {
    let name = "discrepancy::ar1_noise_clean_sessions_name_nothing_in_at_least_95_percent";
    clean_sessions(
        &format!("{name}#one_rate"),
        Noise::Ar1,
        false,
        100,
        false,
        5,
    );
    // Two rates (centripetal tested too): 20 seeds, at most 1 (P(X ≥ 2) ≈ 0.8 % at 0.7 %).
    clean_sessions(&format!("{name}#two_rates"), Noise::Ar1, true, 20, false, 1);
}

#[test]
fn levels_3_4_5_with_a_clipped_channel_name_only_the_clipping() {
    // White, 3, 4 and 5 counts on u, v, w, no noise_sigma, u's peaks clipped 15 counts
    // below their top (a plain clip, 15 times saturation's white limit; saturation at 5
    // times its limit is proven with the other effects): saturation named, and nothing
    // else, in at least 95 of 100 seeds; the clipped readings left out of the noise
    // estimate (its level checked in the_noise_model_is_estimated_without_the_model).
    clean_sessions(
        "discrepancy::levels_3_4_5_with_a_clipped_channel_name_only_the_clipping",
        Noise::Levels345,
        false,
        100,
        true,
        5,
    );
}

/// Each effect at 5 times its limit under `noise` (limits from `key`), `seeds` seeds,
/// with `extra` hidden too: named (with `extra`) and nothing else in at least `least` of
/// them. With
/// `--slow-noise` in `opts`, χ²/dof is not checked (the AR whitening leaves the slow noise
/// in) and the injected parameter must lie within its U (k from its degrees of freedom) in
/// 95.45 % of the runs, within the binomial 99.9 % band either way.
/// The proof `name`.
fn effects_at_five_times(
    name: &str,
    (noise, key): (Noise, &str),
    (seeds, least): (u64, usize),
    extra: Option<(Effect, f64)>,
    opts: &Options,
) {
    let slow = opts.slow_noise;
    let label = format!(
        "{}{}",
        noise.name(),
        if slow { " with --slow-noise" } else { "" }
    );
    let limits = limits(key);
    // Each effect tested, its size, the effects hidden and the names wanted.
    type Case = (Effect, f64, Vec<(Effect, f64)>, Vec<String>);
    let cases: Vec<Case> = Effect::ALL
        .into_iter()
        .filter(|e| extra.is_none_or(|(x, _)| x != *e))
        .map(|e| {
            // The clip's rail is set against u's peak in the single-rate base.
            let extra = extra.filter(|_| e != Effect::Centripetal);
            let m = 5.0 * limits[e.name()];
            let mut want = vec![e.name().to_string()];
            let mut effects = vec![(e, m)];
            if let Some((x, mx)) = extra {
                want.push(x.name().to_string());
                effects.push((x, mx));
            }
            want.sort();
            (e, m, effects, want)
        })
        .collect();
    let per = seeds as usize;
    let trial = |t: usize| {
        let (_, _, effects, _) = &cases[t / per];
        let seed = (t % per) as u64 + 1;
        let a = trials::trial_with(noise, effects, seed, opts).unwrap();
        assert!(estimated(&a));
        a
    };
    prove(name, cases.len() * per, trial, |runs| {
        let mut failures = Vec::new();
        let mut tally = (0, 0);
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for ((e, m, effects, want), runs) in cases.iter().zip(runs.chunks(per)) {
            let mut alone = 0;
            for (i, a) in runs.iter().enumerate() {
                let mut named = a.named_effects.clone();
                named.sort();
                let mut confirmed = a.confirmed_effects.clone();
                confirmed.sort();
                // Named alone, confirmed on the halves, and the verdict "explained".
                if named == *want && confirmed == *want && a.verdict.explained {
                    alone += 1;
                }
                lo = lo.min(a.final_.chi2_dof);
                hi = hi.max(a.final_.chi2_dof);
                if slow {
                    if let Some((v, u)) = trials::estimate_with(a, *e, "expanded_unc") {
                        tally.1 += 1;
                        tally.0 += usize::from((v - m).abs() <= u);
                    }
                } else {
                    if !chi2_ok(a) {
                        failures.push(format!(
                            "{label} {} seed {}: χ²/dof {} (ν_eff {})",
                            e.name(),
                            i + 1,
                            a.final_.chi2_dof,
                            a.final_.dof
                        ));
                    }
                    within_2_sigma(a, *e, *m, &mut tally);
                }
            }
            println!(
                "{label}: {} at {m:.3e}: named{}, confirmed and explained in {alone}/{seeds}",
                e.name(),
                if effects.len() > 1 {
                    " with the clip"
                } else {
                    " alone"
                }
            );
            if alone < least {
                failures.push(format!("{}: {alone}/{seeds}", e.name()));
            }
        }
        println!(
            "{label}: estimates within {} of the truth: {}/{}; final χ²/dof {lo:.4} … {hi:.4}",
            if slow { "U" } else { "2σ" },
            tally.0,
            tally.1
        );
        let (hits, n) = (tally.0 as f64, tally.1 as f64);
        if slow {
            // Within U (k from ν): 95.45 % expected, two-sided, 3.29 binomial standard
            // deviations either way (99.9 %): with 600 estimates [0.927, 0.982].
            let p = 0.9545;
            let half = 3.29 * (p * (1.0 - p) / n).sqrt();
            if !(n > 0.0 && (hits / n - p).abs() <= half) {
                failures.push(format!(
                    "estimates within U: {tally:?}, outside {:.3} … {:.3}",
                    p - half,
                    p + half
                ));
            }
        } else if hits < 0.9 * n {
            // 95.4 % expected; 90 % is ≥ 3 standard deviations below it for ≥ 100 estimates.
            failures.push(format!("estimates within bounds: {tally:?}"));
        }
        failures
    });
}

// Named in at least 90 % of 20 seeds: at 5 times the limit an effect is named in nearly
// every seed (white: 20/20 for all seven), and a workflow that named it alone in only
// 80 % would pass with probability 0.21; one at 99 % fails with probability 1.7e-5.

#[test]
fn ar1_noise_each_effect_at_five_times_its_limit_is_named_alone() {
    effects_at_five_times(
        "discrepancy::ar1_noise_each_effect_at_five_times_its_limit_is_named_alone",
        (Noise::Ar1, "effects_ar1"),
        (20, 18),
        None,
        &Options::default(),
    );
}

#[test]
fn levels_3_4_5_each_effect_at_five_times_its_limit_is_named_with_the_clip() {
    effects_at_five_times(
        "discrepancy::levels_3_4_5_each_effect_at_five_times_its_limit_is_named_with_the_clip",
        (Noise::Levels345, "effects"),
        (10, 9),
        Some((Effect::Saturation, CLIP_DEPTH)),
        &Options::default(),
    );
}

// Slow noise (`--slow-noise`, docs/discrepancy.md "Slow noise"): flicker at a 50 µg floor
// and a 10 µg/√s bias random walk, each on the base's white noise, never stated. The
// workflow is told only to count slow noise, not its kind or level.

/// `--slow-noise`.
fn slow() -> Options {
    Options {
        slow_noise: true,
        ..Options::default()
    }
}

/// Clean single-rate sessions under `noise` with `--slow-noise`, the proof `name`: at most
/// 5 of `seeds` name anything (the bound below). Prints the χ²/dof range.
fn slow_clean_sessions(name: &str, noise: Noise, seeds: u64) {
    let trial = |t: usize| {
        let a = trials::trial_with(noise, &[], t as u64 + 1, &slow()).unwrap();
        assert!(estimated(&a));
        assert_eq!(a.slow_noise.as_ref().map(Vec::len), Some(3));
        // Every test but saturation's (no estimated parameter) counts the slow noise.
        let first = a
            .steps
            .first()
            .map_or(&a.last_candidates, |s| &s.candidates);
        for c in first.iter().filter(|c| c.effect != "saturation") {
            assert_eq!(c.test, "Wald test with slow noise");
            assert!(c.slow_share.is_some_and(|s| s > 0.0 && s < 1.0), "{c:?}");
        }
        a
    };
    prove(name, seeds as usize, trial, |runs| {
        let alarms = alarms(runs, &[]);
        let unexplained = unexplained(runs);
        let (lo, hi) = chi2_range(runs);
        println!(
            "{} with --slow-noise: {} alarms in {seeds} seeds {alarms:?}; {} unexplained \
             {unexplained:?}; final χ²/dof {lo:.4} … {hi:.4}",
            noise.name(),
            alarms.len(),
            unexplained.len()
        );
        let mut failures = Vec::new();
        if alarms.len() > 5 {
            failures.push(format!("{}: {alarms:?}", noise.name()));
        }
        // The verdict "explained" in at least 95 %.
        if unexplained.len() > 5 {
            failures.push(format!("{} unexplained: {unexplained:?}", noise.name()));
        }
        failures
    });
}

// The bound: each test's size is at most α + 10⁻³ (the slow variance's upper bound falls
// short with probability about 10⁻³), so with at most seven tests a step a clean session
// names something with probability at most about 1.4 %; over 100 seeds P(X ≥ 6) ≈ 3e-3
// at that worst case, while a workflow alarming in 10 % of sessions exceeds 5 with
// probability 0.94.

#[test]
fn slow_noise_clean_sessions_name_nothing_in_at_least_95_percent() {
    // Without the option the same sessions name effects (measured: 10 of 10 with flicker).
    let named = (1..=4)
        .filter(|&seed| {
            let a = trials::trial_in(Noise::Flicker50, &[], seed).unwrap();
            !a.named_effects.is_empty()
        })
        .count();
    assert!(
        named >= 3,
        "{named} of 4 flicker sessions name an effect without the option"
    );
    let name = "discrepancy::slow_noise_clean_sessions_name_nothing_in_at_least_95_percent";
    slow_clean_sessions(&format!("{name}#flicker_50ug"), Noise::Flicker50, 100);
    slow_clean_sessions(&format!("{name}#walk_10ug"), Noise::Walk10, 100);
}

// Named alone in at least 95 of 100 seeds, the proof point's 95 %: at 5 times the limit an
// effect is named in nearly every seed; one named in 99 % fails with probability 5e-4 (98 %:
// 0.016), one named in 90 % passes with probability 0.058 (85 %: 0.0016).

#[test]
fn slow_noise_flicker_each_effect_at_five_times_its_limit_is_named_alone() {
    effects_at_five_times(
        "discrepancy::slow_noise_flicker_each_effect_at_five_times_its_limit_is_named_alone",
        (Noise::Flicker50, "effects_slow_flicker50"),
        (100, 95),
        None,
        &slow(),
    );
}

#[test]
fn slow_noise_walk_each_effect_at_five_times_its_limit_is_named_alone() {
    effects_at_five_times(
        "discrepancy::slow_noise_walk_each_effect_at_five_times_its_limit_is_named_alone",
        (Noise::Walk10, "effects_slow_walk10"),
        (100, 95),
        None,
        &slow(),
    );
}

#[test]
fn slow_noise_estimates_every_channel_at_a_100_ug_floor() {
    // At a 100 µg floor the AR model can read the flicker as correlation so long that few
    // averaging lengths remain beyond it: this session's channel v was refused until the
    // shortest length used was capped at the fourth-longest (32 of 100 sessions refused
    // before). Now every channel has its levels, each with a standard uncertainty of at
    // least a tenth of its size or of the flicker's (a walk read as a large negative level
    // once came out with u 10⁴ times below it).
    let toml = format!(
        "{}[sensor.noise]\nstate = false\nflicker_floor_ug = 100.0\n",
        trials::SINGLE_RATE
    );
    let a = trials::analyse_with(&toml, 12, &slow()).unwrap();
    let levels = a.slow_noise.as_ref().unwrap();
    assert_eq!(levels.len(), 3);
    for l in levels {
        let (f, w) = (&l.flicker_allan_variance, &l.random_walk_k2);
        assert!(f.value > 0.0 && f.u > 0.1 * f.value.abs(), "{l:?}");
        assert!(w.u > 0.1 * w.value.abs(), "{l:?}");
    }
}
