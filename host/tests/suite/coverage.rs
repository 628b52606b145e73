//! Monte Carlo validation of the uncertainties, run through the simulator and the whole
//! `calibrate` path (CSV written, parsed, rate test, fits, noise model, budget, intrinsic
//! properties). No file states its noise: the simulator is told not to (`[sensor.noise]
//! state = false`, or correlated noise, which it never states), so the code under test
//! estimates the noise from the data as it must on a real recording.
//!
//! - coverage: 2000 simulated `paper-10mhz` runs of a device mounted 3° off, for each noise
//!   and timing case: white; AR(1) with ρ = 0.3, 0.6, 0.9; a low-pass like the LSM6DS33's
//!   digital filter (ODR/9 at 104 Hz); a 300 ppm rate error; and four rates in one file.
//!   For each property the fraction of the expanded-uncertainty intervals that hold the
//!   truth must lie in [0.93, 0.97]: two-sided, about ±4 binomial σ around 0.95 at 2000
//!   trials (σ = 0.0049), so an understated U fails, and so does a U overstated by 10 %
//!   (coverage 0.972: each property's check catches it in about 70 % of runs, one of the six
//!   in all but 0.05 %). The same for the static method on `metrologia-static`.
//! - efficiency: the Monte Carlo spread of each sensitivity is within 10 % of the
//!   Cramér–Rao bound, computed in this test from the exact regressors and the truth.
//!
//! Each is a proof at two sizes (docs/testing.md): `scripts/bench-proofs` runs it in full
//! and records it under bench/proofs; test-all re-runs its first sessions against that
//! record.
// Matrix arithmetic on small fixed arrays reads more plainly with indices.
#![allow(clippy::needless_range_loop)]

use crate::common::unstated;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rotacal::calibrate::json::{Quantity, RateJson};
use rotacal::calibrate::{calibrate, Options, TypeB};
use rotacal::reference::PAPER_10MHZ;
use rotacal::simulate::{Config, Noise, Simulation, StepError, Truth};
use rotacal_proof::prove;
use std::f64::consts::TAU;

const TRIALS: usize = 2000;

pub(crate) struct Tally {
    names: Vec<&'static str>,
    truth: Vec<f64>,
    covered: Vec<u32>,
    values: Vec<Vec<f64>>,
    std_unc: Vec<Vec<f64>>,
}

impl Tally {
    pub(crate) fn new(names: Vec<&'static str>, truth: Vec<f64>) -> Self {
        let k = names.len();
        Tally {
            names,
            truth,
            covered: vec![0; k],
            values: vec![Vec::new(); k],
            std_unc: vec![Vec::new(); k],
        }
    }

    pub(crate) fn add(&mut self, qs: &[&Quantity]) {
        assert_eq!(qs.len(), self.names.len());
        for (k, q) in qs.iter().enumerate() {
            assert!(q.k >= 2.0);
            assert!((q.expanded_unc - q.k * q.std_unc).abs() <= 1e-12 * q.expanded_unc);
            if (q.value - self.truth[k]).abs() <= q.expanded_unc {
                self.covered[k] += 1;
            }
            self.values[k].push(q.value);
            self.std_unc[k].push(q.std_unc);
        }
    }

    fn sd(&self, k: usize) -> f64 {
        let v = &self.values[k];
        let n = v.len() as f64;
        let m = v.iter().sum::<f64>() / n;
        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    }

    fn mean_u(&self, k: usize) -> f64 {
        self.std_unc[k].iter().sum::<f64>() / self.std_unc[k].len() as f64
    }

    /// Prints each property's coverage and spread; returns the failures.
    pub(crate) fn check(&self) -> Vec<String> {
        let mut failures = Vec::new();
        for k in 0..self.names.len() {
            let frac = f64::from(self.covered[k]) / self.values[k].len() as f64;
            println!(
                "{:<5} coverage {frac:.4}  MC spread {:.4e}  mean stated u {:.4e}  ratio {:.3}",
                self.names[k],
                self.sd(k),
                self.mean_u(k),
                self.sd(k) / self.mean_u(k)
            );
            if !(0.93..=0.97).contains(&frac) {
                failures.push(format!("{}: coverage {frac}", self.names[k]));
            }
        }
        failures
    }
}

