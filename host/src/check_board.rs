//! `rotacal check-board`: what a user runs on the first day with a new board. It finds the
//! device's advertisement, reads its info and status, records a still condition (60 s by
//! default) and judges what only a board can show: the clock the timestamps run on, the
//! link's MTU, that no sample is lost on the link and no conversion on the device, the
//! sensor's conversion rate, its noise density against the datasheet's, and that the
//! device's own fit agrees with the host's. docs/first-board.md lists each item.

use crate::demo::Check;
use crate::link::Link;
use crate::record::{self, Observer, Options, Outcome, Paths, Plan};
use crate::recording::{Metadata, Method, Recording};
use rotacal_shared::device::route::{batch_len, MIN_MTU};
use rotacal_shared::packet::{ClockSource, DeviceInfo};
use rotacal_shared::Condition;
use std::path::Path;
use std::time::Duration;

/// The LSM6DS33's accelerometer noise density in high-performance mode, µg/√Hz (typical,
/// datasheet table 3).
pub const DATASHEET_DENSITY_UG: f64 = 90.0;

/// A board's density may be this factor above or below the datasheet's typical value
/// before the check fails (a typical value, not a limit; the datasheet gives none).
pub const DENSITY_FACTOR: f64 = 2.0;

/// The sensor's conversion rate may be this far from nominal: rotacal's allowance for its
/// internal oscillator (the sampler copes with 7 %; the datasheet gives no tolerance).
pub const ODR_TOLERANCE: f64 = 0.02;

/// Accelerometer sensitivity of the LSM6DS33, mg per count, at ±2, ±4, ±8 and ±16 g
/// (typical, datasheet table 3).
fn mg_per_count(full_scale_g: u8) -> Option<f64> {
    match full_scale_g {
        2 => Some(0.061),
        4 => Some(0.122),
        8 => Some(0.244),
        16 => Some(0.488),
        _ => None,
    }
}

/// The rate the device's fit is told, µHz: a still board fits a sine of any period, and
/// the fit needs 1.5 periods (30 s at 0.05 Hz) to report.
pub const RATE_UHZ: u32 = 50_000;

/// What a check-board run gathered.
pub struct Board {
    /// The device info.
    pub info: DeviceInfo,
    /// The link's ATT MTU.
    pub mtu: u16,
    /// The recording's outcome.
    pub outcome: Outcome,
    /// What the link is.
    pub link: String,
}

/// Connect and record `duration` of condition x (the board lying still) into `dir`.
pub async fn run<L: Link>(
    link: &mut L,
    dir: &Path,
    duration: Duration,
    opts: Options,
    obs: &mut impl Observer,
) -> anyhow::Result<Board> {
    let (info, info_bytes) = record::connect(link, &opts, obs).await?;
    let paths = Paths::beside(&dir.join("check.csv"));
    paths.remove()?;
    let meta = Metadata {
        method: Some(Method::Rotation),
        rate_hz: Some(f64::from(RATE_UHZ) * 1e-6),
        units: Some("counts".into()),
        device: Some(link.describe()),
        ..Metadata::default()
    };
    let files = record::open_files(
        &paths,
        &meta,
        &info_bytes,
        info.tick_hz,
        Condition::X,
        false,
    )?;
    let plan = Plan {
        condition: Condition::X,
        rate_uhz: RATE_UHZ,
        duration,
        sample_rate_mhz: None,
        restart: true,
    };
    let outcome = record::record(link, info, files, plan, opts, obs)
        .await
        .map_err(|(e, _)| anyhow::anyhow!("recording: {e}"))?;
    Ok(Board {
        info,
        mtu: link.mtu(),
        outcome,
        link: link.describe(),
    })
}

/// The conversions of the recording's first group: how many the sensor made (read and
/// missed) and the time from the first to the last read, s.
fn conversions(rec: &Recording, tick_hz: f64) -> Option<(u64, f64, u64)> {
    let g = rec.groups.first()?;
    let aps = g.conversions.as_ref()?;
    let missed = g.missed.as_ref()?;
    let made: u64 = aps
        .iter()
        .zip(missed)
        .map(|(a, m)| a.len() as u64 + u64::from(m.unwrap_or(0)))
        .sum();
    let missed_total: u64 = missed.iter().map(|m| u64::from(m.unwrap_or(0))).sum();
    let first = *g.t_s.first()?;
    let last_row = g.t_s.len().checked_sub(1)?;
    let last_span: u64 = aps
        .get(last_row)?
        .gaps()
        .iter()
        .map(|x| u64::from(*x))
        .sum();
    let last = g.t_s.get(last_row)? + last_span as f64 / tick_hz;
    Some((made, last - first, missed_total))
}

/// The noise of one conversion, counts, per channel: from second differences of the rows,
/// which a still board's slow changes (and a slow table's sine) leave out, each row's
/// variance σ²/n for its n conversions.
pub fn conversion_noise(rec: &Recording) -> Option<[f64; 3]> {
    let g = rec.groups.first()?;
    let aps = g.conversions.as_ref()?;
    let inv: Vec<f64> = aps.iter().map(|a| 1.0 / a.len().max(1) as f64).collect();
    let mut out = [0.0; 3];
    for (o, ch) in out.iter_mut().zip([&g.u, &g.v, &g.w]) {
        let (mut ss, mut weight) = (0.0, 0.0);
        for i in 1..ch.len().saturating_sub(1) {
            let (a, b, c) = (ch.get(i - 1)?, ch.get(i)?, ch.get(i + 1)?);
            let d = a - 2.0 * b + c;
            ss += d * d;
            weight += inv.get(i - 1)? + 4.0 * inv.get(i)? + inv.get(i + 1)?;
        }
        if weight <= 0.0 {
            return None;
        }
        *o = (ss / weight).sqrt();
    }
    Some(out)
}

