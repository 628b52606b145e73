//! `rotacal report FILE --out DIR`: a Markdown report with SVG plots (plotters).
//!
//! - the intrinsic-properties table with U (95 %; k = 2, or Student's t for few poses), the fits, and for static files the
//!   sensitivity matrix and offsets;
//! - per condition (and rate): the raw data with the fitted sines (like Gaitan & Geist (2022) Fig. 5),
//!   the residuals against time or angle, and for rotation the residual amplitude at the
//!   first harmonics of ω (each from a least-squares fit of sin kα, cos kα and a constant
//!   to the residuals, so it holds for records of any length);
//! - for multi-rate files, the properties against rate relative to the lowest rate, with
//!   U (k = 2) as error bars (like Gaitan & Geist (2022) Fig. 6);
//! - for method free: |y| against time with the still intervals marked, the
//!   fitted gravity directions, each pose's residual, and their tables;
//! - with `--slow-noise` (rotation): the residuals' Allan deviation against the noise
//!   model's lines, and each channel's slow levels.
//!
//! SVG needs no fonts at build or run time; the viewer renders the text.

pub mod allan;
pub mod discrepancy;
mod free;
pub mod html;

use crate::calibrate::json::{CalibrationJson, FitJson, Quantity, RateJson};
use crate::calibrate::{self, calibrate, CalibrateError, Options, CLOCK};
use crate::fit::harmonics::{HarmonicSums, HARMONICS};
use crate::recording::{Group, Method, Recording, Scanned};
use plotters::prelude::*;
use rotacal_shared::{Channel, Condition, PhaseStep, Ticks};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Most bins (pixel columns) a plotted series is reduced to: each keeps the smallest and
/// the largest value of its rows, so a long record is drawn as its envelope, spikes
/// included, in a file of fixed size.
const MAX_BINS: usize = 900;

/// What went wrong.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// The calibration failed (the message names file and line).
    #[error(transparent)]
    Calibrate(#[from] CalibrateError),
    /// Reading the file failed.
    #[error(transparent)]
    Read(#[from] crate::recording::RecordingError),
    /// Writing failed.
    #[error("{0}")]
    Write(String),
}

impl From<calibrate::stream::FileError> for ReportError {
    fn from(e: calibrate::stream::FileError) -> Self {
        match e {
            calibrate::stream::FileError::Read(e) => ReportError::Read(e),
            calibrate::stream::FileError::Calibrate(e) => ReportError::Calibrate(e),
        }
    }
}

/// One bin of an [`Envelope`]: its rows, the sum of their x, their least and greatest y.
#[derive(Clone, Copy, Debug)]
struct Bin {
    n: usize,
    x_sum: f64,
    lo: f64,
    hi: f64,
}

impl Bin {
    fn join(a: Option<Bin>, b: Option<Bin>) -> Option<Bin> {
        match (a, b) {
            (Some(a), Some(b)) => Some(Bin {
                n: a.n + b.n,
                x_sum: a.x_sum + b.x_sum,
                lo: a.lo.min(b.lo),
                hi: a.hi.max(b.hi),
            }),
            (a, b) => a.or(b),
        }
    }
}

/// A series of (x ≥ 0, y) reduced as it comes to at most [`MAX_BINS`] bins of x: when an x
/// lands past the last bin, the bins merge in pairs and their width doubles.
#[derive(Clone, Debug)]
pub(crate) struct Envelope {
    width: f64,
    bins: Vec<Option<Bin>>,
}

impl Default for Envelope {
    fn default() -> Self {
        Envelope {
            width: 1e-6,
            bins: vec![None; MAX_BINS],
        }
    }
}

impl Envelope {
    pub(crate) fn add(&mut self, x: f64, y: f64) {
        if !(x.is_finite() && y.is_finite()) {
            return;
        }
        let x = x.max(0.0);
        while (x / self.width) as usize >= MAX_BINS {
            // Bins 2i and 2i + 1 become bin i; the upper half empties.
            let merged: Vec<Option<Bin>> = self
                .bins
                .chunks_exact(2)
                .map(|pair| match *pair {
                    [a, b] => Bin::join(a, b),
                    _ => None,
                })
                .chain(std::iter::repeat(None))
                .take(MAX_BINS)
                .collect();
            self.bins = merged;
            self.width *= 2.0;
        }
        let i = (x / self.width) as usize;
        if let Some(slot) = self.bins.get_mut(i) {
            let one = Bin {
                n: 1,
                x_sum: x,
                lo: y,
                hi: y,
            };
            *slot = Bin::join(*slot, Some(one));
        }
    }

    /// Each bin's mean x, least and greatest y, in order of x.
    pub(crate) fn points(&self) -> impl Iterator<Item = (f64, f64, f64)> + '_ {
        self.bins
            .iter()
            .flatten()
            .map(|b| (b.x_sum / b.n as f64, b.lo, b.hi))
    }

    fn values(&self) -> impl Iterator<Item = f64> + '_ {
        self.points().flat_map(|(_, lo, hi)| [lo, hi])
    }
}

/// One group's data, model and residuals, as envelopes, and its residuals' harmonic sums.
pub(crate) struct Series {
    pub(crate) title: String,
    pub(crate) stem: String,
    pub(crate) x_label: &'static str,
    pub(crate) rotation: bool,
    data: [Envelope; 3],
    model: [Envelope; 3],
    resid: [Envelope; 3],
    harmonics: [HarmonicSums; 3],
    /// Stepped (static with table angles): the fit's A, B, C per channel, to draw it as
    /// the smooth curve it is rather than lines between the angles.
    curve: Option<[[f64; 3]; 3]>,
    /// Sum of squared residuals per channel, and rows: the noise floor of the spectrum.
    ss: [f64; 3],
    n: usize,
    /// The x range of the rows.
    x_range: (f64, f64),
}

