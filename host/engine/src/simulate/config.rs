//! The simulator's configuration: TOML, optionally layered over a named preset.
//!
//! Every section and key is optional except the device; every effect is off unless its
//! table is present. Units are stated per key. Unknown keys are errors, so that a typo
//! never silently turns an effect off. See docs/simulator.md.

use super::FilterError;
use crate::recording::Method;
use serde::Deserialize;

/// The presets, as TOML documents (host/presets/).
pub const PRESETS: [(&str, &str); 3] = [
    (
        "paper-10mhz",
        include_str!("../../../presets/paper-10mhz.toml"),
    ),
    (
        "paper-multirate",
        include_str!("../../../presets/paper-multirate.toml"),
    ),
    (
        "metrologia-static",
        include_str!("../../../presets/metrologia-static.toml"),
    ),
];

/// The LSM6DS33's acceleration noise density (datasheet, ±2 g, high-performance mode),
/// g/√Hz; with its count of 0.061 mg this gives the default noise.
pub const LSM6DS33_NOISE_DENSITY_G: f64 = 90e-6;
/// The LSM6DS33's sensitivity at ±2 g, g per count.
pub const LSM6DS33_G_PER_COUNT: f64 = 0.061e-3;

/// A simulated experiment.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// The preset this file builds on (its keys are overridden by this file's).
    #[serde(default)]
    pub preset: Option<String>,
    /// Seed of every random draw: the same seed and config give the same file.
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// `rotation` (constant rate, seed 000) or `static` (angle steps, seed 001).
    #[serde(default = "default_method")]
    pub method: Method,
    /// Local gravity, m/s².
    #[serde(default = "default_g")]
    pub g_loc: f64,
    /// The device's output units (free text; `counts` enables the LSM6DS33 noise default).
    #[serde(default = "default_units")]
    pub units: String,
    /// The device under test.
    pub device: Device,
    /// How it sits on the platter.
    #[serde(default)]
    pub mounting: Mounting,
    /// Noise and the output stage.
    #[serde(default)]
    pub sensor: Sensor,
    /// Sampling and timestamps.
    #[serde(default)]
    pub timing: Timing,
    /// What the table does.
    #[serde(default)]
    pub table: Table,
    /// The temperature profile written to `temp_c`.
    #[serde(default)]
    pub temperature: Temperature,
    /// Physical effects beyond the papers' model, each off unless given.
    #[serde(default)]
    pub effects: Effects,
    /// Method `free`: still poses of unknown orientation, put down by hand.
    #[serde(default)]
    pub poses: Option<FreePoses>,
}

/// A session of still poses without a table (`method = "free"`): the device is put down
/// in `count` orientations, turned from one to the next over `move_s` seconds (along the
/// great circle, eased in and out), and left still for `still_s` seconds.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FreePoses {
    /// Number of poses (ignored when `directions` is given).
    #[serde(default = "default_pose_count")]
    pub count: usize,
    /// ĝ of each pose in the platter (fixture) frame; default: drawn uniformly over the
    /// sphere from the seed.
    #[serde(default)]
    pub directions: Option<Vec<[f64; 3]>>,
    /// Time still at each pose, s.
    #[serde(default = "default_still_s")]
    pub still_s: f64,
    /// Time to turn from one pose to the next, s.
    #[serde(default = "default_move_s")]
    pub move_s: f64,
    /// Each pose's noise is the sensor's times a factor drawn log-uniformly from
    /// [1/spread, spread] (a hand, a bench, a fan: poses are not equally quiet). 1: none.
    #[serde(default = "default_spread")]
    pub noise_spread: f64,
    /// A ring-down after each placement: amplitude of the specific force, m/s², along a
    /// random direction, decaying with 0.1 s at 12 Hz.
    #[serde(default)]
    pub settle_ms2: f64,
    /// One pose that is not still: it turns steadily through `deg` degrees.
    #[serde(default)]
    pub moved: Option<MovedPose>,
}

/// A pose that turns while it should be still.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MovedPose {
    /// Which pose (0-based).
    pub pose: usize,
    /// How far it turns over its still time, degrees.
    pub deg: f64,
}

fn default_pose_count() -> usize {
    12
}
fn default_still_s() -> f64 {
    4.0
}
fn default_move_s() -> f64 {
    2.0
}
fn default_spread() -> f64 {
    1.0
}

impl Default for FreePoses {
    fn default() -> Self {
        FreePoses {
            count: default_pose_count(),
            directions: None,
            still_s: default_still_s(),
            move_s: default_move_s(),
            noise_spread: default_spread(),
            settle_ms2: 0.0,
            moved: None,
        }
    }
}

fn default_seed() -> u64 {
    1
}
fn default_method() -> Method {
    Method::Rotation
}
fn default_g() -> f64 {
    9.80665
}
fn default_units() -> String {
    "counts".into()
}

/// The device: either its intrinsic properties (then S is built in its own frame, u
/// along x and v in the xy plane) or a full sensitivity matrix, plus offsets.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Device {
    /// Written to the `device` metadata.
    #[serde(default)]
    pub name: Option<String>,
    /// s_u, s_v, s_w, output units per m/s².
    #[serde(default)]
    pub sensitivity: Option<[f64; 3]>,
    /// φ_uv, φ_vw, φ_wu, degrees.
    #[serde(default)]
    pub angles_deg: Option<[f64; 3]>,
    /// S (rows u, v, w; columns the device's x, y, z), output units per m/s².
    #[serde(default)]
    pub matrix: Option<[[f64; 3]; 3]>,
    /// O_u, O_v, O_w, output units.
    #[serde(default)]
    pub offsets: [f64; 3],
}

