//! `rotacal record`'s logic against the simulated device (the firmware's logic on the
//! host) with faults: outages shorter and longer than the ring buffer, dropped and
//! garbage notifications, wrong firmware and protocol versions, a link that never
//! returns. Every run is on a paused clock, so 262 s of recording take a fraction of
//! a second. Then a real-time run of the binary killed with SIGKILL.
use crate::common;
use rotacal::link::simulated::{Faults, SimulatedDevice};
use rotacal::record::capture;
use rotacal::record::{self, Options, Outcome, Paths, Plan, Quiet, RecordError};
use rotacal::recording::{self, Metadata, Method};
use rotacal::simulate::Simulation;
use rotacal_shared::device::route::STREAM_QUEUE;
use rotacal_shared::packet::MAX_AVERAGES;
use rotacal_shared::Condition;
use std::path::PathBuf;
use std::time::Duration;

/// Samples the device streams for condition x: 262.5 s at 16 Hz, each the average of the
/// conversions in its slot; the slot still open at Stop is dropped.
const N: u64 = 4199;

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("rotacal-rec-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn sim() -> Simulation {
    Simulation::new(rotacal::demo::session_config(7).unwrap()).unwrap()
}

struct Run {
    result: Result<
        Outcome,
        (
            RecordError,
            Option<rotacal::recording::from_device::RecordSummary>,
        ),
    >,
    paths: Paths,
    messages: Vec<String>,
    /// Conversions the emulated firmware did not read.
    unread: u64,
    /// Notifications delivered with a bit flipped.
    flipped: u64,
}

fn run_with(name: &str, faults: &str, opts: Options) -> Result<Run, RecordError> {
    let d = dir(name);
    let paths = Paths::beside(&d.join("rec.csv"));
    let mut dev = SimulatedDevice::new(&sim(), faults.parse::<Faults>().unwrap()).unwrap();
    let rt = crate::common::paused_runtime();
    let meta = Metadata {
        method: Some(Method::Rotation),
        rate_hz: Some(0.01),
        units: Some("counts".into()),
        ..Metadata::default()
    };
    rt.block_on(async {
        let mut obs = Quiet::default();
        let (info, bytes) = record::connect(&mut dev, &opts, &mut obs).await?;
        let files = record::open_files(&paths, &meta, &bytes, info.tick_hz, Condition::X, false)?;
        let plan = Plan {
            condition: Condition::X,
            rate_uhz: 10_000,
            duration: Duration::from_secs_f64(262.5),
            sample_rate_mhz: Some(16_000),
            restart: false,
        };
        let result = record::record(&mut dev, info, files, plan, opts, &mut obs).await;
        Ok(Run {
            result,
            paths,
            messages: obs.messages,
            unread: dev.unread(),
            flipped: dev.flipped(),
        })
    })
}

fn run(name: &str, faults: &str) -> Run {
    let opts = Options {
        sync: false,
        ..Options::default()
    };
    run_with(name, faults, opts).unwrap()
}

/// The seq column of a recording, which must read back.
fn seqs(p: &std::path::Path) -> Vec<u64> {
    let text = std::fs::read_to_string(p).unwrap();
    recording::read_in_progress(p).unwrap();
    text.lines()
        .filter(|l| l.starts_with("x,"))
        .map(|l| l.split(',').nth(1).unwrap().parse().unwrap())
        .collect()
}

/// The recording rebuilt from the capture is the same file.
fn rebuild_matches(r: &Run) {
    let text = std::fs::read_to_string(&r.paths.capture).unwrap();
    let cap = capture::read(&text, "capture").unwrap();
    let (mut rows, mut fits) = (Vec::new(), Vec::new());
    let rebuilt = capture::rebuild(&cap, &mut rows, &mut fits).unwrap();
    assert_eq!(
        String::from_utf8(rows).unwrap(),
        std::fs::read_to_string(&r.paths.recording).unwrap(),
        "rebuilt from the capture: {rebuilt:?}"
    );
    assert_eq!(fits, std::fs::read(&r.paths.fits).unwrap());
}

