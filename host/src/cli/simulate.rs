//! `rotacal simulate`: a recording from the forward model of the experiment.

use std::path::PathBuf;

/// `rotacal simulate` arguments.
#[derive(clap::Args)]
pub struct Args {
    /// A TOML configuration file, or the name of a preset (paper-10mhz,
    /// paper-multirate, metrologia-static).
    pub config: String,
    /// The recording to write.
    #[arg(long)]
    pub out: PathBuf,
    /// Override the configuration's seed.
    #[arg(long)]
    pub seed: Option<u64>,
}

/// Run it.
pub fn run(a: Args) -> anyhow::Result<()> {
    use rotacal::simulate::{Config, Simulation};
    let mut cfg = Config::load(&a.config)?;
    if let Some(s) = a.seed {
        cfg.seed = s;
    }
    let sim = Simulation::new(cfg).map_err(|e| anyhow::anyhow!("{}: {e}", a.config))?;
    let sum = sim
        .write_file(&a.out)
        .map_err(|e| anyhow::anyhow!("{}: {e}", a.out.display()))?;
    rotacal::output::emit(&rotacal::simulate::render(&sim, &sum, &a.out))?;
    Ok(())
}
