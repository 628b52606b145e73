//! The slow-noise estimator's tests, and the simulated residuals the model check's tests
//! share.
#![allow(clippy::indexing_slicing)]

use super::*;

/// A 10 mHz sine at 16 Hz over `n` samples, with an offset, a trend and harmonics 2–4:
/// the widened fit of a rotation group.
fn tests_wide(n: usize) -> DMatrix<f64> {
    tests_wide_at(n, 0.01 / 16.0)
}

/// [`tests_wide`] at `turns_per_row`.
pub(in crate::fit::noise) fn tests_wide_at(n: usize, turns_per_row: f64) -> DMatrix<f64> {
    DMatrix::from_fn(n, 10, |t, j| {
        let a = std::f64::consts::TAU * turns_per_row * t as f64;
        match j {
            0 => a.sin(),
            1 => a.cos(),
            2 => 1.0,
            3 => t as f64 / n as f64 - 0.5,
            _ => {
                let k = ((j - 4) / 2 + 2) as f64;
                if j % 2 == 0 {
                    (k * a).sin()
                } else {
                    (k * a).cos()
                }
            }
        }
    })
}

/// White noise plus a walk (or flicker) through the widened fit: the residuals.
pub(in crate::fit::noise) fn tests_residuals(
    d: &SlowDesign,
    (white_var, flicker_q, walk_q): (f64, f64, f64),
    gen: &FlickerIncrements,
    rng: &mut ChaCha8Rng,
) -> Vec<f64> {
    let n = d.hw().nrows();
    let white = NoiseModel::white(white_var, n);
    let mut e = draw_ar(&white, 1.0, n, rng);
    let inc = gen.draw(rng);
    let (mut fl, mut rw) = (0.0, 0.0);
    for (x, dq) in e.iter_mut().skip(1).zip(&inc) {
        fl += flicker_q.sqrt() * dq;
        rw += walk_q.sqrt() * rng.sample::<f64, _>(StandardNormal);
        *x += fl + rw;
    }
    let ev = DVector::from_vec(e);
    let beta = d.gram_inv() * d.hw().tr_mul(&ev);
    (ev - d.hw() * beta).as_slice().to_vec()
}

