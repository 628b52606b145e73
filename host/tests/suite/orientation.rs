//! Static calibration from known orientations (`rotacal::calibrate::poses`): the fit's
//! uncertainties checked by Monte Carlo coverage, and poses that leave S and O
//! under-determined or badly conditioned named.
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal, StandardNormal};
use rotacal::calibrate::methods::from_poses;
use rotacal::calibrate::poses::{self, Options, Pose, PoseError};
use rotacal::calibrate::{static_budget, TypeB};

const G: f64 = 9.81;

/// A device like imucal's example IMU (m/s² in, m/s² out), skewed by a few mrad.
const S: [[f64; 3]; 3] = [
    [0.9966, -0.0148, -0.0075],
    [0.0086, 1.0024, 0.0018],
    [0.0136, 0.0021, 1.0233],
];
const O: [f64; 3] = [0.54, -0.62, 0.39];

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

fn unit(v: [f64; 3]) -> [f64; 3] {
    let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
    v.map(|x| x / n)
}

/// Readings at `dirs`, each pose truly tilted by a normal angle of `tilt_deg` (per axis)
/// off its nominal direction, with white noise `sigma` on `n` readings.
fn session(
    dirs: &[[f64; 3]],
    n: usize,
    sigma: f64,
    tilt_deg: f64,
    rng: &mut impl Rng,
) -> Vec<Pose> {
    let noise = Normal::new(0.0, sigma).unwrap();
    dirs.iter()
        .enumerate()
        .map(|(p, nominal)| {
            let t: [f64; 3] = std::array::from_fn(|_| {
                tilt_deg.to_radians() * Distribution::<f64>::sample(&StandardNormal, &mut *rng)
            });
            // Small rotation: ĝ' = ĝ + t × ĝ.
            let g = unit([
                nominal[0] + t[1] * nominal[2] - t[2] * nominal[1],
                nominal[1] + t[2] * nominal[0] - t[0] * nominal[2],
                nominal[2] + t[0] * nominal[1] - t[1] * nominal[0],
            ]);
            let rows: Vec<[f64; 3]> = (0..n)
                .map(|_| {
                    std::array::from_fn(|j| {
                        G * (0..3).map(|k| S[j][k] * g[k]).sum::<f64>()
                            + O[j]
                            + noise.sample(&mut *rng)
                    })
                })
                .collect();
            let mean: [f64; 3] =
                std::array::from_fn(|j| rows.iter().map(|r| r[j]).sum::<f64>() / n as f64);
            let std = (n > 1).then(|| {
                std::array::from_fn(|j| {
                    (rows.iter().map(|r| (r[j] - mean[j]).powi(2)).sum::<f64>() / (n as f64 - 1.0))
                        .sqrt()
                })
            });
            Pose {
                name: format!("p{p}"),
                gravity: *nominal,
                n,
                mean,
                std,
                first_line: 0,
                noise: None,
                angle_direction: None,
                times_s: Vec::new(),
            }
        })
        .collect()
}

fn truth() -> Vec<f64> {
    let (s, a) = rotacal::simulate::intrinsic_of(&S);
    S.iter()
        .flatten()
        .copied()
        .chain(O)
        .chain(s)
        .chain(a)
        .collect()
}

/// Fraction of 95 % intervals holding the truth, per quantity: S (9), O (3), s (3),
/// φ (3). Each interval is ±k·u with its own k: the pose fit's for the elements of S, the
/// budget's (Welch–Satterthwaite over its sources) for the offsets and properties.
fn coverage(dirs: &[[f64; 3]], n: usize, sigma: f64, tilt_deg: f64, trials: usize) -> Vec<f64> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(0x5EED);
    let truth = truth();
    let mut hits = vec![0usize; truth.len()];
    for _ in 0..trials {
        let poses = session(dirs, n, sigma, tilt_deg, &mut rng);
        let cal = from_poses(poses, G, Options::default()).unwrap();
        let k = cal.pose_fit.k_theta();
        let budget = static_budget(&cal, G, &TypeB::default(), "m/s^2").unwrap();
        let props = [0, 1, 2]
            .map(|j| cal.intrinsic.sensitivity[j].value)
            .into_iter()
            .chain([0, 1, 2].map(|j| cal.intrinsic.angle_deg[j].value))
            .chain([0, 1, 2].map(|j| cal.offsets[j].value));
        // Budget order: s (3), φ (3), O (3); here S, O, s, φ.
        let from_budget: Vec<(f64, f64)> = props
            .enumerate()
            .map(|(q, v)| (v, budget.combined[q].expanded_unc))
            .collect();
        let est: Vec<(f64, f64)> = cal
            .s
            .iter()
            .flatten()
            .zip(cal.s_std.iter().flatten())
            .zip(k)
            .map(|((v, u), k)| (*v, k * u))
            .chain(from_budget[6..9].iter().copied())
            .chain(from_budget[..6].iter().copied())
            .collect();
        for ((h, (v, u)), t) in hits.iter_mut().zip(est).zip(&truth) {
            if (v - t).abs() <= u {
                *h += 1;
            }
        }
    }
    hits.iter().map(|h| *h as f64 / trials as f64).collect()
}

