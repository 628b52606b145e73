//! The discrepancy workflow's terminal summary and its report folder (Markdown and SVG:
//! residuals and their spectrum at k·ω before and after the named effects).

use crate::discrepancy::{Analysis, Criterion, RateIntrinsic};
use crate::report::{self, ReportError, Series};
use rotacal_shared::Channel;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

fn value(v: &serde_json::Value) -> String {
    match (v.get("value"), v.get("expanded_unc")) {
        (Some(x), Some(u)) => {
            // k is 2 unless the slow noise left few degrees of freedom.
            let k = v
                .get("k")
                .and_then(serde_json::Value::as_f64)
                .unwrap_or(2.0);
            format!(
                "{:.4e} ± {:.1e}{}",
                x.as_f64().unwrap_or(f64::NAN),
                u.as_f64().unwrap_or(f64::NAN),
                if (k - 2.0).abs() > 1e-9 {
                    format!(" (k = {k:.2})")
                } else {
                    String::new()
                }
            )
        }
        _ => match v {
            serde_json::Value::Object(m) => m
                .iter()
                .map(|(k, v)| format!("{k} {}", value(v)))
                .collect::<Vec<_>>()
                .join(", "),
            other => other.to_string(),
        },
    }
}

fn params(p: &std::collections::BTreeMap<String, serde_json::Value>) -> String {
    p.iter()
        .map(|(k, v)| format!("{k}: {}", value(v)))
        .collect::<Vec<_>>()
        .join("; ")
}

fn test(c: &Criterion) -> String {
    let slow = c.slow_share.map_or(String::new(), |share| {
        format!(
            "; {}, slow noise {:.0} % of the variance",
            c.test,
            100.0 * share
        )
    });
    format!(
        "F = {:.1} (k = {}, p = {:.1e}, ΔBIC = {:.0}{slow})",
        c.f, c.k, c.p_value, c.delta_bic
    )
}

fn moved(before: &[RateIntrinsic], after: &[RateIntrinsic], o: &mut String) {
    let names = crate::calibrate::json::PROPERTY_NAMES;
    for (b, a) in before.iter().zip(after) {
        let _ = writeln!(o, "  at {} Hz:", b.rate_hz);
        let bq = b.sensitivity.iter().chain(&b.angle_deg);
        let aq = a.sensitivity.iter().chain(&a.angle_deg);
        for ((name, x), y) in names.iter().zip(bq).zip(aq) {
            let shift = y.value - x.value;
            let _ = writeln!(
                o,
                "    {name:<5} {:>14.5} → {:>14.5} ± {:.5} (moved {:+.5}, {:+.1} U)",
                x.value,
                y.value,
                y.expanded_unc,
                shift,
                shift / y.expanded_unc
            );
        }
    }
}

