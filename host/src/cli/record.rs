//! `rotacal record` and `rotacal decode`: open the link and files, show progress
//! (indicatif), report the outcome.

use indicatif::{ProgressBar, ProgressStyle};
use rotacal::link::ble::{BleLink, Target};
use rotacal::link::simulated::{Faults, SimulatedDevice};
use rotacal::link::Link;
use rotacal::record::{self, LinkState, Observer, Options, Paths, Plan, Progress};
use rotacal::recording::{Metadata, Method};
use rotacal_shared::packet::{Chip, DeviceInfo};
use rotacal_shared::Condition;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// The device to talk to: over BLE by name or address, or the firmware's logic on this
/// host (`record`, `check-board`).
#[derive(clap::Args)]
pub struct DeviceArgs {
    /// The device's advertised name or Bluetooth address.
    #[arg(long, default_value = "rotacal", conflicts_with = "simulate")]
    pub device: String,
    /// A simulated device instead (the firmware's logic on this host, in real time), fed
    /// by a simulator preset or TOML file: a dry run of the set-up.
    #[arg(long, value_name = "CONFIG")]
    pub simulate: Option<String>,
    /// Faults for the simulated device, e.g. outage=60:5,drop=0.01,burst=3,garbage=100
    /// (also firmware=, protocol=, replaced=, mute_after=, seed=, mtu=, late=, stuck=;
    /// rotacal help recording).
    #[arg(long, requires = "simulate")]
    pub faults: Option<Faults>,
    /// How long to scan for the device per attempt, e.g. 20s.
    #[arg(long, default_value = "20s", value_parser = rotacal::record::parse_duration)]
    pub scan_timeout: Duration,
}

/// The command line of `rotacal record`.
#[derive(clap::Args)]
pub struct Args {
    /// Which device, or a simulated one.
    #[command(flatten)]
    pub link: DeviceArgs,
    /// The platter axis the table turns about: x, y or z.
    #[arg(long)]
    pub condition: char,
    /// Nominal rotation rate of the table, Hz.
    #[arg(long)]
    pub rate_hz: f64,
    /// How long to record, e.g. 300s, 5min.
    #[arg(long, value_parser = rotacal::record::parse_duration)]
    pub duration: Duration,
    /// Sample rate to set on the device, Hz (default: the device's).
    #[arg(long)]
    pub sample_rate_hz: Option<f64>,
    /// Local gravity, m/s² (metadata).
    #[arg(long)]
    pub g_loc: Option<f64>,
    /// The recording to write; the fit log and capture go beside it.
    #[arg(long)]
    pub out: PathBuf,
    /// Add this condition to an existing recording.
    #[arg(long)]
    pub append: bool,
    /// Stop a condition the device is still running first.
    #[arg(long)]
    pub restart: bool,
    /// Give up when the link stays down this long, e.g. 60s.
    #[arg(long, default_value = "60s", value_parser = rotacal::record::parse_duration)]
    pub reconnect_for: Duration,
}

/// The recording finished, but not everything the device sent is in it: exit status 3
/// (documented in the README), so that scripts can tell it from a failure (1).
#[derive(Debug)]
pub struct Incomplete(pub String);

impl std::fmt::Display for Incomplete {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Incomplete {}

struct Bar(ProgressBar);

impl Observer for Bar {
    fn progress(&mut self, p: &Progress) {
        let link = match p.link {
            LinkState::Connected => "connected".to_string(),
            LinkState::Reconnecting(n) => format!("RECONNECTING (attempt {n})"),
        };
        let rate = p.rows as f64 / p.elapsed.as_secs_f64().max(1e-9);
        self.0.set_length(p.duration.as_secs());
        self.0
            .set_position(p.elapsed.as_secs().min(p.duration.as_secs()));
        self.0.set_message(format!(
            "{} samples ({rate:.1}/s) | missing {} recovered {} lost {} | bad values {} | {link}",
            p.rows, p.missing, p.recovered, p.lost, p.undecodable
        ));
    }

