//! `rotacal`: calibrate triaxial accelerometers by rotation in Earth's gravity.
//! A thin command-line layer over the `rotacal` library: one file per subcommand in `cli/`.

use clap::{CommandFactory, Parser, Subcommand};
use std::process::ExitCode;

mod cli;

#[derive(Parser)]
#[command(
    name = "rotacal",
    version,
    about,
    disable_help_subcommand = true,
    after_long_help = cli::help::TOPIC_LIST
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Intrinsic properties (sensitivities, angles, offsets) with uncertainties from a
    /// recording (the recording CSV: rotacal help formats).
    #[command(after_long_help = cli::help::RECORDING)]
    Calibrate(cli::calibrate::Args),
    /// Correct readings with a calibration: a = M·(y − O) in m/s², written as a recording
    /// with each value's standard uncertainty from the calibration.
    #[command(after_long_help = cli::help::APPLY)]
    Apply(cli::apply::Args),
    /// The correction as constants to embed (C header, Rust module or JSON).
    #[command(after_long_help = cli::help::CALIBRATION)]
    Export(cli::export::Args),
    /// A Markdown report with SVG plots: data and fits, residuals, residual spectrum,
    /// the intrinsic properties with U (95 %), properties against rate.
    #[command(after_long_help = cli::help::RECORDING)]
    Report(cli::report::Args),
    /// Re-fit in f64 exactly the sample windows the device fitted, and compare
    /// (exit 1 if any differs by more than the threshold).
    #[command(after_long_help = cli::help::RECORDING)]
    Crosscheck(cli::crosscheck::Args),
    /// Convert text logs (delimited columns) into a recording; with a section list and a
    /// pose map, static poses with their gravity directions.
    Import(cli::import::Args),
    /// Record one condition from a device over BLE (or a simulated one): the recording,
    /// its fit log (.fits.jsonl) and a capture of every value received (.capture).
    Record(cli::record::Args),
    /// The first day with a board: find it, read its info and status, record it lying
    /// still and check its clock, link, conversions, noise and fit (docs/first-board.md).
    CheckBoard(cli::check_board::Args),
    /// Find where the model and the measurement disagree, name the missing effects,
    /// and show the gap shrink as each is added (docs/discrepancy.md).
    #[command(after_long_help = cli::help::RECORDING)]
    Discrepancy(cli::discrepancy::Args),
    /// Rebuild a recording and its fit log from a capture (after a crash, or to re-decode).
    #[command(after_long_help = cli::help::CAPTURE)]
    Decode(cli::decode::Args),
    /// Simulate the experiment and write a recording (rotacal help simulator).
    #[command(after_long_help = cli::help::SIMULATOR)]
    Simulate(cli::simulate::Args),
    /// Overlapping Allan deviation of each still record and channel, with 1σ intervals
    /// and the fitted noise terms N, B, K (docs/allan.md).
    #[command(after_long_help = cli::help::RECORDING)]
    Allan(cli::allan::Args),
    /// The main job without hardware: simulate the 10 mHz session of Gaitan & Geist (2022),
    /// run it through the firmware's logic, record its packets, calibrate, cross-check,
    /// report; exits with status 1 if any of its checks fails.
    Demo(cli::demo::Args),
    /// Help on a subcommand, or a topic: formats (the files rotacal reads and writes),
    /// simulator, recording, protocol.
    Help(cli::help::Args),
}

fn main() -> ExitCode {
    let result = match Cli::parse().command {
        Command::Calibrate(a) => cli::calibrate::run(a),
        Command::Apply(a) => cli::apply::run(a),
        Command::Export(a) => cli::export::run(a),
        Command::Report(a) => cli::report::run(a),
        Command::Crosscheck(a) => cli::crosscheck::run(a),
        Command::Import(a) => cli::import::run(a),
        Command::Record(a) => cli::record::run(a),
        Command::CheckBoard(a) => cli::check_board::run(a),
        Command::Discrepancy(a) => cli::discrepancy::run(a),
        Command::Decode(a) => cli::decode::run(a),
        Command::Simulate(a) => cli::simulate::run(a),
        Command::Allan(a) => cli::allan::run(a),
        Command::Demo(a) => cli::demo::run(a),
        Command::Help(a) => cli::help::run(a, Cli::command()),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("rotacal: {e:#}");
            if e.downcast_ref::<cli::record::Incomplete>().is_some() {
                ExitCode::from(3)
            } else if e.downcast_ref::<cli::discrepancy::Unexplained>().is_some() {
                ExitCode::from(4)
            } else {
                ExitCode::FAILURE
            }
        }
    }
}
