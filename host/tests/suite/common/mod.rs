//! Helpers shared by the tests.
use rotacal::simulate::Noise;
use std::ffi::OsStr;
use std::process::Command;

/// Run the `rotacal` binary: (success, stdout, stderr).
pub fn run<S: AsRef<OsStr>>(args: &[S]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_rotacal"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A noise table that keeps the simulated file silent about its level (the preset's level,
/// or none, with optional AR coefficients and low-pass): the code under test must estimate
/// it, as on a real recording.
pub fn unstated(ar: Option<Vec<f64>>, lowpass_hz: Option<f64>) -> Option<Noise> {
    Some(Noise {
        sd: None,
        ar,
        lowpass_hz,
        state: false,
        flicker_floor_ug: None,
        random_walk_ug_per_sqrt_s: None,
    })
}

/// The nine properties of a static result as (group, key) in the calibration JSON's
/// `intrinsic`, in `PROPERTY_NAMES_WITH_OFFSETS` order.
pub const PROPERTY_KEYS: [(&str, &str); 9] = [
    ("sensitivity", "u"),
    ("sensitivity", "v"),
    ("sensitivity", "w"),
    ("angle_deg", "uv"),
    ("angle_deg", "vw"),
    ("angle_deg", "wu"),
    ("offset", "u"),
    ("offset", "v"),
    ("offset", "w"),
];

/// A single-threaded tokio runtime on a paused clock: the emulated device's minutes of
/// recording take a fraction of a second.
pub fn paused_runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .start_paused(true)
        .build()
        .unwrap()
}
