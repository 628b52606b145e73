//! Coverage of the intrinsic properties on slow noise (docs/uncertainty.md, "Slow
//! noise"): two-sided coverage of U and the mean of (1.96·z/k)² over sessions of the
//! `paper-10mhz` preset (or the rate given) with 4 counts of white noise, AR(1) noise of
//! coefficient RHO if given, plus flicker and/or a bias random walk (docs/simulator.md),
//! the noise never stated. With `--stepped`, the same device turned in 30° steps
//! instead, 20 readings a step at its 16 Hz, 30 s from step to step (the nine properties;
//! RATE is then ignored), calibrated as they come; `--step DEG` steps by DEG instead (90:
//! twelve static poses, each axis up and down twice). With `--free POSES`, the same device
//! put down by hand in POSES unknown orientations at 104 Hz (still 3 s, turned in 1.5 s,
//! each pose's noise ×1.5 either way, a 0.5 m/s² ring-down; `--tremor MS2` adds a hand's
//! 10 Hz tremor of MS2 RMS per axis), calibrated by the free method. (1.96·z/k)² has mean
//! ≈ 1 (within 3 % for any ν ≥ 5) when z follows Student's t with the ν that gave k; its
//! band is χ²-based.
//!
//!     cargo run --release --example slow_noise_coverage -- [--stepped [--step DEG] | --free POSES [--tremor MS2]] FLOOR_UG WALK_UG_PER_SQRT_S SESSIONS [RHO] [RATE_HZ]
//!
//! `--without-slow-noise` calibrates without the option. Stepped offsets are compared with
//! the bias plus the slow noise's mean over the record's readings, which is what they
//! measure (docs/uncertainty.md, "Slow noise between poses").
//! `--still S` (rotation) also simulates a still recording of S seconds of the same noise
//! (its own seed; the device put down once, at the session's rate) and pools it into the
//! slow levels, as `calibrate --noise-from FILE` does.
//!
//! Prints one JSON line: overall (and how many sessions warned of drift between poses,
//! and the coverage of those that did not; how many had a channel's noise terms widened or
//! narrowed by the model check), then per property (s_u, s_v, s_w, φ_uv, φ_vw, φ_wu, and
//! for stepped sessions O_u, O_v, O_w) its coverage, mean scaled z² and mean k.
use rotacal::calibrate::noise_from::NoiseFrom;
use rotacal::calibrate::{calibrate, CalibrateErrorKind, Options};
use rotacal::recording::{read_bytes, Method};
use rotacal::simulate::config::FreePoses;
use rotacal::simulate::{Config, Noise, NoiseSd, Simulation};
use std::process::ExitCode;
use std::sync::Arc;

