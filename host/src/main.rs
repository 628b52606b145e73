//! `rotacal`: calibrate triaxial accelerometers by rotation in Earth's gravity.
//! A thin command-line layer over the `rotacal` library.
use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser)]
#[command(name = "rotacal", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// The main job without hardware: simulate seed 000's 10 mHz run and fit it.
    Demo {
        /// Seed of the simulated noise.
        #[arg(long, default_value_t = 2022)]
        seed: u64,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Demo { seed } => rotacal::demo::run(seed)
            .and_then(|d| Ok(rotacal::output::emit(&rotacal::demo::render(&d))?)),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("rotacal: {e:#}");
            ExitCode::FAILURE
        }
    }
}