impl Series {
    pub(crate) fn new(title: String, stem: String, x_label: &'static str, rotation: bool) -> Self {
        Series {
            title,
            stem,
            x_label,
            rotation,
            data: Default::default(),
            model: Default::default(),
            resid: Default::default(),
            harmonics: Default::default(),
            curve: None,
            ss: [0.0; 3],
            n: 0,
            x_range: (f64::INFINITY, f64::NEG_INFINITY),
        }
    }

    /// A row at `x` (s or deg) and table angle `alpha` (rad): its readings and the model's.
    pub(crate) fn add(&mut self, x: f64, alpha: f64, y: [f64; 3], model: [f64; 3]) {
        self.x_range = (self.x_range.0.min(x), self.x_range.1.max(x));
        let rotation = self.rotation;
        let envelopes = self
            .data
            .iter_mut()
            .zip(&mut self.model)
            .zip(&mut self.resid);
        let per_channel = envelopes
            .zip(&mut self.harmonics)
            .zip(y.into_iter().zip(model))
            .zip(&mut self.ss);
        self.n += 1;
        for (((((data, fit), resid), harmonics), (y, m)), ss) in per_channel {
            let r = y - m;
            if r.is_finite() {
                *ss += r * r;
            }
            data.add(x, y);
            fit.add(x, m);
            resid.add(x, r);
            if rotation {
                harmonics.add(alpha, r);
            }
        }
    }

    /// Per channel, the mean amplitude white noise of the residuals' RMS gives at one
    /// harmonic: the amplitude of a least-squares sine over n rows of noise σ is Rayleigh
    /// with scale σ·√(2/n), whose mean is σ·√(π/n).
    pub(crate) fn noise_floor(&self) -> [f64; 3] {
        let n = self.n.max(1) as f64;
        self.ss
            .map(|ss| (ss / n).sqrt() * (std::f64::consts::PI / n).sqrt())
    }

    /// The residuals' rms per row, per channel.
    pub(crate) fn row_rms(&self) -> [f64; 3] {
        let n = self.n.max(1) as f64;
        self.ss.map(|ss| (ss / n).sqrt())
    }

    /// The residual amplitude at each harmonic of ω, per channel.
    pub(crate) fn amplitudes(&self) -> Vec<Vec<f64>> {
        self.harmonics
            .iter()
            .map(HarmonicSums::amplitudes)
            .collect()
    }
}

fn coef(fits: &[FitJson], cond: Condition, ch: Channel) -> Option<[f64; 3]> {
    fits.iter()
        .find(|f| f.condition == cond && f.channel == ch)
        .map(|f| [f.a, f.b, f.c])
}

/// How a group's rows become points: the model's coefficients and, for rotation, the
/// rate its angle turns at.
struct GroupPlot {
    coefs: [[f64; 3]; 3],
    step: Option<PhaseStep>,
}

impl GroupPlot {
    fn new(cond: Condition, entry: &RateJson, rotation: bool) -> Result<Self, ReportError> {
        let coefs = Channel::ALL.map(|ch| coef(&entry.fits, cond, ch).unwrap_or([f64::NAN; 3]));
        let step = if rotation {
            let rate = entry
                .fits
                .iter()
                .find(|f| f.condition == cond)
                .and_then(|f| f.rate_hz_fitted)
                .or(entry.rate_hz)
                .unwrap_or(0.0);
            Some(
                PhaseStep::from_hz(rate, CLOCK)
                    .ok_or_else(|| ReportError::Write(format!("rate {rate} Hz unusable")))?,
            )
        } else {
            None
        };
        Ok(GroupPlot { coefs, step })
    }

    /// The x, angle and model of a row: a rotation row by its conversions (an average is
    /// drawn at their mean instant), a static one by its table angle (deg). A row with
    /// neither is at x and angle NaN: drawn nowhere.
    fn point(
        &self,
        ap: Option<&rotacal_shared::Aperture>,
        angle_deg: Option<f64>,
    ) -> (f64, f64, [f64; 3]) {
        let (x, alpha) = match (self.step, ap, angle_deg) {
            (Some(step), Some(ap), _) => {
                let n = ap.len().max(1) as u64;
                let mid = Ticks(ap.ticks().map(|t| t.0).sum::<u64>() / n);
                (
                    mid.0 as f64 / f64::from(CLOCK.hz()),
                    step.phase_at(mid).radians(),
                )
            }
            (_, _, Some(a)) => (a, a.to_radians()),
            (_, _, None) => (f64::NAN, f64::NAN),
        };
        let model = self
            .coefs
            .map(|[a, b, c]| a * alpha.sin() + b * alpha.cos() + c);
        (x, alpha, model)
    }
}

/// The title and file stem of a group's plots.
fn names(cond: char, rate_hz: Option<f64>) -> (String, String) {
    let rate = rate_hz.map(|r| format!(" at {r} Hz")).unwrap_or_default();
    let stem = match rate_hz {
        Some(r) => format!("{cond}_{}mhz", (r * 1000.0).round()),
        None => cond.to_string(),
    };
    (format!("condition {cond}{rate}"), stem)
}

