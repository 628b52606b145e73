//! One condition recorded in several segments: the boots of the device (the recording's
//! `boot` column), between which it restarted, so that each segment's time has an origin of
//! its own and the table's angle at the start of a segment is unknown.
//!
//! The segments are joined into one time line by a shift of each one's ticks, estimated
//! with the rate: the iterated four-parameter fit of [`super::batch::fit_four_param`] with
//! one more unknown per segment after the first, its phase δ_s (a column per segment,
//! ∂y/∂δ_s = A cos α − B sin α on its rows, zero elsewhere). The rate's standard error then
//! comes from within the segments only, as it must: their phases are free. Once joined, a
//! condition is fitted as one record (docs/calibration.md, "A condition in several boots").

use super::batch::{
    fit, mean_over, rate_terms, root_weight, BatchError, FourParamFit, IncrementalQr, Sample,
};
use rotacal_shared::{Aperture, Channel, Model, PhaseStep, TickRate, Ticks};
use std::f64::consts::TAU;

/// Iterations of the joint fit before it gives up.
const MAX_ITER: usize = 50;

/// Points of the first search for each segment's phase.
const GRID: usize = 360;

/// Join the segments of `samples` (each segment's apertures counted from its own first
/// row; `starts` the index of each segment's first sample after the first segment's) into
/// one time line: every segment's ticks are shifted so that the table's phase runs on
/// across the joins, at the rate fitted jointly, and each segment starts one row interval
/// or more after the previous one ends. Returns that rate fit, whose standard error takes
/// the segments' phases as unknown. The starting rate (`nominal`) must be within about
/// 1/(4·span) Hz of the truth, span the longest segment's.
pub fn join(
    samples: &mut [Sample],
    starts: &[usize],
    nominal: PhaseStep,
    clock: TickRate,
) -> Result<FourParamFit, BatchError> {
    let bounds = bounds(samples.len(), starts)?;
    // Each segment's own ticks, kept: the shifts are applied to them afresh each time.
    let own: Vec<Aperture> = samples.iter().map(|(ap, _)| *ap).collect();
    let mut rate = nominal.to_hz(clock);
    let mut offsets = arrange(&own, &bounds, &vec![0.0; bounds.len()], rate, clock)?;
    shift(samples, &own, &bounds, &offsets)?;
    let phases = first_phases(samples, &bounds, nominal, clock)?;
    offsets = turn(samples, (&own, &bounds), &offsets, &phases, rate, clock)?;
    let segments = bounds.len();
    for iter in 1..=MAX_ITER {
        let step = PhaseStep::from_hz(rate, clock).ok_or(BatchError::Singular)?;
        let (first, last) = match (samples.first(), samples.last()) {
            (Some(a), Some(b)) => (a.0.first().0, b.0.last().0),
            _ => return Err(BatchError::TooFewSamples { n: 0, needed: 8 }),
        };
        let t_mid = Ticks(first / 2 + last / 2);
        let ab = sine_ab(&fit(samples, step, clock, Model::SINE, t_mid)?)?;
        // (A, B, C) × 3 channels, δω, then δ_s for each segment after the first.
        let p = 10 + segments - 1;
        let mut joint = IncrementalQr::new(p);
        let mut h = vec![0.0; p];
        for (k, (lo, hi)) in bounds.iter().enumerate() {
            for (ap, y) in samples.get(*lo..*hi).unwrap_or(&[]) {
                let w = root_weight(ap);
                let [s, c, ts, tc] = rate_terms(ap, step, t_mid, clock);
                for ((ch, [a, b]), v) in Channel::ALL.into_iter().zip(ab).zip(y) {
                    h.iter_mut().for_each(|x| *x = 0.0);
                    let col = 3 * ch.index();
                    for (i, x) in [w * s, w * c, w].into_iter().enumerate() {
                        if let Some(slot) = h.get_mut(col + i) {
                            *slot = x;
                        }
                    }
                    if let Some(slot) = h.get_mut(9) {
                        *slot = w * (a * tc - b * ts);
                    }
                    if let Some(slot) = k.checked_sub(1).and_then(|j| h.get_mut(10 + j)) {
                        *slot = w * (a * c - b * s);
                    }
                    joint.push(&h, w * v);
                }
            }
        }
        let joint = joint.solve()?;
        let ch = joint
            .channels
            .first()
            .ok_or(BatchError::Internal("the joint fit has no channel"))?;
        let (dw, se_dw) = match (ch.coef.get(9), ch.se.get(9)) {
            (Some(d), Some(s)) => (*d, *s),
            _ => return Err(BatchError::Internal("the joint fit has no rate column")),
        };
        let deltas: Vec<(f64, f64)> = (10..p)
            .map(|i| match (ch.coef.get(i), ch.se.get(i)) {
                (Some(d), Some(s)) => Ok((*d, *s)),
                _ => Err(BatchError::Internal("the joint fit has no phase column")),
            })
            .collect::<Result<_, _>>()?;
        rate += dw / TAU;
        // The first segment stays.
        let phases: Vec<f64> = std::iter::once(0.0)
            .chain(deltas.iter().map(|(d, _)| *d))
            .collect();
        offsets = turn(samples, (&own, &bounds), &offsets, &phases, rate, clock)?;
        let ticks_per_rad = f64::from(clock.hz()) / (TAU * rate);
        let next = PhaseStep::from_hz(rate, clock).ok_or(BatchError::Singular)?;
        // A tick is the resolution of a shift: a phase step below it cannot be taken.
        let tick_rad = 1.0 / ticks_per_rad;
        let phases_done = deltas
            .iter()
            .all(|(d, s)| d.abs() <= 1e-3 * s || d.abs() < tick_rad);
        if super::batch::converged(dw, se_dw, (step, next), clock) && phases_done {
            return Ok(FourParamFit {
                rate_hz: rate,
                se_rate_hz: se_dw / TAU,
                fit: fit(samples, next, clock, Model::SINE, t_mid)?,
                iterations: iter,
            });
        }
    }
    Err(BatchError::NoConvergence(MAX_ITER))
}

