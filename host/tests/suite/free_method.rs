//! Method free (issue 16): still poses of unknown orientation, found in a continuous
//! recording, calibrated from |a| = g alone.
//!
//! - coverage: 1000 simulated sessions each of 12, 24 and 60 poses drawn over the sphere,
//!   through the simulator's CSV and `calibrate` (detection, pose noise, fit, budget).
//!   Each session's noise is AR(1) with ρ drawn from [0, 0.8], a level per channel, each
//!   pose's level scaled by up to 1.5 either way, a ring-down after each placement, the
//!   device mounted at random; no level is stated. The k = 2 coverage of each of the nine
//!   properties must lie in [0.93, 0.97]: ±2.9 binomial σ about 0.95 at 1000 sessions.
//! - invariance: one noise-free device under random mountings gives the same properties
//!   to 1e-9.
//! - the algebraic residual's bias at low signal-to-noise against the geometric one's.
//! - geometry: a circle, a plane, fewer than nine, a hemisphere, a pose that moved and one
//!   that does not fit, each refused or flagged by name.
//! - imucal's real session without a section list: the detection finds its still poses
//!   and leaves out the rotations; its six orientations cannot give nine properties, and
//!   the refusal says which directions to add.
#![allow(clippy::needless_range_loop)]

use crate::common;
use crate::coverage::Tally;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rotacal::calibrate::free::{self, Pose, Residual};
use rotacal::calibrate::json::CalibrationJson;
use rotacal::calibrate::still::{self, Verdict};
use rotacal::calibrate::{calibrate, Options};
use rotacal::recording::{Method, Recording};
use rotacal::simulate::{Config, Simulation};
use rotacal_proof::{parallel_n, prove};
use std::path::{Path, PathBuf};

const TRUTH_TOML: &str = r#"
g_loc = 9.80101
units = "counts"
method = "free"
[device]
sensitivity = [1669.32, 1669.10, 1676.46]
angles_deg = [90.077, 90.095, 89.910]
offsets = [525.1, 99.6, 442.4]
[timing]
sample_rate_hz = 104.0
"#;

/// The sensor's output stage unless a test gives its own `[sensor]`.
const SENSOR_TOML: &str = "[sensor]\nlsb = 1.0\nfull_scale = [-32768.0, 32767.0]\n";

/// A random rotation matrix (a uniformly random unit quaternion).
fn random_rotation(rng: &mut ChaCha8Rng) -> [[f64; 3]; 3] {
    let mut q = [0.0f64; 4];
    for v in &mut q {
        *v = rand_distr::Distribution::sample(&rand_distr::StandardNormal, rng);
    }
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    let [w, x, y, z] = q.map(|v| v / n);
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - z * w),
            2.0 * (x * z + y * w),
        ],
        [
            2.0 * (x * y + z * w),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - x * w),
        ],
        [
            2.0 * (x * z - y * w),
            2.0 * (y * z + x * w),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

fn matrix_toml(m: &[[f64; 3]; 3]) -> String {
    format!(
        "[[{:?}, {:?}, {:?}], [{:?}, {:?}, {:?}], [{:?}, {:?}, {:?}]]",
        m[0][0], m[0][1], m[0][2], m[1][0], m[1][1], m[1][2], m[2][0], m[2][1], m[2][2]
    )
}

fn sim(extra: &str) -> Simulation {
    let sensor = if extra.contains("[sensor]") {
        ""
    } else {
        SENSOR_TOML
    };
    // Top-level keys (the seed) before the tables.
    let (top, tables) = match extra.find('[') {
        Some(i) => extra.split_at(i),
        None => (extra, ""),
    };
    let cfg: Config = toml::from_str(&format!("{top}\n{TRUTH_TOML}\n{sensor}{tables}")).unwrap();
    Simulation::new(cfg).unwrap()
}

/// One realistic session of `poses` poses.
fn session(poses: usize, seed: u64) -> Simulation {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed);
    let rho: f64 = rng.gen_range(0.0..0.8);
    let sd = [0; 3].map(|_| rng.gen_range(7.0..14.0));
    let mount = random_rotation(&mut rng);
    sim(&format!(
        "seed = {seed}\n[mounting]\nmatrix = {}\n[sensor.noise]\nar = [{rho:?}]\nsd = [{:?}, {:?}, {:?}]\nstate = false\n\
         [poses]\ncount = {poses}\nstill_s = 3.0\nmove_s = 1.5\nnoise_spread = 1.5\nsettle_ms2 = 0.5\n",
        matrix_toml(&mount),
        sd[0],
        sd[1],
        sd[2]
    ))
}

