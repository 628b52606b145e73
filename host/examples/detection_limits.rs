//! The discrepancy workflow's detection limits (docs/discrepancy.md): for each effect, the
//! smallest magnitude, on a grid of factors of √2, that it names in at least 90 % of 20
//! seeds. Writes bench/discrepancy.json; run by scripts/bench-discrepancy.
use rotacal::discrepancy::model::Effect;
use rotacal::discrepancy::trials;
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
fn named_fraction(e: Effect, m: f64) -> f64 {
    let hits = std::thread::scope(|s| {
        let workers: Vec<_> = (0..2u64)
            .map(|w| {
                s.spawn(move || {
                    (1..=SEEDS)
                        .filter(|seed| seed % 2 == w)
                        .filter(|&seed| {
                            trials::trial(&[(e, m)], seed)
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

fn main() {
    let t0 = std::time::Instant::now();
    let mut out = Vec::new();
    for e in Effect::ALL {
        let (_, parameter, unit) = trials::injection(e, 1.0);
        let mut grid = Vec::new();
        let mut limit = None;
        let mut m = start(e);
        for _ in 0..16 {
            let f = named_fraction(e, m);
            eprintln!(
                "{} {parameter} = {m:.3e} {unit}: named in {:.0} %",
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
    let doc = json!({
        "what": "smallest magnitude named in >= 90 % of seeds, grid factor sqrt(2)",
        "seeds": SEEDS,
        "alpha": rotacal::discrepancy::ALPHA,
        "single_rate_base": trials::SINGLE_RATE,
        "multi_rate_base": trials::MULTI_RATE,
        "effects": out,
        "elapsed_s": t0.elapsed().as_secs_f64(),
    });
    let text = serde_json::to_string_pretty(&doc).unwrap_or_default() + "\n";
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../bench/discrepancy.json");
    if let Err(e) = std::fs::write(&path, text) {
        eprintln!("{}: {e}", path.display());
        std::process::exit(1);
    }
    eprintln!(
        "wrote {} in {:.0} s",
        path.display(),
        t0.elapsed().as_secs_f64()
    );
}