/// The cross-check of a run's recording and fit log at the default threshold, which must
/// pass; the report and the fit log.
fn crosscheck_of(
    r: &Run,
) -> (
    rotacal::verify::recorded::CrosscheckReport,
    Vec<rotacal::recording::from_device::LogLine>,
) {
    use rotacal::verify::recorded::{crosscheck, render, DEFAULT_THRESHOLD};
    let rec = recording::read_in_progress(&r.paths.recording).unwrap();
    let log = rotacal::recording::from_device::read_fit_log(
        &std::fs::read_to_string(&r.paths.fits).unwrap(),
        "fits",
    )
    .unwrap();
    let x = crosscheck(&rec, &log, DEFAULT_THRESHOLD).unwrap();
    assert!(x.passed, "{}", render(&x));
    (x, log)
}

fn crosscheck_passes(r: &Run) {
    let (x, _) = crosscheck_of(r);
    // Periodic reports every 160 samples once the fit has a result (1.5 periods), and
    // the final one: 12, as in the QEMU session (36 for three conditions).
    assert_eq!(x.fits.len(), 12);
}

#[test]
fn a_clean_session_records_every_sample() {
    let r = run("clean", "");
    let o = r.result.as_ref().unwrap();
    assert_eq!(o.summary.rows, N);
    assert!(o.summary.lost.is_empty() && o.summary.recovered == 0);
    assert!(o.final_fit && o.link_drops == 0 && o.undecodable == 0);
    assert_eq!(seqs(&r.paths.recording), (0..N).collect::<Vec<_>>());
    crosscheck_passes(&r);
    rebuild_matches(&r);
}

#[test]
fn an_outage_shorter_than_the_ring_is_backfilled() {
    // 10 s down: 160 samples. Up to the firmware's stream queue of them (STREAM_QUEUE
    // batches of at most MAX_AVERAGES) wait in it and go out after the reconnection; the
    // rest come back by replay from the ring.
    let r = run("short-outage", "outage=100:10");
    let o = r.result.as_ref().unwrap();
    assert_eq!(o.link_drops, 1);
    assert_eq!(o.summary.rows, N, "{:?}", r.messages);
    assert!(o.summary.lost.is_empty());
    let queued = (STREAM_QUEUE * MAX_AVERAGES) as u64;
    assert!(
        o.summary.recovered >= 160 - queued,
        "{}",
        o.summary.recovered
    );
    assert_eq!(seqs(&r.paths.recording), (0..N).collect::<Vec<_>>());
    crosscheck_passes(&r);
    rebuild_matches(&r);
}

#[test]
fn outages_of_5_15_and_30_s_lose_nothing() {
    // Through the firmware's own queues (the stream queue's STREAM_QUEUE batches wait
    // through an outage, the results queue paces the replays): issue 33's outages.
    for secs in [5, 15, 30] {
        let r = run(&format!("outage-{secs}"), &format!("outage=100:{secs}"));
        let o = r.result.as_ref().unwrap();
        assert_eq!(o.link_drops, 1, "{secs} s");
        assert!(
            o.summary.lost.is_empty(),
            "{secs} s: lost {:?}",
            o.summary.lost
        );
        assert_eq!(o.summary.rows, N, "{secs} s: {:?}", r.messages);
        assert_eq!(seqs(&r.paths.recording), (0..N).collect::<Vec<_>>());
        crosscheck_passes(&r);
        rebuild_matches(&r);
    }
}

#[test]
fn a_slow_replay_is_waited_for_while_its_samples_come() {
    // A 30 s gap replayed over a slow link (one notification every 150 ms, of which the
    // live stream takes a third: the replay's 69 batches take about 15 s, and its status
    // reply follows them). While replayed samples come, the recorder waits for the reply
    // rather than writing the Backfill again, which would start the replay over (before:
    // 1442 samples received twice and ten "no status reply" messages). Then the same
    // with 5 % of notifications lost, and with the replay cut by three 2 s link drops
    // (each request after one brings part of what is missing: a fresh count of requests,
    // `record::tests::a_request_that_brought_samples_starts_a_fresh_count`).
    for faults in [
        "outage=100:30,notify_every=150",
        "outage=100:30,notify_every=150,drop=0.05",
        "outage=100:30,notify_every=150,outage=135:2,outage=141:2,outage=147:2",
    ] {
        let r = run("slow-replay", faults);
        let o = r.result.as_ref().unwrap();
        println!("{faults}: {:?}\n{:?}", o.summary, r.messages);
        assert!(o.summary.lost.is_empty(), "{faults}: {:?}", r.messages);
        assert_eq!(o.summary.rows, N, "{faults}");
        assert_eq!(seqs(&r.paths.recording), (0..N).collect::<Vec<_>>());
        assert!(
            !r.messages.iter().any(|m| m.contains("no status reply")),
            "{faults}: {:?}",
            r.messages
        );
        if !faults.contains("outage=135") {
            assert_eq!(o.summary.duplicates, 0, "{faults}");
        }
    }
}