/// The mounting misalignment: any rotation, as an axis and angle or as a matrix.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Mounting {
    /// Rotation axis (any length).
    #[serde(default = "default_axis")]
    pub axis: [f64; 3],
    /// Rotation angle, degrees.
    #[serde(default)]
    pub angle_deg: f64,
    /// The rotation matrix (instead of axis and angle).
    #[serde(default)]
    pub matrix: Option<[[f64; 3]; 3]>,
}

fn default_axis() -> [f64; 3] {
    [0.0, 0.0, 1.0]
}

impl Default for Mounting {
    fn default() -> Self {
        Mounting {
            axis: default_axis(),
            angle_deg: 0.0,
            matrix: None,
        }
    }
}

/// Noise, quantisation and the output range.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Sensor {
    /// White noise per sample, output units. Default (counts only): the LSM6DS33's
    /// 90 µg/√Hz over the band up to half the sample rate.
    #[serde(default)]
    pub noise_sigma: Option<f64>,
    /// Quantisation step, output units; 0 turns quantisation off.
    #[serde(default = "default_lsb")]
    pub lsb: f64,
    /// The output register's range [low, high], output units: readings are clipped to it.
    #[serde(default = "default_full_scale")]
    pub full_scale: [f64; 2],
    /// Serially correlated noise and per-channel levels, instead of `noise_sigma`'s white
    /// noise (`[sensor.noise]`). Without it the noise is white at `noise_sigma`.
    #[serde(default)]
    pub noise: Option<Noise>,
}

/// `[sensor.noise]`: each channel's noise is an independent stationary process (white,
/// autoregressive or low-passed) with a stated marginal standard deviation.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Noise {
    /// The marginal standard deviation of each channel's noise, output units, before
    /// quantisation: one for all channels or one per channel. Default: `noise_sigma`'s.
    #[serde(default)]
    pub sd: Option<NoiseSd>,
    /// AR coefficients φ1…φp: e_t = φ1·e_{t−1} + … + φp·e_{t−p} + innovation.
    #[serde(default)]
    pub ar: Option<Vec<f64>>,
    /// Instead of `ar`: white noise through a 2nd-order digital Butterworth low-pass of
    /// this cutoff, Hz (below half the sample rate).
    #[serde(default)]
    pub lowpass_hz: Option<f64>,
    /// Whether the file states `noise_sigma` (it does only when the noise is white and one
    /// level for all channels).
    #[serde(default = "default_true")]
    pub state: bool,
}

fn default_true() -> bool {
    true
}

/// `sensor.noise.sd`: one level, or u, v, w.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(untagged, expecting = "expected one number, or three (u, v, w)")]
pub enum NoiseSd {
    /// The same for all channels.
    All(f64),
    /// Per channel u, v, w.
    PerChannel([f64; 3]),
}

fn default_lsb() -> f64 {
    1.0
}
fn default_full_scale() -> [f64; 2] {
    [-32768.0, 32767.0]
}

impl Default for Sensor {
    fn default() -> Self {
        Sensor {
            noise_sigma: None,
            lsb: default_lsb(),
            full_scale: default_full_scale(),
            noise: None,
        }
    }
}

/// Sampling and timestamps.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Timing {
    /// Samples per second (of true time).
    #[serde(default = "default_fs")]
    pub sample_rate_hz: f64,
    /// The device clock's rate error, ppm: timestamps are (1 + ε)·t.
    #[serde(default)]
    pub clock_error_ppm: f64,
    /// Timestamp jitter (standard deviation), s. At most 0.05 of the sample period.
    #[serde(default)]
    pub jitter_s: f64,
    /// Probability that a sample is lost (its `seq` is skipped).
    #[serde(default)]
    pub drop_probability: f64,
    /// Timestamp resolution: ticks per second of the device clock.
    #[serde(default = "default_tick_hz")]
    pub tick_hz: f64,
    /// Time between one condition (or rate) and the next, s.
    #[serde(default = "default_gap")]
    pub gap_s: f64,
}

fn default_fs() -> f64 {
    16.0
}
fn default_tick_hz() -> f64 {
    1e6
}
fn default_gap() -> f64 {
    60.0
}

impl Default for Timing {
    fn default() -> Self {
        Timing {
            sample_rate_hz: default_fs(),
            clock_error_ppm: 0.0,
            jitter_s: 0.0,
            drop_probability: 0.0,
            tick_hz: default_tick_hz(),
            gap_s: default_gap(),
        }
    }
}

