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
//! change, exactly for its line ([`unit_flicker_quadratic`]; the shape matters, as
//! intervals differ in length). λ is estimated from the changes themselves: the smallest
//! λ ≥ 0 at which the median of d_i²/var d_i over the channel's intervals is the median of
//! χ²₁. The median, because some intervals did move: up to half of them may, and λ does
//! not see them. Over a few seconds flicker and a random walk look alike, and the
//! residuals' Allan variances of such short intervals cannot tell either from the
//! short-range correlation (tried: the levels came out below zero as often as not), so
//! one term, fitted to the statistic the test uses, stands for both.
//!
//! The same λ, where the changes demand one, gives the offsets a term for the bias's
//! wander over the session ([`session_wander`]): a fit's offset is the bias averaged over
//! its poses, not the bias at any one time.

use super::bisect::bracket;
use super::still::{self, Interval, Verdict};
use crate::allan::powerlaw::flicker_structure;
use crate::fit::noise::unit_flicker_quadratic;
use nalgebra::DVector;
use rotacal_shared::Channel;

/// Fewest readings of an interval for it to enter.
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

/// The moved test again for `intervals` of a segment (times `t_s`), each change (as
/// `still` measured it) with its variance widened by the flicker level estimated from the changes. Intervals
/// under [`MIN_ROWS`] readings, or left out for another reason, keep their verdict; so do
/// all of them with fewer than [`MIN_INTERVALS`] to estimate from. Gives each channel's
/// level (`None` when not estimated).
pub fn retest(t_s: &[f64], intervals: &mut [Interval]) -> [Option<Level>; 3] {
    let mut changes: [Vec<Change>; 3] = Default::default();
    for (index, iv) in intervals.iter().enumerate() {
        let open = matches!(iv.verdict, Verdict::Kept | Verdict::Moved { .. });
        if open && iv.n >= MIN_ROWS {
            for (ch, c) in line_changes(index, t_s, iv) {
                ch.of_mut(&mut changes).push(c);
            }
        }
    }
    let mut levels = [None; 3];
    let mut z_max: Vec<Option<(f64, [f64; 3])>> = vec![None; intervals.len()];
    for ch in Channel::ALL {
        let list = ch.of(&changes);
        if list.len() < MIN_INTERVALS {
            return [None; 3];
        }
        let found = level(list);
        let lambda = found.lambda;
        *ch.of_mut(&mut levels) = Some(found);
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
    levels
}

/// A channel's flicker level from its intervals' changes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Level {
    /// λ, output units² per reading (Kasdin's innovation Q).
    pub lambda: f64,
    /// The intervals it came from.
    pub intervals: usize,
    /// Whether the changes demand it: their median z² under the AR model alone exceeds
    /// χ²₁'s median by more than two of its standard errors, √(1.1265/n).
    pub demanded: bool,
}

