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

use super::group::{rate_choice, GroupFit, Refit};
use super::pilot::{self, Fitted, Piece, Pilots};
use super::rotation::{self, FittedGroup};
use super::{err, nominal_rate, preflight, CalibrateError, Options, CLOCK};
use crate::calibrate::json::CalibrationJson;
use crate::fit::moments::{self, Moments, WIDE, WIDE_HARMONIC};
use crate::fit::noise::{LaggedSums, NoiseModel, Rails, LAGS};
use crate::recording::{
    self, Group, Method, Parse, PartRow, Parts, Recording, RecordingError, Scanned,
};
use nalgebra::DMatrix;
use rotacal_shared::intrinsic::ConditionFit;
use rotacal_shared::{Aperture, Condition, FitConfig, FitResult, PhaseStep};
use std::f64::consts::TAU;
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
/// [`HOLD_ROWS`] rows from their rows), any other whole, as [`calibrate`] does.
pub fn calibrate_file(path: &Path, opts: &Options) -> Result<CalibrationJson, FileError> {
    calibrate_file_holding(path, opts, HOLD_ROWS)
}

/// [`calibrate_file`], holding groups of at most `hold` rows in memory (0: stream every
/// group; tests compare the two engines with it).
pub fn calibrate_file_holding(
    path: &Path,
    opts: &Options,
    hold: usize,
) -> Result<CalibrationJson, FileError> {
    calibrate_file_passes(path, opts, hold, true)
}

