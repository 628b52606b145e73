//! Log-log Allan deviation plots, one panel per group (or condition) and channel, the
//! legend in a column of its own so that it never covers data:
//! - `rotacal allan --plot OUT.svg`: the points with their 1σ interval bars, the fitted
//!   model and its three terms ([`write`]);
//! - `rotacal report --slow-noise`: a calibration's residuals against the noise model's
//!   expectation for the same fit and its terms ([`write_residual`]).

use std::path::Path;

use plotters::prelude::*;

use super::{err, svg, ReportError};
use crate::allan::{Fit, Point, TermKind};

/// One panel: a channel of a group.
pub struct Panel<'a> {
    /// Caption.
    pub title: String,
    /// The octave points.
    pub points: &'a [Point],
    /// The terms fit, if it succeeded.
    pub fit: Option<&'a Fit>,
    /// Sample rate, Hz (τ = m/rate for the model lines).
    pub rate_hz: f64,
}

const TERMS: [(TermKind, &str, RGBColor); 3] = [
    (TermKind::White, "white (N)", RGBColor(31, 119, 180)),
    (TermKind::Flicker, "flicker (B)", RGBColor(44, 160, 44)),
    (
        TermKind::RandomWalk,
        "random walk (K)",
        RGBColor(214, 39, 40),
    ),
];
const MODEL: RGBColor = RGBColor(255, 127, 14);

/// Write the panels (three to a row) and the legend to `path`.
pub fn write(panels: &[Panel<'_>], path: &Path, units: &str) -> Result<(), ReportError> {
    let drawn: Vec<Drawn> = panels.iter().map(Panel::drawn).collect();
    let legend = Legend {
        points: "oADEV, 1σ interval",
        lines: std::iter::once(("fitted model", MODEL, 2))
            .chain(TERMS.iter().map(|(_, name, c)| (*name, *c, 1)))
            .collect(),
    };
    draw(&drawn, &legend, path, units)
}

impl Panel<'_> {
    fn drawn(&self) -> Drawn {
        let mut lines = Vec::new();
        if let Some(fit) = self.fit {
            let ms: Vec<usize> = self.points.iter().map(|q| q.m).collect();
            let line = |f: &dyn Fn(usize) -> f64| -> Vec<(f64, f64)> {
                ms.iter()
                    .map(|m| (*m as f64 / self.rate_hz, f(*m).max(0.0).sqrt()))
                    .filter(|(_, v)| *v > 0.0)
                    .collect()
            };
            for (kind, _, colour) in TERMS {
                lines.push((colour, 1, line(&|m| fit.term_avar(kind, m))));
            }
            lines.push((MODEL, 2, line(&|m| fit.avar(m))));
        }
        Drawn {
            title: self.title.clone(),
            points: self
                .points
                .iter()
                .map(|q| (q.tau_s, q.adev, q.interval.map(|i| (i.lo, i.hi))))
                .collect(),
            lines,
        }
    }
}

/// One panel of a calibration's residual Allan deviations ([`write_residual`]).
pub struct ResidualPanel<'a> {
    /// Caption.
    pub title: String,
    /// The averaging lengths, with the model's expectation.
    pub points: &'a [crate::calibrate::json::ResidualAllanJson],
}