fn entry(c: &CalibrationJson) -> &rotacal::calibrate::json::RateJson {
    c.by_rate.first().unwrap()
}

fn coverage(name: &str, poses: usize, trials: usize) {
    coverage_with(name, poses, trials, &Options::default());
}

/// Two-sided coverage of the nine properties over `trials` sessions of `poses` poses,
/// calibrated with `opts`: the proof `name`.
fn coverage_with(name: &str, poses: usize, trials: usize, opts: &Options) {
    coverage_of(name, poses, (trials, true), opts, |seed| {
        session(poses, seed)
    });
}

/// The coverage of `trials` sessions `make(seed)` of `poses` poses, calibrated with
/// `opts`; the offsets against the bias plus the slow noise's mean over the record's
/// readings (their measurand, docs/uncertainty.md); with `bound_lost`, at most 1 % of the
/// poses lost.
fn coverage_of(
    name: &str,
    poses: usize,
    (trials, bound_lost): (usize, bool),
    opts: &Options,
    make: impl Fn(u64) -> Simulation + Sync,
) {
    let names = vec![
        "s_u", "s_v", "s_w", "φ_uv", "φ_vw", "φ_wu", "O_u", "O_v", "O_w",
    ];
    let truth = make(0).truth().properties().to_vec();
    let trial = |i: usize| {
        let s = make(1000 * poses as u64 + i as u64);
        assert_eq!(s.truth().properties().to_vec(), truth);
        let (summary, buf) = s.write(Vec::new()).unwrap();
        let rec = rotacal::recording::read_bytes(&buf, "simulated").unwrap();
        // `--slow-noise` refuses a fit with fewer than 24 poses kept: the poses it kept.
        let cal = match calibrate(&rec, opts) {
            Ok(cal) => cal,
            Err(e) => match *e.kind {
                rotacal::calibrate::CalibrateErrorKind::FreeSlowPoses { kept, .. } => {
                    return Err(kept)
                }
                _ => panic!("{e}"),
            },
        };
        let e = entry(&cal);
        let f = e.free.as_ref().unwrap();
        let kept = f.poses.len();
        let mut q: Vec<rotacal::calibrate::json::Quantity> =
            e.intrinsic.quantities().into_iter().copied().collect();
        // Against the fixed truth: the estimate less the slow noise's share of its measurand.
        for (o, m) in q.iter_mut().skip(6).zip(summary.slow_mean) {
            o.value -= m;
        }
        let why: Vec<String> = f.detection[0]
            .intervals
            .iter()
            .filter(|i| i.interval.verdict != Verdict::Kept)
            .map(|i| i.reason.split(':').next().unwrap_or("").to_string())
            .collect();
        let wander = e.uncertainty_budget.as_ref().is_some_and(|b| {
            b.sources
                .iter()
                .any(|s| s.source == "bias_wander" && s.contribution.iter().any(|c| *c > 0.0))
        });
        Ok((q, kept, f.tau_ms2 > 0.0, why, wander))
    };
    prove(name, trials, trial, |results| {
        tally(poses, names, truth.clone(), results, bound_lost)
    });
}

/// One free session's properties, its poses kept, whether τ was added, why poses were left
/// out, and whether it has a bias_wander line.
type FreeRun = (
    Vec<rotacal::calibrate::json::Quantity>,
    usize,
    bool,
    Vec<String>,
    bool,
);