fn paper_config(trial: usize, start_deg: [f64; 3]) -> Config {
    let mut cfg = Config::preset("paper-10mhz").unwrap();
    cfg.seed = 0x5EED_0000 + trial as u64;
    cfg.mounting.axis = [1.0, 2.0, 2.0];
    cfg.mounting.angle_deg = 3.0;
    cfg.table.start_angle_deg = Some(start_deg);
    cfg.sensor.noise = unstated(None, None);
    cfg
}

/// Cramér–Rao variance of s_j for one run (white noise of standard deviation `sd[j]` on
/// channel j, known rate `rate_hz`, `n` samples at `fs` per condition): the LS covariance
/// σ_j²(HᵀH)⁻¹ of (A, B) per condition, from the exact regressors at the sample times the
/// fit uses, pushed through s_j = √(Σ_c A_c² + B_c²) / (g√2) at the truth.
pub(crate) struct Crb {
    pub sd: [f64; 3],
    pub g: f64,
    pub n: usize,
    pub fs: f64,
    pub rate_hz: f64,
}

pub(crate) fn crb_var(truth: &Truth, start_deg: [f64; 3], c: &Crb) -> [f64; 3] {
    let omega = TAU * c.rate_hz;
    let g = c.g;
    let mut var = [0.0; 3];
    for cond in 0..3 {
        // HᵀH for regressors (sin ωt, cos ωt, 1), t from the condition's first sample.
        let mut m = [[0.0; 3]; 3];
        for k in 0..c.n {
            let (s, co) = (omega * k as f64 / c.fs).sin_cos();
            let h = [s, co, 1.0];
            for i in 0..3 {
                for j in 0..3 {
                    m[i][j] += h[i] * h[j];
                }
            }
        }
        let inv = inverse3(&m);
        let (p, q) = [(1, 2), (0, 2), (0, 1)][cond];
        let (sa, ca) = start_deg[cond].to_radians().sin_cos();
        for j in 0..3 {
            let sp = truth.matrix_platter[j];
            // y = g(S_jp sin(α0 + ωt) + S_jq cos(α0 + ωt)) = A sin ωt + B cos ωt.
            let a = g * (sp[p] * ca - sp[q] * sa);
            let b = g * (sp[p] * sa + sp[q] * ca);
            let d = 2.0 * g * g * truth.sensitivity[j];
            let grad = [a / d, b / d];
            for x in 0..2 {
                for y in 0..2 {
                    var[j] += c.sd[j] * c.sd[j] * grad[x] * inv[x][y] * grad[y];
                }
            }
        }
    }
    var
}

fn inverse3(m: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    let mut inv = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            let (r0, r1) = ([1, 0, 0][j], [2, 2, 1][j]);
            let (c0, c1) = ([1, 0, 0][i], [2, 2, 1][i]);
            let minor = m[r0][c0] * m[r1][c1] - m[r0][c1] * m[r1][c0];
            let sign = if (i + j) % 2 == 0 { 1.0 } else { -1.0 };
            inv[i][j] = sign * minor / det;
        }
    }
    inv
}

#[test]
fn rotation_coverage_and_efficiency_through_the_simulator() {
    prove(
        "coverage::rotation_coverage_and_efficiency_through_the_simulator",
        TRIALS,
        efficiency_trial,
        efficiency_check,
    );
}

/// One session of the efficiency proof: its calibration, each sensitivity's Cramér–Rao
/// variance, and its truth.
fn efficiency_trial(trial: usize) -> (RateJson, [f64; 3], Truth) {
    let mut rng = ChaCha8Rng::seed_from_u64(0xA11E_0000 + trial as u64);
    let start = [0; 3].map(|_| rng.gen::<f64>() * 360.0);
    let sim = Simulation::new(paper_config(trial, start)).unwrap();
    let rec = sim.recording().unwrap();
    let cal = calibrate(&rec, &Options::default()).unwrap();
    let entry = cal.by_rate.into_iter().next().unwrap();
    let cfg = sim.config();
    let sigma2 = sim.noise_floor().powi(2);
    let crb = crb_var(
        sim.truth(),
        start,
        &Crb {
            sd: [sigma2.sqrt(); 3],
            g: cfg.g_loc,
            n: 4200,
            fs: 16.0,
            rate_hz: 0.01,
        },
    );
    (entry, crb, sim.truth().clone())
}

