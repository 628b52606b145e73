//! `calibrate::poses::fit`, the joint least-squares fit of S and O to static poses: exact
//! on noise-free poses, its stated uncertainty against the spread of its estimates over
//! many seeds, and the pose sets it must refuse.
//!
//! The statistical checks use fixed seeds, with bounds of 4 binomial standard deviations
//! around the nominal rate (a correct fit fails one of them about once in 10⁴ seeds), not
//! values read off a run.
// Matrix arithmetic on small fixed arrays reads more plainly with indices.
#![allow(clippy::needless_range_loop)]

use std::array::from_fn;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, StandardNormal};
use rotacal_engine::calibrate::poses::{
    self, OffsetEstimator, Options, PartSource, Pose, PoseError, PoseFit, Scatter, Weights,
};
use rotacal_engine::recording::Oriented;

/// Local gravity, m/s².
const G: f64 = 9.80665;

/// A device in m/s² out (like imucal's example IMU), skewed by a few mrad.
const S: [[f64; 3]; 3] = [
    [0.9966, -0.0148, -0.0075],
    [0.0086, 1.0024, 0.0018],
    [0.0136, 0.0021, 1.0233],
];
const O: [f64; 3] = [0.54, -0.62, 0.39];

/// Readings' white noise, m/s² (imucal's example session). The fits never see it.
const SIGMA: f64 = 0.014;

fn unit(v: [f64; 3]) -> [f64; 3] {
    let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
    v.map(|x| x / n)
}

fn axes() -> Vec<[f64; 3]> {
    vec![
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, -1.0],
    ]
}

/// The directions from a cube's centre to its faces, and to its corners too.
fn cube(corners: bool) -> Vec<[f64; 3]> {
    let mut dirs = axes();
    if corners {
        for x in [-1.0, 1.0] {
            for y in [-1.0, 1.0] {
                for z in [-1.0, 1.0] {
                    dirs.push(unit([x, y, z]));
                }
            }
        }
    }
    dirs
}

/// The 26 directions to a cube's faces, edges and corners.
fn cube26() -> Vec<[f64; 3]> {
    let mut dirs = Vec::new();
    for x in [-1.0, 0.0, 1.0] {
        for y in [-1.0, 0.0, 1.0] {
            for z in [-1.0f64, 0.0, 1.0] {
                if x != 0.0 || y != 0.0 || z != 0.0 {
                    dirs.push(unit([x, y, z]));
                }
            }
        }
    }
    dirs
}

/// The model's reading with gravity along `g_hat`: g·S·ĝ + O.
fn model(s: &[[f64; 3]; 3], o: &[f64; 3], g_hat: &[f64; 3]) -> [f64; 3] {
    from_fn(|j| G * (0..3).map(|k| s[j][k] * g_hat[k]).sum::<f64>() + o[j])
}

