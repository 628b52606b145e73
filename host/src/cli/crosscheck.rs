//! `rotacal crosscheck`: the device's fits against f64 re-fits of the same samples.

use std::path::PathBuf;

/// `rotacal crosscheck` arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The recording CSV (with a seq column).
    pub recording: PathBuf,
    /// The device's fit log (JSON lines).
    pub fit_log: PathBuf,
    /// Pass threshold, in σ_CRLB.
    #[arg(long, default_value_t = rotacal::verify::recorded::DEFAULT_THRESHOLD)]
    pub threshold: f64,
    /// Write the comparison as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

/// Run it (an error when a fit differs by more than the threshold).
pub fn run(a: Args) -> anyhow::Result<()> {
    // One condition is enough to check the device's fits of it.
    let rec = rotacal::recording::read_in_progress(&a.recording)?;
    let log_name = a.fit_log.display().to_string();
    let text =
        std::fs::read_to_string(&a.fit_log).map_err(|e| anyhow::anyhow!("{log_name}: {e}"))?;
    let log = rotacal::recording::from_device::read_fit_log(&text, &log_name)?;
    let report = rotacal::verify::recorded::crosscheck(&rec, &log, a.threshold)?;
    if let Some(path) = &a.json {
        let mut trace = rotacal::trace::Traceability::of_recording(
            rotacal::BUILD,
            &a.recording,
            None,
            None,
            None,
        )?;
        trace.inputs.push(rotacal::trace::input(&a.fit_log)?);
        rotacal::atomic::write(path, trace.json(&report)?)?;
    }
    rotacal::output::emit(&rotacal::verify::recorded::render(&report))?;
    if !report.passed {
        anyhow::bail!("the device's fits do not match the recording (see the table)");
    }
    Ok(())
}