/// Coverage, and each sensitivity's spread against the Cramér–Rao bound.
fn efficiency_check(results: &[(RateJson, [f64; 3], Truth)]) -> Vec<String> {
    let truth = &results[0].2;
    let mut tally = Tally::new(
        vec!["s_u", "s_v", "s_w", "φ_uv", "φ_vw", "φ_wu"],
        truth
            .sensitivity
            .iter()
            .chain(&truth.angles_deg)
            .copied()
            .collect(),
    );
    let mut crb = [0.0; 3];
    let mut rate_fitted = 0;
    for (entry, var, _) in results {
        tally.add(&entry.intrinsic.quantities());
        for j in 0..3 {
            crb[j] += var[j] / TRIALS as f64;
        }
        rate_fitted += usize::from(entry.fits.iter().any(|f| f.rate_hz_fitted.is_some()));
    }
    println!(
        "runs in which a condition's rate was fitted (no rate error simulated): {rate_fitted}"
    );
    let mut failures = tally.check();
    for j in 0..3 {
        let bound = crb[j].sqrt();
        let ratio = tally.sd(j) / bound;
        println!(
            "{} MC spread / Cramér–Rao bound {ratio:.4} (bound {bound:.4e})",
            tally.names[j]
        );
        if (ratio - 1.0).abs() > 0.10 {
            failures.push(format!("{}: spread/CRB {ratio}", tally.names[j]));
        }
    }
    // Expanded uncertainties beside Gaitan & Geist (2022) Table 1's (which states no coverage factor).
    for k in 0..6 {
        let u2 = 2.0 * tally.mean_u(k);
        println!(
            "{}: mean U (k = 2) {u2:.3e}; Gaitan & Geist (2022) Table 1 states {}; {:.0}× smaller",
            tally.names[k],
            PAPER_10MHZ[k].1,
            PAPER_10MHZ[k].1 / u2
        );
    }
    failures
}

#[test]
fn static_coverage_through_the_simulator() {
    prove(
        "coverage::static_coverage_through_the_simulator",
        TRIALS,
        static_trial,
        static_check,
    );
}

/// One static session's calibration.
fn static_trial(trial: usize) -> RateJson {
    let mut cfg = Config::preset("metrologia-static").unwrap();
    cfg.seed = 0x57A7_0000 + trial as u64;
    cfg.mounting.axis = [1.0, 1.0, 0.0];
    cfg.mounting.angle_deg = 5.0;
    cfg.sensor.noise = unstated(None, None);
    let sim = Simulation::new(cfg).unwrap();
    let rec = sim.recording().unwrap();
    calibrate(&rec, &Options::default())
        .unwrap()
        .by_rate
        .remove(0)
}

/// The nine properties' coverage.
fn static_check(results: &[RateJson]) -> Vec<String> {
    let sim = Simulation::new(Config::preset("metrologia-static").unwrap()).unwrap();
    let t = sim.truth();
    let mut tally = Tally::new(
        vec![
            "s_u", "s_v", "s_w", "φ_uv", "φ_vw", "φ_wu", "O_u", "O_v", "O_w",
        ],
        t.properties().to_vec(),
    );
    for entry in results {
        tally.add(&entry.intrinsic.quantities());
    }
    tally.check()
}

/// Coverage of the nine static properties over 2000 stepped sessions of `metrologia-static`
/// turned in `step_deg` steps with `readings` a step (at 1 Hz, `dwell_s` apart) and
/// `step_error`, with AR noise of coefficients `ar` (white if empty; never stated),
/// calibrated with `inputs`: the proof `name`.
fn stepped_coverage(
    name: &str,
    case: &str,
    (step_deg, readings, dwell_s): (f64, u32, Option<f64>),
    ar: &[f64],
    error: StepError,
    inputs: TypeB,
) {
    let cfg = |trial: usize| {
        let mut cfg = Config::preset("metrologia-static").unwrap();
        cfg.seed = 0x57E9_0000 + trial as u64;
        cfg.mounting.axis = [1.0, 1.0, 0.0];
        cfg.mounting.angle_deg = 5.0;
        cfg.sensor.noise = unstated((!ar.is_empty()).then(|| ar.to_vec()), None);
        cfg.table.angle_step_deg = Some(step_deg);
        cfg.table.readings_per_angle = Some(readings);
        cfg.table.dwell_s = dwell_s;
        cfg.effects.step_error = Some(error.clone());
        cfg
    };
    let opts = Options {
        inputs,
        ..Options::default()
    };
    let trial = |trial: usize| {
        let sim = Simulation::new(cfg(trial)).unwrap();
        let rec = sim.recording().unwrap();
        calibrate(&rec, &opts).unwrap().by_rate.remove(0)
    };
    prove(name, TRIALS, trial, |results| {
        stepped_tally(case, &Simulation::new(cfg(0)).unwrap(), results)
    });
}