#[test]
fn an_outage_longer_than_the_ring_loses_only_what_left_it() {
    // 60 s down: the device keeps the last RING samples (32 s); the rest is reported lost.
    let ring = rotacal_shared::device::RING as u64;
    let ring_s = ring as f64 / 16.0;
    let r = run("long-outage", "outage=100:60");
    let o = r.result.as_ref().unwrap();
    let s = &o.summary;
    assert_eq!(s.lost.len(), 1, "{:?}", s.lost);
    let (a, b) = s.lost[0];
    assert_eq!(
        s.rows + s.lost_samples(),
        N,
        "every sample written or reported lost"
    );
    // The loss starts where the link dropped (100 s, seq 1600, less the part-filled
    // batch of at most 7 samples that went out into the void), or after the batches the
    // firmware's stream queue kept through the outage (at most STREAM_QUEUE of
    // MAX_AVERAGES samples), and spans about 60 s less the ring's and those (1 s less to
    // 3 s more, for when the reconnection and the replay are seen).
    let queued = (STREAM_QUEUE * MAX_AVERAGES) as u32;
    assert!((1590..=1600 + queued).contains(&a), "lost from {a}");
    let lost_s = f64::from(b - a + 1) / 16.0;
    let queued_s = f64::from(queued) / 16.0;
    assert!(
        (60.0 - ring_s - 1.0 - queued_s..=60.0 - ring_s + 3.0).contains(&lost_s),
        "{lost_s} s lost"
    );
    // The ring's samples, less those pushed out between the reconnection and the replay
    // (the gap shows with the first live batch: at most 7 samples or 1 s later, so at
    // most 2 s at 16 Hz).
    assert!(s.recovered >= ring - 32, "{}", s.recovered);
    let q = seqs(&r.paths.recording);
    assert!(q.windows(2).all(|w| w[0] < w[1]), "seq increasing");
    assert!(r
        .messages
        .iter()
        .any(|m| m.contains("left the device's ring")));
    rebuild_matches(&r);
}

#[test]
fn dropped_notifications_are_asked_for_again() {
    let r = run("drops", "drop=0.05,seed=3");
    let o = r.result.as_ref().unwrap();
    assert_eq!(o.summary.rows, N, "{:?}", o.summary.lost);
    assert!(o.summary.lost.is_empty());
    assert!(o.summary.recovered > 100, "{}", o.summary.recovered);
    crosscheck_passes(&r);
}

#[test]
fn garbage_notifications_are_counted_and_ignored() {
    let r = run("garbage", "garbage=7,seed=5");
    let o = r.result.as_ref().unwrap();
    assert!(o.undecodable > 30, "{}", o.undecodable);
    assert_eq!(o.summary.rows, N);
    assert!(r
        .messages
        .iter()
        .any(|m| m.contains("not a rotacal packet")));
    crosscheck_passes(&r);
}

fn refused(faults: &str) -> String {
    let opts = Options {
        sync: false,
        ..Options::default()
    };
    match run_with("refused", faults, opts) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("{faults}: accepted"),
    }
}

#[test]
fn a_device_with_other_firmware_or_protocol_is_refused_by_name() {
    let m = refused("firmware=1.2.3");
    assert!(m.contains("firmware 1.2.3") && m.contains("0.x"), "{m}");
    let m = refused("protocol=2");
    assert!(
        m.contains("protocol version 2")
            && m.contains(&format!("version {}", rotacal_shared::packet::VERSION)),
        "{m}"
    );
}

