//! The streaming calibration (`calibrate::stream`, docs/streaming.md) against the engine
//! that holds every row, on the same files, and one pass against two.
//!
//! Each file is calibrated twice by the streaming engine (`Mode::hold`): holding every group
//! (the rows in memory, the engine `rotacal calibrate` used before) and holding none (sums
//! only). What may differ, and by how much, follows from how the sums are used:
//! - the fits' normal equations are summed in another order and solved by Cholesky rather
//!   than QR: values agree to rounding, 10⁻¹⁰ relative (N·ε·κ with N ≈ 6·10⁴ rows, ε the
//!   double precision and κ ≲ 10² for sines and a constant);
//! - the budget's rate line is a difference of two nearby fits divided by u_rate: its
//!   rounding is that of the fits over a change of order u_rate·T ≈ 10⁻⁵, and it is a small
//!   share of U: U agrees to 10⁻⁸ relative;
//! - under correlated noise (an AR model of order p > 0) the streaming engine takes the
//!   noise's effect on the sine fit and on the residuals from its spectrum at the fit's
//!   frequencies rather than from the N × N covariance: an approximation of relative order
//!   τ/N (τ the correlation time in samples). It must move U by less than a tenth of U's
//!   own relative standard uncertainty as an estimate, 1/√(2ν_eff);
//! - when the true rate differs from nominal, the two engines stop the IEEE 1057
//!   iteration at different iterates, within 10⁻³ of its standard error of each other: the
//!   fits move by that fraction of what one standard error of the rate moves them (about
//!   10⁻⁵ relative here), 10⁻⁷ relative at most.
// Tests may index: a panic there is a failure.
#![allow(clippy::indexing_slicing)]

use super::{calibrate_file_as, Mode};
use crate::calibrate::json::CalibrationJson;
use crate::calibrate::Options;
use crate::simulate::config::{RateError, Saturation};
use crate::simulate::{Config, Noise, NoiseSd, Simulation};
use std::path::{Path, PathBuf};

/// A rotation recording of `rows` rows per condition at 104 Hz, paper-10mhz's device,
/// noise of a different level per channel and unstated (as on a real recording).
fn config(seed: u64, rows: u64, ar: Option<Vec<f64>>, lowpass_hz: Option<f64>) -> Config {
    let mut cfg = Config::preset("paper-10mhz").unwrap();
    cfg.seed = seed;
    cfg.table.rates_hz = Some(vec![0.25]);
    cfg.table.samples_per_condition = Some(rows);
    cfg.table.duration_s = None;
    cfg.timing.sample_rate_hz = 104.0;
    cfg.mounting.axis = [1.0, 2.0, 2.0];
    cfg.mounting.angle_deg = 3.0;
    cfg.sensor.noise = Some(Noise {
        sd: Some(NoiseSd::PerChannel([10.6, 8.5, 12.5])),
        ar,
        lowpass_hz,
        state: false,
        flicker_floor_ug: None,
        random_walk_ug_per_sqrt_s: None,
    });
    cfg
}

