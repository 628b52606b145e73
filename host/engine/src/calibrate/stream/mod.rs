//! `rotacal calibrate` on a file: a rotation recording is read in passes, on both cores,
//! and memory does not grow with its length (docs/streaming.md).
//!
//! - **Pass 1** reads and checks every row: the file in two parts ([`Parts`]), each read by
//!   a thread of its own, their groups joined; a file the fast reader hands back (a quote,
//!   any problem) is read by [`recording::scan`] on one thread while this one fits, and
//!   that reader names the problem. A group of at most [`HOLD_ROWS`] rows is kept and
//!   calibrated from its rows exactly as [`super::calibrate`] does. A longer one keeps
//!   sums only: the Taylor sums of [`crate::fit::moments`] (the sine fit, the IEEE 1057
//!   rate fit and the widened noise fit at any nearby rate) and its channels' rails.
//! - **A correcting pass**, only if the data demand it: when the fitted rate is too far
//!   from nominal for the sums' expansion, or a channel has rails (its readings on them
//!   leave the noise fit), the sums are gathered again about the fitted rate (with pilots
//!   about it, for a group without rails).
//! - **Pass 2** takes the residuals of the widened fit at the fitted rate, exactly, into
//!   their lagged sums (the AR noise model, as [`crate::fit::noise::NoiseModel::estimate`]
//!   has it), and the residual sums of squares of the sine fits at the fitted and the
//!   nominal rate. Only for the groups whose pilots cannot stand in for it: pass 1 also
//!   takes the residuals from a pilot fit, corrected to the fitted model afterwards
//!   ([`super::pilot`]).
//!
//! The folder: `mod.rs` the entry and the engine's run; `first` pass 1 (the groups'
//! states); `passes` the correcting and residual passes; `fits` a streamed group's fits
//! from its sums.

mod first;
mod fits;
mod passes;
#[cfg(test)]
mod tests;

use self::first::{first_pass_parts, read_pass, GroupState, PassOne};
use self::fits::{finish, from_pilots, on_rails, prepare, Prepared, Residuals, StreamRefit};
use super::rotation::{self, FittedGroup};
use super::{err, preflight, CalibrateError, CalibrateErrorKind, Options, CLOCK};
use crate::calibrate::json::CalibrationJson;
use crate::recording::{self, Method, Parse, Parts, Recording, RecordingError};
use rotacal_shared::intrinsic::ConditionFit;
use rotacal_shared::PhaseStep;
use std::path::Path;

/// Groups of at most this many rows (10.5 minutes at 104 Hz) are calibrated from their
/// rows in memory; longer ones from sums. It bounds the memory a calibration takes.
pub const HOLD_ROWS: usize = 1 << 16;

/// How far (|ε|·T, rad) the rate fit may move from a pass's expansion point before the
/// sums are gathered again about it: the sine's normal equations then carry a relative
/// error of at most (εT)³/6 ≈ 2·10⁻¹³, the widened fit's (εT)²/2.
const REACH_FIT: f64 = 1e-4;

/// The same for the budget's refits at rate ± u, whose sensitivities are differences of
/// nearby fits: (εT)³/6 relative to a change of order εT, 4·10⁻⁴ of it.
const REACH_REFIT: f64 = 0.05;

/// Rows per block from the reading thread.
const BLOCK: usize = 8192;