/// Move each segment from `offsets` by its phase in `phases` (a phase δ is δ/ω of time at
/// `rate`), arrange them ([`arrange`]) and shift the samples there: the new offsets.
fn turn(
    samples: &mut [Sample],
    (own, bounds): (&[Aperture], &[(usize, usize)]),
    offsets: &[f64],
    phases: &[f64],
    rate: f64,
    clock: TickRate,
) -> Result<Vec<f64>, BatchError> {
    let ticks_per_rad = f64::from(clock.hz()) / (TAU * rate);
    let wanted: Vec<f64> = offsets
        .iter()
        .zip(phases)
        .map(|(o, d)| o + d * ticks_per_rad)
        .collect();
    let offsets = arrange(own, bounds, &wanted, rate, clock)?;
    shift(samples, own, bounds, &offsets)?;
    Ok(offsets)
}

/// The [lo, hi) index range of each segment: the first from 0, the others from `starts`.
fn bounds(n: usize, starts: &[usize]) -> Result<Vec<(usize, usize)>, BatchError> {
    let mut edges = vec![0];
    edges.extend(starts.iter().copied());
    edges.push(n);
    let out: Vec<(usize, usize)> = edges
        .windows(2)
        .filter_map(|w| match w {
            [a, b] => Some((*a, *b)),
            _ => None,
        })
        .collect();
    if out.iter().any(|(a, b)| b <= a) {
        return Err(BatchError::Internal("an empty segment"));
    }
    Ok(out)
}

