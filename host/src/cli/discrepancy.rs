//! `rotacal discrepancy`: where model and measurement disagree, and which effect explains it.

use std::path::PathBuf;

/// `rotacal discrepancy` arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The recording CSV (rotation).
    pub file: PathBuf,
    /// Write the analysis as JSON (its keys: rotacal help formats) here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write a report folder (Markdown, residual and spectrum plots) here.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Local gravity, m/s² (overrides `# g_loc=`).
    #[arg(long)]
    pub g_loc: Option<f64>,
    /// Nominal rotation rate, Hz (overrides `# rate_hz=`).
    #[arg(long)]
    pub rate_hz: Option<f64>,
    /// Significance of each effect's F-test.
    #[arg(long, default_value_t = rotacal::discrepancy::ALPHA)]
    pub alpha: f64,
    /// Count flicker (1/f) noise and a bias random walk, estimated from the data, in
    /// every effect's test (docs/discrepancy.md, "Slow noise").
    #[arg(long)]
    pub slow_noise: bool,
}

/// The analysis ran, and something in the data is not explained (exit status 4): the
/// output, the JSON and the report are written first.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct Unexplained(pub String);

/// Run it.
pub fn run(a: Args) -> anyhow::Result<()> {
    if !(a.alpha > 0.0 && a.alpha < 1.0) {
        anyhow::bail!(
            "--alpha {}: expected a probability between 0 and 1",
            a.alpha
        );
    }
    let rec = rotacal::recording::read(&a.file)?;
    let opts = rotacal::discrepancy::Options {
        g_loc: a.g_loc,
        rate_hz: a.rate_hz,
        alpha: a.alpha,
        slow_noise: a.slow_noise,
    };
    let units = rec
        .meta
        .units
        .clone()
        .unwrap_or_else(|| "output units".into());
    let stated = rec.meta.noise_sigma;
    // The workflow takes the recording's rows over: they are not held twice.
    let rows = rotacal::discrepancy::rows_from(rec, &opts)?;
    let (data, noise) = rotacal::discrepancy::with_noise(rows)?;
    let analysis = rotacal::discrepancy::analyse(data, noise, stated, &opts)?;
    let trace =
        rotacal::trace::Traceability::of_recording(rotacal::BUILD, &a.file, None, a.g_loc, None)?;
    if let Some(path) = &a.json {
        rotacal::atomic::write(path, trace.json(&analysis)?)?;
    }
    rotacal::output::emit(&rotacal::report::discrepancy::render(&analysis))?;
    if let Some(dir) = &a.report {
        // The folder whole or not at all.
        let name = rotacal::atomic::fill_dir(dir, |tmp| -> anyhow::Result<_> {
            let path = rotacal::report::discrepancy::write(&analysis, tmp, &units)?;
            trace.append_to(&path)?;
            Ok(path
                .file_name()
                .map(std::path::PathBuf::from)
                .unwrap_or_default())
        })?;
        let path = dir.join(name);
        rotacal::output::emit(&format!("report: {}\n", path.display()))?;
    }
    if !analysis.verdict.explained {
        return Err(Unexplained(analysis.verdict.summary.clone()).into());
    }
    Ok(())
}
