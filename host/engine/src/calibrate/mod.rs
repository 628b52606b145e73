//! `rotacal calibrate`: from a recording to the calibration JSON and a terminal table.
//!
//! One pipeline per method, each written once: [`preflight`] settles local gravity, the
//! type-B inputs, the method and the units; then
//! - `rotation`: per nominal rate and condition a group's fit (`group`: the IEEE 1057 fit
//!   tests whether the data's rotation rate differs from nominal by more than 3 standard
//!   errors, and if so that rate is used and reported as `rate_hz_fitted`; the sine fit
//!   in f64 with its covariance under the noise estimated from its residuals), from the
//!   rows held in memory or from a streamed file's sums ([`stream`]); the plan of rates,
//!   its checks and the assembly of the entries are the same for both;
//! - `stepped`: the static methods, from angle steps or known orientations ([`poses`]);
//! - `free_method`: still intervals found ([`still`]) and G and O from |a| = g ([`free`]).
//!
//! Timestamps are converted to ticks of a 1 MHz clock (t_s has microsecond resolution in
//! every writer we know of).
//!
//! The other parts: [`methods`] (rotation and stepped methods from fits, the static method
//! from poses, their Monte Carlo), [`budget`] (GUM arithmetic; `sources` the budget lines
//! every method shares), [`correction`] (the correction M·(y − O) and its covariance),
//! [`json`] (the calibration JSON, docs/formats.md) and [`table`] (the terminal summary).

mod bisect;
pub mod budget;
pub mod correction;
mod drift;
mod error;
pub mod free;
mod free_method;
mod group;
pub mod hints;
pub mod json;
pub mod methods;
pub mod noise_from;
mod pilot;
pub mod poses;
mod rotation;
mod sources;
mod stepped;
pub mod still;
pub mod stream;
pub mod structure;
pub mod table;

/// Readings a pose or a still interval needs for a noise model of its own; shorter poses
/// share one pooled over them. (A model's correction for the mean taken out needs N well
/// above the noise's correlation time.)
pub const NOISE_MODEL_MIN: usize = 100;

pub(crate) use error::err;
pub use error::{CalibrateError, CalibrateErrorKind, GroupError, RateError};
pub use free_method::{detection_summary, segments, Segment};
pub use group::{joined, samples, GroupFit};
pub use rotation::rotation_correction;
pub use stepped::{static_budget, static_correction};

use crate::calibrate::json::CalibrationJson;
use crate::recording::{Method, Recording};
use rotacal_shared::TickRate;

/// Command-line choices, which override the file's metadata.
#[derive(Clone, Debug, Default)]
pub struct Options {
    /// Force the method.
    pub method: Option<Method>,
    /// Nominal rotation rate, Hz.
    pub rate_hz: Option<f64>,
    /// Local gravity, m/s².
    pub g_loc: Option<f64>,
    /// Also propagate by Monte Carlo (GUM Supplement 1) with this many trials.
    pub monte_carlo: Option<usize>,
    /// Static data: pose weighting and offset estimator.
    pub poses: poses::Options,
    /// Method free: how still intervals are found.
    pub still: still::Options,
    /// Standard uncertainties of the type-B inputs (override the file's `u_*` keys).
    pub inputs: TypeB,
    /// Rotation: also model flicker and a bias random walk; free: allow for them in the
    /// moved test (`--slow-noise`; under validation, docs/uncertainty.md, "Slow noise").
    pub slow_noise: bool,
    /// Rotation with `slow_noise`: a still recording of the same device, pooled with the
    /// recording's groups in the slow levels' estimate (`--noise-from FILE`).
    pub noise_from: Option<std::sync::Arc<noise_from::NoiseFrom>>,
}