/// A pose from its readings: their mean and sample standard deviation, worked out here.
fn pose(name: String, gravity: [f64; 3], rows: &[[f64; 3]]) -> Pose {
    let n = rows.len();
    let mean: [f64; 3] = from_fn(|j| rows.iter().map(|r| r[j]).sum::<f64>() / n as f64);
    let std = (n > 1).then(|| {
        from_fn(|j| {
            (rows.iter().map(|r| (r[j] - mean[j]).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt()
        })
    });
    Pose {
        name,
        gravity,
        n,
        mean,
        std,
        first_line: 0,
        noise: None,
        angle_direction: None,
        times_s: Vec::new(),
    }
}

/// A standard normal draw.
fn normal(rng: &mut ChaCha8Rng) -> f64 {
    StandardNormal.sample(rng)
}

/// `n` readings at each of `dirs` with white noise [`SIGMA`], each pose truly tilted off
/// its nominal direction by a small rotation, normal with `tilt_deg` per axis. The fit is
/// given the nominal directions and the readings only.
fn session(dirs: &[[f64; 3]], n: usize, tilt_deg: f64, rng: &mut ChaCha8Rng) -> Vec<Pose> {
    let noise = Normal::new(0.0, SIGMA).unwrap();
    dirs.iter()
        .enumerate()
        .map(|(p, d)| {
            let t: [f64; 3] = from_fn(|_| tilt_deg.to_radians() * normal(rng));
            // ĝ + t × ĝ: the small rotation t applied to ĝ.
            let g = unit([
                d[0] + t[1] * d[2] - t[2] * d[1],
                d[1] + t[2] * d[0] - t[0] * d[2],
                d[2] + t[0] * d[1] - t[1] * d[0],
            ]);
            let clean = model(&S, &O, &g);
            let rows: Vec<[f64; 3]> = (0..n)
                .map(|_| from_fn(|j| clean[j] + noise.sample(&mut *rng)))
                .collect();
            pose(format!("p{p}"), *d, &rows)
        })
        .collect()
}

/// (S row-major, O): the order of the fit's covariance.
fn theta(s: &[[f64; 3]; 3], o: &[f64; 3]) -> [f64; 12] {
    from_fn(|i| if i < 9 { s[i / 3][i % 3] } else { o[i - 9] })
}

/// The fit's (S, O), with the joint offsets.
fn estimate(f: &PoseFit) -> [f64; 12] {
    theta(&f.s(), &f.offsets_joint.map(|e| e.value))
}

/// The standard uncertainties the fit states for (S, O).
fn std_unc(f: &PoseFit) -> [f64; 12] {
    theta(&f.s_std(), &f.offsets_joint.map(|e| e.std_unc))
}

/// xᵀ·C⁻¹·x for a symmetric positive definite C, by Cholesky.
fn mahalanobis<const N: usize>(c: &[[f64; N]; N], x: &[f64; N]) -> f64 {
    let mut l = [[0.0; N]; N];
    for i in 0..N {
        for j in 0..=i {
            let s = c[i][j] - (0..j).map(|k| l[i][k] * l[j][k]).sum::<f64>();
            l[i][j] = if i == j {
                assert!(s > 0.0, "covariance not positive definite");
                s.sqrt()
            } else {
                s / l[j][j]
            };
        }
    }
    // Solve L·z = x: xᵀC⁻¹x = |z|².
    let mut z = [0.0; N];
    for i in 0..N {
        z[i] = (x[i] - (0..i).map(|k| l[i][k] * z[k]).sum::<f64>()) / l[i][i];
    }
    z.iter().map(|v| v * v).sum()
}

/// p ± 4 binomial standard deviations over `trials`.
fn band(p: f64, trials: usize) -> (f64, f64) {
    let sd = (p * (1.0 - p) / trials as f64).sqrt();
    (p - 4.0 * sd, p + 4.0 * sd)
}

const NAMES: [&str; 12] = [
    "S_ux", "S_uy", "S_uz", "S_vx", "S_vy", "S_vz", "S_wx", "S_wy", "S_wz", "O_u", "O_v", "O_w",
];

#[test]
fn noise_free_poses_give_s_and_o_to_1e_12() {
    // A device in counts, skewed and offset: the bounds are relative to its scale.
    let s = [
        [1669.3, -2.4, 1.1],
        [3.9, 1668.8, -0.7],
        [-2.6, 5.3, 1676.2],
    ];
    let o = [525.1, 99.6, 442.4];
    let (scale_s, scale_y) = (1676.2, G * 1676.2 + 525.1);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let random: Vec<[f64; 3]> = (0..10)
        .map(|_| unit(from_fn(|_| normal(&mut rng))))
        .collect();
    let want = theta(&s, &o);
    for (set, dirs) in [
        ("six axes", axes()),
        ("ten random directions", random),
        ("26 cube directions", cube26()),
    ] {
        // One reading a pose, or several that are all the same (std 0).
        for n in [1, 5] {
            let poses: Vec<Pose> = dirs
                .iter()
                .enumerate()
                .map(|(p, d)| Pose {
                    n,
                    std: (n > 1).then_some([0.0; 3]),
                    ..pose(format!("p{p}"), *d, &[model(&s, &o, d)])
                })
                .collect();
            for weights in [Weights::RandomEffects, Weights::Equal] {
                let opts = Options {
                    weights,
                    ..Options::default()
                };
                let f = poses::fit(poses.clone(), G, opts)
                    .unwrap_or_else(|e| panic!("{set}, n = {n}, {weights:?}: {e}"));
                let got = estimate(&f);
                let worst = (0..12)
                    .map(|i| (got[i] - want[i]).abs() / if i < 9 { scale_s } else { scale_y })
                    .fold(0.0f64, f64::max);
                println!("{set}, n = {n}, {weights:?}: largest error {worst:.1e} of scale");
                for i in 0..12 {
                    let scale = if i < 9 { scale_s } else { scale_y };
                    assert!(
                        (got[i] - want[i]).abs() <= 1e-12 * scale,
                        "{set}, n = {n}, {weights:?}: {} = {} vs {}",
                        NAMES[i],
                        got[i],
                        want[i]
                    );
                }
                let worst = f
                    .residuals
                    .iter()
                    .flatten()
                    .fold(0.0f64, |m, r| m.max(r.abs()));
                assert!(worst <= 1e-12 * scale_y, "{set}: residual {worst}");
            }
        }
    }
    // imucal's offsets, (ȳ_j(+e_j) + ȳ_j(−e_j))/2, are O_j exactly on the six axis poses.
    let poses: Vec<Pose> = axes()
        .iter()
        .enumerate()
        .map(|(p, d)| pose(format!("p{p}"), *d, &[model(&s, &o, d)]))
        .collect();
    let opts = Options {
        offsets: OffsetEstimator::AxisPairs,
        ..Options::default()
    };
    let f = poses::fit(poses, G, opts).unwrap();
    let pairs = f.offsets_axis_pairs.unwrap();
    for j in 0..3 {
        assert!((pairs[j].value - o[j]).abs() <= 1e-12 * scale_y, "O[{j}]");
        assert_eq!(f.offsets()[j], pairs[j], "the chosen estimator's offsets");
    }
}

/// Equal weights on single readings is ordinary least squares with σ² from the residuals:
/// with normal noise each element's (θ̂ − θ)/u is exactly Student's t with P − 4 degrees of
/// freedom, and each channel's four coefficients jointly give (β̂ − β)ᵀC⁻¹(β̂ − β)/4 ~
/// F(4, P − 4). So the stated intervals must hold 95 % of the time, not about 95 %.
#[test]
fn equal_weights_give_exact_student_t_intervals() {
    // Many trials, as they are cheap: ±4 binomial σ is then ±0.0087, and a standard
    // uncertainty 5 % too small or too large shifts the coverage by about 0.01.
    const TRIALS: usize = 10_000;
    // Quantiles at 22 degrees of freedom, tabulated (mpmath), not from the code under test.
    const T_975_22: f64 = 2.073_873_067_904_03;
    const F_95_4_22: f64 = 2.816_708_339_64;
    let dirs = cube26();
    let mut rng = ChaCha8Rng::seed_from_u64(0x0115);
    let want = theta(&S, &O);
    let mut covered = [0usize; 12];
    let mut beyond_f = [0usize; 3];
    let equal = Options {
        weights: Weights::Equal,
        ..Options::default()
    };
    for _ in 0..TRIALS {
        let f = poses::fit(session(&dirs, 1, 0.0, &mut rng), G, equal).unwrap();
        assert_eq!(f.dof, 22);
        assert_eq!(f.scatter, Scatter::PerChannel);
        let (est, u, k) = (estimate(&f), std_unc(&f), f.k_theta());
        for i in 0..12 {
            assert!((k[i] - T_975_22).abs() < 1e-9, "k = {}", k[i]);
            covered[i] += usize::from((est[i] - want[i]).abs() <= k[i] * u[i]);
        }
        for j in 0..3 {
            let d = [0, 1, 2, 9].map(|a| if a < 9 { 3 * j + a } else { 9 + j });
            let x = d.map(|i| est[i] - want[i]);
            let q = mahalanobis(&f.channels[j].cov, &x) / 4.0;
            beyond_f[j] += usize::from(q > F_95_4_22);
            // The channels are fitted alone: no covariance between them.
            for a in d {
                for b in 0..12 {
                    if !d.contains(&b) {
                        assert_eq!(f.cov[(a, b)], 0.0);
                    }
                }
            }
        }
    }
    let (lo, hi) = band(0.95, TRIALS);
    for i in 0..12 {
        let c = covered[i] as f64 / TRIALS as f64;
        println!("{}: t interval coverage {c:.4}", NAMES[i]);
        assert!((lo..=hi).contains(&c), "{}: coverage {c}", NAMES[i]);
    }
    let (lo, hi) = band(0.05, TRIALS);
    for j in 0..3 {
        let r = beyond_f[j] as f64 / TRIALS as f64;
        println!("channel {j}: F(4, 22) exceedance {r:.4}");
        assert!((lo..=hi).contains(&r), "channel {j}: {r}");
    }
}

/// With one reading a pose there is no pose noise to weigh by: the default fit is then
/// ordinary least squares too, the whole scatter per channel.
#[test]
fn single_readings_by_default_are_ordinary_least_squares() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let poses = session(&cube26(), 1, 0.0, &mut rng);
    let re = poses::fit(poses.clone(), G, Options::default()).unwrap();
    let equal = Options {
        weights: Weights::Equal,
        ..Options::default()
    };
    let ols = poses::fit(poses, G, equal).unwrap();
    assert_eq!(re.scatter, Scatter::PerChannel);
    let (a, b) = (estimate(&re), estimate(&ols));
    for i in 0..12 {
        assert!(
            (a[i] - b[i]).abs() <= 1e-12 * b[i].abs().max(1.0),
            "{}",
            NAMES[i]
        );
        for k in 0..12 {
            let (x, y) = (re.cov[(i, k)], ols.cov[(i, k)]);
            assert!(
                (x - y).abs() <= 1e-9 * ols.cov[(i, i)],
                "cov {i},{k}: {x} vs {y}"
            );
        }
    }
}

/// Coverage of the default (random-effects) fit over `trials` sessions: per element of
/// (S, O) the fraction of ±k·u intervals holding the truth, and the fraction of sessions
/// whose (θ̂ − θ)ᵀC⁻¹(θ̂ − θ) with the stated C exceeds χ²₁₂'s 95th percentile.
fn random_effects_coverage(
    dirs: &[[f64; 3]],
    n: usize,
    tilt_deg: f64,
    (trials, seed): (usize, u64),
) -> ([f64; 12], f64) {
    const CHI2_95_12: f64 = 21.026_069_817_5;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let want = theta(&S, &O);
    let mut covered = [0usize; 12];
    let mut beyond = 0usize;
    for _ in 0..trials {
        let f = poses::fit(session(dirs, n, tilt_deg, &mut rng), G, Options::default()).unwrap();
        // The covariance is the sum of its independent parts.
        let sum = f.parts.iter().fold(f.cov * 0.0, |a, p| a + p.theta);
        assert!((sum - f.cov).abs().max() <= 1e-12 * f.cov.abs().max());
        match f.scatter {
            Scatter::Tilt { .. } => {
                assert!(f.parts.iter().any(|p| p.source == PartSource::PoseTilt))
            }
            Scatter::None => assert!(f.parts.iter().all(|p| p.source == PartSource::PoseNoise)),
            Scatter::PerChannel => panic!("repeated readings at known directions: {:?}", f.notes),
            Scatter::Slow => panic!("slow noise modelled without --slow-noise"),
        }
        let (est, u, k) = (estimate(&f), std_unc(&f), f.k_theta());
        for i in 0..12 {
            covered[i] += usize::from((est[i] - want[i]).abs() <= k[i] * u[i]);
        }
        let c: [[f64; 12]; 12] = from_fn(|a| from_fn(|b| f.cov[(a, b)]));
        let d: [f64; 12] = from_fn(|i| est[i] - want[i]);
        beyond += usize::from(mahalanobis(&c, &d) > CHI2_95_12);
    }
    (
        covered.map(|c| c as f64 / trials as f64),
        beyond as f64 / trials as f64,
    )
}

fn assert_covers(name: &str, c: &[f64; 12], trials: usize) {
    let (lo, hi) = band(0.95, trials);
    let line: Vec<String> = NAMES
        .iter()
        .zip(c)
        .map(|(n, f)| format!("{n} {f:.3}"))
        .collect();
    println!("{name}: {}", line.join(", "));
    for (n, f) in NAMES.iter().zip(c) {
        assert!((lo..=hi).contains(f), "{name}: {n} coverage {f}");
    }
}

/// Six axis poses of 500 readings, no tilt: the uncertainty is the pose noise's. The
/// estimate is independent of the residuals that decide whether a tilt is estimated, so
/// when none is, its distance from the truth in the stated covariance is χ²₁₂; when one
/// is, the covariance only grows. So at most 5 % of sessions may exceed χ²₁₂'s 95th
/// percentile (one-sided); each element's interval must cover 95 % (two-sided).
#[test]
fn six_poses_without_tilt_agree_within_their_covariance() {
    let (c, beyond) = random_effects_coverage(&axes(), 500, 0.0, (2000, 0x5EED));
    assert_covers("six poses, no tilt", &c, 2000);
    println!("χ²₁₂ 95 % exceedance {beyond:.4}");
    assert!(beyond <= band(0.05, 2000).1, "exceedance {beyond}");
}

/// Fourteen poses of 200 readings, each tilted by 0.05° per axis: the tilt dominates the
/// noise (it moves a reading by about 8e-3 m/s², the noise a pose mean by 1e-3), so the
/// intervals hold only if the pose-tilt random effect is estimated and propagated.
#[test]
fn fourteen_tilted_poses_cover_the_truth() {
    let (c, _) = random_effects_coverage(&cube(true), 200, 0.05, (2000, 0x711));
    assert_covers("fourteen poses, tilt 0.05°", &c, 2000);
}

#[test]
fn pose_sets_that_leave_s_or_o_open_are_refused() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut fit = |dirs: &[[f64; 3]], n: usize, opts: Options| {
        poses::fit(session(dirs, n, 0.0, &mut rng), G, opts)
    };
    let under = |r: Result<PoseFit, PoseError>| match r {
        Err(PoseError::UnderDetermined {
            poses,
            cond,
            missing,
        }) => (poses, cond, missing),
        other => panic!("{:?}", other.map(|f| f.s())),
    };
    let d = Options::default();
    // Three poses, four unknowns per channel.
    let (p, _, _) = under(fit(
        &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        20,
        d,
    ));
    assert_eq!(p, 3);
    // Eight poses in the x-y plane: nothing sees S_jz.
    let plane: Vec<[f64; 3]> = (0..8)
        .map(|i| {
            let a = f64::from(i) * 45f64.to_radians();
            [a.cos(), a.sin(), 0.0]
        })
        .collect();
    let (p, cond, missing) = under(fit(&plane, 20, d));
    assert_eq!(p, 8);
    assert!(cond >= 1e8, "{cond}");
    assert!(
        missing.starts_with("+z") || missing.starts_with("-z"),
        "{missing}"
    );
    // Eight poses on a cone 30° about +z: ĝ_z is the same in all, so S_jz·ĝ_z and O_j
    // cannot be told apart; gravity along −z helps most.
    let cone: Vec<[f64; 3]> = (0..8)
        .map(|i| {
            let a = f64::from(i) * 45f64.to_radians();
            let t = 30f64.to_radians();
            [t.sin() * a.cos(), t.sin() * a.sin(), t.cos()]
        })
        .collect();
    let (_, _, missing) = under(fit(&cone, 20, d));
    assert!(missing.starts_with("-z"), "{missing}");
    // Six poses, but only three directions.
    let twice: Vec<[f64; 3]> = axes()[..3].iter().chain(&axes()[..3]).copied().collect();
    under(fit(&twice, 20, d));
    // Four poses of one reading each: S and O exactly determined, nothing left for the
    // uncertainty. Repeated readings give it (from the pose noise), except to equal weights.
    let tetra = [axes()[0], axes()[2], axes()[4], unit([-1.0, -1.0, -1.0])];
    assert_eq!(fit(&tetra, 1, d).unwrap_err(), PoseError::NoUncertainty(4));
    let f = fit(&tetra, 50, d).unwrap();
    assert_eq!(f.dof, 0);
    assert!(std_unc(&f).iter().all(|u| *u > 0.0));
    let equal = Options {
        weights: Weights::Equal,
        ..d
    };
    assert_eq!(
        fit(&tetra, 50, equal).unwrap_err(),
        PoseError::NoUncertainty(4)
    );
    // imucal's offsets need exactly one pose along each of ±x, ±y, ±z.
    let pairs = Options {
        offsets: OffsetEstimator::AxisPairs,
        ..d
    };
    assert_eq!(
        fit(&axes()[..5], 20, pairs).unwrap_err(),
        PoseError::AxisPose("-z".into(), 0)
    );
    let mut extra = axes();
    extra.push([1.0, 0.0, 0.0]);
    assert_eq!(
        fit(&extra, 20, pairs).unwrap_err(),
        PoseError::AxisPose("+x".into(), 2)
    );
    // Barely out of the plane (one pose 3° up): accepted, but flagged, naming z.
    let mut weak = axes()[..4].to_vec();
    weak.push(unit([1.0, 0.0, 3f64.to_radians().tan()]));
    let f = fit(&weak, 20, d).unwrap();
    assert!(f.conditioning.condition_number > poses::WELL_CONDITIONED);
    let s = f.conditioning.suggestion.unwrap();
    assert!(s.contains('z'), "{s}");
    // The six axes are as well conditioned as poses get: √3, no suggestion.
    let f = fit(&axes(), 20, d).unwrap();
    assert!((f.conditioning.condition_number - 3f64.sqrt()).abs() < 1e-12);
    assert_eq!(f.conditioning.suggestion, None);
}

