//! Method free: still intervals found in a continuous recording (or named by its `pose`
//! column), then G and O from |a| = g ([`super::free`]); the entry and its budget.

use super::budget::{Budget, Kind};
use super::drift;
use super::json::{self, CorrectionJson};
use super::sources::{gravity_source, new_budget, values6, variances6};
use super::{
    correction, err, free, poses, still, CalibrateError, CalibrateErrorKind, Options, Preflight,
};
use crate::allan::powerlaw::FLICKER_ALLAN_PLATEAU;
use crate::recording::Recording;
use nalgebra::DMatrix;
use rotacal_shared::{intrinsic, Channel};
use std::borrow::Cow;

/// One continuous stretch of readings searched for still intervals: borrowed from the
/// recording where it holds the rows as they are (a free recording), built otherwise.
pub struct Segment<'a> {
    /// What it is, for names and messages (empty for a whole recording).
    pub label: String,
    /// Time of each row, s.
    pub t_s: Cow<'a, [f64]>,
    /// Readings u, v, w of each row.
    pub y: Cow<'a, [[f64; 3]]>,
    /// File line of each row.
    pub line: Cow<'a, [u64]>,
    /// The `pose` column of a free recording: the poses are named, not found.
    pub names: Option<&'a [String]>,
}

/// The recording's continuous stretches: a free recording whole; a file with conditions
/// one per condition (and rate); a file with gravity directions whole, in file order (its
/// directions unused). Without `t_s`, the rows are `1/sample_rate_hz` apart.
pub fn segments(rec: &Recording) -> Result<Vec<Segment<'_>>, CalibrateError> {
    // The rows' times: `t` when every row has one, else 1/sample_rate_hz apart.
    fn clock<'t>(
        rec: &Recording,
        n: usize,
        t: Option<&'t Vec<f64>>,
        line: u64,
    ) -> Result<Cow<'t, [f64]>, CalibrateError> {
        match t {
            Some(t) if t.len() == n => Ok(Cow::Borrowed(t.as_slice())),
            _ => {
                let fs = rec
                    .meta
                    .sample_rate_hz
                    .ok_or_else(|| err(rec, Some(line), CalibrateErrorKind::NoClock))?;
                Ok(Cow::Owned((0..n).map(|i| i as f64 / fs).collect()))
            }
        }
    }
    if let Some(s) = &rec.series {
        return Ok(vec![Segment {
            label: String::new(),
            t_s: Cow::Borrowed(&s.t_s),
            y: Cow::Borrowed(&s.y),
            line: Cow::Borrowed(&s.line),
            names: s.pose.as_deref(),
        }]);
    }
    if let Some(o) = &rec.oriented {
        let first = o.line.first().copied().unwrap_or(0);
        return Ok(vec![Segment {
            label: String::new(),
            t_s: clock(rec, o.y.len(), o.t_s.as_ref(), first)?,
            y: Cow::Borrowed(&o.y),
            line: Cow::Borrowed(&o.line),
            names: None,
        }]);
    }
    let mut out = Vec::new();
    for g in &rec.groups {
        let n = g.len();
        let t = (!g.t_s.is_empty()).then_some(&g.t_s);
        let rate = g.rate_hz.map(|r| format!(" at {r} Hz")).unwrap_or_default();
        out.push(Segment {
            label: format!("condition {}{rate}", g.condition.letter()),
            t_s: clock(rec, n, t, g.first_line)?,
            // (A group's three columns have a value in every row.)
            y: Cow::Owned(
                g.u.iter()
                    .zip(&g.v)
                    .zip(&g.w)
                    .map(|((u, v), w)| [*u, *v, *w])
                    .collect(),
            ),
            // Rows of a group are consecutive lines unless the file interleaves them.
            line: Cow::Owned((0..n as u64).map(|i| g.first_line + i).collect()),
            names: None,
        });
    }
    Ok(out)
}

/// Per segment: its label, the detection that found its intervals (none where they were
/// named), and its intervals.
type Detections = Vec<(String, Option<still::Detection>, Vec<still::Interval>)>;
/// Per segment with `--slow-noise`: its flicker levels and its rows.
type Wander = Vec<([Option<drift::Level>; 3], usize)>;