/// What the table does.
#[derive(Clone, Debug, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct Table {
    /// Rotation: nominal rates, Hz (several make a multi-rate file). Default 0.01.
    #[serde(default)]
    pub rates_hz: Option<Vec<f64>>,
    /// Rotation: samples per condition and rate.
    #[serde(default)]
    pub samples_per_condition: Option<u64>,
    /// Rotation: record length per condition and rate, s (instead of a sample count).
    #[serde(default)]
    pub duration_s: Option<f64>,
    /// Rotation: the table angle at each condition's first sample, degrees, for x, y, z.
    /// Default: drawn uniformly from the seed (the method does not know it).
    #[serde(default)]
    pub start_angle_deg: Option<[f64; 3]>,
    /// Static: the angle list, degrees.
    #[serde(default)]
    pub angles_deg: Option<Vec<f64>>,
    /// Static: 0, step, 2·step, … below 360° (instead of a list).
    #[serde(default)]
    pub angle_step_deg: Option<f64>,
    /// Static: readings at each angle (one sample period apart).
    #[serde(default)]
    pub readings_per_angle: Option<u32>,
    /// Static: time from one angle to the next, s.
    #[serde(default)]
    pub dwell_s: Option<f64>,
}

/// The temperature profile T(t) = t0 + ramp·t + swing·sin(2πt/period), written to
/// `temp_c` at the given resolution; `temperature_offset` acts on T − t0.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Temperature {
    /// °C at the start of the session.
    #[serde(default = "default_t0")]
    pub t0_c: f64,
    /// °C per hour.
    #[serde(default)]
    pub ramp_c_per_h: f64,
    /// Amplitude of a periodic swing, °C (air conditioning cycling, for example).
    #[serde(default)]
    pub swing_c: f64,
    /// Its period, s.
    #[serde(default = "default_swing_period")]
    pub period_s: f64,
    /// Resolution of the written temperature, °C.
    #[serde(default = "default_t_res")]
    pub resolution_c: f64,
}

fn default_t0() -> f64 {
    25.0
}
fn default_swing_period() -> f64 {
    1800.0
}
fn default_t_res() -> f64 {
    0.01
}

impl Default for Temperature {
    fn default() -> Self {
        Temperature {
            t0_c: default_t0(),
            ramp_c_per_h: 0.0,
            swing_c: 0.0,
            period_s: default_swing_period(),
            resolution_c: default_t_res(),
        }
    }
}

/// The effects of formats.md, each a physical parameterisation (docs/simulator.md).
#[derive(Clone, Debug, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct Effects {
    /// The table turns at (1 + relative) times the nominal rate.
    #[serde(default)]
    pub rate_error: Option<RateError>,
    /// Offsets drift linearly in session time.
    #[serde(default)]
    pub offset_drift: Option<OffsetDrift>,
    /// Offsets follow temperature.
    #[serde(default)]
    pub temperature_offset: Option<TemperatureOffset>,
    /// Quadratic response along each sensitive axis.
    #[serde(default)]
    pub nonlinearity_2nd: Option<Nonlinearity2>,
    /// Cubic response along each sensitive axis.
    #[serde(default)]
    pub nonlinearity_3rd: Option<Nonlinearity3>,
    /// The analog output saturates at rails inside the output range.
    #[serde(default)]
    pub saturation: Option<Saturation>,
    /// The sensor sits off the rotation axis.
    #[serde(default)]
    pub centripetal: Option<Centripetal>,
    /// Channels are sampled at slightly different times.
    #[serde(default)]
    pub axis_time_skew: Option<AxisTimeSkew>,
    /// The rate varies once per revolution.
    #[serde(default)]
    pub rate_ripple: Option<RateRipple>,
    /// Static: each step of the table lands off its nominal orientation.
    #[serde(default)]
    pub step_error: Option<StepError>,
}

/// `step_error`: at each step (condition and angle) the table's true angle is the nominal
/// one plus a normal error, and the platter is tilted by a small random rotation, normal
/// about each axis; the file states the nominal angle. Independent from step to step.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct StepError {
    /// Standard deviation of the angle error, degrees.
    #[serde(default)]
    pub angle_sd_deg: f64,
    /// Standard deviation of the tilt about each axis, degrees.
    #[serde(default)]
    pub tilt_sd_deg: f64,
}

/// `rate_error`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RateError {
    /// True rate / nominal − 1.
    pub relative: f64,
}

/// `offset_drift`: O_j + D_j·t, t in seconds from the start of the session.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct OffsetDrift {
    /// D_u, D_v, D_w, output units per second.
    pub per_s: [f64; 3],
}

/// `temperature_offset`: O_j + c_j·(T − t0).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TemperatureOffset {
    /// c_u, c_v, c_w, output units per °C.
    pub per_c: [f64; 3],
}

/// `nonlinearity_2nd`: the output is s_j·(a + K2_j·a²) with a the acceleration along
/// axis j.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Nonlinearity2 {
    /// K2 per channel, 1/(m/s²).
    pub k2: [f64; 3],
}

/// `nonlinearity_3rd`: s_j·(a + K3_j·a³).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Nonlinearity3 {
    /// K3 per channel, 1/(m/s²)².
    pub k3: [f64; 3],
}

/// `saturation`: the analog output (noise included) is clipped to [low, high].
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Saturation {
    /// [low, high], output units.
    pub rails: [f64; 2],
}

/// `centripetal`: the sensor sits `radius_m` from the rotation axis, so it also senses
/// −ω²·r along the outward direction (fixed in the platter frame).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Centripetal {
    /// Distance from the axis, m.
    pub radius_m: f64,
    /// Outward direction from the axis to the sensor in the platter frame, for the x, y
    /// and z conditions (the part along the axis is removed). Default +y, +z, +x.
    #[serde(default)]
    pub directions: Option<[[f64; 3]; 3]>,
}