/// The nine properties' coverage over `results`, against `sim`'s truth.
fn stepped_tally(case: &str, sim: &Simulation, results: &[RateJson]) -> Vec<String> {
    let mut tally = Tally::new(
        vec![
            "s_u", "s_v", "s_w", "φ_uv", "φ_vw", "φ_wu", "O_u", "O_v", "O_w",
        ],
        sim.truth().properties().to_vec(),
    );
    for entry in results {
        tally.add(&entry.intrinsic.quantities());
    }
    println!("{case}:");
    tally
        .check()
        .into_iter()
        .map(|f| format!("{case}: {f}"))
        .collect()
}

#[test]
fn stepped_coverage_with_stated_angle_errors() {
    // 30° steps (36 poses), 20 readings a step, each angle off by 0.01° (normal), which
    // the lab states (`--u-angle-deg 0.01`, its table's specification); the noise is not
    // stated.
    stepped_coverage(
        "coverage::stepped_coverage_with_stated_angle_errors",
        "stepped, angle errors 0.01° stated",
        (30.0, 20, None),
        &[],
        StepError {
            angle_sd_deg: 0.01,
            tilt_sd_deg: 0.0,
        },
        TypeB {
            u_angle_deg: Some(0.01),
            ..TypeB::default()
        },
    );
}

#[test]
fn stepped_coverage_with_unstated_tilt_errors() {
    // The same table, each step tilted by 0.01° about each axis (normal), nothing stated:
    // the tilt is estimated from the poses' scatter.
    stepped_coverage(
        "coverage::stepped_coverage_with_unstated_tilt_errors",
        "stepped, tilt errors 0.01° unstated",
        (30.0, 20, None),
        &[],
        StepError {
            angle_sd_deg: 0.0,
            tilt_sd_deg: 0.01,
        },
        TypeB::default(),
    );
}

/// Coverage of the six properties (at every rate) over `trials` runs of `cfg(trial)`: the
/// proof `name`.
fn rotation_coverage(name: &str, case: &str, trials: usize, cfg: impl Fn(usize) -> Config + Sync) {
    let trial = |trial: usize| {
        let sim = Simulation::new(cfg(trial)).unwrap();
        let rec = sim.recording().unwrap();
        let cal = calibrate(&rec, &Options::default()).unwrap();
        (cal.by_rate, sim.truth().clone())
    };
    prove(name, trials, trial, |results| rotation_tally(case, results));
}

/// Each rate's coverage of the six properties over `results` (each run's calibration and
/// its truth), printed; the failures.
pub(crate) fn rotation_tally(case: &str, results: &[(Vec<RateJson>, Truth)]) -> Vec<String> {
    let trials = results.len();
    let truth = &results[0].1;
    let values: Vec<f64> = truth
        .sensitivity
        .iter()
        .chain(&truth.angles_deg)
        .copied()
        .collect();
    let rates = results[0].0.len();
    let mut failures = Vec::new();
    for r in 0..rates {
        println!("{case}, rate {r}:");
        let mut tally = Tally::new(
            vec!["s_u", "s_v", "s_w", "φ_uv", "φ_vw", "φ_wu"],
            values.clone(),
        );
        for (by_rate, _) in results {
            tally.add(&by_rate[r].intrinsic.quantities());
        }
        failures.extend(
            tally
                .check()
                .into_iter()
                .map(|f| format!("{case} rate {r}: {f}")),
        );
    }
    let fitted = results
        .iter()
        .filter(|(b, _)| {
            b.iter()
                .any(|e| e.fits.iter().any(|f| f.rate_hz_fitted.is_some()))
        })
        .count();
    let factor: f64 = results
        .iter()
        .flat_map(|(b, _)| b.iter().flat_map(|e| e.noise.iter().flatten()))
        .map(|n| n.variance_factor)
        .sum::<f64>()
        / (results.len() * rates * 9) as f64;
    println!(
        "{case}: runs with a fitted rate {fitted}/{trials}; mean variance factor at ω {factor:.2}"
    );
    failures
}

