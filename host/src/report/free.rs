//! Method free in the report: the still intervals over the readings' magnitude, the fitted
//! gravity directions on the sphere, each pose's residual, and their tables.

use super::{chart, err, range, side_legend, svg, Envelope, Key, ReportError, COLOURS};
use crate::calibrate::free::Residual;
use crate::calibrate::json::{DetectionJson, FreeJson, IntervalJson};
use crate::calibrate::still::Verdict;
use crate::recording::Recording;
use plotters::prelude::*;
use std::fmt::Write as _;
use std::path::Path;

const KEPT: RGBColor = RGBColor(44, 160, 44);
/// Too short, moved, does not fit.
const REJECTED: [(RGBColor, &str); 3] = [
    (RGBColor(255, 127, 14), "rejected: too short"),
    (RGBColor(214, 39, 40), "rejected: moved"),
    (RGBColor(140, 20, 90), "rejected: does not fit"),
];

/// One segment's rows as the detection saw them (`calibrate::segments`): times (s) and |y|.
struct Trace {
    x: Vec<f64>,
    magnitude: Vec<f64>,
}

fn traces(rec: &Recording) -> Result<Vec<Trace>, ReportError> {
    Ok(crate::calibrate::segments(rec)?
        .iter()
        .map(|s| Trace {
            x: s.t_s.to_vec(),
            magnitude: s
                .y
                .iter()
                .map(|y| y.iter().map(|v| v * v).sum::<f64>().sqrt())
                .collect(),
        })
        .collect())
}

/// Index into [`REJECTED`], or `None` for a kept interval.
fn class(v: &Verdict) -> Option<usize> {
    match v {
        Verdict::Kept => None,
        Verdict::TooShort { .. } => Some(0),
        Verdict::Moved { .. } => Some(1),
        Verdict::DoesNotFit { .. } => Some(2),
    }
}

/// Each pixel column's range of |y|, joined: the envelope of a long record, as the points
/// of a line (none for a trace without rows).
fn envelope(t: &Trace) -> Vec<(f64, f64)> {
    let Some(&t0) = t.x.first() else {
        return Vec::new();
    };
    let mut env = Envelope::default();
    for (x, m) in t.x.iter().zip(&t.magnitude) {
        env.add(x - t0, *m);
    }
    env.points()
        .flat_map(|(x, lo, hi)| [(x + t0, lo), (x + t0, hi)])
        .collect()
}

/// |y| against time with each interval as a band: green kept, the others by verdict.
fn plot_magnitude(
    t: &Trace,
    d: &DetectionJson,
    path: &Path,
    units: &str,
) -> Result<(), ReportError> {
    svg(path, (900, 420), |root| {
        root.fill(&WHITE).map_err(err(path))?;
        // The legend in a column of its own, beside the data.
        let (root, side) = root.split_horizontally(900 - 150);
        let root = &root;
        let mut entries = Vec::new();
        let (x0, x1) = range(t.x.iter().copied());
        let (y0, y1) = range(t.magnitude.iter().copied());
        let title = if d.segment.is_empty() {
            "|y| and the still intervals".to_string()
        } else {
            format!("{}: |y| and the still intervals", d.segment)
        };
        let mut c = chart(
            root,
            path,
            &title,
            18,
            (x0, x1),
            (y0, y1),
            "t (s)",
            &format!("|y| ({units})"),
        )?;
        let ends = |i: &IntervalJson| i.interval.span_s;
        let classes = [(KEPT, "kept", None)].into_iter().chain(
            REJECTED
                .iter()
                .enumerate()
                .map(|(k, (c, l))| (*c, *l, Some(k))),
        );
        for (colour, label, which) in classes {
            let bands: Vec<(f64, f64)> = d
                .intervals
                .iter()
                .filter(|i| class(&i.interval.verdict) == which)
                .map(ends)
                .collect();
            if bands.is_empty() {
                continue;
            }
            c.draw_series(
                bands
                    .into_iter()
                    .map(|(a, b)| Rectangle::new([(a, y0), (b, y1)], colour.mix(0.25).filled())),
            )
            .map_err(err(path))?;
            entries.push((label.to_string(), colour, Key::Band));
        }
        let line = COLOURS[0];
        c.draw_series(LineSeries::new(envelope(t), line.stroke_width(1)))
            .map_err(err(path))?;
        entries.push(("|y|".to_string(), line, Key::Line));
        side_legend(&side, &entries, path)?;
        Ok(())
    })
}

/// Lambert azimuthal equal-area projection of a unit vector about +z′ (`upper`) or −z′,
/// scaled so the equator is the unit circle; x′ right and y′ up in both discs.
fn lambert(d: &[f64; 3], upper: bool) -> (f64, f64) {
    let [x, y, z] = *d;
    let s = (1.0 / (1.0 + if upper { z } else { -z }).max(1e-12)).sqrt();
    (x * s, y * s)
}

