//! `rotacal decode`: a recording and its fit log rebuilt from a capture.

use std::path::PathBuf;

/// `rotacal decode` arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The capture.
    pub capture: PathBuf,
    /// The recording to write; the fit log goes beside it.
    #[arg(long)]
    pub out: PathBuf,
}

/// Run it.
pub fn run(a: Args) -> anyhow::Result<()> {
    super::record::decode(&a.capture, &a.out)
}
