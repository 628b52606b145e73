//! The uncertainty budget's arithmetic (`calibrate::budget`, GUM): sources combined in
//! quadrature, Welch–Satterthwaite degrees of freedom on cases worked by hand, the coverage
//! factor from Student's t, and a static calibration's budget against its pose fit.
//!
//! Student's t quantiles below are tabulated (mpmath), not computed by the code under test.
// Per-property index loops read more plainly over parallel lists.
#![allow(clippy::needless_range_loop)]

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use rotacal_engine::calibrate::budget::{
    coverage_factor, coverage_factor_normal_variance, welch_satterthwaite, Budget, Kind,
};
use rotacal_engine::calibrate::methods::from_poses;
use rotacal_engine::calibrate::poses::{Options, Pose};
use rotacal_engine::calibrate::{static_budget, TypeB};

/// t₀.₉₇₅(ν): the two-sided 95 % quantile of Student's t.
const T975: [(f64, f64); 10] = [
    (1.0, 12.706_204_736_174_7),
    (2.0, 4.302_652_729_749_46),
    (3.0, 3.182_446_305_283_71),
    (4.0, 2.776_445_105_197_79),
    (5.0, 2.570_581_835_636_31),
    (10.0, 2.228_138_851_986_27),
    (12.0, 2.178_812_829_667_23),
    (22.0, 2.073_873_067_904_03),
    (30.0, 2.042_272_456_301_24),
    (60.0, 2.000_297_822_014_26),
];

fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * b.abs()
}

#[test]
fn coverage_factor_is_students_t_and_at_least_two() {
    for (nu, t) in T975 {
        let k = coverage_factor(nu);
        assert!(close(k, t, 1e-9), "ν = {nu}: k = {k}, t = {t}");
    }
    // t₀.₉₇₅(61) = 1.99962 and t₀.₉₇₅(100) = 1.98397 are below 2: k = 2, the convention
    // of every result here; so is infinitely many degrees of freedom.
    for nu in [61.0, 100.0, 1e4, 1e7, f64::INFINITY] {
        assert_eq!(coverage_factor(nu), 2.0, "ν = {nu}");
    }
    // Between tabulated points it lies between their quantiles (and falls with ν).
    let k = coverage_factor(12.5);
    assert!(k < 2.178_812_829_667_23 && k > 2.160_368_656_462_79, "{k}");
}

/// The coverage factor for a normal variance estimate does what it says: drawn by Monte
/// Carlo (not by the code's own integral), an error N(0, 1) lies within k·√(1 + δ), δ ~
/// N(0, 2/ν) with V̂ = 1 + δ ≥ 0 (redrawn below), in 95 % of 400 000 draws (±4 binomial σ,
/// ±0.0014). It exceeds Student's t where ν is small (a lower tail heavier than χ²'s needs
/// more), comes within 1 % of it at ν = 60, and is 2 for infinitely many degrees of freedom.
#[test]
fn normal_variance_coverage_factor_covers_95_percent() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x4E0F);
    let unit = Normal::new(0.0, 1.0).unwrap();
    for nu in [6.0, 9.0, 15.0, 40.0] {
        let k = coverage_factor_normal_variance(nu);
        let sd = (2.0f64 / nu).sqrt();
        let draws = 400_000;
        let mut covered = 0u32;
        for _ in 0..draws {
            let v = loop {
                let v = 1.0 + sd * unit.sample(&mut rng);
                if v >= 0.0 {
                    break v;
                }
            };
            let z: f64 = unit.sample(&mut rng);
            covered += u32::from(z.abs() <= k * v.sqrt());
        }
        let frac = f64::from(covered) / f64::from(draws);
        let sigma = (0.95f64 * 0.05 / f64::from(draws)).sqrt();
        assert!(
            (frac - 0.95).abs() <= 4.0 * sigma,
            "ν = {nu}: k = {k}, covered {frac}"
        );
        assert!(k > coverage_factor(nu), "ν = {nu}: {k} ≤ t");
    }
    let k60 = coverage_factor_normal_variance(60.0);
    assert!(close(k60, 2.000_297_822_014_26, 0.01), "{k60}");
    assert_eq!(coverage_factor_normal_variance(f64::INFINITY), 2.0);
    assert_eq!(coverage_factor_normal_variance(0.0), 2.0);
}

#[test]
fn welch_satterthwaite_is_var_squared_over_the_sum() {
    // Two equal contributions of 5 degrees of freedom each: ν = 2² / (1/5 + 1/5) = 10.
    assert!(close(welch_satterthwaite(2.0, 0.4), 10.0, 1e-15));
    // Nothing with finite degrees of freedom: infinitely many.
    assert_eq!(welch_satterthwaite(2.0, 0.0), f64::INFINITY);
}

