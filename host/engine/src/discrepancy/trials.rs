//! Simulated trials for the workflow's proof (host/tests/suite/discrepancy.rs) and its
//! detection-limit benchmark (`scripts/bench-discrepancy`): the data, with one effect of a
//! given magnitude hidden in it, and the analysis of each seed.

use super::model::Effect;
use super::{Analysis, DiscrepancyError, Options};
use crate::simulate::{Config, ConfigError, ReadBackError, Simulation};

/// Why a trial failed: its configuration, its simulation or its analysis.
#[derive(Debug, thiserror::Error)]
pub enum TrialError {
    /// The configuration is refused.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The simulated recording could not be written and read back.
    #[error(transparent)]
    Recording(#[from] ReadBackError),
    /// The workflow failed on it.
    #[error(transparent)]
    Analysis(#[from] DiscrepancyError),
}

/// Single-rate trials: Gaitan & Geist's (2022) 10 mHz run, with the lab's temperature swinging ±1 °C
/// over 10 minutes (so that a temperature coefficient can be told from a drift).
pub const SINGLE_RATE: &str = "preset = \"paper-10mhz\"\n\
    [temperature]\nswing_c = 1.0\nperiod_s = 600.0\n";

/// Multi-rate trials (for centripetal): 0.1 and 0.5 Hz, 2000 samples per condition, on
/// the axis unless the effect moves it.
pub const MULTI_RATE: &str = "preset = \"paper-multirate\"\n\
    [table]\nrates_hz = [0.1, 0.5]\nsamples_per_condition = 2000\n\
    [effects.centripetal]\nradius_m = 0.0\n";

/// The noise of a trial (a `[sensor.noise]` table appended to the base). None of them
/// lets the file state `noise_sigma`: the workflow is told nothing about the noise.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Noise {
    /// White, the base's level (the LSM6DS33's 4.17 counts at 16 Hz), not stated.
    White,
    /// AR(1), ρ = 0.5, marginal sd 4 counts (a filtered sensor's output).
    Ar1,
    /// White, 3, 4 and 5 counts on u, v and w, not stated.
    Levels345,
    /// The base's white noise plus flicker at a 50 µg Allan floor (docs/simulator.md).
    Flicker50,
    /// The base's white noise plus a bias random walk of 10 µg/√s.
    Walk10,
}

impl Noise {
    /// The `[sensor.noise]` table.
    pub fn toml(self) -> &'static str {
        match self {
            Noise::White => "[sensor.noise]\nstate = false\n",
            Noise::Ar1 => "[sensor.noise]\nsd = 4.0\nar = [0.5]\n",
            Noise::Levels345 => "[sensor.noise]\nsd = [3.0, 4.0, 5.0]\nstate = false\n",
            Noise::Flicker50 => "[sensor.noise]\nstate = false\nflicker_floor_ug = 50.0\n",
            Noise::Walk10 => "[sensor.noise]\nstate = false\nrandom_walk_ug_per_sqrt_s = 10.0\n",
        }
    }

    /// A short name (for the benchmark's keys and messages).
    pub fn name(self) -> &'static str {
        match self {
            Noise::White => "white",
            Noise::Ar1 => "ar1_rho0.5_sd4",
            Noise::Levels345 => "white_3_4_5",
            Noise::Flicker50 => "flicker_50ug",
            Noise::Walk10 => "walk_10ug_per_sqrt_s",
        }
    }
}