fn report(name: &str, c: &[f64]) {
    let names = [
        "S_ux", "S_uy", "S_uz", "S_vx", "S_vy", "S_vz", "S_wx", "S_wy", "S_wz", "O_u", "O_v",
        "O_w", "s_u", "s_v", "s_w", "φ_uv", "φ_vw", "φ_wu",
    ];
    let line: Vec<String> = names
        .iter()
        .zip(c)
        .map(|(n, f)| format!("{n} {f:.3}"))
        .collect();
    let mean = c.iter().sum::<f64>() / c.len() as f64;
    println!("{name}: mean {mean:.3}; {}", line.join(", "));
}

#[test]
fn six_position_coverage_with_pose_scatter() {
    // Like imucal's session: noise 0.014 m/s², 500 readings a pose, and each pose placed
    // off its nominal direction by 0.1° (normal, per axis): the tilt dominates.
    let c = coverage(&axes(), 500, 0.014, 0.1, 2000);
    report("six poses, tilt 0.1°", &c);
    assert_two_sided(&c);
}

#[test]
fn six_position_coverage_with_a_tilt_like_the_noise() {
    // A tilt of 0.004° moves a reading by about the standard error of a pose mean.
    let c = coverage(&axes(), 500, 0.014, 0.004, 2000);
    report("six poses, tilt 0.004°", &c);
    assert_two_sided(&c);
}

#[test]
fn six_position_coverage_without_pose_scatter() {
    // Poses exactly on their directions: the uncertainty comes from the pose noise.
    let c = coverage(&axes(), 500, 0.014, 0.0, 2000);
    report("six poses, no tilt", &c);
    assert_two_sided(&c);
}

#[test]
fn fourteen_poses_coverage_with_pose_scatter() {
    // Six faces and eight corners of a cube, tilt 0.05°, 200 readings a pose.
    let mut dirs = axes();
    for x in [-1.0, 1.0] {
        for y in [-1.0, 1.0] {
            for z in [-1.0f64, 1.0] {
                dirs.push(unit([x, y, z]));
            }
        }
    }
    let c = coverage(&dirs, 200, 0.014, 0.05, 2000);
    report("fourteen poses, tilt 0.05°", &c);
    assert_two_sided(&c);
}

/// Every quantity's coverage within [0.93, 0.97]: about ±4 binomial σ around 0.95 at 2000
/// trials (σ = 0.0049), so an understated U fails, and so does one overstated by 10 %.
fn assert_two_sided(c: &[f64]) {
    let bad: Vec<String> = c
        .iter()
        .enumerate()
        .filter(|(_, f)| !(0.93..=0.97).contains(*f))
        .map(|(i, f)| format!("quantity {i}: {f}"))
        .collect();
    assert!(bad.is_empty(), "{bad:?}");
}

#[test]
fn many_single_readings_coverage() {
    // 26 directions (cube faces, edges, corners), one reading each: ordinary least squares.
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
    let c = coverage(&dirs, 1, 0.014, 0.0, 2000);
    report("26 single readings", &c);
    assert_two_sided(&c);
}

fn names(dirs: &[[f64; 3]]) -> Vec<Pose> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(1);
    session(dirs, 20, 0.014, 0.0, &mut rng)
}

