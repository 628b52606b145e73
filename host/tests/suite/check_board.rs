//! `rotacal check-board` (issue 32, proof point 6) against the firmware's logic on the host,
//! on a paused clock: a good board passes every check; a board that reads conversions late
//! fails that check alone and says how many; one whose central keeps BLE's default MTU is
//! refused at the start, naming it. docs/first-board.md.
use rotacal::check_board::{self, DATASHEET_DENSITY_UG};
use rotacal::demo::Check;
use rotacal::link::simulated::{Faults, SimulatedDevice};
use rotacal::record::{Options, Quiet};
use rotacal::simulate::Simulation;
use std::path::PathBuf;
use std::time::Duration;

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("rotacal-check-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The checks, and the folder with the still recording.
fn check(name: &str, faults: &str) -> (anyhow::Result<Vec<Check>>, PathBuf) {
    let sim = Simulation::new(rotacal::demo::session_config(5).unwrap()).unwrap();
    let mut dev = SimulatedDevice::new(&sim, faults.parse::<Faults>().unwrap()).unwrap();
    let rt = crate::common::paused_runtime();
    let opts = Options {
        sync: false,
        ..Options::default()
    };
    let d = dir(name);
    let r = rt.block_on(check_board::check(
        &mut dev,
        &d,
        Duration::from_secs(60),
        opts,
        &mut Quiet::default(),
    ));
    (r, d)
}

fn show(checks: &[Check]) -> String {
    checks
        .iter()
        .map(|c| format!("{} {}: {}\n", c.passed, c.claim, c.measured))
        .collect()
}

#[test]
fn a_good_board_passes_every_check() {
    let (c, d) = check("good", "");
    let c = c.unwrap();
    println!("{}", show(&c));
    assert_eq!(c.len(), 8, "{}", show(&c));
    assert!(c.iter().all(|c| c.passed), "{}", show(&c));
    // The simulator's sensor noise is white at the datasheet's density: 90 µg/√Hz over
    // the 52 Hz Nyquist band at 0.061 mg a count, 10.64 counts a conversion. The estimate
    // from second differences of n rows has a relative standard deviation of about
    // ½·√(2·1.944/n) (1.944: the second differences' correlation at lags 1 and 2); it must
    // find the truth within four of them.
    let truth = DATASHEET_DENSITY_UG * 1e-6 * 52f64.sqrt() / 0.061e-3;
    let rec = rotacal::recording::read_in_progress(&d.join("check.csv")).unwrap();
    let n = rec.groups[0].len() as f64;
    let sd = 0.5 * (2.0 * 1.944 / n).sqrt();
    for (ch, sigma) in ["u", "v", "w"]
        .iter()
        .zip(check_board::conversion_noise(&rec).unwrap())
    {
        let z = (sigma / truth - 1.0) / sd;
        println!("{ch}: {sigma:.3} counts against {truth:.3}, {z:+.1} sd");
        assert!(
            z.abs() < 4.0,
            "{ch}: {sigma} counts, {z:+.1} sd from {truth}"
        );
    }
}

#[test]
fn late_reads_fail_the_conversion_check_alone() {
    let c = check("late", "late=0.005,seed=4").0.unwrap();
    println!("{}", show(&c));
    let failed: Vec<&str> = c
        .iter()
        .filter(|c| !c.passed)
        .map(|c| c.claim.as_str())
        .collect();
    assert_eq!(failed, ["every conversion read"], "{}", show(&c));
}

#[test]
fn the_default_mtu_is_refused_by_name() {
    let e = check("mtu23", "mtu=23").0.unwrap_err();
    let e = format!("{e:#}");
    assert!(e.contains("ATT MTU is 23 bytes"), "{e}");
}
