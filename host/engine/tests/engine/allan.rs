//! `allan`: the overlapping Allan deviation, its intervals and the terms fit.
//! Golden values from allantools 2024.06 (tests/data/allan/README.md).

use std::path::{Path, PathBuf};

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use rotacal_engine::allan::{self, TermKind};

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/allan")
}

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs()
}

/// oadev, the noise id, the EDF and the 1σ interval against allantools' own outputs.
#[test]
fn allan_golden_matches_allantools() {
    let golden: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir().join("golden.json")).unwrap()).unwrap();
    let (mut worst_dev, mut worst_edf, mut worst_ci) = (0.0f64, 0.0f64, 0.0f64);
    for set in golden["sets"].as_array().unwrap() {
        let name = set["name"].as_str().unwrap();
        let rate = set["rate_hz"].as_f64().unwrap();
        let y: Vec<f64> = std::fs::read_to_string(dir().join(format!("{name}.txt")))
            .unwrap()
            .lines()
            .map(|l| l.trim().parse().unwrap())
            .collect();
        assert_eq!(y.len() as u64, set["len"].as_u64().unwrap());
        let pts = allan::oadev(&y, rate, None, true).unwrap();
        let rows = set["rows"].as_array().unwrap();
        assert_eq!(pts.len(), rows.len(), "{name}: number of taus");
        for (p, r) in pts.iter().zip(rows) {
            assert_eq!(p.m as u64, r["m"].as_u64().unwrap(), "{name}");
            assert_eq!(p.n as u64, r["n"].as_u64().unwrap(), "{name} m={}", p.m);
            assert!(rel(p.tau_s, r["tau_s"].as_f64().unwrap()) < 1e-15);
            let e = rel(p.adev, r["adev"].as_f64().unwrap());
            assert!(e < 1e-12, "{name} m={}: adev rel err {e:e}", p.m);
            worst_dev = worst_dev.max(e);
            match (&p.interval, r["alpha"].as_i64()) {
                (None, None) => {}
                (Some(i), Some(alpha)) => {
                    assert_eq!(i64::from(i.alpha), alpha, "{name} m={}: alpha", p.m);
                    let e = rel(i.edf, r["edf"].as_f64().unwrap());
                    assert!(e < 1e-9, "{name} m={}: edf rel err {e:e}", p.m);
                    worst_edf = worst_edf.max(e);
                    for (got, key) in [(i.lo, "lo"), (i.hi, "hi")] {
                        let e = rel(got, r[key].as_f64().unwrap());
                        assert!(e < 1e-9, "{name} m={}: {key} rel err {e:e}", p.m);
                        worst_ci = worst_ci.max(e);
                    }
                }
                (got, want) => panic!("{name} m={}: interval {got:?}, allantools {want:?}", p.m),
            }
        }
        // An explicit list of factors (allantools: taus = m/rate).
        let explicit = set["explicit"].as_array().unwrap();
        let ms: Vec<usize> = explicit
            .iter()
            .map(|r| r["m"].as_u64().unwrap() as usize)
            .collect();
        let pts = allan::oadev(&y, rate, Some(&ms), false).unwrap();
        assert_eq!(pts.len(), explicit.len(), "{name}: explicit factors");
        for (p, r) in pts.iter().zip(explicit) {
            assert_eq!(p.n as u64, r["n"].as_u64().unwrap(), "{name} m={}", p.m);
            let e = rel(p.adev, r["adev"].as_f64().unwrap());
            assert!(e < 1e-12, "{name} m={}: adev rel err {e:e}", p.m);
            worst_dev = worst_dev.max(e);
        }
    }
    eprintln!("worst rel err: adev {worst_dev:e}, edf {worst_edf:e}, interval {worst_ci:e}");
}

/// The χ² quantiles against scipy's to 1e-10 relative, edf 1.3 … 10⁶,
/// and the golden intervals' own edf values (statrs alone is off by 1e-3 at edf 298).
#[test]
fn allan_chi2_quantile_matches_scipy() {
    let golden: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir().join("golden.json")).unwrap()).unwrap();
    let mut worst = 0.0f64;
    let mut worst_statrs = 0.0f64;
    for q in golden["chi2"].as_array().unwrap() {
        let (edf, p, x) = (
            q["edf"].as_f64().unwrap(),
            q["p"].as_f64().unwrap(),
            q["x"].as_f64().unwrap(),
        );
        let got = allan::chi2_quantile(p, edf).unwrap();
        let e = rel(got, x);
        assert!(e < 1e-10, "edf {edf} p {p}: rel err {e:e}");
        worst = worst.max(e);
        use statrs::distribution::ContinuousCDF;
        let raw = statrs::distribution::ChiSquared::new(edf)
            .unwrap()
            .inverse_cdf(p);
        worst_statrs = worst_statrs.max(rel(raw, x));
    }
    eprintln!("chi2 worst rel err {worst:e} (statrs inverse_cdf alone: {worst_statrs:e})");
}

/// The exact flicker Allan variance against its ratios to the plateau 2 ln2·Q/π.
#[test]
fn allan_flicker_expected_avar() {
    let plateau = 2.0 * std::f64::consts::LN_2 / std::f64::consts::PI;
    for (m, ratio) in [
        (1, 1.443),
        (2, 1.154),
        (4, 1.050),
        (8, 1.015),
        (16, 1.0046),
        (64, 1.0004),
    ] {
        let r = allan::expected_avar(TermKind::Flicker, m) / plateau;
        assert!((r - ratio).abs() < 6e-4, "m={m}: {r}");
    }
    // m = 1: AVAR = D(1)/2 = 2Q/π exactly.
    assert!(
        rel(
            allan::expected_avar(TermKind::Flicker, 1),
            2.0 / std::f64::consts::PI
        ) < 1e-15
    );
}