/// The still intervals of every segment of `rec`: found (or named), with `--slow-noise`
/// retested against a flicker term.
fn find_poses(
    rec: &Recording,
    opts: &Options,
    units: &str,
) -> Result<(Detections, Vec<String>, Wander), CalibrateError> {
    let mut detections: Detections = Vec::new();
    let mut drift_notes = Vec::new();
    let mut wander: Wander = Vec::new();
    for seg in segments(rec)? {
        let found = match seg.names {
            Some(names) => (None, still::named(&seg.t_s, &seg.y, &seg.line, names)),
            None => match still::detect(&seg.t_s, &seg.y, &seg.line, opts.still) {
                Ok(d) => {
                    let iv = d.intervals.clone();
                    (Some(d), Ok(iv))
                }
                Err(e) => (None, Err(e)),
            },
        };
        let (det, mut intervals) = (
            found.0,
            found.1.map_err(|e| {
                let at = if seg.label.is_empty() {
                    String::new()
                } else {
                    format!("{}: ", seg.label)
                };
                err(
                    rec,
                    seg.line.first().copied(),
                    CalibrateErrorKind::Still { at, source: e },
                )
            })?,
        );
        if opts.slow_noise {
            let levels = drift::retest(&seg.t_s, &mut intervals);
            drift_notes.push(drift_note(&seg.label, &levels, units));
            wander.push((levels, seg.t_s.len()));
        }
        let intervals = intervals
            .into_iter()
            .map(|mut i| {
                if !seg.label.is_empty() {
                    i.name = format!("{} {}", seg.label, i.name);
                }
                i
            })
            .collect();
        detections.push((seg.label, det, intervals));
    }
    Ok((detections, drift_notes, wander))
}

/// With `--slow-noise`, the fewest poses a free fit takes: the scatter τ between placements
/// is estimated from P − 9 residual degrees of freedom, and with fewer than 15 slow noise
/// that scatter carries is missed too often (measured: docs/uncertainty.md, "Free poses
/// under slow noise").
pub const SLOW_MIN_POSES: usize = 24;