fn correlated(trial: usize, noise: Option<Noise>) -> Config {
    let mut rng = ChaCha8Rng::seed_from_u64(0xA11E_0000 + trial as u64);
    let mut cfg = paper_config(trial, [0; 3].map(|_| rng.gen::<f64>() * 360.0));
    cfg.sensor.noise = noise;
    cfg
}

#[test]
fn rotation_coverage_ar1_0_3() {
    rotation_coverage(
        "coverage::rotation_coverage_ar1_0_3",
        "AR(1) ρ = 0.3",
        TRIALS,
        |t| correlated(t, unstated(Some(vec![0.3]), None)),
    );
}

#[test]
fn rotation_coverage_ar1_0_6() {
    rotation_coverage(
        "coverage::rotation_coverage_ar1_0_6",
        "AR(1) ρ = 0.6",
        TRIALS,
        |t| correlated(t, unstated(Some(vec![0.6]), None)),
    );
}

#[test]
fn rotation_coverage_ar1_0_9() {
    rotation_coverage(
        "coverage::rotation_coverage_ar1_0_9",
        "AR(1) ρ = 0.9",
        TRIALS,
        |t| correlated(t, unstated(Some(vec![0.9]), None)),
    );
}

#[test]
fn rotation_coverage_lowpass_like_the_lsm6ds33() {
    // The LSM6DS33 at 104 Hz with its digital low-pass at ODR/9 (11.6 Hz), Gaitan & Geist's (2022)
    // 262.5 s per condition at the sensor's own rate; the level that of the 11.6 Hz band.
    // 1000 runs (each 6.5 times the samples): [0.93, 0.97] is then ±2.9 binomial σ.
    rotation_coverage(
        "coverage::rotation_coverage_lowpass_like_the_lsm6ds33",
        "low-pass 11.6 Hz at 104 Hz",
        1000,
        |t| {
            let mut cfg = correlated(t, unstated(None, Some(104.0 / 9.0)));
            cfg.timing.sample_rate_hz = 104.0;
            cfg.table.samples_per_condition = Some(27_300);
            cfg
        },
    );
}

#[test]
fn rotation_coverage_with_a_300_ppm_rate_error() {
    rotation_coverage(
        "coverage::rotation_coverage_with_a_300_ppm_rate_error",
        "rate error 300 ppm",
        TRIALS,
        |t| {
            let mut cfg = correlated(t, unstated(None, None));
            cfg.effects.rate_error = Some(rotacal::simulate::config::RateError { relative: 3e-4 });
            cfg
        },
    );
}

#[test]
fn rotation_coverage_at_four_rates_in_one_file() {
    rotation_coverage(
        "coverage::rotation_coverage_at_four_rates_in_one_file",
        "10, 50, 100, 500 mHz",
        TRIALS,
        |t| {
            let mut cfg = Config::preset("paper-multirate").unwrap();
            cfg.seed = 0x4A7E_0000 + t as u64;
            cfg.sensor.noise = unstated(Some(vec![0.5]), None);
            cfg
        },
    );
}

#[test]
fn stepped_coverage_with_correlated_readings() {
    // 20 readings a step of AR(1) noise with ρ = 0.6 (the mean of 20 has about 3.4 times
    // the variance std²/20 says), no angle or tilt error, nothing stated: each pose's mean
    // takes its variance from one AR model pooled over the poses. The table takes 10 s
    // to the next angle (30 s from step to step), during which the noise runs on.
    stepped_coverage(
        "coverage::stepped_coverage_with_correlated_readings",
        "stepped, 20 readings of AR(1) ρ = 0.6",
        (30.0, 20, Some(30.0)),
        &[0.6],
        StepError {
            angle_sd_deg: 0.0,
            tilt_sd_deg: 0.0,
        },
        TypeB::default(),
    );
}