/// Mean and standard error of the mean.
fn mean_se(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

/// The exact expectations of the statistics against the mean of simulated ones, term by
/// term: white, flicker, walk (4 standard errors of the mean, per averaging length).
#[test]
fn expected_statistics_match_simulated_ones() {
    let n = 2000;
    let d = SlowDesign::new(&tests_wide(n), &vec![1.0; n]).unwrap();
    let white = NoiseModel::white(4.0, n);
    let gamma: Vec<f64> = std::iter::once(4.0)
        .chain(std::iter::repeat_n(0.0, n - 1))
        .collect();
    let gen = FlickerIncrements::new(n - 1);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let walk: Vec<f64> = d.expected_slow[1].iter().map(|v| v * 0.01).collect();
    let cases: [(&str, f64, f64, f64, Vec<f64>); 3] = [
        ("white", 1.0, 0.0, 0.0, d.expected_ar(&white, &gamma)),
        ("flicker", 1e-9, 1.0, 0.0, d.expected_slow[0].clone()),
        ("walk", 1e-9, 0.0, 0.01, walk),
    ];
    for (name, scale, fq, wq, expected) in cases {
        let draws: Vec<Vec<f64>> = (0..400)
            .filter_map(|_| {
                d.draw_residuals((&white, scale), &[(fq, wq)], &gen, &mut rng)
                    .pop()
                    .map(|r| d.statistics(&r))
            })
            .collect();
        for (i, e) in expected.iter().enumerate() {
            let v: Vec<f64> = draws.iter().map(|s| s[i]).collect();
            let (mean, se) = mean_se(&v);
            let z = (mean - e) / se;
            assert!(
                z.abs() < 4.0,
                "{name} m = {}: simulated {mean:e}, expected {e:e}, z = {z:.1}",
                d.octaves[i].m
            );
        }
    }
}

/// The sine amplitude's variance under unit flicker and unit walk, W̃ᵀ(WTW)W̃, against
/// 3000 simulated records (the variance's relative standard error √(2/3000) = 2.6 %;
/// bound 4 of them).
/// The standalone flicker quadratic is the design's, bit for bit, on a line's change.
/// The residual Allan check's expectation, AR(1) ρ = 0.6 plus flicker through the
/// widened fit, against the mean of simulated residuals' statistics (4 standard errors
/// of the mean per averaging length); and the AR model's autocovariances, all at once,
/// against its recursion one lag at a time.
#[test]
fn residual_allan_expectation_matches_simulated_residuals() {
    let n = 2000;
    let d = SlowDesign::new(&tests_wide(n), &vec![1.0; n]).unwrap();
    let ar = NoiseModel::from_autocovariances(&[4.0, 2.4], n, n).unwrap();
    assert_eq!(ar.order(), 1);
    let gamma = ar.autocovariances(n);
    for k in [0, 1, 2, 7, 100, n - 1] {
        let want = ar.var * ar.autocorrelation(k);
        assert!((gamma[k] - want).abs() <= 1e-12 * ar.var, "lag {k}");
    }
    let (fq, wq) = (0.5, 0.0);
    let gen = FlickerIncrements::new(n - 1);
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let draws: Vec<Vec<ResidualAllan>> = (0..400)
        .filter_map(|_| {
            d.draw_residuals((&ar, 1.0), &[(fq, wq)], &gen, &mut rng)
                .pop()
                .map(|r| d.residual_allan(&r, &ar, [fq, wq]))
        })
        .collect();
    let first = &draws[0];
    assert_eq!(first.len(), d.octaves.len());
    for (i, point) in first.iter().enumerate() {
        let v: Vec<f64> = draws.iter().map(|s| s[i].observed).collect();
        let (mean, se) = mean_se(&v);
        let z = (mean - point.expected()) / se;
        assert!(
            z.abs() < 4.0,
            "m = {}: simulated {mean:e}, expected {:e}, z = {z:.1}",
            point.m,
            point.expected()
        );
        assert_eq!(point.walk, 0.0);
        assert!(point.short_range > 0.0 && point.flicker > 0.0);
    }
    // The AR part dominates the shortest averaging, the flicker the longest.
    let (short, long) = (&first[0], &first[first.len() - 1]);
    assert!(short.short_range > short.flicker && long.flicker > long.short_range);
}

#[test]
fn unit_flicker_quadratic_is_the_designs() {
    let n = 300;
    let h = DMatrix::from_fn(n, 2, |t, j| if j == 0 { 1.0 } else { t as f64 / n as f64 });
    let est = &h * h.tr_mul(&h).try_inverse().unwrap();
    let x: DVector<f64> = est.column(1).into_owned();
    let design = SlowDesign::new(&h, &vec![1.0; n]).unwrap();
    assert_eq!(unit_flicker_quadratic(&x), design.slow_quadratic(&x)[0]);
}

#[test]
fn slow_forms_across_a_gap_match_simulated_noise() {
    // Two stretches of 200 rows with 200 unrecorded between them; the estimator is a
    // slope within each stretch plus the difference of their means: a contrast whose
    // variance needs the slow noise across the gap.
    let n = 600;
    let x = DMatrix::from_fn(n, 2, |t, j| {
        let within = (t % 400) as f64 / 200.0 - 0.5;
        match (t < 200, t >= 400, j) {
            (true, _, 0) => within + 0.5 / 200.0,
            (_, true, 0) => within + 0.5 / 200.0,
            (true, _, _) => -1.0 / 200.0,
            (_, true, _) => 1.0 / 200.0,
            _ => 0.0,
        }
    });
    let [fl, rw] = SlowForms::new(n).of(&x);
    let gen = FlickerIncrements::new(n - 1);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let reps = 3000;
    let mut draws = [Vec::new(), Vec::new()];
    for _ in 0..reps {
        let inc = gen.draw(&mut rng);
        let (mut f, mut w) = (DVector::zeros(n), DVector::zeros(n));
        let (mut a, mut b) = (0.0, 0.0);
        for t in 1..n {
            a += inc[t - 1];
            b += rng.sample::<f64, _>(StandardNormal);
            f[t] = a;
            w[t] = b;
        }
        draws[0].push(x.tr_mul(&f));
        draws[1].push(x.tr_mul(&w));
    }
    for (exact, d) in [fl, rw].iter().zip(&draws) {
        for i in 0..2 {
            let var = d.iter().map(|v| v[i] * v[i]).sum::<f64>() / reps as f64;
            let rel = var / exact[(i, i)] - 1.0;
            assert!(rel.abs() < 4.0 * (2.0 / reps as f64).sqrt(), "{i}: {rel}");
        }
        let cov = d.iter().map(|v| v[0] * v[1]).sum::<f64>() / reps as f64;
        let scale = (exact[(0, 0)] * exact[(1, 1)]).sqrt();
        assert!((cov - exact[(0, 1)]).abs() < 4.0 * scale / (reps as f64).sqrt());
    }
}

#[test]
fn slow_covariances_match_simulated_fits() {
    let n = 4200;
    let wide = tests_wide(n);
    let d = SlowDesign::new(&wide, &vec![1.0; n]).unwrap();
    let h = wide.columns(0, 3).into_owned();
    let [fl, rw] = d.slow_covariances(&h).unwrap();
    let inv = h.tr_mul(&h).try_inverse().unwrap();
    let gen = FlickerIncrements::new(n - 1);
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let reps = 3000;
    let (mut a_fl, mut a_rw) = (Vec::new(), Vec::new());
    for _ in 0..reps {
        let inc = gen.draw(&mut rng);
        let (mut e_fl, mut e_rw) = (vec![0.0; n], vec![0.0; n]);
        let (mut x, mut y) = (0.0, 0.0);
        for ((f, w), dq) in e_fl.iter_mut().zip(e_rw.iter_mut()).skip(1).zip(&inc) {
            x += dq;
            y += rng.sample::<f64, _>(StandardNormal);
            *f = x;
            *w = y;
        }
        a_fl.push((&inv * h.tr_mul(&DVector::from_vec(e_fl)))[0]);
        a_rw.push((&inv * h.tr_mul(&DVector::from_vec(e_rw)))[0]);
    }
    for (name, v, predicted) in [("flicker", a_fl, fl[(0, 0)]), ("walk", a_rw, rw[(0, 0)])] {
        let (mean, _) = mean_se(&v);
        let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (reps - 1) as f64;
        let rel = var / predicted - 1.0;
        assert!(
            rel.abs() < 4.0 * (2.0 / reps as f64).sqrt(),
            "{name}: simulated var A {var:e}, predicted {predicted:e}"
        );
    }
}

/// The pooled estimate over three groups is unbiased for the walk and for flicker
/// (mean over 60 records of three groups each within 4 standard errors of the truth),
/// the short-range noise's AR model estimated from the same residuals as `calibrate`
/// does.
#[test]
fn pooled_levels_are_unbiased() {
    let name = "fit::noise::slow::tests::pooled_levels_are_unbiased";
    let n = 4200;
    let d = SlowDesign::new(&tests_wide(n), &vec![1.0; n]).unwrap();
    let gen = FlickerIncrements::new(n - 1);
    for (case, truth, stream) in [
        ("walk", (16.0, 0.0, 0.0017), 0u64),
        ("flicker", (16.0, 1.0, 0.0), 1),
    ] {
        let trial = |t: usize| {
            let mut rng = ChaCha8Rng::seed_from_u64(9 + (stream << 32) + t as u64);
            let resids: Vec<Vec<f64>> = (0..3)
                .map(|_| tests_residuals(&d, truth, &gen, &mut rng))
                .collect();
            let models: Vec<NoiseModel> = resids
                .iter()
                .map(|r| {
                    NoiseModel::estimate(r, &[])
                        .unwrap()
                        .rescaled(d.hw())
                        .unwrap()
                })
                .collect();
            let parts: Vec<SlowPart> = resids
                .iter()
                .zip(&models)
                .map(|(r, m)| SlowPart {
                    design: &d,
                    resid: r,
                    ar: m,
                })
                .collect();
            let fit = &estimate_pooled(&parts, 0).unwrap().unwrap()[0].0;
            (fit.theta[1], fit.theta[2])
        };
        rotacal_proof::prove(&format!("{name}#{case}"), 60, trial, |est| {
            let q: Vec<f64> = est.iter().map(|e| e.0).collect();
            let w: Vec<f64> = est.iter().map(|e| e.1).collect();
            let mut failures = Vec::new();
            for (what, v, t) in [("Q", &q, truth.1), ("q", &w, truth.2)] {
                let (mean, se) = mean_se(v);
                println!("{case}: {what} mean {mean:e} ± {se:e}, truth {t:e}");
                if (mean - t).abs() >= 4.0 * se {
                    failures.push(format!(
                        "{case}: {what} mean {mean:e} ± {se:e}, truth {t:e}"
                    ));
                }
            }
            failures
        });
    }
}
