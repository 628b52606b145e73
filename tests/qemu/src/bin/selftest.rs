//! The shared self-test cases on the emulated Cortex-M4F. Ends with `N passed, M failed`
//! and exits nonzero if any failed.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use panic_semihosting as _;
use rotacal_qemu_tests::{exit, hprintln};
use rotacal_shared::selftest::CASES;

#[entry]
fn main() -> ! {
    let (mut passed, mut failed) = (0u32, 0u32);
    for case in CASES {
        match (case.run)() {
            Ok(()) => {
                passed += 1;
                hprintln!("ok   {}", case.name);
            }
            Err(what) => {
                failed += 1;
                hprintln!("FAIL {}: {}", case.name, what);
            }
        }
    }
    hprintln!("{} passed, {} failed", passed, failed);
    exit(failed == 0)
}
