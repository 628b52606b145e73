//! Puts the workspace's memory.x (S140 7.3.0 layout) on the linker search path and adds the
//! linker scripts: .cargo/config.toml only sets target-cpu, so the link args come from here.

use std::env;
use std::error::Error;
use std::fs;
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn Error>> {
    let manifest_dir =
        PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").ok_or("no CARGO_MANIFEST_DIR")?);
    let out = PathBuf::from(env::var_os("OUT_DIR").ok_or("no OUT_DIR")?);
    let memory_x = manifest_dir.join("..").join("memory.x");
    fs::copy(&memory_x, out.join("memory.x"))
        .map_err(|e| format!("copy {}: {e}", memory_x.display()))?;
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", memory_x.display());
    println!("cargo:rerun-if-changed=build.rs");

    // --nmagic: sections need not be page-aligned in the file (flash starts at 0x27000).
    println!("cargo:rustc-link-arg-bins=--nmagic");
    // cortex-m-rt's script; it INCLUDEs memory.x from the search path above.
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    // defmt's sections for interned log strings.
    println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    Ok(())
}