/// [`calibrate_file_holding`] with the residual pass for every streamed group, whatever
/// its pilots allow (`one_pass` false; tests compare the two with it).
pub fn calibrate_file_passes(
    path: &Path,
    opts: &Options,
    hold: usize,
    one_pass: bool,
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
    if parts
        .as_ref()
        .is_some_and(|p| p.method() != Method::Rotation)
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
            };
            let Some(mut rec) = read_pass(path, opts.method, Parse::All, |ev| first.take(ev))?
            else {
                return whole();
            };
            if first.method != Method::Rotation {
                return whole();
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

/// The rows of `parts` over `ranges`, each range on a thread of its own: `each` gives a
/// state per range (from `fresh`) each row with its file line, and the states come back in
/// file order; `None` when a range needs the csv reader (or `each` stopped it).
fn over_parts<T: Send>(
    parts: &Parts,
    ranges: &[(u64, u64)],
    parse: Parse,
    fresh: impl Fn() -> T + Sync,
    each: impl Fn(&mut T, u64, PartRow) -> bool + Sync,
) -> Result<Option<Vec<(T, u64)>>, RecordingError> {
    let results: Vec<Result<Option<(T, u64)>, RecordingError>> = std::thread::scope(|scope| {
        let handles: Vec<_> = ranges
            .iter()
            .map(|range| {
                let (fresh, each) = (&fresh, &each);
                scope.spawn(move || {
                    let mut state = fresh();
                    let lines =
                        parts.rows(*range, parse, |line, row| each(&mut state, line, row))?;
                    Ok(lines.map(|l| (state, l)))
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| {
                h.join().unwrap_or_else(|_| {
                    Err(RecordingError {
                        source_name: String::new(),
                        line: None,
                        kind: recording::RecordingErrorKind::Io(std::io::Error::other(
                            "a reading thread failed",
                        )),
                    })
                })
            })
            .collect()
    });
    let mut out = Vec::with_capacity(results.len());
    for r in results {
        match r? {
            Some(x) => out.push(x),
            None => return Ok(None),
        }
    }
    Ok(Some(out))
}

/// A row's group key: its condition and its `rate_hz` column's bits.
type Key = (Condition, Option<u64>);

fn key_of(row: &PartRow) -> Key {
    (row.condition, row.rate_hz.map(f64::to_bits))
}

/// The index of `key` in `keys`, trying the previous row's group (`last`) first (rows of
/// a group come together) and remembering it.
fn find_group(keys: &[Key], last: &mut Option<usize>, key: Key) -> Option<usize> {
    let i = last
        .filter(|i| keys.get(*i) == Some(&key))
        .or_else(|| keys.iter().position(|k| *k == key))?;
    *last = Some(i);
    Some(i)
}

/// The groups of one range: keyed by (condition, rate bits), in order of first
/// appearance, with their file lines counted from the range's first line.
#[derive(Default)]
struct RangeGroups {
    keys: Vec<Key>,
    groups: Vec<GroupState>,
    last: Option<usize>,
}

/// Pass 1 over the file in parts: every row read and checked as [`recording::scan`]
/// would, the groups of each part joined. `None` when the file needs the sequential
/// reader (a quote, or any problem, which that reader then names).
fn first_pass_parts(
    parts: &Parts,
    ranges: &[(u64, u64)],
    opts: &Options,
    hold: usize,
) -> Result<Option<Vec<GroupState>>, RecordingError> {
    let meta = parts.meta();
    let scale = recording::tick_scale(meta, CLOCK);
    let each = |st: &mut RangeGroups, line: u64, row: PartRow| -> bool {
        let key = key_of(&row);
        let i = match find_group(&st.keys, &mut st.last, key) {
            Some(i) => i,
            None => {
                st.keys.push(key);
                let nominal = nominal_rate(row.rate_hz, opts, meta);
                st.groups
                    .push(GroupState::new(row.condition, row.rate_hz, line, nominal));
                st.keys.len() - 1
            }
        };
        st.last = Some(i);
        let Some(g) = st.groups.get_mut(i) else {
            return false;
        };
        if let (Some(t), Some(l)) = (row.t_s, g.last_t) {
            if t < l {
                return false; // time went backwards: the sequential reader says where
            }
        }
        g.add(row.t_s, row.y, row.conv_gaps, hold, scale);
        true
    };
    let Some(states) = over_parts(parts, ranges, Parse::All, RangeGroups::default, each)? else {
        return Ok(None);
    };
    // Join the ranges: a group's rows go on where the previous range left them.
    let mut keys: Vec<(Condition, Option<u64>)> = Vec::new();
    let mut groups: Vec<GroupState> = Vec::new();
    let mut line_base = parts.header_line();
    for (st, lines) in states {
        for (key, mut g) in st.keys.into_iter().zip(st.groups) {
            g.first_line += line_base;
            if let Some(k) = g.kept.as_mut() {
                k.first_line = g.first_line;
            }
            match keys.iter().position(|k| *k == key) {
                Some(i) => {
                    if !groups
                        .get_mut(i)
                        .is_some_and(|before| before.follow(g, hold))
                    {
                        return Ok(None);
                    }
                }
                None => {
                    keys.push(key);
                    groups.push(g);
                }
            }
        }
        line_base += lines;
    }
    // Every rate needs its three conditions: else the sequential reader says which.
    for (_, rate) in &keys {
        if Condition::ALL.iter().any(|c| !keys.contains(&(*c, *rate))) {
            return Ok(None);
        }
    }
    Ok(Some(groups))
}

/// One pass over the file by the sequential reader (a file the parts reader hands back):
/// the reader on a thread of its own, `each` on this one.
fn read_pass(
    path: &Path,
    method: Option<Method>,
    parse: Parse,
    mut each: impl FnMut(Scanned),
) -> Result<Option<Recording>, RecordingError> {
    let (tx, rx) = std::sync::mpsc::sync_channel::<Vec<Scanned>>(4);
    std::thread::scope(|scope| {
        let reader = scope.spawn(move || {
            let mut block = Vec::with_capacity(BLOCK);
            let out = recording::scan(path, method, parse, |ev| {
                block.push(ev);
                if block.len() >= BLOCK {
                    // A closed channel means the fitting side has stopped: nothing to do.
                    let _ = tx.send(std::mem::replace(&mut block, Vec::with_capacity(BLOCK)));
                }
            });
            if !block.is_empty() {
                let _ = tx.send(block);
            }
            out
        });
        for block in rx {
            for ev in block {
                each(ev);
            }
        }
        reader.join().unwrap_or_else(|_| {
            Err(RecordingError {
                source_name: path.display().to_string(),
                line: None,
                kind: recording::RecordingErrorKind::Io(std::io::Error::other(
                    "the reading thread failed",
                )),
            })
        })
    })
}

/// A group as pass 1 leaves it.
struct GroupState {
    condition: Condition,
    rate_col: Option<f64>,
    first_line: u64,
    /// The nominal rate and its step, once known (`None`: unknown or unusable, reported
    /// when the group is calibrated).
    nominal: Option<(f64, PhaseStep)>,
    /// The first and the last row's time, s.
    t0: Option<f64>,
    last_t: Option<f64>,
    rows: usize,
    /// Clock ticks from the first conversion to the last.
    span_ticks: u64,
    /// The rows, while there are at most `hold` of them.
    kept: Option<Group>,
    moments: Option<Moments>,
    rails: [Rails; 3],
    /// The first problem with a row's time or conversions.
    row_problem: Option<&'static str>,
    /// The pilot of the rows this thread read, and once groups read in parts are joined,
    /// each part's (`pilot`).
    pilots: Pilots,
}

/// Pass 1 on one thread (a file the parts reader hands back): the groups as the
/// sequential reader's events come.
struct PassOne<'a> {
    hold: usize,
    opts: &'a Options,
    /// Clock ticks per device tick (`conv_gaps`).
    scale: f64,
    method: Method,
    meta: Option<Box<recording::Metadata>>,
    groups: Vec<GroupState>,
}

impl PassOne<'_> {
    fn take(&mut self, ev: Scanned) {
        match ev {
            Scanned::Start { meta, method, .. } => {
                // The start of a reading (a second one starts afresh).
                self.groups.clear();
                self.method = self.opts.method.unwrap_or(method);
                self.scale = recording::tick_scale(&meta, CLOCK);
                self.meta = Some(meta);
            }
            Scanned::Group {
                condition,
                rate_hz,
                first_line,
            } => {
                let nominal = match &self.meta {
                    Some(meta) => nominal_rate(rate_hz, self.opts, meta),
                    None => rate_hz.or(self.opts.rate_hz),
                };
                self.groups
                    .push(GroupState::new(condition, rate_hz, first_line, nominal));
            }
            Scanned::Row {
                group,
                t_s,
                y,
                conv_gaps,
                ..
            } => {
                if self.method != Method::Rotation {
                    return;
                }
                let (hold, scale) = (self.hold, self.scale);
                if let Some(g) = self.groups.get_mut(group) {
                    g.add(t_s, y, conv_gaps, hold, scale);
                }
            }
        }
    }
}

impl GroupState {
    /// A new group, at file line `first_line`, of nominal rate `nominal` if known.
    fn new(
        condition: Condition,
        rate_col: Option<f64>,
        first_line: u64,
        nominal: Option<f64>,
    ) -> Self {
        let nominal = nominal.and_then(|r| PhaseStep::from_hz(r, CLOCK).map(|s| (r, s)));
        GroupState {
            condition,
            rate_col,
            first_line,
            nominal,
            t0: None,
            last_t: None,
            rows: 0,
            span_ticks: 0,
            kept: Some(Group {
                condition,
                rate_hz: rate_col,
                t_s: Vec::new(),
                angle_deg: Vec::new(),
                u: Vec::new(),
                v: Vec::new(),
                w: Vec::new(),
                seq: None,
                temp_c: None,
                unc: None,
                conversions: None,
                first_line,
            }),
            moments: nominal.map(|(_, s)| Moments::new(s, CLOCK)),
            rails: [Rails::default(); 3],
            row_problem: None,
            pilots: Pilots::new(true),
        }
    }

    /// Go on with the same group as read by another thread from where this one stopped
    /// (its rows' times from its own first row): false if its rows go back in time.
    fn follow(&mut self, later: GroupState, hold: usize) -> bool {
        let (Some(t0), Some(t1)) = (self.t0, later.t0) else {
            if self.t0.is_none() {
                *self = later;
            }
            return true;
        };
        if self.last_t.is_some_and(|l| t1 < l) {
            return false;
        }
        let shift = ((t1 - t0) * f64::from(CLOCK.hz())).round();
        if !(0.0..1.8e19).contains(&shift) {
            self.row_problem = self.row_problem.or(Some("t_s out of range"));
        }
        let shift = shift.max(0.0) as u64;
        self.kept = match (self.kept.take(), later.kept) {
            (Some(mut a), Some(b)) if self.rows + later.rows <= hold => {
                a.t_s.extend(b.t_s);
                a.u.extend(b.u);
                a.v.extend(b.v);
                a.w.extend(b.w);
                if let Some(c) = b.conversions {
                    a.conversions.get_or_insert_with(Vec::new).extend(c);
                }
                Some(a)
            }
            _ => None,
        };
        if let (Some(a), Some(b)) = (&self.moments, &later.moments) {
            self.pilots.join(a, later.pilots, b, shift);
        }
        self.moments = match (self.moments.take(), later.moments) {
            (Some(a), Some(b)) => Some(a.merged(&b.shifted(shift))),
            (a, _) => a,
        };
        for (a, b) in self.rails.iter_mut().zip(later.rails) {
            *a = a.merged(&b);
        }
        self.span_ticks = self.span_ticks.max(shift.saturating_add(later.span_ticks));
        self.rows += later.rows;
        self.last_t = later.last_t.or(self.last_t);
        self.row_problem = self.row_problem.or(later.row_problem);
        true
    }

    fn add(
        &mut self,
        t_s: Option<f64>,
        y: [f64; 3],
        conv: Option<Aperture>,
        hold: usize,
        scale: f64,
    ) {
        self.rows += 1;
        if let Some(k) = self.kept.as_mut() {
            if self.rows <= hold {
                k.t_s.extend(t_s);
                k.u.push(y[0]);
                k.v.push(y[1]);
                k.w.push(y[2]);
                if let Some(c) = conv {
                    k.conversions.get_or_insert_with(Vec::new).push(c);
                }
            } else {
                self.kept = None;
            }
        }
        if self.row_problem.is_some() {
            return;
        }
        let Some(t) = t_s else {
            return; // no t_s column: reported when the group is calibrated
        };
        let t0 = *self.t0.get_or_insert(t);
        self.last_t = Some(t);
        let ap = match recording::row_aperture(t, t0, conv.as_ref(), scale, CLOCK) {
            Ok(ap) => ap,
            Err(m) => {
                self.row_problem = Some(m);
                return;
            }
        };
        self.span_ticks = self.span_ticks.max(ap.last().0);
        if let Some(m) = self.moments.as_mut() {
            let f = m.add(&ap, y);
            self.pilots.add(ap.first().0, f.as_ref(), y, m);
        }
        for (r, v) in self.rails.iter_mut().zip(y) {
            r.add(v);
        }
    }
}

/// A streamed group's fits before its residual pass.
struct Prepared {
    /// The group's index.
    index: usize,
    nominal_hz: f64,
    nominal: PhaseStep,
    /// The sums the fits come from (about nominal, or about the fitted rate after a
    /// correcting pass).
    moments: Moments,
    rails: [(Option<f64>, Option<f64>); 3],
    four: moments::FourParam,
    fitted: PhaseStep,
    /// The widened fit's coefficients per channel, at the fitted rate.
    beta: [[f64; WIDE]; 3],
    rows: usize,
    /// Clock ticks from the first conversion to the last.
    span_ticks: u64,
    /// Each part's sums and pilot, in file order: from pass 1 (about the nominal rate), and
    /// from the correcting pass if it ran (about the rate pass 1 fitted).
    pieces: Vec<Piece>,
    pieces_fitted: Vec<Piece>,
}

struct Engine<'a> {
    path: &'a Path,
    rec: &'a Recording,
    opts: &'a Options,
    groups: Vec<GroupState>,
    /// The file in parts, when pass 1 read it so.
    parts: Option<(Parts, Vec<(u64, u64)>)>,
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
                "internal: the streaming engine is for rotation files",
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
                        *slot = Some(rotation::held(rec, &kept, rate.nominal_hz)?);
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
            return Err(err(rec, None, "internal: residual sums missing").into());
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
        Ok(rotation::assemble(
            rec,
            pre,
            self.opts.monte_carlo,
            &plan,
            fitted,
        )?)
    }

    fn group(&self, i: usize) -> Result<&GroupState, CalibrateError> {
        self.groups
            .get(i)
            .ok_or_else(|| err(self.rec, None, "internal: group index"))
    }

    /// A pass over the file handing the rows of the groups in `wanted` (with their
    /// aperture) to `each`, after `fresh` makes the state they go into; in parts, one per
    /// core, whose states `join` puts together in file order, when pass 1 read the file
    /// so. Checks that each group has as many rows as in pass 1. Returns the state.
    fn pass<T: Send>(
        &self,
        wanted: &[usize],
        fresh: impl Fn() -> T + Sync,
        each: impl Fn(&mut T, usize, &Aperture, [f64; 3]) + Sync,
        join: impl Fn(T, T) -> T,
    ) -> Result<T, FileError> {
        let scale = recording::tick_scale(&self.rec.meta, CLOCK);
        let keys: Vec<Key> = self
            .groups
            .iter()
            .map(|g| (g.condition, g.rate_col.map(f64::to_bits)))
            .collect();
        let t0: Vec<f64> = self.groups.iter().map(|g| g.t0.unwrap_or(0.0)).collect();
        let n = self.groups.len();
        // A row of group `gi`: counted, and handed on with its conversions if wanted.
        let feed = |state: &mut T,
                    rows: &mut [usize],
                    gi: usize,
                    t_s: Option<f64>,
                    y: [f64; 3],
                    gaps: Option<&Aperture>| {
            if let Some(r) = rows.get_mut(gi) {
                *r += 1;
            }
            if let (true, Some(t), Some(t0)) = (wanted.contains(&gi), t_s, t0.get(gi)) {
                if let Ok(ap) = recording::row_aperture(t, *t0, gaps, scale, CLOCK) {
                    each(state, gi, &ap, y);
                }
            }
        };
        let check = |rows: &[usize]| -> Result<(), FileError> {
            for &i in wanted {
                if rows.get(i) != self.groups.get(i).map(|g| g.rows).as_ref() {
                    return Err(err(self.rec, None, "the file changed while it was read").into());
                }
            }
            Ok(())
        };
        if let Some((parts, ranges)) = &self.parts {
            let fresh_part = || (fresh(), vec![0usize; n], None::<usize>);
            let each_row = |(state, rows, last): &mut (T, Vec<usize>, Option<usize>),
                            _line: u64,
                            row: PartRow| {
                let Some(gi) = find_group(&keys, last, key_of(&row)) else {
                    return false;
                };
                feed(state, rows, gi, row.t_s, row.y, row.conv_gaps.as_ref());
                true
            };
            if let Some(states) = over_parts(parts, ranges, Parse::Fit, fresh_part, each_row)? {
                let mut total = vec![0usize; n];
                let mut joined: Option<T> = None;
                for ((state, rows, _), _) in states {
                    for (a, b) in total.iter_mut().zip(rows) {
                        *a += b;
                    }
                    joined = Some(match joined {
                        Some(j) => join(j, state),
                        None => state,
                    });
                }
                check(&total)?;
                return Ok(joined.unwrap_or_else(fresh));
            }
        }
        let mut rows: Vec<usize> = vec![0; n];
        let mut state = fresh();
        read_pass(self.path, self.opts.method, Parse::Fit, |ev| match ev {
            Scanned::Start { .. } => {
                // A second reading of the file (by the csv reader) starts afresh.
                rows.iter_mut().for_each(|r| *r = 0);
                state = fresh();
            }
            Scanned::Row {
                group,
                t_s,
                y,
                conv_gaps,
                ..
            } => feed(&mut state, &mut rows, group, t_s, y, conv_gaps.as_ref()),
            Scanned::Group { .. } => {}
        })?;
        check(&rows)?;
        Ok(state)
    }

    /// Gather the sums again about each group's fitted rate, its readings on rails
    /// apart, and refit. A group without rails also gets its parts' pilots about that
    /// rate (`pilot`), which may then stand in for the residual pass.
    fn correcting_pass(&self, prepared: &mut [Prepared], which: &[usize]) -> Result<(), FileError> {
        let wanted: Vec<usize> = which
            .iter()
            .filter_map(|k| prepared.get(*k).map(|p| p.index))
            .collect();
        let rails: Vec<[(Option<f64>, Option<f64>); 3]> = which
            .iter()
            .filter_map(|k| prepared.get(*k).map(|p| p.rails))
            .collect();
        let fresh = || -> Vec<Correcting> {
            which
                .iter()
                .filter_map(|k| prepared.get(*k))
                .map(|p| {
                    let m = Moments::new(p.fitted, CLOCK);
                    Correcting {
                        all: m.clone(),
                        flagged: [m.clone(), m.clone(), m],
                        pilots: Pilots::new(self.one_pass && !on_rails(&p.rails)),
                    }
                })
                .collect()
        };
        let each = |sums: &mut Vec<Correcting>, group: usize, ap: &Aperture, y: [f64; 3]| {
            let Some(k) = wanted.iter().position(|g| *g == group) else {
                return;
            };
            if let (Some(c), Some(r)) = (sums.get_mut(k), rails.get(k)) {
                let f = c.all.add(ap, y);
                c.pilots.add(ap.first().0, f.as_ref(), y, &c.all);
                for ((f, r), v) in c.flagged.iter_mut().zip(r).zip(y) {
                    if Rails::flags(*r, v) {
                        f.add(ap, y);
                    }
                }
            }
        };
        // The parts share the group's origin: their sums add, and each keeps its pilot.
        let join = |a: Vec<Correcting>, b: Vec<Correcting>| {
            a.into_iter()
                .zip(b)
                .map(|(mut a, b)| {
                    a.pilots.join(&a.all, b.pilots, &b.all, 0);
                    let [a0, a1, a2] = a.flagged;
                    let [b0, b1, b2] = b.flagged;
                    Correcting {
                        all: a.all.merged(&b.all),
                        flagged: [a0.merged(&b0), a1.merged(&b1), a2.merged(&b2)],
                        pilots: a.pilots,
                    }
                })
                .collect()
        };
        let sums = self.pass(&wanted, fresh, each, join)?;
        for (k, c) in which.iter().zip(sums) {
            let Some(p) = prepared.get_mut(*k) else {
                continue;
            };
            let Correcting {
                all,
                flagged,
                pilots,
            } = c;
            p.pieces_fitted = pilots.into_pieces(&all);
            let all = all.dense();
            let gs = self.group(p.index)?;
            let fail = |e: String| {
                err(
                    self.rec,
                    Some(gs.first_line),
                    format!("condition {}: {e}", gs.condition.letter()),
                )
            };
            // (`all` is gathered about p.fitted: it reaches it by construction.)
            if !p.moments.within(p.fitted, REACH_FIT) {
                // The first expansion could not reach the rate: fit again from here.
                p.four = moments::four_param(&all, p.fitted, CLOCK)
                    .map_err(|e| fail(format!("rate fit: {e}")))?;
                p.fitted = PhaseStep::from_hz(p.four.rate_hz, CLOCK)
                    .ok_or_else(|| fail("fitted rate unusable".into()))?;
                if !all.within(p.fitted, REACH_FIT) {
                    return Err(fail(format!(
                        "the rate fit moved {:.2e} rad over the record after a correcting pass: \
                         the rate is not steady enough to fit",
                        all.reach(p.fitted)
                    ))
                    .into());
                }
            }
            let flagged = flagged.map(|f| (f.rows() > 0).then_some(f));
            p.moments = all;
            p.beta = moments::wide_betas(&p.moments, &flagged, p.fitted).map_err(fail)?;
        }
        Ok(())
    }

    /// The residuals of each group's widened fit at its fitted rate, into lagged sums per
    /// channel, and the residual sums of squares of its sine fits at the fitted and the
    /// nominal rate.
    fn residual_pass(&self, prepared: &[&Prepared]) -> Result<Vec<Residuals>, FileError> {
        if prepared.is_empty() {
            return Ok(Vec::new());
        }
        let wanted: Vec<usize> = prepared.iter().map(|p| p.index).collect();
        // Each group's sine coefficients at the fitted and the nominal rate, and the
        // shift between the two (rad/s).
        let mut sines = Vec::with_capacity(prepared.len());
        for p in prepared {
            sines.push(sine_pair(p).map_err(|e| err(self.rec, None, e))?);
        }
        let fresh = || -> Vec<Residuals> {
            prepared
                .iter()
                .map(|_| Residuals {
                    lagged: Default::default(),
                    rss_fitted: [0.0; 3],
                    rss_nominal: [0.0; 3],
                })
                .collect()
        };
        let each = |out: &mut Vec<Residuals>, group: usize, ap: &Aperture, y: [f64; 3]| {
            let Some(k) = wanted.iter().position(|g| *g == group) else {
                return;
            };
            let (Some(p), Some(r), Some((bf, bn, shift))) =
                (prepared.get(k), out.get_mut(k), sines.get(k))
            else {
                return;
            };
            let (v, at_nominal) =
                moments::wide_regressors(ap, p.fitted, (p.nominal, *shift), CLOCK);
            let n = ap.len().max(1) as f64;
            // An average of n conversions has variance σ²/n (one: no square root).
            let w = if ap.len() > 1 { n.sqrt() } else { 1.0 };
            for ch in 0..3 {
                let (Some(acc), Some(yv), Some(beta), Some(rails), Some(f), Some(nm)) = (
                    r.lagged.get_mut(ch),
                    y.get(ch),
                    p.beta.get(ch),
                    p.rails.get(ch),
                    bf.get(ch),
                    bn.get(ch),
                ) else {
                    continue;
                };
                let fitted: f64 = v.iter().zip(beta).map(|(a, b)| a * b).sum();
                acc.add(w * (yv - fitted), Rails::flags(*rails, *yv));
                let ef = yv - (f[0] * v[0] + f[1] * v[1] + f[2]);
                let en = yv - (nm[0] * at_nominal[0] + nm[1] * at_nominal[1] + nm[2]);
                if let (Some(a), Some(b)) = (r.rss_fitted.get_mut(ch), r.rss_nominal.get_mut(ch)) {
                    *a += n * ef * ef;
                    *b += n * en * en;
                }
            }
        };
        let join = |a: Vec<Residuals>, b: Vec<Residuals>| {
            a.into_iter()
                .zip(b)
                .map(|(a, b)| Residuals {
                    lagged: [0, 1, 2].map(|ch| a.lagged[ch].followed_by(&b.lagged[ch])),
                    rss_fitted: [0, 1, 2].map(|ch| a.rss_fitted[ch] + b.rss_fitted[ch]),
                    rss_nominal: [0, 1, 2].map(|ch| a.rss_nominal[ch] + b.rss_nominal[ch]),
                })
                .collect()
        };
        self.pass(&wanted, fresh, each, join)
    }
}