/// The fitted ĝ of each pose on two equal-area discs, z′ ≥ 0 and z′ < 0, labelled by
/// pose number (the tables' #).
fn plot_directions(free: &FreeJson, path: &Path) -> Result<(), ReportError> {
    svg(path, (900, 500), |root| {
        root.fill(&WHITE).map_err(err(path))?;
        let body = root
            .titled(
                "fitted gravity directions ĝ, device frame (Lambert equal-area)",
                ("sans-serif", 18),
            )
            .map_err(err(path))?;
        let (left, right) = body.split_horizontally(450);
        let ring = |r: f64| -> Vec<(f64, f64)> {
            (0..=360)
                .map(|k| {
                    let a = f64::from(k).to_radians();
                    (r * a.cos(), r * a.sin())
                })
                .collect()
        };
        for (area, upper, title) in [
            (&left, true, "z′ ≥ 0 (seen from +z′)"),
            (&right, false, "z′ < 0 (seen from +z′, through the sphere)"),
        ] {
            let area = area.titled(title, ("sans-serif", 15)).map_err(err(path))?;
            // A square plot so the circles stay round.
            let (w, h) = area.dim_in_pixel();
            let side = w.min(h).saturating_sub(20);
            let (mx, my) = ((w - side) / 2, (h - side) / 2);
            let area = area.margin(my, my, mx, mx);
            let mut c = ChartBuilder::on(&area)
                .build_cartesian_2d(-1.2f64..1.2, -1.2f64..1.2)
                .map_err(err(path))?;
            c.draw_series(LineSeries::new(ring(1.0), BLACK.stroke_width(1)))
                .map_err(err(path))?;
            // 45° from the pole: X² + Y² = 1 − |z|.
            let r45 = (1.0 - std::f64::consts::FRAC_1_SQRT_2).sqrt();
            c.draw_series(LineSeries::new(ring(r45), BLACK.mix(0.3).stroke_width(1)))
                .map_err(err(path))?;
            c.draw_series(LineSeries::new(
                [(-1.0, 0.0), (1.0, 0.0)],
                BLACK.mix(0.2).stroke_width(1),
            ))
            .map_err(err(path))?;
            c.draw_series(LineSeries::new(
                [(0.0, -1.0), (0.0, 1.0)],
                BLACK.mix(0.2).stroke_width(1),
            ))
            .map_err(err(path))?;
            let axis = ("sans-serif", 14).into_font().color(&BLACK);
            c.draw_series([
                Text::new("x′", (1.04, 0.02), axis.clone()),
                Text::new("y′", (0.02, 1.08), axis),
            ])
            .map_err(err(path))?;
            let pts: Vec<(usize, (f64, f64))> = free
                .poses
                .iter()
                .enumerate()
                .filter(|(_, p)| (p.direction[2] >= 0.0) == upper)
                .map(|(i, p)| (i + 1, lambert(&p.direction, upper)))
                .collect();
            let dot = COLOURS[0];
            c.draw_series(pts.iter().map(|(_, p)| Circle::new(*p, 4, dot.filled())))
                .map_err(err(path))?;
            let label = ("sans-serif", 13).into_font().color(&BLACK);
            c.draw_series(
                pts.iter().map(|(i, (x, y))| {
                    Text::new(i.to_string(), (x + 0.04, y + 0.04), label.clone())
                }),
            )
            .map_err(err(path))?;
        }
        Ok(())
    })
}

/// |a| − g of each pose with ±2 standard deviations.
fn plot_pose_residuals(free: &FreeJson, path: &Path) -> Result<(), ReportError> {
    svg(path, (900, 420), |root| {
        root.fill(&WHITE).map_err(err(path))?;
        let n = free.poses.len() as f64;
        let (y0, y1) = range(free.poses.iter().flat_map(|p| {
            let u = 2.0 * p.residual_std_ms2;
            [p.residual_ms2 - u, p.residual_ms2 + u, 0.0]
        }));
        // Not `chart`: pose numbers want integer ticks.
        let mut c = ChartBuilder::on(root)
            .caption(
                "residual |a| − g of each pose (bars: ±2 standard deviations)",
                ("sans-serif", 18),
            )
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(0.5..n + 0.5, y0..y1)
            .map_err(err(path))?;
        c.configure_mesh()
            .x_labels(free.poses.len().clamp(1, 30))
            .x_label_formatter(&|x| format!("{x:.0}"))
            .disable_x_mesh()
            .x_desc("pose #")
            .y_desc("|a| − g (m/s²)")
            .draw()
            .map_err(err(path))?;
        c.draw_series(LineSeries::new(
            [(0.5, 0.0), (n + 0.5, 0.0)],
            BLACK.mix(0.4).stroke_width(1),
        ))
        .map_err(err(path))?;
        let col = COLOURS[0];
        c.draw_series(free.poses.iter().enumerate().map(|(i, p)| {
            let u = 2.0 * p.residual_std_ms2;
            let x = (i + 1) as f64;
            ErrorBar::new_vertical(
                x,
                p.residual_ms2 - u,
                p.residual_ms2,
                p.residual_ms2 + u,
                col.filled(),
                8,
            )
        }))
        .map_err(err(path))?;
        Ok(())
    })
}