/// The terminal summary.
pub fn render(a: &Analysis) -> String {
    let mut o = String::new();
    let n = &a.noise_sigma;
    let _ = writeln!(
        o,
        "Noise sd: u {:.3}, v {:.3}, w {:.3} ({})",
        n.u, n.v, n.w, n.source
    );
    for ch in Channel::ALL {
        let ms: Vec<_> = a.noise_model.iter().filter(|m| m.channel == ch).collect();
        let lag1 = ms
            .iter()
            .map(|m| m.lag1_autocorrelation)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
                (lo.min(x), hi.max(x))
            });
        let order = ms.iter().map(|m| m.ar.len()).max().unwrap_or(0);
        let excluded: usize = ms.iter().map(|m| m.n_excluded).sum();
        let _ = writeln!(
            o,
            "  {}: {} groups, AR order up to {order}, lag-1 autocorrelation {:.3} to {:.3}, \
             {excluded} readings at a rail left out",
            ch.letter(),
            ms.len(),
            lag1.0,
            lag1.1
        );
    }
    if let Some(s) = &a.noise_sigma_stated {
        let _ = writeln!(
            o,
            "The file states noise_sigma = {} (not used): {}",
            s.stated,
            if s.contradicted {
                format!("the data contradict it: {}", s.why)
            } else {
                "the data agree with it".to_string()
            }
        );
    }
    if let Some(slow) = &a.slow_noise {
        let _ = writeln!(
            o,
            "Slow noise (--slow-noise), counted in every test but saturation's: flicker's \
             Allan variance (floor²) and the walk's K², ± standard uncertainty:"
        );
        let term = |e: &crate::discrepancy::slow::Estimate| format!("{:.4} ± {:.4}", e.value, e.u);
        for c in slow {
            let _ = writeln!(
                o,
                "  {}: flicker {} (output units²), walk {} (output units²/s)",
                c.channel.letter(),
                term(&c.flicker_allan_variance),
                term(&c.random_walk_k2)
            );
        }
    }
    let _ = writeln!(
        o,
        "Baseline (3-parameter sines at the nominal rate, constant offsets): χ²/dof {:.3}, \
         residual RMS {:.3}",
        a.baseline.chi2_dof, a.baseline.rms_residual
    );
    if !a.findings.is_empty() {
        let _ = writeln!(
            o,
            "Where the baseline disagrees (z > {}, largest first):",
            crate::discrepancy::locate::Z_LIST
        );
        for f in a.findings.iter().take(10) {
            let _ = writeln!(o, "  {}: {} {:.4} (z = {:.0})", f.at, f.what, f.size, f.z);
        }
    }
    for (i, s) in a.steps.iter().enumerate() {
        let _ = writeln!(
            o,
            "Step {}: {} named, {}; χ²/dof {:.3}, RMS {:.3}",
            i + 1,
            s.effect,
            test(&s.criterion),
            s.chi2_dof,
            s.rms_residual
        );
    }
    if a.steps.is_empty() {
        let _ = writeln!(
            o,
            "No effect of the catalogue beyond the baseline is demanded by the data{}",
            if a.verdict.explained {
                "."
            } else {
                "; they are not explained (the verdict, below)."
            }
        );
    }
    let _ = writeln!(
        o,
        "Not demanded (p ≥ {}): {}",
        a.alpha,
        a.last_candidates
            .iter()
            .map(|c| format!("{} p = {:.2}", c.effect, c.p_value))
            .collect::<Vec<_>>()
            .join(", ")
    );
    for (e, why) in &a.untestable {
        let _ = writeln!(o, "Not testable here: {e}: {why}");
    }
    let slow = a.slow_noise.is_some();
    for (e, p) in &a.final_parameters {
        let _ = writeln!(
            o,
            "{e} (final model, ± U{}): {}",
            if slow {
                ", slow noise included, k = 2 unless given"
            } else {
                " k = 2"
            },
            params(p)
        );
    }
    if slow {
        let _ = writeln!(
            o,
            "Final: χ²/dof {:.3}, residual RMS {:.3}; the AR whitening leaves the slow noise \
             in, so χ²/dof is not compared with 1 ± {:.3} under --slow-noise",
            a.final_.chi2_dof,
            a.final_.rms_residual,
            3.0 * (2.0 / a.final_.dof).sqrt()
        );
    } else {
        let _ = writeln!(
            o,
            "Final: χ²/dof {:.3} (expected 1 ± {:.3}), residual RMS {:.3}",
            a.final_.chi2_dof,
            3.0 * (2.0 / a.final_.dof).sqrt(),
            a.final_.rms_residual
        );
    }
    if !a.steps.is_empty() {
        let _ = writeln!(
            o,
            "Intrinsic properties, baseline → final model (± U, k = 2{}):",
            if slow {
                "; from the AR model alone, without the slow noise: \
                 `rotacal calibrate --slow-noise` gives them with it"
            } else {
                ""
            }
        );
        moved(&a.intrinsic_baseline, &a.intrinsic_final, &mut o);
        for c in &a.confirmation {
            let _ = writeln!(
                o,
                "{} {}: {}",
                if c.confirmed {
                    "Confirmed:"
                } else {
                    "Candidate, not confirmed:"
                },
                c.effect,
                c.reason
            );
        }
        if a.confirmed_effects.len() < a.steps.len() {
            let why = if a.verdict.explained {
                "they fail the halves' checks above"
            } else {
                "the data are not explained, so the tests that named them assumed a model \
                 the data reject"
            };
            let _ = writeln!(
                o,
                "Not confirmed: {} (candidates: {why}); the result applies no correction for \
                 them: its properties are {}.",
                a.steps
                    .iter()
                    .map(|s| s.effect.as_str())
                    .filter(|e| !a.confirmed_effects.iter().any(|c| c == e))
                    .collect::<Vec<_>>()
                    .join(", "),
                if a.confirmed_effects.is_empty() {
                    "the baseline's above"
                } else {
                    "those of the confirmed effects' model (JSON intrinsic_confirmed)"
                }
            );
        }
    }
    verdict(a, &mut o);
    o
}