/// The smallest λ ≥ 0 at which the median of d²/(v + λf) is at most χ²₁'s median, and
/// whether λ = 0 is more than two standard errors of the median away from it.
fn level(list: &[Change]) -> Level {
    let n = list.len();
    let median = |lambda: f64| {
        let mut r: Vec<f64> = list
            .iter()
            .map(|c| c.d * c.d / (c.var_ar + lambda * c.unit_flicker))
            .collect();
        r.sort_by(f64::total_cmp);
        r.get(r.len() / 2).copied().unwrap_or(0.0)
    };
    let at_zero = median(0.0);
    let demanded = at_zero > CHI2_1_MEDIAN + 2.0 * (1.1265 / n.max(1) as f64).sqrt();
    if at_zero <= CHI2_1_MEDIAN {
        return Level {
            lambda: 0.0,
            intervals: n,
            demanded,
        };
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
    Level {
        lambda: hi,
        intervals: n,
        demanded,
    }
}

/// Each channel's change over an interval (rows `lo..hi` of times `t_s`) as the moved test
/// measured it, with the variance unit flicker gives it under the same line.
fn line_changes(index: usize, t_s: &[f64], iv: &Interval) -> Vec<(Channel, Change)> {
    let Some(times) = t_s.get(iv.rows.0..iv.rows.1) else {
        return Vec::new();
    };
    let h = still::line_design(times);
    let Some(inv) = h.tr_mul(&h).try_inverse() else {
        return Vec::new();
    };
    let weights: DVector<f64> = (&h * inv).column(1) * 2.0;
    let unit_flicker = unit_flicker_quadratic(&weights);
    Channel::ALL
        .into_iter()
        .zip(iv.change)
        .filter_map(|(ch, tested)| {
            let t = tested?;
            (t.var_ar.is_finite() && t.var_ar > 0.0).then_some((
                ch,
                Change {
                    index,
                    d: t.d,
                    var_ar: t.var_ar,
                    unit_flicker,
                },
            ))
        })
        .collect()
}

/// How many times of the session the bias's wander about its mean is averaged over.
const WANDER_GRID: usize = 64;

/// The variance unit flicker gives the bias at a time of the session about the mean of the
/// poses' biases (the offset a fit measures): Var(b(t) − b̄), b̄ the mean over the poses at
/// sample indices `poses` (their middles), averaged over `WANDER_GRID` times spread evenly
/// from sample `first` to `last`. From the generalised covariance: (1/P)·Σ_i D(|t − t_i|) −
/// (1/2P²)·Σ_ik D(|t_i − t_k|), D the structure function.
pub fn session_wander(poses: &[f64], (first, last): (f64, f64)) -> f64 {
    let p = poses.len() as f64;
    if poses.is_empty() || last.is_nan() || first.is_nan() || last < first {
        return f64::NAN;
    }
    let d = |a: f64, b: f64| flicker_structure((a - b).abs().round() as u64);
    let within: f64 = poses
        .iter()
        .map(|a| poses.iter().map(|b| d(*a, *b)).sum::<f64>())
        .sum::<f64>()
        / (2.0 * p * p);
    let grid =
        (0..WANDER_GRID).map(|g| first + (last - first) * g as f64 / (WANDER_GRID - 1) as f64);
    grid.map(|t| poses.iter().map(|a| d(t, *a)).sum::<f64>() / p - within)
        .sum::<f64>()
        / WANDER_GRID as f64
}

/// The degrees of freedom of λ from `n` intervals: the median of n χ²₁ values has variance
/// 1/(4n·f²), f = 0.4711 the χ²₁ density at its median 0.4549, so λ (where the flicker
/// term dominates a change's variance) has relative variance 5.44/n, which is 2/ν.
pub fn level_dof(n: usize) -> f64 {
    const F: f64 = 0.471_1;
    let rel = 1.0 / (4.0 * F * F * CHI2_1_MEDIAN * CHI2_1_MEDIAN);
    2.0 * n as f64 / rel
}

#[cfg(test)]
#[allow(clippy::indexing_slicing)]
mod tests {
    use super::*;
    use crate::allan::powerlaw::flicker_increments;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    /// The wander against simulated unit flicker (a Kasdin path from its increments): over
    /// 3000 paths, Var(b(t) − b̄) averaged over the grid, within 4 of its standard errors.
    #[test]
    fn session_wander_matches_simulated_flicker() {
        let n = 4000;
        let poses: Vec<f64> = (0..12).map(|i| 150.0 + 320.0 * f64::from(i)).collect();
        let expected = session_wander(&poses, (0.0, (n - 1) as f64));
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let grid: Vec<usize> = (0..WANDER_GRID)
            .map(|g| ((n - 1) as f64 * g as f64 / (WANDER_GRID - 1) as f64).round() as usize)
            .collect();
        let draws: Vec<f64> = (0..3000)
            .map(|_| {
                let inc = flicker_increments(n - 1, &mut rng);
                let mut b = vec![0.0; n];
                for t in 1..n {
                    b[t] = b[t - 1] + inc[t - 1];
                }
                let mean = poses.iter().map(|p| b[*p as usize]).sum::<f64>() / poses.len() as f64;
                grid.iter().map(|&t| (b[t] - mean).powi(2)).sum::<f64>() / grid.len() as f64
            })
            .collect();
        let m = draws.iter().sum::<f64>() / draws.len() as f64;
        let sd =
            (draws.iter().map(|d| (d - m).powi(2)).sum::<f64>() / (draws.len() - 1) as f64).sqrt();
        let se = sd / (draws.len() as f64).sqrt();
        println!("wander: simulated {m:.4} ± {se:.4}, computed {expected:.4}");
        assert!((m - expected).abs() < 4.0 * se, "{m} ± {se} vs {expected}");
    }
}
