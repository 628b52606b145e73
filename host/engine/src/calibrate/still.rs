//! Still intervals in a continuous recording (method free, docs/calibration.md).
//!
//! The readings are cut into windows of `window_s`. A window is still when its variance,
//! channel by channel over the noise variance measured in the data and averaged over the
//! channels, stays below `threshold`. The noise variance is that of the still windows
//! themselves, found by iteration from the quietest tenth, so no level is given and none
//! is assumed. Runs of still windows are candidate intervals; one window is trimmed at
//! each end (a turn's last slow part hides in the window next to it). A candidate is
//! kept when it lasts `min_still_s` and did not move: a line through each channel's
//! readings, with its standard error under an AR model of the residuals, must not change
//! by more than [`MOVED_Z`] standard errors over the interval.
//!
//! Every candidate is reported with its span, mean, scatter and verdict.

use crate::fit::noise::NoiseModel;
use nalgebra::DMatrix;
use rotacal_shared::Channel;

/// Choices of the detection.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Options {
    /// Window length, s.
    pub window_s: f64,
    /// A window is still when its variance over the noise variance, averaged over the
    /// channels, is below this.
    pub threshold: f64,
    /// Shortest interval kept, s (after trimming).
    pub min_still_s: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            window_s: 0.5,
            threshold: 4.0,
            min_still_s: 1.0,
        }
    }
}

/// How many standard errors a line through an interval's readings may change by before
/// the interval is taken to have moved: the normal quantile for a two-sided 1e-4 per
/// channel (3 channels per interval, so about 3e-4 of still intervals are lost).
pub const MOVED_Z: f64 = 3.891;

/// What became of a candidate interval.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
#[serde(rename_all = "kebab-case", tag = "verdict")]
pub enum Verdict {
    /// A pose.
    Kept,
    /// Shorter than the minimum.
    TooShort {
        /// Its length after trimming, s.
        duration_s: f64,
    },
    /// The readings drift: the device turned or slid.
    Moved {
        /// Change over the interval per channel, output units.
        change: [f64; 3],
        /// That change over its standard error, the largest of the channels.
        z: f64,
    },
    /// Its mean does not fit |a| = g with the others (set by the fit).
    DoesNotFit {
        /// (|a| − g) in m/s².
        residual_ms2: f64,
        /// That over its standard error.
        z: f64,
    },
}

impl Verdict {
    /// The reason in a sentence.
    pub fn reason(&self, min_s: f64) -> String {
        match self {
            Verdict::Kept => "kept".into(),
            Verdict::TooShort { duration_s } => {
                format!("too short: {duration_s:.2} s still, the minimum is {min_s} s")
            }
            Verdict::Moved { change, z } => format!(
                "moved: the readings changed by ({:.3e}, {:.3e}, {:.3e}) over the interval, \
                 {z:.1} standard errors (limit {MOVED_Z})",
                change[0], change[1], change[2]
            ),
            Verdict::DoesNotFit { residual_ms2, z } => format!(
                "does not fit: |a| − g = {residual_ms2:.3e} m/s², {z:.1} standard errors from \
                 the others' fit"
            ),
        }
    }
}

/// One candidate interval.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Interval {
    /// Its name (`pose column`, else `still N` in order).
    pub name: String,
    /// First and one past the last row (indices into the segment).
    pub rows: (usize, usize),
    /// Time of the first and last row, s.
    pub span_s: (f64, f64),
    /// File line of its first row.
    pub first_line: u64,
    /// Rows.
    pub n: usize,
    /// Mean u, v, w.
    pub mean: [f64; 3],
    /// Standard deviation of the readings, u, v, w.
    pub std: [f64; 3],
    /// Standard error of the mean, u, v, w, under an AR model of the readings about a line
    /// (std/√n below 100 readings).
    pub std_err: [f64; 3],
    /// Kept, or why not.
    #[serde(flatten)]
    pub verdict: Verdict,
    /// Per channel, the moved test's line change and its variance under the AR model
    /// (`None` where the interval was too short to test, or the model failed); not written.
    #[serde(skip)]
    pub change: [Option<Change>; 3],
}