/// Method free: still intervals found (or named), then G and O from |a| = g.
pub(super) fn entry(
    rec: &Recording,
    opts: &Options,
    pre: &Preflight,
) -> Result<json::RateJson, CalibrateError> {
    let (g, units) = (pre.g_loc, pre.units.as_str());
    if opts.monte_carlo.is_some() {
        return Err(err(rec, None, CalibrateErrorKind::MonteCarloFree));
    }
    let (mut detections, drift_notes, wander) = find_poses(rec, opts, units)?;
    let poses: Vec<free::Pose> = detections
        .iter()
        .flat_map(|(_, _, iv)| iv.iter())
        .filter(|i| i.verdict == still::Verdict::Kept)
        .map(free::Pose::from_interval)
        .collect();
    // With `--slow-noise` the scatter is measured in every fit: slow noise as small as the
    // poses' own noise escapes the χ² test on P − 9 degrees of freedom, yet counts.
    let scatter = if opts.slow_noise {
        free::Scatter::Measured
    } else {
        free::Scatter::Tested
    };
    let mut fit = free::fit_with(&poses, g, free::Residual::Geometric, scatter).map_err(|e| {
        err(
            rec,
            None,
            CalibrateErrorKind::Free {
                source: e,
                detections: detection_summary(&detections, opts.still),
            },
        )
    })?;
    // The fit's rejections, on the intervals.
    for (_, _, iv) in &mut detections {
        for i in iv.iter_mut() {
            if let Some((_, v)) = fit.rejected.iter().find(|(n, _)| *n == i.name) {
                i.verdict = v.clone();
            }
        }
    }
    // After the fit's rejections, so that the detection shows every pose left out.
    if opts.slow_noise && fit.poses.len() < SLOW_MIN_POSES {
        return Err(err(
            rec,
            None,
            CalibrateErrorKind::FreeSlowPoses {
                kept: fit.poses.len(),
                detections: detection_summary(&detections, opts.still),
            },
        ));
    }
    // With `--slow-noise` the poses' scatter beyond their noise is the bias's wander: its
    // mean over the poses against the record's is the bias_wander line's, so τ's share of
    // it leaves the offsets (docs/uncertainty.md, "Free poses under slow noise").
    let wander_term = WanderTerm::of((&wander, &detections));
    let common_out = wander_term.is_some() && fit.take_out_common_scatter();
    let s_cov = poses::s_block(&fit.cov);
    let intr = intrinsic::from_matrix_cov(&fit.l, &s_cov)
        .map_err(|e| err(rec, None, CalibrateErrorKind::Intrinsic(e)))?;
    // (S row-major, O): O's variances are the last three of the diagonal.
    let [.., var_u, var_v, var_w]: [f64; 12] = fit.cov.diagonal().into();
    let [o_u, o_v, o_w] = fit.offsets;
    let offsets =
        [(o_u, var_u), (o_v, var_v), (o_w, var_w)].map(|(value, var)| intrinsic::Estimate {
            value,
            std_unc: var.max(0.0).sqrt(),
        });
    let b = free_budget(
        &fit,
        &intr,
        &offsets,
        (wander_term.as_ref(), common_out),
        drift_notes,
        pre,
    );
    let mut entry = json::free_entry(&intr, &offsets, &b, &fit, &detections).ok_or_else(|| {
        err(
            rec,
            None,
            CalibrateErrorKind::Internal("a budget without a line per property"),
        )
    })?;
    let cov12 = DMatrix::from_iterator(12, 12, fit.cov.iter().copied());
    let (device, _) =
        correction::from_matrix(&fit.l, fit.offsets, &cov12).map_err(|e| err(rec, None, e))?;
    entry.correction = Some(CorrectionJson::new(
        units,
        device,
        None,
        fit.k,
        "the fit of G and O to the still poses (|a| = g)",
    ));
    entry.uncertainty_budget = Some(b);
    Ok(entry)
}

