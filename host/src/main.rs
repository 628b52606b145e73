//! `rotacal`: calibrate triaxial accelerometers by rotation in Earth's gravity.
//! A thin command-line layer over the `rotacal` library.
use clap::{Parser, Subcommand, ValueEnum};
use std::path::PathBuf;
use std::process::ExitCode;

mod cli;
use cli::{import, record};

#[derive(Parser)]
#[command(name = "rotacal", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Clone, Copy, ValueEnum)]
enum MethodArg {
    Rotation,
    Static,
}

#[derive(Clone, Copy, ValueEnum)]
enum WeightsArg {
    /// 1/(se² + τ²), τ the poses' scatter beyond their noise (default).
    RandomEffects,
    /// Every pose equally (ordinary least squares on the pose means, as imucal).
    Equal,
}

#[derive(Clone, Copy, ValueEnum)]
enum OffsetsArg {
    /// From the joint fit of all poses (default).
    Joint,
    /// imucal's: each channel's from the up/down pair of its own axis.
    AxisPairs,
}

#[derive(Clone, Copy, ValueEnum)]
enum FrameArg {
    /// The device's orthonormal frame (x′ along u, y′ in the u-v plane).
    Device,
    /// The platter (pose) frame: static calibrations only.
    Platter,
}

#[derive(Clone, Copy, ValueEnum)]
enum FormatArg {
    C,
    Rust,
    Json,
}

#[derive(Clone, Copy, ValueEnum)]
enum PrecisionArg {
    F32,
    F64,
}

impl From<FrameArg> for rotacal::correction::Frame {
    fn from(f: FrameArg) -> Self {
        match f {
            FrameArg::Device => Self::Device,
            FrameArg::Platter => Self::Platter,
        }
    }
}

/// The choices of a calibration, shared by `calibrate` and `report` so that both give the
/// same numbers for the same options.
#[derive(clap::Args)]
struct CalibrationArgs {
    /// Override the method (default: the file's `method`, else rotation if it has t_s).
    #[arg(long, value_enum)]
    method: Option<MethodArg>,
    /// Nominal rotation rate, Hz (overrides `# rate_hz=`).
    #[arg(long)]
    rate_hz: Option<f64>,
    /// Local gravity, m/s² (overrides `# g_loc=`).
    #[arg(long)]
    g_loc: Option<f64>,
    /// Standard uncertainty of g_loc, m/s² (overrides `# u_g_loc=`): about 1e-4 relative
    /// from a latitude-and-height formula, 1e-5 from a gravity model or map, 1e-8 from
    /// an absolute gravimeter.
    #[arg(long)]
    u_g_loc: Option<f64>,
    /// Rotation files: standard uncertainty of each timestamp beyond its resolution
    /// (jitter), seconds (overrides `# u_time_s=`).
    #[arg(long)]
    u_time_s: Option<f64>,
    /// Stepped static files: standard uncertainty of each table angle, degrees
    /// (overrides `# u_angle_deg=`): the table's positioning accuracy, independent from
    /// step to step.
    #[arg(long)]
    u_angle_deg: Option<f64>,
    /// Check the uncertainties by Monte Carlo (GUM Supplement 1) with N trials.
    #[arg(long, value_name = "N")]
    monte_carlo: Option<usize>,
    /// Static data: how to weight the pose means.
    #[arg(long, value_enum, default_value = "random-effects")]
    pose_weights: WeightsArg,
    /// Static data: which offsets to report.
    #[arg(long, value_enum, default_value = "joint")]
    offsets: OffsetsArg,
}

