//! `rotacal crosscheck RECORDING FIT-LOG`: re-fits in f64 (nalgebra QR), from the recorded
//! samples, exactly the windows the device fitted (first to last seq, per condition),
//! with the device's regressors (its phase step and clock), and compares.
//!
//! Pass: every A, B, C of every report within `threshold` σ_CRLB of the host's value,
//! with σ_CRLB = √(2σ̂²/N) for A and B and √(σ̂²/N) for C (σ̂ the host fit's residual
//! standard deviation), and every window complete.
//!
//! The default threshold, 10⁻⁵ σ_CRLB, is set by what the check must see: one count changed
//! in one conversion of one sample moves the row's mean by 1/n (n ≤ 7 conversions), and the
//! fitted offset C of every window holding it by 1/(nN) counts, which is 1/(n·σ̂·√N) in
//! units of σ_CRLB(C) = σ̂/√N: about 5·10⁻⁴ for the demo's final windows (N = 4199, σ̂ ≈ 4.2
//! counts per averaged sample), 50 times the threshold. The device's f32 fit and the host's f64 re-fit
//! agree to 1.4–2.2·10⁻⁷ σ_CRLB on the demo's session, 45 times below it (docs/protocol.md).

use crate::recording::from_device::{FitLine, LogLine};
use crate::recording::Recording;
use crate::verify::{compare, VerifyError};
use rotacal_shared::{Condition, Ticks};
use serde::Serialize;
use std::fmt::Write as _;

/// The default pass threshold, in σ_CRLB.
pub const DEFAULT_THRESHOLD: f64 = 1e-5;

/// One device fit against the host's.
#[derive(Clone, Debug, Serialize)]
pub struct FitCheck {
    /// x, y or z.
    pub condition: Condition,
    /// At stop or periodic.
    pub is_final: bool,
    /// The device's window.
    pub first_seq: u32,
    /// See `first_seq`.
    pub last_seq: u32,
    /// Samples the device fitted.
    pub n_device: u32,
    /// Rows of the window found in the recording.
    pub n_recorded: usize,
    /// max over channels and A, B, C of |device − host| / host standard error.
    pub max_delta_se: f64,
    /// … / σ_CRLB.
    pub max_delta_crlb: f64,
    /// Within the threshold and complete.
    pub passed: bool,
}

/// The comparison.
#[derive(Clone, Debug, Serialize)]
pub struct CrosscheckReport {
    /// Pass threshold, σ_CRLB.
    pub threshold: f64,
    /// Every report.
    pub fits: Vec<FitCheck>,
    /// Worst over all.
    pub max_delta_crlb: f64,
    /// All passed (and there was at least one).
    pub passed: bool,
}

fn check_one(rec: &Recording, f: &FitLine, threshold: f64) -> Result<FitCheck, VerifyError> {
    let mut window = Vec::new();
    for g in rec.groups.iter().filter(|g| g.condition == f.condition) {
        let seq = g.seq.as_ref().ok_or_else(|| VerifyError::NoSeq {
            source_name: rec.source.clone(),
        })?;
        let readings = g.u.iter().zip(&g.v).zip(&g.w);
        for (i, (s, ((&u, &v), &w))) in seq.iter().zip(readings).enumerate() {
            // Sequence numbers start afresh in each boot of the device.
            let boot = g
                .boot
                .as_ref()
                .map_or(0, |b| b.get(i).copied().unwrap_or(0));
            if boot == f.boot && (u64::from(f.first_seq)..=u64::from(f.last_seq)).contains(s) {
                let t = *g.t_s.get(i).ok_or(VerifyError::NoTime)?;
                let ticks = (t * f64::from(f.tick_hz)).round();
                if !(0.0..1.8e19).contains(&ticks) {
                    return Err(VerifyError::TimeOutOfRange {
                        source_name: rec.source.clone(),
                        t_s: t,
                    });
                }
                // The conversions the row averages, in the same device ticks.
                let ap = g.aperture(i, Ticks(ticks as u64), 1.0).ok_or_else(|| {
                    VerifyError::Conversions {
                        source_name: rec.source.clone(),
                        seq: *s,
                    }
                })?;
                window.push((ap, [u, v, w]));
            }
        }
    }
    let n_recorded = window.len();
    let (max_se, max_crlb) = if n_recorded == f.n as usize {
        let c = compare(&window, f)?;
        (c.max_delta_se, c.max_delta_crlb)
    } else {
        (f64::INFINITY, f64::INFINITY)
    };
    Ok(FitCheck {
        condition: f.condition,
        is_final: f.is_final,
        first_seq: f.first_seq,
        last_seq: f.last_seq,
        n_device: f.n,
        n_recorded,
        max_delta_se: max_se,
        max_delta_crlb: max_crlb,
        passed: max_crlb <= threshold,
    })
}

/// Compare every fit report of the log with the recording.
pub fn crosscheck(
    rec: &Recording,
    log: &[LogLine],
    threshold: f64,
) -> Result<CrosscheckReport, VerifyError> {
    rec.require_conditions("the cross-check")?;
    let fits = log
        .iter()
        .filter_map(|l| match l {
            LogLine::Fit(f) => Some(check_one(rec, f, threshold)),
            LogLine::QuickLook { .. } => None,
        })
        .collect::<Result<Vec<_>, _>>()?;
    let max = fits.iter().map(|f| f.max_delta_crlb).fold(0.0, f64::max);
    Ok(CrosscheckReport {
        threshold,
        passed: !fits.is_empty() && fits.iter().all(|f| f.passed),
        max_delta_crlb: max,
        fits,
    })
}

/// The terminal table.
pub fn render(r: &CrosscheckReport) -> String {
    let mut o = String::from(
        "cond  kind      seq window        n dev / rec   max Δ/se   max Δ/σ_CRLB  result\n",
    );
    for f in &r.fits {
        let _ = writeln!(
            o,
            "{:<5} {:<9} {:>7}–{:<7} {:>6} / {:<6} {:>9.2e}   {:>12.2e}  {}",
            f.condition,
            if f.is_final { "final" } else { "periodic" },
            f.first_seq,
            f.last_seq,
            f.n_device,
            f.n_recorded,
            f.max_delta_se,
            f.max_delta_crlb,
            if f.passed { "ok" } else { "FAIL" }
        );
    }
    let _ = writeln!(
        o,
        "{} device fits; worst |device − host f64| = {:.2e} σ_CRLB (threshold {:e}): {}",
        r.fits.len(),
        r.max_delta_crlb,
        r.threshold,
        if r.passed { "passed" } else { "FAILED" }
    );
    o
}