fn main() -> ExitCode {
    let all: Vec<String> = std::env::args().skip(1).collect();
    let stepped = all.iter().any(|a| a == "--stepped");
    // Rotation and free calibrate with `--slow-noise` unless told not to.
    let slow = !all.iter().any(|a| a == "--without-slow-noise");
    let free: Option<usize> = all
        .iter()
        .position(|a| a == "--free")
        .and_then(|i| all.get(i + 1))
        .and_then(|n| n.parse().ok());
    let still_s: Option<f64> = all
        .iter()
        .position(|a| a == "--still")
        .and_then(|i| all.get(i + 1))
        .and_then(|n| n.parse().ok());
    let step_deg: Option<f64> = all
        .iter()
        .position(|a| a == "--step")
        .and_then(|i| all.get(i + 1))
        .and_then(|n| n.parse().ok());
    let tremor: Option<f64> = all
        .iter()
        .position(|a| a == "--tremor")
        .and_then(|i| all.get(i + 1))
        .and_then(|n| n.parse().ok());
    let args: Vec<f64> = all
        .iter()
        .filter(|a| !a.starts_with("--"))
        .skip(
            usize::from(free.is_some())
                + usize::from(still_s.is_some())
                + usize::from(step_deg.is_some())
                + usize::from(tremor.is_some()),
        )
        .filter_map(|a| a.parse().ok())
        .collect();
    let (floor, walk, sessions, rho, rate) = match args[..] {
        [f, w, s] => (f, w, s, 0.0, 0.01),
        [f, w, s, r] => (f, w, s, r, 0.01),
        [f, w, s, r, hz] => (f, w, s, r, hz),
        _ => {
            eprintln!(
                "usage: slow_noise_coverage [--stepped | --free POSES] FLOOR_UG WALK_UG_PER_SQRT_S SESSIONS [RHO] [RATE_HZ]"
            );
            return ExitCode::from(2);
        }
    };
    let (mut covered, mut total, mut z2) = (0u32, 0u32, 0.0);
    let (mut sessions_warned, mut quiet) = (0u32, (0u32, 0u32));
    let mut rescaled = (0u32, 0u32);
    let mut refused = 0u32;
    let mut per = [(0u32, 0.0f64, 0.0f64, 0.0f64); 9];
    for t in 0..sessions as u64 {
        let mut cfg = match Config::preset("paper-10mhz") {
            Ok(c) => c,
            Err(e) => {
                eprintln!("{e}");
                return ExitCode::FAILURE;
            }
        };
        cfg.seed = 0xF11C_0000 + t;
        if let Some(count) = free {
            cfg.method = Method::Free;
            cfg.table.rates_hz = None;
            cfg.table.samples_per_condition = None;
            cfg.table.duration_s = None;
            cfg.timing.sample_rate_hz = 104.0;
            cfg.poses = Some(FreePoses {
                count,
                directions: None,
                still_s: 3.0,
                move_s: 1.5,
                noise_spread: 1.5,
                settle_ms2: 0.5,
                tremor_ms2: tremor.unwrap_or(0.0),
                ..FreePoses::default()
            });
        } else if stepped {
            cfg.method = Method::Static;
            cfg.table.rates_hz = None;
            cfg.table.samples_per_condition = None;
            cfg.table.duration_s = None;
            cfg.table.angle_step_deg = Some(step_deg.unwrap_or(30.0));
            cfg.table.readings_per_angle = Some(20);
            cfg.table.dwell_s = Some(30.0);
        } else {
            cfg.table.rates_hz = Some(vec![rate]);
        }
        cfg.sensor.noise = Some(Noise {
            sd: Some(NoiseSd::All(4.0)),
            ar: (rho != 0.0).then(|| vec![rho]),
            lowpass_hz: None,
            state: false,
            flicker_floor_ug: Some(NoiseSd::All(floor)),
            random_walk_ug_per_sqrt_s: Some(NoiseSd::All(walk)),
        });
        let still = match still_s.map(|s| still_noise(&cfg, s)).transpose() {
            Ok(s) => s,
            Err(e) => {
                eprintln!("session {t}: still recording: {e}");
                return ExitCode::FAILURE;
            }
        };
        let run = Simulation::new(cfg)
            .map_err(|e| e.to_string())
            .and_then(|sim| {
                let (summary, buf) = sim.write(Vec::new()).map_err(|e| e.to_string())?;
                let rec = read_bytes(&buf, "simulated").map_err(|e| e.to_string())?;
                let opts = Options {
                    slow_noise: slow,
                    noise_from: still,
                    ..Options::default()
                };
                match calibrate(&rec, &opts) {
                    Ok(cal) => Ok(Some((sim, summary, cal))),
                    // Too few poses kept for --slow-noise: a refusal, counted apart.
                    Err(e) if matches!(*e.kind, CalibrateErrorKind::FreeSlowPoses { .. }) => {
                        Ok(None)
                    }
                    Err(e) => Err(e.to_string()),
                }
            });
        let (sim, summary, cal) = match run {
            Ok(Some(r)) => r,
            Ok(None) => {
                refused += 1;
                continue;
            }
            Err(e) => {
                eprintln!("session {t}: {e}");
                return ExitCode::FAILURE;
            }
        };
        let truth = sim.truth();
        let mut values = truth.properties();
        // A static or free calibration's offsets are the bias averaged over the record's
        // readings (docs/uncertainty.md): the slow noise's mean over them is part of the
        // measurand.
        if stepped || free.is_some() {
            for (o, m) in values.iter_mut().skip(6).zip(summary.slow_mean) {
                *o += m;
            }
        }
        // A session that warns of drift between poses: its intervals are also counted apart.
        let warned = cal.by_rate.iter().any(|r| {
            r.uncertainty_budget.as_ref().is_some_and(|b| {
                b.notes
                    .iter()
                    .any(|n| n.contains("from one pose to the next"))
            })
        });
        sessions_warned += u32::from(warned);
        // A session whose model check rescaled a channel's noise terms, either way.
        let checked = cal.by_rate.iter().flat_map(|r| r.noise.iter().flatten());
        let mut rescaled_here = (false, false);
        for c in checked.filter_map(|n| n.slow.as_ref()?.model_check.as_ref()) {
            rescaled_here.0 |= c.rescaled_by > 1.0;
            rescaled_here.1 |= c.rescaled_by < 1.0;
        }
        rescaled.0 += u32::from(rescaled_here.0);
        rescaled.1 += u32::from(rescaled_here.1);
        for rate in &cal.by_rate {
            for ((q, tr), p) in rate
                .intrinsic
                .quantities()
                .iter()
                .zip(values)
                .zip(per.iter_mut())
            {
                p.0 += u32::from((q.value - tr).abs() <= q.expanded_unc);
                p.1 += (1.96 * (q.value - tr) / q.std_unc / q.k).powi(2);
                p.2 += q.k;
                p.3 += 1.0;
                total += 1;
                z2 += (1.96 * (q.value - tr) / q.std_unc / q.k).powi(2);
                covered += u32::from((q.value - tr).abs() <= q.expanded_unc);
                if !warned {
                    quiet.0 += u32::from((q.value - tr).abs() <= q.expanded_unc);
                    quiet.1 += 1;
                }
            }
        }
    }
    let per_quantity: Vec<String> = per
        .iter()
        .filter(|p| p.3 > 0.0)
        .map(|p| {
            format!(
                "[{:.4}, {:.4}, {:.3}]",
                f64::from(p.0) / p.3,
                p.1 / p.3,
                p.2 / p.3
            )
        })
        .collect();
    println!(
        "{{\"method\": \"{}\", \"flicker_floor_ug\": {floor}, \"random_walk_ug_per_sqrt_s\": {walk}, \"ar1\": {rho}, \"rate_hz\": {rate}, \"sessions\": {sessions}, \"sessions_refused\": {refused}, \"intervals\": {total}, \"coverage\": {:.4}, \"mean_scaled_z2\": {:.4}, \"sessions_warned\": {sessions_warned}, \"sessions_widened\": {}, \"sessions_narrowed\": {}, \"coverage_unwarned\": {:.4}, \"per_quantity_coverage_z2_k\": [{}]}}",
        match (free, stepped, slow) {
            (Some(_), _, true) => "free, --slow-noise",
            (Some(_), _, false) => "free",
            (None, true, true) => "stepped, --slow-noise",
            (None, true, false) => "stepped",
            (None, false, true) if still_s.is_some() => "rotation, --noise-from",
            (None, false, true) => "rotation, --slow-noise",
            (None, false, false) => "rotation",
        },
        f64::from(covered) / f64::from(total),
        z2 / f64::from(total),
        rescaled.0,
        rescaled.1,
        f64::from(quiet.0) / f64::from(quiet.1),
        per_quantity.join(", ")
    );
    ExitCode::SUCCESS
}

/// A still recording of `seconds` with the noise of session `cfg` (its own seed): the
/// device put down once, at the session's rate, prepared for `Options::noise_from`.
fn still_noise(cfg: &Config, seconds: f64) -> Result<Arc<NoiseFrom>, String> {
    let mut still = cfg.clone();
    still.seed = cfg.seed ^ 0x5711_0000_0000;
    still.method = Method::Free;
    still.table.rates_hz = None;
    still.table.samples_per_condition = None;
    still.table.duration_s = None;
    still.table.start_angle_deg = None;
    still.poses = Some(FreePoses::one_still(seconds));
    let rec = Simulation::new(still)
        .map_err(|e| e.to_string())?
        .recording()
        .map_err(|e| e.to_string())?;
    NoiseFrom::new(&rec)
        .map(Arc::new)
        .map_err(|e| e.to_string())
}
