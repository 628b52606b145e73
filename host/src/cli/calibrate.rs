//! `rotacal calibrate`: a recording to its calibration, printed and optionally as JSON.

use clap::ValueEnum;
use std::path::PathBuf;

/// `--method`.
#[derive(Clone, Copy, ValueEnum)]
pub enum MethodArg {
    /// Constant-rate rotation (Gaitan & Geist, 2022).
    Rotation,
    /// Stepped angles (Gaitan et al., 2021) or poses of known orientation.
    Static,
    /// Still poses of unknown orientation, found in the readings (|a| = g).
    Free,
}

/// `--pose-weights`.
#[derive(Clone, Copy, ValueEnum)]
pub enum WeightsArg {
    /// Each pose mean by its covariance: its readings' noise and a tilt of the pose
    /// estimated from the poses (default; per channel 1/(se² + τ²) for single readings).
    RandomEffects,
    /// Every pose equally (ordinary least squares on the pose means, as imucal).
    Equal,
}

/// `--offsets`.
#[derive(Clone, Copy, ValueEnum)]
pub enum OffsetsArg {
    /// From the joint fit of all poses (default).
    Joint,
    /// imucal's: each channel's from the up/down pair of its own axis.
    AxisPairs,
}

/// The choices of a calibration, shared by `calibrate` and `report` so that both give the
/// same numbers for the same options.
#[derive(clap::Args)]
pub struct Options {
    /// Override the method (default: the file's `method`, else rotation if it has t_s).
    #[arg(long, value_enum)]
    pub method: Option<MethodArg>,
    /// Nominal rotation rate, Hz (overrides `# rate_hz=`).
    #[arg(long)]
    pub rate_hz: Option<f64>,
    /// Local gravity, m/s² (overrides `# g_loc=`).
    #[arg(long)]
    pub g_loc: Option<f64>,
    /// Standard uncertainty of g_loc, m/s² (overrides `# u_g_loc=`): about 1e-4 relative
    /// from a latitude-and-height formula, 1e-5 from a gravity model or map, 1e-8 from
    /// an absolute gravimeter.
    #[arg(long)]
    pub u_g_loc: Option<f64>,
    /// Rotation files: standard uncertainty of each timestamp beyond its resolution
    /// (jitter), seconds (overrides `# u_time_s=`).
    #[arg(long)]
    pub u_time_s: Option<f64>,
    /// Stepped static files: standard uncertainty of each table angle, degrees
    /// (overrides `# u_angle_deg=`): the table's positioning accuracy, independent from
    /// step to step.
    #[arg(long)]
    pub u_angle_deg: Option<f64>,
    /// Check the uncertainties by Monte Carlo (GUM Supplement 1) with N trials.
    #[arg(long, value_name = "N")]
    pub monte_carlo: Option<usize>,
    /// Static data: how to weight the pose means.
    #[arg(long, value_enum, default_value = "random-effects")]
    pub pose_weights: WeightsArg,
    /// Static data: which offsets to report.
    #[arg(long, value_enum, default_value = "joint")]
    pub offsets: OffsetsArg,
    /// Method free: window of the still detection, s.
    #[arg(long, default_value_t = 0.5, value_name = "S")]
    pub still_window_s: f64,
    /// Method free: a window is still when its variance is below this many times the
    /// noise variance measured in the data (averaged over the channels).
    #[arg(long, default_value_t = 4.0, value_name = "RATIO")]
    pub still_threshold: f64,
    /// Method free: shortest still interval kept, s.
    #[arg(long, default_value_t = 1.0, value_name = "S")]
    pub min_still_s: f64,
    /// Rotation: also model flicker and a bias random walk, pooled per channel over the
    /// recording; stepped and static poses with reading times: the same terms between the
    /// poses, in U and the offsets; free: allow for the flicker the still intervals'
    /// changes show in the moved test, measure the poses' scatter in every fit, and refuse
    /// fewer than 24 poses kept (docs/uncertainty.md, "Slow noise", "Slow noise between
    /// poses", "Free poses under slow noise").
    #[arg(long)]
    pub slow_noise: bool,
    /// Rotation: a still recording of the same device, in the same units and at the same
    /// row rate, pooled with the recording in the flicker and random walk levels (implies
    /// --slow-noise; docs/uncertainty.md, "Slow noise").
    #[arg(long, value_name = "FILE")]
    pub noise_from: Option<PathBuf>,
}