/// `axis_time_skew`: channel j is sampled at t + τ_j.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct AxisTimeSkew {
    /// τ_u, τ_v, τ_w, s.
    pub skew_s: [f64; 3],
}

/// `rate_ripple`: dα/dt = ω·(1 + ε·cos(ωτ + ψ)), so the angle carries ε·sin(ωτ + ψ).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RateRipple {
    /// ε, relative rate ripple (equal to the angle ripple in radians).
    pub relative: f64,
    /// ψ, degrees.
    #[serde(default)]
    pub phase_deg: f64,
}

/// A configuration problem, naming the key (or the file or preset).
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// A key's value, or a combination of keys, is refused.
    #[error("{key}: {why}")]
    Invalid {
        /// The key or keys, dotted (`timing.jitter_s`).
        key: &'static str,
        /// What the value must be.
        why: &'static str,
    },
    /// A key holds a value that is not finite.
    #[error("{key}: values must be finite")]
    NotFinite {
        /// The key, dotted.
        key: &'static str,
    },
    /// A key that belongs to another method.
    #[error("{key}: applies to method = \"{method}\" only")]
    OtherMethod {
        /// The key, dotted.
        key: &'static str,
        /// The method or methods it belongs to.
        method: &'static str,
    },
    /// No noise level, and units the LSM6DS33 default does not apply to.
    #[error(
        "{key}: give it (the LSM6DS33 default applies only to units = \"counts\", not \"{units}\")"
    )]
    NoNoiseLevel {
        /// `sensor.noise.sd` or `sensor.noise_sigma`.
        key: &'static str,
        /// The configuration's units.
        units: String,
    },
    /// A low-pass cutoff outside (0, fs/2).
    #[error(
        "sensor.noise.lowpass_hz: must lie between 0 and half the sample rate ({nyquist_hz} Hz)"
    )]
    Lowpass {
        /// Half the sample rate, Hz.
        nyquist_hz: f64,
    },
    /// A noise filter that cannot be simulated. Its text is part of this one's (not a
    /// `source`: the CLI prints the chain, which would repeat it).
    #[error("sensor.noise.{key}: {cause}")]
    NoiseFilter {
        /// `ar` or `lowpass_hz`.
        key: &'static str,
        /// Why.
        cause: FilterError,
    },
    /// Not TOML.
    #[error("{}", syntax_text(.0))]
    Syntax(toml::de::Error),
    /// TOML, but not a configuration (an unknown key, a wrong type).
    #[error("{}", .0.to_string().trim_end())]
    Schema(toml::de::Error),
    /// `preset = "…"` names no preset.
    #[error("unknown preset '{name}' (presets: {})", preset_names())]
    UnknownPreset {
        /// The name given.
        name: String,
    },
    /// A built-in preset that is not TOML: a bug, as the presets are part of rotacal.
    #[error("internal: preset {name}: {cause} (a bug in rotacal; please report it)")]
    Preset {
        /// The preset.
        name: String,
        /// The parser's complaint.
        cause: toml::de::Error,
    },
    /// Neither a file nor a preset.
    #[error("{name}: no such file, and not a preset (presets: {})", preset_names())]
    NotFound {
        /// The name or path given.
        name: String,
    },
    /// The file could not be read.
    #[error("{path}: {cause}")]
    Read {
        /// The file.
        path: String,
        /// Why.
        cause: std::io::Error,
    },
    /// The file's configuration is refused.
    #[error("{path}: {cause}")]
    InFile {
        /// The file.
        path: String,
        /// Why.
        cause: Box<ConfigError>,
    },
}

/// A TOML syntax error's text, its snippet's lines indented under the first.
fn syntax_text(e: &toml::de::Error) -> String {
    e.to_string().trim_end().replace('\n', "\n  ")
}

/// The presets' names, for messages.
fn preset_names() -> String {
    let names: Vec<&str> = PRESETS.iter().map(|(n, _)| *n).collect();
    names.join(", ")
}

fn preset_text(name: &str) -> Result<&'static str, ConfigError> {
    PRESETS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, t)| *t)
        .ok_or_else(|| ConfigError::UnknownPreset {
            name: name.to_string(),
        })
}

/// Later tables override earlier ones key by key; other values replace.
fn merge(base: &mut toml::Table, over: toml::Table) {
    for (k, v) in over {
        match (base.get_mut(&k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge(b, o),
            (_, v) => {
                base.insert(k, v);
            }
        }
    }
}

/// Keys that say the same thing in different ways, per section (a dot reaches into a
/// sub-table): setting one in a file replaces the preset's other.
const ALTERNATIVES: [(&str, &[&str], &[&str]); 5] = [
    ("device", &["sensitivity", "angles_deg"], &["matrix"]),
    ("mounting", &["axis", "angle_deg"], &["matrix"]),
    ("table", &["samples_per_condition"], &["duration_s"]),
    ("table", &["angles_deg"], &["angle_step_deg"]),
    ("sensor", &["noise_sigma"], &["noise.sd"]),
];

/// The table holding `path`'s last key, and that key.
fn parent<'a>(t: &'a toml::Table, path: &'a str) -> Option<(&'a toml::Table, &'a str)> {
    match path.split_once('.') {
        Some((head, rest)) => match t.get(head) {
            Some(toml::Value::Table(sub)) => parent(sub, rest),
            _ => None,
        },
        None => Some((t, path)),
    }
}