    fn message(&mut self, m: &str) {
        // A hidden bar (stderr not a terminal: a script, a log file) prints nothing, but
        // the messages (link lost, samples given up, the device's identity) must reach it.
        if self.0.is_hidden() {
            eprintln!("{m}");
        } else {
            self.0.println(m);
        }
    }
}

fn chip(c: Chip) -> &'static str {
    match c {
        Chip::None => "no accelerometer",
        Chip::Lsm6ds33 => "LSM6DS33",
        Chip::Lsm6ds3trc => "LSM6DS3TR-C",
    }
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let condition = Condition::from_letter(a.condition)
        .ok_or_else(|| anyhow::anyhow!("--condition '{}': expected x, y or z", a.condition))?;
    if !(a.rate_hz.is_finite() && a.rate_hz > 0.0 && a.rate_hz < 4294.0) {
        anyhow::bail!(
            "--rate-hz {}: expected a positive rate below 4294 Hz",
            a.rate_hz
        );
    }
    let sample_rate_mhz = match a.sample_rate_hz {
        Some(f) if f.is_finite() && f > 0.0 && f * 1e3 < f64::from(u32::MAX) => {
            Some((f * 1e3).round() as u32)
        }
        Some(f) => anyhow::bail!("--sample-rate-hz {f}: expected a positive rate"),
        None => None,
    };
    if let Some(g) = a.g_loc {
        if !(g.is_finite() && g > 0.0) {
            anyhow::bail!("--g-loc {g}: expected a positive acceleration in m/s²");
        }
    }
    let plan = Plan {
        condition,
        rate_uhz: (a.rate_hz * 1e6).round() as u32,
        duration: a.duration,
        sample_rate_mhz,
        restart: a.restart,
    };
    let opts = Options {
        reconnect_for: a.reconnect_for,
        ..Options::default()
    };
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    match &a.link.simulate {
        Some(cfg) => {
            let sim = rotacal::simulate::Simulation::new(rotacal::simulate::Config::load(cfg)?)?;
            let mut link = SimulatedDevice::new(&sim, a.link.faults.clone().unwrap_or_default())?;
            rt.block_on(closing(&mut link, &a, plan, opts))
        }
        // The link is made and dropped inside the runtime: bluez-async's streams remove
        // their D-Bus match rules in a task when dropped, which panics (and, in a
        // destructor, aborts the process) outside a runtime.
        None => rt.block_on(async {
            let mut link = BleLink::new(Target::parse(&a.link.device), a.link.scan_timeout);
            closing(&mut link, &a, plan, opts).await
        }),
    }
}

/// The session, then the link closed whatever its outcome.
async fn closing<L: Link>(link: &mut L, a: &Args, plan: Plan, opts: Options) -> anyhow::Result<()> {
    let result = session(link, a, plan, opts).await;
    link.close().await;
    result
}

