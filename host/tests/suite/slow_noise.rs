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
