//! Helpers shared by the command-line tests.
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
