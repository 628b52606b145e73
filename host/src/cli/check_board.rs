//! `rotacal check-board`: the first day with a board (docs/first-board.md).

use super::record::DeviceArgs;
use rotacal::check_board;
use rotacal::link::ble::{BleLink, Target};
use rotacal::link::simulated::SimulatedDevice;
use rotacal::link::Link;
use rotacal::record::{Observer, Options, Progress};
use std::path::PathBuf;
use std::time::Duration;

/// The command line of `rotacal check-board`.
#[derive(clap::Args)]
pub struct Args {
    /// Which device, or a simulated one.
    #[command(flatten)]
    pub link: DeviceArgs,
    /// How long to record the board lying still, e.g. 60s.
    #[arg(long, default_value = "60s", value_parser = rotacal::record::parse_duration)]
    pub duration: Duration,
    /// The folder for the still recording (check.csv, its fit log and capture).
    #[arg(long, default_value = "rotacal-check")]
    pub out: PathBuf,
}

/// Messages to stderr; no progress bar.
struct Plain;

impl Observer for Plain {
    fn progress(&mut self, _: &Progress) {}
    fn message(&mut self, m: &str) {
        eprintln!("{m}");
    }
}

/// Some check failed (exit 1).
#[derive(Debug, thiserror::Error)]
#[error("{0} of the board's checks failed")]
pub struct Failed(usize);

pub fn run(a: Args) -> anyhow::Result<()> {
    std::fs::create_dir_all(&a.out).map_err(|e| anyhow::anyhow!("{}: {e}", a.out.display()))?;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let opts = Options::default();
    eprintln!(
        "recording {} s with the board lying still",
        a.duration.as_secs()
    );
    let checks = match &a.link.simulate {
        Some(cfg) => {
            let sim = rotacal::simulate::Simulation::new(rotacal::simulate::Config::load(cfg)?)?;
            let mut link = SimulatedDevice::new(&sim, a.link.faults.clone().unwrap_or_default())?;
            rt.block_on(closing(&mut link, &a, opts))?
        }
        // Made and dropped inside the runtime (cli/record.rs says why).
        None => rt.block_on(async {
            let mut link = BleLink::new(Target::parse(&a.link.device), a.link.scan_timeout);
            closing(&mut link, &a, opts).await
        })?,
    };
    let failed = checks.iter().filter(|c| !c.passed).count();
    for c in &checks {
        println!(
            "{} {}: {}",
            if c.passed { "ok  " } else { "FAIL" },
            c.claim,
            c.measured
        );
    }
    if failed > 0 {
        return Err(Failed(failed).into());
    }
    println!("All {} checks passed.", checks.len());
    Ok(())
}

async fn closing<L: Link>(
    link: &mut L,
    a: &Args,
    opts: Options,
) -> anyhow::Result<Vec<rotacal::demo::Check>> {
    let r = check_board::check(link, &a.out, a.duration, opts, &mut Plain).await;
    link.close().await;
    r
}