async fn session<L: Link>(link: &mut L, a: &Args, plan: Plan, opts: Options) -> anyhow::Result<()> {
    let bar = ProgressBar::new(plan.duration.as_secs());
    bar.set_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} s  {msg}")
            .map_err(anyhow::Error::msg)?
            .progress_chars("=> "),
    );
    bar.set_message(format!("connecting to {}", link.describe()));
    let mut obs = Bar(bar);
    let (info, info_bytes) = record::connect(link, &opts, &mut obs).await?;
    let meta = metadata(a, &info, &link.describe());
    let paths = Paths::beside(&a.out);
    let files = record::open_files(
        &paths,
        &meta,
        &info_bytes,
        info.tick_hz,
        plan.condition,
        a.append,
    )?;
    obs.message(&format!(
        "{}: {} on firmware {}.{}.{}, clock {} Hz, ring {} samples",
        link.describe(),
        chip(info.chip),
        info.firmware[0],
        info.firmware[1],
        info.firmware[2],
        info.tick_hz,
        info.ring_capacity
    ));
    let result = record::record(link, info, files, plan, opts, &mut obs).await;
    obs.0.finish_and_clear();
    let files = format!(
        "{}, {}, {}",
        paths.recording.display(),
        paths.fits.display(),
        paths.capture.display()
    );
    match result {
        Ok(o) => {
            let s = &o.summary;
            // Exit 0 only for files that read back as calibrate reads them.
            let written = s.rows;
            record::check_reads_back(&paths, plan.condition, written).map_err(|e| {
                anyhow::anyhow!("the recording does not read back: {e}\nfiles: {files}")
            })?;
            println!(
                "recorded condition {}: {} samples ({} recovered by replay, {} received twice, \
                 {} lost{}), {} fit-log lines, {} link drop(s), {} undecodable value(s), {} \
                 conversion(s) lost on the device{}{}\n\
                 files: {files}",
                plan.condition.letter(),
                s.rows,
                s.recovered,
                s.duplicates,
                s.lost_samples(),
                if s.lost.is_empty() {
                    String::new()
                } else {
                    format!(": seq {:?}", s.lost)
                },
                s.fit_lines,
                o.link_drops,
                o.undecodable,
                o.device_lost,
                if o.final_fit {
                    ""
                } else {
                    "; the final fit report is missing"
                },
                match o.restarts {
                    0 => String::new(),
                    n => format!(
                        "; the device restarted {n} time(s) (a watchdog, a panic or its power): \
                         the condition's rows are in {} boots, which calibrate joins; lost seqs \
                         are numbered in their boot",
                        n + 1
                    ),
                }
            );
            // A sample batch that did not decode is a gap in the seqs: asked for again,
            // or among the lost. What the results characteristic carried is not.
            if s.lost.is_empty() && o.undecodable_results == 0 {
                Ok(())
            } else {
                Err(Incomplete(format!(
                    "the recording reads back but is incomplete: {} sample(s) lost, {} \
                     value(s) of the results characteristic (fit reports, quick-look, \
                     status) did not decode",
                    s.lost_samples(),
                    o.undecodable_results
                ))
                .into())
            }
        }
        Err((e, summary)) => {
            let kept = summary.map_or_else(
                || "what arrived is in the capture (rotacal decode rebuilds from it)".into(),
                |s| match record::check_reads_back(&paths, plan.condition, s.rows) {
                    _ if s.rows == 0 => "no samples were recorded".to_string(),
                    Ok(()) => format!("{} samples kept in a file that reads back", s.rows),
                    Err(why) => format!(
                        "{} samples kept, but the file does not read back ({why}); the capture \
                         holds what arrived (rotacal decode rebuilds from it)",
                        s.rows
                    ),
                },
            );
            anyhow::bail!("{e}\n{kept}; files: {files}")
        }
    }
}

fn metadata(a: &Args, info: &DeviceInfo, link: &str) -> Metadata {
    let sample_rate = a
        .sample_rate_hz
        .unwrap_or(f64::from(info.sample_rate_mhz) / 1e3);
    Metadata {
        method: Some(Method::Rotation),
        rate_hz: Some(a.rate_hz),
        g_loc: a.g_loc,
        units: Some("counts".into()),
        sample_rate_hz: Some(sample_rate),
        noise_sigma: None,
        device: Some(format!(
            "{} firmware {}.{}.{} ({link})",
            chip(info.chip),
            info.firmware[0],
            info.firmware[1],
            info.firmware[2]
        )),
        other: Default::default(),
    }
}

pub fn decode(capture: &Path, out: &Path) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(capture)
        .map_err(|e| anyhow::anyhow!("{}: {e}", capture.display()))?;
    let cap = rotacal::record::capture::read(&text, &capture.display().to_string())
        .map_err(anyhow::Error::msg)?;
    let paths = Paths::beside(out);
    let create = |p: &Path| {
        std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(p)
            .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))
    };
    let rows = create(&paths.recording)?;
    let fits = create(&paths.fits)?;
    let r = rotacal::record::capture::rebuild(&cap, rows, fits)
        .map_err(|e| anyhow::anyhow!("{}: {e}", capture.display()))?;
    let s = &r.summary;
    println!(
        "rebuilt {} samples ({} lost: {:?}), {} fit-log lines{}\nfiles: {}, {}",
        s.rows,
        s.lost_samples(),
        s.lost,
        s.fit_lines,
        if cap.truncated {
            "; the capture's last line was incomplete and is ignored"
        } else {
            ""
        },
        paths.recording.display(),
        paths.fits.display()
    );
    if let Some((line, why)) = r.undecodable.first() {
        anyhow::bail!(
            "{}:{line}: {why}; {} value(s) in all did not decode and were skipped \
             (the rest is rebuilt)",
            capture.display(),
            r.undecodable.len()
        );
    }
    Ok(())
}