fn x_label(rotation: bool) -> &'static str {
    if rotation {
        "time from the condition's first sample (s)"
    } else {
        "table angle α (deg)"
    }
}

fn series(rec: &Recording, g: &Group, entry: &RateJson) -> Result<Series, ReportError> {
    let cond = g.condition.letter();
    let rotation = match rec.method {
        Method::Rotation => true,
        Method::Free => {
            return Err(ReportError::Write(
                "method free has no per-condition fits to plot".into(),
            ))
        }
        Method::Static => false,
    };
    let plot = GroupPlot::new(g.condition, entry, rotation)?;
    let (title, stem) = names(cond, entry.rate_hz);
    let mut s = Series::new(title, stem, x_label(rotation), rotation);
    if !rotation {
        s.curve = Some(plot.coefs);
    }
    let samples = if rotation {
        // A condition in several boots, joined as its calibration joined it.
        match entry.rate_hz {
            Some(r) => calibrate::joined(rec, g, r)?.0,
            None => calibrate::samples(rec, g)?,
        }
    } else {
        Vec::new()
    };
    // Rotation: each row's conversions (none for a file without t_s); static: its angle.
    let (mut aps, mut angles) = (samples.iter().map(|(ap, _)| ap), g.angle_deg.iter());
    for ((&u, &v), &w) in g.u.iter().zip(&g.v).zip(&g.w) {
        let (x, alpha, model) = plot.point(aps.next(), angles.next().copied());
        s.add(x, alpha, [u, v, w], model);
    }
    Ok(s)
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

/// An SVG of `size` drawn by `draw` in memory, then written to `path` whole or not at all.
pub(crate) fn svg(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(&DrawingArea<SVGBackend<'_>, plotters::coord::Shift>) -> Result<(), ReportError>,
) -> Result<(), ReportError> {
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, size).into_drawing_area();
        draw(&root)?;
        root.present().map_err(err(path))?;
    }
    crate::atomic::write(path, buf).map_err(err(path))
}

/// What a legend entry shows beside its label.
#[derive(Clone, Copy)]
pub(crate) enum Key {
    /// A dot (data).
    Dot,
    /// A line (a fit).
    Line,
    /// A dashed line (a reference level).
    Dashed,
    /// A pale band (an interval of the axis).
    Band,
}

/// A legend beside the plots, outside the data: one line per entry from the top of `area`.
pub(crate) fn side_legend(
    area: &DrawingArea<SVGBackend<'_>, plotters::coord::Shift>,
    entries: &[(String, RGBColor, Key)],
    path: &Path,
) -> Result<(), ReportError> {
    for (i, (label, c, key)) in entries.iter().enumerate() {
        let y = 40 + 22 * i as i32;
        match key {
            Key::Dot => area
                .draw(&Circle::new((16, y), 4, c.filled()))
                .map_err(err(path))?,
            Key::Line => area
                .draw(&PathElement::new(vec![(6, y), (26, y)], c.stroke_width(2)))
                .map_err(err(path))?,
            Key::Band => area
                .draw(&Rectangle::new(
                    [(6, y - 6), (26, y + 6)],
                    c.mix(0.25).filled(),
                ))
                .map_err(err(path))?,
            Key::Dashed => {
                for x in [6, 14, 22] {
                    area.draw(&PathElement::new(
                        vec![(x, y), (x + 5, y)],
                        c.stroke_width(2),
                    ))
                    .map_err(err(path))?;
                }
            }
        }
        area.draw(&Text::new(
            label.clone(),
            (34, y - 8),
            ("sans-serif", 14).into_font(),
        ))
        .map_err(err(path))?;
    }
    Ok(())
}

/// The plot's drawing area, white, split into the plots (three panels, one per channel,
/// stacked) and a legend column at the right.
#[allow(clippy::type_complexity)]
fn panels<'b>(
    root: &DrawingArea<SVGBackend<'b>, plotters::coord::Shift>,
    width: u32,
    legend: u32,
    path: &Path,
) -> Result<
    (
        Vec<DrawingArea<SVGBackend<'b>, plotters::coord::Shift>>,
        DrawingArea<SVGBackend<'b>, plotters::coord::Shift>,
    ),
    ReportError,
> {
    root.fill(&WHITE).map_err(err(path))?;
    let (plots, side) = root.split_horizontally(width - legend);
    Ok((plots.split_evenly((3, 1)), side))
}

/// An envelope's bins as marks: a bar from each bin's least to its greatest value (a dot
/// for a bin of one value).
fn marks(e: &Envelope, c: RGBColor) -> Vec<PathElement<(f64, f64)>> {
    e.points()
        .map(|(x, lo, hi)| PathElement::new(vec![(x, lo), (x, hi)], c.stroke_width(2)))
        .collect()
}