/// The free fit's budget: the poses (noise, and τ when estimated), the bias's wander with
/// `--slow-noise`, g_loc, and the notes.
fn free_budget(
    fit: &free::FreeFit,
    intr: &intrinsic::Intrinsic,
    offsets: &[intrinsic::Estimate; 3],
    (wander, common_out): (Option<&WanderTerm>, bool),
    drift_notes: Vec<String>,
    pre: &Preflight,
) -> Budget {
    let (g, inputs, units) = (pre.g_loc, &pre.inputs, pre.units.as_str());
    // The budget: the poses (noise, and τ when estimated) and g_loc.
    let mut b = new_budget(units, true);
    let mut contribution: Vec<f64> = variances6(&intr.cov)
        .iter()
        .map(|v| v.max(0.0).sqrt())
        .collect();
    contribution.extend(offsets.iter().map(|o| o.std_unc));
    let nu = fit.nu.is_finite().then_some(fit.nu);
    let mut nu_each = [nu; 9];
    if let Some(tau2) = fit.tau2_measured {
        // Each property's variance holds c·τ²: its degrees of freedom from τ²'s variance.
        let per = intrinsic::from_matrix_cov(&fit.l, &poses::s_block(&fit.cov_per_tau2));
        let mut c: Vec<f64> = per.map_or(vec![0.0; 6], |p| variances6(&p.cov).to_vec());
        c.extend(fit.cov_per_tau2.diagonal().iter().skip(9));
        for ((n, u), c) in nu_each.iter_mut().zip(&contribution).zip(&c) {
            let dof = free::scatter_dof(u * u, *c, tau2);
            *n = dof.is_finite().then_some(dof);
        }
    }
    let description = if let Some((tau2, _)) = fit.tau2_measured {
        format!(
            "the fit of G and O to the {} still poses' means (JSON free.poses): each pose's \
             noise (an AR model of its readings about a line) and a scatter τ² = {tau2:.3e} \
             m²/s⁴ beyond it, measured from χ² and counted whatever its sign; each property's \
             ν from τ²'s variance{}",
            fit.poses.len(),
            if common_out {
                "; the offsets without τ²'s common part (the poses' mean error, which the \
                 bias_wander line counts)"
            } else {
                ""
            }
        )
    } else if fit.tau_ms2 > 0.0 {
        format!(
            "the fit of G and O to the {} still poses' means (JSON free.poses): each pose's \
             noise (an AR model of its readings about a line) and a scatter τ = {:.3e} m/s² \
             beyond it, with P − 9 = {} degrees of freedom",
            fit.poses.len(),
            fit.tau_ms2,
            fit.dof
        )
    } else if fit.dof == 0 {
        format!(
            "the fit of G and O to the {} still poses' means (JSON free.poses), each pose's \
             noise from an AR model of its readings about a line, unchecked: no degree of \
             freedom is left",
            fit.poses.len()
        )
    } else {
        format!(
            "the fit of G and O to the {} still poses' means (JSON free.poses), each pose's \
             noise from an AR model of its readings about a line; χ² = {:.1} on {} degrees of \
             freedom agrees with that noise",
            fit.poses.len(),
            fit.chi2,
            fit.dof
        )
    };
    b.vector("poses", Kind::A, description, &contribution, &nu_each);
    if let Some(term) = wander {
        bias_wander(&mut b, term, units);
    }
    if fit.dof == 0 {
        // Nine poses fit the nine unknowns exactly: nothing tests the readings' noise model
        // against how the poses scatter (hand placements drift between poses), so U may be
        // too small and nothing here could tell.
        b.notes.push(format!(
            "{} poses for 9 unknowns: no degree of freedom is left to check the noise model \
             against the poses' scatter, so U rests on each pose's own noise alone and is \
             unchecked; with 12 or more poses χ² tests it",
            fit.poses.len()
        ));
    }
    let wanted = (fit.tau_ms2 > 0.0 || fit.tau2_measured.is_some_and(|(t2, _)| t2 != 0.0))
        && wander.is_some();
    if wanted && !common_out {
        b.notes.push(
            "--slow-noise: τ's common part could not be taken out of the offsets (what would \
             be left is not a covariance), so it counts beside the bias_wander line and the \
             offsets' U may be larger than it needs to be"
                .into(),
        );
    }
    b.notes.extend(fit.notes.iter().cloned());
    b.notes.extend(drift_notes);
    let values = values6(intr);
    let mut cg = vec![0.0; 9];
    for (c, v) in cg.iter_mut().zip(values.iter().take(3)) {
        *c = -v / g;
    }
    gravity_source(&mut b, g, inputs.u_g_loc, &cg);
    if inputs.u_time_s.is_some() || inputs.u_angle_deg.is_some() {
        b.notes.push(
            "u_time_s or u_angle_deg was given, but method free uses neither timestamps nor \
             angles"
                .into(),
        );
    }
    b.combine();
    b
}

/// The offsets' term for the bias's wander in a one-segment recording: the fit measures
/// the bias averaged over its kept poses, the measurand is the bias averaged over the
/// record's readings (as for every method).
struct WanderTerm {
    /// The variance unit flicker gives the difference ([`drift::record_against_poses`]).
    unit: f64,
    /// Each channel's flicker level from the moved test.
    levels: [Option<drift::Level>; 3],
    /// The kept poses.
    poses: usize,
}

impl WanderTerm {
    /// For a recording of one segment with `--slow-noise`, when the kept poses give a unit.
    fn of((wander, detections): (&Wander, &Detections)) -> Option<WanderTerm> {
        let ([(levels, rows)], [(_, _, intervals)]) = (wander.as_slice(), detections.as_slice())
        else {
            return None;
        };
        let poses: Vec<(usize, usize)> = intervals
            .iter()
            .filter(|i| i.verdict == still::Verdict::Kept)
            .map(|i| i.rows)
            .collect();
        let unit = drift::record_against_poses(&poses, *rows);
        (unit.is_finite() && unit > 0.0).then_some(WanderTerm {
            unit,
            levels: *levels,
            poses: poses.len(),
        })
    }
}