/// A calibration of a file failed: reading it, or calibrating it.
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    /// The file could not be read.
    #[error(transparent)]
    Read(#[from] RecordingError),
    /// It was read but not calibrated.
    #[error(transparent)]
    Calibrate(#[from] CalibrateError),
}

/// Calibrate the recording at `path`: a rotation file as a stream (groups of at most
/// [`HOLD_ROWS`] rows from their rows), any other whole, as [`super::calibrate`] does.
pub fn calibrate_file(path: &Path, opts: &Options) -> Result<CalibrationJson, FileError> {
    calibrate_file_as(path, opts, Mode::default())
}

/// Calibrate a recording held as columns in memory (the Python package's DataFrames) as
/// [`calibrate_file`] calibrates a file: a rotation recording read in two parts of rows,
/// on two threads, where the columns are (no copy), groups of at most [`HOLD_ROWS`] rows
/// from their rows and longer ones from sums; anything else, and columns with a problem
/// (which their reader then names), whole, as [`super::calibrate`] does. `meta` is the `# key=value` metadata; `source` names the columns in messages.
pub fn calibrate_columns(
    columns: &[recording::Column<'_>],
    meta: &[(&str, &str)],
    source: &str,
    opts: &Options,
) -> Result<CalibrationJson, FileError> {
    let whole = || -> Result<CalibrationJson, FileError> {
        let rec = recording::read_columns(columns, meta, source, opts.method)?;
        Ok(super::calibrate(&rec, opts)?)
    };
    if matches!(opts.method, Some(Method::Static | Method::Free)) {
        return whole();
    }
    let Some(parts) = Parts::of_columns(columns, meta, source, opts.method)? else {
        return whole();
    };
    if parts.method() != Method::Rotation || parts.segmented() {
        return whole();
    }
    let rec = Recording {
        source: source.to_string(),
        meta: parts.meta().clone(),
        method: parts.method(),
        groups: Vec::new(),
        oriented: None,
        series: None,
    };
    let ranges = parts.split(2)?;
    // A row with a problem: the columns read whole, whose reader names it.
    let Some(groups) = first_pass_parts(&parts, &ranges, opts, HOLD_ROWS)? else {
        return whole();
    };
    if groups.is_empty() {
        return whole();
    }
    Engine {
        path: Path::new(source),
        rec: &rec,
        opts,
        groups,
        parts: Some((parts, ranges)),
        one_pass: true,
    }
    .run()
}

/// How the streaming engine treats a file's groups: what [`calibrate_file`] does, and
/// what the tests compare it with.
#[derive(Clone, Copy, Debug)]
struct Mode {
    /// Groups of at most this many rows are held in memory (0: every group streamed;
    /// `usize::MAX`: every group held, the engine that holds the rows).
    hold: usize,
    /// Whether the pilots' sums may stand in for the residual pass (false: the residual
    /// pass for every streamed group).
    one_pass: bool,
}

impl Default for Mode {
    fn default() -> Self {
        Mode {
            hold: HOLD_ROWS,
            one_pass: true,
        }
    }
}

/// [`calibrate_file`] in `mode`.
fn calibrate_file_as(
    path: &Path,
    opts: &Options,
    Mode { hold, one_pass }: Mode,
) -> Result<CalibrationJson, FileError> {
    let whole = || -> Result<CalibrationJson, FileError> {
        let rec = recording::read_as(path, opts.method)?;
        Ok(super::calibrate(&rec, opts)?)
    };
    if matches!(opts.method, Some(Method::Static | Method::Free)) {
        return whole();
    }
    // The file in two parts, one per core; else (a quote, a problem to name) in one.
    let parts = Parts::open(path, opts.method)?;
    // A file in segments is calibrated with its rows in hand: the joins need them
    // (docs/streaming.md).
    if parts
        .as_ref()
        .is_some_and(|p| p.method() != Method::Rotation || p.segmented())
    {
        return whole();
    }
    let split = match parts {
        Some(p) => {
            let ranges = p.split(2)?;
            first_pass_parts(&p, &ranges, opts, hold)?.map(|g| (p, ranges, g))
        }
        None => None,
    };
    let (rec, groups, parts) = match split {
        // No rows: the reader's error names the file and the problem.
        Some((_, _, groups)) if groups.is_empty() => return whole(),
        Some((p, ranges, groups)) => {
            let rec = Recording {
                source: path.display().to_string(),
                meta: p.meta().clone(),
                method: p.method(),
                groups: Vec::new(),
                oriented: None,
                series: None,
            };
            (rec, groups, Some((p, ranges)))
        }
        None => {
            let mut first = PassOne {
                hold,
                opts,
                scale: 1.0,
                method: Method::Rotation,
                meta: None,
                groups: Vec::new(),
                segmented: false,
            };
            let Some(mut rec) = read_pass(path, opts.method, Parse::All, |ev| first.take(ev))?
            else {
                return whole();
            };
            if first.method != Method::Rotation || first.segmented || first.groups.is_empty() {
                return whole();
            }
            for g in &mut first.groups {
                g.settle();
            }
            if let Some(meta) = first.meta.take() {
                rec.meta = *meta;
            }
            (rec, first.groups, None)
        }
    };
    Engine {
        path,
        rec: &rec,
        opts,
        groups,
        parts,
        one_pass,
    }
    .run()
}

struct Engine<'a> {
    path: &'a Path,
    rec: &'a Recording,
    opts: &'a Options,
    groups: Vec<GroupState>,
    /// The file in parts, when pass 1 read it so.
    parts: Option<(Parts<'a>, Vec<(u64, u64)>)>,
    /// Whether the pilots' sums may stand in for the residual pass.
    one_pass: bool,
}

impl Engine<'_> {
    fn run(mut self) -> Result<CalibrationJson, FileError> {
        let rec = self.rec;
        let pre = preflight(rec, self.opts)?;
        if pre.method != Method::Rotation {
            return Err(err(
                rec,
                None,
                CalibrateErrorKind::Internal("the streaming engine is for rotation files"),
            )
            .into());
        }
        let keys: Vec<_> = self
            .groups
            .iter()
            .map(|gs| (gs.condition, gs.rate_col))
            .collect();
        let plan = rotation::plan(rec, &keys, self.opts)?;
        // Each group: from its rows, or prepared for the residual pass.
        let mut fitted: Vec<Option<FittedGroup<'_>>> = keys.iter().map(|_| None).collect();
        let mut prepared: Vec<Prepared> = Vec::new();
        for rate in &plan {
            for &i in &rate.groups {
                let Some(gs) = self.groups.get_mut(i) else {
                    continue;
                };
                if let Some(kept) = gs.kept.take() {
                    if let Some(slot) = fitted.get_mut(i) {
                        *slot = Some(rotation::held(
                            rec,
                            &kept,
                            rate.nominal_hz,
                            self.opts.slow_noise,
                        )?);
                    }
                } else {
                    prepared.push(prepare(rec, i, gs, rate.nominal_hz)?);
                }
            }
        }
        // A correcting pass for the groups whose data demand it.
        let again: Vec<usize> = prepared
            .iter()
            .enumerate()
            .filter(|(_, p)| !p.moments.within(p.fitted, REACH_FIT) || on_rails(&p.rails))
            .map(|(k, _)| k)
            .collect();
        if !again.is_empty() {
            self.correcting_pass(&mut prepared, &again)?;
        }
        // The residuals' sums from the pilots where the data allow, else from a pass.
        let mut residuals: Vec<Option<Residuals>> = Vec::with_capacity(prepared.len());
        for p in &prepared {
            let one_pass = self.one_pass && !on_rails(&p.rails);
            residuals.push(if one_pass { from_pilots(p) } else { None });
        }
        let rest: Vec<&Prepared> = prepared
            .iter()
            .zip(&residuals)
            .filter(|(_, r)| r.is_none())
            .map(|(p, _)| p)
            .collect();
        let mut passed = self.residual_pass(&rest)?.into_iter();
        let residuals: Vec<Residuals> = residuals
            .into_iter()
            .filter_map(|r| r.or_else(|| passed.next()))
            .collect();
        if residuals.len() != prepared.len() {
            return Err(err(
                rec,
                None,
                CalibrateErrorKind::Internal("residual sums missing"),
            )
            .into());
        }
        for (p, r) in prepared.iter().zip(residuals) {
            let gs = self.group(p.index)?;
            let fit = finish(rec, gs, p, r)?;
            let refit = StreamRefit {
                moments: p.moments.clone(),
                central: PhaseStep::from_hz(fit.rate_hz, CLOCK).unwrap_or(p.nominal),
                fit: ConditionFit::from_fit(&fit.fit),
            };
            if let Some(slot) = fitted.get_mut(p.index) {
                *slot = Some(FittedGroup {
                    fit,
                    refit: Box::new(refit),
                });
            }
        }
        Ok(rotation::assemble(rec, pre, self.opts, &plan, fitted)?)
    }
}

impl Engine<'_> {
    fn group(&self, i: usize) -> Result<&GroupState, CalibrateError> {
        self.groups
            .get(i)
            .ok_or_else(|| err(self.rec, None, CalibrateErrorKind::Internal("group index")))
    }
}
