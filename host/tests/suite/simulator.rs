//! The simulator against an independent implementation of docs/simulator.md, its
//! randomness (seeded, and with the stated statistics), its presets (calibrated back to
//! their truth) and its configuration errors.
// Matrix arithmetic on small fixed arrays reads more plainly with indices.
#![allow(clippy::needless_range_loop)]

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rotacal::calibrate::{self, Options};
use rotacal::recording::{Group, Recording};
use rotacal::simulate::{Config, Simulation};
use rotacal_shared::Channel;
use statrs::distribution::{ChiSquared, ContinuousCDF};
use std::f64::consts::{PI, SQRT_2, TAU};
use std::process::Command;

fn sim(toml: &str) -> Simulation {
    Simulation::new(Config::from_toml(toml).unwrap()).unwrap()
}

fn rec(s: &Simulation) -> Recording {
    s.recording().unwrap()
}

/// Rotation by `deg` about x, then y, then z (R = Rz·Ry·Rx): a different construction from
/// the library's axis-angle formula.
fn rot_xyz(dx: f64, dy: f64, dz: f64) -> [[f64; 3]; 3] {
    let (sx, cx) = dx.to_radians().sin_cos();
    let (sy, cy) = dy.to_radians().sin_cos();
    let (sz, cz) = dz.to_radians().sin_cos();
    let rx = [[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]];
    let ry = [[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]];
    let rz = [[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]];
    mul(&rz, &mul(&ry, &rx))
}

fn mul(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut m = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    m
}

fn fmt_matrix(m: &[[f64; 3]; 3]) -> String {
    format!(
        "[[{:?}, {:?}, {:?}], [{:?}, {:?}, {:?}], [{:?}, {:?}, {:?}]]",
        m[0][0], m[0][1], m[0][2], m[1][0], m[1][1], m[1][2], m[2][0], m[2][1], m[2][2]
    )
}

/// ĝ(α) per condition (docs/method.md §1), written out again.
fn g_hat(cond: usize, a: f64) -> [f64; 3] {
    match cond {
        0 => [0.0, a.sin(), a.cos()],
        1 => [a.sin(), 0.0, a.cos()],
        _ => [a.sin(), a.cos(), 0.0],
    }
}

const S: [[f64; 3]; 3] = [
    [1650.0, 12.0, -8.0],
    [-6.0, 1680.0, 15.0],
    [9.0, -4.0, 1700.0],
];
const O: [f64; 3] = [300.0, -150.0, 60.0];
const G: f64 = 9.81;

