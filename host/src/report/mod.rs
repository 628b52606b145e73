//! `rotacal report FILE --out DIR`: a Markdown report with SVG plots (plotters).
//!
//! - the intrinsic-properties table with U (95 %; k = 2, or Student's t for few poses), the fits, and for static files the
//!   sensitivity matrix and offsets;
//! - per condition (and rate): the raw data with the fitted sines (like seed 000 Fig. 5),
//!   the residuals against time or angle, and for rotation the residual amplitude at the
//!   first harmonics of ω (each from a least-squares fit of sin kα, cos kα and a constant
//!   to the residuals, so it holds for records of any length);
//! - for multi-rate files, the properties against rate relative to the lowest rate, with
//!   U (k = 2) as error bars (like seed 000 Fig. 6);
//! - for method free: |y| against time with the still intervals marked, the
//!   fitted gravity directions, each pose's residual, and their tables.
//!
//! SVG needs no fonts at build or run time; the viewer renders the text.

pub mod discrepancy;
mod free;

use crate::calibrate::json::{CalibrationJson, FitJson, Quantity, RateJson};
use crate::calibrate::{self, calibrate, CalibrateError, Options, CLOCK};
use crate::fit::harmonics::{harmonic_amplitudes, HARMONICS};
use crate::recording::{Group, Method, Recording};
use plotters::prelude::*;
use rotacal_shared::{PhaseStep, Ticks};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Most points drawn per series (the data are decimated evenly beyond that).
const MAX_POINTS: usize = 3000;

/// What went wrong.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// The calibration failed (the message names file and line).
    #[error(transparent)]
    Calibrate(#[from] CalibrateError),
    /// Writing failed.
    #[error("{0}")]
    Write(String),
}

/// One group's data, model and residuals.
pub(crate) struct Series {
    pub(crate) title: String,
    pub(crate) stem: String,
    /// Time (s from the group's first row) or angle (deg).
    pub(crate) x: Vec<f64>,
    pub(crate) x_label: &'static str,
    pub(crate) alpha: Vec<f64>,
    pub(crate) y: [Vec<f64>; 3],
    pub(crate) model: [Vec<f64>; 3],
    pub(crate) rotation: bool,
}

fn coef(fits: &[FitJson], cond: char, ch: &str) -> Option<[f64; 3]> {
    fits.iter()
        .find(|f| f.condition.starts_with(cond) && f.channel == ch)
        .map(|f| [f.a, f.b, f.c])
}

fn series(rec: &Recording, g: &Group, entry: &RateJson) -> Result<Series, ReportError> {
    let cond = g.condition.letter();
    let coefs = ["u", "v", "w"].map(|ch| coef(&entry.fits, cond, ch));
    let (x, alpha, x_label, rotation) = match rec.method {
        Method::Rotation => {
            let s = calibrate::samples(rec, g)?;
            let rate = entry
                .fits
                .iter()
                .find(|f| f.condition.starts_with(cond))
                .and_then(|f| f.rate_hz_fitted)
                .or(entry.rate_hz)
                .unwrap_or(0.0);
            let step = PhaseStep::from_hz(rate, CLOCK)
                .ok_or_else(|| ReportError::Write(format!("rate {rate} Hz unusable")))?;
            let hz = f64::from(CLOCK.hz());
            // An average is drawn at the mean instant of its conversions.
            let mid = |ap: &rotacal_shared::Aperture| {
                let n = ap.len().max(1) as u64;
                Ticks(ap.ticks().map(|t| t.0).sum::<u64>() / n)
            };
            (
                s.iter().map(|(ap, _)| mid(ap).0 as f64 / hz).collect(),
                s.iter()
                    .map(|(ap, _)| step.phase_at(mid(ap)).radians())
                    .collect(),
                "time from the condition's first sample (s)",
                true,
            )
        }
        Method::Free => {
            return Err(ReportError::Write(
                "method free has no per-condition fits to plot".into(),
            ))
        }
        Method::Static => (
            g.angle_deg.clone(),
            g.angle_deg
                .iter()
                .map(|a| a.to_radians())
                .collect::<Vec<_>>(),
            "table angle α (deg)",
            false,
        ),
    };
    let y = [g.u.clone(), g.v.clone(), g.w.clone()];
    let model = [0, 1, 2].map(|ch| {
        let [a, b, c] = coefs[ch].unwrap_or([f64::NAN; 3]);
        alpha
            .iter()
            .map(|t: &f64| a * t.sin() + b * t.cos() + c)
            .collect()
    });
    let rate = entry
        .rate_hz
        .map(|r| format!(" at {r} Hz"))
        .unwrap_or_default();
    let stem = match entry.rate_hz {
        Some(r) => format!("{cond}_{}mhz", (r * 1000.0).round()),
        None => cond.to_string(),
    };
    Ok(Series {
        title: format!("condition {cond}{rate}"),
        stem,
        x,
        x_label,
        alpha,
        y,
        model,
        rotation,
    })
}

