//! Plausibility: what a calibration's numbers, or a file's rows, say about a mistake in its
//! description. The units: sensitivities near 1/g per m/s² are readings in g, near 1 in
//! m/s², whatever `units` says. The rate: each condition's dominant frequency, from its
//! rows, against the nominal rate a fit failed at. Each hint is a sentence computed from
//! the numbers it names (docs/calibration.md, "Plausibility").

use super::json::CalibrationJson;
use crate::recording::Recording;
use std::f64::consts::TAU;

/// How far a ratio may be from 1 and still be taken for it: a MEMS sensitivity is within
/// a few percent of nominal, a wrong unit a factor of g (9.8) or more away.
const NEAR: f64 = 0.25;

fn near_one(r: f64) -> bool {
    (r - 1.0).abs() <= NEAR
}

/// A hint when the sensitivities contradict the recording's `units`: readings whose
/// sensitivities are about 1/g_loc per m/s² are in g; about 1, in m/s².
pub fn units(cal: &CalibrationJson) -> Option<String> {
    let s: Vec<f64> = cal
        .by_rate
        .iter()
        .flat_map(|r| {
            let s = &r.intrinsic.sensitivity;
            [s.u.value, s.v.value, s.w.value]
        })
        .map(f64::abs)
        .collect();
    if s.is_empty() {
        return None;
    }
    let mean = s.iter().sum::<f64>() / s.len() as f64;
    let g = cal.g_loc;
    let label = cal.units.trim().to_ascii_lowercase().replace(' ', "");
    let says_g = label == "g";
    let says_ms2 = matches!(label.as_str(), "m/s^2" | "m/s2" | "m/s²" | "ms^-2");
    let like_g = s.iter().all(|x| near_one(x * g));
    let like_ms2 = s.iter().all(|x| near_one(*x));
    let head = format!(
        "the sensitivities (mean {mean:.4} {} per m/s²)",
        if cal.units.is_empty() {
            "units"
        } else {
            &cal.units
        }
    );
    if like_g && !says_g {
        Some(format!(
            "{head} are about 1/g_loc = {:.4}: the readings look like g, not {}; if so, \
             set units=g (import --units g, or the file's '# units=')",
            1.0 / g,
            shown(&cal.units)
        ))
    } else if like_ms2 && !says_ms2 {
        Some(format!(
            "{head} are about 1: the readings look like m/s², not {}; if so, set \
             units=m/s^2",
            shown(&cal.units)
        ))
    } else if (says_g && !like_g) || (says_ms2 && !like_ms2) {
        let want = if says_g { 1.0 / g } else { 1.0 };
        Some(format!(
            "{head} are {:.3} times what readings in {} would give ({want:.4}): check the \
             units, or the scale the readings were imported with (import --scale)",
            mean / want,
            cal.units
        ))
    } else {
        None
    }
}

fn shown(units: &str) -> String {
    if units.is_empty() {
        "unlabelled".into()
    } else {
        format!("'{units}'")
    }
}

/// The frequency with the most power in `y` sampled at `t` (seconds), between 0.4 and
/// 400 cycles over the record: a grid of an eighth of a cycle over the record, then the
/// peak refined by halving the step. `None` for a record too short to say.
pub fn dominant_hz(t: &[f64], y: &[f64]) -> Option<f64> {
    let (first, last) = (t.first()?, t.last()?);
    let span = last - first;
    if t.len() < 8 || t.len() != y.len() || span.is_nan() || span <= 0.0 {
        return None;
    }
    let mean = y.iter().sum::<f64>() / y.len() as f64;
    let power = |f: f64| {
        let (mut c, mut s) = (0.0, 0.0);
        for (ti, yi) in t.iter().zip(y) {
            let a = TAU * f * (ti - first);
            c += (yi - mean) * a.cos();
            s += (yi - mean) * a.sin();
        }
        c * c + s * s
    };
    // Not beyond the rows' own Nyquist frequency.
    let nyquist = 0.5 * (t.len() - 1) as f64 / span;
    let step = 1.0 / (8.0 * span);
    let top = (400.0 / span).min(nyquist);
    let mut best = (0.0, f64::NEG_INFINITY);
    let mut f = 0.4 / span;
    while f <= top {
        let p = power(f);
        if p > best.1 {
            best = (f, p);
        }
        f += step;
    }
    let (mut f, mut p) = best;
    let mut h = step / 2.0;
    while h > step / 256.0 {
        for g in [f - h, f + h] {
            let q = power(g);
            if q > p {
                (f, p) = (g, q);
            }
        }
        h /= 2.0;
    }
    (p.is_finite() && f > 0.0).then_some(f)
}

