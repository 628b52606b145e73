//! The noise model (`rotacal::fit::noise`) on its own: what it estimates from residuals, and
//! the coverage of the fit covariance it gives, on noise as sensors make it (serially
//! correlated, clipped). The code under test sees only the residuals and the regressors:
//! never the true level or correlation.
//!
//! Bounds come from statistics: an autocorrelation estimate has Bartlett's standard error,
//! a coverage fraction its binomial spread (1000 trials: σ = 0.0069 at 0.95, so
//! [0.93, 0.97] is about ±3σ; an interval 10 % too wide covers 0.972, which a single
//! coefficient's check catches only about half the time, the three together mostly).
use nalgebra::DMatrix;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rotacal::fit::noise::{clipped, NoiseModel};
use rotacal_shared::{Channel, Condition};
use std::f64::consts::TAU;

/// AR(1) noise of marginal sd `sd` and coefficient `rho`, started stationary.
fn ar1(n: usize, rho: f64, sd: f64, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let innov = sd * (1.0 - rho * rho).sqrt();
    let mut e: f64 = sd * <StandardNormal as Distribution<f64>>::sample(&StandardNormal, rng);
    (0..n)
        .map(|_| {
            let out = e;
            let z: f64 = StandardNormal.sample(rng);
            e = rho * e + innov * z;
            out
        })
        .collect()
}

/// Regressors sin, cos, 1 of a 10 mHz rotation sampled at 16 Hz (Gaitan & Geist's (2022) run).
fn design(n: usize) -> DMatrix<f64> {
    DMatrix::from_fn(n, 3, |i, j| {
        let a = TAU * 0.01 * i as f64 / 16.0;
        [a.sin(), a.cos(), 1.0][j]
    })
}

fn ols(h: &DMatrix<f64>, y: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let yv = nalgebra::DVector::from_column_slice(y);
    let coef = (h.transpose() * h).try_inverse().unwrap() * h.transpose() * &yv;
    let resid = (&yv - h * &coef).as_slice().to_vec();
    (coef.as_slice().to_vec(), resid)
}

#[test]
fn ar1_parameters_are_recovered_from_residuals() {
    let n = 4200;
    let h = design(n);
    for (rho, seed) in [(0.0, 1u64), (0.3, 2), (0.6, 3), (0.9, 4)] {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let e = ar1(n, rho, 4.0, &mut rng);
        let y: Vec<f64> = (0..n)
            .map(|i| 1000.0 * h[(i, 0)] - 300.0 * h[(i, 1)] + 500.0 + e[i])
            .collect();
        let (_, resid) = ols(&h, &y);
        let (m, _) = NoiseModel::estimate(&resid, &[])
            .unwrap()
            .regression_cov(&h)
            .unwrap();
        let r1 = m.autocorrelation(1);
        // Bartlett: var(ρ̂₁) ≈ (1 − ρ²)/N for AR(1); ±4σ, plus the O(1/N) bias.
        let se = ((1.0 - rho * rho) / n as f64).sqrt();
        println!(
            "ρ = {rho}: ρ̂₁ = {r1:.4} (±4σ = {:.4}), sd = {:.3}, AR({}), factor {:.2}",
            4.0 * se,
            m.sd(),
            m.order(),
            m.variance_factor(0.0)
        );
        assert!((r1 - rho).abs() <= 4.0 * se + 2.0 / n as f64, "ρ̂₁ {r1}");
        // The sample variance of AR(1) noise has variance 2σ⁴(1 + ρ²)/(N(1 − ρ²)).
        let sd_se = 4.0 * ((1.0 + rho * rho) / (2.0 * n as f64 * (1.0 - rho * rho))).sqrt();
        assert!((m.sd() - 4.0).abs() <= 4.0 * sd_se, "sd {}", m.sd());
        if rho == 0.0 {
            assert_eq!(m.order(), 0, "white noise taken for correlated");
        }
    }
}

/// Coverage of k = 2 intervals for A, B and C over `trials` records, and the mean z².
fn coverage(rho: f64, trials: usize) -> ([f64; 3], [f64; 3]) {
    let n = 4200;
    let h = design(n);
    let truth = [40.0, -25.0, 3.0];
    let mut hit = [0usize; 3];
    let mut z2 = [0.0; 3];
    for t in 0..trials {
        let mut rng = ChaCha8Rng::seed_from_u64(0xC0FE_0000 + t as u64);
        let e = ar1(n, rho, 4.0, &mut rng);
        let y: Vec<f64> = (0..n)
            .map(|i| (0..3).map(|j| h[(i, j)] * truth[j]).sum::<f64>() + e[i])
            .collect();
        let (coef, resid) = ols(&h, &y);
        let (_, cov) = NoiseModel::estimate(&resid, &clipped(&y))
            .unwrap()
            .regression_cov(&h)
            .unwrap();
        for j in 0..3 {
            let z = (coef[j] - truth[j]) / cov[(j, j)].sqrt();
            z2[j] += z * z / trials as f64;
            if z.abs() <= 2.0 {
                hit[j] += 1;
            }
        }
    }
    (hit.map(|h| h as f64 / trials as f64), z2)
}

