//! The static stepped method (Gaitan et al. (2021)): its Table 1 reproduced noise-free against an
//! independent calculation, Monte Carlo coverage of the uncertainties, and mounting
//! invariance of the intrinsic properties.
// Matrix arithmetic on small fixed arrays reads more plainly with indices.
#![allow(clippy::needless_range_loop)]

use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use rotacal::calibrate::methods::static_method;
use rotacal::calibrate::poses::StaticCondition;
use rotacal::simulate::geometry::{mounted, rotation};
use rotacal_shared::Condition;

/// Gaitan et al. (2021)'s g_loc, m/s².
const G: f64 = 9.801018;

/// Gaitan et al. (2021) Table 1 (volts): per condition x, y, z and channel u, v, w: (A, B, O).
const TABLE1: [[[f64; 3]; 3]; 3] = [
    [
        [-0.010809, 0.000919, -0.00559],
        [1.975968, -0.032913, 0.014132],
        [0.007058, 1.984217, 0.002869],
    ],
    [
        [1.9735310, 0.000244, -0.004931],
        [-0.0235130, -0.033380, 0.013402],
        [-0.0106390, 1.984207, 0.002850],
    ],
    [
        [1.973499, -0.0104570, -0.004913],
        [-0.023842, 1.9759280, 0.014103],
        [-0.011098, 0.0075540, 0.003180],
    ],
];

fn angles() -> Vec<f64> {
    (0..72).map(|i| f64::from(i) * 5.0).collect()
}

#[test]
fn seed_001_table_1_reproduced() {
    let a = angles();
    let data: Vec<[Vec<f64>; 3]> = (0..3)
        .map(|c| {
            [0, 1, 2].map(|j| {
                let [ca, cb, co] = TABLE1[c][j];
                a.iter()
                    .map(|d| ca * d.to_radians().sin() + cb * d.to_radians().cos() + co)
                    .collect()
            })
        })
        .collect();
    let conds: Vec<StaticCondition> = Condition::ALL
        .iter()
        .zip(&data)
        .map(|(c, d)| StaticCondition {
            condition: *c,
            angle_deg: &a,
            y: [&d[0], &d[1], &d[2]],
            t_s: &[],
            first_line: 0,
        })
        .collect();
    let r = static_method(&conds, G, Default::default()).unwrap();

    // Independent calculation. On full-circle uniform steps sin, cos and 1 are orthogonal
    // within a condition, so the joint least-squares S is the mean of each element's two
    // duplicates (Gaitan et al. (2021) eq. 20) and O the mean of the three per-condition offsets.
    let t = |c: usize, j: usize, p: usize| TABLE1[c][j][p];
    let mut s = [[0.0; 3]; 3];
    for j in 0..3 {
        s[j] = [
            (t(1, j, 0) + t(2, j, 0)) / (2.0 * G),
            (t(0, j, 0) + t(2, j, 1)) / (2.0 * G),
            (t(0, j, 1) + t(1, j, 1)) / (2.0 * G),
        ];
    }
    let o: Vec<f64> = (0..3)
        .map(|j| (t(0, j, 2) + t(1, j, 2) + t(2, j, 2)) / 3.0)
        .collect();
    let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let rel = |x: f64, y: f64| (x - y).abs() / y.abs().max(1e-300);
    for j in 0..3 {
        for k in 0..3 {
            assert!(
                rel(r.s[j][k], s[j][k]) < 1e-9,
                "S[{j}][{k}]: {} vs {}",
                r.s[j][k],
                s[j][k]
            );
            assert!(rel(r.duplicate_average.as_ref().unwrap().s[j][k].value, s[j][k]) < 1e-9);
        }
        assert!(rel(r.offsets[j].value, o[j]) < 1e-9, "O[{j}]");
        assert!(rel(r.duplicate_average.as_ref().unwrap().offsets[j].value, o[j]) < 1e-9);
        assert!(
            rel(r.intrinsic.sensitivity[j].value, norm(s[j])) < 1e-9,
            "s[{j}]"
        );
    }
    for (k, (j, l)) in [(0, 1), (1, 2), (2, 0)].into_iter().enumerate() {
        let c =
            (s[j][0] * s[l][0] + s[j][1] * s[l][1] + s[j][2] * s[l][2]) / (norm(s[j]) * norm(s[l]));
        let phi = c.acos().to_degrees();
        assert!(
            rel(r.intrinsic.angle_deg[k].value, phi) < 1e-9,
            "angle {k}: {} vs {phi}",
            r.intrinsic.angle_deg[k].value
        );
    }
    println!("S (V per m/s²): {:?}", r.s);
    println!("O (V): {:?}", r.offsets.map(|e| e.value));
    println!(
        "s (V per m/s²): {:?}",
        r.intrinsic.sensitivity.map(|e| e.value)
    );
    println!("φ (deg): {:?}", r.intrinsic.angle_deg.map(|e| e.value));
}

/// A Dytran-like device in volts (S from Table 1's duplicate means), mounted by `r`.
fn device(rot: &[[f64; 3]; 3]) -> ([[f64; 3]; 3], [f64; 3]) {
    let mut s0 = [[0.0; 3]; 3];
    for j in 0..3 {
        s0[j] = [
            (TABLE1[1][j][0] + TABLE1[2][j][0]) / (2.0 * G),
            (TABLE1[0][j][0] + TABLE1[2][j][1]) / (2.0 * G),
            (TABLE1[0][j][1] + TABLE1[1][j][1]) / (2.0 * G),
        ];
    }
    (mounted(&s0, rot), [-0.0051, 0.0139, 0.0030])
}