/// A, B, C per channel.
type SineCoefficients = [[f64; 3]; 3];

/// A group's sine coefficients at the fitted and the nominal rate, and the fitted rate
/// less the nominal (rad/s).
fn sine_pair(p: &Prepared) -> Result<(SineCoefficients, SineCoefficients, f64), String> {
    let at_fitted = moments::sine_coefficients(&p.moments, p.fitted).map_err(|e| e.to_string())?;
    let at_nominal =
        moments::sine_coefficients(&p.moments, p.nominal).map_err(|e| e.to_string())?;
    Ok((
        at_fitted,
        at_nominal,
        moments::eps_between(p.fitted, p.nominal, CLOCK),
    ))
}

/// A group's residual sums from its parts' pilots (`pilot`), without a residual pass:
/// `None` when a part has no pilot, or the corrections' error bound is not below
/// [`pilot::KAPPA`] of the sums' own scatter.
fn from_pilots(p: &Prepared) -> Option<Residuals> {
    let (sine_fitted, sine_nominal, eps) = sine_pair(p).ok()?;
    let fit = Fitted {
        nominal: p.nominal,
        fitted: p.fitted,
        eps,
        wide: &p.beta,
        sine_fitted: &sine_fitted,
        sine_nominal: &sine_nominal,
    };
    let corrected = |pieces: &[Piece]| -> Option<Vec<pilot::PieceSums>> {
        pieces.iter().map(|pc| pilot::corrected(pc, &fit)).collect()
    };
    // The lagged sums and the fitted rate's RSS from the pilots about the rate the sums
    // were last gathered about; the nominal rate's RSS from pass 1's, about nominal.
    let at_nominal = corrected(&p.pieces)?;
    let sums = if p.pieces_fitted.is_empty() {
        None
    } else {
        Some(corrected(&p.pieces_fitted)?)
    };
    let sums = sums.as_ref().unwrap_or(&at_nominal);
    let mut out = Residuals {
        lagged: Default::default(),
        rss_fitted: [0.0; 3],
        rss_nominal: [0.0; 3],
    };
    let rows = p.rows.max(1) as f64;
    for ch in 0..3 {
        // Joined in file order, and the bounds summed over the parts: the fitted rate's
        // RSS from `sums`, the nominal rate's from `at_nominal`.
        let (mut joined, mut bound) = (None::<LaggedSums>, [0.0; LAGS]);
        let (mut rss, mut rss_bound) = ([0.0; 2], [0.0; 2]);
        for c in sums.iter().filter_map(|s| s.get(ch)) {
            joined = Some(match joined {
                Some(j) => j.followed_by(&c.lagged),
                None => c.lagged.clone(),
            });
            for (a, x) in bound.iter_mut().zip(c.bound) {
                *a += x;
            }
            rss[0] += c.rss[0];
            rss_bound[0] += c.rss_bound[0];
        }
        for c in at_nominal.iter().filter_map(|s| s.get(ch)) {
            rss[1] += c.rss[1];
            rss_bound[1] += c.rss_bound[1];
        }
        let joined = joined?;
        // The lagged sums' own standard error is about γ₀·√N, the RSS's RSS·√(2/N).
        let (prod, _) = joined.products();
        let own = prod.first().copied().unwrap_or(0.0) / rows.sqrt();
        let within = bound.iter().all(|b| *b <= pilot::KAPPA * own)
            && rss_bound
                .iter()
                .zip(rss)
                .all(|(b, r)| *b <= pilot::KAPPA * r * (2.0 / rows).sqrt());
        if !within || !own.is_finite() {
            return None;
        }
        if let (Some(l), Some(f), Some(n)) = (
            out.lagged.get_mut(ch),
            out.rss_fitted.get_mut(ch),
            out.rss_nominal.get_mut(ch),
        ) {
            (*l, *f, *n) = (joined, rss[0], rss[1]);
        }
    }
    Some(out)
}

