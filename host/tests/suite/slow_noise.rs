//! `calibrate --slow-noise` on simulated slow noise (docs/uncertainty.md, "Slow noise"): the
//! levels it reports against the simulated ones, U growing with them, and nothing of it
//! without the option.

use rotacal::calibrate::json::CalibrationJson;
use rotacal::calibrate::{calibrate, Options};
use rotacal::simulate::{Config, Noise, NoiseSd, Simulation};

/// `paper-10mhz` with 4 counts of white noise plus a flicker floor (µg) and a random walk
/// (µg/√s), calibrated with and without `--slow-noise`.
fn both(seed: u64, floor_ug: f64, walk_ug: f64) -> (CalibrationJson, CalibrationJson) {
    let mut cfg = Config::preset("paper-10mhz").unwrap();
    cfg.seed = seed;
    cfg.sensor.noise = Some(Noise {
        sd: Some(NoiseSd::All(4.0)),
        ar: None,
        lowpass_hz: None,
        state: false,
        flicker_floor_ug: Some(NoiseSd::All(floor_ug)),
        random_walk_ug_per_sqrt_s: Some(NoiseSd::All(walk_ug)),
    });
    let rec = Simulation::new(cfg).unwrap().recording().unwrap();
    let slow = Options {
        slow_noise: true,
        ..Options::default()
    };
    (
        calibrate(&rec, &slow).unwrap(),
        calibrate(&rec, &Options::default()).unwrap(),
    )
}

/// Each channel's flicker Allan variance and walk K², in µg² and µg²/s, within 4 of their
/// standard uncertainties of the simulated ones (every entry, 4 sessions a case); the
/// sensitivities' U larger with the slow terms; no `slow` without the option.
#[test]
fn slow_levels_are_found_where_simulated() {
    for (floor, walk) in [(45.0, 0.0), (0.0, 10.0)] {
        for seed in 0..4 {
            let (with, without) = both(0x510E_0000 + seed, floor, walk);
            let noise = with.by_rate[0].noise.as_ref().unwrap();
            let mut seen = 0;
            for n in noise {
                // A channel with readings on a rail keeps the AR model alone.
                let Some(s) = &n.slow else { continue };
                seen += 1;
                let checks = [
                    (
                        "flicker Allan variance",
                        &s.flicker_allan_variance,
                        floor * floor,
                    ),
                    ("random walk K²", &s.random_walk_k2, walk * walk),
                ];
                for (what, term, truth) in checks {
                    let (v, u) = (term.value_ug.unwrap(), term.u_ug.unwrap());
                    assert!(
                        (v - truth).abs() <= 4.0 * u,
                        "seed {seed}, {} {}: {what} {v:.1} ± {u:.1} µg², simulated {truth}",
                        n.condition,
                        n.channel
                    );
                }
            }
            assert!(seen >= 6, "slow terms in only {seen} of 9 entries");
            let grown = with.by_rate[0].intrinsic.quantities()[..3]
                .iter()
                .zip(&without.by_rate[0].intrinsic.quantities()[..3])
                .all(|(a, b)| a.std_unc > b.std_unc);
            assert!(grown, "seed {seed}: U did not grow with the slow terms");
            assert!(without.by_rate[0]
                .noise
                .as_ref()
                .unwrap()
                .iter()
                .all(|n| n.slow.is_none()));
        }
    }
}

/// Stepped sessions of the same device (30° steps, 20 readings a step at 16 Hz, 30 s from
/// step to step), 4 counts of white noise, AR(1) coefficient `rho` if not 0, and a random
/// walk (µg/√s), never stated: how many of `sessions` warn that the pose residuals are
/// correlated from one pose to the next.
fn stepped_drift_warnings(rho: f64, walk_ug: f64, sessions: u64) -> usize {
    crate::coverage::parallel_n(sessions as usize, |t| {
        let mut cfg = Config::preset("paper-10mhz").unwrap();
        cfg.seed = 0xD21F_0000 + t as u64;
        cfg.method = rotacal::recording::Method::Static;
        cfg.table.rates_hz = None;
        cfg.table.samples_per_condition = None;
        cfg.table.angle_step_deg = Some(30.0);
        cfg.table.readings_per_angle = Some(20);
        cfg.table.dwell_s = Some(30.0);
        cfg.sensor.noise = Some(Noise {
            sd: Some(NoiseSd::All(4.0)),
            ar: (rho != 0.0).then(|| vec![rho]),
            lowpass_hz: None,
            state: false,
            flicker_floor_ug: None,
            random_walk_ug_per_sqrt_s: Some(NoiseSd::All(walk_ug)),
        });
        let rec = Simulation::new(cfg).unwrap().recording().unwrap();
        let cal = calibrate(&rec, &Options::default()).unwrap();
        cal.by_rate.iter().any(|r| {
            r.uncertainty_budget.as_ref().is_some_and(|b| {
                b.notes
                    .iter()
                    .any(|n| n.contains("correlated from one pose to the next"))
            })
        })
    })
    .into_iter()
    .filter(|w| *w)
    .count()
}

/// The serial test of the pose residuals (docs/uncertainty.md, "Drift between poses"):
/// independent poses warn in about 0.3 % of sessions (three channels at 0.1 % each), so
/// of 500 white and 500 AR(1) ρ = 0.6 sessions at most 8 each may warn (binomial mean
/// 1.5, P(> 8) ≈ 2e-5); a bias random walk of 10 µg/√s warns in at least 95 % of 200.
#[test]
fn stepped_drift_between_poses_is_warned_of_and_independent_poses_are_not() {
    let white = stepped_drift_warnings(0.0, 0.0, 500);
    let ar = stepped_drift_warnings(0.6, 0.0, 500);
    let walk = stepped_drift_warnings(0.0, 10.0, 200);
    println!("drift warnings: white {white}/500, AR(1) 0.6 {ar}/500, walk 10 µg/√s {walk}/200");
    assert!(white <= 8 && ar <= 8, "false alarms: {white}, {ar}");
    assert!(walk >= 190, "walk warned in {walk}/200");
}