#[test]
fn a_link_that_never_returns_ends_with_what_was_recorded() {
    let opts = Options {
        sync: false,
        reconnect_for: Duration::from_secs(30),
        ..Options::default()
    };
    let r = run_with("gone", "outage=100:10000", opts).unwrap();
    let (e, s) = r.result.as_ref().unwrap_err();
    assert!(e.to_string().contains("gave up after 3"), "{e}");
    let s = s.as_ref().unwrap();
    // Everything up to the drop (100 s at 16 Hz), within a batch.
    assert!((1580..=1600).contains(&s.rows), "{}", s.rows);
    assert_eq!(seqs(&r.paths.recording).len() as u64, s.rows);
}

#[test]
fn a_killed_recording_is_valid_up_to_its_last_line() {
    use std::io::Write;
    let d = dir("kill");
    let cfg = d.join("sim.toml");
    std::fs::File::create(&cfg)
        .unwrap()
        .write_all(
            b"preset = \"paper-10mhz\"\n[timing]\nsample_rate_hz = 104.0\ntick_hz = 1e6\n\
              [table]\nsamples_per_condition = 27300\n",
        )
        .unwrap();
    let out = d.join("rec.csv");
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_rotacal"))
        .args(["record", "--simulate"])
        .arg(&cfg)
        .args(["--condition", "x", "--rate-hz", "0.01", "--duration", "60s"])
        .arg("--out")
        .arg(&out)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(3500));
    child.kill().unwrap(); // SIGKILL: no destructor, no flush
    child.wait().unwrap();
    let text = std::fs::read_to_string(&out).unwrap();
    assert!(text.ends_with('\n'), "a partial last line");
    let n = seqs(&out).len();
    // Synced every second: at least the first two seconds are on disk.
    assert!(n >= 32, "{n} rows after 3.5 s");
    let q = seqs(&out);
    assert_eq!(q, (0..n as u64).collect::<Vec<_>>());
    // The capture rebuilds at least as much.
    let rebuilt = d.join("rebuilt.csv");
    let (ok, stdout, stderr) = common::run(&[
        std::path::Path::new("decode"),
        &d.join("rec.capture"),
        std::path::Path::new("--out"),
        &rebuilt,
    ]);
    assert!(ok, "{stdout}{stderr}");
    assert!(seqs(&rebuilt).len() >= n);
    // Appending another condition first cuts any partial line, then refuses condition x
    // again by name.
    let (ok, _, err) = common::run(&[
        "record",
        "--simulate",
        cfg.to_str().unwrap(),
        "--condition",
        "x",
        "--rate-hz",
        "0.01",
        "--duration",
        "1s",
        "--append",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("already holds condition x"), "{err}");
}

#[test]
fn a_stop_during_an_outage_waits_for_the_link() {
    // The link is down from 261 s to 266 s: the stop at 262.5 s is written after the
    // reconnection, and the samples of the outage come back from the ring.
    let r = run("stop-outage", "outage=261:5");
    let o = r.result.as_ref().unwrap();
    assert_eq!(o.link_drops, 1, "{:?}", r.messages);
    assert!(o.final_fit);
    assert!(o.summary.lost.is_empty(), "{:?}", o.summary.lost);
    // Sampling went on until the stop arrived, 3.5 s late: more rows, none missing.
    let q = seqs(&r.paths.recording);
    assert!(q.len() as u64 >= N, "{}", q.len());
    assert_eq!(q, (0..q.len() as u64).collect::<Vec<_>>());
    crosscheck_passes(&r);
}

#[test]
fn an_outage_as_long_as_the_ring_loses_nothing() {
    // 30 s down: 480 samples, within the ring's 512 and the stream queue's 84. The replay
    // goes out as the firmware's queues drain (its own routing and depths), the batches
    // kept in its stream queue through the outage go out after the reconnection, and each
    // command's status reply comes (the recorder stops on a missing one).
    let r = run("ring-outage", "outage=100:30");
    let o = r.result.as_ref().unwrap();
    assert_eq!(o.link_drops, 1);
    assert!(o.summary.lost.is_empty(), "{:?}", o.summary.lost);
    assert_eq!(seqs(&r.paths.recording), (0..N).collect::<Vec<_>>());
    crosscheck_passes(&r);
    rebuild_matches(&r);
}