/// A group's sums in the correcting pass, on one thread: all its rows', each channel's
/// readings on rails, and its pilots.
struct Correcting {
    all: Moments,
    flagged: [Moments; 3],
    pilots: Pilots,
}

/// Whether a channel of a group has readings on a rail.
fn on_rails(rails: &[(Option<f64>, Option<f64>); 3]) -> bool {
    rails.iter().any(|r| r.0.is_some() || r.1.is_some())
}

/// What the residual pass gives for a group.
struct Residuals {
    /// Per channel, the widened fit's residuals' lagged sums.
    lagged: [LaggedSums; 3],
    /// Per channel, Σ n·(y − ŷ)² of the sine fit at the fitted and at the nominal rate.
    rss_fitted: [f64; 3],
    rss_nominal: [f64; 3],
}

/// A streamed group's fit, from its sums and its residuals: the noise model, the rate
/// the fit uses, the sine fit and its covariance, as [`super::fit_group`] makes them.
fn finish(
    rec: &Recording,
    gs: &GroupState,
    p: &Prepared,
    r: Residuals,
) -> Result<GroupFit, CalibrateError> {
    let fail = |e: String| {
        err(
            rec,
            Some(gs.first_line),
            format!("condition {}: {e}", gs.condition.letter()),
        )
    };
    let span_s = p.span_ticks as f64 / f64::from(CLOCK.hz());
    let omega = TAU * p.four.rate_hz * span_s / (p.rows.max(2) - 1) as f64;
    let freqs: Vec<f64> = WIDE_HARMONIC
        .iter()
        .map(|k| f64::from(*k) * omega)
        .collect();
    let mut noise = Vec::with_capacity(3);
    for acc in &r.lagged {
        let (n, used) = acc.counts();
        let m = NoiseModel::from_autocovariances(&acc.autocovariances(), n, used)
            .and_then(|m| m.rescaled_for_sinusoids(n, &freqs))
            .map_err(|e| fail(e.to_string()))?;
        noise.push(m);
    }
    let Ok(noise) = <[NoiseModel; 3]>::try_from(noise) else {
        return Err(fail("three channels expected".into()));
    };
    let (se_rate, differs) = rate_choice(
        (p.four.rate_hz, p.four.se_rate_hz),
        &p.four.coef,
        &noise,
        omega,
        p.nominal_hz,
    );
    let (step, rate_hz, rate_fitted, u_rate_hz, rss) = if differs {
        (
            p.fitted,
            p.four.rate_hz,
            Some(p.four.rate_hz),
            se_rate,
            r.rss_fitted,
        )
    } else {
        let u = se_rate.hypot(p.four.rate_hz - p.nominal_hz);
        (p.nominal, p.nominal_hz, None, u, r.rss_nominal)
    };
    let normal = p.moments.sine_at(step);
    let fit = sine_result(&normal, rss, p).map_err(fail)?;
    let gram = DMatrix::from_iterator(3, 3, normal.g.iter().copied());
    let mut cov = [[[0.0; 3]; 3]; 3];
    for (c, m) in cov.iter_mut().zip(&noise) {
        let s = m
            .sandwich_for_sinusoids(&gram, &[omega, omega, 0.0])
            .map_err(|e| fail(e.to_string()))?;
        for (a, row) in c.iter_mut().enumerate() {
            for (b, x) in row.iter_mut().enumerate() {
                *x = s[(a, b)];
            }
        }
    }
    Ok(GroupFit {
        condition: gs.condition,
        fit,
        rate_hz,
        rate_fitted,
        u_rate_hz,
        cov,
        noise,
        omega_per_sample: omega,
    })
}