impl From<CalibrationArgs> for rotacal::calibrate_recording::Options {
    fn from(a: CalibrationArgs) -> Self {
        rotacal::calibrate_recording::Options {
            method: a.method.map(|m| match m {
                MethodArg::Rotation => rotacal::recording::Method::Rotation,
                MethodArg::Static => rotacal::recording::Method::Static,
            }),
            rate_hz: a.rate_hz,
            g_loc: a.g_loc,
            monte_carlo: a.monte_carlo,
            inputs: rotacal::calibrate_recording::TypeB {
                u_g_loc: a.u_g_loc,
                u_time_s: a.u_time_s,
                u_angle_deg: a.u_angle_deg,
            },
            poses: rotacal::orientation::Options {
                weights: match a.pose_weights {
                    WeightsArg::RandomEffects => rotacal::orientation::Weights::RandomEffects,
                    WeightsArg::Equal => rotacal::orientation::Weights::Equal,
                },
                offsets: match a.offsets {
                    OffsetsArg::Joint => rotacal::orientation::OffsetEstimator::Joint,
                    OffsetsArg::AxisPairs => rotacal::orientation::OffsetEstimator::AxisPairs,
                },
                // Set from the type-B inputs (flag or file) when the file is read.
                u_angle_rad: None,
            },
        }
    }
}

