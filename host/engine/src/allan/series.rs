//! A recording's groups (condition, pose, free series) and channels as uniformly sampled
//! series, each checked for gaps: a dropped sample would bend every τ above it, so it is an
//! error naming where, never bridged.

use super::AllanError;
use crate::recording::Recording;

/// Standard gravity, m/s² (the g of µg; ISO 80000-3).
pub const STANDARD_GRAVITY: f64 = 9.806_65;

/// One µg in m/s² (10⁻⁶ standard gravity, written out so the simulator's levels keep their
/// bits).
pub const MICRO_G: f64 = 9.806_65e-6;

/// A gap or irregular step in a record's timing.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
#[error(
    "{group}: {what} between t_s = {before_s} s and {after_s} s (a step of {step_s:.6} s; \
     the sample interval is {interval_s:.6} s){}",
    line.map_or(String::new(), |l| format!(", at line {l}"))
)]
pub struct Gap {
    /// The group's name.
    pub group: String,
    /// `a gap (dropped samples)` or `a step shorter than half the sample interval`.
    pub what: &'static str,
    /// Time of the sample before, s.
    pub before_s: f64,
    /// Time of the sample after, s.
    pub after_s: f64,
    /// The step, s.
    pub step_s: f64,
    /// The nominal interval, s.
    pub interval_s: f64,
    /// 1-based file line of the sample after, when known.
    pub line: Option<u64>,
}

/// One uniformly sampled still record with its three channels.
#[derive(Clone, Debug, PartialEq)]
pub struct Still {
    /// `condition x`, `pose z_p`, `free series`.
    pub name: String,
    /// Sample rate, Hz.
    pub rate_hz: f64,
    /// Time of each sample, s (t_s, or i/rate when the file has none).
    pub t_s: Vec<f64>,
    /// Channels u, v, w, file units.
    pub channels: [Channel; 3],
    /// 1-based file line of each sample, when known.
    pub line: Option<Vec<u64>>,
}

/// One channel's samples.
#[derive(Clone, Debug, PartialEq)]
pub struct Channel {
    /// `u`, `v` or `w`.
    pub name: &'static str,
    /// The samples, file units.
    pub y: Vec<f64>,
}

/// How file units turn into µg.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Scale {
    /// µg per file unit, when the units allow it.
    pub micro_g_per_unit: Option<f64>,
    /// The units the results are in: `µg`, or the file's own.
    pub units: String,
}

/// µg per file unit for the `units` metadata: m/s² (by standard gravity), g, mg, µg.
/// Counts, volts and unknown units have no conversion (the file carries no sensitivity).
pub fn to_micro_g(units: Option<&str>) -> Scale {
    let u = units.map(str::trim).unwrap_or("");
    let lower = u.to_ascii_lowercase();
    let factor = match lower.as_str() {
        "m/s^2" | "m/s2" | "m/s²" | "m s^-2" | "m*s^-2" => Some(1e6 / STANDARD_GRAVITY),
        "g" | "g0" | "g_n" => Some(1e6),
        "mg" => Some(1e3),
        "ug" | "µg" | "μg" | "micro-g" => Some(1.0),
        _ => None,
    };
    Scale {
        micro_g_per_unit: factor,
        units: if factor.is_some() {
            "µg".to_string()
        } else if u.is_empty() {
            "file units".to_string()
        } else {
            u.to_string()
        },
    }
}

/// The still records of `rec`, restricted to `from_s ≤ t ≤ to_s` (device time t_s; i/rate
/// from the group's start without it), with their rates. Groups: each condition (and
/// rate; each run of one table angle in a stepped file), each run of one pose in a file
/// with gravity directions, the free series (each run of one `pose` name, if it has that
/// column). A rotation group is taken whole: it is not still (the caller says so).
pub fn series_of(
    rec: &Recording,
    from_s: Option<f64>,
    to_s: Option<f64>,
) -> Result<Vec<Still>, AllanError> {
    let meta_rate = rec.meta.sample_rate_hz;
    let mut raw: Vec<Raw> = vec![];
    for g in &rec.groups {
        let name = match g.rate_hz {
            Some(r) => format!(
                "condition {} at {r} Hz (from line {})",
                g.condition, g.first_line
            ),
            None => format!("condition {} (from line {})", g.condition, g.first_line),
        };
        let y: Vec<[f64; 3]> =
            g.u.iter()
                .zip(&g.v)
                .zip(&g.w)
                .map(|((u, v), w)| [*u, *v, *w])
                .collect();
        let t = (!g.t_s.is_empty()).then_some(g.t_s.as_slice());
        let boots = g.boot.as_ref().filter(|_| g.in_several_boots());
        if let (Some(b), true) = (boots, g.angle_deg.is_empty()) {
            // Each boot's clock starts afresh: one record per boot.
            let labels: Vec<String> = b
                .iter()
                .map(|k| format!("{} boot {k}", g.condition))
                .collect();
            push_runs(&mut raw, "condition", &labels, &y, t, None);
        } else if g.angle_deg.is_empty() {
            raw.push((name, t.map(<[f64]>::to_vec), y, None));
        } else {
            // A stepped group is still only at each table angle: one record per step.
            let labels: Vec<String> = g
                .angle_deg
                .iter()
                .map(|a| format!("{} at {a}°", g.condition))
                .collect();
            push_runs(&mut raw, "condition", &labels, &y, t, None);
        }
    }
    if let Some(o) = &rec.oriented {
        let labels: Vec<String> = match &o.pose {
            Some(p) => p.clone(),
            None => o
                .gravity
                .iter()
                .map(|g| format!("({:.3}, {:.3}, {:.3})", g[0], g[1], g[2]))
                .collect(),
        };
        push_runs(
            &mut raw,
            "pose",
            &labels,
            &o.y,
            o.t_s.as_deref(),
            Some(&o.line),
        );
    }
    if let Some(s) = &rec.series {
        match &s.pose {
            Some(p) => push_runs(&mut raw, "pose", p, &s.y, Some(&s.t_s), Some(&s.line)),
            None => raw.push((
                "free series".to_string(),
                Some(s.t_s.clone()),
                s.y.clone(),
                Some(s.line.clone()),
            )),
        }
    }
    let mut out = vec![];
    for (name, t, y, line) in raw {
        if let Some(still) = uniform(name, t, y, line, meta_rate, from_s, to_s)? {
            out.push(still);
        }
    }
    Ok(out)
}