#[test]
fn a_device_whose_crystal_did_not_start_is_named() {
    use rotacal_shared::packet::{Chip, ClockSource, DeviceInfo, Packet};
    let info = |clock| DeviceInfo {
        firmware: rotacal::link::simulated::FIRMWARE,
        chip: Chip::Lsm6ds33,
        clock,
        tick_hz: 1_000_000,
        sensor_odr_mhz: 104_000,
        sample_rate_mhz: 16_000,
        full_scale_g: 2,
        ring_capacity: 512,
    };
    // The device info as the board sends it, read back as the recorder reads it.
    let read = |clock| {
        let bytes = rotacal::recording::from_device::encode(&Packet::Info(info(clock)));
        record::check_info(&bytes).unwrap()
    };
    assert_eq!(record::clock_warning(&read(ClockSource::TimerHfxo)), None);
    let w = record::clock_warning(&read(ClockSource::TimerHfint)).unwrap();
    assert!(w.contains("crystal did not start"), "{w}");
    let w = record::clock_warning(&read(ClockSource::RtcLfrc)).unwrap();
    assert!(w.contains("±500 ppm"), "{w}");
}

/// Issue 32, proof point 3: conversions the firmware reads too late (1 %, each overwritten
/// by the next on the LSM6DS33's latched line) or not at all (reads stuck for 40 ms and
/// for 300 ms) are counted exactly: in the device's `lost`, and per sample in `conv_missed`,
/// so that every row accounts for the 6 or 7 conversions of its 62.5 ms slot.
#[test]
fn conversions_the_device_did_not_read_are_counted() {
    let r = run("unread", "late=0.01,stuck=60:40,stuck=150:300,seed=9");
    let o = r.result.as_ref().unwrap();
    println!("{} unread, device lost {}", r.unread, o.device_lost);
    assert!(r.unread > 250, "{}", r.unread);
    assert_eq!(
        u64::from(o.device_lost),
        r.unread,
        "the status counts every one"
    );
    assert!(o.summary.lost.is_empty(), "{:?}", o.summary.lost);
    let rec = recording::read_in_progress(&r.paths.recording).unwrap();
    let g = &rec.groups[0];
    let missed: Vec<u8> = g
        .missed
        .as_ref()
        .unwrap()
        .iter()
        .map(|m| m.unwrap())
        .collect();
    let counted: u64 = missed.iter().map(|m| u64::from(*m)).sum();
    for (i, (a, m)) in g
        .conversions
        .as_ref()
        .unwrap()
        .iter()
        .zip(&missed)
        .enumerate()
    {
        let slot = a.len() + usize::from(*m);
        assert!(
            (6..=7).contains(&slot),
            "row {i}: {} read + {m} missed",
            a.len()
        );
    }
    // Only the stuck 300 ms leaves slots without a read conversion: the grid restarts at
    // the first read after it, and its conversions after the last slot's end (at most the
    // 32 that 300 ms hold at 104 Hz) are in the status's count and in no row.
    assert!(
        counted <= r.unread && r.unread - counted <= 32,
        "{counted} of {}",
        r.unread
    );
    crosscheck_passes(&r);
    rebuild_matches(&r);
}

