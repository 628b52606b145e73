//! `rotacal demo`: the main job without hardware (the wiring is `rotacal::demo`).

use std::path::PathBuf;

/// `rotacal demo` arguments.
#[derive(clap::Args)]
pub struct Args {
    /// Seed of the simulation.
    #[arg(long, default_value_t = 2022)]
    pub seed: u64,
    /// The folder to write (created if missing).
    #[arg(long, default_value = "rotacal-demo")]
    pub out: PathBuf,
    /// A fault put into the chain on purpose (corrupt-device-fit): it exists only to
    /// prove that the demo can fail (its tests use it).
    #[arg(long, hide = true)]
    pub inject: Option<rotacal::demo::Inject>,
}

/// Run it (an error when one of its checks fails).
pub fn run(a: Args) -> anyhow::Result<()> {
    rotacal::demo::command(a.seed, &a.out, a.inject)
}