fn remove_path(t: &mut toml::Table, path: &str) {
    match path.split_once('.') {
        Some((head, rest)) => {
            if let Some(toml::Value::Table(sub)) = t.get_mut(head) {
                remove_path(sub, rest);
            }
        }
        None => {
            t.remove(path);
        }
    }
}

/// Drop from `base` whatever `over` replaces by an alternative key.
fn drop_replaced(base: &mut toml::Table, over: &toml::Table) {
    for (section, one, other) in ALTERNATIVES {
        let (Some(toml::Value::Table(b)), Some(toml::Value::Table(o))) =
            (base.get_mut(section), over.get(section))
        else {
            continue;
        };
        for (mine, theirs) in [(one, other), (other, one)] {
            let given = |k: &&str| parent(o, k).is_some_and(|(t, key)| t.contains_key(key));
            if mine.iter().any(given) {
                for k in theirs.iter() {
                    remove_path(b, k);
                }
            }
        }
    }
}

impl Config {
    /// A preset by name.
    pub fn preset(name: &str) -> Result<Config, ConfigError> {
        Config::from_toml(&format!("preset = \"{name}\"\n"))
    }

    /// A TOML file at `name_or_path`, else the preset of that name; errors name it.
    pub fn load(name_or_path: &str) -> Result<Config, ConfigError> {
        let path = std::path::Path::new(name_or_path);
        if path.exists() {
            let text = std::fs::read_to_string(path).map_err(|cause| ConfigError::Read {
                path: name_or_path.to_string(),
                cause,
            })?;
            Config::from_toml(&text).map_err(|cause| ConfigError::InFile {
                path: name_or_path.to_string(),
                cause: Box::new(cause),
            })
        } else if PRESETS.iter().any(|(n, _)| *n == name_or_path) {
            Config::preset(name_or_path)
        } else {
            Err(ConfigError::NotFound {
                name: name_or_path.to_string(),
            })
        }
    }