pub(crate) fn residuals(s: &Series, ch: usize) -> Vec<f64> {
    s.y[ch]
        .iter()
        .zip(&s.model[ch])
        .map(|(y, m)| y - m)
        .collect()
}

fn decimate(n: usize) -> usize {
    n.div_ceil(MAX_POINTS).max(1)
}

fn range(vals: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = vals
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
            (l.min(v), h.max(v))
        });
    if !lo.is_finite() {
        return (-1.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-12);
    (lo - pad, hi + pad)
}

const COLOURS: [RGBColor; 3] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
];
const CHANNELS: [&str; 3] = ["u", "v", "w"];

fn err<E: std::fmt::Display>(path: &Path) -> impl Fn(E) -> ReportError + '_ {
    move |e| ReportError::Write(format!("{}: {e}", path.display()))
}

type Chart<'a, 'b> = ChartContext<
    'a,
    SVGBackend<'b>,
    Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
>;

/// Axes with a caption and labels, the house style of every plot.
#[allow(clippy::too_many_arguments)]
fn chart<'a, 'b>(
    area: &'a DrawingArea<SVGBackend<'b>, plotters::coord::Shift>,
    path: &Path,
    caption: &str,
    caption_size: u32,
    x: (f64, f64),
    y: (f64, f64),
    x_desc: &str,
    y_desc: &str,
) -> Result<Chart<'a, 'b>, ReportError> {
    let mut c = ChartBuilder::on(area)
        .caption(caption, ("sans-serif", caption_size))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(x.0..x.1, y.0..y.1)
        .map_err(err(path))?;
    c.configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .draw()
        .map_err(err(path))?;
    Ok(c)
}

fn legend<'a, 'b: 'a>(c: &mut Chart<'a, 'b>, path: &Path) -> Result<(), ReportError> {
    c.configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(err(path))
}

/// Raw data (points) and fitted sines (lines), three channels.
fn plot_fit(s: &Series, path: &Path, units: &str) -> Result<(), ReportError> {
    let root = SVGBackend::new(path, (900, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(err(path))?;
    let (x0, x1) = range(s.x.iter().copied());
    let (y0, y1) = range(s.y.iter().flatten().copied());
    let mut chart = chart(
        &root,
        path,
        &format!("{}: data and fitted sines", s.title),
        18,
        (x0, x1),
        (y0, y1),
        s.x_label,
        units,
    )?;
    let step = decimate(s.x.len());
    for ch in 0..3 {
        let c = COLOURS[ch];
        chart
            .draw_series(
                s.x.iter()
                    .zip(&s.y[ch])
                    .step_by(step)
                    .map(|(x, y)| Circle::new((*x, *y), 1, c.filled())),
            )
            .map_err(err(path))?
            .label(format!("{} data", CHANNELS[ch]))
            .legend(move |(x, y)| Circle::new((x + 10, y), 3, c.filled()));
        let mut line: Vec<(f64, f64)> =
            s.x.iter()
                .copied()
                .zip(s.model[ch].iter().copied())
                .collect();
        line.sort_by(|a, b| a.0.total_cmp(&b.0));
        chart
            .draw_series(LineSeries::new(
                line.into_iter().step_by(step),
                c.stroke_width(1),
            ))
            .map_err(err(path))?
            .label(format!("{} fit", CHANNELS[ch]))
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], c));
    }
    legend(&mut chart, path)?;
    root.present().map_err(err(path))
}

/// Residuals against time or angle, three channels.
pub(crate) fn plot_residuals(s: &Series, path: &Path, units: &str) -> Result<(), ReportError> {
    let r: Vec<Vec<f64>> = (0..3).map(|ch| residuals(s, ch)).collect();
    let root = SVGBackend::new(path, (900, 420)).into_drawing_area();
    root.fill(&WHITE).map_err(err(path))?;
    let (x0, x1) = range(s.x.iter().copied());
    let (y0, y1) = range(r.iter().flatten().copied());
    let mut chart = chart(
        &root,
        path,
        &format!("{}: residuals", s.title),
        18,
        (x0, x1),
        (y0, y1),
        s.x_label,
        &format!("data − fit ({units})"),
    )?;
    let step = decimate(s.x.len());
    for (ch, rc) in r.iter().enumerate() {
        let c = COLOURS[ch];
        chart
            .draw_series(
                s.x.iter()
                    .zip(rc)
                    .step_by(step)
                    .map(|(x, y)| Circle::new((*x, *y), 1, c.filled())),
            )
            .map_err(err(path))?
            .label(CHANNELS[ch])
            .legend(move |(x, y)| Circle::new((x + 10, y), 3, c.filled()));
    }
    legend(&mut chart, path)?;
    root.present().map_err(err(path))
}