/// White + Kasdin–Walter flicker + random walk, θ = (σ_s², Q, q), seeded.
fn known_noise(n_samples: usize, theta: [f64; 3], seed: u64) -> Vec<f64> {
    let [white_var, q_fl, q_rw] = theta;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let std = Normal::new(0.0, 1.0).unwrap();
    let mut draw = |n: usize| -> Vec<f64> { (0..n).map(|_| std.sample(&mut rng)).collect() };
    // Flicker: y = (1 − B)^(−1/2) w, Kasdin & Walter 1992's filter h_k = h_{k−1}(k − ½)/k,
    // convolved directly (allantools noise_kasdin does the same by FFT). It starts at
    // rest, which lowers the largest-τ AVAR by ~1 % (docs/simulator.md, "Slow noise"): well inside the SEs.
    let w = draw(n_samples);
    let mut h = vec![1.0f64; n_samples];
    for k in 1..n_samples {
        h[k] = h[k - 1] * (k as f64 - 0.5) / k as f64;
    }
    let sq = q_fl.sqrt();
    let flicker: Vec<f64> = (0..n_samples)
        .map(|n| sq * (0..=n).map(|k| h[k] * w[n - k]).sum::<f64>())
        .collect();
    let white = draw(n_samples);
    let steps = draw(n_samples);
    let mut walk = 0.0;
    (0..n_samples)
        .map(|i| {
            walk += q_rw.sqrt() * steps[i];
            white_var.sqrt() * white[i] + flicker[i] + walk
        })
        .collect()
}

/// White + flicker + random walk with known parameters: the fit recovers each within 4
/// standard errors (fixed seed), and the IEEE forms follow from θ.
#[test]
fn allan_terms_recover_known_noise() {
    const N: usize = 16384;
    let rate_hz = 100.0;
    let theta = [100.0, 100.0, 0.1];
    let y = known_noise(N, theta, 30);
    let pts = allan::oadev(&y, rate_hz, None, true).unwrap();
    let fit = allan::fit_terms(&pts, N, rate_hz).unwrap();
    for (t, truth) in fit.terms.iter().zip(theta) {
        let se = t.theta_se_u2.expect("every term resolved");
        let z = (t.theta_u2 - truth) / se;
        eprintln!(
            "{:?}: {} ± {se} (truth {truth}, z = {z:.2})",
            t.kind, t.theta_u2
        );
        assert!(z.abs() < 4.0, "{:?}: z = {z}", t.kind);
        // Each term is resolved: its SE is below its true value.
        assert!(se < truth, "{:?}: SE {se} not informative", t.kind);
    }
    // IEEE forms: N = √(σ²/fs), B = √Q, K = √(q·fs), floor = 0.6643·B.
    let [n, b, k] = [&fit.terms[0], &fit.terms[1], &fit.terms[2]];
    assert!(rel(n.ieee, (n.theta_u2 / rate_hz).sqrt()) < 1e-14);
    assert!(rel(b.ieee, b.theta_u2.sqrt()) < 1e-14);
    assert!(rel(k.ieee, (k.theta_u2 * rate_hz).sqrt()) < 1e-14);
    assert!(rel(fit.flicker_floor, 0.664_282_154_3 * b.ieee) < 1e-9);
}

/// The standard errors hold: over 24 records of white + flicker + random walk with known θ,
/// each term's mean z² (z = (θ̂ − θ)/SE) lies in the two-sided χ²_n/n band at
/// p = 0.0005 a side. The weighted fit's own covariance failed this (its z spread was 1.25,
/// 1.40 and 1.82: mean z² about 1.6, 2.0 and 3.3); a SE overstated twice over fails too.
#[test]
fn allan_terms_standard_errors_hold_over_seeds() {
    const N: usize = 4096;
    let theta = [100.0, 100.0, 0.2];
    let mut zs = vec![vec![]; 3];
    for seed in 0..24 {
        let y = known_noise(N, theta, 1000 + seed);
        let pts = allan::oadev(&y, 100.0, None, true).unwrap();
        let fit = allan::fit_terms(&pts, N, 100.0).unwrap();
        for ((t, truth), z) in fit.terms.iter().zip(theta).zip(&mut zs) {
            if let Some(se) = t.theta_se_u2 {
                z.push((t.theta_u2 - truth) / se);
            }
        }
    }
    for (z, kind) in zs.iter().zip(["white", "flicker", "random walk"]) {
        let n = z.len() as f64;
        assert!(n >= 20.0, "{kind}: resolved in {n} of 24");
        let mean_z2 = z.iter().map(|v| v * v).sum::<f64>() / n;
        let (lo, hi) = (
            allan::chi2_quantile(0.0005, n).unwrap() / n,
            allan::chi2_quantile(0.9995, n).unwrap() / n,
        );
        eprintln!("{kind}: {n} resolved, mean z² {mean_z2:.2} (band {lo:.2}–{hi:.2})");
        assert!((lo..=hi).contains(&mean_z2), "{kind}: mean z² {mean_z2}");
    }
}
