// The build scripts' shared body (host/build.rs, python/build.rs): sets ROTACAL_COMMIT
// to `git describe --always --dirty`, or "unknown" outside a git checkout. Both crates sit
// one folder below the checkout, so the paths below serve both.
use std::process::Command;

fn main() {
    let commit = Command::new("git")
        .args(["describe", "--always", "--dirty", "--abbrev=12"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "unknown".into());
    println!("cargo:rustc-env=ROTACAL_COMMIT={commit}");
    // Again when the checkout moves or its index changes, and when the crate does.
    for p in ["../.git/HEAD", "../.git/index", "src", "Cargo.toml"] {
        println!("cargo:rerun-if-changed={p}");
    }
}