#[derive(Subcommand)]
enum Command {
    /// Intrinsic properties (sensitivities, angles, offsets) with uncertainties from a
    /// recording (the recording CSV: docs/formats.md in rotacal's source).
    Calibrate {
        /// The recording CSV.
        file: PathBuf,
        #[command(flatten)]
        options: CalibrationArgs,
        /// Write the result as JSON (docs/formats.md) here.
        #[arg(long)]
        json: Option<PathBuf>,
    },
    /// Correct readings with a calibration: a = M·(y − O) in m/s², written as a recording
    /// with each value's standard uncertainty from the calibration.
    Apply {
        /// The calibration JSON (`rotacal calibrate --json`).
        calibration: PathBuf,
        /// The recording to correct.
        recording: PathBuf,
        /// The corrected recording to write.
        #[arg(long)]
        out: PathBuf,
        /// The frame of the result.
        #[arg(long, value_enum, default_value = "device")]
        frame: FrameArg,
        /// Which calibration, when the file has several rates.
        #[arg(long)]
        rate_hz: Option<f64>,
    },
    /// The correction as constants to embed (C header, Rust module or JSON).
    Export {
        /// The calibration JSON (`rotacal calibrate --json`).
        calibration: PathBuf,
        /// Output language.
        #[arg(long, value_enum)]
        format: FormatArg,
        /// The frame.
        #[arg(long, value_enum, default_value = "device")]
        frame: FrameArg,
        /// Floating-point type of the constants (C and Rust).
        #[arg(long, value_enum, default_value = "f32")]
        precision: PrecisionArg,
        /// Which calibration, when the file has several rates.
        #[arg(long)]
        rate_hz: Option<f64>,
        /// Write here instead of standard output.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// A Markdown report with SVG plots: data and fits, residuals, residual spectrum,
    /// the intrinsic properties with U (95 %), properties against rate.
    Report {
        /// The recording CSV.
        file: PathBuf,
        /// The folder to write (created if missing).
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        options: CalibrationArgs,
    },
    /// Re-fit in f64 exactly the sample windows the device fitted, and compare
    /// (exit 1 if any differs by more than the threshold).
    Crosscheck {
        /// The recording CSV (with a seq column).
        recording: PathBuf,
        /// The device's fit log (JSON lines).
        fit_log: PathBuf,
        /// Pass threshold, in σ_CRLB.
        #[arg(long, default_value_t = rotacal::crosscheck::DEFAULT_THRESHOLD)]
        threshold: f64,
        /// Write the comparison as JSON here.
        #[arg(long)]
        json: Option<PathBuf>,
    },
    /// Convert text logs (delimited columns) into a recording; with a section list and a
    /// pose map, static poses with their gravity directions.
    Import(import::Args),
    /// Record one condition from a device over BLE (or a simulated one): the recording,
    /// its fit log (.fits.jsonl) and a capture of every value received (.capture).
    Record(record::Args),
    /// Find where the model and the measurement disagree, name the missing effects,
    /// and show the gap shrink as each is added (docs/discrepancy.md).
    Discrepancy {
        /// The recording CSV (rotation).
        file: PathBuf,
        /// Write the analysis as JSON (docs/formats.md) here.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Write a report folder (Markdown, residual and spectrum plots) here.
        #[arg(long)]
        report: Option<PathBuf>,
        /// Local gravity, m/s² (overrides `# g_loc=`).
        #[arg(long)]
        g_loc: Option<f64>,
        /// Nominal rotation rate, Hz (overrides `# rate_hz=`).
        #[arg(long)]
        rate_hz: Option<f64>,
        /// Significance of each effect's F-test.
        #[arg(long, default_value_t = rotacal::discrepancy::ALPHA)]
        alpha: f64,
    },
    /// Rebuild a recording and its fit log from a capture (after a crash, or to re-decode).
    Decode {
        /// The capture.
        capture: PathBuf,
        /// The recording to write; the fit log goes beside it.
        #[arg(long)]
        out: PathBuf,
    },
    /// Simulate the experiment and write a recording (docs/simulator.md).
    Simulate {
        /// A TOML configuration file, or the name of a preset (paper-10mhz,
        /// paper-multirate, metrologia-static).
        config: String,
        /// The recording to write.
        #[arg(long)]
        out: PathBuf,
        /// Override the configuration's seed.
        #[arg(long)]
        seed: Option<u64>,
    },
    /// The main job without hardware: simulate seed 000's 10 mHz session, run it through
    /// the firmware's logic, record its packets, calibrate, cross-check, report; exits
    /// with status 1 if any of its checks fails.
    Demo {
        /// Seed of the simulation.
        #[arg(long, default_value_t = 2022)]
        seed: u64,
        /// The folder to write (created if missing).
        #[arg(long, default_value = "rotacal-demo")]
        out: PathBuf,
        /// A fault put into the chain on purpose (corrupt-device-fit): it exists only to
        /// prove that the demo can fail (its tests use it).
        #[arg(long, hide = true)]
        inject: Option<rotacal::demo::Inject>,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Calibrate {
            file,
            options,
            json,
        } => calibrate(file, json, options.into()),
        Command::Apply {
            calibration,
            recording,
            out,
            frame,
            rate_hz,
        } => rotacal::apply::run(&calibration, &recording, &out, frame.into(), rate_hz).and_then(
            |(_, text)| {
                Ok(rotacal::output::emit(&format!(
                    "wrote {}\n{text}",
                    out.display()
                ))?)
            },
        ),
        Command::Export {
            calibration,
            format,
            frame,
            precision,
            rate_hz,
            out,
        } => export(
            &calibration,
            match format {
                FormatArg::C => rotacal::export::Format::C,
                FormatArg::Rust => rotacal::export::Format::Rust,
                FormatArg::Json => rotacal::export::Format::Json,
            },
            frame.into(),
            match precision {
                PrecisionArg::F32 => rotacal::export::Precision::F32,
                PrecisionArg::F64 => rotacal::export::Precision::F64,
            },
            rate_hz,
            out.as_deref(),
        ),
        Command::Simulate { config, out, seed } => simulate(&config, &out, seed),
        Command::Report { file, out, options } => report(&file, &out, &options.into()),
        Command::Import(args) => import::run(args),
        Command::Crosscheck {
            recording,
            fit_log,
            threshold,
            json,
        } => crosscheck(&recording, &fit_log, threshold, json.as_deref()),
        Command::Record(args) => record::run(args),
        Command::Discrepancy {
            file,
            json,
            report,
            g_loc,
            rate_hz,
            alpha,
        } => discrepancy(
            &file,
            json.as_deref(),
            report.as_deref(),
            g_loc,
            rate_hz,
            alpha,
        ),
        Command::Decode { capture, out } => record::decode(&capture, &out),
        Command::Demo { seed, out, inject } => rotacal::demo::command(seed, &out, inject),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("rotacal: {e:#}");
            if e.downcast_ref::<cli::record::Incomplete>().is_some() {
                ExitCode::from(3)
            } else {
                ExitCode::FAILURE
            }
        }
    }
}