/// A budget of three properties, built from every kind of source.
fn three_properties() -> Budget {
    let units = ["V".to_string(), "V".to_string(), "deg".to_string()];
    let mut b = Budget::new(&["a", "b", "c"], &units);
    // One input of u = 0.5 with sensitivities 2, −3, 0: contributions 1, 1.5, 0, type B.
    b.scalar(
        "scalar",
        Kind::B,
        "type B",
        (0.5, "m/s^2"),
        &[2.0, -3.0, 0.0],
        None,
    );
    // The same with 3 degrees of freedom.
    b.scalar(
        "scalar_a",
        Kind::A,
        "type A",
        (1.0, "V"),
        &[1.0, 0.0, 0.0],
        Some(3.0),
    );
    b.vector(
        "fits",
        Kind::A,
        "a vector input",
        &[0.0, 4.0, 0.1],
        &[Some(5.0), Some(9.0), None],
    );
    b.combine();
    b
}

#[test]
fn combined_uncertainty_is_the_root_sum_square_of_contributions() {
    let b = three_properties();
    let scalar = b.source("scalar").unwrap();
    assert_eq!(scalar.contribution, [1.0, 1.5, 0.0]);
    assert_eq!(scalar.sensitivity, [Some(2.0), Some(-3.0), Some(0.0)]);
    assert_eq!(scalar.dof, [None, None, None]);
    assert_eq!(b.source("fits").unwrap().sensitivity, [None, None, None]);
    assert!(b.source("none").is_none());
    // By hand: a = √(1 + 1) (1 from each scalar), b = √(1.5² + 4²) = √18.25, c = 0.1.
    let want = [2f64.sqrt(), 18.25f64.sqrt(), 0.1];
    for i in 0..3 {
        let c = &b.combined[i];
        assert_eq!(c.quantity, ["a", "b", "c"][i]);
        assert!(
            close(c.std_unc, want[i], 1e-15),
            "{}: {}",
            c.quantity,
            c.std_unc
        );
        assert!(close(c.expanded_unc, c.k * c.std_unc, 1e-15));
    }
    // The largest contribution names the dominant source (the first of equals).
    let dominant: Vec<&str> = b.combined.iter().map(|c| c.dominant.as_str()).collect();
    assert_eq!(dominant, ["scalar", "fits", "fits"]);
}

#[test]
fn effective_degrees_of_freedom_and_k_by_hand() {
    let b = three_properties();
    // a: 1 (type B, ν ∞) and 1 (ν 3): ν = 2² / (1⁴/3) = 12, k = t(12).
    let a = &b.combined[0];
    assert!(close(a.nu_eff.unwrap(), 12.0, 1e-14), "{:?}", a.nu_eff);
    assert!(close(a.k, 2.178_812_829_667_23, 1e-9), "{}", a.k);
    // b: 1.5 (ν ∞) and 4 (ν 9): ν = 18.25² / (4⁴/9) = 333.0625 · 9 / 256 = 11.709…, k
    // between t(11) and t(12).
    let bq = &b.combined[1];
    let nu = 18.25f64.powi(2) * 9.0 / 256.0;
    assert!(close(bq.nu_eff.unwrap(), nu, 1e-14), "{:?}", bq.nu_eff);
    assert!(
        bq.k > 2.178_812_829_667_23 && bq.k < 2.200_985_160_082_95,
        "{}",
        bq.k
    );
    // c: only an infinite-ν source: ν infinite (null in the JSON), k = 2.
    let c = &b.combined[2];
    assert_eq!(c.nu_eff, None);
    assert_eq!(c.k, 2.0);
    // Two type-A sources, 3 (ν 4) and 4 (ν 9): u_c = 5 and ν = 5⁴ / (3⁴/4 + 4⁴/9) =
    // 22500/1753 = 12.835…
    let mut h = Budget::new(&["q"], &["V".to_string()]);
    h.vector("one", Kind::A, "", &[3.0], &[Some(4.0)]);
    h.vector("two", Kind::A, "", &[4.0], &[Some(9.0)]);
    h.combine();
    let q = &h.combined[0];
    assert!(close(q.std_unc, 5.0, 1e-15));
    assert!(
        close(q.nu_eff.unwrap(), 22500.0 / 1753.0, 1e-14),
        "{:?}",
        q.nu_eff
    );
    // t₀.₉₇₅(22500/1753), tabulated.
    assert!(close(q.k, 2.163_192_792_356_24, 1e-9), "{}", q.k);
    assert!(close(q.expanded_unc, 5.0 * 2.163_192_792_356_24, 1e-9));
}