/// A folder of this process's own for `test`.
fn tmp(test: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("rotacal-streaming-{}-{test}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn write(dir: &Path, name: &str, cfg: Config) -> PathBuf {
    let path = dir.join(name);
    Simulation::new(cfg).unwrap().write_file(&path).unwrap();
    path
}

/// The streaming engine holding groups of at most `hold` rows, with one pass where the
/// pilots allow.
fn holding(hold: usize) -> Mode {
    Mode {
        hold,
        one_pass: true,
    }
}

/// (held, streamed) calibrations of `path`.
fn both(path: &Path, opts: &Options) -> (CalibrationJson, CalibrationJson) {
    let held = calibrate_file_as(path, opts, holding(usize::MAX)).unwrap();
    let streamed = calibrate_file_as(path, opts, holding(0)).unwrap();
    (held, streamed)
}

/// The largest relative differences of the six properties' values and of their standard
/// uncertainties, and the smallest ν_eff, over every rate.
fn differences(a: &CalibrationJson, b: &CalibrationJson) -> (f64, f64, f64) {
    assert_eq!(a.by_rate.len(), b.by_rate.len());
    let (mut dv, mut du, mut nu) = (0.0f64, 0.0f64, f64::INFINITY);
    for (ra, rb) in a.by_rate.iter().zip(&b.by_rate) {
        assert_eq!(ra.rate_hz, rb.rate_hz);
        for (qa, qb) in ra
            .intrinsic
            .quantities()
            .iter()
            .zip(rb.intrinsic.quantities())
        {
            dv = dv.max((qa.value - qb.value).abs() / qa.value.abs());
            du = du.max((qa.std_unc - qb.std_unc).abs() / qa.std_unc);
        }
        let budget = ra.uncertainty_budget.as_ref().unwrap();
        for c in budget.combined.iter() {
            if let Some(n) = c.nu_eff {
                nu = nu.min(n);
            }
        }
    }
    (dv, du, nu)
}

/// The AR orders the streamed calibration chose, per channel and condition.
fn orders(c: &CalibrationJson) -> Vec<usize> {
    c.by_rate
        .iter()
        .flat_map(|r| r.noise.iter().flatten().map(|n| n.ar.len()))
        .collect()
}

/// `b`'s differences from `a` as [`differences`] gives them, with U's bound: a tenth of
/// U's own relative uncertainty under correlated noise, rounding (10⁻⁸) under white. The
/// AR orders must be the same, and U within its bound.
fn compared(what: &str, a: &CalibrationJson, b: &CalibrationJson) -> (f64, f64, f64, f64) {
    let (dv, du, nu) = differences(a, b);
    assert_eq!(orders(a), orders(b), "{what}: AR orders");
    let correlated = orders(b).iter().any(|p| *p > 0);
    let bound_u = if correlated {
        0.1 / (2.0 * nu).sqrt()
    } else {
        1e-8
    };
    assert!(du <= bound_u, "{what}: U differs by {du:e} > {bound_u:e}");
    (dv, du, bound_u, nu)
}

/// The two engines agree as the module's documentation says they must.
fn agree(what: &str, path: &Path, opts: &Options) {
    let (held, streamed) = both(path, opts);
    let (dv, du, bound_u, nu) = compared(what, &held, &streamed);
    println!("{what}: values {dv:.1e}, U {du:.1e} (bound {bound_u:.1e}, ν_eff ≥ {nu:.0})");
    assert!(dv <= 1e-10, "{what}: values differ by {dv:e}");
}

#[test]
fn white_noise_gives_the_held_engines_figures() {
    let dir = tmp("white");
    let path = write(dir.as_path(), "white.csv", config(181, 20_000, None, None));
    let (held, streamed) = both(&path, &Options::default());
    assert!(
        orders(&streamed).iter().all(|p| *p == 0),
        "white noise read as AR"
    );
    agree("white", &path, &Options::default());
    // The fits, noise levels and rms residuals too.
    let (a, b) = (&held.by_rate[0], &streamed.by_rate[0]);
    for (fa, fb) in a.fits.iter().zip(&b.fits) {
        let amp = fa.a.hypot(fa.b).max(1.0);
        for (x, y) in [(fa.a, fb.a), (fa.b, fb.b), (fa.c, fb.c)] {
            assert!((x - y).abs() <= 1e-10 * amp, "fit {x} against {y}");
        }
        assert!((fa.rms_residual - fb.rms_residual).abs() <= 1e-10 * fa.rms_residual);
        assert_eq!(fa.n, fb.n);
    }
    for (na, nb) in a.noise.iter().flatten().zip(b.noise.iter().flatten()) {
        assert!(
            (na.sd - nb.sd).abs() <= 1e-10 * na.sd,
            "{} {}",
            na.sd,
            nb.sd
        );
    }
}

#[test]
fn correlated_noise_moves_u_by_less_than_its_own_uncertainty_allows() {
    let dir = tmp("correlated");
    let ar = write(
        dir.as_path(),
        "ar.csv",
        config(182, 20_000, Some(vec![0.6]), None),
    );
    agree("AR(1) 0.6", &ar, &Options::default());
    let lp = write(
        dir.as_path(),
        "lowpass.csv",
        config(183, 20_000, None, Some(11.6)),
    );
    agree("low-pass 11.6 Hz", &lp, &Options::default());
}

#[test]
fn clipped_channels_take_the_correcting_pass() {
    let dir = tmp("clipped");
    let mut cfg = config(184, 20_000, None, None);
    // Rails inside the ±16 000-count swing: some channels' peaks pile up on them.
    cfg.effects.saturation = Some(Saturation {
        rails: [-15_000.0, 15_000.0],
    });
    let path = write(dir.as_path(), "clipped.csv", cfg);
    let streamed = calibrate_file_as(&path, &Options::default(), holding(0)).unwrap();
    let excluded: usize = streamed.by_rate[0]
        .noise
        .iter()
        .flatten()
        .map(|n| n.n_excluded)
        .sum();
    assert!(excluded > 0, "no reading was found on a rail");
    agree("clipped", &path, &Options::default());
}

#[test]
fn a_rate_off_nominal_is_fitted_and_refitted() {
    let dir = tmp("rate");
    let mut cfg = config(185, 20_000, None, None);
    cfg.effects.rate_error = Some(RateError { relative: 2e-4 });
    let path = write(dir.as_path(), "rate.csv", cfg);
    let (held, streamed) = both(&path, &Options::default());
    for c in [&held, &streamed] {
        assert!(c.by_rate[0].fits.iter().all(|f| f.rate_hz_fitted.is_some()));
    }
    let (dv, du, _) = differences(&held, &streamed);
    println!("rate off nominal: values {dv:.1e}, U {du:.1e}");
    assert!(dv <= 1e-7 && du <= 1e-7, "values {dv:e}, U {du:e}");
}

#[test]
fn averaged_rows_and_several_rates() {
    let dir = tmp("averaged");
    // Through the firmware's logic: rows that average several conversions (conv_gaps).
    let sim = Simulation::new(config(186, 20_000, None, None)).unwrap();
    let path = dir.as_path().join("device.csv");
    let file = std::fs::File::create(&path).unwrap();
    crate::simulate::device::record(&sim, file, std::io::sink()).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.contains("conv_gaps"));
    agree("averaged rows", &path, &Options::default());
    // Two rates in one file.
    let mut cfg = config(187, 12_000, None, None);
    cfg.table.rates_hz = Some(vec![0.25, 0.5]);
    let path = write(dir.as_path(), "two-rates.csv", cfg);
    agree("two rates", &path, &Options::default());
}

