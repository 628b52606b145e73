//! `rotacal allan`: the overlapping Allan deviation of each still record and channel, its
//! 1σ intervals and the fitted IEEE noise terms (docs/allan.md).

use std::fmt::Write as _;
use std::path::PathBuf;

use rotacal::allan::analysis::AllanJson as Out;
use rotacal::allan::{Fit, TermKind};

/// `rotacal allan` arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The recording CSV (rotacal help formats); each condition, pose or free series is one
    /// record, sampled uniformly (a gap is an error).
    pub file: PathBuf,
    /// Write the numbers as JSON (rotacal help formats, "Allan JSON") here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write a log-log plot (SVG) here.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Use only samples at t_s ≥ this, seconds (device time; without t_s, from the start).
    #[arg(long)]
    pub from: Option<f64>,
    /// Use only samples at t_s ≤ this, seconds.
    #[arg(long)]
    pub to: Option<f64>,
}

/// Run it.
pub fn run(a: Args) -> anyhow::Result<()> {
    let name = a.file.display().to_string();
    if let (Some(f), Some(t)) = (a.from, a.to) {
        if f > t {
            anyhow::bail!("{name}: --from {f} is after --to {t}");
        }
    }
    let rec = rotacal::recording::read(&a.file)?;
    let out = rotacal::allan::analysis::analyse(&rec, &name, a.from, a.to)?;
    rotacal::output::emit(&render(&out))?;
    if let Some(path) = &a.json {
        let trace =
            rotacal::trace::Traceability::of_recording(rotacal::BUILD, &a.file, None, None, None)?;
        rotacal::atomic::write(path, trace.json(&out)?)?;
    }
    if let Some(path) = &a.plot {
        let panels: Vec<rotacal::report::allan::Panel<'_>> = out
            .groups
            .iter()
            .flat_map(|g| {
                g.channels.iter().map(|c| rotacal::report::allan::Panel {
                    title: format!("{}, {}", g.name, c.channel),
                    points: &c.points,
                    fit: c.terms.as_ref(),
                    rate_hz: g.rate_hz,
                })
            })
            .collect();
        rotacal::report::allan::write(&panels, path, &out.scale.units)?;
    }
    Ok(())
}

/// The tables and terms as text.
fn render(out: &Out) -> String {
    let u = &out.scale.units;
    let mut s = String::new();
    let _ = match out.scale.micro_g_per_unit {
        Some(f) => writeln!(s, "{}: results in µg ({f} µg per file unit)", out.file),
        None => writeln!(
            s,
            "{}: results in {u} (the file's units; it gives no sensitivity to convert to µg)",
            out.file
        ),
    };
    if out.method == rotacal::recording::Method::Rotation {
        let _ = writeln!(
            s,
            "note: method=rotation: these records turn, so each deviation includes the rotation signal, not only noise"
        );
    }
    for g in &out.groups {
        for c in &g.channels {
            let _ = writeln!(
                s,
                "\n{}, channel {}: {} samples at {:.6} Hz, mean {:.6e} {u}",
                g.name, c.channel, g.samples, g.rate_hz, c.mean
            );
            let _ = writeln!(
                s,
                "  {:>12} {:>8} {:>8} {:>12} {:>12} {:>12} {:>3} {:>9}",
                "τ s", "m", "n", "ADEV", "1σ lo", "1σ hi", "α", "edf"
            );
            for p in &c.points {
                let _ = match p.interval {
                    Some(i) => writeln!(
                        s,
                        "  {:>12.6} {:>8} {:>8} {:>12.5e} {:>12.5e} {:>12.5e} {:>3} {:>9.1}",
                        p.tau_s, p.m, p.n, p.adev, i.lo, i.hi, i.alpha, i.edf
                    ),
                    None => writeln!(
                        s,
                        "  {:>12.6} {:>8} {:>8} {:>12.5e} {:>12} {:>12} {:>3} {:>9}",
                        p.tau_s, p.m, p.n, p.adev, "-", "-", "-", "-"
                    ),
                };
            }
            match (&c.terms, &c.terms_error) {
                (Some(f), _) => render_terms(&mut s, f, c.noise_density_one_sided, u),
                (None, Some(e)) => {
                    let _ = writeln!(s, "  terms: not fitted: {e}");
                }
                (None, None) => {}
            }
        }
    }
    s
}

fn render_terms(s: &mut String, f: &Fit, nd: Option<f64>, u: &str) {
    let _ = writeln!(
        s,
        "  terms (weighted least squares on {} octave points, {} iterations, reduced χ² {:.2}):",
        f.points, f.iterations, f.reduced_chi2
    );
    let pm = |v: f64, se: Option<f64>| match se {
        Some(e) => format!("{v:.4e} ± {e:.2e}"),
        None => format!("{v:.4e}"),
    };
    for t in &f.terms {
        if !t.resolved {
            let _ = writeln!(
                s,
                "    {:<12} not resolved: its unconstrained estimate was negative, set to 0",
                match t.kind {
                    TermKind::White => "white",
                    TermKind::Flicker => "flicker",
                    TermKind::RandomWalk => "random walk",
                }
            );
            continue;
        }
        let _ = match t.kind {
            TermKind::White => writeln!(
                s,
                "    white        N = {} {u}/√Hz (two-sided, = σ(1 s)); one-sided density √h0 = {} {u}/√Hz; h0 = {} {u}²/Hz",
                pm(t.ieee, t.ieee_se),
                nd.map_or("-".to_string(), |v| format!("{v:.4e}")),
                pm(t.h, t.h_se)
            ),
            TermKind::Flicker => writeln!(
                s,
                "    flicker      B = {} {u} (floor 0.6643·B = {:.4e} {u}); h-1 = {} {u}²",
                pm(t.ieee, t.ieee_se),
                f.flicker_floor,
                pm(t.h, t.h_se)
            ),
            TermKind::RandomWalk => writeln!(
                s,
                "    random walk  K = {} {u}/√s; h-2 = {} {u}²·Hz",
                pm(t.ieee, t.ieee_se),
                pm(t.h, t.h_se)
            ),
        };
    }
}
