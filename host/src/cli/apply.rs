//! `rotacal apply`: readings corrected to m/s² with a calibration.

use super::FrameArg;
use std::path::PathBuf;

/// `rotacal apply` arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The calibration JSON (`rotacal calibrate --json`).
    pub calibration: PathBuf,
    /// The recording to correct.
    pub recording: PathBuf,
    /// The corrected recording to write.
    #[arg(long)]
    pub out: PathBuf,
    /// The frame of the result.
    #[arg(long, value_enum, default_value = "device")]
    pub frame: FrameArg,
    /// Which calibration, when the file has several rates.
    #[arg(long)]
    pub rate_hz: Option<f64>,
}

/// Run it.
pub fn run(a: Args) -> anyhow::Result<()> {
    let trace = rotacal::trace::Traceability::new(rotacal::BUILD, &[&a.calibration, &a.recording])?;
    let (_, text) = rotacal::correct::apply::run(
        &a.calibration,
        &a.recording,
        &a.out,
        a.frame.into(),
        a.rate_hz,
        &trace.as_metadata(&["calibration", "recording"]),
    )?;
    rotacal::output::emit(&format!("wrote {}\n{text}", a.out.display()))?;
    Ok(())
}
