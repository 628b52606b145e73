//! Pass 1: every row read and checked, in two parts on two threads or by the csv reader
//! on one; each group held (at most the hold limit of rows) or summed.

use super::BLOCK;
use crate::calibrate::pilot::{self, Pilots};
use crate::calibrate::{nominal_rate, Options, CLOCK};
use crate::fit::block::Block;
use crate::fit::moments::Moments;
use crate::fit::noise::Rails;
use crate::recording::{
    self, Group, Method, Parse, PartRow, Parts, Recording, RecordingError, Scanned, Stretch,
};
use rotacal_shared::{Aperture, Condition, PhaseStep};
use std::path::Path;

/// The rows of `parts` over `ranges`, each range on a thread of its own: `each` gives a
/// state per range (from `fresh`) each row with its file line, `each_stretch` a stretch of
/// one group's rows held as columns ([`Parts::stretches`]), and the states come back in
/// file order; `None` when a range needs the csv reader (or `each` stopped it).
pub(super) fn over_parts<T: Send>(
    parts: &Parts,
    ranges: &[(u64, u64)],
    parse: Parse,
    fresh: impl Fn() -> T + Sync,
    each: impl Fn(&mut T, u64, PartRow) -> bool + Sync,
    each_stretch: impl Fn(&mut T, u64, Stretch<'_>) -> bool + Sync,
) -> Result<Option<Vec<(T, u64)>>, RecordingError> {
    let results: Vec<Result<Option<(T, u64)>, RecordingError>> = std::thread::scope(|scope| {
        let handles: Vec<_> = ranges
            .iter()
            .map(|range| {
                let (fresh, each, each_stretch) = (&fresh, &each, &each_stretch);
                scope.spawn(move || {
                    let state = std::cell::RefCell::new(fresh());
                    let lines = parts.stretches(
                        *range,
                        parse,
                        |line, row| each(&mut state.borrow_mut(), line, row),
                        |line, st| each_stretch(&mut state.borrow_mut(), line, st),
                    )?;
                    Ok(lines.map(|l| (state.into_inner(), l)))
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
                        row: None,
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
pub(super) type Key = (Condition, Option<u64>);

pub(super) fn key_of(row: &PartRow) -> Key {
    (row.condition, row.rate_hz.map(f64::to_bits))
}

/// The index of `key` in `keys`, trying the previous row's group (`last`) first (rows of
/// a group come together) and remembering it.
pub(super) fn find_group(keys: &[Key], last: &mut Option<usize>, key: Key) -> Option<usize> {
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
pub(super) fn first_pass_parts(
    parts: &Parts,
    ranges: &[(u64, u64)],
    opts: &Options,
    hold: usize,
) -> Result<Option<Vec<GroupState>>, RecordingError> {
    let meta = parts.meta();
    let scale = recording::tick_scale(meta, CLOCK);
    let group = |st: &mut RangeGroups, condition, rate_hz: Option<f64>, line| {
        let key = (condition, rate_hz.map(f64::to_bits));
        let i = match find_group(&st.keys, &mut st.last, key) {
            Some(i) => i,
            None => {
                st.keys.push(key);
                let nominal = nominal_rate(rate_hz, opts, meta);
                st.groups
                    .push(GroupState::new(condition, rate_hz, line, nominal));
                st.keys.len() - 1
            }
        };
        st.last = Some(i);
        i
    };
    let each = |st: &mut RangeGroups, line: u64, row: PartRow| -> bool {
        let i = group(st, row.condition, row.rate_hz, line);
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
    let each_stretch = |st: &mut RangeGroups, line: u64, run: Stretch| -> bool {
        let i = group(st, run.condition, run.rate_hz, line);
        let Some(g) = st.groups.get_mut(i) else {
            return false;
        };
        if let Some(t) = run.t_s {
            // Time may not go backwards (the sequential reader says where).
            let before = g.last_t.zip(t.first()).is_some_and(|(l, f)| *f < l);
            if before || t.iter().zip(t.iter().skip(1)).any(|(a, b)| b < a) {
                return false;
            }
        }
        g.add_stretch(run.t_s, run.y, hold, scale);
        true
    };
    let Some(states) = over_parts(
        parts,
        ranges,
        Parse::All,
        RangeGroups::default,
        each,
        each_stretch,
    )?
    else {
        return Ok(None);
    };
    // Join the ranges: a group's rows go on where the previous range left them.
    let mut keys: Vec<(Condition, Option<u64>)> = Vec::new();
    let mut groups: Vec<GroupState> = Vec::new();
    let mut line_base = parts.header_line();
    for (st, lines) in states {
        for (key, mut g) in st.keys.into_iter().zip(st.groups) {
            g.settle();
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
pub(super) fn read_pass(
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
                row: None,
                kind: recording::RecordingErrorKind::Io(std::io::Error::other(
                    "the reading thread failed",
                )),
            })
        })
    })
}

/// A group as pass 1 leaves it.
pub(super) struct GroupState {
    pub(super) condition: Condition,
    pub(super) rate_col: Option<f64>,
    pub(super) first_line: u64,
    /// The nominal rate and its step, once known (`None`: unknown or unusable, reported
    /// when the group is calibrated).
    pub(super) nominal: Option<(f64, PhaseStep)>,
    /// The first and the last row's time, s.
    pub(super) t0: Option<f64>,
    pub(super) last_t: Option<f64>,
    pub(super) rows: usize,
    /// Clock ticks from the first conversion to the last.
    pub(super) span_ticks: u64,
    /// The rows, while there are at most `hold` of them.
    pub(super) kept: Option<Group>,
    pub(super) moments: Option<Moments>,
    pub(super) rails: [Rails; 3],
    /// The first problem with a row's time or conversions.
    pub(super) row_problem: Option<&'static str>,
    /// The pilot of the rows this thread read, and once groups read in parts are joined,
    /// each part's (`pilot`).
    pub(super) pilots: Pilots,
    /// Rows of one conversion waiting to be summed a block at a time ([`Self::settle`]).
    block: Box<Block>,
}

/// Pass 1 on one thread (a file the parts reader hands back): the groups as the
/// sequential reader's events come.
pub(super) struct PassOne<'a> {
    pub(super) hold: usize,
    pub(super) opts: &'a Options,
    /// Clock ticks per device tick (`conv_gaps`).
    pub(super) scale: f64,
    pub(super) method: Method,
    pub(super) meta: Option<Box<recording::Metadata>>,
    pub(super) groups: Vec<GroupState>,
    /// The file has a `boot` column.
    pub(super) segmented: bool,
}

impl PassOne<'_> {
    pub(super) fn take(&mut self, ev: Scanned) {
        match ev {
            Scanned::Start {
                meta,
                method,
                columns,
            } => {
                // The start of a reading (a second one starts afresh).
                self.groups.clear();
                self.segmented = columns.boot;
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
                missed: None,
                boot: None,
                first_line,
            }),
            moments: nominal.map(|(_, s)| Moments::new(s, CLOCK)),
            rails: [Rails::default(); 3],
            row_problem: None,
            pilots: Pilots::new(true),
            block: Box::default(),
        }
    }

    /// The rows waiting to be summed, summed: before the sums are read or joined.
    pub(super) fn settle(&mut self) {
        if let Some(m) = self.moments.as_mut() {
            pilot::settle(m, &mut self.pilots, &mut self.block);
        }
    }

    /// Go on with the same group as read by another thread from where this one stopped
    /// (its rows' times from its own first row): false if its rows go back in time.
    fn follow(&mut self, mut later: GroupState, hold: usize) -> bool {
        self.settle();
        later.settle();
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

    /// [`GroupState::add`] of each row of a stretch of rows of one conversion each (times
    /// `t_s` if the recording has them, readings `y`): the same, a row at a time, without a
    /// call per row.
    fn add_stretch(&mut self, t_s: Option<&[f64]>, y: [&[f64]; 3], hold: usize, scale: f64) {
        let [u, v, w] = y;
        let n = u.len();
        if let Some(k) = self.kept.as_mut() {
            if self.rows + n <= hold {
                k.t_s.extend_from_slice(t_s.unwrap_or(&[]));
                k.u.extend_from_slice(u);
                k.v.extend_from_slice(v);
                k.w.extend_from_slice(w);
            } else {
                self.kept = None;
            }
        }
        self.rows += n;
        let Some(t_s) = t_s else {
            return; // no t_s column: reported when the group is calibrated
        };
        for (((t, u), v), w) in t_s.iter().zip(u).zip(v).zip(w) {
            if self.row_problem.is_some() {
                return;
            }
            self.add_timed(*t, [*u, *v, *w], None, scale);
        }
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
        self.add_timed(t, y, conv.as_ref(), scale);
    }

    /// A row with a time `t` s (and its conversions `conv`, if the file has them) into
    /// the sums and the rails, no problem having been met before it.
    #[inline]
    fn add_timed(&mut self, t: f64, y: [f64; 3], conv: Option<&Aperture>, scale: f64) {
        let t0 = *self.t0.get_or_insert(t);
        self.last_t = Some(t);
        let ap = match recording::row_aperture(t, t0, conv, scale, CLOCK) {
            Ok(ap) => ap,
            Err(m) => {
                self.row_problem = Some(m);
                return;
            }
        };
        self.span_ticks = self.span_ticks.max(ap.last().0);
        if let Some(m) = self.moments.as_mut() {
            pilot::feed(m, &mut self.pilots, &mut self.block, &ap, y);
        }
        for (r, v) in self.rails.iter_mut().zip(y) {
            r.add(v);
        }
    }
}