/// Raw data (each pixel column's range) and the fitted sines (a line through each
/// column's range), a panel per channel.
fn plot_fit(s: &Series, path: &Path, units: &str) -> Result<(), ReportError> {
    svg(path, (900, 720), |root| {
        let (areas, side) = panels(root, 900, 150, path)?;
        let (x0, x1) = range([s.x_range.0, s.x_range.1].into_iter());
        let per_channel = s.data.iter().zip(&s.model).zip(COLOURS).zip(CHANNELS);
        for (i, ((((data, model), c), name), area)) in per_channel.zip(&areas).enumerate() {
            let (y0, y1) = range(data.values().chain(model.values()));
            let mut chart = chart(
                area,
                path,
                &format!("{}: {name}", s.title),
                15,
                (x0, x1),
                (y0, y1),
                s.x_label,
                units,
            )?;
            let line: Vec<(f64, f64)> = match (s.curve, Channel::ALL.get(i)) {
                // Stepped: the readings as points, the fitted sine as the curve it is.
                (Some(coefs), Some(ch)) => {
                    let [a, b, cc] = *ch.of(&coefs);
                    chart
                        .draw_series(
                            data.points()
                                .flat_map(|(x, lo, hi)| [(x, lo), (x, hi)])
                                .map(|p| Circle::new(p, 3, c.filled())),
                        )
                        .map_err(err(path))?;
                    let steps = 720;
                    (0..=steps)
                        .map(|k| {
                            let x = x0 + (x1 - x0) * k as f64 / steps as f64;
                            let r = x.to_radians();
                            (x, a * r.sin() + b * r.cos() + cc)
                        })
                        .collect()
                }
                _ => {
                    chart.draw_series(marks(data, c)).map_err(err(path))?;
                    model
                        .points()
                        .flat_map(|(x, lo, hi)| [(x, lo), (x, hi)])
                        .collect()
                }
            };
            chart
                .draw_series(LineSeries::new(line, BLACK.stroke_width(1)))
                .map_err(err(path))?;
        }
        let mut entries: Vec<(String, RGBColor, Key)> = CHANNELS
            .iter()
            .zip(COLOURS)
            .map(|(n, c)| (format!("{n}: data"), c, Key::Dot))
            .collect();
        entries.push(("fitted sine".into(), BLACK, Key::Line));
        side_legend(&side, &entries, path)?;
        Ok(())
    })
}

/// Residuals against time or angle (each pixel column's range), a panel per channel.
pub(crate) fn plot_residuals(s: &Series, path: &Path, units: &str) -> Result<(), ReportError> {
    svg(path, (900, 620), |root| {
        let (areas, side) = panels(root, 900, 150, path)?;
        let (x0, x1) = range([s.x_range.0, s.x_range.1].into_iter());
        for (((e, c), name), area) in s.resid.iter().zip(COLOURS).zip(CHANNELS).zip(&areas) {
            let (y0, y1) = range(e.values());
            let mut chart = chart(
                area,
                path,
                &format!("{}: residuals of {name}", s.title),
                15,
                (x0, x1),
                (y0, y1),
                s.x_label,
                &format!("data − fit ({units})"),
            )?;
            chart.draw_series(marks(e, c)).map_err(err(path))?;
        }
        let entries: Vec<(String, RGBColor, Key)> = CHANNELS
            .iter()
            .zip(COLOURS)
            .map(|(n, c)| (format!("{n}: data − fit"), c, Key::Dot))
            .collect();
        side_legend(&side, &entries, path)?;
        Ok(())
    })
}

/// Residual amplitude at the harmonics 2…8 of ω on a log axis (k = 1 is fitted, so it is
/// zero), with each channel's white-noise floor.
pub(crate) fn plot_spectrum(
    s: &Series,
    amps: &[Vec<f64>],
    path: &Path,
    units: &str,
) -> Result<(), ReportError> {
    svg(path, (850, 420), |root| {
        root.fill(&WHITE).map_err(err(path))?;
        let (plot, side) = root.split_horizontally(850 - 190);
        let floor = s.noise_floor();
        let shown = amps
            .iter()
            .flat_map(|a| a.iter().skip(1).copied())
            .chain(floor)
            .filter(|v| *v > 0.0 && v.is_finite());
        let (lo, hi) = shown.fold((f64::INFINITY, 0.0f64), |(l, h), v| (l.min(v), h.max(v)));
        let (lo, hi) = if lo.is_finite() && hi > 0.0 {
            (lo / 3.0, hi * 3.0)
        } else {
            (1e-6, 1.0)
        };
        let mut chart = ChartBuilder::on(&plot)
            .caption(
                format!("{}: residual amplitude at k·ω", s.title),
                ("sans-serif", 16),
            )
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(80)
            .build_cartesian_2d(1.5f64..(HARMONICS as f64 + 0.5), (lo..hi).log_scale())
            .map_err(err(path))?;
        chart
            .configure_mesh()
            .x_desc("harmonic k (k = 1 is fitted)")
            .y_desc(format!("amplitude ({units})"))
            .x_labels(HARMONICS)
            .x_label_formatter(&|x| format!("{x:.0}"))
            .draw()
            .map_err(err(path))?;
        for (ch, ((a, c), f)) in amps.iter().zip(COLOURS).zip(floor).enumerate() {
            let off = (ch as f64 - 1.0) * 0.2;
            chart
                .draw_series(a.iter().enumerate().skip(1).map(|(k, v)| {
                    let x = k as f64 + 1.0 + off;
                    Rectangle::new([(x - 0.09, lo), (x + 0.09, v.max(lo))], c.filled())
                }))
                .map_err(err(path))?;
            chart
                .draw_series(DashedLineSeries::new(
                    [(1.5, f), (HARMONICS as f64 + 0.5, f)],
                    6,
                    4,
                    c.stroke_width(1),
                ))
                .map_err(err(path))?;
        }
        let mut entries: Vec<(String, RGBColor, Key)> = CHANNELS
            .iter()
            .zip(COLOURS)
            .map(|(n, c)| (n.to_string(), c, Key::Dot))
            .collect();
        entries.extend(
            CHANNELS
                .iter()
                .zip(COLOURS)
                .map(|(n, c)| (format!("{n}: white-noise floor"), c, Key::Dashed)),
        );
        side_legend(&side, &entries, path)?;
        Ok(())
    })
}