fn three(v: &[f64; 3], f: impl Fn(f64) -> String) -> String {
    v.map(f).join(", ")
}

/// The section of a free entry: plots in `dir`, Markdown appended to `md`.
pub(crate) fn write(
    rec: &Recording,
    free: &FreeJson,
    units: &str,
    dir: &Path,
    md: &mut String,
) -> Result<(), ReportError> {
    let _ = writeln!(md, "\n### Still intervals\n");
    for d in &free.detection {
        let at = if d.segment.is_empty() {
            String::new()
        } else {
            format!("{}: ", d.segment)
        };
        let kept = d
            .intervals
            .iter()
            .filter(|i| i.interval.verdict == Verdict::Kept)
            .count();
        match &d.found {
            Some(f) => {
                let _ = writeln!(
                    md,
                    "- {at}{} candidate interval(s), {kept} kept; windows of {} s ({} rows) at {:.3} Hz, \
                     still below {} × the noise variance (noise sd u, v, w = {} {units}), \
                     {:.1} % of the windows still; the minimum is {} s.",
                    d.intervals.len(),
                    f.options.window_s,
                    f.window_rows,
                    f.sample_rate_hz,
                    f.options.threshold,
                    three(&f.noise_sd, |v| format!("{v:.3e}")),
                    100.0 * f.still_fraction,
                    f.options.min_still_s
                );
            }
            None => {
                let _ = writeln!(
                    md,
                    "- {at}{} interval(s) named in the file's pose column, {kept} kept.",
                    d.intervals.len()
                );
            }
        }
    }
    let _ = writeln!(md);
    let many = free.detection.len() > 1;
    for (k, (t, d)) in traces(rec)?.iter().zip(&free.detection).enumerate() {
        let name = if many {
            format!("magnitude_{}.svg", k + 1)
        } else {
            "magnitude.svg".to_string()
        };
        plot_magnitude(t, d, &dir.join(&name), units)?;
        let _ = writeln!(md, "![magnitude and still intervals]({name})\n");
    }
    let _ = writeln!(
        md,
        "| interval | span (s) | n | mean u, v, w ({units}) | std u, v, w ({units}) | verdict |\n| --- | --- | --- | --- | --- | --- |"
    );
    for i in free.detection.iter().flat_map(|d| &d.intervals) {
        let iv = &i.interval;
        let _ = writeln!(
            md,
            "| {} | {:.3} – {:.3} | {} | {} | {} | {} |",
            iv.name,
            iv.span_s.0,
            iv.span_s.1,
            iv.n,
            three(&iv.mean, |v| format!("{v:.2}")),
            three(&iv.std, |v| format!("{v:.2}")),
            // A pipe would end the cell.
            i.reason.replace('|', "\\|")
        );
    }
    let residual = match free.residual {
        Residual::Geometric => "|a| − g",
        Residual::Algebraic => "(|a|² − g²)/(2g)",
    };
    let nu = free
        .nu
        .map(|v| format!("{v:.1}"))
        .unwrap_or_else(|| "∞".into());
    let chi2_dof = if free.dof > 0 {
        format!(" (χ²/dof = {:.3})", free.chi2 / free.dof as f64)
    } else {
        String::new()
    };
    let _ = writeln!(
        md,
        "\n### Poses\n\n{} poses fitted by {residual}: χ² = {:.2} on {} degrees of freedom{chi2_dof}, \
         τ = {:.3e} m/s², ν = {nu}, condition number {:.2}.\n",
        free.poses.len(),
        free.chi2,
        free.dof,
        free.tau_ms2,
        free.condition_number
    );
    if let Some(s) = &free.suggestion {
        let _ = writeln!(
            md,
            "**Poorly conditioned**: add poses with gravity near {s}.\n"
        );
    }
    let _ = writeln!(
        md,
        "| # | pose | fitted ĝ x′, y′, z′ | \\|a\\| − g ± std (m/s²) |\n| --- | --- | --- | --- |"
    );
    for (i, p) in free.poses.iter().enumerate() {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {:+.3e} ± {:.2e} |",
            i + 1,
            p.name,
            three(&p.direction, |v| format!("{v:+.4}")),
            p.residual_ms2,
            p.residual_std_ms2
        );
    }
    plot_directions(free, &dir.join("directions.svg"))?;
    plot_pose_residuals(free, &dir.join("pose_residuals.svg"))?;
    let _ = writeln!(
        md,
        "\n![fitted gravity directions](directions.svg)\n\n![pose residuals](pose_residuals.svg)\n"
    );
    Ok(())
}