/// Judge the board from what [`run`] gathered and the recording and fit log it wrote.
pub fn assess(b: &Board, rec: &Recording, crosscheck_passed: bool) -> Vec<Check> {
    let mut c = Vec::new();
    let i = &b.info;
    c.push(Check {
        claim: "the device advertises and answers".into(),
        passed: true,
        measured: format!(
            "{}: firmware {}.{}.{}, {:?}, ring {} samples",
            b.link, i.firmware[0], i.firmware[1], i.firmware[2], i.chip, i.ring_capacity
        ),
    });
    c.push(Check {
        claim: "timestamps run on the 32 MHz crystal".into(),
        passed: i.clock == ClockSource::TimerHfxo,
        measured: record::clock_warning(i)
            .unwrap_or_else(|| format!("clock {:?} at {} Hz", i.clock, i.tick_hz)),
    });
    c.push(Check {
        claim: format!("the link's ATT MTU carries the device's packets (at least {MIN_MTU})"),
        passed: b.mtu >= MIN_MTU,
        measured: format!(
            "MTU {} bytes: {} samples a batch",
            b.mtu,
            batch_len(b.mtu).map_or("no".into(), |n| n.to_string())
        ),
    });
    let o = &b.outcome;
    c.push(Check {
        claim: "nothing lost on the link".into(),
        passed: o.summary.lost.is_empty() && o.undecodable == 0,
        measured: format!(
            "{} samples, {} lost, {} recovered by replay, {} undecodable, {} link drop(s)",
            o.summary.rows,
            o.summary.lost_samples(),
            o.summary.recovered,
            o.undecodable,
            o.link_drops
        ),
    });
    let odr = f64::from(i.sensor_odr_mhz) / 1000.0;
    match conversions(rec, f64::from(i.tick_hz)) {
        Some((made, span, missed)) if span > 0.0 => {
            c.push(Check {
                claim: "every conversion read".into(),
                passed: missed == 0 && o.device_lost == 0,
                measured: format!(
                    "{made} conversions, {missed} not read (conv_missed), {} lost on the \
                     device (status)",
                    o.device_lost
                ),
            });
            let rate = (made.saturating_sub(1)) as f64 / span;
            let dev = rate / odr - 1.0;
            c.push(Check {
                claim: format!(
                    "the sensor converts at {odr} Hz within ±{:.0} %",
                    ODR_TOLERANCE * 100.0
                ),
                passed: dev.abs() <= ODR_TOLERANCE,
                measured: format!(
                    "{rate:.4} Hz over {span:.1} s of the device clock ({:+.0} ppm)",
                    dev * 1e6
                ),
            });
        }
        _ => c.push(Check {
            claim: "the recording has the conversions' instants".into(),
            passed: false,
            measured: "no conv_gaps or conv_missed column, or under one row".into(),
        }),
    }
    match (conversion_noise(rec), mg_per_count(i.full_scale_g)) {
        (Some(sigma), Some(mg)) => {
            // White up to the Nyquist frequency of the conversions.
            let density = sigma.map(|s| s * mg * 1000.0 / (odr / 2.0).sqrt());
            let lo = DATASHEET_DENSITY_UG / DENSITY_FACTOR;
            let hi = DATASHEET_DENSITY_UG * DENSITY_FACTOR;
            c.push(Check {
                claim: format!(
                    "noise density within {DENSITY_FACTOR}× of the datasheet's \
                     {DATASHEET_DENSITY_UG} µg/√Hz"
                ),
                passed: density.iter().all(|d| (lo..=hi).contains(d)),
                measured: format!(
                    "u {:.0}, v {:.0}, w {:.0} µg/√Hz (one conversion: {:.2}, {:.2}, {:.2} \
                     counts)",
                    density[0], density[1], density[2], sigma[0], sigma[1], sigma[2]
                ),
            });
        }
        _ => c.push(Check {
            claim: "noise density measured".into(),
            passed: false,
            measured: format!(
                "no noise estimate (too few rows, or full scale ±{} g unknown)",
                i.full_scale_g
            ),
        }),
    }
    c.push(Check {
        claim: "the device's streaming fit agrees with the host's re-fit".into(),
        passed: crosscheck_passed && o.final_fit,
        measured: format!(
            "final fit report {}, cross-check {}",
            if o.final_fit { "received" } else { "missing" },
            if crosscheck_passed {
                "passed"
            } else {
                "failed"
            }
        ),
    });
    c
}

/// [`run`], then [`assess`] of the files it wrote.
pub async fn check<L: Link>(
    link: &mut L,
    dir: &Path,
    duration: Duration,
    opts: Options,
    obs: &mut impl Observer,
) -> anyhow::Result<Vec<Check>> {
    let board = run(link, dir, duration, opts, obs).await?;
    let paths = Paths::beside(&dir.join("check.csv"));
    // One condition: read as a recording in progress (a full one needs x, y and z).
    let rec = crate::recording::read_in_progress(&paths.recording)?;
    let log = crate::recording::from_device::read_fit_log(
        &std::fs::read_to_string(&paths.fits)?,
        &paths.fits.display().to_string(),
    )?;
    let x = crate::verify::recorded::crosscheck(
        &rec,
        &log,
        crate::verify::recorded::DEFAULT_THRESHOLD,
    )?;
    Ok(assess(&board, &rec, x.passed))
}
