//! Applying a calibration (`rotacal::calibrate::correction`, `rotacal apply`, `rotacal export`):
//! simulated truth round-trips within the stated uncertainty, rotation data become
//! orthonormal sinusoids, static poses read g, and the exported constants compile and
//! compute what `apply` computes.
use crate::common;
use common::run;
use rotacal::calibrate::correction::{self, Correction, Frame};
use rotacal::calibrate::json::CorrectionJson;
use rotacal::calibrate::{calibrate, Options};
use rotacal::correct::apply;
use rotacal::simulate::{Config, Simulation};
use rotacal_proof::parallel_n;
use std::path::PathBuf;

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("rotacal-apply-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// Test directions: the six axes and four cube diagonals.
fn directions() -> Vec<[f64; 3]> {
    let r = 1.0 / 3f64.sqrt();
    vec![
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, -1.0],
        [r, r, r],
        [-r, r, -r],
        [r, -r, -r],
        [-r, -r, r],
    ]
}

fn mat_vec(m: &[[f64; 3]; 3], v: &[f64; 3]) -> [f64; 3] {
    m.map(|row| (0..3).map(|k| row[k] * v[k]).sum())
}

/// The device and platter accelerations the truth gives for gravity along `d`, and the
/// noise-free reading there.
fn truth_at(sim: &Simulation, g: f64, d: &[f64; 3]) -> ([f64; 3], [f64; 3], [f64; 3]) {
    let t = sim.truth();
    let s = t.matrix_platter;
    let y = {
        let sy = mat_vec(&s, d);
        [0, 1, 2].map(|j| g * sy[j] + t.offsets[j])
    };
    // Q = L⁻¹·S with G = S·Sᵀ = L·Lᵀ: the device frame of the truth.
    let l_inv = correction::device_matrix(&correction::gram_of(&s)).unwrap();
    let q = [0, 1, 2].map(|i| [0, 1, 2].map(|j| (0..3).map(|k| l_inv[i][k] * s[k][j]).sum()));
    let platter = d.map(|x| g * x);
    (mat_vec(&q, &platter), platter, y)
}

struct Count {
    inside: usize,
    total: usize,
    worst: f64,
}

impl Count {
    fn add(&mut self, est: [f64; 3], u: [f64; 3], truth: [f64; 3]) {
        for i in 0..3 {
            let z = (est[i] - truth[i]).abs() / u[i];
            self.worst = self.worst.max(z);
            self.inside += usize::from(z <= 2.0);
            self.total += 1;
        }
    }
    fn fraction(&self) -> f64 {
        self.inside as f64 / self.total as f64
    }
}

fn corrections(cfg: Config) -> (Simulation, CorrectionJson) {
    let sim = Simulation::new(cfg).unwrap();
    let rec = sim.recording().unwrap();
    let mut cal = calibrate(&rec, &Options::default()).unwrap();
    let c = cal.by_rate.remove(0).correction.unwrap();
    (sim, c)
}

/// Calibrate, then apply to the noise-free reading at ten directions: the corrected
/// acceleration must hold the simulated one within 2 standard uncertainties about 95 % of
/// the time, in both frames (static) or the device frame (rotation).
#[test]
fn simulated_truth_round_trips_within_uncertainty() {
    const TRIALS: usize = 400;
    for preset in ["metrologia-static", "paper-10mhz"] {
        let results = parallel_n(TRIALS, |i| {
            let mut cfg = Config::preset(preset).unwrap();
            cfg.seed = 0xA991_0000 + i as u64;
            cfg.mounting.axis = [1.0, 1.0, 0.0];
            cfg.mounting.angle_deg = 5.0;
            let g = cfg.g_loc;
            let (sim, c) = corrections(cfg);
            directions()
                .iter()
                .map(|d| {
                    let (dev, pla, y) = truth_at(&sim, g, d);
                    let (a, u) = c.device_frame.apply(y);
                    let p = c.platter_frame.as_ref().map(|p| (p.apply(y), pla));
                    ((a, u, dev), p)
                })
                .collect::<Vec<_>>()
        });
        let mut device = Count {
            inside: 0,
            total: 0,
            worst: 0.0,
        };
        let mut platter = Count {
            inside: 0,
            total: 0,
            worst: 0.0,
        };
        for ((a, u, t), p) in results.into_iter().flatten() {
            device.add(a, u, t);
            if let Some(((a, u), t)) = p {
                platter.add(a, u, t);
            }
        }
        println!(
            "{preset}: device frame {:.3} within 2u ({} values, worst {:.2} u)",
            device.fraction(),
            device.total,
            device.worst
        );
        assert!((0.93..=0.97).contains(&device.fraction()));
        if platter.total > 0 {
            println!(
                "{preset}: platter frame {:.3} within 2u (worst {:.2} u)",
                platter.fraction(),
                platter.worst
            );
            assert!((0.93..=0.97).contains(&platter.fraction()));
        }
    }
}