#[test]
fn fit_covariance_covers_under_correlated_noise() {
    let mut failures = Vec::new();
    for rho in [0.0, 0.3, 0.6, 0.9] {
        let (cov, z2) = coverage(rho, 1000);
        println!("AR(1) ρ = {rho}: coverage A, B, C {cov:.3?}; mean z² {z2:.3?}");
        for c in cov {
            if !(0.93..=0.97).contains(&c) {
                failures.push(format!("ρ = {rho}: coverage {c}"));
            }
        }
    }
    assert!(failures.is_empty(), "{failures:?}");
}

#[test]
fn clipped_samples_do_not_bias_the_level() {
    // A channel whose readings clip at a rail below the sine's peak: the readings on the
    // rail are not noise about the model, so counting them would misread the level. They
    // are found (at least three readings on the extreme value) and left out, and the level
    // is the true one within the statistical bound.
    let n = 4200;
    let h = design(n);
    let mut failures = Vec::new();
    for seed in 0..20u64 {
        let mut rng = ChaCha8Rng::seed_from_u64(0xC1_0000 + seed);
        let e = ar1(n, 0.0, 4.0, &mut rng);
        let y: Vec<f64> = (0..n)
            .map(|i| (400.0 * h[(i, 0)] + e[i]).round().min(380.0))
            .collect();
        let flags = clipped(&y);
        let left_out = flags.iter().filter(|f| **f).count();
        // Readings on the rail are not measurements of the model: the fit leaves them out
        // too (as the discrepancy workflow's saturation model does), and its residuals
        // elsewhere are noise.
        let keep: Vec<usize> = (0..n).filter(|&i| !flags[i]).collect();
        let hk = DMatrix::from_fn(keep.len(), 3, |i, j| h[(keep[i], j)]);
        let (coef, _) = ols(&hk, &keep.iter().map(|&i| y[i]).collect::<Vec<_>>());
        let resid: Vec<f64> = (0..n)
            .map(|i| y[i] - (0..3).map(|j| h[(i, j)] * coef[j]).sum::<f64>())
            .collect();
        let with = NoiseModel::estimate(&resid, &flags).unwrap();
        let all = NoiseModel::estimate(&resid, &[]).unwrap();
        assert_eq!(with.excluded, left_out);
        // sd of the sample sd: σ/√(2N); quantisation adds 1/12 count².
        let truth = (16.0f64 + 1.0 / 12.0).sqrt();
        let bound = 4.0 * truth / (2.0 * (n - left_out) as f64).sqrt();
        if seed == 0 {
            println!(
                "{left_out} readings on the rail left out: sd {:.3} (truth {truth:.3} ± {bound:.3}); with them {:.3}",
                with.sd(),
                all.sd()
            );
        }
        if left_out < 200 || (with.sd() - truth).abs() > bound {
            failures.push(format!(
                "seed {seed}: {left_out} left out, sd {}",
                with.sd()
            ));
        }
    }
    assert!(failures.is_empty(), "{failures:?}");
}

#[test]
fn calibrate_leaves_a_clipping_channel_out_of_its_noise() {
    // u's peaks (525 + 16 361 counts) clip at 16 880 in the conditions where u sees all of
    // gravity; v and w stay below the rail. calibrate finds the rail, leaves those readings
    // out of the noise fit and estimate, and reads u's level as the others'.
    use rotacal::calibrate::{calibrate, Options};
    use rotacal::simulate::{Config, Simulation};
    let mut cfg = Config::from_toml(
        "preset = \"paper-10mhz\"\n[effects.saturation]\nrails = [-40000.0, 16880.0]\n",
    )
    .unwrap();
    cfg.sensor.noise = crate::common::unstated(None, None);
    let rec = Simulation::new(cfg).unwrap().recording().unwrap();
    let cal = calibrate(&rec, &Options::default()).unwrap();
    let noise = cal.by_rate[0].noise.as_ref().unwrap();
    // White noise of 4.173 counts quantised to whole counts: 4.183; the sd of a sample sd
    // of N readings is σ/√(2N).
    let truth = (4.173_089f64.powi(2) + 1.0 / 12.0).sqrt();
    let mut clipped = 0;
    for n in noise {
        let bound = 4.0 * truth / (2.0 * (n.n - n.n_excluded) as f64).sqrt();
        println!(
            "{} {}: sd {:.3} (truth {truth:.3} ± {bound:.3}), {} on a rail",
            n.condition, n.channel, n.sd, n.n_excluded
        );
        assert!(
            (n.sd - truth).abs() <= bound,
            "{} {}: {}",
            n.condition,
            n.channel,
            n.sd
        );
        if n.channel == Channel::U && n.condition != Condition::X {
            clipped += n.n_excluded;
        }
    }
    assert!(clipped > 50, "{clipped} of u's readings on the rail");
}