#[test]
fn a_file_the_fast_reader_hands_back_gives_the_same_figures() {
    let dir = tmp("quoted");
    let path = write(dir.as_path(), "plain.csv", config(188, 20_000, None, None));
    // The same file with one field quoted: read by the csv reader, in one part.
    let text = std::fs::read_to_string(&path).unwrap();
    let quoted = text.replacen("\nx,0,", "\n\"x\",0,", 1);
    assert_ne!(quoted, text);
    let qpath = dir.as_path().join("quoted.csv");
    std::fs::write(&qpath, quoted).unwrap();
    let opts = Options::default();
    let a = calibrate_file_as(&path, &opts, holding(0)).unwrap();
    let b = calibrate_file_as(&qpath, &opts, holding(0)).unwrap();
    let (dv, du, _) = differences(&a, &b);
    assert!(dv <= 1e-10 && du <= 1e-8, "values {dv:e}, U {du:e}");
}

/// One pass against two: the residuals' lagged sums from each part's pilot
/// (`calibrate::pilot`) against the residual pass, on the same streamed file. Lag 0 and
/// the residual sums of squares are exact algebra on the pass's sums (the expansion's
/// remainder aside, (εT)² ≤ 10⁻⁸ of a harmonic): the noise level, the rms residuals and,
/// for white noise, U agree to rounding, 10⁻⁸ relative as above. The other lags carry the
/// uniform-spacing error the engine bounds at run time by 0.01 of their own standard
/// error, γ₀·√N: under correlated noise U moves by less than a tenth of its own relative
/// uncertainty, as for the held engine. The values do not depend on the residuals at all.
fn one_pass_agrees(what: &str, path: &Path) -> (CalibrationJson, CalibrationJson) {
    let opts = Options::default();
    let one = calibrate_file_as(
        path,
        &opts,
        Mode {
            hold: 0,
            one_pass: true,
        },
    )
    .unwrap();
    let two = calibrate_file_as(
        path,
        &opts,
        Mode {
            hold: 0,
            one_pass: false,
        },
    )
    .unwrap();
    let (dv, du, bound_u, _) = compared(what, &two, &one);
    println!("one pass, {what}: values {dv:.1e}, U {du:.1e} (bound {bound_u:.1e})");
    assert!(dv == 0.0, "{what}: values differ by {dv:e}");
    for (a, b) in two.by_rate.iter().zip(&one.by_rate) {
        for (fa, fb) in a.fits.iter().zip(&b.fits) {
            let d = (fa.rms_residual - fb.rms_residual).abs() / fa.rms_residual;
            assert!(d <= 1e-10, "{what}: rms residual {d:e}");
        }
        for (na, nb) in a.noise.iter().flatten().zip(b.noise.iter().flatten()) {
            assert!((na.sd - nb.sd).abs() <= 1e-8 * na.sd, "{what}: noise sd");
        }
    }
    (one, two)
}

