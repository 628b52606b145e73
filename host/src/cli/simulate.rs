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
    simulate(&a.config, &a.out, a.seed)
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