/// A hint when the rows of a rotation recording turn at a rate other than `nominal_hz`
/// (each condition's strongest channel's dominant frequency more than 10 % away).
pub fn rate(rec: &Recording, nominal_hz: f64) -> Option<String> {
    // (frequency as shown, the conditions that show it)
    let mut seen: Vec<(String, Vec<char>)> = Vec::new();
    for g in &rec.groups {
        let nominal = g.rate_hz.unwrap_or(nominal_hz);
        let spread = |y: &[f64]| {
            let m = y.iter().sum::<f64>() / y.len().max(1) as f64;
            y.iter().map(|v| (v - m).powi(2)).sum::<f64>()
        };
        let y = [&g.u, &g.v, &g.w]
            .into_iter()
            .max_by(|a, b| spread(a).total_cmp(&spread(b)))?;
        let f = dominant_hz(&g.t_s, y)?;
        if (f / nominal - 1.0).abs() > 0.1 {
            let shown = significant(f);
            match seen.iter_mut().find(|(s, _)| *s == shown) {
                Some((_, c)) => c.push(g.condition.letter()),
                None => seen.push((shown, vec![g.condition.letter()])),
            }
        }
    }
    (!seen.is_empty()).then(|| {
        let said: Vec<String> = seen
            .iter()
            .map(|(f, c)| {
                let c: Vec<String> = c.iter().map(char::to_string).collect();
                let s = if c.len() > 1 { "s" } else { "" };
                format!("{f} Hz (condition{s} {})", c.join(", "))
            })
            .collect();
        format!(
            "the data look like {}, not the nominal {} Hz: check --rate-hz or the file's \
             rate_hz",
            said.join("; "),
            significant(nominal_hz)
        )
    })
}

/// [`rate`] for the rotation recording at `path` calibrated with `opts`, at the nominal
/// rate the options or the file give; `None` when it is not a rotation recording that
/// reads, or its rows agree with the rate.
pub fn rate_of_file(path: &std::path::Path, opts: &super::Options) -> Option<String> {
    let rec = crate::recording::read_as(path, opts.method).ok()?;
    if rec.method != crate::recording::Method::Rotation {
        return None;
    }
    let nominal = opts.rate_hz.or(rec.meta.rate_hz)?;
    rate(&rec, nominal)
}

/// `x` to three significant figures.
fn significant(x: f64) -> String {
    let digits = (2 - x.abs().log10().floor() as i32).max(0) as usize;
    format!("{x:.digits$}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_dominant_frequency_of_a_short_noisy_sine() {
        // 2.6 periods of 0.01 Hz at 16 Hz, with an offset and a second channel's worth of
        // deterministic "noise".
        let t: Vec<f64> = (0..4160).map(|i| 3.0 + i as f64 / 16.0).collect();
        let y: Vec<f64> = t
            .iter()
            .enumerate()
            .map(|(i, t)| 100.0 + 50.0 * (TAU * 0.01 * t + 0.3).sin() + ((i * 7919) % 13) as f64)
            .collect();
        let f = dominant_hz(&t, &y).unwrap();
        assert!((f / 0.01 - 1.0).abs() < 0.05, "{f}");
        assert_eq!(significant(f), "0.0100");
        assert_eq!(significant(0.02), "0.0200");
        assert_eq!(significant(12.345), "12.3");
    }
}