/// A board that resets mid-recording comes back idle and counting from zero: the recorder
/// says it restarted, keeps the rows before, starts the condition again and records on in
/// boot 1 to the planned end; the file reads back, the capture rebuilds it, and the device's
/// fit agrees with the rows of its own boot. Three ways: a reset; a panic (the build for
/// boards without a probe resets at once); a hang of the firmware's executor, which takes no
/// event and sends nothing while the SoftDevice keeps the link, until the watchdog resets
/// the board 4 s later.
#[test]
fn a_device_that_restarts_is_named_and_the_recording_goes_on_in_a_new_boot() {
    for fault in ["reset=100", "panic=100", "hang=100"] {
        let r = run(&fault.replace('=', "-"), fault);
        let o = r.result.as_ref().unwrap();
        println!("{fault}: {:?}; {:?}", o.summary, r.messages);
        assert_eq!(o.restarts, 1, "{fault}");
        assert!(
            r.messages
                .iter()
                .any(|m| m.contains("the device restarted") && m.contains("boot 1")),
            "{fault}: {:?}",
            r.messages
        );
        let rec = recording::read_in_progress(&r.paths.recording).unwrap();
        let g = &rec.groups[0];
        let (boot, seq) = (g.boot.as_ref().unwrap(), g.seq.as_ref().unwrap());
        let before = boot.iter().filter(|b| **b == 0).count();
        // About 100 s at 16 Hz before the restart, every seq once and in order; after it
        // the table's remaining time less the restart's (the board boots in 1 s, a hang
        // waits for the watchdog first), every seq of the new boot once and in order.
        assert!((1500..=1610).contains(&before), "{fault}: {before} rows");
        assert_eq!(&seq[..before], &(0..before as u64).collect::<Vec<_>>()[..]);
        let after = &seq[before..];
        assert!(boot[before..].iter().all(|b| *b == 1));
        assert!(after.windows(2).all(|w| w[1] == w[0] + 1), "{fault}");
        assert!(
            (2400..=2600).contains(&after.len()),
            "{fault}: {} rows",
            after.len()
        );
        // Time starts afresh in the new boot.
        assert!(g.t_s[before] < g.t_s[before - 1]);
        // Nothing invented: what the restart cost is counted lost, and only that.
        assert!(
            o.summary.lost_samples() <= 16 * 8,
            "{fault}: {:?}",
            o.summary.lost
        );
        rebuild_matches(&r);
        crosscheck_passes_in_boots(&r);
    }
    // And a stop by another host is named as such.
    let st = rotacal_shared::packet::Status {
        state: rotacal_shared::packet::RunState::Idle,
        sensor: rotacal_shared::packet::SensorStatus::Ok,
        condition: Some(Condition::X),
        lost: 0,
        ring_oldest: 900,
        ring_newest: 1539,
        last_error: None,
    };
    assert!(record::stopped(&st).contains("stopped by another host"));
}

/// The device's fits agree with the recording's rows of their boot.
fn crosscheck_passes_in_boots(r: &Run) {
    let (_, log) = crosscheck_of(r);
    let boots: Vec<u32> = log
        .iter()
        .filter_map(|l| match l {
            rotacal::recording::from_device::LogLine::Fit(f) => Some(f.boot),
            _ => None,
        })
        .collect();
    // Boot 0's 100 s are too short for a periodic report (1.5 periods): boot 1's final
    // one, whose seqs boot 0 has too, is checked against boot 1's rows alone.
    assert_eq!(boots, [1]);
}

#[test]
fn a_session_with_a_restart_calibrates_within_u() {
    use rotacal::demo::{record_session, session_config};
    // The watchdog resets the board 100 s into condition y (262.5 s each).
    let sim = Simulation::new(session_config(2022).unwrap()).unwrap();
    let mut dev = SimulatedDevice::new(&sim, "hang=362.5".parse::<Faults>().unwrap()).unwrap();
    let d = dir("restart-session");
    let paths = Paths::beside(&d.join("rec.csv"));
    let meta = crate::mtu::meta(&sim);
    let outcomes = record_session(&mut dev, &paths, &meta, Duration::from_secs_f64(262.5)).unwrap();
    let restarts: Vec<u32> = outcomes.iter().map(|(_, o)| o.restarts).collect();
    assert_eq!(restarts, [0, 1, 0]);
    let rec = recording::read(&paths.recording).unwrap();
    let boots = |c: Condition| {
        let g = rec.groups.iter().find(|g| g.condition == c).unwrap();
        let b = g.boot.as_ref().unwrap();
        (b[0], b[b.len() - 1])
    };
    // x in the first boot, y across the restart, z (appended) in the second.
    assert_eq!(Condition::ALL.map(boots), [(0, 0), (0, 1), (1, 1)]);
    calibrates_within_u(&paths.recording, &sim);
}

/// The recording at `path` calibrates within the demo's bound of `sim`'s truth.
fn calibrates_within_u(path: &std::path::Path, sim: &Simulation) {
    use rotacal::calibrate::json::PROPERTY_NAMES;
    use rotacal::demo::TRUTH_LIMIT_U;
    let cal = rotacal::calibrate::stream::calibrate_file(path, &Default::default()).unwrap();
    let ours = cal.by_rate[0].intrinsic.quantities();
    for ((name, q), t) in PROPERTY_NAMES
        .iter()
        .zip(ours)
        .zip(sim.truth().properties())
    {
        let r = (q.value - t).abs() / q.expanded_unc;
        println!("{name}: |Δ| = {r:.2} U");
        assert!(r <= TRUTH_LIMIT_U, "{name}: {r:.2} U from the truth");
    }
}