/// The sine fit as the streaming fit reports it ([`rotacal_shared::SineFit::solve`]),
/// from the sums' normal equations at its rate and the residual sums of squares the
/// residual pass measured.
fn sine_result(
    normal: &moments::SineNormal,
    rss: [f64; 3],
    p: &Prepared,
) -> Result<FitResult<f64>, String> {
    let singular = || "singular fit: the samples do not determine every parameter".to_string();
    let chol = normal.g.cholesky().ok_or_else(singular)?;
    let inv = chol.inverse();
    let n = u32::try_from(p.rows).map_err(|_| "too many rows for one fit".to_string())?;
    let mut unscaled_cov = [[0.0; rotacal_shared::MAX_PARAMS]; rotacal_shared::MAX_PARAMS];
    for (i, row) in unscaled_cov.iter_mut().enumerate().take(3) {
        for (j, x) in row.iter_mut().enumerate().take(3) {
            *x = inv[(i, j)];
        }
    }
    let mut channels = [rotacal_shared::ChannelFit::<f64> {
        coef: [rotacal_shared::DoubleWord { hi: 0.0, lo: 0.0 }; rotacal_shared::MAX_PARAMS],
        se: [0.0; rotacal_shared::MAX_PARAMS],
        rss: 0.0,
        sigma: 0.0,
        rms_residual: 0.0,
    }; 3];
    for (ch, (out, rss)) in channels.iter_mut().zip(rss).enumerate() {
        let b = chol.solve(&normal.xh.column(ch).into_owned());
        let var = rss / f64::from(n.saturating_sub(3).max(1));
        for i in 0..3 {
            if let (Some(c), Some(se)) = (out.coef.get_mut(i), out.se.get_mut(i)) {
                *c = rotacal_shared::DoubleWord { hi: b[i], lo: 0.0 };
                *se = (var * inv[(i, i)].max(0.0)).sqrt();
            }
        }
        out.rss = rss;
        out.sigma = var.sqrt();
        out.rms_residual = (rss / f64::from(n.max(1))).sqrt();
    }
    Ok(FitResult {
        model: rotacal_shared::Model::SINE,
        n,
        t_first: rotacal_shared::Ticks(0),
        t_last: rotacal_shared::Ticks(p.span_ticks),
        t_ref: None,
        unscaled_cov,
        channels,
    })
}

