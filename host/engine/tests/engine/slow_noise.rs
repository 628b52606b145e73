//! The simulator's flicker and bias random walk (docs/simulator.md): what it writes has the
//! structure function, E[(e_{t+k} − e_t)²], that its truth states, from one sample to
//! minutes, with each channel at its own level in µg and µg/√s.

use rotacal_engine::simulate::{Config, Simulation};
use rotacal_shared::{Channel, Condition};

/// A still device (one angle) read 8192 times a condition at 16 Hz, no quantisation, with
/// AR(1) fast noise, flicker and random walk at different levels per channel.
fn still(seed: u64, flicker_ug: [f64; 3], walk_ug: [f64; 3]) -> Config {
    let text = format!(
        r#"
seed = {seed}
method = "static"
units = "counts"
[device]
sensitivity = [1669.32, 1669.10, 1676.46]
angles_deg = [90.077, 90.095, 89.910]
offsets = [25.1, 9.6, 42.4]
[sensor]
lsb = 0.0
full_scale = [-1e9, 1e9]
[sensor.noise]
sd = [0.5, 0.7, 1.0]
ar = [0.5]
flicker_floor_ug = {flicker_ug:?}
random_walk_ug_per_sqrt_s = {walk_ug:?}
[timing]
sample_rate_hz = 16.0
[table]
angles_deg = [0.0]
readings_per_angle = 8192
"#
    );
    toml::from_str(&text).unwrap()
}

/// Each channel's samples in condition x (one angle: consecutive, 1/fs apart).
fn channels(sim: &Simulation) -> [Vec<f64>; 3] {
    let mut out = [Vec::new(), Vec::new(), Vec::new()];
    sim.run(|row| {
        if row.condition == Condition::X {
            for (o, y) in out.iter_mut().zip([row.u, row.v, row.w]) {
                o.push(y);
            }
        }
        Ok(())
    })
    .unwrap();
    out
}

fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var.sqrt())
}

/// Over 100 sessions, the mean squared increment at lags of 1 sample to 256 s against the
/// truth's structure function: within 4 standard errors of the Monte Carlo mean (two-sided).
/// Each standard error is under 8 % of the slow terms' part from 16 s on, where they
/// dominate, so a flicker or walk level off by a third fails.
#[test]
fn flicker_and_random_walk_have_the_stated_structure_function() {
    let (flicker, walk) = ([20.0, 50.0, 100.0], [2.0, 5.0, 10.0]);
    let lags = [1u64, 16, 256, 4096];
    let mut per_seed = vec![[[0.0; 4]; 3]; 100];
    let mut truth = None;
    for (seed, out) in per_seed.iter_mut().enumerate() {
        let sim = Simulation::new(still(seed as u64, flicker, walk)).unwrap();
        for (ch, y) in channels(&sim).iter().enumerate() {
            for (li, &k) in lags.iter().enumerate() {
                let k = k as usize;
                let d = y.iter().zip(&y[k..]).map(|(a, b)| (b - a).powi(2));
                out[ch][li] = d.sum::<f64>() / (y.len() - k) as f64;
            }
        }
        truth.get_or_insert_with(|| sim.truth().clone());
    }
    let truth = truth.unwrap();
    let mut report = Vec::new();
    for (ci, ch) in Channel::ALL.into_iter().enumerate() {
        for (li, &k) in lags.iter().enumerate() {
            let vals: Vec<f64> = per_seed.iter().map(|s| s[ci][li]).collect();
            let (mean, sd) = mean_sd(&vals);
            let se = sd / (vals.len() as f64).sqrt();
            let want = truth.noise_structure(ch, k);
            report.push(format!(
                "{ch:?} lag {k}: {mean:.4} vs {want:.4} (se {se:.4})"
            ));
            assert!((mean - want).abs() < 4.0 * se, "{report:#?}");
            let slow = truth.slow.structure(ch, k);
            assert!(k < 256 || se < 0.08 * slow, "{report:#?}");
        }
    }
    println!("{report:#?}");
}

/// The slow terms are in physical units: the structure function's slow part at long lags
/// follows the flicker's (4Q/π)·Σ1/(2j − 1) and the walk's k·K²/fs with Q and K from µg.
#[test]
fn slow_levels_convert_from_micro_g() {
    let sim = Simulation::new(still(1, [50.0; 3], [0.0; 3])).unwrap();
    let t = sim.truth();
    // The flicker's Allan deviation at long τ is its floor: 50 µg in counts.
    let floor = 50.0 * 9.806_65e-6 * t.sensitivity[0];
    let fl_only =
        rotacal_engine::simulate::slow::allan_variance(4096, |k| t.slow.structure(Channel::U, k));
    assert!(
        (fl_only.sqrt() / floor - 1.0).abs() < 1e-4,
        "{}",
        fl_only.sqrt() / floor
    );
    let sim = Simulation::new(still(1, [0.0; 3], [10.0; 3])).unwrap();
    let t = sim.truth();
    // The walk's at τ = 3 s (m = 48): K·√(τ/3) = K, with the discrete K²Δ²/(6τ) term.
    let k = 10.0 * 9.806_65e-6 * t.sensitivity[1];
    let rw =
        rotacal_engine::simulate::slow::allan_variance(48, |j| t.slow.structure(Channel::V, j));
    let want = k * k * (1.0 + (1.0 / 16.0f64).powi(2) / (6.0 * 3.0) / 1.0);
    assert!((rw / want - 1.0).abs() < 1e-9, "{}", rw / want);
}