/// Standard uncertainties of the inputs that are not in the data (type B).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TypeB {
    /// Local gravity, m/s² (`--u-g-loc`, `# u_g_loc=`).
    pub u_g_loc: Option<f64>,
    /// Each timestamp beyond its resolution (jitter), s (`--u-time-s`, `# u_time_s=`).
    pub u_time_s: Option<f64>,
    /// Each stepped table angle, degrees (`--u-angle-deg`, `# u_angle_deg=`).
    pub u_angle_deg: Option<f64>,
}

impl TypeB {
    /// These, else the recording's metadata.
    fn or_file(self, rec: &Recording) -> TypeB {
        TypeB {
            u_g_loc: self.u_g_loc.or(rec.meta.uncertainty("u_g_loc")),
            u_time_s: self.u_time_s.or(rec.meta.uncertainty("u_time_s")),
            u_angle_deg: self.u_angle_deg.or(rec.meta.uncertainty("u_angle_deg")),
        }
    }
}

/// The clock rotation timestamps are converted to (t_s has microsecond resolution).
pub const CLOCK: TickRate = TickRate::MHZ_1;

/// What every calibration settles first: local gravity, the type-B inputs, the method and
/// the units, each checked.
pub(crate) struct Preflight {
    /// Local gravity, m/s².
    pub g_loc: f64,
    /// The type-B inputs: the command line's, else the file's.
    pub inputs: TypeB,
    /// The method: the command line's, else the file's.
    pub method: Method,
    /// The readings' units.
    pub units: String,
}

impl Preflight {
    /// The calibration JSON of `by_rate` (one entry for the static and free methods).
    pub fn json(self, by_rate: Vec<json::RateJson>) -> CalibrationJson {
        CalibrationJson {
            method: self.method,
            g_loc: self.g_loc,
            units: self.units,
            by_rate,
            residual_structure: None,
        }
    }
}

/// Local gravity, the type-B inputs, the method and the units of `rec` under `opts`.
pub(crate) fn preflight(rec: &Recording, opts: &Options) -> Result<Preflight, CalibrateError> {
    let g = opts
        .g_loc
        .or(rec.meta.g_loc)
        .ok_or_else(|| err(rec, None, CalibrateErrorKind::NoGravity))?;
    if !(g.is_finite() && g > 0.0) {
        return Err(err(rec, None, CalibrateErrorKind::BadGravity(g)));
    }
    let inputs = opts.inputs.or_file(rec);
    if let Some((option, value)) = [
        ("--u-g-loc", inputs.u_g_loc),
        ("--u-time-s", inputs.u_time_s),
    ]
    .into_iter()
    .find_map(|(n, u)| u.filter(|u| !(u.is_finite() && *u >= 0.0)).map(|u| (n, u)))
    {
        return Err(err(
            rec,
            None,
            CalibrateErrorKind::BadUncertainty { option, value },
        ));
    }
    let method = opts.method.unwrap_or(rec.method);
    if opts.noise_from.is_some() && method != Method::Rotation {
        return Err(err(rec, None, CalibrateErrorKind::NoiseFromMethod(method)));
    }
    let units = rec
        .meta
        .units
        .clone()
        .unwrap_or_else(|| "output units".into());
    Ok(Preflight {
        g_loc: g,
        inputs,
        method,
        units,
    })
}

/// The nominal rotation rate of a group whose `rate_hz` column says `column`: that, else
/// the command line's, else the file's metadata's.
pub(crate) fn nominal_rate(
    column: Option<f64>,
    opts: &Options,
    meta: &crate::recording::Metadata,
) -> Option<f64> {
    column.or(opts.rate_hz).or(meta.rate_hz)
}

/// Calibrate a recording.
pub fn calibrate(rec: &Recording, opts: &Options) -> Result<CalibrationJson, CalibrateError> {
    let pre = preflight(rec, opts)?;
    let entry = match pre.method {
        Method::Rotation => return rotation::calibrate_held(rec, opts, pre),
        Method::Free => free_method::entry(rec, opts, &pre)?,
        Method::Static => stepped::entry(rec, opts, &pre)?,
    };
    Ok(pre.json(vec![entry]))
}