/// A streamed group's fits from its pass-1 sums.
fn prepare(
    rec: &Recording,
    index: usize,
    gs: &mut GroupState,
    nominal_hz: f64,
) -> Result<Prepared, CalibrateError> {
    let line = Some(gs.first_line);
    let fail = |e: String| {
        err(
            rec,
            line,
            format!("condition {}: {e}", gs.condition.letter()),
        )
    };
    if gs.t0.is_none() {
        return Err(err(rec, line, "rotation needs a t_s column"));
    }
    if let Some(m) = gs.row_problem {
        return Err(err(rec, line, m));
    }
    let (Some((_, nominal)), Some(moments)) = (gs.nominal, gs.moments.take()) else {
        return Err(err(
            rec,
            line,
            format!("rotation rate {nominal_hz} Hz is not usable"),
        ));
    };
    // Each part's sums and pilot (a group one thread read whole: its own).
    let pieces = std::mem::take(&mut gs.pilots).into_pieces(&moments);
    // Folded once: every fit below reads the dense sums.
    let moments = moments.dense();
    // As the streaming fit checks its record (method.md §5).
    let cfg = FitConfig::sine(nominal, CLOCK);
    let span = gs.span_ticks;
    let milli = (nominal.turns_x2_64(span).saturating_mul(1000) >> 64) as u64;
    if milli < u64::from(cfg.min_milli_periods) {
        let e = rotacal_shared::FitError::TooFewPeriods {
            milli_periods: milli,
            needed: cfg.min_milli_periods,
        };
        return Err(fail(e.to_string()));
    }
    let four = moments::four_param(&moments, nominal, CLOCK)
        .map_err(|e| fail(format!("rate fit: {e}")))?;
    let fitted = PhaseStep::from_hz(four.rate_hz, CLOCK)
        .ok_or_else(|| err(rec, line, "fitted rate unusable"))?;
    let rails = gs.rails.map(|r| r.found());
    // The widened fit's coefficients, if the sums reach the fitted rate (else the
    // correcting pass computes them, as it does with rails).
    let beta = if moments.within(fitted, REACH_FIT) {
        moments::wide_betas(&moments, &[None, None, None], fitted).map_err(fail)?
    } else {
        [[0.0; WIDE]; 3]
    };
    Ok(Prepared {
        index,
        nominal_hz,
        nominal,
        moments,
        rails,
        four,
        fitted,
        beta,
        rows: gs.rows,
        span_ticks: gs.span_ticks,
        pieces,
        pieces_fitted: Vec::new(),
    })
}