/// Several rates: the correction's offsets are the conditions' C at ω = 0, free of the
/// centripetal acceleration (22 cm off the axis in `paper-multirate`), and hold the truth.
#[test]
fn multirate_offsets_are_free_of_centripetal_acceleration() {
    let sim = Simulation::new(Config::preset("paper-multirate").unwrap()).unwrap();
    let rec = sim.recording().unwrap();
    let cal = calibrate(&rec, &Options::default()).unwrap();
    let truth = sim.truth().offsets;
    for r in &cal.by_rate {
        let c = r.correction.as_ref().unwrap();
        assert!(c.offset_source.contains("ω = 0"), "{}", c.offset_source);
        let d = &c.device_frame;
        for (j, t) in truth.iter().enumerate() {
            let z = (d.offset[j] - t) / d.offset_std_unc[j];
            println!(
                "{:?} Hz: O[{j}] = {:.3} ± {:.3} (truth {}), {z:+.2} u",
                r.rate_hz, d.offset[j], d.offset_std_unc[j], truth[j]
            );
            assert!(z.abs() < 3.0);
        }
    }
}

fn apply_to(rec: &rotacal::recording::Recording, c: &Correction) -> rotacal::recording::Recording {
    let mut buf = Vec::new();
    let job = apply::Job {
        correction: c,
        units_in: rec.meta.units.as_deref().unwrap_or("output units"),
        k: 2.0,
        cal_name: "test",
        g_loc: None,
        out_name: "buffer",
        provenance: &[],
    };
    apply::apply(rec, &job, &mut buf).unwrap();
    rotacal::recording::read_from(buf.as_slice(), "applied").unwrap()
}

/// Calibrate on one run, correct an independent run with it, calibrate that: the three
/// corrected channels are orthonormal sinusoids (sensitivity 1, angles 90°, offsets 0)
/// within the two runs' combined uncertainty.
#[test]
fn corrected_rotation_channels_are_orthonormal_sinusoids() {
    const PAIRS: usize = 100;
    let results = parallel_n(PAIRS, |i| {
        let mut cfg = Config::preset("paper-10mhz").unwrap();
        cfg.seed = 0x0127_0000 + 2 * i as u64;
        let (_, c) = corrections(cfg.clone());
        let a_cal = {
            let sim = Simulation::new(cfg.clone()).unwrap();
            calibrate(&sim.recording().unwrap(), &Options::default())
                .unwrap()
                .by_rate
                .remove(0)
        };
        cfg.seed += 1;
        let other = Simulation::new(cfg).unwrap().recording().unwrap();
        let corrected = apply_to(&other, &c.device_frame);
        let b = calibrate(&corrected, &Options::default())
            .unwrap()
            .by_rate
            .remove(0);
        (a_cal, b)
    });
    let mut inside = 0;
    let mut total = 0;
    for (k, (a, b)) in results.iter().enumerate() {
        let qa = a.intrinsic.quantities();
        let qb = b.intrinsic.quantities();
        let mut line = Vec::new();
        for (j, (x, y)) in qa.iter().zip(&qb).enumerate() {
            // Relative for the sensitivities (1 in m/s² per m/s² after correction).
            let (dev, u) = if j < 3 {
                (
                    y.value - 1.0,
                    ((x.std_unc / x.value).powi(2) + y.std_unc.powi(2)).sqrt(),
                )
            } else {
                (
                    y.value - 90.0,
                    (x.std_unc.powi(2) + y.std_unc.powi(2)).sqrt(),
                )
            };
            inside += usize::from(dev.abs() <= 2.0 * u);
            total += 1;
            line.push(format!("{:.2}", dev / u));
        }
        // Offsets of the corrected channels: the fits' C, 0 within their uncertainty and
        // the correction's.
        let mean_c: f64 = b.fits.iter().map(|f| f.c.abs()).sum::<f64>() / b.fits.len() as f64;
        assert!(mean_c < 0.01, "mean |C| {mean_c} m/s²");
        if k == 0 {
            println!(
                "pair 0: corrected s = {:.7} {:.7} {:.7}, φ = {:.5} {:.5} {:.5}; deviations/u {}",
                qb[0].value,
                qb[1].value,
                qb[2].value,
                qb[3].value,
                qb[4].value,
                qb[5].value,
                line.join(" ")
            );
        }
    }
    let f = inside as f64 / total as f64;
    println!("{inside}/{total} = {f:.3} of s − 1 and φ − 90° within 2u");
    assert!((0.93..=0.97).contains(&f), "{f}");
}

