//! `rotacal export`: the correction as constants to embed.

use super::FrameArg;
use clap::ValueEnum;
use std::path::PathBuf;

#[derive(Clone, Copy, ValueEnum)]
pub enum FormatArg {
    C,
    Rust,
    Json,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum PrecisionArg {
    F32,
    F64,
}

/// `rotacal export` arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The calibration JSON (`rotacal calibrate --json`).
    pub calibration: PathBuf,
    /// Output language.
    #[arg(long, value_enum)]
    pub format: FormatArg,
    /// The frame.
    #[arg(long, value_enum, default_value = "device")]
    pub frame: FrameArg,
    /// Floating-point type of the constants (C and Rust).
    #[arg(long, value_enum, default_value = "f32")]
    pub precision: PrecisionArg,
    /// Which calibration, when the file has several rates.
    #[arg(long)]
    pub rate_hz: Option<f64>,
    /// Write here instead of standard output.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Run it.
pub fn run(a: Args) -> anyhow::Result<()> {
    let format = match a.format {
        FormatArg::C => rotacal::correct::export::Format::C,
        FormatArg::Rust => rotacal::correct::export::Format::Rust,
        FormatArg::Json => rotacal::correct::export::Format::Json,
    };
    let precision = match a.precision {
        PrecisionArg::F32 => rotacal::correct::export::Precision::F32,
        PrecisionArg::F64 => rotacal::correct::export::Precision::F64,
    };
    let l = rotacal::correct::apply::load(&a.calibration, a.rate_hz, a.frame.into())?;
    let name = a.calibration.display().to_string();
    let trace = rotacal::trace::Traceability::of_calibration(rotacal::BUILD, &a.calibration)?;
    let lines: Vec<String> = trace
        .comment("traceability: ")
        .lines()
        .map(String::from)
        .collect();
    let body = rotacal::correct::export::render(
        &l.json,
        &l.correction,
        &name,
        format,
        precision,
        (&lines, Some(serde_json::to_value(&trace)?)),
    );
    match a.out {
        Some(p) => rotacal::atomic::write(&p, body)?,
        None => rotacal::output::emit(&body)?,
    }
    Ok(())
}
