//! The discrepancy workflow's detection limits (docs/discrepancy.md): for each effect, the
//! smallest magnitude, on a grid of factors of √2, that it names in at least 90 % of 20
//! seeds, under white noise (key `effects`) and under AR(1) noise of ρ = 0.5 and sd 4
//! counts (key `effects_ar1`), neither stated in the file. Writes bench/discrepancy.json;
//! run by scripts/bench-discrepancy. Arguments `white` and/or `ar1` measure only those and
//! keep the file's other keys.
#![allow(clippy::indexing_slicing)]
use rotacal::discrepancy::model::Effect;
use rotacal::discrepancy::trials::{self, Noise};
use serde_json::json;

const SEEDS: u64 = 20;
const NEEDED: f64 = 0.9;

/// Where each effect's grid starts (below its limit).
fn start(e: Effect) -> f64 {
    match e {
        Effect::RateError => 2.5e-7,
        Effect::OffsetDrift => 2.5e-4,
        Effect::TemperatureOffset => 0.03,
        Effect::Nonlinearity2nd => 5e-7,
        Effect::Nonlinearity3rd => 1e-7,
        Effect::Saturation => 0.5,
        Effect::Centripetal => 1e-6,
    }
}

/// The fraction of seeds in which `e` at `m` is named.
fn named_fraction(noise: Noise, e: Effect, m: f64) -> f64 {
    let hits = std::thread::scope(|s| {
        let workers: Vec<_> = (0..2u64)
            .map(|w| {
                s.spawn(move || {
                    (1..=SEEDS)
                        .filter(|seed| seed % 2 == w)
                        .filter(|&seed| {
                            trials::trial_in(noise, &[(e, m)], seed)
                                .map(|a| a.named_effects.iter().any(|n| n == e.name()))
                                .unwrap_or(false)
                        })
                        .count()
                })
            })
            .collect();
        workers
            .into_iter()
            .map(|h| h.join().unwrap_or(0))
            .sum::<usize>()
    });
    hits as f64 / SEEDS as f64
}

/// Every effect's grid and limit under `noise`.
fn limits(noise: Noise) -> Vec<serde_json::Value> {
    let mut out = Vec::new();
    for e in Effect::ALL {
        let (_, parameter, unit) = trials::injection(e, 1.0);
        let mut grid = Vec::new();
        let mut limit = None;
        let mut m = start(e);
        for _ in 0..16 {
            let f = named_fraction(noise, e, m);
            eprintln!(
                "{}: {} {parameter} = {m:.3e} {unit}: named in {:.0} %",
                noise.name(),
                e.name(),
                f * 100.0
            );
            grid.push(json!({"magnitude": m, "named_fraction": f}));
            if f >= NEEDED {
                limit = Some(m);
                break;
            }
            m *= std::f64::consts::SQRT_2;
        }
        out.push(json!({
            "effect": e.name(),
            "parameter": parameter,
            "unit": unit,
            "detection_limit": limit,
            "grid": grid,
        }));
    }
    out
}

fn main() {
    let t0 = std::time::Instant::now();
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../bench/discrepancy.json");
    let args: Vec<String> = std::env::args().skip(1).collect();
    let which: Vec<(Noise, &str)> = [(Noise::White, "effects"), (Noise::Ar1, "effects_ar1")]
        .into_iter()
        .filter(|(n, _)| {
            args.is_empty()
                || args.iter().any(|a| {
                    (a == "white" && *n == Noise::White) || (a == "ar1" && *n == Noise::Ar1)
                })
        })
        .collect();
    let mut doc = std::fs::read_to_string(&path)
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .filter(|d| d.is_object())
        .unwrap_or_else(|| json!({}));
    let mut elapsed = serde_json::Map::new();
    for (noise, key) in which {
        let t = std::time::Instant::now();
        let found = limits(noise);
        doc[key] = json!(found);
        doc[format!("{key}_noise")] = json!(noise.toml());
        elapsed.insert(key.to_string(), json!(t.elapsed().as_secs_f64()));
        doc[format!("{key}_elapsed_s")] = json!(t.elapsed().as_secs_f64());
    }
    doc["what"] = json!(
        "smallest magnitude named in >= 90 % of seeds, grid factor sqrt(2); \
         effects: white noise, effects_ar1: AR(1) rho 0.5 sd 4 counts; noise_sigma not stated"
    );
    doc["seeds"] = json!(SEEDS);
    doc["alpha"] = json!(rotacal::discrepancy::ALPHA);
    doc["single_rate_base"] = json!(trials::SINGLE_RATE);
    doc["multi_rate_base"] = json!(trials::MULTI_RATE);
    doc["elapsed_s"] = json!(t0.elapsed().as_secs_f64());
    let text = serde_json::to_string_pretty(&doc).unwrap_or_default() + "\n";
    if let Err(e) = std::fs::write(&path, text) {
        eprintln!("{}: {e}", path.display());
        std::process::exit(1);
    }
    eprintln!(
        "wrote {} in {:.0} s ({elapsed:?})",
        path.display(),
        t0.elapsed().as_secs_f64()
    );
}