/// Static poses with repeated readings (stepped, 20 readings at each of 216 poses, five
/// runs): after correction every pose reads g within the noise of its mean, in both frames.
#[test]
fn corrected_static_poses_read_g() {
    for frame in [Frame::Device, Frame::Platter] {
        let (mut within, mut poses, mut ss, mut rows) = (0, 0, 0.0, 0);
        let mut worst: f64 = 0.0;
        for seed in 0..5 {
            let mut cfg = Config::preset("metrologia-static").unwrap();
            cfg.seed = 0x57A7_1C00 + seed;
            cfg.table.readings_per_angle = Some(20);
            cfg.mounting.axis = [1.0, 0.0, 1.0];
            cfg.mounting.angle_deg = 3.0;
            let g = cfg.g_loc;
            let sim = Simulation::new(cfg).unwrap();
            let rec = sim.recording().unwrap();
            let c = calibrate(&rec, &Options::default())
                .unwrap()
                .by_rate
                .remove(0)
                .correction
                .unwrap();
            let corr = match frame {
                Frame::Device => c.device_frame,
                Frame::Platter => c.platter_frame.unwrap(),
            };
            let out = apply_to(&rec, &corr);
            // |a| − g per pose; the noise of one |a| pooled over all poses of the run.
            let mut means = Vec::new();
            let (mut pooled, mut dof) = (0.0, 0.0);
            for grp in &out.groups {
                let mut i = 0;
                while i < grp.len() {
                    let a0 = grp.angle_deg[i];
                    let mut d = Vec::new();
                    while i < grp.len() && grp.angle_deg[i] == a0 {
                        d.push((grp.u[i].powi(2) + grp.v[i].powi(2) + grp.w[i].powi(2)).sqrt() - g);
                        i += 1;
                    }
                    let n = d.len() as f64;
                    let m = d.iter().sum::<f64>() / n;
                    pooled += d.iter().map(|x| (x - m).powi(2)).sum::<f64>();
                    dof += n - 1.0;
                    ss += d.iter().map(|x| x * x).sum::<f64>();
                    rows += d.len();
                    means.push((m, n));
                }
            }
            let sd = (pooled / dof).sqrt();
            for (m, n) in means {
                let z = m.abs() / (sd / n.sqrt());
                worst = worst.max(z);
                within += usize::from(z <= 2.0);
                poses += 1;
            }
        }
        let rms = (ss / rows as f64).sqrt();
        println!(
            "{frame:?} frame: {within}/{poses} poses with |mean |a| − g| ≤ 2 se (worst {worst:.2} se); RMS |a| − g {rms:.2e} m/s²"
        );
        assert!(within as f64 / poses as f64 >= 0.94 && worst < 4.5);
    }
}