/// Everything on at once (rotation, two rates, noise-free), compared value by value with
/// the model written out in this test.
#[test]
fn rotation_with_every_effect_matches_an_independent_model() {
    let r = rot_xyz(2.0, -3.0, 4.0);
    let toml = format!(
        r#"
seed = 5
g_loc = {G}
[device]
matrix = {s}
offsets = [{o0}, {o1}, {o2}]
[mounting]
matrix = {r}
[sensor]
noise_sigma = 0.0
lsb = 0.0
full_scale = [-1e9, 1e9]
[timing]
sample_rate_hz = 10.0
clock_error_ppm = 250.0
tick_hz = 1e9
gap_s = 7.5
[table]
rates_hz = [0.02, 0.3]
samples_per_condition = 600
start_angle_deg = [10.0, 200.0, 300.0]
[temperature]
t0_c = 22.0
ramp_c_per_h = 3.0
swing_c = 0.4
period_s = 500.0
resolution_c = 0.0
[effects.rate_error]
relative = 2e-4
[effects.offset_drift]
per_s = [0.01, -0.02, 0.005]
[effects.temperature_offset]
per_c = [3.0, -2.0, 1.0]
[effects.nonlinearity_2nd]
k2 = [1e-3, -2e-3, 5e-4]
[effects.nonlinearity_3rd]
k3 = [-1e-4, 2e-4, 3e-4]
[effects.centripetal]
radius_m = 0.22
directions = [[0.0, 1.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
[effects.axis_time_skew]
skew_s = [0.0, 0.004, -0.002]
[effects.rate_ripple]
relative = 0.01
phase_deg = 30.0
"#,
        s = fmt_matrix(&S),
        r = fmt_matrix(&r),
        o0 = O[0],
        o1 = O[1],
        o2 = O[2],
    );
    let simulation = sim(&toml);
    let recording = rec(&simulation);
    // Platter-frame matrix S·Rᵀ.
    let mut sp = [[0.0; 3]; 3];
    for j in 0..3 {
        for k in 0..3 {
            sp[j][k] = (0..3).map(|m| S[j][m] * r[k][m]).sum();
        }
    }
    let dirs = [[0.0, 1.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]].map(|d: [f64; 3]| {
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        d.map(|v| v / n)
    });
    let k2 = [1e-3, -2e-3, 5e-4];
    let k3 = [-1e-4, 2e-4, 3e-4];
    let drift = [0.01, -0.02, 0.005];
    let tc = [3.0, -2.0, 1.0];
    let skew = [0.0, 0.004, -0.002];
    let start = [10.0f64, 200.0, 300.0].map(f64::to_radians);
    let (n, fs, gap) = (600usize, 10.0, 7.5);
    assert_eq!(recording.groups.len(), 6);
    let mut worst = 0.0f64;
    for (gi, g) in recording.groups.iter().enumerate() {
        assert_eq!(g.len(), n);
        let rate = [0.02, 0.3][gi / 3];
        assert_eq!(g.rate_hz, Some(rate));
        let cond = g.condition.index();
        assert_eq!(cond, gi % 3);
        let omega = TAU * rate * (1.0 + 2e-4);
        let tg = gi as f64 * (n as f64 / fs + gap);
        let seq = g.seq.as_ref().unwrap();
        let temp = g.temp_c.as_ref().unwrap();
        for k in 0..n {
            assert_eq!(seq[k], (gi * n + k) as u64);
            let tau = k as f64 / fs;
            let t = tg + tau;
            let ts = ((1.0 + 250e-6) * t * 1e9).round() / 1e9;
            assert!(
                (g.t_s[k] - ts).abs() <= 1e-12 * ts.max(1.0),
                "t_s {} vs {ts}",
                g.t_s[k]
            );
            let temp_t = 22.0 + 3.0 * t / 3600.0 + 0.4 * (TAU * t / 500.0).sin();
            assert!((temp[k] - temp_t).abs() < 1e-12);
            let y = [g.u[k], g.v[k], g.w[k]];
            for j in 0..3 {
                let tj = tau + skew[j];
                let psi = 30f64.to_radians();
                let alpha =
                    start[cond] + omega * tj + 0.01 * ((omega * tj + psi).sin() - psi.sin());
                let gh = g_hat(cond, alpha);
                let f: Vec<f64> = (0..3)
                    .map(|i| G * gh[i] - omega * omega * 0.22 * dirs[cond][i])
                    .collect();
                let sj = (sp[j][0].powi(2) + sp[j][1].powi(2) + sp[j][2].powi(2)).sqrt();
                let a = (0..3).map(|i| sp[j][i] * f[i]).sum::<f64>() / sj;
                let want = sj * (a + k2[j] * a * a + k3[j] * a * a * a)
                    + O[j]
                    + drift[j] * t
                    + tc[j] * (temp_t - 22.0);
                worst = worst.max((y[j] - want).abs() / want.abs().max(1.0));
            }
        }
    }
    assert!(worst < 1e-11, "worst relative difference {worst:e}");
    // The truth the simulation reports is the device's, not the mounted matrix's.
    let t = simulation.truth();
    let sn = S.map(|row| (row[0] * row[0] + row[1] * row[1] + row[2] * row[2]).sqrt());
    for j in 0..3 {
        assert!((t.sensitivity[j] - sn[j]).abs() < 1e-9);
    }
    let uv = ((0..3).map(|i| S[0][i] * S[1][i]).sum::<f64>() / (sn[0] * sn[1]))
        .acos()
        .to_degrees();
    assert!((t.angles_deg[0] - uv).abs() < 1e-9);
}

/// The effects outside the discrepancy workflow's catalogue (a higher-order response, an
/// offset step, a nodding axis), compared value by value with the model written out here.
#[test]
fn effects_outside_the_catalogue_match_an_independent_model() {
    let toml = format!(
        r#"
seed = 6
g_loc = {G}
[device]
matrix = {s}
offsets = [{o0}, {o1}, {o2}]
[sensor]
noise_sigma = 0.0
lsb = 0.0
full_scale = [-1e9, 1e9]
[timing]
sample_rate_hz = 10.0
tick_hz = 1e9
gap_s = 5.0
[table]
rates_hz = [0.05]
samples_per_condition = 400
start_angle_deg = [10.0, 200.0, 300.0]
[effects.nonlinearity_high]
order = 5
k = [1e-6, -2e-6, 3e-6]
[effects.offset_step]
at_s = 57.25
size = [4.0, -7.0, 0.5]
[effects.axis_wobble]
tilt_deg = 0.3
phase_deg = 20.0
"#,
        s = fmt_matrix(&S),
        o0 = O[0],
        o1 = O[1],
        o2 = O[2],
    );
    let recording = rec(&sim(&toml));
    let k5 = [1e-6, -2e-6, 3e-6];
    let step = [4.0, -7.0, 0.5];
    let start = [10.0f64, 200.0, 300.0].map(f64::to_radians);
    let (n, fs, gap, omega) = (400usize, 10.0, 5.0, TAU * 0.05);
    let sn = S.map(|row| (row[0] * row[0] + row[1] * row[1] + row[2] * row[2]).sqrt());
    let (mut worst, mut stepped) = (0.0f64, 0usize);
    for (gi, g) in recording.groups.iter().enumerate() {
        let tg = gi as f64 * (n as f64 / fs + gap);
        for k in 0..n {
            let tau = k as f64 / fs;
            let t = tg + tau;
            let alpha = start[gi] + omega * tau;
            let theta = 0.3f64.to_radians() * (2.0 * alpha + 20f64.to_radians()).sin();
            let mut gh = g_hat(gi, alpha).map(|v| v * theta.cos());
            gh[gi] += theta.sin();
            let y = [g.u[k], g.v[k], g.w[k]];
            for j in 0..3 {
                let a = (0..3).map(|i| S[j][i] * G * gh[i]).sum::<f64>() / sn[j];
                let jump = if t >= 57.25 { step[j] } else { 0.0 };
                let want = sn[j] * (a + k5[j] * a.powi(5)) + O[j] + jump;
                worst = worst.max((y[j] - want).abs() / want.abs().max(1.0));
            }
            stepped += usize::from(t >= 57.25);
        }
    }
    assert!(worst < 1e-11, "worst relative difference {worst:e}");
    // The step falls inside the y condition's group (45 s + 12.3 s): 277 of its rows and
    // all of z's.
    assert_eq!(stepped, 277 + n);
}

/// The static method's timing and effects, with repeated readings and an angle list.
#[test]
fn static_with_effects_matches_an_independent_model() {
    let toml = format!(
        r#"
method = "static"
g_loc = {G}
units = "V"
[device]
matrix = {s}
offsets = [0.1, -0.2, 0.3]
[mounting]
axis = [0.0, 0.0, 1.0]
angle_deg = 90.0
[sensor]
noise_sigma = 0.0
lsb = 0.0
full_scale = [-1e9, 1e9]
[timing]
sample_rate_hz = 2.0
gap_s = 100.0
[table]
angles_deg = [0.0, 30.0, 90.0, 200.0]
readings_per_angle = 3
dwell_s = 5.0
[temperature]
ramp_c_per_h = 36.0
resolution_c = 0.0
[effects.offset_drift]
per_s = [1e-4, 0.0, -1e-4]
[effects.temperature_offset]
per_c = [0.0, 0.01, 0.0]
[effects.nonlinearity_2nd]
k2 = [1e-3, 0.0, 0.0]
"#,
        s = fmt_matrix(&S.map(|r| r.map(|v| v * 1e-4)))
    );
    let recording = rec(&sim(&toml));
    // 90° about z, written as a matrix: R = [[0,-1,0],[1,0,0],[0,0,1]]; S·Rᵀ.
    let sp = S.map(|r| [-r[1] * 1e-4, r[0] * 1e-4, r[2] * 1e-4]);
    let angles = [0.0f64, 30.0, 90.0, 200.0];
    for (c, g) in recording.groups.iter().enumerate() {
        assert_eq!(g.len(), 12);
        let tg = c as f64 * (4.0 * 5.0 + 100.0);
        for row in 0..12 {
            let (k, r) = (row / 3, row % 3);
            assert_eq!(g.angle_deg[row], angles[k]);
            let t = tg + k as f64 * 5.0 + r as f64 / 2.0;
            assert!((g.t_s[row] - t).abs() < 1e-9);
            let temp = 25.0 + 36.0 * t / 3600.0;
            let f = g_hat(c, angles[k].to_radians()).map(|v| G * v);
            let y = [g.u[row], g.v[row], g.w[row]];
            for j in 0..3 {
                let sj = (sp[j][0].powi(2) + sp[j][1].powi(2) + sp[j][2].powi(2)).sqrt();
                let a = (0..3).map(|i| sp[j][i] * f[i]).sum::<f64>() / sj;
                let k2 = [1e-3, 0.0, 0.0][j];
                let want = sj * (a + k2 * a * a)
                    + [0.1, -0.2, 0.3][j]
                    + [1e-4, 0.0, -1e-4][j] * t
                    + [0.0, 0.01, 0.0][j] * (temp - 25.0);
                assert!((y[j] - want).abs() < 1e-12, "{} vs {want}", y[j]);
            }
        }
    }
}

/// Rails, quantisation and the register range act in that order, and are counted.
#[test]
fn saturation_quantisation_and_range() {
    let base = format!(
        r#"
g_loc = {G}
[device]
matrix = {s}
offsets = [300.0, -150.0, 60.0]
[sensor]
noise_sigma = 0.0
lsb = 0.5
full_scale = [-16000.0, 16000.5]
[table]
samples_per_condition = 1000
rates_hz = [0.05]
"#,
        s = fmt_matrix(&S)
    );
    let plain = sim(&base);
    let (sum0, _) = plain.write(Vec::new()).unwrap();
    let clipped = sim(&(base.clone() + "[effects.saturation]\nrails = [-15000.0, 15500.2]\n"));
    let (sum1, _) = clipped.write(Vec::new()).unwrap();
    let (a, b) = (rec(&plain), rec(&clipped));
    let mut at_rails = 0u64;
    let mut at_range = 0u64;
    for (ga, gb) in a.groups.iter().zip(&b.groups) {
        for (ya, yb) in [(&ga.u, &gb.u), (&ga.v, &gb.v), (&ga.w, &gb.w)] {
            for (x, y) in ya.iter().zip(yb.iter()) {
                assert_eq!((x / 0.5).fract(), 0.0, "{x} not a multiple of the lsb");
                if *x == -16000.0 || *x == 16000.5 {
                    at_range += 1;
                }
                // Rails, then rounding to the lsb.
                let want = (x.clamp(-15000.0, 15500.2) / 0.5).round() * 0.5;
                assert_eq!(*y, want);
                if *y != *x {
                    at_rails += 1;
                }
            }
        }
    }
    // S·ĝ·g reaches about 1700·9.81 + 300 ≈ 16980: both stages must have clipped.
    assert!(at_range > 0 && at_rails > 0);
    assert_eq!(sum0.clipped, at_range);
    assert!(sum1.clipped >= at_rails);
}

/// Same seed, same bytes; another seed, other bytes; the CLI's --seed overrides.
#[test]
fn seeded_and_reproducible() {
    let cfg = Config::preset("paper-10mhz").unwrap();
    let one = Simulation::new(cfg.clone())
        .unwrap()
        .write(Vec::new())
        .unwrap()
        .1;
    let two = Simulation::new(cfg.clone())
        .unwrap()
        .write(Vec::new())
        .unwrap()
        .1;
    assert_eq!(one, two);
    let mut other = cfg;
    other.seed += 1;
    let three = Simulation::new(other).unwrap().write(Vec::new()).unwrap().1;
    assert_ne!(one, three);

    let dir = std::env::temp_dir().join(format!("rotacal-sim-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("a.csv");
    let status = Command::new(env!("CARGO_BIN_EXE_rotacal"))
        .args(["simulate", "paper-10mhz", "--seed", "2022", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(status.status.success());
    assert_eq!(std::fs::read(&out).unwrap(), one, "preset seed is 2022");
    std::fs::remove_dir_all(&dir).ok();
}

/// Noise (the LSM6DS33 default, plus quantisation), jitter and drops have the stated
/// statistics. Bounds are ±5 standard errors of each estimate.
#[test]
fn noise_jitter_and_drops_have_the_stated_statistics() {
    let cfg = Config::from_toml(
        r#"
preset = "paper-10mhz"
seed = 77
[table]
samples_per_condition = 20000
start_angle_deg = [0.0, 90.0, 45.0]
[timing]
jitter_s = 0.002
drop_probability = 0.1
"#,
    )
    .unwrap();
    let s = Simulation::new(cfg).unwrap();
    // 90 µg/√Hz · √8 Hz / 0.061 mg = 4.173 counts; with lsb²/12: 4.183.
    assert!((s.truth().noise_sigma - 4.173_089).abs() < 1e-5);
    let floor = s.noise_floor();
    let r = rec(&s);
    assert_eq!(r.meta.noise_sigma, Some(floor));
    let mut kept = 0usize;
    for g in &r.groups {
        kept += g.len();
        // Drops change which rows exist, not the noise draws' statistics.
        let sd = residual_sd_with_drops(g, &s);
        for x in sd {
            let se = floor / (2.0 * g.len() as f64).sqrt();
            assert!((x - floor).abs() < 5.0 * se, "noise sd {x} vs {floor}");
        }
        // Jitter: t_s minus the nominal instant (from seq).
        let seq = g.seq.as_ref().unwrap();
        let gi = r
            .groups
            .iter()
            .position(|h| h.condition == g.condition)
            .unwrap();
        let tg = gi as f64 * (20000.0 / 16.0 + 60.0);
        let d: Vec<f64> = seq
            .iter()
            .zip(&g.t_s)
            .map(|(q, t)| t - (tg + (*q as usize - gi * 20000) as f64 / 16.0))
            .collect();
        let m = d.iter().sum::<f64>() / d.len() as f64;
        let sd = (d.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (d.len() - 1) as f64).sqrt();
        let se = 0.002 / (2.0 * d.len() as f64).sqrt();
        assert!((sd - 0.002).abs() < 5.0 * se + 1e-6, "jitter sd {sd}");
    }
    let total = 60000.0;
    let dropped = total - kept as f64;
    let se = (total * 0.1 * 0.9).sqrt();
    assert!((dropped - 6000.0).abs() < 5.0 * se, "dropped {dropped}");
}

fn residual_sd_with_drops(g: &Group, s: &Simulation) -> Vec<f64> {
    // The noise-free twin has no jitter/drop draws, so match rows by seq.
    let mut cfg = s.config().clone();
    cfg.sensor.noise_sigma = Some(0.0);
    cfg.sensor.lsb = 0.0;
    cfg.timing.jitter_s = 0.0;
    cfg.timing.drop_probability = 0.0;
    let twin = Simulation::new(cfg).unwrap().recording().unwrap();
    let tg = twin.group(g.condition, g.rate_hz).unwrap();
    let tseq = tg.seq.as_ref().unwrap();
    let first = tseq[0];
    let seq = g.seq.as_ref().unwrap();
    let idx: Vec<usize> = seq.iter().map(|q| (q - first) as usize).collect();
    [(&g.u, &tg.u), (&g.v, &tg.v), (&g.w, &tg.w)]
        .iter()
        .map(|(y, y0)| {
            let d: Vec<f64> = y.iter().zip(&idx).map(|(a, i)| a - y0[*i]).collect();
            let m = d.iter().sum::<f64>() / d.len() as f64;
            (d.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (d.len() - 1) as f64).sqrt()
        })
        .collect()
}

/// Every preset calibrates back to its truth. One draw per property, so the bound is
/// 5 standard uncertainties (a false failure about once in 10⁵ runs); the k = 2 coverage
/// is tested over 2000 trials in tests/coverage.rs.
#[test]
fn presets_calibrate_to_their_truth() {
    for name in ["paper-10mhz", "paper-multirate", "metrologia-static"] {
        let s = Simulation::new(Config::preset(name).unwrap()).unwrap();
        let r = rec(&s);
        let cal = calibrate::calibrate(&r, &Options::default()).unwrap();
        let t = s.truth();
        let expect_rates = if name == "paper-multirate" { 4 } else { 1 };
        assert_eq!(cal.by_rate.len(), expect_rates, "{name}");
        for entry in &cal.by_rate {
            let pairs = entry.intrinsic.quantities().into_iter().zip(t.properties());
            for (q, truth) in pairs {
                assert!(
                    (q.value - truth).abs() < 5.0 * q.std_unc,
                    "{name}: {} ± {} vs truth {truth}",
                    q.value,
                    q.std_unc
                );
            }
        }
    }
}

/// The axis-angle and matrix forms of the mounting agree (90° about z).
#[test]
fn mounting_axis_angle_equals_matrix() {
    let base = "preset = \"paper-10mhz\"\n[table]\nsamples_per_condition = 100\n";
    let a = sim(&format!(
        "{base}[mounting]\naxis = [0.0, 0.0, 2.0]\nangle_deg = 90.0\n"
    ));
    let b = sim(&format!(
        "{base}[mounting]\nmatrix = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]\n"
    ));
    let (ta, tb) = (a.truth(), b.truth());
    for j in 0..3 {
        for k in 0..3 {
            assert!((ta.matrix_platter[j][k] - tb.matrix_platter[j][k]).abs() < 1e-9);
        }
    }
    assert_eq!(ta.matrix_device, tb.matrix_device);
}

/// A file's key replaces the preset's alternative to it.
#[test]
fn alternatives_replace_the_presets() {
    let c = Config::from_toml("preset = \"paper-10mhz\"\n[table]\nduration_s = 60.0\n").unwrap();
    assert_eq!(c.samples_per_condition(), 960);
    let c = Config::from_toml(
        "preset = \"paper-10mhz\"\n[device]\nmatrix = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]\n",
    )
    .unwrap();
    assert_eq!(c.device.sensitivity, None);
    assert_eq!(c.device.offsets, [525.1, 99.6, 442.4]);
    let c = Config::from_toml(
        "preset = \"metrologia-static\"\n[table]\nangles_deg = [0.0, 90.0, 180.0, 270.0]\n",
    )
    .unwrap();
    assert_eq!(c.static_angles(), vec![0.0, 90.0, 180.0, 270.0]);
}

/// Configuration mistakes are refused with a message that names the key.
#[test]
fn bad_configurations_name_the_key() {
    let cases: &[(&str, &str)] = &[
        ("preset = \"paper-10mhz\"\n[sensor]\nnois_sigma = 1.0\n", "nois_sigma"),
        ("[device]\noffsets = [0.0, 0.0, 0.0]\n", "device"),
        ("preset = \"nope\"\n", "unknown preset 'nope'"),
        ("preset = \"paper-10mhz\"\n[timing]\njitter_s = 0.01\n", "timing.jitter_s"),
        ("preset = \"paper-10mhz\"\n[timing]\ndrop_probability = 1.0\n", "timing.drop_probability"),
        (
            "preset = \"paper-10mhz\"\n[mounting]\nmatrix = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]\n",
            "mounting.matrix",
        ),
        (
            "preset = \"metrologia-static\"\n[effects.rate_error]\nrelative = 1e-4\n",
            "effects.rate_error",
        ),
        ("preset = \"paper-10mhz\"\n[table]\nrates_hz = [0.01, -1.0]\n", "table.rates_hz"),
        ("preset = \"paper-10mhz\"\nunits = \"V\"\n", "sensor.noise_sigma"),
        ("preset = \"paper-10mhz\"\n[effects.saturation]\nrails = [5.0, 1.0]\n", "effects.saturation.rails"),
        ("preset = \"paper-10mhz\"\n[table]\nangle_step_deg = 5.0\n", "table.angle_step_deg"),
        ("preset = \"paper-10mhz\"\n[device]\nsensitivity = [1.0, 1.0]\n", "sensitivity"),
        ("g_loc = -1.0\n[device]\nmatrix = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]\n", "g_loc"),
        ("this is not toml", "TOML"),
        (
            "preset = \"paper-10mhz\"\n[table]\nduration_s = 60.0\nsamples_per_condition = 100\n",
            "not both",
        ),
        (
            "preset = \"paper-10mhz\"\n[mounting]\nangle_deg = 2.0\nmatrix = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]\n",
            "not both",
        ),
        // [sensor.noise]: each refused naming its key(s).
        ("preset = \"paper-10mhz\"\n[sensor.noise]\nar = [1.2]\n", "sensor.noise.ar: not stationary"),
        // Poles 1 and 0.5 (z² − 1.5z + 0.5): one on the unit circle.
        ("preset = \"paper-10mhz\"\n[sensor.noise]\nar = [1.5, -0.5]\n", "sensor.noise.ar: not stationary"),
        ("preset = \"paper-10mhz\"\n[sensor.noise]\nar = [0.9999999]\n", "sensor.noise.ar: its memory is too long"),
        ("preset = \"paper-10mhz\"\n[sensor.noise]\nar = []\n", "sensor.noise.ar"),
        (
            "preset = \"paper-10mhz\"\n[sensor.noise]\nar = [0.5]\nlowpass_hz = 2.0\n",
            "sensor.noise.ar and sensor.noise.lowpass_hz",
        ),
        ("preset = \"paper-10mhz\"\n[sensor.noise]\nlowpass_hz = 8.0\n", "sensor.noise.lowpass_hz"),
        ("preset = \"paper-10mhz\"\n[sensor.noise]\nlowpass_hz = 0.0\n", "sensor.noise.lowpass_hz"),
        ("preset = \"paper-10mhz\"\n[sensor.noise]\nsd = -1.0\n", "sensor.noise.sd"),
        ("preset = \"paper-10mhz\"\n[sensor.noise]\nsd = [1.0, -2.0, 3.0]\n", "sensor.noise.sd"),
        ("preset = \"paper-10mhz\"\n[sensor.noise]\nsd = [1.0, 2.0]\n", "sensor.noise.sd"),
        (
            "preset = \"paper-10mhz\"\n[sensor]\nnoise_sigma = 3.0\n[sensor.noise]\nsd = 3.0\n",
            "sensor.noise_sigma and sensor.noise.sd",
        ),
        ("preset = \"paper-10mhz\"\n[sensor.noise]\nlow_pass_hz = 2.0\n", "low_pass_hz"),
        ("preset = \"paper-10mhz\"\nunits = \"V\"\n[sensor.noise]\nar = [0.5]\n", "sensor.noise.sd"),
        (
            "preset = \"paper-10mhz\"\n[effects.nonlinearity_high]\norder = 3\nk = [0.0, 0.0, 0.0]\n",
            "effects.nonlinearity_high.order",
        ),
        (
            "preset = \"paper-10mhz\"\n[effects.offset_step]\nat_s = inf\nsize = [1.0, 0.0, 0.0]\n",
            "effects.offset_step.at_s",
        ),
        (
            "preset = \"paper-10mhz\"\n[effects.axis_wobble]\ntilt_deg = 9.0\n",
            "effects.axis_wobble.tilt_deg",
        ),
        (
            "preset = \"metrologia-static\"\n[effects.axis_wobble]\ntilt_deg = 0.1\n",
            "effects.axis_wobble",
        ),
        (
            "preset = \"paper-10mhz\"\n[effects.noise_change]\nat_s = 10.0\nfactor = 0.0\n",
            "effects.noise_change.factor",
        ),
    ];
    for (text, want) in cases {
        let err = Config::from_toml(text)
            .and_then(Simulation::new)
            .err()
            .unwrap_or_else(|| panic!("accepted:\n{text}"));
        let msg = err.to_string();
        assert!(msg.contains(want), "for\n{text}\ngot: {msg}");
    }
    // The CLI: a missing file that is not a preset.
    let out = Command::new(env!("CARGO_BIN_EXE_rotacal"))
        .args(["simulate", "no-such.toml", "--out", "/dev/null"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("no-such.toml") && err.contains("paper-10mhz"),
        "{err}"
    );
}

// ---------------------------------------------------------------------------------------
// [sensor.noise]: the page's noise written out again, and its statistics.

/// The page's filter for a noise table: b, a (a_0 = 1 left out), V = Σ h_k², the burn-in
/// n_b and ρ_k, each found here by other means than the library's.
struct PageNoise {
    b: Vec<f64>,
    a: Vec<f64>,
    v: f64,
    burn: usize,
    rho: Vec<f64>,
}

fn burn_in(r: f64) -> usize {
    (1e-12f64.ln() / r.ln()).ceil() as usize
}

/// AR(2) e_t = φ1·e_{t−1} + φ2·e_{t−2} + w_t with complex roots: modulus √(−φ2), and γ_0
/// and ρ_k in closed form (Yule–Walker).
fn page_ar2(phi1: f64, phi2: f64) -> PageNoise {
    assert!(phi1 * phi1 + 4.0 * phi2 < 0.0, "complex roots expected");
    let v = (1.0 - phi2) / ((1.0 + phi2) * ((1.0 - phi2).powi(2) - phi1 * phi1));
    let mut rho = vec![1.0, phi1 / (1.0 - phi2)];
    for k in 2..50 {
        rho.push(phi1 * rho[k - 1] + phi2 * rho[k - 2]);
    }
    PageNoise {
        b: vec![1.0],
        a: vec![-phi1, -phi2],
        v,
        burn: burn_in((-phi2).sqrt()),
        rho,
    }
}

/// The page's Butterworth: its complex pole pair has modulus √a_2; V and ρ_k from a long
/// impulse response.
fn page_butterworth(fc: f64, fs: f64) -> PageNoise {
    let k = (PI * fc / fs).tan();
    let d = 1.0 + SQRT_2 * k + k * k;
    let b = vec![k * k / d, 2.0 * k * k / d, k * k / d];
    let a = vec![2.0 * (k * k - 1.0) / d, (1.0 - SQRT_2 * k + k * k) / d];
    let n = 5000;
    let mut h = vec![0.0; n];
    for t in 0..n {
        let x = if t < 3 { b[t] } else { 0.0 };
        let y1 = if t >= 1 { h[t - 1] } else { 0.0 };
        let y2 = if t >= 2 { h[t - 2] } else { 0.0 };
        h[t] = x - a[0] * y1 - a[1] * y2;
    }
    let v: f64 = h.iter().map(|x| x * x).sum();
    let rho = (0..50)
        .map(|lag| (0..n - lag).map(|i| h[i] * h[i + lag]).sum::<f64>() / v)
        .collect();
    PageNoise {
        burn: burn_in(a[1].sqrt()),
        b,
        a,
        v,
        rho,
    }
}

/// The page's noise for the first `samples` samples of a file whose only stream-0 draws
/// are the noise's: n_b burn-in innovations per channel from stream 1 (u's, then v's, then
/// w's), then three per sample from stream 0, all through the filter from rest. With
/// `dwell = Some((readings, idle))` (a static file), after every `readings` samples the
/// filter runs `idle` unread steps per channel on innovations from stream 3 (u's, then
/// v's, then w's).
fn page_noise(
    p: &PageNoise,
    sd: [f64; 3],
    seed: u64,
    samples: usize,
    dwell: Option<(usize, usize)>,
) -> [Vec<f64>; 3] {
    let mut s1 = ChaCha8Rng::seed_from_u64(seed);
    s1.set_stream(1);
    // Each channel's innovations, and whether the step's output is a sample of the file.
    let mut w: [Vec<(f64, bool)>; 3] = Default::default();
    for wj in w.iter_mut() {
        for _ in 0..p.burn {
            wj.push((s1.sample(StandardNormal), false));
        }
    }
    let mut s0 = ChaCha8Rng::seed_from_u64(seed);
    let mut s3 = ChaCha8Rng::seed_from_u64(seed);
    s3.set_stream(3);
    for i in 0..samples {
        for wj in w.iter_mut() {
            wj.push((s0.sample(StandardNormal), true));
        }
        if let Some((_, idle)) = dwell.filter(|(readings, _)| (i + 1) % readings == 0) {
            for wj in w.iter_mut() {
                for _ in 0..idle {
                    wj.push((s3.sample(StandardNormal), false));
                }
            }
        }
    }
    let mut out: [Vec<f64>; 3] = Default::default();
    for j in 0..3 {
        let n = w[j].len();
        let mut y = vec![0.0; n];
        for t in 0..n {
            let mut x = 0.0;
            for (i, bi) in p.b.iter().enumerate() {
                if t >= i {
                    x += bi * w[j][t - i].0;
                }
            }
            for (i, ai) in p.a.iter().enumerate() {
                if t > i {
                    x -= ai * y[t - i - 1];
                }
            }
            y[t] = x;
        }
        out[j] = y
            .iter()
            .zip(&w[j])
            .filter(|(_, (_, read))| *read)
            .map(|(y, _)| sd[j] / p.v.sqrt() * y)
            .collect();
    }
    out
}

/// The file's noise per channel, in file order: the recording minus its noise-free twin
/// (the configurations here have lsb = 0 and no clipping, so this is the noise to rounding).
fn noise_of(s: &Simulation) -> [Vec<f64>; 3] {
    let mut cfg = s.config().clone();
    cfg.sensor.noise = None;
    cfg.sensor.noise_sigma = Some(0.0);
    let (noisy, twin) = (rec(s), Simulation::new(cfg).unwrap().recording().unwrap());
    let mut e: [Vec<f64>; 3] = Default::default();
    for (g, g0) in noisy.groups.iter().zip(&twin.groups) {
        assert_eq!(g.len(), g0.len());
        for (ej, (y, y0)) in e
            .iter_mut()
            .zip([(&g.u, &g0.u), (&g.v, &g0.v), (&g.w, &g0.w)])
        {
            ej.extend(y.iter().zip(y0.iter()).map(|(a, b)| a - b));
        }
    }
    e
}

fn noise_config(preamble: &str, noise: &str) -> String {
    format!(
        "seed = 11\ng_loc = {G}\n{preamble}\n[device]\nmatrix = {s}\noffsets = [{}, {}, {}]\n\
         [sensor]\nlsb = 0.0\nfull_scale = [-1e9, 1e9]\n[sensor.noise]\n{noise}\n",
        O[0],
        O[1],
        O[2],
        s = fmt_matrix(&S),
    )
}

/// AR and low-pass files reproduced sample for sample from the page's equations and RNG
/// stream rules, across rates, conditions and static angles; the truth's process agrees
/// with the page's.
#[test]
fn correlated_noise_matches_an_independent_model() {
    let cases = [
        (
            "AR(2) over two rates",
            noise_config(
                "[timing]\nsample_rate_hz = 16.0\n[table]\nrates_hz = [0.02, 0.3]\n\
                 samples_per_condition = 200\nstart_angle_deg = [10.0, 200.0, 300.0]",
                "sd = [3.0, 4.0, 5.0]\nar = [1.5, -0.7]",
            ),
            page_ar2(1.5, -0.7),
            [3.0, 4.0, 5.0],
            None,
        ),
        (
            "Butterworth, static",
            noise_config(
                "method = \"static\"\n[timing]\nsample_rate_hz = 104.0\n[table]\n\
                 angles_deg = [0.0, 90.0, 180.0, 270.0]\nreadings_per_angle = 50\ndwell_s = 1.0",
                "sd = 2.5\nlowpass_hz = 11.6",
            ),
            page_butterworth(11.6, 104.0),
            [2.5; 3],
            // 50 readings a second-long dwell at 104 Hz: 54 unread steps after each.
            Some((50, 54)),
        ),
    ];
    for (name, toml, page, sd, dwell) in cases {
        let s = sim(&toml);
        let t = s.truth();
        let p = &t.noise_process;
        assert_eq!(p.burn_in(), page.burn as u64, "{name}: burn-in");
        assert!(
            (p.variance_per_innovation() / page.v - 1.0).abs() < 1e-12,
            "{name}: V"
        );
        for (x, y) in p.feedback().iter().zip(&page.a) {
            assert!((x - y).abs() < 1e-15, "{name}: a");
        }
        for (x, y) in p.feedforward().iter().zip(&page.b) {
            assert!((x - y).abs() < 1e-15, "{name}: b");
        }
        for (k, r) in page.rho.iter().enumerate() {
            for ch in Channel::ALL {
                let got = t.noise_autocorrelation(ch, k as u64);
                assert!((got - r).abs() < 1e-12, "{name}: ρ_{k} {got} vs {r}");
            }
        }
        assert_eq!(t.noise_sd, sd);
        // The long-run factor is Σρ over all lags, and the spectral shape integrates to 1.
        let sum_rho = 1.0 + 2.0 * (1..2000).map(|k| p.autocorrelation(k)).sum::<f64>();
        assert!(
            (p.long_run_factor() / sum_rho - 1.0).abs() < 1e-9,
            "{name}: Σρ"
        );
        let m = 4096;
        let integral = (0..m)
            .map(|i| p.spectral_shape((i as f64 + 0.5) / m as f64 - 0.5))
            .sum::<f64>()
            / m as f64;
        assert!(
            (integral - 1.0).abs() < 1e-9,
            "{name}: ∫ shape = {integral}"
        );

        let e = noise_of(&s);
        let want = page_noise(&page, sd, 11, e[0].len(), dwell);
        let mut worst = 0.0f64;
        for j in 0..3 {
            for (x, y) in e[j].iter().zip(&want[j]) {
                worst = worst.max((x - y).abs());
            }
        }
        println!(
            "{name}: {} samples, burn-in {}, V = {:.6}, worst |file − page| {worst:.1e}",
            e[0].len(),
            page.burn,
            page.v
        );
        assert!(worst < 1e-9, "{name}: worst difference {worst:e}");
        assert_eq!(
            rec(&s).meta.noise_sigma,
            None,
            "{name}: coloured noise is not stated"
        );
    }
}

/// Autocorrelation at `lag` (any sign) from the truth.
fn rho_of(s: &Simulation, lag: i64) -> f64 {
    s.truth()
        .noise_autocorrelation(Channel::U, lag.unsigned_abs())
}

/// Bartlett's standard error of a lag-k sample autocorrelation from n samples of a
/// process with autocorrelation ρ.
fn bartlett_se(rho: &dyn Fn(i64) -> f64, k: i64, n: usize) -> f64 {
    let l = 500;
    let v: f64 = (-l..=l)
        .map(|i| {
            rho(i + k).powi(2) + rho(i - k) * rho(i + k) - 4.0 * rho(k) * rho(i) * rho(i + k)
                + 2.0 * rho(i).powi(2) * rho(k).powi(2)
        })
        .sum();
    (v / n as f64).sqrt()
}

/// Each channel's marginal sd and lag-1, lag-2 autocorrelations against the truth.
/// Bounds from statistics: the mean square of n correlated Gaussian samples is taken as
/// σ²·χ²(n_eff)/n_eff with n_eff = n / Σ_k ρ_k² (equal variance of the estimate), at
/// probability 1e-6 each side; the autocorrelations within 4 of Bartlett's standard errors.
fn check_noise_statistics(name: &str, s: &Simulation) {
    let e = noise_of(s);
    let t = s.truth();
    let n = e[0].len();
    let rho = |k: i64| rho_of(s, k);
    let sum_sq: f64 = (-2000..=2000).map(|k| rho(k).powi(2)).sum();
    let n_eff = n as f64 / sum_sq;
    let chi = ChiSquared::new(n_eff).unwrap();
    let (lo, hi) = (
        (chi.inverse_cdf(1e-6) / n_eff).sqrt(),
        (chi.inverse_cdf(1.0 - 1e-6) / n_eff).sqrt(),
    );
    for j in 0..3 {
        let x = &e[j];
        let ms = x.iter().map(|v| v * v).sum::<f64>() / n as f64;
        let sd = ms.sqrt();
        let want = t.noise_sd[j];
        println!(
            "{name} ch {j}: sd {sd:.4} vs {want} (bounds {:.4} … {:.4}, n = {n}, n_eff = {n_eff:.0})",
            want * lo,
            want * hi
        );
        assert!(
            sd >= want * lo && sd <= want * hi,
            "{name} channel {j}: sd {sd}"
        );
        for k in [1i64, 2] {
            let m = n - k as usize;
            let r = (0..m).map(|i| x[i] * x[i + k as usize]).sum::<f64>() / (ms * n as f64);
            let se = bartlett_se(&rho, k, n);
            println!(
                "{name} ch {j}: r_{k} {r:.4} vs ρ_{k} {:.4} (se {se:.4}, z = {:+.2})",
                rho(k),
                (r - rho(k)) / se
            );
            assert!(
                (r - rho(k)).abs() < 4.0 * se,
                "{name} channel {j}: r_{k} {r} vs {}",
                rho(k)
            );
        }
    }
    // The channels are independent: lag-0 cross-correlation within 4 standard errors,
    // Var ≈ Σ_k ρ_k²/n for two independent series of the same shape.
    for (a, b) in [(0, 1), (1, 2), (2, 0)] {
        let c = e[a].iter().zip(&e[b]).map(|(x, y)| x * y).sum::<f64>();
        let na: f64 = e[a].iter().map(|x| x * x).sum();
        let nb: f64 = e[b].iter().map(|x| x * x).sum();
        let r = c / (na * nb).sqrt();
        let se = (sum_sq / n as f64).sqrt();
        println!("{name} channels {a}, {b}: cross-correlation {r:+.4} (se {se:.4})");
        assert!(
            r.abs() < 4.0 * se,
            "{name}: channels {a}, {b} correlate {r}"
        );
    }
}

fn long_noise(fs: f64, noise: &str) -> Simulation {
    sim(&noise_config(
        &format!(
            "[timing]\nsample_rate_hz = {fs:?}\n[table]\nsamples_per_condition = 20000\n\
             start_angle_deg = [0.0, 0.0, 0.0]"
        ),
        noise,
    ))
}

#[test]
fn ar_noise_has_the_stated_statistics() {
    let s = long_noise(16.0, "sd = [3.0, 4.0, 5.0]\nar = [0.6]");
    assert!((rho_of(&s, 1) - 0.6).abs() < 1e-12 && (rho_of(&s, 2) - 0.36).abs() < 1e-12);
    check_noise_statistics("AR(1) 0.6", &s);
}

/// The LSM6DS33's LPF2 at ODR/9: 11.6 Hz at 104 Hz.
#[test]
fn lowpass_noise_has_the_stated_statistics() {
    check_noise_statistics(
        "low-pass 11.6 Hz at 104 Hz",
        &long_noise(104.0, "sd = 4.0\nlowpass_hz = 11.6"),
    );
}

/// Per-channel levels 3, 4, 5 of white noise.
#[test]
fn per_channel_white_levels_are_honoured() {
    let s = long_noise(16.0, "sd = [3, 4, 5]");
    assert_eq!(s.truth().noise_sd, [3.0, 4.0, 5.0]);
    assert_eq!(rho_of(&s, 1), 0.0);
    check_noise_statistics("white 3, 4, 5", &s);
}

/// `# noise_sigma=` is written only when it is true: white noise of one level, and not
/// turned off. A white table of one level is byte for byte the `noise_sigma` file.
#[test]
fn noise_sigma_is_stated_only_when_true() {
    let base = "preset = \"paper-10mhz\"\nseed = 3\n[table]\nsamples_per_condition = 50\n";
    let bytes = |extra: &str| {
        let s = sim(&format!("{base}{extra}"));
        let (_, b) = s.write(Vec::new()).unwrap();
        let text = String::from_utf8(b.clone()).unwrap();
        let stated = rec(&s).meta.noise_sigma;
        assert_eq!(
            stated.is_some(),
            text.lines().any(|l| l.starts_with("# noise_sigma=")),
            "{extra}"
        );
        (b, stated, s.noise_floor())
    };
    let floor4 = (16.0f64 + 1.0 / 12.0).sqrt();
    let (plain, stated, floor) = bytes("");
    assert_eq!(stated, Some(floor));
    let cases: &[(&str, Option<f64>)] = &[
        ("[sensor.noise]\n", Some(floor)),
        ("[sensor.noise]\nsd = 4.0\n", Some(floor4)),
        ("[sensor.noise]\nsd = [4.0, 4.0, 4.0]\n", Some(floor4)),
        ("[sensor.noise]\nsd = [3.0, 4.0, 5.0]\n", None),
        ("[sensor.noise]\nsd = 4.0\nstate = false\n", None),
        ("[sensor.noise]\nsd = 4.0\nar = [0.3]\n", None),
        ("[sensor.noise]\nsd = 4.0\nlowpass_hz = 3.0\n", None),
        ("[sensor.noise]\nar = [0.3]\nstate = true\n", None),
    ];
    for (extra, want) in cases {
        assert_eq!(bytes(extra).1, *want, "{extra}");
    }
    // White noise through the table draws exactly what noise_sigma draws.
    assert_eq!(bytes("[sensor.noise]\n").0, plain);
    assert_eq!(
        bytes("[sensor.noise]\nsd = 4.0\n").0,
        bytes("[sensor]\nnoise_sigma = 4.0\n").0
    );
    // A file's noise.sd replaces a preset's noise_sigma (same level, same bytes).
    let a = Simulation::new(Config::preset("metrologia-static").unwrap()).unwrap();
    let b = sim("preset = \"metrologia-static\"\n[sensor.noise]\nsd = 100e-6\n");
    assert_eq!(
        a.write(Vec::new()).unwrap().1,
        b.write(Vec::new()).unwrap().1
    );
}

/// A hand's tremor (`poses.tremor_ms2`, docs/simulator.md): on a channel across gravity,
/// the tremor alone (no sensor noise) has the RMS asked for, is zero-mean, and rings at
/// its frequency. Expected values from the AR(2) it is (poles r·e^{±iω}, r = e^{−2π/fs}
/// for a 2 Hz band, ω = 2π·10/fs): ρ(k) ≈ r^k·cos(kω) for a narrow band (−0.74 at k = 5,
/// +0.53 at k = 10). Over 200 s at 104 Hz the band has about 2·2 Hz·200 s = 800 degrees
/// of freedom, so the variance is within 0.2 of its value (4 standard errors of 0.05) and
/// each ρ within 0.15 (4 of about 1/√200, its error over 200 one-hertz resolution cells
/// ≤ 0.035); the mean within 4 standard errors of the band's level at zero frequency.
#[test]
fn tremor_has_its_rms_band_and_zero_mean() {
    let toml = |tremor: f64| {
        format!(
            "method = \"free\"\nunits = \"counts\"\nseed = 7\n\
             device = {{ sensitivity = [1669.32, 1669.10, 1676.46], angles_deg = [90.0, 90.0, \
             90.0], offsets = [525.1, 99.6, 442.4] }}\n\
             [sensor]\nlsb = 1.0\nfull_scale = [-32768.0, 32767.0]\n\
             [timing]\nsample_rate_hz = 104.0\n\
             [poses]\ndirections = [[0.0, 0.0, 1.0]]\nstill_s = 200.0\ntremor_ms2 = {tremor:?}\n"
        )
    };
    let u = |tremor: f64| -> Vec<f64> {
        let r = rec(&sim(&toml(tremor)));
        r.series.unwrap().y.iter().map(|y| y[0]).collect()
    };
    let (still, shaken) = (u(0.0), u(0.05));
    let n = shaken.len() as f64;
    let d: Vec<f64> = shaken.iter().zip(&still).map(|(a, b)| a - b).collect();
    let mean = d.iter().sum::<f64>() / n;
    let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
    let want = (0.05 * 1669.32f64).powi(2);
    assert!(
        (var / want - 1.0).abs() < 0.2,
        "variance {var:.1}, want {want:.1}"
    );
    let rho = |k: usize| {
        d.iter()
            .zip(d.iter().skip(k))
            .map(|(a, b)| (a - mean) * (b - mean))
            .sum::<f64>()
            / (n * var)
    };
    let r = (-TAU / 104.0).exp();
    let w = TAU * 10.0 / 104.0;
    for k in [5usize, 10] {
        let expect = r.powi(k as i32) * (k as f64 * w).cos();
        assert!(
            (rho(k) - expect).abs() < 0.15,
            "ρ({k}) = {:.3}, want {expect:.3}",
            rho(k)
        );
    }
    // The AR(2)'s level at zero frequency per reading: sd·|1/(1 − a₁ − a₂)| over its RMS.
    let (a1, a2) = (2.0 * r * w.cos(), -r * r);
    let gain = (1.0 - a2) / ((1.0 + a2) * ((1.0 - a2).powi(2) - a1 * a1));
    let dc = want.sqrt() / gain.sqrt() / (1.0 - a1 - a2);
    assert!(
        mean.abs() < 4.0 * dc / n.sqrt(),
        "mean {mean:.3}, its standard error {:.3}",
        dc / n.sqrt()
    );
}
