//! Generates the f32 sine/cosine table of `real.rs`: sin and cos at 257 points of the
//! first octant, each as an f32 pair (hi, lo) whose sum is within ~1e-16 of the value.
//! Computed with libm (pure Rust), so every build host writes the same bits.
use std::fmt::Write as _;
use std::{env, fs, path::PathBuf};

const STEPS: u32 = 256;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut src = String::from(
        "/// sin, cos at i·(π/4)/256, i = 0..=256, as (sin.hi, sin.lo, cos.hi, cos.lo) bits.\n\
         pub(crate) const OCTANT_TABLE_F32: [[u32; 4]; 257] = [\n",
    );
    for i in 0..=STEPS {
        let a = f64::from(i) * (std::f64::consts::FRAC_PI_4 / f64::from(STEPS));
        let pair = |v: f64| {
            let hi = v as f32;
            let lo = (v - f64::from(hi)) as f32;
            (hi.to_bits(), lo.to_bits())
        };
        let (sh, sl) = pair(libm::sin(a));
        let (ch, cl) = pair(libm::cos(a));
        let _ = writeln!(src, "    [{sh:#010x}, {sl:#010x}, {ch:#010x}, {cl:#010x}],");
    }
    src.push_str("];\n");
    let out = PathBuf::from(env::var_os("OUT_DIR").ok_or("cargo did not set OUT_DIR")?);
    fs::write(out.join("octant_table.rs"), src)?;
    println!("cargo:rerun-if-changed=build.rs");
    Ok(())
}