fn simulate(s: &[[f64; 3]; 3], o: &[f64; 3], sigma: f64, rng: &mut impl Rng) -> Vec<[Vec<f64>; 3]> {
    let a = angles();
    let noise = Normal::new(0.0, sigma).unwrap();
    Condition::ALL
        .iter()
        .map(|c| {
            [0, 1, 2].map(|j| {
                a.iter()
                    .map(|d| {
                        let gd = c.gravity_direction(d.to_radians());
                        G * (s[j][0] * gd[0] + s[j][1] * gd[1] + s[j][2] * gd[2])
                            + o[j]
                            + noise.sample(&mut *rng)
                    })
                    .collect()
            })
        })
        .collect()
}

fn calibrate(data: &[[Vec<f64>; 3]]) -> rotacal::calibrate::methods::StaticCalibration {
    let a = angles();
    let conds: Vec<StaticCondition> = Condition::ALL
        .iter()
        .zip(data)
        .map(|(c, d)| StaticCondition {
            condition: *c,
            angle_deg: &a,
            y: [&d[0], &d[1], &d[2]],
            t_s: &[],
            first_line: 0,
        })
        .collect();
    static_method(&conds, G, Default::default()).unwrap()
}

#[test]
fn static_k2_intervals_cover_the_truth() {
    const TRIALS: usize = 2000;
    let (s, o) = device(&rotation([1.0, -1.0, 2.0], 4.0));
    let truth_s: Vec<f64> = (0..3)
        .map(|j| (s[j][0].powi(2) + s[j][1].powi(2) + s[j][2].powi(2)).sqrt())
        .collect();
    let truth_phi: Vec<f64> = [(0, 1), (1, 2), (2, 0)]
        .iter()
        .map(|&(j, k)| {
            let d: f64 = (0..3).map(|a| s[j][a] * s[k][a]).sum();
            (d / (truth_s[j] * truth_s[k])).acos().to_degrees()
        })
        .collect();
    let mut rng = rand::rngs::StdRng::seed_from_u64(1729);
    let mut covered = [0usize; 9];
    for _ in 0..TRIALS {
        let r = calibrate(&simulate(&s, &o, 0.5e-3, &mut rng));
        let est = r
            .intrinsic
            .sensitivity
            .iter()
            .chain(r.intrinsic.angle_deg.iter())
            .chain(r.offsets.iter());
        let truth = truth_s.iter().chain(truth_phi.iter()).chain(o.iter());
        for (k, (e, t)) in est.zip(truth).enumerate() {
            if (e.value - t).abs() <= 2.0 * e.std_unc {
                covered[k] += 1;
            }
        }
    }
    let names = [
        "s_u", "s_v", "s_w", "φ_uv", "φ_vw", "φ_wu", "O_u", "O_v", "O_w",
    ];
    let fracs: Vec<f64> = covered.iter().map(|&c| c as f64 / TRIALS as f64).collect();
    for (n, f) in names.iter().zip(&fracs) {
        println!("{n:<5} coverage {f:.4}");
    }
    for (n, f) in names.iter().zip(&fracs) {
        assert!((0.93..=0.97).contains(f), "{n}: coverage {f}");
    }
}

/// Gaitan et al. (2021)'s finding, in simulation: the sensitivity matrix moves with the mounting,
/// the intrinsic properties don't (noise-free: to 1e-9).
#[test]
fn matrix_moves_with_mounting_intrinsic_does_not() {
    let mut rng = rand::rngs::StdRng::seed_from_u64(0);
    let (s0, o) = device(&rotation([1.0, 0.0, 0.0], 0.0));
    let base = calibrate(&simulate(&s0, &o, 0.0, &mut rng));
    for (axis, deg) in [
        ([1.0, 0.0, 0.0], 2.0),
        ([0.0, 1.0, 1.0], 5.0),
        ([1.0, 1.0, 1.0], 10.0),
    ] {
        let (s, o) = device(&rotation(axis, deg));
        let r = calibrate(&simulate(&s, &o, 0.0, &mut rng));
        let moved = (0..3)
            .flat_map(|j| (0..3).map(move |a| (j, a)))
            .map(|(j, a)| (r.s[j][a] - base.s[j][a]).abs())
            .fold(0.0, f64::max);
        assert!(
            moved > 1e-3 * deg / 10.0,
            "S barely moved at {deg}°: {moved}"
        );
        for k in 0..3 {
            let ds = (r.intrinsic.sensitivity[k].value - base.intrinsic.sensitivity[k].value).abs();
            let dphi = (r.intrinsic.angle_deg[k].value - base.intrinsic.angle_deg[k].value).abs();
            assert!(
                ds < 1e-9 * base.intrinsic.sensitivity[k].value,
                "s moved at {deg}°"
            );
            assert!(dphi < 1e-9 * 90.0, "φ moved at {deg}°");
        }
        println!("{deg}° about {axis:?}: max |ΔS| = {moved:.2e} V per m/s², intrinsic unchanged");
    }
}
