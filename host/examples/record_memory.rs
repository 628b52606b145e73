//! The recorder's memory over a long session (issue 33, "bounded memory"): `rotacal
//! record`'s session (the recorder, its capture and files on disk) against the emulated
//! firmware for one 10-hour condition of device time, on a paused clock, with 2 % of the
//! notifications lost (so that gaps are held and backfilled all along). The process's
//! resident memory is read from /proc/self/status when the session passes one hour and at
//! its end; the emulated device's stream of conversions is made before either, so what
//! grows between them is the session's. Writes bench/record-memory.json; run by
//! scripts/bench-record-memory, which fails when the growth passes 1 MB.
use rotacal::link::simulated::{Faults, SimulatedDevice};
use rotacal::record::{self, Observer, Paths, Plan, Progress};
use rotacal::recording::{Metadata, Method};
use rotacal::simulate::Simulation;
use rotacal_shared::Condition;
use serde_json::json;
use std::time::Duration;

const HOURS: f64 = 10.0;

/// A field of /proc/self/status, in bytes (`VmRSS`, `VmHWM`).
fn status_bytes(field: &str) -> u64 {
    let text = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    text.lines()
        .find(|l| l.starts_with(field))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|kb| kb.parse::<u64>().ok())
        .map_or(0, |kb| kb * 1024)
}

/// Notes the memory when the session passes its first hour.
#[derive(Default)]
struct AtOneHour {
    rss: Option<u64>,
    hwm: Option<u64>,
}

impl Observer for AtOneHour {
    fn progress(&mut self, p: &Progress) {
        if self.rss.is_none() && p.elapsed >= Duration::from_secs(3600) {
            self.rss = Some(status_bytes("VmRSS:"));
            self.hwm = Some(status_bytes("VmHWM:"));
        }
    }
    fn message(&mut self, _: &str) {}
}

fn main() -> anyhow::Result<()> {
    let mut cfg = rotacal::demo::session_config(2022)?;
    // Condition x for the whole session (y and z are made too, and not recorded).
    cfg.table.samples_per_condition = Some((HOURS * 3600.0 * 104.0) as u64 + 1040);
    let sim = Simulation::new(cfg)?;
    let faults: Faults = "drop=0.02,seed=7".parse()?;
    let mut dev = SimulatedDevice::new(&sim, faults)?;
    let dir = std::env::temp_dir().join(format!("rotacal-record-memory-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let paths = Paths::beside(&dir.join("rec.csv"));
    paths.remove()?;
    let meta = Metadata {
        method: Some(Method::Rotation),
        rate_hz: Some(0.01),
        units: Some("counts".into()),
        sample_rate_hz: Some(16.0),
        ..Metadata::default()
    };
    let before = status_bytes("VmRSS:");
    let (rt, opts) = rotacal::demo::paused()?;
    let mut obs = AtOneHour::default();
    let outcome = rt.block_on(async {
        let (info, bytes) = record::connect(&mut dev, &opts, &mut obs).await?;
        let files = record::open_files(&paths, &meta, &bytes, info.tick_hz, Condition::X, false)?;
        let plan = Plan {
            condition: Condition::X,
            rate_uhz: 10_000,
            duration: Duration::from_secs_f64(HOURS * 3600.0),
            sample_rate_mhz: Some(16_000),
            restart: false,
        };
        record::record(&mut dev, info, files, plan, opts, &mut obs)
            .await
            .map_err(|(e, _)| anyhow::anyhow!("{e}"))
    })?;
    let end_hwm = status_bytes("VmHWM:");
    let end_rss = status_bytes("VmRSS:");
    let (Some(rss_1h), Some(hwm_1h)) = (obs.rss, obs.hwm) else {
        anyhow::bail!("the session never passed its first hour");
    };
    // Within 1 MB of the first hour's peak (issue 33's proof point).
    let growth = end_hwm.saturating_sub(hwm_1h);
    let out = json!({
        "what": "rotacal record's session over one 10-hour condition of device time (16 Hz, 2 % of notifications lost, backfilled), emulated firmware, paused clock",
        "device_hours": HOURS,
        "rows": outcome.summary.rows,
        "recovered": outcome.summary.recovered,
        "lost": outcome.summary.lost_samples(),
        "rss_before_session_bytes": before,
        "rss_at_1h_bytes": rss_1h,
        "peak_rss_at_1h_bytes": hwm_1h,
        "peak_rss_at_end_bytes": end_hwm,
        "rss_at_end_bytes": end_rss,
        "growth_after_1h_bytes": growth,
        "limit_bytes": 1_000_000,
        "passed": growth <= 1_000_000,
    });
    println!("{}", serde_json::to_string_pretty(&out)?);
    std::fs::write(
        concat!(env!("CARGO_MANIFEST_DIR"), "/../bench/record-memory.json"),
        serde_json::to_string_pretty(&out)? + "\n",
    )?;
    paths.remove()?;
    let _ = std::fs::remove_dir(&dir);
    if growth > 1_000_000 {
        anyhow::bail!("memory grew by {growth} bytes after the first hour (limit 1 MB)");
    }
    Ok(())
}