/// Static poses (stepped angles, six positions, any known orientations): each pose's
/// residual (mean − model) per channel, a panel per channel, with bars of ±k·√(se² + τ²),
/// the spread the pose fit allows a pose's mean (its readings' noise and the poses'
/// scatter τ; k from ν).
fn plot_poses(
    p: &crate::calibrate::json::PosesJson,
    path: &Path,
    units: &str,
) -> Result<(), ReportError> {
    let n = p.list.len();
    let width = (480 + 26 * n as u32).clamp(760, 1400);
    svg(path, (width, 660), |root| {
        let (areas, side) = panels(root, width, 210, path)?;
        let names: Vec<&str> = p.list.iter().map(|q| q.name.as_str()).collect();
        // At most about 24 names under the axis: every `every`-th pose is named.
        let every = n.div_ceil(24).max(1);
        for (ci, ((c, name), area)) in COLOURS.iter().zip(CHANNELS).zip(&areas).enumerate() {
            let tau = p.tau.get(ci).copied().unwrap_or(0.0);
            let pts: Vec<(i32, f64, f64)> = p
                .list
                .iter()
                .enumerate()
                .map(|(i, q)| {
                    let r = q.residual.get(ci).copied().unwrap_or(f64::NAN);
                    let se = q.std_err.and_then(|s| s.get(ci).copied()).unwrap_or(0.0);
                    (i as i32, r, p.k * (se * se + tau * tau).sqrt())
                })
                .collect();
            let (y0, y1) = range(pts.iter().flat_map(|(_, r, b)| [r - b, r + b, 0.0]));
            let mut chart = ChartBuilder::on(area)
                .caption(format!("poses: residual of {name}"), ("sans-serif", 15))
                .margin(10)
                .x_label_area_size(40)
                .y_label_area_size(70)
                .build_cartesian_2d((0..n as i32).into_segmented(), y0..y1)
                .map_err(err(path))?;
            chart
                .configure_mesh()
                .x_labels(n)
                .x_label_formatter(&|v| match v {
                    SegmentValue::CenterOf(i) | SegmentValue::Exact(i) => usize::try_from(*i)
                        .ok()
                        .filter(|i| i % every == 0)
                        .and_then(|i| names.get(i))
                        .map_or(String::new(), |s| s.to_string()),
                    SegmentValue::Last => String::new(),
                })
                .y_desc(format!("mean − model ({units})"))
                .draw()
                .map_err(err(path))?;
            chart
                .draw_series(pts.iter().map(|(i, r, b)| {
                    ErrorBar::new_vertical(
                        SegmentValue::CenterOf(*i),
                        r - b,
                        *r,
                        r + b,
                        c.filled(),
                        6,
                    )
                }))
                .map_err(err(path))?;
        }
        let mut entries: Vec<(String, RGBColor, Key)> = CHANNELS
            .iter()
            .zip(COLOURS)
            .map(|(n, c)| (n.to_string(), c, Key::Dot))
            .collect();
        entries.push(("bars: ±k·√(se² + τ²)".to_string(), BLACK, Key::Line));
        entries.push((format!("k = {:.2}", p.k), BLACK, Key::Line));
        side_legend(&side, &entries, path)?;
        Ok(())
    })
}

/// s_u, s_v, s_w.
fn sensitivities(e: &RateJson) -> [&Quantity; 3] {
    let s = &e.intrinsic.sensitivity;
    [&s.u, &s.v, &s.w]
}

/// φ_uv, φ_vw, φ_wu.
fn angles(e: &RateJson) -> [&Quantity; 3] {
    let a = &e.intrinsic.angle_deg;
    [&a.uv, &a.vw, &a.wu]
}

