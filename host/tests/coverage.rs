//! Monte Carlo validation of the uncertainties, run through the simulator and the whole
//! `calibrate` path (CSV written, parsed, rate test, fits, intrinsic properties):
//!
//! - coverage: 2000 simulated `paper-10mhz` runs of a device mounted 3° off. For each
//!   property the fraction of k = 2 intervals that hold the truth must lie in
//!   [0.93, 0.97] (about ±4 binomial σ around 0.954 at 2000 trials). The same for the
//!   static method on `metrologia-static`.
//! - efficiency: the Monte Carlo spread of each sensitivity is within 10 % of the
//!   Cramér–Rao bound, computed in this test from the exact regressors and the truth.
// Matrix arithmetic on small fixed arrays reads more plainly with indices.
#![allow(clippy::needless_range_loop)]

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rotacal::calibrate_recording::{calibrate, Options};
use rotacal::calibration_file::{Quantity, RateJson};
use rotacal::demo::PAPER_10MHZ;
use rotacal::simulate::{Config, Simulation, Truth};
use std::f64::consts::TAU;

const TRIALS: usize = 2000;

/// Runs `trial(i)` for i in 0..TRIALS on two threads.
fn parallel<T: Send>(trial: impl Fn(usize) -> T + Sync) -> Vec<T> {
    let half = TRIALS / 2;
    std::thread::scope(|s| {
        let a = s.spawn(|| (0..half).map(&trial).collect::<Vec<_>>());
        let mut out: Vec<T> = (half..TRIALS).map(&trial).collect();
        let mut first = a.join().unwrap();
        first.append(&mut out);
        first
    })
}

struct Tally {
    names: Vec<&'static str>,
    truth: Vec<f64>,
    covered: Vec<u32>,
    values: Vec<Vec<f64>>,
    std_unc: Vec<Vec<f64>>,
}

impl Tally {
    fn new(names: Vec<&'static str>, truth: Vec<f64>) -> Self {
        let k = names.len();
        Tally {
            names,
            truth,
            covered: vec![0; k],
            values: vec![Vec::new(); k],
            std_unc: vec![Vec::new(); k],
        }
    }

    fn add(&mut self, qs: &[&Quantity]) {
        assert_eq!(qs.len(), self.names.len());
        for (k, q) in qs.iter().enumerate() {
            assert_eq!(q.k, 2.0);
            assert!((q.expanded_unc - 2.0 * q.std_unc).abs() <= 1e-12 * q.expanded_unc);
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
    fn check(&self) -> Vec<String> {
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
    cfg
}

/// Cramér–Rao variance of s_j for one run (white noise of variance σ², known rate): the
/// LS covariance σ²(HᵀH)⁻¹ of (A, B) per condition, from the exact regressors at the
/// sample times the fit uses, pushed through s_j = √(Σ_c A_c² + B_c²) / (g√2) at the truth.
fn crb_var(truth: &Truth, start_deg: [f64; 3], sigma2: f64, g: f64, n: usize, fs: f64) -> [f64; 3] {
    let omega = TAU * 0.01;
    let mut var = [0.0; 3];
    for c in 0..3 {
        // HᵀH for regressors (sin ωt, cos ωt, 1), t from the condition's first sample.
        let mut m = [[0.0; 3]; 3];
        for k in 0..n {
            let (s, co) = (omega * k as f64 / fs).sin_cos();
            let h = [s, co, 1.0];
            for i in 0..3 {
                for j in 0..3 {
                    m[i][j] += h[i] * h[j];
                }
            }
        }
        let inv = inverse3(&m);
        let (p, q) = [(1, 2), (0, 2), (0, 1)][c];
        let (sa, ca) = start_deg[c].to_radians().sin_cos();
        for j in 0..3 {
            let sp = truth.matrix_platter[j];
            // y = g(S_jp sin(α0 + ωt) + S_jq cos(α0 + ωt)) = A sin ωt + B cos ωt.
            let a = g * (sp[p] * ca - sp[q] * sa);
            let b = g * (sp[p] * sa + sp[q] * ca);
            let d = 2.0 * g * g * truth.sensitivity[j];
            let grad = [a / d, b / d];
            for x in 0..2 {
                for y in 0..2 {
                    var[j] += sigma2 * grad[x] * inv[x][y] * grad[y];
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
    let results: Vec<(RateJson, [f64; 3], Truth)> = parallel(|trial| {
        let mut rng = ChaCha8Rng::seed_from_u64(0xA11E_0000 + trial as u64);
        let start = [0; 3].map(|_| rng.gen::<f64>() * 360.0);
        let sim = Simulation::new(paper_config(trial, start)).unwrap();
        let rec = sim.recording().unwrap();
        let cal = calibrate(&rec, &Options::default()).unwrap();
        let entry = cal.by_rate.into_iter().next().unwrap();
        let cfg = sim.config();
        let sigma2 = sim.noise_floor().powi(2);
        let crb = crb_var(sim.truth(), start, sigma2, cfg.g_loc, 4200, 16.0);
        (entry, crb, sim.truth().clone())
    });
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
    for (entry, var, _) in &results {
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
    // Expanded uncertainties beside seed 000 Table 1's (which states no coverage factor).
    for k in 0..6 {
        let u2 = 2.0 * tally.mean_u(k);
        println!(
            "{}: mean U (k = 2) {u2:.3e}; seed 000 Table 1 states {}; {:.0}× smaller",
            tally.names[k],
            PAPER_10MHZ[k].1,
            PAPER_10MHZ[k].1 / u2
        );
    }
    assert!(failures.is_empty(), "{failures:?}");
}

#[test]
fn static_coverage_through_the_simulator() {
    let results: Vec<RateJson> = parallel(|trial| {
        let mut cfg = Config::preset("metrologia-static").unwrap();
        cfg.seed = 0x57A7_0000 + trial as u64;
        cfg.mounting.axis = [1.0, 1.0, 0.0];
        cfg.mounting.angle_deg = 5.0;
        let sim = Simulation::new(cfg).unwrap();
        let rec = sim.recording().unwrap();
        calibrate(&rec, &Options::default())
            .unwrap()
            .by_rate
            .remove(0)
    });
    let sim = Simulation::new(Config::preset("metrologia-static").unwrap()).unwrap();
    let t = sim.truth();
    let mut tally = Tally::new(
        vec![
            "s_u", "s_v", "s_w", "φ_uv", "φ_vw", "φ_wu", "O_u", "O_v", "O_w",
        ],
        t.properties().to_vec(),
    );
    for entry in &results {
        tally.add(&entry.intrinsic.quantities());
    }
    let failures = tally.check();
    assert!(failures.is_empty(), "{failures:?}");
}
