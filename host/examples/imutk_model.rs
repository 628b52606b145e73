//! imu_tk's accelerometer model (Tedaldi, Pretto, Menegatti, ICRA 2014) refitted on the
//! poses a free calibration kept, against that calibration (docs/uncertainty.md, "Slow
//! noise in the moved test").
//!
//!     rotacal calibrate FILE --json CAL.json [--slow-noise]
//!     cargo run --release --example imutk_model -- CAL.json
//!
//! The model: a = T·K·(y − b), T unit upper-triangular with the misalignments α_yz, α_zy,
//! α_zx, K the diagonal of scales, b the biases; fitted by Levenberg–Marquardt to the kept
//! poses' means with imu_tk's cost Σ(g² − ‖a‖²)², from a start that uses no rotacal result
//! (b at the poses' mean, one scale g/median‖y − b‖). S = (T·K)⁻¹ maps m/s² to output
//! units, so the intrinsic properties are its rows' lengths and angles, and O = b. Prints
//! each property beside rotacal's, their difference and that over rotacal's U.
#![allow(clippy::indexing_slicing)]
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};
use std::process::ExitCode;

/// T·K from the nine parameters (α_yz, α_zy, α_zx, s_x, s_y, s_z, b_x, b_y, b_z).
fn tk(p: &DVector<f64>) -> Matrix3<f64> {
    let t = Matrix3::new(1.0, -p[0], p[1], 0.0, 1.0, -p[2], 0.0, 0.0, 1.0);
    t * Matrix3::from_diagonal(&Vector3::new(p[3], p[4], p[5]))
}

/// imu_tk's residuals g² − ‖a‖², one per pose.
fn residuals(p: &DVector<f64>, y: &[Vector3<f64>], g: f64) -> DVector<f64> {
    let m = tk(p);
    let b = Vector3::new(p[6], p[7], p[8]);
    DVector::from_iterator(
        y.len(),
        y.iter().map(|yi| g * g - (m * (yi - b)).norm_squared()),
    )
}

fn fit(y: &[Vector3<f64>], g: f64) -> DVector<f64> {
    let n = y.len() as f64;
    let b0 = y.iter().fold(Vector3::zeros(), |s, v| s + v) / n;
    let mut norms: Vec<f64> = y.iter().map(|v| (v - b0).norm()).collect();
    norms.sort_by(f64::total_cmp);
    let scale = g / norms[norms.len() / 2];
    let mut p = DVector::from_vec(vec![
        0.0, 0.0, 0.0, scale, scale, scale, b0[0], b0[1], b0[2],
    ]);
    let mut lambda = 1e-3;
    let cost = |p: &DVector<f64>| residuals(p, y, g).norm_squared();
    for _ in 0..500 {
        let r = residuals(&p, y, g);
        let mut jac = DMatrix::zeros(y.len(), 9);
        for k in 0..9 {
            let h = 1e-7 * p[k].abs().max(1e-6);
            let mut q = p.clone();
            q[k] += h;
            let rk = residuals(&q, y, g);
            jac.set_column(k, &((rk - &r) / h));
        }
        let jtj = jac.transpose() * &jac;
        let jtr = jac.transpose() * &r;
        let before = cost(&p);
        let mut stepped = false;
        for _ in 0..20 {
            let mut a = jtj.clone();
            for k in 0..9 {
                a[(k, k)] *= 1.0 + lambda;
            }
            let Some(step) = a.lu().solve(&(-&jtr)) else {
                lambda *= 10.0;
                continue;
            };
            let q = &p + &step;
            if cost(&q) < before {
                p = q;
                lambda = (lambda / 10.0).max(1e-12);
                stepped = true;
                break;
            }
            lambda *= 10.0;
        }
        if !stepped {
            break;
        }
    }
    p
}

fn main() -> ExitCode {
    let Some(path) = std::env::args().nth(1) else {
        eprintln!("usage: imutk_model CAL.json (rotacal calibrate FILE --json CAL.json)");
        return ExitCode::from(2);
    };
    let cal: serde_json::Value = match std::fs::read_to_string(&path)
        .map_err(|e| e.to_string())
        .and_then(|t| serde_json::from_str(&t).map_err(|e| e.to_string()))
    {
        Ok(v) => v,
        Err(e) => {
            eprintln!("{path}: {e}");
            return ExitCode::FAILURE;
        }
    };
    let g = cal["g_loc"].as_f64().unwrap_or(f64::NAN);
    let entry = &cal["by_rate"][0];
    let mut y = Vec::new();
    for d in entry["free"]["detection"].as_array().into_iter().flatten() {
        for iv in d["intervals"].as_array().into_iter().flatten() {
            if iv["verdict"] == "kept" {
                let m: Vec<f64> = iv["mean"]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .filter_map(|v| v.as_f64())
                    .collect();
                if m.len() == 3 {
                    y.push(Vector3::new(m[0], m[1], m[2]));
                }
            }
        }
    }
    if y.len() < 9 || !g.is_finite() {
        eprintln!("{path}: not a free calibration with nine kept poses and g_loc");
        return ExitCode::FAILURE;
    }
    let p = fit(&y, g);
    let Some(s) = tk(&p).try_inverse() else {
        eprintln!("the fitted T·K is singular");
        return ExitCode::FAILURE;
    };
    let rows: Vec<Vector3<f64>> = (0..3).map(|j| s.row(j).transpose()).collect();
    let angle = |a: usize, b: usize| {
        (rows[a].dot(&rows[b]) / (rows[a].norm() * rows[b].norm()))
            .acos()
            .to_degrees()
    };
    let ours = [
        rows[0].norm(),
        rows[1].norm(),
        rows[2].norm(),
        angle(0, 1),
        angle(1, 2),
        angle(2, 0),
        p[6],
        p[7],
        p[8],
    ];
    let intr = &entry["intrinsic"];
    let theirs = [
        &intr["sensitivity"]["u"],
        &intr["sensitivity"]["v"],
        &intr["sensitivity"]["w"],
        &intr["angle_deg"]["uv"],
        &intr["angle_deg"]["vw"],
        &intr["angle_deg"]["wu"],
        &intr["offset"]["u"],
        &intr["offset"]["v"],
        &intr["offset"]["w"],
    ];
    let names = [
        "s_u", "s_v", "s_w", "φ_uv", "φ_vw", "φ_wu", "O_u", "O_v", "O_w",
    ];
    println!(
        "{} kept poses; imu_tk's model (cost Σ(g² − ‖a‖²)²) against rotacal:",
        y.len()
    );
    let mut worst: f64 = 0.0;
    for ((name, o), t) in names.iter().zip(ours).zip(theirs) {
        let (v, u) = (
            t["value"].as_f64().unwrap_or(f64::NAN),
            t["expanded_unc"].as_f64().unwrap_or(f64::NAN),
        );
        worst = worst.max(((o - v) / u).abs());
        println!(
            "  {name:<5} imu_tk {o:>14.6}  rotacal {v:>14.6} ± {u:.3e}  difference {:+.3e} = {:+.2} U",
            o - v,
            (o - v) / u
        );
    }
    println!("largest |difference| / U: {worst:.2}");
    ExitCode::SUCCESS
}