/// The `bias_wander` line: each channel's flicker level λ from the moved test, where the
/// changes demand it, times the variance unit flicker gives the difference, with λ's
/// degrees of freedom.
fn bias_wander(b: &mut Budget, term: &WanderTerm, units: &str) {
    let mut contribution = vec![0.0; 9];
    let mut dof = vec![None; 9];
    for ((c, d), l) in contribution
        .iter_mut()
        .skip(6)
        .zip(dof.iter_mut().skip(6))
        .zip(&term.levels)
    {
        if let Some(l) = l.filter(|l| l.demanded) {
            *c = (l.lambda * term.unit).max(0.0).sqrt();
            *d = Some(drift::level_dof(l.intervals));
        }
    }
    b.vector(
        "bias_wander",
        Kind::A,
        format!(
            "--slow-noise: the bias averaged over the record's readings (the offsets' \
             measurand) against its mean over the {} kept poses (what the fit measures), in \
             {units}, under each channel's flicker level from the moved test where the changes \
             demand one (0 elsewhere); ν from that level's median estimate \
             (docs/uncertainty.md)",
            term.poses
        ),
        &contribution,
        &dof,
    );
}

/// What the moved test allowed for in a segment (`label`): each channel's flicker level,
/// as the Allan-deviation floor √(2 ln 2·λ/π) in output units.
fn drift_note(label: &str, levels: &[Option<drift::Level>; 3], units: &str) -> String {
    let at = if label.is_empty() {
        String::new()
    } else {
        format!(" ({label})")
    };
    let each: Vec<String> = Channel::ALL
        .iter()
        .zip(levels)
        .map(|(c, l)| match l {
            Some(l) => format!(
                "{c} {:.3e} {units}{}",
                (FLICKER_ALLAN_PLATEAU * l.lambda).sqrt(),
                if l.demanded {
                    ""
                } else {
                    " (not demanded by the changes)"
                }
            ),
            None => format!("{c} not estimated"),
        })
        .collect();
    let few = if levels.iter().all(Option::is_none) {
        format!(
            " (fewer than {} intervals to estimate it from)",
            drift::MIN_INTERVALS
        )
    } else {
        String::new()
    };
    format!(
        "--slow-noise: the moved test allows for flicker at the level the still intervals' \
         changes show{at}{few}, as an Allan-deviation floor: {}; between the poses the \
         slow noise counts through the measured scatter τ² (the poses line), and in a \
         recording of one piece the offsets' U includes how the bias averaged over the poses \
         differs from its mean over the record (the bias_wander line)",
        each.join(", ")
    )
}

/// The detection in a few lines: what was found, at which threshold, and why each
/// interval not kept was left out.
pub fn detection_summary(
    detections: &[(String, Option<still::Detection>, Vec<still::Interval>)],
    opts: still::Options,
) -> String {
    let mut out = String::new();
    for (label, det, iv) in detections {
        let kept = iv
            .iter()
            .filter(|i| i.verdict == still::Verdict::Kept)
            .count();
        let at = if label.is_empty() {
            String::new()
        } else {
            format!("{label}: ")
        };
        match det {
            Some(d) => {
                out += &format!(
                "{at}{} still interval(s) found, {kept} kept: windows of {} s ({} rows), still \
                 when their variance is below {}× the noise variance (noise sd per channel \
                 {:.3e}, {:.3e}, {:.3e}, measured in the still windows; {:.0} % of the windows \
                 still), at least {} s each\n",
                iv.len(),
                opts.window_s,
                d.window_rows,
                opts.threshold,
                d.noise_sd[0],
                d.noise_sd[1],
                d.noise_sd[2],
                100.0 * d.still_fraction,
                opts.min_still_s
            )
            }
            None => out += &format!("{at}{} named pose(s), {kept} kept\n", iv.len()),
        }
        for i in iv.iter().filter(|i| i.verdict != still::Verdict::Kept) {
            out += &format!(
                "  {} ({:.2}–{:.2} s, line {}): {}\n",
                i.name,
                i.span_s.0,
                i.span_s.1,
                i.first_line,
                i.verdict.reason(opts.min_still_s)
            );
        }
    }
    out.trim_end().to_string()
}