/// A calibration's residual Allan deviations against the model's expectation for the same
/// fit, its terms drawn where positive: one panel per condition and channel.
pub fn write_residual(
    panels: &[ResidualPanel<'_>],
    path: &Path,
    units: &str,
) -> Result<(), ReportError> {
    let drawn: Vec<Drawn> = panels
        .iter()
        .map(|p| {
            let line = |f: &dyn Fn(&crate::calibrate::json::ResidualAllanJson) -> f64| {
                p.points
                    .iter()
                    .map(|q| (q.tau_s, f(q)))
                    .filter(|(_, v)| v.is_finite() && *v > 0.0)
                    .map(|(t, v)| (t, v.sqrt()))
                    .collect::<Vec<_>>()
            };
            Drawn {
                title: p.title.clone(),
                points: p
                    .points
                    .iter()
                    .map(|q| {
                        let i = q.observed_adev_interval.map(|[lo, hi]| (lo, hi));
                        (q.tau_s, q.observed_avar.max(0.0).sqrt(), i)
                    })
                    .collect(),
                lines: vec![
                    (TERMS[0].2, 1, line(&|q| q.short_range_avar)),
                    (TERMS[1].2, 1, line(&|q| q.flicker_avar)),
                    (TERMS[2].2, 1, line(&|q| q.walk_avar)),
                    (MODEL, 2, line(&|q| q.expected_avar)),
                ],
            }
        })
        .collect();
    let legend = Legend {
        points: "residuals' oADEV, 1σ interval",
        lines: vec![
            ("model, through the fit", MODEL, 2),
            ("short-range (AR)", TERMS[0].2, 1),
            ("flicker (B)", TERMS[1].2, 1),
            ("random walk (K)", TERMS[2].2, 1),
        ],
    };
    draw(&drawn, &legend, path, units)
}

/// What one panel draws, in order: its lines (colour, width, points), then its points
/// (τ, deviation, 1σ interval).
struct Drawn {
    title: String,
    points: Vec<Dot>,
    lines: Vec<Line>,
}

/// A point: τ, deviation and its 1σ interval.
type Dot = (f64, f64, Option<(f64, f64)>);
/// A line: colour, width and its (τ, deviation) points.
type Line = (RGBColor, u32, Vec<(f64, f64)>);

/// The legend: the points' label and each line's (label, colour, width).
struct Legend {
    points: &'static str,
    lines: Vec<(&'static str, RGBColor, u32)>,
}

fn draw(panels: &[Drawn], legend: &Legend, path: &Path, units: &str) -> Result<(), ReportError> {
    let rows = panels.len().div_ceil(3).max(1);
    svg(path, (1200, 340 * rows as u32), |root| {
        root.fill(&WHITE).map_err(err(path))?;
        let (plots, legend_area) = root.split_horizontally(1020);
        for (area, panel) in plots.split_evenly((rows, 3)).iter().zip(panels) {
            draw_panel(area, panel, path, units)?;
        }
        draw_legend(&legend_area, legend, path)?;
        Ok(())
    })
}

fn draw_panel(
    area: &DrawingArea<SVGBackend<'_>, plotters::coord::Shift>,
    p: &Drawn,
    path: &Path,
    units: &str,
) -> Result<(), ReportError> {
    let positive = |v: &f64| v.is_finite() && *v > 0.0;
    let ys = p.points.iter().flat_map(|&(_, adev, interval)| {
        let (lo, hi) = interval.unwrap_or((adev, adev));
        [adev, lo, hi]
    });
    let (y0, y1) = ys
        .filter(positive)
        .fold((f64::INFINITY, 0.0f64), |(a, b), v| (a.min(v), b.max(v)));
    let (x0, x1) = p
        .points
        .iter()
        .map(|q| q.0)
        .filter(positive)
        .fold((f64::INFINITY, 0.0f64), |(a, b), v| (a.min(v), b.max(v)));
    if !(y0.is_finite() && x0.is_finite()) {
        return Ok(());
    }
    let mut c = ChartBuilder::on(area)
        .caption(&p.title, ("sans-serif", 13))
        .margin(8)
        .x_label_area_size(32)
        .y_label_area_size(56)
        .build_cartesian_2d(
            (x0 / 1.5..x1 * 1.5).log_scale(),
            (y0 / 1.5..y1 * 1.5).log_scale(),
        )
        .map_err(err(path))?;
    c.configure_mesh()
        .x_desc("τ (s)")
        .y_desc(format!("ADEV ({units})"))
        .label_style(("sans-serif", 10))
        .draw()
        .map_err(err(path))?;
    // plotters does not clip: a term far below the data (a walk at short τ) would be drawn
    // over the axis labels. A line keeps its points inside the panel's range.
    let (lo, hi) = (y0 / 1.5, y1 * 1.5);
    for (colour, width, line) in &p.lines {
        c.draw_series(LineSeries::new(
            line.iter()
                .copied()
                .filter(|&(_, v)| (lo..=hi).contains(&v)),
            colour.stroke_width(*width),
        ))
        .map_err(err(path))?;
    }
    c.draw_series(p.points.iter().filter_map(|&(tau, adev, interval)| {
        interval.map(|(lo, hi)| ErrorBar::new_vertical(tau, lo, adev, hi, BLACK.filled(), 6))
    }))
    .map_err(err(path))?;
    c.draw_series(
        p.points
            .iter()
            .map(|&(tau, adev, _)| Circle::new((tau, adev), 3, BLACK.filled())),
    )
    .map_err(err(path))?;
    Ok(())
}

fn draw_legend(
    area: &DrawingArea<SVGBackend<'_>, plotters::coord::Shift>,
    legend: &Legend,
    path: &Path,
) -> Result<(), ReportError> {
    let style = ("sans-serif", 13).into_font().color(&BLACK);
    let mut y = 40;
    area.draw(&Circle::new((14, y), 3, BLACK.filled()))
        .map_err(err(path))?;
    area.draw(&Text::new(legend.points, (28, y - 7), style.clone()))
        .map_err(err(path))?;
    y += 24;
    for &(name, colour, width) in &legend.lines {
        area.draw(&PathElement::new(
            vec![(4, y), (24, y)],
            colour.stroke_width(width),
        ))
        .map_err(err(path))?;
        area.draw(&Text::new(name, (28, y - 7), style.clone()))
            .map_err(err(path))?;
        y += 24;
    }
    Ok(())
}
