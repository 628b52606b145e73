//! The simulator's configuration: TOML, optionally layered over a named preset.
//!
//! Every section and key is optional except the device; every effect is off unless its
//! table is present. Units are stated per key. Unknown keys are errors, so that a typo
//! never silently turns an effect off. See docs/simulator.md.
//!
//! Here the configuration's types, presets and loading; `validate` checks every key's
//! range and combination, `error` says what is wrong and where.

mod error;
mod validate;

pub use error::ConfigError;

use crate::recording::Method;
use serde::Deserialize;

/// The presets, as TOML documents (host/presets/).
pub const PRESETS: [(&str, &str); 3] = [
    (
        "paper-10mhz",
        include_str!("../../../../presets/paper-10mhz.toml"),
    ),
    (
        "paper-multirate",
        include_str!("../../../../presets/paper-multirate.toml"),
    ),
    (
        "metrologia-static",
        include_str!("../../../../presets/metrologia-static.toml"),
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
    /// `rotation` (constant rate, Gaitan & Geist (2022)) or `static` (angle steps, Gaitan et al. (2021)).
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
    /// A hand's tremor while a pose is held: a narrow band of specific force (2 Hz wide
    /// about `tremor_hz`), independent on each axis, with this RMS per axis, m/s². 0: none.
    #[serde(default)]
    pub tremor_ms2: f64,
    /// The tremor's centre frequency, Hz (physiological tremor: 8–12 Hz).
    #[serde(default = "default_tremor_hz")]
    pub tremor_hz: f64,
    /// One pose that is not still: it turns steadily through `deg` degrees.
    #[serde(default)]
    pub moved: Option<MovedPose>,
}

impl FreePoses {
    /// A still recording: the device put down once, gently, and left for `seconds` (with
    /// method free, what a lab records for `calibrate --noise-from`).
    pub fn one_still(seconds: f64) -> FreePoses {
        FreePoses {
            count: 1,
            directions: None,
            still_s: seconds,
            move_s: 1.0,
            noise_spread: 1.0,
            settle_ms2: 0.0,
            tremor_ms2: 0.0,
            tremor_hz: default_tremor_hz(),
            moved: None,
        }
    }
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
fn default_tremor_hz() -> f64 {
    10.0
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
            tremor_ms2: 0.0,
            tremor_hz: default_tremor_hz(),
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
    /// Flicker (1/f) noise: the floor of its Allan deviation, µg (bias instability
    /// B = floor/0.6643), one for all channels or u, v, w.
    #[serde(default)]
    pub flicker_floor_ug: Option<NoiseSd>,
    /// Bias random walk K, µg/√s (σ_A(τ) = K·√(τ/3)), one for all channels or u, v, w.
    #[serde(default)]
    pub random_walk_ug_per_sqrt_s: Option<NoiseSd>,
}

impl NoiseSd {
    /// The level of each channel (u, v, w).
    pub fn per_channel(&self) -> [f64; 3] {
        match self {
            NoiseSd::All(s) => [*s; 3],
            NoiseSd::PerChannel(s) => *s,
        }
    }
}

fn default_true() -> bool {
    true
}

/// A level of `[sensor.noise]` (`sd`, `flicker_floor_ug`, `random_walk_ug_per_sqrt_s`):
/// one for all channels, or u, v, w.
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
    /// A response of one higher order (4 … 7) along each sensitive axis: outside the
    /// discrepancy workflow's catalogue.
    #[serde(default)]
    pub nonlinearity_high: Option<NonlinearityHigh>,
    /// The offsets jump once: outside the catalogue.
    #[serde(default)]
    pub offset_step: Option<OffsetStep>,
    /// The platter's axis nods a whole number of times per revolution: outside the
    /// catalogue.
    #[serde(default)]
    pub axis_wobble: Option<AxisWobble>,
    /// The sensor's short-range noise changes its level once: outside the catalogue.
    #[serde(default)]
    pub noise_change: Option<NoiseChange>,
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

/// `nonlinearity_high`: s_j·(a + K_j·a^order).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct NonlinearityHigh {
    /// The power, 4 … 7.
    pub order: u32,
    /// K per channel, 1/(m/s²)^(order − 1).
    pub k: [f64; 3],
}

/// `offset_step`: from session time `at_s` on, channel j's offset is O_j + size_j (a
/// shock, or a range or filter setting changed during the session).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct OffsetStep {
    /// When, seconds from the start of the session.
    pub at_s: f64,
    /// The jump per channel, output units.
    pub size: [f64; 3],
}

/// `axis_wobble`: the platter's axis nods `per_rev` times per revolution, so gravity, in
/// the platter frame, leaves the plane of rotation towards the axis by the angle
/// θ = tilt·sin(per_rev·α + ψ): ĝ' = cos θ·ĝ(α) + sin θ·n̂, n̂ the condition's axis.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct AxisWobble {
    /// The largest tilt, degrees.
    pub tilt_deg: f64,
    /// Nods per revolution (default 2).
    #[serde(default = "two")]
    pub per_rev: u32,
    /// ψ, degrees.
    #[serde(default)]
    pub phase_deg: f64,
}

/// `noise_change`: from session time `at_s` on, the sensor's noise (white and AR, not the
/// slow terms) is `factor` times what `[sensor.noise]` says (rotation).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct NoiseChange {
    /// When, seconds from the start of the session.
    pub at_s: f64,
    /// The noise's factor after it.
    pub factor: f64,
}

fn two() -> u32 {
    2
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
            Some(sd) => Ok(sd.per_channel()),
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
}