/// The coverage of `results` of `poses` poses each (a refused session: the poses it kept),
/// and the poses lost: the failures.
fn tally(
    poses: usize,
    names: Vec<&'static str>,
    truth: Vec<f64>,
    results: &[Result<FreeRun, usize>],
    bound_lost: bool,
) -> Vec<String> {
    let trials = results.len();
    let mut tally = Tally::new(names, truth);
    let (mut lost, mut scatter) = (0usize, 0usize);
    let mut reasons: std::collections::BTreeMap<String, usize> = Default::default();
    let refused: Vec<usize> = results
        .iter()
        .filter_map(|r| r.as_ref().err())
        .copied()
        .collect();
    lost += refused.iter().map(|kept| poses - kept).sum::<usize>();
    let results: Vec<&FreeRun> = results.iter().filter_map(|r| r.as_ref().ok()).collect();
    let wandered = results.iter().filter(|r| r.4).count();
    for (q, kept, tau, why, _) in results {
        tally.add(&q.iter().collect::<Vec<_>>());
        lost += poses - kept;
        scatter += usize::from(*tau);
        for w in why {
            *reasons.entry(w.clone()).or_default() += 1;
        }
    }
    println!(
        "{poses} poses, {trials} sessions: {lost} poses lost in all ({reasons:?}), τ added in \
         {scatter} sessions, a bias_wander line in {wandered}, {} refused (too few poses \
         kept for --slow-noise)",
        refused.len()
    );
    let mut failures: Vec<String> = tally
        .check()
        .into_iter()
        .map(|f| format!("{poses} poses: {f}"))
        .collect();
    // Poses are found: the moved test alone would lose 3e-4 of them; the ring-down after
    // each placement, decayed to about e⁻⁵ where the kept part begins, adds to that.
    // At most 1 % lost.
    if bound_lost && lost * 100 > poses * trials {
        failures.push(format!("{poses} poses: {lost} poses lost"));
    }
    failures
}

#[test]
fn coverage_12_poses() {
    coverage("free_method::coverage_12_poses", 12, 1000);
}

#[test]
fn coverage_24_poses() {
    coverage("free_method::coverage_24_poses", 24, 1000);
}

/// `--slow-noise` on sessions without slow noise (AR noise of 7–14 counts): the option must
/// not overstate U there (the offsets' `bias_wander` line counts only where the changes
/// demand a flicker level; docs/uncertainty.md).
#[test]
fn coverage_24_poses_with_the_slow_noise_option_and_none() {
    let slow = Options {
        slow_noise: true,
        ..Options::default()
    };
    coverage_with(
        "free_method::coverage_24_poses_with_the_slow_noise_option_and_none",
        24,
        1000,
        &slow,
    );
}

/// One session of hand placements under slow noise, the noise never stated: white noise
/// of 3–6 counts per channel, flicker at an Allan floor of `floor` µg and a bias random
/// walk of `walk` µg/√s on every channel, a hand's tremor of `tremor` m/s² at 10 Hz while
/// each pose is held, a ring-down after each placement, each pose's noise ×1.5 either way,
/// the device mounted at random.
fn hand_session(poses: usize, seed: u64, (floor, walk, tremor): (f64, f64, f64)) -> Simulation {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x510e);
    let sd = [0; 3].map(|_| rng.gen_range(3.0..6.0));
    let mount = random_rotation(&mut rng);
    sim(&format!(
        "seed = {seed}\n[mounting]\nmatrix = {}\n[sensor.noise]\nsd = [{:?}, {:?}, {:?}]\n\
         flicker_floor_ug = {floor:?}\nrandom_walk_ug_per_sqrt_s = {walk:?}\nstate = false\n\
         [poses]\ncount = {poses}\nstill_s = 3.0\nmove_s = 1.5\nnoise_spread = 1.5\n\
         settle_ms2 = 0.5\ntremor_ms2 = {tremor:?}\n",
        matrix_toml(&mount),
        sd[0],
        sd[1],
        sd[2]
    ))
}

/// Issue 30's third proof point at 24 poses: hand placements with settling, tremor,
/// flicker and a bias random walk, calibrated with `--slow-noise`: every property's
/// coverage in [0.93, 0.97], two-sided (±2.9 binomial σ at 1000 sessions), so that the
/// offsets' U is neither short (the poses' mean bias against the record's, the
/// `bias_wander` line) nor long (τ's common part, which that line replaces:
/// docs/uncertainty.md, "Free poses under slow noise"). Sessions that keep fewer than 24
/// poses are refused and counted as poses lost.
#[test]
fn coverage_24_poses_under_slow_noise() {
    let slow = Options {
        slow_noise: true,
        ..Options::default()
    };
    for (case, levels) in [
        ("flicker_45ug_walk_10ug_tremor", (45.0, 10.0, 0.02)),
        ("flicker_100ug", (100.0, 0.0, 0.0)),
        ("walk_10ug", (0.0, 10.0, 0.0)),
    ] {
        // Under slow noise the moved test and the ring-down leave out more poses than the
        // 1 % bounded without it: counted and printed, not bounded here.
        coverage_of(
            &format!("free_method::coverage_24_poses_under_slow_noise.{case}"),
            26,
            (1000, false),
            &slow,
            |seed| hand_session(26, seed, levels),
        );
    }
}

