//! Monte Carlo coverage of the rotation method's uncertainties (GUM Supplement 1 style
//! validation): 2000 simulated seed 000 10 mHz runs (three conditions × 4200 samples at
//! 16 Hz, LSM6DS33 noise, quantised to counts) of a device with seed 000 Table 1's DC
//! properties, mounted 3° off. For each of the six properties the fraction of k = 2
//! intervals that hold the truth must lie in [0.93, 0.97] (≈ ±4 binomial σ around 0.954
//! at 2000 trials). The spread is also compared with the Cramér–Rao bound.
// Matrix arithmetic on small fixed arrays reads more plainly with indices.
#![allow(clippy::needless_range_loop)]
use rotacal::calibrate;
use rotacal::demo::{
    paper_run_spec, sensitivity_from_intrinsic, PAPER_DC_ANGLES_DEG, PAPER_DC_SENSITIVITY,
    PAPER_G_LOC,
};
use rotacal::geometry::{mounted, rotation};
use rotacal_shared::synth::Synth;
use rotacal_shared::{FitConfig, PhaseStep, SineFit, TickRate};

const TRIALS: u64 = 2000;

/// 3° about (1, 2, 2).
fn tilt(s: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    mounted(&s, &rotation([1.0, 2.0, 2.0], 3.0))
}

#[test]
fn rotation_k2_intervals_cover_the_truth() {
    let clock = TickRate::MHZ_1;
    let step = PhaseStep::from_micro_hz(10_000, clock).unwrap();
    let s = tilt(sensitivity_from_intrinsic(
        PAPER_DC_SENSITIVITY,
        PAPER_DC_ANGLES_DEG,
    ));
    let truth: Vec<f64> = PAPER_DC_SENSITIVITY
        .iter()
        .chain(PAPER_DC_ANGLES_DEG.iter())
        .copied()
        .collect();
    let mut covered = [0u32; 6];
    let mut sum = [0.0f64; 6];
    let mut sum2 = [0.0f64; 6];
    let mut mean_u = [0.0f64; 6];
    for trial in 0..TRIALS {
        let fits = [0usize, 1, 2].map(|axis| {
            let spec = paper_run_spec(&s, axis, step, 0x5EED_0000 + 3 * trial + axis as u64);
            let mut fit = SineFit::<f64>::new(FitConfig::sine(step, clock));
            for smp in Synth::new(spec) {
                fit.update(smp.t, smp.counts.map(f64::from)).unwrap();
            }
            fit.solve().unwrap()
        });
        let r = calibrate::rotation([&fits[0], &fits[1], &fits[2]], PAPER_G_LOC, 0.0).unwrap();
        let est: Vec<_> = r
            .intrinsic
            .sensitivity
            .iter()
            .chain(r.intrinsic.angle_deg.iter())
            .collect();
        for k in 0..6 {
            let e = est[k];
            if (e.value - truth[k]).abs() <= 2.0 * e.std_unc {
                covered[k] += 1;
            }
            sum[k] += e.value;
            sum2[k] += e.value * e.value;
            mean_u[k] += e.std_unc / TRIALS as f64;
        }
    }
    let names = ["s_u", "s_v", "s_w", "φ_uv", "φ_vw", "φ_wu"];
    let n = TRIALS as f64;
    let mut failures = Vec::new();
    for k in 0..6 {
        let frac = f64::from(covered[k]) / n;
        let sd = ((sum2[k] - sum[k] * sum[k] / n) / (n - 1.0)).sqrt();
        println!(
            "{:<5} coverage {:.4}  MC spread {:.3e}  mean stated u {:.3e}  ratio {:.3}",
            names[k],
            frac,
            sd,
            mean_u[k],
            sd / mean_u[k]
        );
        if !(0.93..=0.97).contains(&frac) {
            failures.push(format!("{}: coverage {frac}", names[k]));
        }
    }
    assert!(failures.is_empty(), "{failures:?}");
}