    /// Parse TOML text; a `preset = "…"` key layers it over that preset.
    pub fn from_toml(text: &str) -> Result<Config, ConfigError> {
        let table: toml::Table = text.parse().map_err(ConfigError::Syntax)?;
        let merged = match table.get("preset") {
            Some(toml::Value::String(name)) => {
                let mut base: toml::Table =
                    preset_text(name)?
                        .parse()
                        .map_err(|cause| ConfigError::Preset {
                            name: name.clone(),
                            cause,
                        })?;
                drop_replaced(&mut base, &table);
                merge(&mut base, table);
                base
            }
            Some(_) => {
                return Err(ConfigError::Invalid {
                    key: "preset",
                    why: "expected a preset name",
                })
            }
            None => table,
        };
        let cfg: Config = toml::Value::Table(merged)
            .try_into()
            .map_err(ConfigError::Schema)?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// The white-noise standard deviation per sample, output units.
    pub fn noise_sigma(&self) -> Result<f64, ConfigError> {
        match self.sensor.noise_sigma {
            Some(s) => Ok(s),
            None if self.units == "counts" => Ok(LSM6DS33_NOISE_DENSITY_G
                * (self.timing.sample_rate_hz / 2.0).sqrt()
                / LSM6DS33_G_PER_COUNT),
            None => Err(ConfigError::NoNoiseLevel {
                key: if self.sensor.noise.is_some() {
                    "sensor.noise.sd"
                } else {
                    "sensor.noise_sigma"
                },
                units: self.units.clone(),
            }),
        }
    }

    /// The marginal standard deviation of each channel's noise (u, v, w), output units,
    /// before quantisation: `sensor.noise.sd`, else `noise_sigma()` for all three.
    pub fn noise_sd(&self) -> Result<[f64; 3], ConfigError> {
        match self.sensor.noise.as_ref().and_then(|n| n.sd.as_ref()) {
            Some(NoiseSd::All(s)) => Ok([*s; 3]),
            Some(NoiseSd::PerChannel(s)) => Ok(*s),
            None => self.noise_sigma().map(|s| [s; 3]),
        }
    }

    /// Rotation: the nominal rates.
    pub fn rates_hz(&self) -> Vec<f64> {
        self.table.rates_hz.clone().unwrap_or_else(|| vec![0.01])
    }

    /// Rotation: samples per condition and rate.
    pub fn samples_per_condition(&self) -> u64 {
        match (self.table.samples_per_condition, self.table.duration_s) {
            (Some(n), _) => n,
            (None, Some(d)) => (d * self.timing.sample_rate_hz).round() as u64,
            (None, None) => 4200,
        }
    }

    /// Static: the angle list, degrees.
    pub fn static_angles(&self) -> Vec<f64> {
        if let Some(a) = &self.table.angles_deg {
            return a.clone();
        }
        let step = self.table.angle_step_deg.unwrap_or(5.0);
        let n = (360.0 / step - 1e-9).ceil() as usize;
        (0..n).map(|i| i as f64 * step).collect()
    }

    /// Checks every key's range and the combinations allowed, one section after another
    /// in a fixed order, so the first error reported is always the same one.
    fn validate(&self) -> Result<(), ConfigError> {
        if !(self.g_loc.is_finite() && self.g_loc > 0.0) {
            return bad("g_loc", "must be a positive number of m/s²");
        }
        self.device.validate()?;
        self.mounting.validate()?;
        self.validate_sensor()?;
        self.timing.validate()?;
        self.validate_noise_model()?;
        self.validate_method()?;
        self.temperature.validate()?;
        self.effects.validate()
    }

    /// `[sensor]`: the white noise, the quantisation and the range. The noise model is
    /// checked after `[timing]`, as it needs the sample rate.
    fn validate_sensor(&self) -> Result<(), ConfigError> {
        let s = &self.sensor;
        if let Some(n) = s.noise_sigma {
            if !(n.is_finite() && n >= 0.0) {
                return bad("sensor.noise_sigma", "must be ≥ 0");
            }
        }
        self.noise_sd()?;
        if !(s.lsb.is_finite() && s.lsb >= 0.0) {
            return bad("sensor.lsb", "must be ≥ 0 (0: no quantisation)");
        }
        finite("sensor.full_scale", &s.full_scale)?;
        if s.full_scale[0] >= s.full_scale[1] {
            return bad("sensor.full_scale", "low must be below high");
        }
        Ok(())
    }

    /// `[sensor.noise]`: one level given, not two, and a process that can be built at
    /// the sample rate.
    fn validate_noise_model(&self) -> Result<(), ConfigError> {
        let Some(nz) = &self.sensor.noise else {
            return Ok(());
        };
        if self.sensor.noise_sigma.is_some() && nz.sd.is_some() {
            return bad(
                "sensor.noise_sigma and sensor.noise.sd",
                "give one, not both (sd is the marginal level of [sensor.noise])",
            );
        }
        if self
            .noise_sd()?
            .iter()
            .any(|x| !(x.is_finite() && *x >= 0.0))
        {
            return bad("sensor.noise.sd", "must be ≥ 0");
        }
        super::NoiseProcess::new(nz, self.timing.sample_rate_hz)?;
        Ok(())
    }

    /// The keys of the method chosen, and none that belong to another method only.
    fn validate_method(&self) -> Result<(), ConfigError> {
        if self.method != Method::Free && self.poses.is_some() {
            return bad("poses", "applies to method = \"free\" only");
        }
        match self.method {
            Method::Rotation => self.validate_rotation(),
            Method::Free => self.validate_free(),
            Method::Static => self.validate_static(),
        }
    }

    /// Rotation: the rates, how long each condition lasts and the start angles.
    fn validate_rotation(&self) -> Result<(), ConfigError> {
        let tb = &self.table;
        let rates = self.rates_hz();
        if rates.is_empty() || rates.iter().any(|r| !(r.is_finite() && *r > 0.0)) {
            return bad("table.rates_hz", "give one or more positive rates");
        }
        if tb.duration_s.is_some() && tb.samples_per_condition.is_some() {
            return bad(
                "table",
                "give samples_per_condition or duration_s, not both",
            );
        }
        if let Some(d) = tb.duration_s {
            if !(d.is_finite() && d > 0.0) {
                return bad("table.duration_s", "must be positive");
            }
        }
        if self.samples_per_condition() < 8 {
            return bad("table.samples_per_condition", "must be at least 8");
        }
        if let Some(a) = tb.start_angle_deg {
            finite("table.start_angle_deg", &a)?;
        }
        only_for(
            "static",
            &[&self.effects.static_keys()[..], &tb.static_keys()].concat(),
        )
    }

    /// Free: no table or table effect, and poses that can be simulated.
    fn validate_free(&self) -> Result<(), ConfigError> {
        let (tb, fx) = (&self.table, &self.effects);
        only_for(
            "rotation or static",
            &[
                &tb.rotation_keys()[..],
                &tb.static_keys(),
                &fx.rotation_keys(),
                &fx.static_keys(),
            ]
            .concat(),
        )?;
        self.poses.clone().unwrap_or_default().validate()
    }

    /// Static: the angle list or step, the readings per angle and the dwell.
    fn validate_static(&self) -> Result<(), ConfigError> {
        let tb = &self.table;
        only_for(
            "rotation",
            &[&tb.rotation_keys()[..], &self.effects.rotation_keys()].concat(),
        )?;
        if tb.angles_deg.is_some() && tb.angle_step_deg.is_some() {
            return bad("table", "give angles_deg or angle_step_deg, not both");
        }
        if let Some(step) = tb.angle_step_deg {
            if !(step.is_finite() && step > 0.0 && step <= 120.0) {
                return bad("table.angle_step_deg", "must lie in (0, 120]");
            }
        }
        if let Some(a) = &tb.angles_deg {
            finite("table.angles_deg", a)?;
            if a.len() < 3 {
                return bad("table.angles_deg", "give at least 3 angles");
            }
        }
        if tb.readings_per_angle == Some(0) {
            return bad("table.readings_per_angle", "must be at least 1");
        }
        if let Some(d) = tb.dwell_s {
            if !(d.is_finite() && d >= 0.0) {
                return bad("table.dwell_s", "must be ≥ 0");
            }
        }
        Ok(())
    }
}

impl Device {
    /// Either sensitivities and angles in range, or a matrix; finite offsets.
    fn validate(&self) -> Result<(), ConfigError> {
        match (self.sensitivity, self.angles_deg, self.matrix) {
            (Some(s), Some(a), None) => {
                finite("device.sensitivity", &s)?;
                finite("device.angles_deg", &a)?;
                if s.iter().any(|x| *x <= 0.0) {
                    return bad("device.sensitivity", "must be positive");
                }
                if a.iter().any(|x| *x <= 0.0 || *x >= 180.0) {
                    return bad("device.angles_deg", "must lie between 0 and 180");
                }
            }
            (None, None, Some(m)) => finite("device.matrix", m.as_flattened())?,
            _ => {
                return bad(
                    "device",
                    "give either sensitivity and angles_deg, or matrix",
                )
            }
        }
        finite("device.offsets", &self.offsets)
    }
}

impl Mounting {
    /// An axis and angle, or a rotation matrix, not both.
    fn validate(&self) -> Result<(), ConfigError> {
        finite("mounting.axis", &self.axis)?;
        finite("mounting.angle_deg", &[self.angle_deg])?;
        if self.matrix.is_none() && self.axis.iter().all(|x| *x == 0.0) {
            return bad("mounting.axis", "must not be zero");
        }
        if self.matrix.is_some() && self.angle_deg != 0.0 {
            return bad("mounting", "give axis and angle_deg, or matrix, not both");
        }
        if let Some(m) = &self.matrix {
            finite("mounting.matrix", m.as_flattened())?;
            if !is_rotation(m) {
                return bad(
                    "mounting.matrix",
                    "is not a rotation (needs RᵀR = I to 1e-9 and det R = +1)",
                );
            }
        }
        Ok(())
    }
}

impl Timing {
    /// Rates, clock error, jitter, drops and gaps that keep the timestamps in order.
    fn validate(&self) -> Result<(), ConfigError> {
        if !(self.sample_rate_hz.is_finite() && self.sample_rate_hz > 0.0) {
            return bad("timing.sample_rate_hz", "must be positive");
        }
        if !(self.clock_error_ppm.is_finite() && self.clock_error_ppm.abs() < 1e5) {
            return bad("timing.clock_error_ppm", "must be finite and below 1e5");
        }
        if !(self.jitter_s.is_finite()
            && self.jitter_s >= 0.0
            && self.jitter_s <= 0.05 / self.sample_rate_hz)
        {
            return bad(
                "timing.jitter_s",
                "must be ≥ 0 and at most 0.05 of the sample period (so timestamps stay in order)",
            );
        }
        if !(0.0..1.0).contains(&self.drop_probability) {
            return bad("timing.drop_probability", "must lie in [0, 1)");
        }
        if !(self.tick_hz.is_finite() && self.tick_hz >= self.sample_rate_hz) {
            return bad("timing.tick_hz", "must be at least the sample rate");
        }
        if !(self.gap_s.is_finite() && self.gap_s >= 0.0) {
            return bad("timing.gap_s", "must be ≥ 0");
        }
        Ok(())
    }
}

impl Table {
    /// The keys only rotation uses, each with whether it is given.
    fn rotation_keys(&self) -> [(&'static str, bool); 4] {
        [
            ("table.rates_hz", self.rates_hz.is_some()),
            (
                "table.samples_per_condition",
                self.samples_per_condition.is_some(),
            ),
            ("table.duration_s", self.duration_s.is_some()),
            ("table.start_angle_deg", self.start_angle_deg.is_some()),
        ]
    }

    /// The keys only the static method uses, each with whether it is given.
    fn static_keys(&self) -> [(&'static str, bool); 4] {
        [
            ("table.angles_deg", self.angles_deg.is_some()),
            ("table.angle_step_deg", self.angle_step_deg.is_some()),
            (
                "table.readings_per_angle",
                self.readings_per_angle.is_some(),
            ),
            ("table.dwell_s", self.dwell_s.is_some()),
        ]
    }
}

impl FreePoses {
    /// At least one pose, non-zero directions, and times, spread and move in range.
    fn validate(&self) -> Result<(), ConfigError> {
        let n = self.directions.as_ref().map_or(self.count, Vec::len);
        if n == 0 {
            return bad("poses", "give at least one pose");
        }
        if let Some(d) = &self.directions {
            finite("poses.directions", d.as_flattened())?;
            if d.iter()
                .any(|v| v.iter().map(|x| x * x).sum::<f64>() < 1e-12)
            {
                return bad("poses.directions", "each must be a non-zero vector");
            }
        }
        if !(self.still_s.is_finite() && self.still_s > 0.0) {
            return bad("poses.still_s", "must be positive");
        }
        if !(self.move_s.is_finite() && self.move_s >= 0.0) {
            return bad("poses.move_s", "must be ≥ 0");
        }
        if !(self.noise_spread.is_finite() && self.noise_spread >= 1.0) {
            return bad("poses.noise_spread", "must be ≥ 1");
        }
        if !(self.settle_ms2.is_finite() && self.settle_ms2 >= 0.0) {
            return bad("poses.settle_ms2", "must be ≥ 0");
        }
        if let Some(m) = &self.moved {
            if m.pose >= n || !m.deg.is_finite() {
                return bad("poses.moved", "pose must be one of the poses, deg finite");
            }
        }
        Ok(())
    }
}

impl Temperature {
    /// Finite values, a positive period and a resolution ≥ 0.
    fn validate(&self) -> Result<(), ConfigError> {
        finite(
            "temperature",
            &[
                self.t0_c,
                self.ramp_c_per_h,
                self.swing_c,
                self.period_s,
                self.resolution_c,
            ],
        )?;
        if self.period_s <= 0.0 {
            return bad("temperature.period_s", "must be positive");
        }
        if self.resolution_c < 0.0 {
            return bad("temperature.resolution_c", "must be ≥ 0");
        }
        Ok(())
    }
}

impl Effects {
    /// The effects only rotation simulates, each with whether it is given.
    fn rotation_keys(&self) -> [(&'static str, bool); 4] {
        [
            ("effects.rate_error", self.rate_error.is_some()),
            ("effects.centripetal", self.centripetal.is_some()),
            ("effects.axis_time_skew", self.axis_time_skew.is_some()),
            ("effects.rate_ripple", self.rate_ripple.is_some()),
        ]
    }

    /// The effect only the static method simulates, with whether it is given.
    fn static_keys(&self) -> [(&'static str, bool); 1] {
        [("effects.step_error", self.step_error.is_some())]
    }

    /// Each effect given: finite parameters, in the range the simulator handles.
    fn validate(&self) -> Result<(), ConfigError> {
        if let Some(r) = &self.rate_error {
            if !(r.relative.is_finite() && r.relative.abs() < 0.1) {
                return bad(
                    "effects.rate_error.relative",
                    "must be finite and below 0.1 in size",
                );
            }
        }
        if let Some(x) = &self.offset_drift {
            finite("effects.offset_drift.per_s", &x.per_s)?;
        }
        if let Some(x) = &self.step_error {
            let ok = |v: f64| v.is_finite() && (0.0..=5.0).contains(&v);
            if !ok(x.angle_sd_deg) || !ok(x.tilt_sd_deg) {
                return bad(
                    "effects.step_error",
                    "angle_sd_deg and tilt_sd_deg must lie in [0, 5] degrees",
                );
            }
        }
        if let Some(x) = &self.temperature_offset {
            finite("effects.temperature_offset.per_c", &x.per_c)?;
        }
        if let Some(x) = &self.nonlinearity_2nd {
            finite("effects.nonlinearity_2nd.k2", &x.k2)?;
        }
        if let Some(x) = &self.nonlinearity_3rd {
            finite("effects.nonlinearity_3rd.k3", &x.k3)?;
        }
        if let Some(x) = &self.saturation {
            finite("effects.saturation.rails", &x.rails)?;
            if x.rails[0] >= x.rails[1] {
                return bad("effects.saturation.rails", "low must be below high");
            }
        }
        if let Some(x) = &self.centripetal {
            x.validate()?;
        }
        if let Some(x) = &self.axis_time_skew {
            finite("effects.axis_time_skew.skew_s", &x.skew_s)?;
        }
        if let Some(x) = &self.rate_ripple {
            finite("effects.rate_ripple", &[x.relative, x.phase_deg])?;
            if x.relative.abs() >= 1.0 {
                return bad("effects.rate_ripple.relative", "must be below 1 in size");
            }
        }
        Ok(())
    }
}

impl Centripetal {
    /// A radius ≥ 0, and directions each with a part across its condition's axis.
    fn validate(&self) -> Result<(), ConfigError> {
        if !(self.radius_m.is_finite() && self.radius_m >= 0.0) {
            return bad("effects.centripetal.radius_m", "must be ≥ 0");
        }
        if let Some(d) = &self.directions {
            finite("effects.centripetal.directions", d.as_flattened())?;
            for (i, dir) in d.iter().enumerate() {
                let mut p = *dir;
                p[i] = 0.0;
                if p.iter().map(|v| v * v).sum::<f64>() < 1e-12 {
                    return bad(
                        "effects.centripetal.directions",
                        "each must have a part across its condition's axis",
                    );
                }
            }
        }
        Ok(())
    }
}

/// The error for `key`, saying why its value is refused.
fn bad(key: &'static str, why: &'static str) -> Result<(), ConfigError> {
    Err(ConfigError::Invalid { key, why })
}

/// Refuse non-finite values of `key`.
fn finite(key: &'static str, xs: &[f64]) -> Result<(), ConfigError> {
    if xs.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(ConfigError::NotFinite { key })
    }
}

/// Refuse keys that belong to the other method.
fn only_for(method: &'static str, keys: &[(&'static str, bool)]) -> Result<(), ConfigError> {
    match keys.iter().find(|(_, set)| *set) {
        Some(&(key, _)) => Err(ConfigError::OtherMethod { key, method }),
        None => Ok(()),
    }
}

fn is_rotation(m: &[[f64; 3]; 3]) -> bool {
    let mut ok = true;
    for i in 0..3 {
        for j in 0..3 {
            let dot: f64 = (0..3).map(|k| m[k][i] * m[k][j]).sum();
            let want = if i == j { 1.0 } else { 0.0 };
            ok &= (dot - want).abs() <= 1e-9;
        }
    }
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    ok && (det - 1.0).abs() <= 1e-9
}