/// A group before its timing is checked: name, t_s, rows u v w, file lines.
type Raw = (String, Option<Vec<f64>>, Vec<[f64; 3]>, Option<Vec<u64>>);

/// Split rows into runs of equal consecutive labels (`line`: the rows' file lines, when
/// known).
fn push_runs(
    raw: &mut Vec<Raw>,
    kind: &str,
    labels: &[String],
    y: &[[f64; 3]],
    t_s: Option<&[f64]>,
    line: Option<&[u64]>,
) {
    let mut start = 0;
    while start < labels.len() {
        let Some(label) = labels.get(start) else {
            break;
        };
        let len = labels
            .iter()
            .skip(start)
            .take_while(|l| *l == label)
            .count();
        let take = |v: &[f64]| v.iter().skip(start).take(len).copied().collect::<Vec<_>>();
        let name = match line.and_then(|l| l.get(start)) {
            Some(first) => format!("{kind} {label} (from line {first})"),
            None => format!("{kind} {label}"),
        };
        raw.push((
            name,
            t_s.map(take),
            y.iter().skip(start).take(len).copied().collect(),
            line.map(|l| l.iter().skip(start).take(len).copied().collect()),
        ));
        start += len;
    }
}

/// Check the spacing, restrict to the window, and transpose into channels. `None` when
/// the window leaves nothing.
fn uniform(
    name: String,
    t: Option<Vec<f64>>,
    y: Vec<[f64; 3]>,
    line: Option<Vec<u64>>,
    meta_rate: Option<f64>,
    from_s: Option<f64>,
    to_s: Option<f64>,
) -> Result<Option<Still>, AllanError> {
    let (t_s, interval_s) = match t {
        Some(t) => {
            let mut steps: Vec<f64> = t.iter().zip(t.iter().skip(1)).map(|(a, b)| b - a).collect();
            steps.sort_by(f64::total_cmp);
            // The median step: robust to the gaps it is used to find.
            let med = steps
                .get(steps.len() / 2)
                .copied()
                .or_else(|| meta_rate.map(|r| 1.0 / r));
            (t, med.unwrap_or(f64::NAN))
        }
        None => {
            let dt = meta_rate.map_or(f64::NAN, |r| 1.0 / r);
            ((0..y.len()).map(|i| i as f64 * dt).collect(), dt)
        }
    };
    if !(interval_s.is_finite() && interval_s > 0.0) {
        return Err(AllanError::NoRate { group: name });
    }
    let keep: Vec<usize> = t_s
        .iter()
        .enumerate()
        .filter(|(_, t)| from_s.is_none_or(|f| **t >= f) && to_s.is_none_or(|e| **t <= e))
        .map(|(i, _)| i)
        .collect();
    let pick = |i: &usize| t_s.get(*i).copied().unwrap_or(f64::NAN);
    let tw: Vec<f64> = keep.iter().map(pick).collect();
    for (k, (a, b)) in tw.iter().zip(tw.iter().skip(1)).enumerate() {
        let step = b - a;
        let what = if step > 1.5 * interval_s {
            "a gap (dropped samples)"
        } else if step < 0.5 * interval_s {
            "a step shorter than half the sample interval"
        } else {
            continue;
        };
        let row = keep.get(k + 1).copied().unwrap_or(0);
        return Err(AllanError::Gap(Gap {
            group: name,
            what,
            before_s: *a,
            after_s: *b,
            step_s: step,
            interval_s,
            line: line.as_ref().and_then(|l| l.get(row).copied()),
        }));
    }
    if keep.is_empty() {
        return Ok(None);
    }
    let chan = |c: usize| {
        keep.iter()
            .filter_map(|i| y.get(*i).and_then(|r| r.get(c)).copied())
            .collect::<Vec<f64>>()
    };
    // The mean spacing of the window: t_s written with few digits makes single steps coarse.
    let rate_hz = match (tw.first(), tw.last()) {
        (Some(a), Some(b)) if tw.len() > 1 && b > a => (tw.len() - 1) as f64 / (b - a),
        _ => 1.0 / interval_s,
    };
    Ok(Some(Still {
        name,
        rate_hz,
        t_s: tw,
        channels: [
            Channel {
                name: "u",
                y: chan(0),
            },
            Channel {
                name: "v",
                y: chan(1),
            },
            Channel {
                name: "w",
                y: chan(2),
            },
        ],
        line: line.map(|l| keep.iter().filter_map(|i| l.get(*i).copied()).collect()),
    }))
}