/// A streamed condition's sine refitted at a nearby rate: the fit's own (A, B) moved by
/// the change the sums give between its rate (`central`) and the new one.
struct StreamRefit {
    moments: Moments,
    central: PhaseStep,
    fit: ConditionFit,
}

impl Refit for StreamRefit {
    fn refit(&self, rate_hz: f64) -> Result<ConditionFit, String> {
        let step = PhaseStep::from_hz(rate_hz, CLOCK)
            .ok_or_else(|| format!("rate {rate_hz} Hz unusable"))?;
        if !self.moments.within(step, REACH_REFIT) {
            return Err(format!(
                "the refit at {rate_hz} Hz is {:.2e} rad over the record from the streamed sums' \
                 rate, beyond their reach ({REACH_REFIT})",
                self.moments.reach(step)
            ));
        }
        let (at, here) = (
            moments::sine_coefficients(&self.moments, step).map_err(|e| e.to_string())?,
            moments::sine_coefficients(&self.moments, self.central).map_err(|e| e.to_string())?,
        );
        let mut out = self.fit;
        for ch in 0..3 {
            if let (Some(a), Some(b), Some(x), Some(h)) = (
                out.a.get_mut(ch),
                out.b.get_mut(ch),
                at.get(ch),
                here.get(ch),
            ) {
                *a += x[0] - h[0];
                *b += x[1] - h[1];
            }
        }
        Ok(out)
    }
}