/// Properties against rate (a log axis: rates span decades), relative to the lowest rate,
/// with U as error bars: sensitivities in parts per million, angles in degrees; the legend
/// beside the panels.
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
    svg(path, (900, 700), |root| {
        root.fill(&WHITE).map_err(err(path))?;
        let (plots, side) = root.split_horizontally(900 - 130);
        let (top, bottom) = plots.split_vertically(350);
        let rate = |e: &RateJson| e.rate_hz.unwrap_or(0.0);
        let (lo, hi) = entries
            .iter()
            .map(|e| rate(e))
            .filter(|r| *r > 0.0)
            .fold((f64::INFINITY, 0.0f64), |(l, h), r| (l.min(r), h.max(r)));
        let (x0, x1) = if lo.is_finite() && hi > 0.0 {
            (lo / 1.5, hi * 1.5)
        } else {
            (1e-3, 1.0)
        };
        type Pick = fn(&RateJson) -> [&Quantity; 3];
        let mut legend_entries = Vec::new();
        for (panel, area, pick, names, scale, unit) in [
            (
                "sensitivities",
                &top,
                sensitivities as Pick,
                ["s_u", "s_v", "s_w"],
                1e6,
                "Δs / s (ppm)",
            ),
            (
                "angles",
                &bottom,
                angles as Pick,
                ["φ_uv", "φ_vw", "φ_wu"],
                1.0,
                "Δφ (deg)",
            ),
        ] {
            let base = pick(first).map(|q| q.value);
            // Per property, its points (rate, change, U) in order of rate.
            let mut pts: [Vec<(f64, f64, f64)>; 3] = Default::default();
            for e in &entries {
                for ((series, q), base) in pts.iter_mut().zip(pick(e)).zip(base) {
                    let norm = if scale == 1.0 { 1.0 } else { base };
                    series.push((
                        rate(e),
                        (q.value - base) / norm * scale,
                        q.expanded_unc / norm * scale,
                    ));
                }
            }
            let (y0, y1) = range(pts.iter().flatten().flat_map(|(_, v, u)| [v - u, v + u]));
            let mut chart = ChartBuilder::on(area)
                .caption(
                    format!(
                        "{panel} against rate, relative to {} Hz (bars: U)",
                        rate(first)
                    ),
                    ("sans-serif", 16),
                )
                .margin(10)
                .x_label_area_size(40)
                .y_label_area_size(70)
                .build_cartesian_2d((x0..x1).log_scale(), y0..y1)
                .map_err(err(path))?;
            chart
                .configure_mesh()
                .x_desc("rotation rate (Hz, log scale)")
                .y_desc(unit)
                .draw()
                .map_err(err(path))?;
            for (i, ((series, c), name)) in pts.iter().zip(COLOURS).zip(names).enumerate() {
                // Side by side around each rate, by a fixed ratio on the log axis.
                let f = 1.0 + 0.015 * (i as f64 - 1.0);
                chart
                    .draw_series(series.iter().map(|(x, y, u)| {
                        ErrorBar::new_vertical(x * f, y - u, *y, y + u, c.filled(), 6)
                    }))
                    .map_err(err(path))?;
                legend_entries.push((name.to_string(), c, Key::Dot));
            }
        }
        side_legend(&side, &legend_entries, path)?;
        Ok(())
    })
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

/// Write the report; returns the Markdown file's path and the calibration.
pub fn write(
    rec: &Recording,
    opts: &Options,
    dir: &Path,
) -> Result<(PathBuf, CalibrationJson), ReportError> {
    let cal = calibrate(rec, opts)?;
    let mut groups = |entry: &RateJson| -> Result<Vec<Series>, ReportError> {
        // Method free fits no sines: its groups (if any) were searched for still poses.
        if rec.method == Method::Free || entry.free.is_some() {
            return Ok(Vec::new());
        }
        // Single-rate and static files have no rate column: every group belongs to the entry.
        rec.groups
            .iter()
            .filter(|g| g.rate_hz.is_none() || g.rate_hz == entry.rate_hz)
            .map(|g| series(rec, g, entry))
            .collect()
    };
    let mut free = |f: &calibrate::json::FreeJson, units: &str, md: &mut String| {
        free::write(rec, f, units, dir, md)
    };
    let path = markdown(&cal, &rec.source, rec.rows(), dir, &mut groups, &mut free)?;
    Ok((path, cal))
}

/// [`write`] for the recording at `path`: a rotation file streams (calibrated by
/// [`calibrate::stream`], its plots reduced to pixel columns as the rows come), in
/// memory that does not grow with its length; any other is read whole.
pub fn write_file(
    path: &Path,
    opts: &Options,
    dir: &Path,
) -> Result<(PathBuf, CalibrationJson), ReportError> {
    let rotation = match opts.method {
        Some(Method::Static | Method::Free) => false,
        _ => crate::recording::Parts::open(path, opts.method)?
            .is_some_and(|p| p.method() == Method::Rotation),
    };
    if !rotation {
        let rec = crate::recording::read_as(path, opts.method)?;
        return write(&rec, opts, dir);
    }
    let cal = calibrate::stream::calibrate_file(path, opts)?;
    let (mut by_entry, rows) = streamed_series(path, opts, &cal)?;
    let mut groups = |entry: &RateJson| -> Result<Vec<Series>, ReportError> {
        let i = cal.by_rate.iter().position(|e| std::ptr::eq(e, entry));
        Ok(i.and_then(|i| by_entry.get_mut(i))
            .map(std::mem::take)
            .unwrap_or_default())
    };
    let mut free = |_: &calibrate::json::FreeJson, _: &str, _: &mut String| Ok(());
    let md = markdown(
        &cal,
        &path.display().to_string(),
        rows,
        dir,
        &mut groups,
        &mut free,
    )?;
    Ok((md, cal))
}