#[test]
fn coverage_60_poses() {
    coverage("free_method::coverage_60_poses", 60, 1000);
}

/// Nine poses fit the nine unknowns exactly: the output says that nothing is left to check
/// the noise model (in the budget's notes, which the terminal and the JSON carry); twelve
/// poses leave three degrees of freedom and no such note.
#[test]
fn nine_poses_say_no_degree_of_freedom_is_left() {
    let note = |poses: usize| {
        let rec = session(poses, 77).recording().unwrap();
        let cal = calibrate(&rec, &Options::default()).unwrap();
        let e = entry(&cal);
        let f = e.free.as_ref().unwrap();
        let notes = serde_json::to_string(&e.uncertainty_budget).unwrap();
        (
            f.poses.len(),
            notes.contains("no degree of freedom is left"),
        )
    };
    assert_eq!(note(9), (9, true));
    assert_eq!(note(12), (12, false));
}

#[test]
fn intrinsic_properties_do_not_depend_on_the_mounting() {
    // The same fixture directions, no noise, no quantisation; the device turned at random.
    let mut rng = ChaCha8Rng::seed_from_u64(16);
    let dirs: Vec<String> = (0..14)
        .map(|_| {
            let v = [0; 3].map(|_| rng.gen_range(-1.0..1.0f64));
            format!("[{:?}, {:?}, {:?}]", v[0], v[1], v[2])
        })
        .collect();
    let mut first: Option<[f64; 9]> = None;
    let mut worst: f64 = 0.0;
    for trial in 0..8 {
        let m = random_rotation(&mut rng);
        let s = sim(&format!(
            "seed = 3\n[sensor]\nlsb = 0.0\n[sensor.noise]\nsd = 0.0\nstate = false\n[mounting]\nmatrix = {}\n[poses]\ndirections = [{}]\nstill_s = 3.0\nmove_s = 1.5\n",
            matrix_toml(&m),
            dirs.join(", ")
        ));
        let cal = calibrate(&s.recording().unwrap(), &Options::default()).unwrap();
        let q = entry(&cal).intrinsic.quantities();
        let v: [f64; 9] = std::array::from_fn(|k| q[k].value);
        let truth = s.truth().properties();
        for k in 0..9 {
            let scale = if k >= 6 { truth[0] * 9.80101 } else { truth[k] };
            worst = worst.max((v[k] - truth[k]).abs() / scale);
            if let Some(f) = first {
                worst = worst.max((v[k] - f[k]).abs() / scale);
            }
        }
        first.get_or_insert(v);
        let f = entry(&cal).free.as_ref().unwrap();
        for i in &f.detection[0].intervals {
            if i.interval.verdict != Verdict::Kept {
                println!(
                    "trial {trial}: {} {:?} {}",
                    i.interval.name, i.interval.span_s, i.reason
                );
            }
        }
        assert_eq!(f.poses.len(), 14, "trial {trial}");
    }
    println!("noise-free, 8 mountings: largest relative difference {worst:.2e}");
    assert!(worst <= 1e-9, "{worst}");
}

