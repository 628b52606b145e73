//! How far the current noise model falls short on slow noise (docs/uncertainty.md, "Not
//! yet"): k = 2 coverage and mean z² of the six intrinsic properties over sessions of the
//! `paper-10mhz` preset with 4 counts of white noise plus flicker and/or a bias random walk
//! (docs/simulator.md), the noise never stated.
//!
//!     cargo run --release --example slow_noise_coverage -- FLOOR_UG WALK_UG_PER_SQRT_S SESSIONS
use rotacal::calibrate::{calibrate, Options};
use rotacal::simulate::{Config, Noise, NoiseSd, Simulation};
use std::process::ExitCode;

fn main() -> ExitCode {
    let args: Vec<f64> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let [floor, walk, sessions] = args[..] else {
        eprintln!("usage: slow_noise_coverage FLOOR_UG WALK_UG_PER_SQRT_S SESSIONS");
        return ExitCode::from(2);
    };
    let (mut covered, mut total, mut z2) = (0u32, 0u32, 0.0);
    for t in 0..sessions as u64 {
        let mut cfg = match Config::preset("paper-10mhz") {
            Ok(c) => c,
            Err(e) => {
                eprintln!("{e}");
                return ExitCode::FAILURE;
            }
        };
        cfg.seed = 0xF11C_0000 + t;
        cfg.sensor.noise = Some(Noise {
            sd: Some(NoiseSd::All(4.0)),
            ar: None,
            lowpass_hz: None,
            state: false,
            flicker_floor_ug: Some(NoiseSd::All(floor)),
            random_walk_ug_per_sqrt_s: Some(NoiseSd::All(walk)),
        });
        let run = Simulation::new(cfg)
            .map_err(|e| e.to_string())
            .and_then(|sim| {
                let rec = sim.recording().map_err(|e| e.to_string())?;
                let cal = calibrate(&rec, &Options::default()).map_err(|e| e.to_string())?;
                Ok((sim, cal))
            });
        let (sim, cal) = match run {
            Ok(r) => r,
            Err(e) => {
                eprintln!("session {t}: {e}");
                return ExitCode::FAILURE;
            }
        };
        let truth = sim.truth();
        let values = truth.sensitivity.iter().chain(&truth.angles_deg);
        for rate in &cal.by_rate {
            for (q, tr) in rate.intrinsic.quantities().iter().zip(values.clone()) {
                total += 1;
                z2 += ((q.value - tr) / q.std_unc).powi(2);
                covered += u32::from((q.value - tr).abs() <= q.expanded_unc);
            }
        }
    }
    println!(
        "flicker floor {floor} µg, random walk {walk} µg/√s: k = 2 coverage {:.3}, mean z² {:.2} ({total} intervals)",
        f64::from(covered) / f64::from(total),
        z2 / f64::from(total)
    );
    ExitCode::SUCCESS
}