#[test]
fn missing_orientations_are_named() {
    // No pose sees z: S_jz is unobservable.
    let four = &axes()[..4];
    match poses::fit(names(four), G, Options::default()) {
        Err(e @ PoseError::UnderDetermined { .. }) => {
            let m = e.to_string();
            println!("{m}");
            assert!(m.contains("along +z") || m.contains("along -z"), "{m}");
        }
        other => panic!("{other:?}"),
    }
    // Only +x, +y, +z: three poses for four unknowns per channel.
    let up = [axes()[0], axes()[2], axes()[4]];
    assert!(matches!(
        poses::fit(names(&up), G, Options::default()),
        Err(PoseError::UnderDetermined { poses: 3, .. })
    ));
    // Five of six: determined, one degree of freedom, well conditioned.
    let five = &axes()[..5];
    let f = poses::fit(names(five), G, Options::default()).unwrap();
    assert_eq!(f.dof, 1);
    assert!(f.conditioning.suggestion.is_none());
    // imucal's offsets need the sixth.
    let opts = Options {
        offsets: poses::OffsetEstimator::AxisPairs,
        ..Options::default()
    };
    let e = poses::fit(names(five), G, opts).unwrap_err();
    assert!(e.to_string().contains("along -z"), "{e}");
    // Four poses that barely see z (one tilted 3° out of the x-y plane): flagged, and the
    // suggestion is a z pose.
    let mut weak = axes()[..4].to_vec();
    weak.push(unit([1.0, 0.0, 3f64.to_radians().tan()]));
    let f = poses::fit(names(&weak), G, Options::default()).unwrap();
    let s = f.conditioning.suggestion.clone().unwrap();
    println!(
        "condition number {:.1}: add {s}",
        f.conditioning.condition_number
    );
    assert!(f.conditioning.condition_number > poses::WELL_CONDITIONED);
    assert!(s.contains('z'), "{s}");
    // Four exact poses, one reading each: S and O exactly determined, no uncertainty.
    let mut rng = rand::rngs::StdRng::seed_from_u64(2);
    let tetra = [axes()[0], axes()[2], axes()[4], unit([-1.0, -1.0, -1.0])];
    let e = poses::fit(
        session(&tetra, 1, 0.014, 0.0, &mut rng),
        G,
        Options::default(),
    )
    .unwrap_err();
    assert_eq!(e, PoseError::NoUncertainty(4));
}

#[test]
fn a_pose_that_moved_is_flagged() {
    let mut rng = rand::rngs::StdRng::seed_from_u64(3);
    let mut poses = session(&axes(), 200, 0.014, 0.0, &mut rng);
    if let Some(s) = poses[2].std.as_mut() {
        s[1] *= 5.0;
    }
    let f = poses::fit(poses, G, Options::default()).unwrap();
    assert_eq!(f.not_still, vec!["p2".to_string()]);
}

#[test]
fn exactly_determined_or_constant_poses() {
    let mut rng = rand::rngs::StdRng::seed_from_u64(4);
    let tetra = [axes()[0], axes()[2], axes()[4], unit([-1.0, -1.0, -1.0])];
    // Four poses of repeated readings: S and O exact, the uncertainty from the pose noise
    // (random-effects weights); equal weights have nothing to estimate it from.
    let poses = session(&tetra, 50, 0.014, 0.0, &mut rng);
    let f = poses::fit(poses.clone(), G, Options::default()).unwrap();
    assert_eq!(f.dof, 0);
    assert!(f
        .channels
        .iter()
        .all(|c| c.cov[0][0] > 0.0 && c.nu == 196.0));
    let equal = Options {
        weights: poses::Weights::Equal,
        ..Options::default()
    };
    assert_eq!(
        poses::fit(poses, G, equal).unwrap_err(),
        PoseError::NoUncertainty(4)
    );
    // A channel that did not change at one pose (a quantised sensor held still): its
    // standard error is 0, and the fit still stands, with a positive uncertainty.
    let mut poses = session(&axes(), 50, 0.014, 0.0, &mut rng);
    if let Some(s) = poses[0].std.as_mut() {
        s[1] = 0.0;
    }
    let f = poses::fit(poses, G, Options::default()).unwrap();
    assert!(f
        .channels
        .iter()
        .all(|c| c.cov[1][1] > 0.0 && c.cov[3][3] > 0.0));
}