#[test]
fn the_algebraic_residual_is_biased_at_low_signal_to_noise() {
    // 60 poses of 20 readings each with noise of 0.25 g per reading: each pose mean and
    // its standard error come from its readings, as from a recording.
    let g = 9.80101;
    let s_true = [[1.02, 0.0, 0.0], [0.01, 0.98, 0.0], [-0.02, 0.015, 1.01]];
    let o_true = [0.3, -0.2, 0.1];
    let sigma = 0.25 * g;
    let trials = 400;
    let runs = parallel_n(trials, |i| {
        let mut rng = ChaCha8Rng::seed_from_u64(9000 + i as u64);
        let mut normal =
            || -> f64 { rand_distr::Distribution::sample(&rand_distr::StandardNormal, &mut rng) };
        let poses: Vec<Pose> = (0..60)
            .map(|p| {
                let v = [normal(), normal(), normal()];
                let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
                let a = v.map(|x| g * x / n);
                let y_true =
                    [0, 1, 2].map(|j| (0..3).map(|k| s_true[j][k] * a[k]).sum::<f64>() + o_true[j]);
                let readings: Vec<[f64; 3]> = (0..20)
                    .map(|_| y_true.map(|y| y + sigma * normal()))
                    .collect();
                let mean = [0, 1, 2].map(|j| readings.iter().map(|r| r[j]).sum::<f64>() / 20.0);
                let std_err = [0, 1, 2].map(|j| {
                    (readings
                        .iter()
                        .map(|r| (r[j] - mean[j]).powi(2))
                        .sum::<f64>()
                        / 19.0
                        / 20.0)
                        .sqrt()
                });
                Pose {
                    name: format!("{p}"),
                    mean,
                    std_err,
                }
            })
            .collect();
        let sens = |r: Residual| {
            let f = free::fit(&poses, g, r).unwrap();
            [0, 1, 2].map(|j| f.l[j].iter().map(|x| x * x).sum::<f64>().sqrt())
        };
        (sens(Residual::Geometric), sens(Residual::Algebraic))
    });
    let truth = s_true.map(|r| r.iter().map(|x| x * x).sum::<f64>().sqrt());
    for (name, pick) in [("geometric", 0usize), ("algebraic", 1)] {
        let mut zs = Vec::new();
        for j in 0..3 {
            let rel: Vec<f64> = runs
                .iter()
                .map(|r| if pick == 0 { r.0[j] } else { r.1[j] } / truth[j] - 1.0)
                .collect();
            let n = rel.len() as f64;
            let m = rel.iter().sum::<f64>() / n;
            let se = (rel.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0) / n).sqrt();
            println!(
                "{name}: s_{} relative bias {m:+.3e} ± {se:.1e} (Monte Carlo se)",
                ["u", "v", "w"][j]
            );
            zs.push(m / se);
        }
        if pick == 0 {
            // Unbiased: each within 3.5 Monte Carlo standard errors (Bonferroni over six).
            assert!(zs.iter().all(|z| z.abs() < 3.5), "geometric: {zs:?}");
        } else {
            // The algebraic form: its residual's mean is off by tr(C)/(2g) and its score
            // correlates with its Jacobian, about +1 % here, far beyond.
            assert!(zs.iter().all(|z| *z > 8.0), "algebraic: {zs:?}");
        }
    }
}

/// Calibrate and expect a refusal whose message holds every `texts`.
fn refused(rec: &Recording, texts: &[&str]) {
    let e = calibrate(rec, &Options::default()).unwrap_err().to_string();
    println!("{e}\n");
    for t in texts {
        assert!(e.contains(t), "'{t}' not in: {e}");
    }
}

fn directions_toml(dirs: &[[f64; 3]]) -> String {
    let v: Vec<String> = dirs
        .iter()
        .map(|d| format!("[{:?}, {:?}, {:?}]", d[0], d[1], d[2]))
        .collect();
    format!("[{}]", v.join(", "))
}

fn quiet_session(dirs: &[[f64; 3]], extra: &str) -> Recording {
    sim(&format!(
        "seed = 5\n[sensor.noise]\nar = [0.5]\nsd = 10.0\nstate = false\n[poses]\ndirections = {}\nstill_s = 3.0\nmove_s = 1.5\n{extra}",
        directions_toml(dirs)
    ))
    .recording()
    .unwrap()
}

#[test]
fn bad_geometry_is_refused_or_flagged_by_name() {
    let deg = |a: f64| a.to_radians();
    // A rotation about one axis: twelve directions on a great circle.
    let circle: Vec<[f64; 3]> = (0..12)
        .map(|k| {
            let a = deg(30.0 * k as f64);
            [a.cos(), a.sin(), 0.0]
        })
        .collect();
    refused(
        &quiet_session(&circle, ""),
        &[
            "under-determined",
            "one plane",
            "one circle",
            "add poses with gravity near",
        ],
    );
    // A cone: twelve directions 40° above the horizontal, all in one plane.
    let cone: Vec<[f64; 3]> = (0..12)
        .map(|k| {
            let a = deg(30.0 * k as f64);
            let e = deg(40.0);
            [e.cos() * a.cos(), e.cos() * a.sin(), e.sin()]
        })
        .collect();
    refused(
        &quiet_session(&cone, ""),
        &[
            "under-determined",
            "one plane",
            "one circle",
            "add poses with gravity near",
        ],
    );
    // Eight poses.
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    let eight: Vec<[f64; 3]> = (0..8)
        .map(|_| [0; 3].map(|_| rng.gen_range(-1.0..1.0f64)))
        .collect();
    refused(
        &quiet_session(&eight, ""),
        &[
            "8 still pose(s) in 8 distinct orientation(s)",
            "at least nine",
            "add poses with gravity near",
        ],
    );
    // Twelve poses on the upper half only: fitted, but flagged.
    let upper: Vec<[f64; 3]> = (0..12)
        .map(|k| {
            let a = deg(47.0 * k as f64);
            let e = deg(20.0 + 5.0 * k as f64);
            [e.cos() * a.cos(), e.cos() * a.sin(), e.sin()]
        })
        .collect();
    let cal = calibrate(&quiet_session(&upper, ""), &Options::default()).unwrap();
    let f = entry(&cal).free.as_ref().unwrap();
    println!(
        "hemisphere: condition number {:.1}, suggestion {:?}",
        f.condition_number, f.suggestion
    );
    assert!(f.condition_number > free::WELL_CONDITIONED);
    assert!(
        f.suggestion.as_ref().is_some_and(|s| s.contains('−')),
        "{:?}",
        f.suggestion
    );
    let notes = &entry(&cal).uncertainty_budget.as_ref().unwrap().notes;
    assert!(
        notes.iter().any(|n| n.contains("badly conditioned")),
        "{notes:?}"
    );
}