#[test]
fn a_pose_name_with_two_directions_is_refused_with_its_lines() {
    let rows = |g: [[f64; 3]; 3], names: [&str; 3]| Oriented {
        gravity: g.to_vec(),
        pose: Some(names.map(String::from).to_vec()),
        y: vec![[1.0, 2.0, 3.0]; 3],
        t_s: None,
        seq: None,
        temp_c: None,
        unc: None,
        line: vec![5, 6, 9],
    };
    let (x, y, mx) = ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]);
    assert_eq!(
        poses::poses_from_oriented(&rows([x, y, mx], ["a", "b", "a"])).unwrap_err(),
        PoseError::PoseDirection {
            name: "a".into(),
            first: 5,
            line: 9
        }
    );
    // The same name at the same direction is one pose of two readings.
    let p = poses::poses_from_oriented(&rows([x, y, x], ["a", "b", "a"])).unwrap();
    assert_eq!(p.iter().map(|q| q.n).collect::<Vec<_>>(), [2, 1]);
    assert_eq!((p[0].first_line, p[1].first_line), (5, 6));
}

/// The fit is a function of the set of poses (their order does not matter) and of g·S
/// (gravity twice as strong halves S and leaves O).
#[test]
fn order_of_poses_and_scale_of_gravity() {
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let poses = session(&cube(true), 100, 0.02, &mut rng);
    let f = poses::fit(poses.clone(), G, Options::default()).unwrap();
    let mut shuffled = poses.clone();
    shuffled.reverse();
    shuffled.rotate_left(5);
    let r = poses::fit(shuffled, G, Options::default()).unwrap();
    let g2 = poses::fit(poses, 2.0 * G, Options::default()).unwrap();
    let (a, b, c) = (estimate(&f), estimate(&r), estimate(&g2));
    let u = std_unc(&f);
    let (ur, u2) = (std_unc(&r), std_unc(&g2));
    for i in 0..12 {
        let halve = if i < 9 { 0.5 } else { 1.0 };
        assert!((a[i] - b[i]).abs() <= 1e-9 * u[i], "{} reordered", NAMES[i]);
        assert!(
            (a[i] * halve - c[i]).abs() <= 1e-9 * u[i],
            "{} at 2g",
            NAMES[i]
        );
        assert!(
            (u[i] - ur[i]).abs() <= 1e-9 * u[i],
            "u({}) reordered",
            NAMES[i]
        );
        assert!(
            (u[i] * halve - u2[i]).abs() <= 1e-9 * u[i],
            "u({}) at 2g",
            NAMES[i]
        );
    }
}

#[test]
fn a_pose_that_was_not_still_is_named() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let poses = session(&axes(), 200, 0.0, &mut rng);
    let with_std = |factor: f64| {
        let mut p = poses.clone();
        if let Some(s) = p[2].std.as_mut() {
            s[1] *= factor;
        }
        poses::fit(p, G, Options::default()).unwrap().not_still
    };
    // NOT_STILL_FACTOR (3) times the median pose's spread: the sample spreads of equally
    // still poses differ by a few per cent at 200 readings, so 2 and 5 are on either side.
    assert_eq!(poses::NOT_STILL_FACTOR, 3.0);
    assert_eq!(with_std(5.0), ["p2"]);
    assert!(with_std(2.0).is_empty());
}
