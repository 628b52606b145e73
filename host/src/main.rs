//! `rotacal`: calibrate triaxial accelerometers by rotation in Earth's gravity.
//! A thin command-line layer over the `rotacal` library.
use clap::{Parser, Subcommand, ValueEnum};
use std::path::PathBuf;
use std::process::ExitCode;

mod cli;
use cli::record;

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

#[derive(Subcommand)]
enum Command {
    /// Intrinsic properties (sensitivities, angles, offsets) with uncertainties from a
    /// recording (../shared/docs/formats.md).
    Calibrate {
        /// The recording CSV.
        file: PathBuf,
        /// Override the method (default: the file's `method`, else rotation if it has t_s).
        #[arg(long, value_enum)]
        method: Option<MethodArg>,
        /// Nominal rotation rate, Hz (overrides `# rate_hz=`).
        #[arg(long)]
        rate_hz: Option<f64>,
        /// Local gravity, m/s² (overrides `# g_loc=`).
        #[arg(long)]
        g_loc: Option<f64>,
        /// Write the result as JSON (formats.md) here.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Check the uncertainties by Monte Carlo (GUM Supplement 1) with N trials.
        #[arg(long, value_name = "N")]
        monte_carlo: Option<usize>,
    },
    /// A Markdown report with SVG plots: data and fits, residuals, residual spectrum,
    /// the intrinsic properties with U (k = 2), properties against rate.
    Report {
        /// The recording CSV.
        file: PathBuf,
        /// The folder to write (created if missing).
        #[arg(long)]
        out: PathBuf,
        /// Nominal rotation rate, Hz (overrides `# rate_hz=`).
        #[arg(long)]
        rate_hz: Option<f64>,
        /// Local gravity, m/s² (overrides `# g_loc=`).
        #[arg(long)]
        g_loc: Option<f64>,
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
    /// Convert text logs (delimited columns) into a recording.
    Import {
        /// The logs, one per condition unless a condition column is mapped.
        #[arg(required = true)]
        inputs: Vec<PathBuf>,
        /// Which field holds what, 0-based: t=0,u=1,v=2,w=3[,condition=N][,angle=N][,temp=N][,seq=N].
        #[arg(long)]
        columns: rotacal::import::ColumnMap,
        /// The condition of each input, in order (x, y, z), e.g. --condition x,y,z.
        #[arg(long, value_delimiter = ',')]
        condition: Vec<char>,
        /// Header lines to skip at the top of each input.
        #[arg(long, default_value_t = 0)]
        skip: usize,
        /// Seconds per unit of the time column (e.g. 0.001 for milliseconds).
        #[arg(long, default_value_t = 1.0)]
        time_scale: f64,
        /// Nominal rotation rate, Hz (metadata).
        #[arg(long)]
        rate_hz: Option<f64>,
        /// Local gravity, m/s² (metadata).
        #[arg(long)]
        g_loc: Option<f64>,
        /// Output units (metadata), e.g. counts or V.
        #[arg(long)]
        units: Option<String>,
        /// The recording to write.
        #[arg(long)]
        out: PathBuf,
    },
    /// Record one condition from a device over BLE (or a simulated one): the recording,
    /// its fit log (.fits.jsonl) and a capture of every value received (.capture).
    Record(record::Args),
    /// Find where the model and the measurement disagree, name the missing effects,
    /// and show the gap shrink as each is added (docs/discrepancy.md).
    Discrepancy {
        /// The recording CSV (rotation).
        file: PathBuf,
        /// Write the analysis as JSON (formats.md) here.
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
    /// the firmware's logic, record its packets, calibrate, cross-check, report.
    Demo {
        /// Seed of the simulation.
        #[arg(long, default_value_t = 2022)]
        seed: u64,
        /// The folder to write (created if missing).
        #[arg(long, default_value = "rotacal-demo")]
        out: PathBuf,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Calibrate {
            file,
            method,
            rate_hz,
            g_loc,
            json,
            monte_carlo,
        } => calibrate(file, method, rate_hz, g_loc, json, monte_carlo),
        Command::Simulate { config, out, seed } => simulate(&config, &out, seed),
        Command::Report {
            file,
            out,
            rate_hz,
            g_loc,
        } => report(&file, &out, rate_hz, g_loc),
        Command::Import {
            inputs,
            columns,
            condition,
            skip,
            time_scale,
            rate_hz,
            g_loc,
            units,
            out,
        } => import(
            &inputs,
            columns,
            &condition,
            skip,
            time_scale,
            rotacal::recording::Metadata {
                rate_hz,
                g_loc,
                units,
                ..Default::default()
            },
            &out,
        ),
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
        Command::Demo { seed, out } => rotacal::demo::run(seed, &out)
            .and_then(|d| Ok(rotacal::output::emit(&rotacal::demo::render(&d))?)),
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
    method: Option<MethodArg>,
    rate_hz: Option<f64>,
    g_loc: Option<f64>,
    json: Option<PathBuf>,
    monte_carlo: Option<usize>,
) -> anyhow::Result<()> {
    use rotacal::recording::Method;
    let rec = rotacal::recording::read(&file)?;
    let opts = rotacal::calibrate_recording::Options {
        method: method.map(|m| match m {
            MethodArg::Rotation => Method::Rotation,
            MethodArg::Static => Method::Static,
        }),
        rate_hz,
        g_loc,
        monte_carlo,
    };
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

fn import(
    inputs: &[PathBuf],
    columns: rotacal::import::ColumnMap,
    condition: &[char],
    skip: usize,
    time_scale: f64,
    meta: rotacal::recording::Metadata,
    out: &std::path::Path,
) -> anyhow::Result<()> {
    use rotacal_shared::Condition;
    let conditions = condition
        .iter()
        .map(|c| {
            Condition::from_letter(*c)
                .ok_or_else(|| anyhow::anyhow!("--condition '{c}': expected x, y or z"))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let mut readers: Vec<(String, Box<dyn std::io::BufRead>)> = Vec::new();
    for p in inputs {
        let f = std::fs::File::open(p).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
        readers.push((
            p.display().to_string(),
            Box::new(std::io::BufReader::new(f)),
        ));
    }
    let spec = rotacal::import::ImportSpec {
        columns,
        conditions,
        skip,
        time_scale,
        meta,
    };
    let file = std::fs::File::create(out).map_err(|e| anyhow::anyhow!("{}: {e}", out.display()))?;
    let counts = rotacal::import::import(readers, &spec, file)?;
    let total: usize = counts.iter().sum();
    rotacal::output::emit(&format!(
        "wrote {}: {total} rows ({})\n",
        out.display(),
        counts
            .iter()
            .zip(inputs)
            .map(|(n, p)| format!("{n} from {}", p.display()))
            .collect::<Vec<_>>()
            .join(", ")
    ))?;
    Ok(())
}

fn report(
    file: &std::path::Path,
    out: &std::path::Path,
    rate_hz: Option<f64>,
    g_loc: Option<f64>,
) -> anyhow::Result<()> {
    let rec = rotacal::recording::read(file)?;
    let opts = rotacal::calibrate_recording::Options {
        rate_hz,
        g_loc,
        ..Default::default()
    };
    let path = rotacal::report::write(&rec, &opts, out)?;
    rotacal::output::emit(&format!("wrote {}\n", path.display()))?;
    Ok(())
}
