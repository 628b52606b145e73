//! `rotacal allan --plot OUT.svg`: log-log Allan deviation with the 1σ interval bars, the
//! fitted model and its three terms, one panel per group and channel, the legend in a
//! column of its own so that it never covers data.

use std::path::Path;

use plotters::prelude::*;

use super::{err, ReportError};
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
    let rows = panels.len().div_ceil(3).max(1);
    let root = SVGBackend::new(path, (1200, 340 * rows as u32)).into_drawing_area();
    root.fill(&WHITE).map_err(err(path))?;
    let (plots, legend_area) = root.split_horizontally(1020);
    for (area, panel) in plots.split_evenly((rows, 3)).iter().zip(panels) {
        draw_panel(area, panel, path, units)?;
    }
    draw_legend(&legend_area, path)?;
    root.present().map_err(err(path))
}

fn draw_panel(
    area: &DrawingArea<SVGBackend<'_>, plotters::coord::Shift>,
    p: &Panel<'_>,
    path: &Path,
    units: &str,
) -> Result<(), ReportError> {
    let positive = |v: &f64| v.is_finite() && *v > 0.0;
    let ys = p.points.iter().flat_map(|q| {
        let (lo, hi) = q.interval.map_or((q.adev, q.adev), |i| (i.lo, i.hi));
        [q.adev, lo, hi]
    });
    let (y0, y1) = ys
        .filter(positive)
        .fold((f64::INFINITY, 0.0f64), |(a, b), v| (a.min(v), b.max(v)));
    let (x0, x1) = p
        .points
        .iter()
        .map(|q| q.tau_s)
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
    if let Some(fit) = p.fit {
        let ms: Vec<usize> = p.points.iter().map(|q| q.m).collect();
        let line = |f: &dyn Fn(usize) -> f64| -> Vec<(f64, f64)> {
            ms.iter()
                .map(|m| (*m as f64 / p.rate_hz, f(*m).max(0.0).sqrt()))
                .filter(|(_, v)| *v > 0.0)
                .collect()
        };
        for (kind, _, colour) in TERMS {
            c.draw_series(LineSeries::new(
                line(&|m| fit.term_avar(kind, m)),
                colour.stroke_width(1),
            ))
            .map_err(err(path))?;
        }
        c.draw_series(LineSeries::new(
            line(&|m| fit.avar(m)),
            MODEL.stroke_width(2),
        ))
        .map_err(err(path))?;
    }
    c.draw_series(p.points.iter().filter_map(|q| {
        q.interval
            .map(|i| ErrorBar::new_vertical(q.tau_s, i.lo, q.adev, i.hi, BLACK.filled(), 6))
    }))
    .map_err(err(path))?;
    c.draw_series(
        p.points
            .iter()
            .map(|q| Circle::new((q.tau_s, q.adev), 3, BLACK.filled())),
    )
    .map_err(err(path))?;
    Ok(())
}

fn draw_legend(
    area: &DrawingArea<SVGBackend<'_>, plotters::coord::Shift>,
    path: &Path,
) -> Result<(), ReportError> {
    let style = ("sans-serif", 13).into_font().color(&BLACK);
    let mut y = 40;
    area.draw(&Circle::new((14, y), 3, BLACK.filled()))
        .map_err(err(path))?;
    area.draw(&Text::new("oADEV, 1σ interval", (28, y - 7), style.clone()))
        .map_err(err(path))?;
    y += 24;
    let entries = [("fitted model", MODEL, 2)]
        .into_iter()
        .chain(TERMS.iter().map(|(_, name, c)| (*name, *c, 1)));
    for (name, colour, width) in entries {
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