/// Residual amplitude at the harmonics of ω.
pub(crate) fn plot_spectrum(
    s: &Series,
    amps: &[Vec<f64>],
    path: &Path,
    units: &str,
) -> Result<(), ReportError> {
    let root = SVGBackend::new(path, (700, 400)).into_drawing_area();
    root.fill(&WHITE).map_err(err(path))?;
    let (_, y1) = range(amps.iter().flatten().copied());
    let mut chart = chart(
        &root,
        path,
        &format!("{}: residual amplitude at k·ω", s.title),
        18,
        (0.5f64, (HARMONICS as f64 + 0.5)),
        (0.0, y1.max(1e-12)),
        "harmonic k",
        &format!("amplitude ({units})"),
    )?;
    for (ch, a) in amps.iter().enumerate() {
        let c = COLOURS[ch];
        let off = (ch as f64 - 1.0) * 0.2;
        chart
            .draw_series(a.iter().enumerate().map(|(k, v)| {
                let x = k as f64 + 1.0 + off;
                Rectangle::new([(x - 0.09, 0.0), (x + 0.09, *v)], c.filled())
            }))
            .map_err(err(path))?
            .label(CHANNELS[ch])
            .legend(move |(x, y)| Rectangle::new([(x + 5, y - 4), (x + 13, y + 4)], c.filled()));
    }
    legend(&mut chart, path)?;
    root.present().map_err(err(path))
}

/// s_u, s_v, s_w, φ_uv, φ_vw, φ_wu (not the offsets).
fn props(e: &RateJson) -> Vec<&Quantity> {
    let mut q = e.intrinsic.quantities();
    q.truncate(6);
    q
}

/// Properties against rate, relative to the lowest rate, with U (k = 2) as error bars:
/// sensitivities in parts per million, angles in degrees.
fn plot_rates(cal: &CalibrationJson, path: &Path) -> Result<(), ReportError> {
    let mut entries: Vec<&RateJson> = cal.by_rate.iter().collect();
    entries.sort_by(|a, b| {
        a.rate_hz
            .unwrap_or(0.0)
            .total_cmp(&b.rate_hz.unwrap_or(0.0))
    });
    let Some(first) = entries.first() else {
        return Ok(());
    };
    let base: Vec<f64> = props(first).iter().map(|q| q.value).collect();
    let root = SVGBackend::new(path, (900, 700)).into_drawing_area();
    root.fill(&WHITE).map_err(err(path))?;
    let (top, bottom) = root.split_vertically(350);
    let rates: Vec<f64> = entries.iter().map(|e| e.rate_hz.unwrap_or(0.0)).collect();
    let (x0, x1) = range(rates.iter().copied());
    for (panel, area, idx, scale, unit) in [
        ("sensitivities", &top, [0usize, 1, 2], 1e6, "Δs / s (ppm)"),
        ("angles", &bottom, [3usize, 4, 5], 1.0, "Δφ (deg)"),
    ] {
        let pts: Vec<Vec<(f64, f64, f64)>> = idx
            .iter()
            .map(|&k| {
                entries
                    .iter()
                    .map(|e| {
                        let q = props(e)[k];
                        let norm = if scale == 1.0 { 1.0 } else { base[k] };
                        let r = e.rate_hz.unwrap_or(0.0);
                        (
                            r,
                            (q.value - base[k]) / norm * scale,
                            q.expanded_unc / norm * scale,
                        )
                    })
                    .collect()
            })
            .collect();
        let (y0, y1) = range(pts.iter().flatten().flat_map(|(_, v, u)| [v - u, v + u]));
        let mut chart = chart(
            area,
            path,
            &format!(
                "{panel} against rate, relative to {} Hz (bars: U, k = 2)",
                rates[0]
            ),
            16,
            (x0, x1),
            (y0, y1),
            "rotation rate (Hz)",
            unit,
        )?;
        for (i, series) in pts.iter().enumerate() {
            let c = COLOURS[i];
            let name = ["u", "v", "w", "uv", "vw", "wu"][idx[i]];
            let dx = (x1 - x0) * 0.006 * (i as f64 - 1.0);
            chart
                .draw_series(series.iter().map(|(x, y, u)| {
                    ErrorBar::new_vertical(x + dx, y - u, *y, y + u, c.filled(), 6)
                }))
                .map_err(err(path))?
                .label(name)
                .legend(move |(x, y)| Circle::new((x + 10, y), 3, c.filled()));
        }
        legend(&mut chart, path)?;
    }
    root.present().map_err(err(path))
}

