//! The reference values rotacal reproduces: Table 1 of Gaitan & Geist, *Measurement* 189
//! (2022) 110528 (docs/method.md), the paper whose 10 mHz session the demo, the simulator's
//! `paper-10mhz` preset and the tests take as their truth.

use rotacal_shared::synth::{self, crosscheck, SynthSpec};
use rotacal_shared::{PhaseStep, TickRate};

/// Gaitan & Geist (2022) Table 1, DC column: sensitivities (counts per m/s²), angles φ_uv, φ_vw, φ_wu
/// (degrees) and offsets (counts).
pub const PAPER_DC_SENSITIVITY: [f64; 3] = [1669.32, 1669.10, 1676.46];
/// See [`PAPER_DC_SENSITIVITY`].
pub const PAPER_DC_ANGLES_DEG: [f64; 3] = [90.077, 90.095, 89.910];
/// See [`PAPER_DC_SENSITIVITY`].
pub const PAPER_DC_OFFSETS: [f64; 3] = [525.1, 99.6, 442.4];
/// Gaitan & Geist (2022) Table 1, 10 mHz column: s_u, s_v, s_w, φ_uv, φ_vw, φ_wu and their stated
/// uncertainties (the paper does not give the coverage factor).
pub const PAPER_10MHZ: [(f64, f64); 6] = [
    (1669.54, 0.66),
    (1669.14, 0.47),
    (1676.43, 0.75),
    (90.099, 0.032),
    (90.122, 0.034),
    (89.910, 0.040),
];
/// Gaitan & Geist (2022)'s local gravity, m/s².
pub const PAPER_G_LOC: f64 = 9.80101;

/// Gaitan & Geist (2022)'s 10 mHz run, one condition: the sensitivity matrix `s` (counts per m/s²)
/// turned about platter axis `axis` (0 = x, 1 = y, 2 = z) with Gaitan & Geist (2022) Table 1's DC
/// offsets, 4200 samples at 16 Hz with LSM6DS33 noise, timestamps on a 1 MHz clock.
/// `step` is the true rotation per tick (nominally 10 mHz).
pub fn paper_run_spec(s: &[[f64; 3]; 3], axis: usize, step: PhaseStep, seed: u64) -> SynthSpec {
    SynthSpec {
        coef: synth::coefficients(s, &PAPER_DC_OFFSETS, PAPER_G_LOC, axis),
        noise_sigma: crosscheck::noise_sigma(16_000),
        step,
        clock: TickRate::MHZ_1,
        sample_rate_mhz: 16_000,
        n_samples: 4200,
        drop_per_million: 0,
        seed,
    }
}
