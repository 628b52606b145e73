//! `rotacal report`: a Markdown report with plots, calibrated with `calibrate`'s options.

use std::path::PathBuf;

/// `rotacal report` arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The recording CSV.
    pub file: PathBuf,
    /// The folder to write (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write DIR/report.html: one self-contained file (plots inline, no network)
    /// that a browser prints to PDF, a certificate with the results, U and k, the budget,
    /// the plots and the traceability block.
    #[arg(long)]
    pub html: bool,
    #[command(flatten)]
    pub options: super::calibrate::Options,
}

/// Run it.
pub fn run(a: Args) -> anyhow::Result<()> {
    let opts = a.options.into_engine()?;
    // The folder whole or not at all: a report that fails part way leaves nothing.
    rotacal::atomic::fill_dir(&a.out, |dir| -> anyhow::Result<()> {
        let (path, cal) = rotacal::report::write_file(&a.file, &opts, dir)
            .map_err(|e| super::calibrate::with_rate_hint(e.into(), &a.file, &opts))?;
        rotacal::trace::Traceability::of_calibrating(rotacal::BUILD, &a.file, &opts)?
            .append_to(&path)?;
        if a.html {
            // The report as written, its traceability block last.
            let md = std::fs::read_to_string(&path)
                .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
            let html = rotacal::report::html::certificate(
                &cal,
                &a.file.display().to_string(),
                &md,
                dir,
                &rotacal::calibrate::table::render(&cal),
            )?;
            rotacal::atomic::write(&dir.join("report.html"), html)?;
        }
        Ok(())
    })?;
    rotacal::output::emit(&format!("wrote {}\n", a.out.join("report.md").display()))?;
    if a.html {
        rotacal::output::emit(&format!("wrote {}\n", a.out.join("report.html").display()))?;
    }
    Ok(())
}
