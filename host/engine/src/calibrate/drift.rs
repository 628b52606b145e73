//! The free method's moved test under slow noise (`--slow-noise`; docs/uncertainty.md,
//! "Slow noise in the moved test").
//!
//! An interval "moved" when a line through its readings changes by more than
//! [`still::MOVED_Z`] standard errors. That standard error comes from an AR model of the
//! line's residuals, which sees 32 lags: a device lying still also wanders over seconds
//! (flicker, bias wander), and such an interval reads as moved.
//!
//! Here each change d_i gains, per channel, a flicker term: var d_i = v_i + λ·f_i, with
//! v_i the AR model's variance and f_i the variance unit flicker gives that interval's
//! change, exactly for its line ([`SlowDesign::slow_quadratic`]; the shape matters, as
//! intervals differ in length). λ is estimated from the changes themselves: the smallest
//! λ ≥ 0 at which the median of d_i²/var d_i over the channel's intervals is the median of
//! χ²₁. The median, because some intervals did move: up to half of them may, and λ does
//! not see them. Over a few seconds flicker and a random walk look alike, and the
//! residuals' Allan variances of such short intervals cannot tell either from the
//! short-range correlation (tried: the levels came out below zero as often as not), so
//! one term, fitted to the statistic the test uses, stands for both.

use super::poses::bracket;
use super::still::{self, Interval, Verdict};
use crate::fit::noise::{NoiseError, NoiseModel, SlowDesign};
use nalgebra::{DMatrix, DVector};
use rotacal_shared::Channel;

/// Fewest readings of an interval for it to enter (the slow design's minimum).
const MIN_ROWS: usize = 64;

/// Fewest intervals for the median to stand on.
pub const MIN_INTERVALS: usize = 8;

/// The median of χ² with one degree of freedom.
const CHI2_1_MEDIAN: f64 = 0.454_936_423_119_572_8;

/// One channel's change of one interval.
struct Change {
    index: usize,
    /// The change over the interval, 2 × the line's slope.
    d: f64,
    /// Its variance under the AR model.
    var_ar: f64,
    /// Its variance under unit flicker (Kasdin's innovation Q = 1 per reading).
    unit_flicker: f64,
}

/// The moved test again for `intervals` of a segment (times `t_s`, readings `y`), each
/// change's variance widened by the flicker level estimated from the changes. Intervals
/// under [`MIN_ROWS`] readings, or left out for another reason, keep their verdict; so do
/// all of them with fewer than [`MIN_INTERVALS`] to estimate from. Gives λ per channel
/// (output units² per reading; `None` when not estimated).
pub fn retest(
    t_s: &[f64],
    y: &[[f64; 3]],
    intervals: &mut [Interval],
) -> Result<[Option<f64>; 3], NoiseError> {
    let mut changes: [Vec<Change>; 3] = Default::default();
    for (index, iv) in intervals.iter().enumerate() {
        let open = matches!(iv.verdict, Verdict::Kept | Verdict::Moved { .. });
        if open && iv.n >= MIN_ROWS {
            for (ch, c) in line_changes(index, t_s, y, iv.rows)? {
                ch.of_mut(&mut changes).push(c);
            }
        }
    }
    let mut levels = [None; 3];
    let mut z_max: Vec<Option<(f64, [f64; 3])>> = vec![None; intervals.len()];
    for ch in Channel::ALL {
        let list = ch.of(&changes);
        if list.len() < MIN_INTERVALS {
            return Ok([None; 3]);
        }
        let lambda = level(list);
        *ch.of_mut(&mut levels) = Some(lambda);
        for c in list {
            let z = c.d.abs() / (c.var_ar + lambda * c.unit_flicker).max(0.0).sqrt();
            if let Some(slot) = z_max.get_mut(c.index) {
                let (mut z0, mut d) = slot.unwrap_or((0.0, [0.0; 3]));
                z0 = z0.max(z);
                *ch.of_mut(&mut d) = c.d;
                *slot = Some((z0, d));
            }
        }
    }
    for (iv, zm) in intervals.iter_mut().zip(z_max) {
        if let Some((z, change)) = zm {
            iv.verdict = if z > still::MOVED_Z {
                Verdict::Moved { change, z }
            } else {
                Verdict::Kept
            };
        }
    }
    Ok(levels)
}

/// The smallest λ ≥ 0 at which the median of d²/(v + λf) is at most χ²₁'s median.
fn level(list: &[Change]) -> f64 {
    let median = |lambda: f64| {
        let mut r: Vec<f64> = list
            .iter()
            .map(|c| c.d * c.d / (c.var_ar + lambda * c.unit_flicker))
            .collect();
        r.sort_by(f64::total_cmp);
        r.get(r.len() / 2).copied().unwrap_or(0.0)
    };
    if median(0.0) <= CHI2_1_MEDIAN {
        return 0.0;
    }
    // At hi every ratio is at most d²/(λf) ≤ the target.
    let hi = list
        .iter()
        .filter(|c| c.unit_flicker > 0.0)
        .map(|c| c.d * c.d / (c.unit_flicker * CHI2_1_MEDIAN))
        .fold(0.0, f64::max);
    let (_, hi) = bracket(
        &median,
        CHI2_1_MEDIAN,
        (0.0, hi.max(f64::MIN_POSITIVE)),
        200,
        0.0,
    );
    hi
}

/// Each channel's change over an interval's rows `lo..hi`, through the line `still` fits.
fn line_changes(
    index: usize,
    t_s: &[f64],
    y: &[[f64; 3]],
    (lo, hi): (usize, usize),
) -> Result<Vec<(Channel, Change)>, NoiseError> {
    let (Some(times), Some(rows)) = (t_s.get(lo..hi), y.get(lo..hi)) else {
        return Ok(Vec::new());
    };
    let n = rows.len();
    let t0 = times.first().copied().unwrap_or(0.0);
    let t1 = times.last().copied().unwrap_or(t0);
    let tm = times.iter().sum::<f64>() / n.max(1) as f64;
    let half = ((t1 - t0) / 2.0).max(1e-300);
    let h = DMatrix::from_row_iterator(n, 2, times.iter().flat_map(|t| [1.0, (t - tm) / half]));
    let Some(inv) = h.tr_mul(&h).try_inverse() else {
        return Ok(Vec::new());
    };
    let est = &h * inv;
    let weights: DVector<f64> = est.column(1) * 2.0;
    let [unit_flicker, _] = SlowDesign::new(&h, &vec![1.0; n])?.slow_quadratic(&weights);
    let mut out = Vec::new();
    for ch in Channel::ALL {
        let yj = DVector::from_iterator(n, rows.iter().map(|r| *ch.of(r)));
        let resid = &yj - &h * est.tr_mul(&yj);
        // As `still` tests it: the AR model of the residuals, rescaled for the line.
        let Ok((_, cov)) =
            NoiseModel::estimate(resid.as_slice(), &[]).and_then(|m| m.regression_cov(&h))
        else {
            continue;
        };
        let var_ar = 4.0 * cov.get((1, 1)).copied().unwrap_or(f64::NAN);
        if var_ar.is_finite() && var_ar > 0.0 {
            out.push((
                ch,
                Change {
                    index,
                    d: weights.dot(&yj),
                    var_ar,
                    unit_flicker,
                },
            ));
        }
    }
    Ok(out)
}