fn q(x: &Quantity, unit: &str) -> String {
    let d = calibrate::table::decimals(x.expanded_unc);
    let k = if (x.k - crate::calibrate::json::K).abs() > 1e-12 {
        format!(" (k = {:.2})", x.k)
    } else {
        String::new()
    };
    format!("{:.d$} ± {:.d$} {unit}{k}", x.value, x.expanded_unc)
}

/// Write the report; returns the Markdown file's path.
pub fn write(rec: &Recording, opts: &Options, dir: &Path) -> Result<PathBuf, ReportError> {
    let cal = calibrate(rec, opts)?;
    std::fs::create_dir_all(dir).map_err(err(dir))?;
    let units = cal.units.clone();
    let mut md = String::new();
    let _ = writeln!(md, "# rotacal report: {}\n", rec.source);
    let _ = writeln!(
        md,
        "Method {}, g_loc = {} m/s², units {units}, {} rows. Uncertainties are expanded, U (95 %, coverage factor k as stated).\n",
        cal.method,
        cal.g_loc,
        rec.rows()
    );
    let su = format!("{units}/(m/s²)");
    for entry in &cal.by_rate {
        let heading = match (entry.rate_hz, &entry.free) {
            (Some(r), _) => format!("Rotation at {r} Hz"),
            (None, Some(_)) => "Free poses (unknown orientation)".into(),
            (None, None) => "Static".into(),
        };
        let _ = writeln!(md, "## {heading}\n");
        let _ = writeln!(
            md,
            "| property | value ± U (k = {} unless stated) |\n| --- | --- |",
            crate::calibrate::json::K
        );
        let names = crate::calibrate::json::PROPERTY_NAMES;
        for (i, x) in props(entry).iter().enumerate() {
            let _ = writeln!(
                md,
                "| {} | {} |",
                names[i],
                q(x, if i < 3 { &su } else { "°" })
            );
        }
        if let Some(o) = &entry.intrinsic.offset {
            for (n, x) in [("O_u", &o.u), ("O_v", &o.v), ("O_w", &o.w)] {
                let _ = writeln!(md, "| {n} | {} |", q(x, &units));
            }
        }
        if let Some(p) = &entry.angle_deg_phase_method {
            for (n, x) in [
                ("φ_uv (phase method)", &p.uv),
                ("φ_vw (phase method)", &p.vw),
                ("φ_wu (phase method)", &p.wu),
            ] {
                let _ = writeln!(md, "| {n} | {} |", q(x, "°"));
            }
        }
        if let Some(m) = &entry.sensitivity_matrix {
            let _ = writeln!(
                md,
                "\nSensitivity matrix S ({su}; rows u, v, w; columns platter x, y, z), value (standard uncertainty):\n\n| | x | y | z |\n| --- | --- | --- | --- |"
            );
            for (j, row) in m.value.iter().enumerate() {
                let cells: Vec<String> = row
                    .iter()
                    .zip(&m.std_unc[j])
                    .map(|(v, u)| format!("{v:.9} ({u:.2e})"))
                    .collect();
                let _ = writeln!(md, "| {} | {} |", CHANNELS[j], cells.join(" | "));
            }
        }
        if let Some(p) = &entry.poses {
            let _ = writeln!(
                md,
                "\nPoses ({}; condition number {:.2}; {}: τ = {:.2e}, {:.2e}, {:.2e} {units}; k = {:.2} from ν = {}):\n\n\
                 | pose | ĝ | n | std u, v, w (how still) | residual u, v, w (mean − model) |\n| --- | --- | --- | --- | --- |",
                p.list.len(),
                p.condition_number,
                p.scatter,
                p.tau[0],
                p.tau[1],
                p.tau[2],
                p.k,
                p.nu.iter().fold(f64::INFINITY, |a, b| a.min(*b))
            );
            for q in &p.list {
                let std = q
                    .std
                    .map(|s| format!("{:.2e}, {:.2e}, {:.2e}", s[0], s[1], s[2]))
                    .unwrap_or_else(|| "single reading".into());
                let _ = writeln!(
                    md,
                    "| {} | {} | {} | {std} | {:+.2e}, {:+.2e}, {:+.2e} |",
                    q.name,
                    crate::calibrate::poses::direction_name(&q.gravity),
                    q.n,
                    q.residual[0],
                    q.residual[1],
                    q.residual[2]
                );
            }
            if let Some(s) = &p.suggestion {
                let _ = writeln!(
                    md,
                    "\n**Poorly conditioned**: add a pose with gravity along {s}."
                );
            }
            if !p.not_still.is_empty() {
                let _ = writeln!(md, "\n**Not still**: {}.", p.not_still.join(", "));
            }
            if let Some(d) = p.offsets_difference {
                let _ = writeln!(
                    md,
                    "\nOffsets of the joint fit minus those of each axis's up/down pair (imucal's estimator): {:+.6}, {:+.6}, {:+.6} {units}.",
                    d[0], d[1], d[2]
                );
            }
        }
        if let Some(c) = &entry.correction {
            let d = &c.device_frame;
            let _ = writeln!(
                md,
                "\nCorrection to m/s², a = M·(y − O), device frame (`rotacal apply`, `rotacal export`):\n\n| | M (m/s² per {units}) | O ± u ({units}) |\n| --- | --- | --- |"
            );
            for (j, row) in d.matrix.iter().enumerate() {
                let _ = writeln!(
                    md,
                    "| {} | {:.9}, {:.9}, {:.9} | {:.6} ± {:.1e} |",
                    ["x′", "y′", "z′"][j],
                    row[0],
                    row[1],
                    row[2],
                    d.offset[j],
                    d.offset_std_unc[j]
                );
            }
        }
        if let Some(f) = &entry.free {
            free::write(rec, f, &units, dir, &mut md)?;
        }
        if !entry.fits.is_empty() {
            let _ = writeln!(md, "\nFits (A sin α + B cos α + C, {units}):\n\n| condition | channel | A ± se | B ± se | C ± se | rms residual | n |\n| --- | --- | --- | --- | --- | --- | --- |");
        }
        for f in &entry.fits {
            let _ = writeln!(
                md,
                "| {} | {} | {:.4} ± {:.2e} | {:.4} ± {:.2e} | {:.4} ± {:.2e} | {:.4} | {} |",
                f.condition, f.channel, f.a, f.se_a, f.b, f.se_b, f.c, f.se_c, f.rms_residual, f.n
            );
        }
        let _ = writeln!(md);
        // Method free fits no sines: its groups (if any) were searched for still poses.
        let groups = if rec.method == Method::Free || entry.free.is_some() {
            &[][..]
        } else {
            &rec.groups[..]
        };
        // Single-rate and static files have no rate column: every group belongs to the entry.
        for g in groups
            .iter()
            .filter(|g| g.rate_hz.is_none() || g.rate_hz == entry.rate_hz)
        {
            let s = series(rec, g, entry)?;
            let fit = dir.join(format!("fit_{}.svg", s.stem));
            let res = dir.join(format!("residuals_{}.svg", s.stem));
            plot_fit(&s, &fit, &units)?;
            plot_residuals(&s, &res, &units)?;
            let _ = writeln!(
                md,
                "### {}\n\n![data and fit](fit_{stem}.svg)\n\n![residuals](residuals_{stem}.svg)",
                s.title,
                stem = s.stem
            );
            if s.rotation {
                let amps: Vec<Vec<f64>> = (0..3)
                    .map(|ch| harmonic_amplitudes(&s.alpha, &residuals(&s, ch)))
                    .collect();
                let spec = dir.join(format!("spectrum_{}.svg", s.stem));
                plot_spectrum(&s, &amps, &spec, &units)?;
                let _ = writeln!(md, "\n![residual spectrum](spectrum_{}.svg)\n", s.stem);
                let _ = writeln!(
                    md,
                    "Residual amplitude at k·ω ({units}):\n\n| harmonic k | u | v | w |\n| --- | --- | --- | --- |"
                );
                if let [u, v, w] = amps.as_slice() {
                    for (k, ((a, b), c)) in u.iter().zip(v).zip(w).enumerate() {
                        let _ = writeln!(md, "| {} | {a:.3e} | {b:.3e} | {c:.3e} |", k + 1);
                    }
                }
                let _ = writeln!(md);
            }
        }
    }
    if cal.by_rate.len() > 1 {
        plot_rates(&cal, &dir.join("rates.svg"))?;
        let _ = writeln!(
            md,
            "## Properties against rate\n\n![properties against rate](rates.svg)\n"
        );
    }
    let path = dir.join("report.md");
    std::fs::write(&path, md).map_err(err(&path))?;
    Ok(path)
}