/// Each segment's shift, ticks: the first 0; each next one `wanted`, plus or less whole
/// periods at `rate`, to start one of its row intervals or more after the previous one
/// ends (the least such shift).
fn arrange(
    own: &[Aperture],
    bounds: &[(usize, usize)],
    wanted: &[f64],
    rate: f64,
    clock: TickRate,
) -> Result<Vec<f64>, BatchError> {
    let period = f64::from(clock.hz()) / rate;
    let mut out = Vec::with_capacity(bounds.len());
    let mut end = 0.0;
    for (k, ((lo, hi), want)) in bounds.iter().zip(wanted).enumerate() {
        let seg = own.get(*lo..*hi).unwrap_or(&[]);
        let (Some(a), Some(b)) = (seg.first(), seg.last()) else {
            return Err(BatchError::Internal("an empty segment"));
        };
        let (first, last) = (a.first().0 as f64, b.last().0 as f64);
        let interval = ((last - first) / (seg.len().max(2) - 1) as f64).max(1.0);
        let offset = if k == 0 {
            0.0
        } else {
            let least = end + interval - first;
            want + ((least - want) / period).ceil() * period
        };
        end = last + offset;
        out.push(offset);
    }
    Ok(out)
}

/// Apply `offsets` (ticks, rounded) to each segment's own apertures.
fn shift(
    samples: &mut [Sample],
    own: &[Aperture],
    bounds: &[(usize, usize)],
    offsets: &[f64],
) -> Result<(), BatchError> {
    for ((lo, hi), off) in bounds.iter().zip(offsets) {
        if !(0.0..1.8e19).contains(off) {
            return Err(BatchError::Internal("a segment's shift out of range"));
        }
        let off = off.round() as u64;
        let range = samples.get_mut(*lo..*hi).unwrap_or(&mut []);
        for ((ap, _), o) in range.iter_mut().zip(own.get(*lo..*hi).unwrap_or(&[])) {
            *ap = Aperture::new(Ticks(o.first().0.saturating_add(off)), o.gaps())
                .ok_or(BatchError::Internal("a shifted aperture"))?;
        }
    }
    Ok(())
}

/// Each segment's phase behind the longest one's, rad, from a search over the circle: the
/// sine fitted to the longest segment, moved by δ, against each other segment's rows
/// (least squares in δ alone). A first guess for the joint fit, which would otherwise be
/// caught by a wrong minimum half a turn away.
fn first_phases(
    samples: &[Sample],
    bounds: &[(usize, usize)],
    step: PhaseStep,
    clock: TickRate,
) -> Result<Vec<f64>, BatchError> {
    let longest = bounds
        .iter()
        .enumerate()
        .max_by_key(|(_, (lo, hi))| hi - lo)
        .map_or(0, |(k, _)| k);
    let (lo, hi) = bounds.get(longest).copied().unwrap_or((0, 0));
    let reference = fit(
        samples.get(lo..hi).unwrap_or(&[]),
        step,
        clock,
        Model::SINE,
        Ticks(0),
    )?;
    let coef: Vec<[f64; 3]> = reference
        .channels
        .iter()
        .map(|c| match c.coef.as_slice() {
            [a, b, off, ..] => Ok([*a, *b, *off]),
            _ => Err(BatchError::Internal("a sine fit without A, B and C")),
        })
        .collect::<Result<_, _>>()?;
    let mut out = Vec::with_capacity(bounds.len());
    for (lo, hi) in bounds {
        // With ŷ = C + A sin(α + δ) + B cos(α + δ) = C + cos δ·(A s + B c) + sin δ·(A c − B s),
        // the squared error is a quadratic form in (cos δ, sin δ): its sums, once.
        let (mut p, mut q) = ([0.0; 2], [0.0; 3]);
        for (ap, y) in samples.get(*lo..*hi).unwrap_or(&[]) {
            let n = ap.len().max(1) as f64;
            let [s, c] = mean_over(ap, |t| {
                let (s, c) = step.phase_at(t).sin_cos::<f64>();
                [s.hi, c.hi]
            });
            for ([a, b, off], v) in coef.iter().zip(y) {
                let (e1, e2) = (a * s + b * c, a * c - b * s);
                let r = v - off;
                p[0] += n * r * e1;
                p[1] += n * r * e2;
                q[0] += n * e1 * e1;
                q[1] += n * e1 * e2;
                q[2] += n * e2 * e2;
            }
        }
        let cost = |d: f64| {
            let (cd, sd) = (d.cos(), d.sin());
            q[0] * cd * cd + 2.0 * q[1] * cd * sd + q[2] * sd * sd - 2.0 * (p[0] * cd + p[1] * sd)
        };
        let best = (0..GRID)
            .map(|i| TAU * i as f64 / GRID as f64)
            .min_by(|a, b| cost(*a).total_cmp(&cost(*b)))
            .unwrap_or(0.0);
        out.push(best);
    }
    // Relative to the first segment, which stays where it is.
    let first = out.first().copied().unwrap_or(0.0);
    Ok(out.iter().map(|d| d - first).collect())
}