/// One channel's change over an interval, as the moved test measured it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Change {
    /// The line's change from the first to the last row, 2 × its slope (output units).
    pub d: f64,
    /// Its variance under the AR model of the line's residuals (output units²).
    pub var_ar: f64,
}

/// The regressors (1, (t − t̄)/half) of the line through readings at `times`, half being
/// half their span: its slope is half the change over them.
pub fn line_design(times: &[f64]) -> DMatrix<f64> {
    let n = times.len();
    let t0 = times.first().copied().unwrap_or(0.0);
    let t1 = times.last().copied().unwrap_or(t0);
    let tm = times.iter().sum::<f64>() / n.max(1) as f64;
    let half = ((t1 - t0) / 2.0).max(1e-300);
    DMatrix::from_row_iterator(n, 2, times.iter().flat_map(|t| [1.0, (t - tm) / half]))
}

/// The detection's result for one continuous segment.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Detection {
    /// The options used.
    pub options: Options,
    /// Rows per window.
    pub window_rows: usize,
    /// Sample rate, Hz (from the median time step).
    pub sample_rate_hz: f64,
    /// Standard deviation of the readings within a still window, per channel: the noise
    /// the thresholds are relative to.
    pub noise_sd: [f64; 3],
    /// Fraction of the windows found still.
    pub still_fraction: f64,
    /// Every candidate, in time order.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub intervals: Vec<Interval>,
}

/// Why nothing could be detected.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum StillError {
    /// Too few rows or no usable time base.
    #[error("{0}")]
    Data(String),
}

/// The median of `v` (sorted in place); NaN when empty.
pub fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    // The middle one (n odd) or two (n even) of the sorted values.
    let mut middle = v.iter().skip(n.saturating_sub(1) / 2);
    match (middle.next(), middle.next()) {
        (Some(a), Some(b)) if n % 2 == 0 => (a + b) / 2.0,
        (Some(m), _) => *m,
        (None, _) => f64::NAN,
    }
}