#[test]
fn one_pass_gives_the_residual_pass_figures() {
    let dir = tmp("one-pass");
    let json = |c: &CalibrationJson| serde_json::to_string(c).unwrap();
    let white = write(dir.as_path(), "white.csv", config(191, 20_000, None, None));
    let (one, two) = one_pass_agrees("white", &white);
    // The pilots' sums stood in (the residual pass's own are not the same to the bit).
    assert_ne!(json(&one), json(&two), "the residual pass ran");
    let ar = write(
        dir.as_path(),
        "ar.csv",
        config(192, 20_000, Some(vec![0.6]), None),
    );
    one_pass_agrees("AR(1) 0.6", &ar);
    let lp = write(
        dir.as_path(),
        "lowpass.csv",
        config(193, 20_000, None, Some(11.6)),
    );
    one_pass_agrees("low-pass 11.6 Hz", &lp);
    // Timestamps 2 µs (sd) off the grid: the pilots hold.
    let mut cfg = config(194, 20_000, Some(vec![0.3]), None);
    cfg.timing.jitter_s = 2e-6;
    let rough = write(dir.as_path(), "rough.csv", cfg);
    let (one, two) = one_pass_agrees("jitter 2 µs", &rough);
    assert_ne!(json(&one), json(&two), "the residual pass ran");
    // A clock 40 ppm fast: the rate is beyond pass 1's reach and the correcting pass runs,
    // with pilots about the rate pass 1 fitted, which stand in for the residual pass.
    let mut cfg = config(197, 20_000, Some(vec![0.3]), None);
    cfg.timing.clock_error_ppm = 40.0;
    let fast = write(dir.as_path(), "fast-clock.csv", cfg);
    let (one, two) = one_pass_agrees("clock 40 ppm fast", &fast);
    assert_ne!(json(&one), json(&two), "the residual pass ran");
    // Lost samples (rows a period apart span two) and jitter of 0.05 of the period: the
    // bound is not met and the residual pass runs.
    let mut cfg = config(195, 20_000, None, None);
    cfg.timing.drop_probability = 1e-3;
    let lost = write(dir.as_path(), "lost.csv", cfg);
    let mut cfg = config(196, 20_000, None, None);
    cfg.timing.jitter_s = 0.05 / 104.0;
    let jittery = write(dir.as_path(), "jittery.csv", cfg);
    for (what, path) in [("lost samples", &lost), ("jitter 480 µs", &jittery)] {
        let (one, two) = one_pass_agrees(what, path);
        assert_eq!(json(&one), json(&two), "{what}: the pilots' sums stood in");
    }
    std::fs::remove_dir_all(&dir).ok();
}