/// The exported C and Rust constants compile and compute what `apply` computes.
#[test]
fn exported_constants_compile_and_agree() {
    let rec = tmp("static.csv");
    let (ok, _, e) = run(&[
        "simulate",
        "metrologia-static",
        "--out",
        rec.to_str().unwrap(),
    ]);
    assert!(ok, "{e}");
    let cal = tmp("static.json");
    let (ok, _, e) = run(&[
        "calibrate",
        rec.to_str().unwrap(),
        "--json",
        cal.to_str().unwrap(),
    ]);
    assert!(ok, "{e}");
    let text = std::fs::read_to_string(&cal).unwrap();
    let all = apply::read_corrections(&text, "cal").unwrap();
    let y = [1.234, -0.567, 2.001];
    for frame in [Frame::Device, Frame::Platter] {
        let (_, c) = apply::choose(&all, None, frame, "cal").unwrap();
        let (want, _) = c.apply(y);
        let name = if frame == Frame::Device {
            "device"
        } else {
            "platter"
        };
        for (format, precision, tol) in [
            ("c", "f32", 1e-5),
            ("rust", "f32", 1e-5),
            ("rust", "f64", 1e-12),
        ] {
            let ext = if format == "c" { "h" } else { "rs" };
            let out = tmp(&format!("cal-{name}-{precision}.{ext}"));
            let (ok, _, e) = run(&[
                "export",
                cal.to_str().unwrap(),
                "--format",
                format,
                "--frame",
                name,
                "--precision",
                precision,
                "--out",
                out.to_str().unwrap(),
            ]);
            assert!(ok, "{e}");
            let bin = tmp(&format!("prog-{name}-{format}-{precision}"));
            let src = if format == "c" {
                let src = tmp(&format!("main-{name}.c"));
                std::fs::write(
                    &src,
                    format!(
                        "#include <stdio.h>\n#include \"{}\"\nint main(void) {{ float y[3] = {{{}f, {}f, {}f}}; float a[3]; \
                         rotacal_correct(y, a); printf(\"%.9e %.9e %.9e\\n\", a[0], a[1], a[2]); return 0; }}\n",
                        out.display(),
                        y[0],
                        y[1],
                        y[2]
                    ),
                )
                .unwrap();
                let st = std::process::Command::new("cc")
                    .args(["-std=c99", "-Wall", "-Werror", "-o"])
                    .arg(&bin)
                    .arg(&src)
                    .status()
                    .unwrap();
                assert!(st.success(), "cc failed on {}", out.display());
                src
            } else {
                let src = tmp(&format!("main-{name}-{precision}.rs"));
                std::fs::write(
                    &src,
                    format!(
                        "#[path = \"{}\"]\nmod cal;\nfn main() {{ let a = cal::correct([{:?}, {:?}, {:?}]); \
                         println!(\"{{:e}} {{:e}} {{:e}}\", a[0], a[1], a[2]); }}\n",
                        out.display(),
                        y[0],
                        y[1],
                        y[2]
                    ),
                )
                .unwrap();
                let rustc = std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into());
                let st = std::process::Command::new(rustc)
                    .args(["--edition", "2021", "-D", "warnings", "-o"])
                    .arg(&bin)
                    .arg(&src)
                    .status()
                    .unwrap();
                assert!(st.success(), "rustc failed on {}", out.display());
                src
            };
            let printed = std::process::Command::new(&bin).output().unwrap();
            let got: Vec<f64> = String::from_utf8_lossy(&printed.stdout)
                .split_whitespace()
                .map(|x| x.parse().unwrap())
                .collect();
            assert_eq!(got.len(), 3, "{}: printed {got:?}", src.display());
            for (g, w) in got.iter().zip(want) {
                assert!(
                    (g - w).abs() <= tol * w.abs().max(1.0),
                    "{}: {got:?} vs {want:?}",
                    src.display()
                );
            }
        }
    }
}
