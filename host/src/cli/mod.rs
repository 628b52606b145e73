//! The command line: one file per subcommand, each its arguments (clap) and a `run` that
//! calls the libraries; the terminal-only parts (progress display) with `record`.

use clap::ValueEnum;

pub mod allan;
pub mod apply;
pub mod calibrate;
pub mod check_board;
pub mod crosscheck;
pub mod decode;
pub mod demo;
pub mod discrepancy;
pub mod export;
pub mod help;
pub mod import;
pub mod record;
pub mod report;
pub mod simulate;

#[derive(Clone, Copy, ValueEnum)]
pub enum FrameArg {
    /// The device's orthonormal frame (x′ along u, y′ in the u-v plane).
    Device,
    /// The platter (pose) frame: static calibrations only.
    Platter,
}

impl From<FrameArg> for rotacal::calibrate::correction::Frame {
    fn from(f: FrameArg) -> Self {
        match f {
            FrameArg::Device => Self::Device,
            FrameArg::Platter => Self::Platter,
        }
    }
}