/// The still intervals of one continuous segment: times `t_s` (non-decreasing), readings
/// `y`, file lines `line`.
pub fn detect(
    t_s: &[f64],
    y: &[[f64; 3]],
    line: &[u64],
    opts: Options,
) -> Result<Detection, StillError> {
    let n = y.len().min(t_s.len());
    if !(opts.window_s > 0.0 && opts.threshold > 1.0 && opts.min_still_s >= 0.0) {
        return Err(StillError::Data(
            "still detection: the window must be positive and the threshold above 1".into(),
        ));
    }
    let mut dt: Vec<f64> = t_s
        .iter()
        .zip(t_s.iter().skip(1))
        .map(|(t0, t1)| t1 - t0)
        .filter(|d| *d > 0.0)
        .collect();
    let step = median(&mut dt);
    if !(step.is_finite() && step > 0.0) {
        return Err(StillError::Data(
            "still detection needs increasing t_s (the sample rate comes from it)".into(),
        ));
    }
    let fs = 1.0 / step;
    let w = ((opts.window_s * fs).round() as usize).max(4);
    let blocks = n / w;
    if blocks < 3 {
        return Err(StillError::Data(format!(
            "{n} rows make {blocks} windows of {w} rows: too few to find still intervals"
        )));
    }
    // Each window's variance per channel.
    let var: Vec<[f64; 3]> = y
        .chunks_exact(w)
        .take(blocks)
        .map(|rows| {
            let m = rows.len().max(1) as f64;
            Channel::ALL.map(|ch| {
                let mean = rows.iter().map(|r| *ch.of(r)).sum::<f64>() / m;
                rows.iter().map(|r| (ch.of(r) - mean).powi(2)).sum::<f64>() / (m - 1.0).max(1.0)
            })
        })
        .collect();
    // The noise: from the quietest tenth of the windows, then from the windows found still,
    // until the set stops changing.
    let score = |v: &[f64; 3]| v.iter().map(|x| x.max(1e-300).ln()).sum::<f64>();
    let mut order: Vec<(f64, &[f64; 3])> = var.iter().map(|v| (score(v), v)).collect();
    order.sort_by(|a, b| a.0.total_cmp(&b.0));
    let quiet: Vec<&[f64; 3]> = order
        .iter()
        .take((blocks / 10).max(1))
        .map(|(_, v)| *v)
        .collect();
    // Below 1e-10 of the readings' size the data are noise-free: that is the floor.
    let scale = y
        .iter()
        .map(|r| r.iter().map(|v| v * v).sum::<f64>())
        .sum::<f64>()
        / n.max(1) as f64;
    let floor = 1e-20 * scale;
    let mut noise = Channel::ALL
        .map(|ch| median(&mut quiet.iter().map(|v| *ch.of(v)).collect::<Vec<_>>()).max(floor));
    let ratio = |v: &[f64; 3], noise: &[f64; 3]| {
        v.iter()
            .zip(noise)
            .map(|(v, n)| v / n.max(1e-300))
            .sum::<f64>()
            / 3.0
    };
    let mut still: Vec<bool> = vec![false; blocks];
    for _ in 0..50 {
        let next: Vec<bool> = var
            .iter()
            .map(|v| ratio(v, &noise) < opts.threshold)
            .collect();
        let count = next.iter().filter(|s| **s).count();
        if count == 0 {
            break;
        }
        noise = Channel::ALL
            .map(|ch| {
                var.iter()
                    .zip(&next)
                    .filter(|(_, s)| **s)
                    .map(|(v, _)| *ch.of(v))
                    .sum::<f64>()
                    / count as f64
            })
            .map(|v| v.max(floor));
        let done = next == still;
        still = next;
        if done {
            break;
        }
    }
    let still_fraction = still.iter().filter(|s| **s).count() as f64 / blocks as f64;
    // Runs of still windows, trimmed by one window at each end.
    let mut intervals = Vec::new();
    let mut b = 0;
    while b < blocks {
        let run = still.iter().skip(b).take_while(|s| **s).count();
        if run == 0 {
            b += 1;
            continue;
        }
        let start = b;
        b += run;
        let (lo, hi) = if b - start > 2 {
            ((start + 1) * w, (b - 1) * w)
        } else {
            (start * w, b * w)
        };
        let name = format!("still {}", intervals.len() + 1);
        let trimmed = b - start > 2;
        let mut iv = interval(name, t_s, y, line, (lo, hi))?;
        let duration = if trimmed {
            iv.span_s.1 - iv.span_s.0 + step
        } else {
            0.0
        };
        if duration < opts.min_still_s {
            iv.verdict = Verdict::TooShort {
                duration_s: duration,
            };
        }
        intervals.push(iv);
    }
    Ok(Detection {
        options: opts,
        window_rows: w,
        sample_rate_hz: fs,
        noise_sd: noise.map(f64::sqrt),
        still_fraction,
        intervals,
    })
}

/// The poses of a segment whose rows are named (a `pose` column): each name's rows, in
/// order of first appearance, with the same stillness test as detected intervals.
pub fn named(
    t_s: &[f64],
    y: &[[f64; 3]],
    line: &[u64],
    names: &[String],
) -> Result<Vec<Interval>, StillError> {
    let mut out: Vec<Interval> = Vec::new();
    let mut seen: Vec<&str> = Vec::new();
    for (i, name) in names.iter().enumerate() {
        if seen.contains(&name.as_str()) {
            continue;
        }
        seen.push(name);
        // A name's rows must be one run.
        let end = names
            .iter()
            .enumerate()
            .skip(i)
            .take_while(|(_, n)| *n == name)
            .last()
            .map_or(i + 1, |(k, _)| k + 1);
        if names.iter().skip(end).any(|n| n == name) {
            return Err(StillError::Data(format!(
                "pose '{name}' (line {}) appears again after other rows: a pose's rows must \
                 be consecutive",
                line.get(i).copied().unwrap_or(0)
            )));
        }
        out.push(interval(name.clone(), t_s, y, line, (i, end))?);
    }
    Ok(out)
}

