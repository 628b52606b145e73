//! The link's ATT MTU: the device sizes its batches to it and refuses below the smallest
//! that carries a fit report, and the recorder names it. The demo's session (x, y, z at
//! 0.01 Hz, 262.5 s each) on the simulated link, at the MTUs centrals grant: 247 (BlueZ,
//! Android on request), 185 (CoreBluetooth), 153 (the least the device works over) and 23
//! (BLE's default, a central that never asks). docs/protocol.md, "The MTU".
use rotacal::calibrate::json::PROPERTY_NAMES;
use rotacal::demo::{record_session, session_config, TRUTH_LIMIT_U};
use rotacal::link::simulated::{Faults, SimulatedDevice};
use rotacal::record::Paths;
use rotacal::recording::{Metadata, Method};
use rotacal::simulate::Simulation;
use rotacal_shared::device::route::{batch_len, MIN_MTU};
use std::path::PathBuf;
use std::time::Duration;

const SEED: u64 = 2022;

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("rotacal-mtu-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The demo's recording metadata for `sim`.
pub(crate) fn meta(sim: &Simulation) -> Metadata {
    Metadata {
        method: Some(Method::Rotation),
        g_loc: Some(sim.config().g_loc),
        rate_hz: Some(0.01),
        units: Some("counts".into()),
        sample_rate_hz: Some(16.0),
        ..Metadata::default()
    }
}

/// Record the session at `mtu`: the recording's text, or the error.
fn session(mtu: u16) -> (Result<String, String>, Simulation) {
    let sim = Simulation::new(session_config(SEED).unwrap()).unwrap();
    let faults: Faults = format!("mtu={mtu}").parse().unwrap();
    let mut dev = SimulatedDevice::new(&sim, faults).unwrap();
    let d = dir(&mtu.to_string());
    let paths = Paths::beside(&d.join("rec.csv"));
    let duration = Duration::from_secs_f64(262.5);
    let r = record_session(&mut dev, &paths, &meta(&sim), duration)
        .map(|outcomes| {
            for (c, o) in &outcomes {
                assert!(
                    o.summary.lost.is_empty(),
                    "MTU {mtu}, {c:?}: {:?}",
                    o.summary
                );
                // Nothing had to be asked for again: no batch was too long for the link.
                assert_eq!(o.summary.recovered, 0, "MTU {mtu}, {c:?}");
                assert!(o.final_fit && o.undecodable == 0, "MTU {mtu}, {c:?}");
            }
            std::fs::read_to_string(&paths.recording).unwrap()
        })
        .map_err(|e| format!("{e:#}"));
    (r, sim)
}

#[test]
fn batches_follow_the_mtu_and_the_data_do_not() {
    assert_eq!(MIN_MTU, 153);
    assert_eq!(
        [247, 185, 158, 153, 152, 23].map(batch_len),
        [Some(7), Some(5), Some(4), Some(4), None, None]
    );
    let (full, sim) = session(247);
    let full = full.unwrap();
    // 262.5 s at 16 Hz per condition, less the slot open at Stop.
    let rows = |c: &str| full.lines().filter(|l| l.starts_with(c)).count();
    assert_eq!(["x,", "y,", "z,"].map(rows), [4199; 3]);
    for mtu in [185, 153] {
        let (text, _) = session(mtu);
        // The same samples, conversions and instants, row for row: only the packets
        // that carried them differ.
        assert!(
            text.unwrap() == full,
            "MTU {mtu}: the recording differs from MTU 247's"
        );
    }
    // And that recording calibrates within the demo's bound of the truth.
    let dir = dir("calibrate");
    let path = dir.join("rec.csv");
    std::fs::write(&path, &full).unwrap();
    let rec = rotacal::recording::read(&path).unwrap();
    let cal = rotacal::calibrate::calibrate(&rec, &Default::default()).unwrap();
    let ours = cal.by_rate[0].intrinsic.quantities();
    let truth = sim.truth().properties();
    for ((name, q), t) in PROPERTY_NAMES.iter().zip(ours).zip(truth) {
        let r = (q.value - t).abs() / q.expanded_unc;
        println!("{name}: |Δ| = {r:.2} U");
        assert!(r <= TRUTH_LIMIT_U, "{name}: {r:.2} U from the truth");
    }
}

#[test]
fn below_the_smallest_mtu_the_device_refuses_and_the_recorder_names_it() {
    for mtu in [23, 152] {
        let (r, _) = session(mtu);
        let e = r.unwrap_err();
        println!("MTU {mtu}: {e}");
        assert!(e.contains("start"), "{e}");
        assert!(e.contains(&format!("ATT MTU is {mtu} bytes")), "{e}");
        assert!(e.contains(&format!("at least {MIN_MTU}")), "{e}");
    }
}