/// The verdict and, when the data are not explained, where (at most ten places).
fn verdict(a: &Analysis, o: &mut String) {
    let v = &a.verdict;
    let _ = writeln!(o, "Verdict: {}", v.summary);
    if v.unexplained.is_empty() {
        return;
    }
    let _ = writeln!(
        o,
        "Not explained (size in output units, in noise sd, and z; largest first{}):",
        if v.unexplained.len() > 10 {
            format!(", 10 of {}", v.unexplained.len())
        } else {
            String::new()
        }
    );
    for u in v.unexplained.iter().take(10) {
        let _ = writeln!(
            o,
            "  {}: {}, {:.4} ({:.2} sd, z = {:.1})",
            u.at, u.what, u.size, u.size_in_sd, u.z
        );
    }
}

fn series(a: &Analysis, gi: usize, fit: usize, label: &str) -> Option<Series> {
    let g = a.data.groups.get(gi)?;
    let f = a.fits.get(fit)?;
    let r = Channel::ALL.map(|ch| f.residuals(&a.data, gi, ch));
    let mut s = Series::new(
        format!("{} at {} Hz, {label}", g.condition.letter(), g.rate_hz),
        format!(
            "{}_{}mhz_{label}",
            g.condition.letter(),
            (g.rate_hz * 1e3).round()
        ),
        "time in condition (s)",
        true,
    );
    // Every row has its readings and residuals (the fit's residuals are of each reading).
    let [yu, yv, yw] = &g.y;
    let [ru, rv, rw] = &r;
    let readings = yu.iter().zip(yv).zip(yw);
    let residuals = ru.iter().zip(rv).zip(rw);
    for (t, (((&u, &v), &w), ((&eu, &ev), &ew))) in g.tau.iter().zip(readings.zip(residuals)) {
        s.add(*t, g.omega() * t, [u, v, w], [u - eu, v - ev, w - ew]);
    }
    Some(s)
}

/// Write `dir/discrepancy.md` and its plots; returns the Markdown's path.
pub fn write(a: &Analysis, dir: &Path, units: &str) -> Result<PathBuf, ReportError> {
    let io = |e: std::io::Error| ReportError::Write(format!("{}: {e}", dir.display()));
    std::fs::create_dir_all(dir).map_err(io)?;
    let mut md = String::from("# Model discrepancy\n\n```text\n");
    md.push_str(&render(a));
    md.push_str("```\n\n## Residuals before and after\n\n");
    let last = a.fits.len().saturating_sub(1);
    // The three groups where the baseline misses most.
    let mut order: Vec<(f64, usize)> = a
        .fits
        .first()
        .map(|f| {
            (0..a.data.groups.len())
                .map(|gi| {
                    let r = Channel::ALL.map(|ch| f.residuals(&a.data, gi, ch));
                    let n = r.iter().map(Vec::len).sum::<usize>().max(1);
                    (
                        r.iter().flatten().map(|x| x * x).sum::<f64>() / n as f64,
                        gi,
                    )
                })
                .collect()
        })
        .unwrap_or_default();
    order.sort_by(|x, y| y.0.total_cmp(&x.0));
    for gi in order.into_iter().map(|(_, gi)| gi).take(3) {
        for (fit, label) in [(0, "baseline"), (last, "final")] {
            let Some(s) = series(a, gi, fit, label) else {
                continue;
            };
            let res = dir.join(format!("residuals_{}.svg", s.stem));
            report::plot_residuals(&s, &res, units)?;
            let amps = s.amplitudes();
            let spec = dir.join(format!("spectrum_{}.svg", s.stem));
            report::plot_spectrum(&s, &amps, &spec, units)?;
            let name = |p: &Path| {
                p.file_name()
                    .map_or(String::new(), |n| n.to_string_lossy().into_owned())
            };
            let _ = writeln!(
                md,
                "![{}]({})\n![{}]({})\n",
                s.title,
                name(&res),
                s.title,
                name(&spec)
            );
        }
    }
    let path = dir.join("discrepancy.md");
    crate::atomic::write(&path, md).map_err(io)?;
    Ok(path)
}