/// A and B of each channel of a sine fit.
fn sine_ab(f: &super::batch::BatchFit) -> Result<[[f64; 2]; 3], BatchError> {
    let ab = |k: usize| match f.channels.get(k).map(|c| c.coef.as_slice()) {
        Some([a, b, ..]) => Ok([*a, *b]),
        _ => Err(BatchError::Internal("a sine fit without A and B")),
    };
    Ok([ab(0)?, ab(1)?, ab(2)?])
}

#[cfg(test)]
#[allow(clippy::indexing_slicing)]
mod tests {
    use super::*;

    const CLOCK: TickRate = TickRate::MHZ_1;

    /// Noise-free rows at 16 Hz of a sine at `rate` Hz, cut at row `cut` with `lost` rows
    /// dropped, the rows after it timed from their own first: (samples, start of boot 1).
    fn two_boots(rate: f64, n: usize, cut: usize, lost: usize) -> (Vec<Sample>, usize) {
        let y = |t_s: f64| {
            let a = TAU * rate * t_s + 0.7;
            [
                100.0 + 9000.0 * a.sin() + 500.0 * a.cos(),
                -40.0 - 300.0 * a.sin() + 9100.0 * a.cos(),
                7.0 + 80.0 * a.sin() - 20.0 * a.cos(),
            ]
        };
        let mut out = Vec::new();
        for i in (0..n).filter(|i| *i < cut || *i >= cut + lost) {
            let t_s = i as f64 / 16.0;
            let own = if i < cut {
                t_s
            } else {
                t_s - (cut + lost) as f64 / 16.0
            };
            let ticks = (own * 1e6).round() as u64;
            out.push((Aperture::point(Ticks(ticks)), y(t_s)));
        }
        (out, cut)
    }

    #[test]
    fn joined_boots_are_one_sine_at_the_true_rate() {
        for (truth, nominal) in [(0.01, 0.01), (0.01 * (1.0 + 3e-4), 0.01), (0.5, 0.5)] {
            let (mut s, cut) = two_boots(truth, 4200, 1700, 80);
            let step = PhaseStep::from_hz(nominal, CLOCK).unwrap();
            let f = join(&mut s, &[cut], step, CLOCK).unwrap();
            assert!(
                ((f.rate_hz - truth) / truth).abs() < 1e-9,
                "rate {} for {truth}",
                f.rate_hz
            );
            // Boot 1 starts after boot 0 ends, and one sine fits both to rounding.
            assert!(s[cut].0.first().0 > s[cut - 1].0.first().0);
            for ch in &f.fit.channels {
                let rms = (ch.rss / s.len() as f64).sqrt();
                assert!(rms < 1e-3, "rms {rms} counts at {truth} Hz");
            }
        }
    }

    #[test]
    fn an_empty_boot_is_refused() {
        let (mut s, cut) = two_boots(0.01, 400, 200, 0);
        let step = PhaseStep::from_hz(0.01, CLOCK).unwrap();
        assert!(matches!(
            join(&mut s, &[cut, cut], step, CLOCK),
            Err(BatchError::Internal(_))
        ));
    }
}