/// Each rate entry's series, from one pass over a rotation file; and the rows read.
fn streamed_series(
    path: &Path,
    opts: &Options,
    cal: &CalibrationJson,
) -> Result<(Vec<Vec<Series>>, usize), ReportError> {
    /// A group's entry, its series' place among the entry's, how its points are made.
    struct Open {
        entry: usize,
        slot: usize,
        plot: GroupPlot,
        t0: Option<f64>,
    }
    let mut out: Vec<Vec<Series>> = cal.by_rate.iter().map(|_| Vec::new()).collect();
    let mut open: Vec<Option<Open>> = Vec::new();
    let mut scale = 1.0;
    let mut rows = 0usize;
    let mut problem: Option<ReportError> = None;
    crate::recording::scan(
        path,
        opts.method,
        crate::recording::Parse::Fit,
        |ev| match ev {
            Scanned::Start { meta, .. } => {
                // A second reading (the csv reader's) starts afresh.
                out.iter_mut().for_each(Vec::clear);
                open.clear();
                rows = 0;
                scale = crate::recording::tick_scale(&meta, CLOCK);
            }
            Scanned::Group {
                condition, rate_hz, ..
            } => {
                let entry = cal
                    .by_rate
                    .iter()
                    .position(|e| rate_hz.is_none() || rate_hz == e.rate_hz);
                let made = entry.and_then(|i| {
                    let e = cal.by_rate.get(i)?;
                    let cond = condition.letter();
                    match GroupPlot::new(condition, e, true) {
                        Ok(plot) => {
                            let (title, stem) = names(cond, e.rate_hz);
                            let list = out.get_mut(i)?;
                            list.push(Series::new(title, stem, x_label(true), true));
                            Some(Open {
                                entry: i,
                                slot: list.len() - 1,
                                plot,
                                t0: None,
                            })
                        }
                        Err(e) => {
                            problem = Some(e);
                            None
                        }
                    }
                });
                open.push(made);
            }
            Scanned::Row {
                group,
                t_s: Some(t),
                y,
                conv_gaps,
                ..
            } => {
                rows += 1;
                let Some(Some(g)) = open.get_mut(group) else {
                    return;
                };
                let t0 = *g.t0.get_or_insert(t);
                let Ok(ap) =
                    crate::recording::row_aperture(t, t0, conv_gaps.as_ref(), scale, CLOCK)
                else {
                    return;
                };
                let (x, alpha, model) = g.plot.point(Some(&ap), None);
                if let Some(s) = out.get_mut(g.entry).and_then(|v| v.get_mut(g.slot)) {
                    s.add(x, alpha, y, model);
                }
            }
            Scanned::Row { .. } => rows += 1,
        },
    )?;
    match problem {
        Some(e) => Err(e),
        None => Ok((out, rows)),
    }
}

/// An entry's table of properties (the six, the offsets and the phase method's angles
/// when it has them), and its sensitivity matrix if any.
fn property_tables(md: &mut String, entry: &RateJson, units: &str) {
    let su = format!("{units}/(m/s²)");
    let _ = writeln!(
        md,
        "| property | value ± U (k = {} unless stated) |\n| --- | --- |",
        crate::calibrate::json::K
    );
    let six = sensitivities(entry).into_iter().map(|x| (x, su.as_str()));
    let six = six.chain(angles(entry).into_iter().map(|x| (x, "°")));
    for (name, (x, unit)) in crate::calibrate::json::PROPERTY_NAMES.iter().zip(six) {
        let _ = writeln!(md, "| {} | {} |", name, q(x, unit));
    }
    if let Some(o) = &entry.intrinsic.offset {
        for (n, x) in [("O_u", &o.u), ("O_v", &o.v), ("O_w", &o.w)] {
            let _ = writeln!(md, "| {n} | {} |", q(x, units));
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
        for ((row, unc), name) in m.value.iter().zip(&m.std_unc).zip(CHANNELS) {
            let cells: Vec<String> = row
                .iter()
                .zip(unc)
                .map(|(v, u)| format!("{v:.9} ({u:.2e})"))
                .collect();
            let _ = writeln!(md, "| {} | {} |", name, cells.join(" | "));
        }
    }
}

/// A static entry's poses: their table, and what the fit says of them.
fn pose_table(md: &mut String, p: &crate::calibrate::json::PosesJson, units: &str) {
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

/// The correction to m/s² in the device frame: its matrix and offsets.
fn correction_table(md: &mut String, c: &crate::calibrate::json::CorrectionJson, units: &str) {
    let d = &c.device_frame;
    let _ = writeln!(
        md,
        "\nCorrection to m/s², a = M·(y − O), device frame (`rotacal apply`, `rotacal export`):\n\n| | M (m/s² per {units}) | O ± u ({units}) |\n| --- | --- | --- |"
    );
    let rows = d.matrix.iter().zip(&d.offset).zip(&d.offset_std_unc);
    for (name, ((row, offset), unc)) in ["x′", "y′", "z′"].into_iter().zip(rows) {
        let _ = writeln!(
            md,
            "| {} | {:.9}, {:.9}, {:.9} | {:.6} ± {:.1e} |",
            name, row[0], row[1], row[2], offset, unc
        );
    }
}

/// With `--slow-noise`: an entry's residual Allan deviations against the model's lines
/// (one panel per condition and channel), and each channel's slow levels.
fn residual_allan(
    md: &mut String,
    entry: &RateJson,
    units: &str,
    dir: &Path,
) -> Result<(), ReportError> {
    let modelled: Vec<_> = entry
        .noise
        .iter()
        .flatten()
        .filter_map(|n| n.slow.as_ref().map(|s| (n, s)))
        .filter(|(_, s)| !s.residual_allan.is_empty())
        .collect();
    if modelled.is_empty() {
        return Ok(());
    }
    let stem = entry
        .rate_hz
        .map(|r| format!("_{}mhz", (r * 1000.0).round()))
        .unwrap_or_default();
    let file = format!("allan_residuals{stem}.svg");
    let panels: Vec<allan::ResidualPanel<'_>> = modelled
        .iter()
        .map(|(n, s)| allan::ResidualPanel {
            title: format!("condition {}, channel {}", n.condition, n.channel),
            points: &s.residual_allan,
        })
        .collect();
    allan::write_residual(&panels, &dir.join(&file), units)?;
    let rate = entry
        .rate_hz
        .map(|r| format!(" at {r} Hz"))
        .unwrap_or_default();
    let _ = writeln!(
        md,
        "## Allan deviation of the residuals{rate}\n\n\
         Each fit's residuals (points, with the 1σ interval of their noise type where one \
         can be given) against what the noise model predicts for them through the same fit \
         (lines): the short-range AR model, flicker and random walk at the levels estimated \
         from the residuals (docs/uncertainty.md, \"Slow noise\"). Where the points leave \
         the model's line, the model does not describe the data at that averaging time.\n\n\
         ![residual Allan deviation]({file})\n\n\
         | channel | flicker floor ({units}) | flicker floor (µg) | random walk ({units}/√s) \
         | random walk (µg/√s) |\n| --- | --- | --- | --- | --- |"
    );
    // The levels are one per channel, pooled over the groups: each channel once.
    let mut seen = Vec::new();
    for (n, s) in &modelled {
        if seen.contains(&n.channel) {
            continue;
        }
        seen.push(n.channel);
        let term = |t: &Option<crate::calibrate::json::SlowTerm>, ug: bool| match t {
            Some(t) if ug => match (t.value_ug, t.u_ug) {
                (Some(v), Some(u)) => format!("{v:.3} (u = {u:.3})"),
                _ => "–".into(),
            },
            Some(t) => format!("{:.4} (u = {:.4})", t.value, t.u),
            None => "not positive".into(),
        };
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} |",
            n.channel,
            term(&s.terms.flicker_floor, false),
            term(&s.terms.flicker_floor, true),
            term(&s.terms.random_walk_per_sqrt_s, false),
            term(&s.terms.random_walk_per_sqrt_s, true),
        );
    }
    let _ = writeln!(md);
    Ok(())
}

