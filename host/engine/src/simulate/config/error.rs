//! What is wrong with a configuration, naming the key, the file or the preset.

use super::PRESETS;
use crate::simulate::FilterError;

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
