//! The discrepancy workflow's detection limits (docs/discrepancy.md): for each effect, the
//! smallest magnitude, on a grid of factors of √2, that it names in at least 90 % of 20
//! seeds, under white noise (key `effects`) and under AR(1) noise of ρ = 0.5 and sd 4
//! counts (key `effects_ar1`), neither stated in the file; and with `--slow-noise` under
//! white noise (`effects_slow_white`), white noise plus flicker at a 50 µg floor
//! (`effects_slow_flicker50`) and white noise plus a 10 µg/√s random walk
//! (`effects_slow_walk10`). Writes bench/discrepancy.json; run by scripts/bench-discrepancy.
//! Arguments (`white`, `ar1`, `slow-white`, `slow-flicker`, `slow-walk`) measure only those
//! and keep the file's other keys.
#![allow(clippy::indexing_slicing)]
use rotacal::discrepancy::model::Effect;
use rotacal::discrepancy::trials::{self, Noise};
use rotacal::discrepancy::Options;
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

/// One measured set: its key in the file, its argument, the noise, and whether the
/// workflow counts slow noise.
const RUNS: [(&str, &str, Noise, bool); 5] = [
    ("effects", "white", Noise::White, false),
    ("effects_ar1", "ar1", Noise::Ar1, false),
    ("effects_slow_white", "slow-white", Noise::White, true),
    (
        "effects_slow_flicker50",
        "slow-flicker",
        Noise::Flicker50,
        true,
    ),
    ("effects_slow_walk10", "slow-walk", Noise::Walk10, true),
];

/// The fraction of seeds in which `e` at `m` is named.
fn named_fraction(noise: Noise, slow: bool, e: Effect, m: f64) -> f64 {
    let opts = Options {
        slow_noise: slow,
        ..Options::default()
    };
    let hits = std::thread::scope(|s| {
        let workers: Vec<_> = (0..2u64)
            .map(|w| {
                s.spawn(move || {
                    (1..=SEEDS)
                        .filter(|seed| seed % 2 == w)
                        .filter(|&seed| {
                            trials::trial_with(noise, &[(e, m)], seed, &opts)
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

/// Every effect's grid and limit under `noise`. With slow noise counted the grid starts 8
/// times higher and runs up to 8 times further, as the limits are larger; where the start
/// is named already, it is halved until it is not.
fn limits(noise: Noise, slow: bool) -> Vec<serde_json::Value> {
    let (from, steps) = if slow { (8.0, 22) } else { (1.0, 16) };
    let mut out = Vec::new();
    for e in Effect::ALL {
        let (_, parameter, unit) = trials::injection(e, 1.0);
        let mut grid = Vec::new();
        let mut limit = None;
        let mut m = start(e) * from;
        // The grid must start where the effect is missed: step down until it is.
        for _ in 0..8 {
            if named_fraction(noise, slow, e, m) < NEEDED {
                break;
            }
            m /= 2.0;
        }
        for _ in 0..steps {
            let f = named_fraction(noise, slow, e, m);
            eprintln!(
                "{}{}: {} {parameter} = {m:.3e} {unit}: named in {:.0} %",
                noise.name(),
                if slow { " (--slow-noise)" } else { "" },
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
    let which: Vec<_> = RUNS
        .into_iter()
        .filter(|(_, arg, _, _)| args.is_empty() || args.iter().any(|a| a == arg))
        .collect();
    let mut doc = std::fs::read_to_string(&path)
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .filter(|d| d.is_object())
        .unwrap_or_else(|| json!({}));
    let mut elapsed = serde_json::Map::new();
    for (key, _, noise, slow) in which {
        let t = std::time::Instant::now();
        let found = limits(noise, slow);
        doc[key] = json!(found);
        doc[format!("{key}_noise")] = json!(noise.toml());
        elapsed.insert(key.to_string(), json!(t.elapsed().as_secs_f64()));
        doc[format!("{key}_elapsed_s")] = json!(t.elapsed().as_secs_f64());
    }
    doc["what"] = json!(
        "smallest magnitude named in >= 90 % of seeds, grid factor sqrt(2); \
         effects: white noise, effects_ar1: AR(1) rho 0.5 sd 4 counts; effects_slow_*: \
         with --slow-noise, white noise alone, plus flicker at a 50 ug floor, plus a \
         10 ug/sqrt(s) random walk; noise_sigma not stated"
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
