//! The device logic (`rotacal_shared::device`) on the emulated Cortex-M4F, driven by the
//! simulated three-condition session (`SessionSpec::PAPER`). Prints every packet the
//! device sends as one line `P <hex>`; the host (`rotacal-fitcheck --session`) runs the
//! same session through the same code, requires the same bytes, decodes them and re-fits
//! every reported window in f64.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use cortex_m_semihosting::hio;
use panic_semihosting as _;
use rotacal_qemu_tests::{exit, hprintln};
use rotacal_shared::device::simulated::SessionSpec;
use rotacal_shared::device::{Config, Device, RING};
use rotacal_shared::packet::{Packet, MAX_PACKET};

#[entry]
fn main() -> ! {
    let Ok(mut stdout) = hio::hstdout() else {
        exit(false)
    };
    let mut dev = Device::<RING>::new(Config::FEATHER);
    let mut count = 0u32;
    let mut ok = true;
    // How deep the device logic takes the stack below this frame (the firmware's budget
    // for it: scripts/fw-size). The printing closure's buffers are counted too.
    let painted = rotacal_qemu_tests::stack::paint();
    SessionSpec::PAPER.run(&mut dev, &mut |p: Packet| {
        let mut bytes = [0u8; MAX_PACKET];
        let Ok(n) = p.encode(&mut bytes) else {
            ok = false;
            return;
        };
        // "P " + 2 hex digits per byte + newline, written in one semihosting call.
        let mut line = [0u8; 3 + 2 * MAX_PACKET];
        line[0] = b'P';
        line[1] = b' ';
        const HEX: &[u8; 16] = b"0123456789abcdef";
        for (i, b) in bytes[..n].iter().enumerate() {
            line[2 + 2 * i] = HEX[usize::from(b >> 4)];
            line[3 + 2 * i] = HEX[usize::from(b & 15)];
        }
        line[2 + 2 * n] = b'\n';
        if stdout.write_all(&line[..3 + 2 * n]).is_err() {
            ok = false;
        }
        count += 1;
    });
    hprintln!("session stack={} bytes", painted.used());
    hprintln!("session done packets={}", count);
    exit(ok)
}