/// Where an effect of magnitude `m` goes, and its unit.
pub fn injection(e: Effect, m: f64) -> (String, &'static str, &'static str) {
    match e {
        Effect::RateError => (
            format!("[effects.rate_error]\nrelative = {m:e}\n"),
            "relative",
            "1",
        ),
        Effect::OffsetDrift => (
            format!("[effects.offset_drift]\nper_s = [{m:e}, 0.0, 0.0]\n"),
            "D_u",
            "counts/s",
        ),
        Effect::TemperatureOffset => (
            format!("[effects.temperature_offset]\nper_c = [{m:e}, 0.0, 0.0]\n"),
            "c_u",
            "counts/°C",
        ),
        Effect::Nonlinearity2nd => (
            format!("[effects.nonlinearity_2nd]\nk2 = [0.0, 0.0, {m:e}]\n"),
            "K2_w",
            "1/(m/s²)",
        ),
        Effect::Nonlinearity3rd => (
            format!("[effects.nonlinearity_3rd]\nk3 = [0.0, {m:e}, 0.0]\n"),
            "K3_v",
            "1/(m/s²)²",
        ),
        // The high rail m counts below u's peak reading (O_u + s_u·g = 16886.3 counts).
        Effect::Saturation => (
            format!(
                "[effects.saturation]\nrails = [-32768.0, {:.1}]\n",
                (16886.3 - m).round()
            ),
            "depth below u's peak",
            "counts",
        ),
        Effect::Centripetal => (
            format!("[effects.centripetal]\nradius_m = {m:e}\n"),
            "radius",
            "m",
        ),
    }
}

/// The base configuration an effect is tried on.
pub fn base(e: Effect) -> &'static str {
    match e {
        Effect::Centripetal => MULTI_RATE,
        _ => SINGLE_RATE,
    }
}

/// Simulate `toml` with `seed` and analyse it.
pub fn analyse(toml: &str, seed: u64) -> Result<Analysis, TrialError> {
    analyse_with(toml, seed, &Options::default())
}

/// Simulate `toml` with `seed` and analyse it with `opts`.
pub fn analyse_with(toml: &str, seed: u64, opts: &Options) -> Result<Analysis, TrialError> {
    let mut cfg = Config::from_toml(toml)?;
    cfg.seed = seed;
    let rec = Simulation::new(cfg)?.recording()?;
    Ok(super::run(&rec, opts)?)
}

/// One trial: `effects` at their magnitudes, hidden in their base, white noise not stated.
pub fn trial(effects: &[(Effect, f64)], seed: u64) -> Result<Analysis, TrialError> {
    trial_in(Noise::White, effects, seed)
}

/// One trial under `noise`: `effects` at their magnitudes, hidden in their base.
pub fn trial_in(
    noise: Noise,
    effects: &[(Effect, f64)],
    seed: u64,
) -> Result<Analysis, TrialError> {
    trial_with(noise, effects, seed, &Options::default())
}

/// [`trial_in`] analysed with `opts`.
pub fn trial_with(
    noise: Noise,
    effects: &[(Effect, f64)],
    seed: u64,
    opts: &Options,
) -> Result<Analysis, TrialError> {
    let multi = effects.iter().any(|(e, _)| *e == Effect::Centripetal);
    let mut toml = String::from(base(if multi {
        Effect::Centripetal
    } else {
        Effect::RateError
    }));
    for &(e, m) in effects {
        toml.push_str(&injection(e, m).0);
    }
    // A later [effects.centripetal] table replaces the base's.
    if multi {
        toml = toml.replacen("[effects.centripetal]\nradius_m = 0.0\n", "", 1);
    }
    toml.push_str(noise.toml());
    analyse_with(&toml, seed, opts)
}

/// The injected parameter's estimate and standard uncertainty in the final model.
pub fn estimate(a: &Analysis, e: Effect) -> Option<(f64, f64)> {
    estimate_with(a, e, "std_unc")
}

/// The injected parameter's estimate and its uncertainty `key` ("std_unc" or
/// "expanded_unc") in the final model.
pub fn estimate_with(a: &Analysis, e: Effect, key: &str) -> Option<(f64, f64)> {
    let p = a.final_parameters.get(e.name())?;
    let pick = |v: &serde_json::Value| -> Option<(f64, f64)> {
        Some((v.get("value")?.as_f64()?, v.get(key)?.as_f64()?))
    };
    match e {
        Effect::RateError => pick(p.get("relative")?),
        Effect::OffsetDrift => pick(p.get("per_s")?.get("u")?),
        Effect::TemperatureOffset => pick(p.get("per_c")?.get("u")?),
        Effect::Nonlinearity2nd => pick(p.get("k2")?.get("w")?),
        Effect::Nonlinearity3rd => pick(p.get("k3")?.get("v")?),
        // The rails are read off the data, not estimated with an uncertainty.
        Effect::Saturation => None,
        Effect::Centripetal => pick(p.get("radius_m")?.get("y")?),
    }
}
