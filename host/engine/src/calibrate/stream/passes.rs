//! The passes after the first: a correcting pass about the fitted rate when the data
//! demand it, and the residual pass for the groups whose pilots cannot stand in for it.

use super::first::{find_group, key_of, over_parts, read_pass, Key};
use super::fits::{on_rails, sine_pair, Prepared, Residuals};
use super::{Engine, FileError, REACH_FIT};
use crate::calibrate::pilot::{self, Pilots};
use crate::calibrate::{err, CalibrateErrorKind, GroupError, CLOCK};
use crate::fit::block::Block;
use crate::fit::moments::{self, Moments};
use crate::fit::noise::Rails;
use crate::recording::{self, Parse, PartRow, Scanned, Stretch};
use rotacal_shared::{Aperture, Channel, PhaseStep};

impl Engine<'_> {
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
                    return Err(err(self.rec, None, CalibrateErrorKind::FileChanged).into());
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
            let each_stretch =
                |state: &mut (T, Vec<usize>, Option<usize>), line: u64, st: Stretch| {
                    st.rows()
                        .zip(line..)
                        .all(|(row, line)| each_row(state, line, row))
                };
            if let Some(states) = over_parts(
                parts,
                ranges,
                Parse::Fit,
                fresh_part,
                each_row,
                each_stretch,
            )? {
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
            if parts.in_memory() {
                // Columns were checked whole when opened: there is no file to read again.
                return Err(err(
                    self.rec,
                    None,
                    CalibrateErrorKind::Internal("a row of the columns failed in a later pass"),
                )
                .into());
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
    pub(super) fn correcting_pass(
        &self,
        prepared: &mut [Prepared],
        which: &[usize],
    ) -> Result<(), FileError> {
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
                        block: Box::default(),
                    }
                })
                .collect()
        };
        let each = |sums: &mut Vec<Correcting>, group: usize, ap: &Aperture, y: [f64; 3]| {
            let Some(k) = wanted.iter().position(|g| *g == group) else {
                return;
            };
            if let (Some(c), Some(r)) = (sums.get_mut(k), rails.get(k)) {
                pilot::feed(&mut c.all, &mut c.pilots, &mut c.block, ap, y);
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
                .map(|(mut a, mut b)| {
                    a.settle();
                    b.settle();
                    a.pilots.join(&a.all, b.pilots, &b.all, 0);
                    let [a0, a1, a2] = a.flagged;
                    let [b0, b1, b2] = b.flagged;
                    Correcting {
                        all: a.all.merged(&b.all),
                        flagged: [a0.merged(&b0), a1.merged(&b1), a2.merged(&b2)],
                        pilots: a.pilots,
                        block: a.block,
                    }
                })
                .collect()
        };
        let sums = self.pass(&wanted, fresh, each, join)?;
        for (k, mut c) in which.iter().zip(sums) {
            let Some(p) = prepared.get_mut(*k) else {
                continue;
            };
            c.settle();
            let Correcting {
                all,
                flagged,
                pilots,
                ..
            } = c;
            p.pieces_fitted = pilots.into_pieces(&all);
            let all = all.dense();
            let gs = self.group(p.index)?;
            let fail = |e: GroupError| e.of(self.rec, Some(gs.first_line), gs.condition);
            // (`all` is gathered about p.fitted: it reaches it by construction.)
            if !p.moments.within(p.fitted, REACH_FIT) {
                // The first expansion could not reach the rate: fit again from here.
                p.four = moments::four_param(&all, p.fitted, CLOCK)
                    .map_err(|e| fail(GroupError::RateFit(e)))?;
                p.fitted = PhaseStep::from_hz(p.four.rate_hz, CLOCK)
                    .ok_or_else(|| fail(GroupError::FittedRate))?;
                if !all.within(p.fitted, REACH_FIT) {
                    let reach = all.reach(p.fitted);
                    return Err(fail(GroupError::Unsteady { reach }).into());
                }
            }
            let flagged = flagged.map(|f| (f.rows() > 0).then_some(f));
            p.moments = all;
            p.beta =
                moments::wide_betas(&p.moments, &flagged, p.fitted).map_err(|e| fail(e.into()))?;
        }
        Ok(())
    }

    /// The residuals of each group's widened fit at its fitted rate, into lagged sums per
    /// channel, and the residual sums of squares of its sine fits at the fitted and the
    /// nominal rate.
    pub(super) fn residual_pass(
        &self,
        prepared: &[&Prepared],
    ) -> Result<Vec<Residuals>, FileError> {
        if prepared.is_empty() {
            return Ok(Vec::new());
        }
        let wanted: Vec<usize> = prepared.iter().map(|p| p.index).collect();
        // Each group's sine coefficients at the fitted and the nominal rate, and the
        // shift between the two (rad/s).
        let mut sines = Vec::with_capacity(prepared.len());
        for p in prepared {
            let gs = self.group(p.index)?;
            sines.push(sine_pair(p).map_err(|e| {
                GroupError::from(e).of(self.rec, Some(gs.first_line), gs.condition)
            })?);
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
                    lagged: Channel::ALL.map(|ch| ch.of(&a.lagged).followed_by(ch.of(&b.lagged))),
                    rss_fitted: Channel::ALL.map(|ch| ch.of(&a.rss_fitted) + ch.of(&b.rss_fitted)),
                    rss_nominal: Channel::ALL
                        .map(|ch| ch.of(&a.rss_nominal) + ch.of(&b.rss_nominal)),
                })
                .collect()
        };
        self.pass(&wanted, fresh, each, join)
    }
}

/// A group's sums in the correcting pass, on one thread: all its rows', each channel's
/// readings on rails, and its pilots.
struct Correcting {
    all: Moments,
    flagged: [Moments; 3],
    pilots: Pilots,
    /// Rows waiting to be summed into `all` and `pilots` a block at a time.
    block: Box<Block>,
}

impl Correcting {
    /// The rows waiting, summed.
    fn settle(&mut self) {
        pilot::settle(&mut self.all, &mut self.pilots, &mut self.block);
    }
}