/// The report's Markdown and plots, from a calibration and each rate entry's series.
#[allow(clippy::type_complexity)]
fn markdown(
    cal: &CalibrationJson,
    source: &str,
    rows: usize,
    dir: &Path,
    groups: &mut dyn FnMut(&RateJson) -> Result<Vec<Series>, ReportError>,
    free: &mut dyn FnMut(&calibrate::json::FreeJson, &str, &mut String) -> Result<(), ReportError>,
) -> Result<PathBuf, ReportError> {
    std::fs::create_dir_all(dir).map_err(err(dir))?;
    let units = cal.units.clone();
    let mut md = String::new();
    let _ = writeln!(md, "# rotacal report: {source}\n");
    let _ = writeln!(
        md,
        "Method {}, g_loc = {} m/s², units {units}, {rows} rows. Uncertainties are expanded, U (95 %, coverage factor k as stated).\n",
        cal.method,
        cal.g_loc,
    );
    for entry in &cal.by_rate {
        let heading = match (entry.rate_hz, &entry.free) {
            (Some(r), _) => format!("Rotation at {r} Hz"),
            (None, Some(_)) => "Free poses (unknown orientation)".into(),
            (None, None) => "Static".into(),
        };
        let _ = writeln!(md, "## {heading}\n");
        property_tables(&mut md, entry, &units);
        if let Some(p) = &entry.poses {
            pose_table(&mut md, p, &units);
            let stem = entry.rate_hz.map_or("poses".to_string(), |r| {
                format!("poses_{}mhz", (r * 1e3).round())
            });
            plot_poses(p, &dir.join(format!("{stem}.svg")), &units)?;
            let _ = writeln!(md, "\n![pose residuals]({stem}.svg)\n");
        }
        if let Some(c) = &entry.correction {
            correction_table(&mut md, c, &units);
        }
        if let Some(f) = &entry.free {
            free(f, &units, &mut md)?;
        }
        if !entry.fits.is_empty() {
            // The fit weighs a row of n conversions n times: its rms is one conversion's,
            // √n above the rows' own, which the residual plots show (issue 34: 10.9
            // against 4.2 for the demo's rows of six or seven conversions).
            let _ = writeln!(md, "\nFits (A sin α + B cos α + C, {units}; rms residual: a single conversion's, where rows average conversions; the plots' rows scatter √n less):\n\n| condition | channel | A ± se | B ± se | C ± se | rms residual | n |\n| --- | --- | --- | --- | --- | --- | --- |");
        }
        for f in &entry.fits {
            let _ = writeln!(
                md,
                "| {} | {} | {:.4} ± {:.2e} | {:.4} ± {:.2e} | {:.4} ± {:.2e} | {:.4} | {} |",
                f.condition, f.channel, f.a, f.se_a, f.b, f.se_b, f.c, f.se_c, f.rms_residual, f.n
            );
        }
        let _ = writeln!(md);
        for s in groups(entry)? {
            let fit = dir.join(format!("fit_{}.svg", s.stem));
            let res = dir.join(format!("residuals_{}.svg", s.stem));
            plot_fit(&s, &fit, &units)?;
            plot_residuals(&s, &res, &units)?;
            let rms = s.row_rms();
            let _ = writeln!(
                md,
                "### {}\n\n![data and fit](fit_{stem}.svg)\n\n![residuals](residuals_{stem}.svg)\n\n\
                 rms of the plotted residuals, per row: u {:.4}, v {:.4}, w {:.4} {units}",
                s.title,
                rms[0],
                rms[1],
                rms[2],
                stem = s.stem
            );
            if s.rotation {
                let amps = s.amplitudes();
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
    for entry in &cal.by_rate {
        residual_allan(&mut md, entry, &units, dir)?;
    }
    if cal.by_rate.len() > 1 {
        plot_rates(cal, &dir.join("rates.svg"))?;
        let _ = writeln!(
            md,
            "## Properties against rate\n\n![properties against rate](rates.svg)\n"
        );
    }
    let path = dir.join("report.md");
    crate::atomic::write(&path, md).map_err(err(&path))?;
    Ok(path)
}