fn calibrate(
    file: PathBuf,
    json: Option<PathBuf>,
    opts: rotacal::calibrate_recording::Options,
) -> anyhow::Result<()> {
    let rec = rotacal::recording::read(&file)?;
    let cal = rotacal::calibrate_recording::calibrate(&rec, &opts)?;
    if let Some(path) = json {
        let text = serde_json::to_string_pretty(&cal)? + "\n";
        std::fs::write(&path, text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    }
    rotacal::output::emit(&rotacal::calibrate_recording::render(&cal))?;
    Ok(())
}

fn simulate(config: &str, out: &std::path::Path, seed: Option<u64>) -> anyhow::Result<()> {
    use rotacal::simulate::{Config, Simulation};
    let mut cfg = Config::load(config)?;
    if let Some(s) = seed {
        cfg.seed = s;
    }
    let sim = Simulation::new(cfg).map_err(|e| anyhow::anyhow!("{config}: {e}"))?;
    let sum = sim
        .write_file(out)
        .map_err(|e| anyhow::anyhow!("{}: {e}", out.display()))?;
    rotacal::output::emit(&rotacal::simulate::render(&sim, &sum, out))?;
    Ok(())
}

fn discrepancy(
    file: &std::path::Path,
    json: Option<&std::path::Path>,
    report: Option<&std::path::Path>,
    g_loc: Option<f64>,
    rate_hz: Option<f64>,
    alpha: f64,
) -> anyhow::Result<()> {
    if !(alpha > 0.0 && alpha < 1.0) {
        anyhow::bail!("--alpha {alpha}: expected a probability between 0 and 1");
    }
    let rec = rotacal::recording::read(file)?;
    let opts = rotacal::discrepancy::Options {
        g_loc,
        rate_hz,
        alpha,
    };
    let a = rotacal::discrepancy::run(&rec, &opts).map_err(anyhow::Error::msg)?;
    if let Some(path) = json {
        std::fs::write(path, serde_json::to_string_pretty(&a)? + "\n")
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    }
    rotacal::output::emit(&rotacal::discrepancy::report::render(&a))?;
    if let Some(dir) = report {
        let units = rec.meta.units.as_deref().unwrap_or("output units");
        let path = rotacal::discrepancy::report::write(&a, dir, units)?;
        rotacal::output::emit(&format!("report: {}\n", path.display()))?;
    }
    Ok(())
}

fn crosscheck(
    recording: &std::path::Path,
    fit_log: &std::path::Path,
    threshold: f64,
    json: Option<&std::path::Path>,
) -> anyhow::Result<()> {
    // One condition is enough to check the device's fits of it.
    let rec = rotacal::recording::read_in_progress(recording)?;
    let text = std::fs::read_to_string(fit_log)
        .map_err(|e| anyhow::anyhow!("{}: {e}", fit_log.display()))?;
    let log = rotacal::acquire::read_fit_log(&text, &fit_log.display().to_string())
        .map_err(anyhow::Error::msg)?;
    let report =
        rotacal::crosscheck::crosscheck(&rec, &log, threshold).map_err(anyhow::Error::msg)?;
    if let Some(path) = json {
        std::fs::write(path, serde_json::to_string_pretty(&report)? + "\n")
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    }
    rotacal::output::emit(&rotacal::crosscheck::render(&report))?;
    if !report.passed {
        anyhow::bail!("the device's fits do not match the recording (see the table)");
    }
    Ok(())
}

fn export(
    cal: &std::path::Path,
    format: rotacal::export::Format,
    frame: rotacal::correction::Frame,
    precision: rotacal::export::Precision,
    rate_hz: Option<f64>,
    out: Option<&std::path::Path>,
) -> anyhow::Result<()> {
    let l = rotacal::apply::load(cal, rate_hz, frame)?;
    let name = cal.display().to_string();
    let body = rotacal::export::render(&l.json, &l.correction, &name, format, precision);
    match out {
        Some(p) => std::fs::write(p, body).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?,
        None => rotacal::output::emit(&body)?,
    }
    Ok(())
}

fn report(
    file: &std::path::Path,
    out: &std::path::Path,
    opts: &rotacal::calibrate_recording::Options,
) -> anyhow::Result<()> {
    let rec = rotacal::recording::read(file)?;
    let path = rotacal::report::write(&rec, opts, out)?;
    rotacal::output::emit(&format!("wrote {}\n", path.display()))?;
    Ok(())
}