/// A static calibration's budget: its `poses` line is the pose fit's own uncertainty, its
/// g_loc line moves only the sensitivities (by s·u_g/g), and each property combines the
/// two in quadrature.
#[test]
fn a_static_budget_against_its_pose_fit() {
    let g = 9.80665;
    let s = [
        [1.002, 0.004, -0.003],
        [-0.002, 0.998, 0.006],
        [0.005, -0.001, 1.011],
    ];
    let o = [0.2, -0.1, 0.05];
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    let noise = Normal::new(0.0, 0.01).unwrap();
    let mut dirs = vec![
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, -1.0],
    ];
    let r = 3f64.sqrt().recip();
    dirs.extend([[r, r, r], [-r, -r, -r], [r, -r, r], [-r, r, -r]]);
    let poses: Vec<Pose> = dirs
        .iter()
        .enumerate()
        .map(|(p, d)| {
            let n = 100;
            let rows: Vec<[f64; 3]> = (0..n)
                .map(|_| {
                    std::array::from_fn(|j| {
                        g * (0..3).map(|k| s[j][k] * d[k]).sum::<f64>()
                            + o[j]
                            + noise.sample(&mut rng)
                    })
                })
                .collect();
            let mean: [f64; 3] =
                std::array::from_fn(|j| rows.iter().map(|r| r[j]).sum::<f64>() / n as f64);
            let std = std::array::from_fn(|j| {
                (rows.iter().map(|r| (r[j] - mean[j]).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt()
            });
            Pose {
                name: format!("p{p}"),
                gravity: *d,
                n,
                mean,
                std: Some(std),
                first_line: 0,
                noise: None,
                angle_direction: None,
                times_s: Vec::new(),
            }
        })
        .collect();
    let cal = from_poses(poses, g, Options::default()).unwrap();
    let u_g = 2e-4;
    let inputs = TypeB {
        u_g_loc: Some(u_g),
        ..TypeB::default()
    };
    let b = static_budget(&cal, g, &inputs, "m/s^2").unwrap();
    assert_eq!(
        b.quantities,
        ["s_u", "s_v", "s_w", "φ_uv", "φ_vw", "φ_wu", "O_u", "O_v", "O_w"]
    );
    let poses_line = b.source("poses").unwrap();
    let g_line = b.source("g_loc").unwrap();
    assert_eq!((poses_line.kind, g_line.kind), (Kind::A, Kind::B));
    assert_eq!(g_line.std_unc, Some(u_g));
    for i in 0..9 {
        let c = &b.combined[i];
        // Quadrature of the two lines, and k from Welch–Satterthwaite over them.
        let (p, gl) = (poses_line.contribution[i], g_line.contribution[i]);
        assert!(close(c.std_unc, p.hypot(gl), 1e-14), "{}", c.quantity);
        let nu = poses_line.dof[i].unwrap_or(f64::INFINITY);
        let nu_eff = (p * p + gl * gl).powi(2) / (p.powi(4) / nu);
        assert!(close(c.nu_eff.unwrap_or(f64::INFINITY), nu_eff, 1e-12));
        assert!(close(c.k, coverage_factor(nu_eff), 1e-15));
        if i < 3 {
            // s ∝ 1/g: u(s) = s·u_g/g, sensitivity −s/g.
            let sv = cal.intrinsic.sensitivity[i].value;
            assert!(close(gl, sv * u_g / g, 1e-14));
            assert!(close(g_line.sensitivity[i].unwrap(), -sv / g, 1e-14));
        } else {
            assert_eq!(gl, 0.0, "{}", c.quantity);
        }
    }
    // The offsets' line is the pose fit's offset uncertainty.
    for j in 0..3 {
        assert!(close(
            poses_line.contribution[6 + j],
            cal.offsets[j].std_unc,
            1e-12
        ));
    }
    // Without u_g_loc the line stays, at zero, and the budget says so.
    let b0 = static_budget(&cal, g, &TypeB::default(), "m/s^2").unwrap();
    assert_eq!(b0.source("g_loc").unwrap().contribution, [0.0; 9]);
    assert_eq!(b0.notes.len(), 1, "{:?}", b0.notes);
    for i in 0..9 {
        assert!(close(
            b0.combined[i].std_unc,
            poses_line.contribution[i],
            1e-15
        ));
    }
}