#[test]
fn a_lost_status_reply_is_asked_for_again_and_nothing_is_lost() {
    // After a 10 s outage the recorder asks for the device's status, then for the gap: the
    // first two status notifications from 110 s are lost on the air (issue 33: a Backfill
    // whose reply is lost ended the session with exit 1). And one lost in a live stream
    // with dropped notifications.
    for faults in [
        "outage=100:10,lost_status=110,lost_status=110",
        "drop=0.02,lost_status=50,lost_status=50,lost_status=150",
    ] {
        let r = run("lost-status", faults);
        let o = r.result.as_ref().unwrap();
        println!("{faults}: {:?}", r.messages);
        assert!(o.summary.lost.is_empty(), "{faults}: {:?}", o.summary.lost);
        assert_eq!(o.summary.rows, N, "{faults}");
        assert!(
            r.messages
                .iter()
                .any(|m| m.contains("no status reply") && m.contains("again")),
            "{faults}: {:?}",
            r.messages
        );
        assert_eq!(seqs(&r.paths.recording), (0..N).collect::<Vec<_>>());
        rebuild_matches(&r);
    }
}

#[test]
fn a_finished_recording_is_read_back_before_it_is_called_done() {
    let r = run("reads-back", "drop=0.01");
    let o = r.result.as_ref().unwrap();
    record::check_reads_back(&r.paths, Condition::X, o.summary.rows).unwrap();
    // A count that is not the file's is named.
    let e = record::check_reads_back(&r.paths, Condition::X, o.summary.rows + 1).unwrap_err();
    assert!(
        e.contains(&format!("{} rows of condition x read back", o.summary.rows)),
        "{e}"
    );
    // A line that does not read is named by its number.
    let mut text = std::fs::read_to_string(&r.paths.recording).unwrap();
    let line = text.lines().count() + 1;
    text.push_str("x,99999,1.0,not-a-number,0,0,25.0,,0,0\n");
    std::fs::write(&r.paths.recording, text).unwrap();
    let e = record::check_reads_back(&r.paths, Condition::X, o.summary.rows).unwrap_err();
    assert!(e.contains(&format!("rec.csv:{line}:")), "{e}");
}

#[test]
fn a_conditions_lost_first_batch_is_asked_for_and_recovered() {
    // The Start's status reply says where the condition starts (issue 33: its first batch
    // lost was never asked for, and counting began at the first sample received).
    let r = run("first-batch", "lost_batch=0");
    let o = r.result.as_ref().unwrap();
    assert!(o.summary.lost.is_empty(), "{:?}", o.summary.lost);
    assert_eq!(o.summary.rows, N);
    assert!(o.summary.recovered >= 7, "{}", o.summary.recovered);
    assert_eq!(seqs(&r.paths.recording), (0..N).collect::<Vec<_>>());
    crosscheck_passes(&r);
    rebuild_matches(&r);
}

#[test]
fn the_first_batches_of_appended_conditions_are_recovered_and_calibrate() {
    use rotacal::demo::{record_session, session_config};
    // Each condition's first batch lost (x at the session's start, y and z after the
    // ring already holds the conditions before them).
    let sim = Simulation::new(session_config(2022).unwrap()).unwrap();
    let faults = "lost_batch=0,lost_batch=263,lost_batch=526";
    let mut dev = SimulatedDevice::new(&sim, faults.parse::<Faults>().unwrap()).unwrap();
    let d = dir("first-batches");
    let paths = Paths::beside(&d.join("rec.csv"));
    let outcomes = record_session(
        &mut dev,
        &paths,
        &crate::mtu::meta(&sim),
        Duration::from_secs_f64(262.5),
    )
    .unwrap();
    for (c, o) in &outcomes {
        assert!(o.summary.lost.is_empty(), "{c:?}: {:?}", o.summary.lost);
        assert_eq!(o.summary.rows, N, "{c:?}");
        assert!(o.summary.recovered >= 7, "{c:?}: {}", o.summary.recovered);
    }
    calibrates_within_u(&paths.recording, &sim);
}