fn random_dirs(n: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| [0; 3].map(|_| rng.gen_range(-1.0..1.0f64)))
        .collect()
}

#[test]
fn a_pose_that_moved_is_named_and_left_out() {
    let dirs = random_dirs(14, 14);
    let rec = quiet_session(&dirs, "moved = { pose = 4, deg = 0.5 }\n");
    let cal = calibrate(&rec, &Options::default()).unwrap();
    let f = entry(&cal).free.as_ref().unwrap();
    let ivs = &f.detection[0].intervals;
    let moved: Vec<&str> = ivs
        .iter()
        .filter(|i| matches!(i.interval.verdict, Verdict::Moved { .. }))
        .map(|i| i.interval.name.as_str())
        .collect();
    println!("moved: {moved:?}: {}", ivs[4].reason);
    assert_eq!(moved, ["still 5"]);
    assert!(ivs[4].reason.starts_with("moved"));
    assert_eq!(f.poses.len(), 13);
}

#[test]
fn a_pose_that_does_not_fit_is_named_and_left_out() {
    let dirs = random_dirs(16, 16);
    let mut rec = quiet_session(&dirs, "");
    // Pose 7 (still from 6·4.5 s): the device leant on something, 5e-3 g more on u.
    let s = rec.series.as_mut().unwrap();
    for (t, y) in s.t_s.iter().zip(s.y.iter_mut()) {
        if (31.5..34.5).contains(t) {
            y[0] += 5e-3 * 9.80101 * 1669.32;
        }
    }
    let cal = calibrate(&rec, &Options::default()).unwrap();
    let f = entry(&cal).free.as_ref().unwrap();
    let bad: Vec<(&str, &str)> = f.detection[0]
        .intervals
        .iter()
        .filter(|i| matches!(i.interval.verdict, Verdict::DoesNotFit { .. }))
        .map(|i| (i.interval.name.as_str(), i.reason.as_str()))
        .collect();
    println!("{bad:?}");
    assert_eq!(bad.len(), 1);
    assert_eq!(bad[0].0, "still 8");
    assert_eq!(f.poses.len(), 15);
    // What is left agrees with the truth.
    let truth = sim("seed = 1\n[poses]\ncount = 1\n").truth().properties();
    for (q, t) in entry(&cal).intrinsic.quantities().iter().zip(truth) {
        assert!(
            (q.value - t).abs() <= 1.5 * q.expanded_unc,
            "{} vs {t} ± {}",
            q.value,
            q.expanded_unc
        );
    }
}

fn data() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/imucal-ferraris")
}

