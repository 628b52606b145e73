//! The residuals' structure check (docs/uncertainty.md, "Structure beyond the noise"): the
//! widened fit each group's noise model is estimated from leaves noise only, unless the
//! data hold what no noise model should take in: a harmonic of the table angle above the
//! fourth, or a step in the level. Such structure would read as correlated noise and widen
//! U in silence; the scan ([`crate::fit::structure`]) finds it, and the calibration warns
//! and sets `residual_structure.found` in its JSON (the file's count of tests and the JSON
//! are made where the groups are assembled, `rotation.rs`).

use crate::fit::structure::{self, HarmonicTest, StepTest};
use nalgebra::{DMatrix, DVector};

/// The chance that noise alone raises a warning anywhere in a file, per kind of test
/// (harmonics, steps): Bonferroni over the file's tests of that kind.
pub const ALPHA: f64 = 1e-3;

/// The weighted columns sin kα, cos kα of the harmonics k asked for, per row.
pub(super) type HarmonicColumns<'a> = dyn Fn(&[usize]) -> DMatrix<f64> + 'a;

/// One channel's scan of its widened-fit residuals, before the file's count of tests.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ChannelScan {
    /// Each harmonic above the fourth below the sampling limit.
    pub harmonics: Vec<HarmonicTest>,
    /// The most likely step, and its time from the group's first row, s.
    pub step: Option<(StepTest, f64)>,
    /// With `--slow-noise`, where the channel's slow noise was estimated: the step's
    /// statistic standardised by its variance under the AR model and the flicker and walk
    /// levels, which replaces the scan's own (a walk makes steps the AR model cannot).
    pub slow_z: Option<f64>,
}

/// The scan of one channel: `resid` the weighted residuals of the fit of the columns of
/// `wide`, `flags` its rows at a rail (left out of the fit, zero here), `dt_s` the mean
/// row interval, `rate_hz` the rotation's, `times` each row's time from the first, s,
/// and `weight` the rows' rms weight (sizes are given in the readings' units).
/// `harmonic_columns` gives the weighted columns sin kα, cos kα of harmonics k: those the
/// channel's own tests find (Bonferroni over them) join the fit before the step is looked
/// for, as a harmonic left in would make steps of its own.
pub(super) fn scan_channel(
    resid: &DVector<f64>,
    (wide, harmonic_columns): (&DMatrix<f64>, &HarmonicColumns<'_>),
    flags: &[bool],
    (dt_s, rate_hz, weight): (f64, f64, f64),
    times: &[f64],
) -> ChannelScan {
    let mut e = resid.clone();
    let mask = |x: &mut DMatrix<f64>| {
        for (mut row, _) in x.row_iter_mut().zip(flags).filter(|(_, f)| **f) {
            row.fill(0.0);
        }
    };
    for (v, _) in e.iter_mut().zip(flags).filter(|(_, f)| **f) {
        *v = 0.0;
    }
    let mut harmonics = structure::harmonics(e.as_slice(), dt_s, rate_hz);
    let count = harmonics.len().max(1) as f64;
    let found: Vec<usize> = harmonics
        .iter()
        .filter(|h| h.p_single * count < ALPHA)
        .map(|h| h.k)
        .collect();
    for h in &mut harmonics {
        h.amplitude /= weight;
    }
    let mut x = wide.clone();
    if !found.is_empty() {
        let extra = harmonic_columns(&found);
        if extra.nrows() == x.nrows() {
            let q = x.ncols();
            x = x.resize_horizontally(q + extra.ncols(), 0.0);
            x.columns_mut(q, extra.ncols()).copy_from(&extra);
        }
    }
    mask(&mut x);
    let basis = x.qr().q();
    // e is orthogonal to `wide`'s columns: its residual on the wider basis is e less its
    // projection.
    if !found.is_empty() {
        let proj = &basis * (basis.tr_mul(&e));
        e -= proj;
    }
    let step = structure::step(e.as_slice(), &basis).map(|mut s| {
        s.size /= weight;
        (s, times.get(s.row).copied().unwrap_or(f64::NAN))
    });
    ChannelScan {
        harmonics,
        step,
        slow_z: None,
    }
}