/// The rows of a recording by seq: its time, and its other fields but the temperature (a
/// corrupted temperature packet leaves its rows the one before).
fn rows_by_seq(p: &std::path::Path) -> std::collections::BTreeMap<u64, (f64, String)> {
    std::fs::read_to_string(p)
        .unwrap()
        .lines()
        .filter(|l| l.starts_with("x,"))
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            let seq = f[1].parse().unwrap();
            let rest: Vec<&str> = f
                .iter()
                .enumerate()
                .filter(|(i, _)| *i != 2 && *i != 6)
                .map(|(_, x)| *x)
                .collect();
            (seq, (f[2].parse().unwrap(), rest.join(",")))
        })
        .collect()
}

#[test]
fn bits_flipped_past_the_links_crc_invent_nothing() {
    // Half of the sample batches (live and replayed) with one random bit flipped, four
    // sessions: every flipped batch is refused by its CRC and asked for again; nothing is
    // recorded that the device did not send, and whatever is not recovered is counted lost
    // (issue 33, proof point 3). Statuses lost or corrupted: `a_lost_status_reply_...`.
    let clean = rows_by_seq(&run("flip-clean", "").paths.recording);
    assert_eq!(clean.len() as u64, N);
    let mut flipped = 0;
    for seed in 1..=4 {
        let faults = format!("flip=0.5,seed={seed}");
        let r = run(&format!("flip-{seed}"), &faults);
        flipped += r.flipped;
        let summary = match &r.result {
            Ok(o) => o.summary.clone(),
            Err((e, s)) => {
                println!("{faults}: {e}");
                s.clone().unwrap()
            }
        };
        // The file reads back, and holds only what the device sent, where it sent it.
        recording::read_in_progress(&r.paths.recording).unwrap();
        // (Its clock may start later than the clean run's: a Start whose reply was
        // corrupted is written again. Every row keeps the same offset.)
        let rows = rows_by_seq(&r.paths.recording);
        let offset = rows.iter().next().map(|(seq, (t, _))| t - clean[seq].0);
        for (seq, (t, row)) in &rows {
            let (t_clean, row_clean) = &clean[seq];
            assert_eq!(row, row_clean, "{faults}: seq {seq}");
            let off = t - t_clean;
            assert!(
                (off - offset.unwrap()).abs() < 1e-6,
                "{faults}: seq {seq} moved {off} s"
            );
        }
        assert_eq!(
            rows.len() as u64 + summary.lost_samples(),
            N,
            "{faults}: {} rows, lost {:?}",
            rows.len(),
            summary.lost
        );
        println!(
            "{faults}: {} flipped, {} rows, {} lost, {} recovered",
            r.flipped,
            rows.len(),
            summary.lost_samples(),
            summary.recovered
        );
    }
    assert!(flipped >= 1000, "{flipped} batches flipped");
}

#[test]
fn a_duplicated_or_late_first_batch_is_kept_once_and_in_order() {
    // Issue 33: a late first batch was dropped and counted "received twice". Each of the
    // conditions' first batches delivered twice, or after the batch that follows it.
    for faults in [
        "twice_batch=0",
        "late_batch=0",
        "twice_batch=0,late_batch=100",
    ] {
        let r = run(
            &format!("first-{}", faults.replace([',', '='], "-")),
            faults,
        );
        let o = r.result.as_ref().unwrap();
        println!("{faults}: {:?}", o.summary);
        assert!(o.summary.lost.is_empty(), "{faults}: {:?}", o.summary.lost);
        assert_eq!(o.summary.rows, N, "{faults}");
        assert_eq!(
            seqs(&r.paths.recording),
            (0..N).collect::<Vec<_>>(),
            "{faults}"
        );
        crosscheck_passes(&r);
        rebuild_matches(&r);
    }
    // Delivered twice: the second copy is counted, not written.
    let r = run("first-twice-count", "twice_batch=0");
    assert!(r.result.as_ref().unwrap().summary.duplicates >= 7);
}