impl Options {
    /// The engine's options; reads and prepares the `--noise-from` recording, if given.
    pub fn into_engine(self) -> anyhow::Result<rotacal::calibrate::Options> {
        let still = match &self.noise_from {
            Some(path) => {
                let rec = rotacal::recording::read(path)?;
                let prepared = rotacal::calibrate::noise_from::NoiseFrom::new(&rec)
                    .map_err(|e| anyhow::anyhow!("--noise-from {}: {e}", path.display()))?;
                Some(std::sync::Arc::new(prepared))
            }
            None => None,
        };
        let mut opts: rotacal::calibrate::Options = self.into();
        if still.is_some() {
            opts.slow_noise = true;
        }
        opts.noise_from = still;
        Ok(opts)
    }
}

impl From<Options> for rotacal::calibrate::Options {
    fn from(a: Options) -> Self {
        rotacal::calibrate::Options {
            method: a.method.map(|m| match m {
                MethodArg::Rotation => rotacal::recording::Method::Rotation,
                MethodArg::Static => rotacal::recording::Method::Static,
                MethodArg::Free => rotacal::recording::Method::Free,
            }),
            still: rotacal::calibrate::still::Options {
                window_s: a.still_window_s,
                threshold: a.still_threshold,
                min_still_s: a.min_still_s,
            },
            rate_hz: a.rate_hz,
            g_loc: a.g_loc,
            monte_carlo: a.monte_carlo,
            slow_noise: a.slow_noise,
            noise_from: None,
            inputs: rotacal::calibrate::TypeB {
                u_g_loc: a.u_g_loc,
                u_time_s: a.u_time_s,
                u_angle_deg: a.u_angle_deg,
            },
            poses: rotacal::calibrate::poses::Options {
                weights: match a.pose_weights {
                    WeightsArg::RandomEffects => rotacal::calibrate::poses::Weights::RandomEffects,
                    WeightsArg::Equal => rotacal::calibrate::poses::Weights::Equal,
                },
                offsets: match a.offsets {
                    OffsetsArg::Joint => rotacal::calibrate::poses::OffsetEstimator::Joint,
                    OffsetsArg::AxisPairs => rotacal::calibrate::poses::OffsetEstimator::AxisPairs,
                },
                // Set from the type-B inputs (flag or file) when the file is read.
                u_angle_rad: None,
                // Set from `slow_noise` when the poses are fitted.
                slow: false,
            },
        }
    }
}

/// `rotacal calibrate` arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The recording CSV.
    pub file: PathBuf,
    #[command(flatten)]
    pub options: Options,
    /// Write the result as JSON (its keys: rotacal help formats) here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

/// Run it.
pub fn run(a: Args) -> anyhow::Result<()> {
    let opts = a.options.into_engine()?;
    let cal = rotacal::calibrate::stream::calibrate_file(&a.file, &opts)
        .map_err(|e| with_rate_hint(e.into(), &a.file, &opts))?;
    if let Some(path) = a.json {
        let trace = rotacal::trace::Traceability::of_calibrating(rotacal::BUILD, &a.file, &opts)?;
        rotacal::atomic::write(&path, trace.json(&cal)?)?;
    }
    rotacal::output::emit(&rotacal::calibrate::table::render(&cal))?;
    if let Some(h) = rotacal::calibrate::hints::units(&cal) {
        eprintln!("warning: {h}");
    }
    if let Some(c) = cal.residual_structure.as_ref().filter(|c| c.found) {
        eprintln!(
            "warning: {} finding(s) of structure beyond the noise in the residuals (see the \
             table's end and the JSON's residual_structure)",
            c.structure.len()
        );
    }
    Ok(())
}

/// A calibration's failure, with what the rows say if they turn at another rate than the
/// nominal one (a wrong --rate-hz gives a singular fit or one that does not converge).
pub fn with_rate_hint(
    e: anyhow::Error,
    file: &std::path::Path,
    opts: &rotacal::calibrate::Options,
) -> anyhow::Error {
    match rotacal::calibrate::hints::rate_of_file(file, opts) {
        Some(h) => anyhow::anyhow!("{e:#}\n{h}"),
        None => e,
    }
}