#[test]
fn imucal_session_without_a_section_list() {
    let tmp = std::env::temp_dir().join(format!("rotacal-free-imucal-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    let out = tmp.join("free.csv");
    let d = data();
    let (ok, stdout, stderr) = common::run(&[
        "import".as_ref(),
        d.join("example_ferraris_session.csv").as_os_str(),
        "--columns".as_ref(),
        "t=0,u=4,v=5,w=6".as_ref(),
        "--skip".as_ref(),
        "1".as_ref(),
        "--time-scale".as_ref(),
        "0.009765625".as_ref(),
        "--g-loc".as_ref(),
        "9.81".as_ref(),
        "--units".as_ref(),
        "m/s^2".as_ref(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    assert!(ok, "{stderr}");
    println!("{stdout}");
    let rec = rotacal::recording::read(&out).unwrap();
    assert_eq!(rec.method, Method::Free);
    let s = rec.series.as_ref().unwrap();
    let det = still::detect(&s.t_s, &s.y, &s.line, still::Options::default()).unwrap();
    // imucal's own section list (data-row positions, end exclusive).
    let list: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(d.join("example_ferraris_session_list.json")).unwrap(),
    )
    .unwrap();
    let section = |n: &str| {
        let x = &list[n];
        (
            x["start"].as_u64().unwrap() as usize,
            x["end"].as_u64().unwrap() as usize,
        )
    };
    println!(
        "noise sd {:?}, {:.0} % still",
        det.noise_sd,
        100.0 * det.still_fraction
    );
    for i in &det.intervals {
        println!(
            "{} rows {:?} ({:.2}–{:.2} s) n {} mean {:?}: {:?}",
            i.name, i.rows, i.span_s.0, i.span_s.1, i.n, i.mean, i.verdict
        );
    }
    let kept: Vec<&still::Interval> = det
        .intervals
        .iter()
        .filter(|i| i.verdict == Verdict::Kept)
        .collect();
    // Every still section of imucal's list lies in a kept interval that covers most of it.
    for name in ["x_p", "x_a", "y_p", "y_a", "z_p", "z_a"] {
        let (a, b) = section(name);
        let best = kept
            .iter()
            .map(|i| i.rows.1.min(b).saturating_sub(i.rows.0.max(a)))
            .max()
            .unwrap();
        println!("{name}: {best} of {} rows in one kept interval", b - a);
        assert!(best * 10 >= (b - a) * 8, "{name}");
    }
    // The rotations: no kept interval overlaps them.
    for name in ["x_rot", "y_rot", "z_rot"] {
        let (a, b) = section(name);
        for i in &kept {
            assert!(i.rows.1 <= a || i.rows.0 >= b, "{name} overlaps {}", i.name);
        }
    }
    // Six orientations cannot give nine properties: refused, with the directions to add.
    let (ok, _, stderr) = common::run(&["calibrate".as_ref(), out.as_os_str()]);
    println!("{stderr}");
    assert!(!ok);
    assert!(
        stderr.contains(&format!(
            "{} still pose(s) in 6 distinct orientation(s)",
            kept.len()
        )),
        "{stderr}"
    );
    assert!(stderr.contains("add poses with gravity near ("), "{stderr}");
}

/// Names of the intervals left out as moved.
fn moved_names(cal: &CalibrationJson) -> Vec<String> {
    let f = entry(cal).free.as_ref().unwrap();
    f.detection
        .iter()
        .flat_map(|d| &d.intervals)
        .filter(|i| matches!(i.interval.verdict, Verdict::Moved { .. }))
        .map(|i| i.interval.name.clone())
        .collect()
}

/// A session of 28 poses still for 6 s, 4 counts of white noise with a 45 µg flicker floor
/// and a 10 µg/√s bias random walk (never stated), a ring-down after each placement, and
/// `extra` in `[poses]`.
fn slow_session(seed: u64, extra: &str) -> Recording {
    sim(&format!(
        "seed = {seed}\n[sensor.noise]\nsd = 4.0\nflicker_floor_ug = 45.0\n\
         random_walk_ug_per_sqrt_s = 10.0\nstate = false\n\
         [poses]\ncount = 28\nstill_s = 6.0\nmove_s = 3.0\nsettle_ms2 = 0.5\n{extra}"
    ))
    .recording()
    .unwrap()
}

/// `--slow-noise` with 12 poses (3 residual degrees of freedom) is refused, saying why and
/// how many poses it needs: measured, such fits covered 0.79–0.93 under slow noise because
/// the scatter between placements goes unseen (docs/uncertainty.md, "Free poses under slow
/// noise"). Without the option the same recording calibrates; with 28 poses the option is
/// taken.
#[test]
fn slow_noise_with_too_few_free_poses_is_refused() {
    let twelve = sim(
        "seed = 1201\n[sensor.noise]\nsd = 4.0\nflicker_floor_ug = 45.0\nstate = false\n\
         [poses]\ncount = 12\nstill_s = 3.0\nmove_s = 1.5\n",
    )
    .recording()
    .unwrap();
    let slow = Options {
        slow_noise: true,
        ..Options::default()
    };
    let e = calibrate(&twelve, &slow).unwrap_err();
    assert!(
        matches!(
            *e.kind,
            rotacal::calibrate::CalibrateErrorKind::FreeSlowPoses { kept: 12, .. }
        ),
        "{e}"
    );
    let text = e.to_string();
    for part in [
        "12 poses kept",
        "at least 24",
        "P − 9 = 3",
        "without --slow-noise",
    ] {
        assert!(text.contains(part), "{part:?} not in {text}");
    }
    assert!(calibrate(&twelve, &Options::default()).is_ok());
    assert!(calibrate(&slow_session(1202, ""), &slow).is_ok());
}

/// `--slow-noise` in the moved test (docs/uncertainty.md, "Slow noise in the moved test").
/// Over 20 sessions (560 still intervals) with slow noise, the AR model alone calls many
/// still intervals moved; with the option at most 1 % may be (its design target: the
/// binomial 99.9 % point at p = 0.01 is 14 of 560). A pose that turns 0.5° over its 6 s is
/// still named in every session, under the same noise. (28 poses: with a pose or two left
/// out, at least 24 remain for the option's fit.)
#[test]
fn slow_noise_keeps_still_intervals_and_still_names_a_moved_pose() {
    let slow = Options {
        slow_noise: true,
        ..Options::default()
    };
    let counts = parallel_n(20, |i| {
        let rec = slow_session(0x51F7_0000 + i as u64, "");
        let without = moved_names(&calibrate(&rec, &Options::default()).unwrap()).len();
        let with = moved_names(&calibrate(&rec, &slow).unwrap()).len();
        let rec = slow_session(0x51F8_0000 + i as u64, "moved = { pose = 4, deg = 0.5 }\n");
        let named = moved_names(&calibrate(&rec, &slow).unwrap());
        (
            without,
            with,
            named.contains(&"still 5".to_string()),
            named.len(),
        )
    });
    let without: usize = counts.iter().map(|c| c.0).sum();
    let with: usize = counts.iter().map(|c| c.1).sum();
    let found = counts.iter().filter(|c| c.2).count();
    let others: usize = counts.iter().map(|c| c.3 - usize::from(c.2)).sum();
    println!(
        "still intervals called moved: {without}/560 without the option, {with}/560 with; \
         the turning pose named in {found}/20 (other intervals moved there: {others}/540)"
    );
    assert!(without >= 56, "the sessions barely need it: {without}/560");
    assert!(with <= 14, "{with}/560 still intervals called moved");
    assert_eq!(found, 20);
}

/// imu_tk's Xsens recording (host/tests/data/imutk-xsens; BSD, Tedaldi et al. 2014): 39
/// still intervals (the first 51 s and 38 placements). The AR model alone leaves 13 out as
/// moved, some by 1–3 counts of slow drift; with `--slow-noise` (flicker floors of 0.20,
/// 0.33 and 0.79 counts from the changes, beside 0.27, 0.32 and 0.54 counts in the first
/// 51 s's Allan deviation, `rotacal allan --to 51`) only the two that change by 3.9 and
/// 9.4 counts, 5.6 and 4.4 standard errors.
#[test]
fn imutk_xsens_placements_with_slow_noise() {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/imutk-xsens/xsens_acc_free.csv");
    let rec = rotacal::recording::read(&path).unwrap();
    let plain = calibrate(&rec, &Options::default()).unwrap();
    let slow = calibrate(
        &rec,
        &Options {
            slow_noise: true,
            ..Options::default()
        },
    )
    .unwrap();
    let f = entry(&slow).free.as_ref().unwrap();
    let total: usize = f.detection.iter().map(|d| d.intervals.len()).sum();
    println!(
        "{total} intervals; moved without the option: {:?}; with: {:?}",
        moved_names(&plain),
        moved_names(&slow)
    );
    for d in &f.detection {
        for i in &d.intervals {
            if i.interval.verdict != Verdict::Kept {
                println!("  {}: {}", i.interval.name, i.reason);
            }
        }
    }
    assert_eq!(total, 39);
    assert_eq!(moved_names(&plain).len(), 13);
    assert_eq!(moved_names(&slow), ["still 11", "still 28"]);
    assert_eq!(f.poses.len(), 37);
}