/// An interval's statistics and its stillness test.
fn interval(
    name: String,
    t_s: &[f64],
    y: &[[f64; 3]],
    line: &[u64],
    (lo, hi): (usize, usize),
) -> Result<Interval, StillError> {
    let beyond = || StillError::Data("interval beyond the data".into());
    let rows = y.get(lo..hi).ok_or_else(beyond)?;
    let times = t_s.get(lo..hi).ok_or_else(beyond)?;
    let n = rows.len();
    let m = n.max(1) as f64;
    let mean = Channel::ALL.map(|ch| rows.iter().map(|r| *ch.of(r)).sum::<f64>() / m);
    let std = Channel::ALL.map(|ch| {
        let sq = rows.iter().map(|r| (ch.of(r) - ch.of(&mean)).powi(2));
        (sq.sum::<f64>() / (m - 1.0).max(1.0)).sqrt()
    });
    let t0 = times.first().copied().unwrap_or(0.0);
    let t1 = times.last().copied().unwrap_or(t0);
    let mut std_err = std.map(|s| s / m.sqrt());
    let mut verdict = Verdict::Kept;
    let mut tested = [None; 3];
    if n >= super::NOISE_MODEL_MIN {
        // A line through each channel: its residuals give the noise model, its slope the
        // change over the interval.
        let h = line_design(times);
        let hth = h.tr_mul(&h);
        let inv = hth.try_inverse().ok_or_else(|| {
            StillError::Data(format!(
                "interval at line {}: times do not advance",
                line.get(lo).copied().unwrap_or(0)
            ))
        })?;
        let mut change = [0.0; 3];
        let mut z_max: f64 = 0.0;
        let each = std_err
            .iter_mut()
            .zip(change.iter_mut())
            .zip(tested.iter_mut());
        for (ch, ((se, change), tested)) in Channel::ALL.into_iter().zip(each) {
            let yj = nalgebra::DVector::from_iterator(n, rows.iter().map(|r| *ch.of(r)));
            let beta = &inv * h.tr_mul(&yj);
            let resid = &yj - &h * &beta;
            let Ok((_, cov)) =
                NoiseModel::estimate(resid.as_slice(), &[]).and_then(|nm| nm.regression_cov(&h))
            else {
                continue;
            };
            let diagonal = cov.diagonal();
            let ([_, slope], [var_0, var_1]) = (beta.as_slice(), diagonal.as_slice()) else {
                return Err(StillError::Data(
                    "internal: a line's fit without two coefficients (a bug in rotacal)".into(),
                ));
            };
            *se = var_0.max(0.0).sqrt();
            // The line's change from the first to the last row: 2·slope (its error not
            // below 1e-10 of the reading: round-off of noise-free data).
            let d = 2.0 * slope;
            let se_d = (2.0 * var_1.max(0.0).sqrt()).max(1e-10 * ch.of(&mean).abs());
            *change = d;
            *tested = Some(Change {
                d,
                var_ar: 4.0 * var_1,
            });
            if se_d > 0.0 {
                z_max = z_max.max(d.abs() / se_d);
            }
        }
        if z_max > MOVED_Z {
            verdict = Verdict::Moved { change, z: z_max };
        }
    }
    Ok(Interval {
        name,
        rows: (lo, hi),
        span_s: (t0, t1),
        first_line: line.get(lo).copied().unwrap_or(0),
        n,
        mean,
        std,
        std_err,
        verdict,
        change: tested,
    })
}
