//! The f32 streaming fit on the emulated Cortex-M4F, over the cross-check records of
//! `rotacal_shared::synth::crosscheck`. Prints every result as exact f32 bit patterns;
//! the host (`qemu-check`) regenerates the same samples, checks the checksum, fits them
//! in f64 and compares.
//!
//! Line format (hex = f32 bits):
//! `record NAME AXIS MODEL n=N sum=HEX`
//! `fit NAME AXIS MODEL CH A.hi A.lo B.hi B.lo C.hi C.lo seA seB seC sigma`
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use panic_semihosting as _;
use rotacal_qemu_tests::{exit, hprintln};
use rotacal_shared::synth::{crosscheck, Checksum, Synth};
use rotacal_shared::{FitConfig, Model, SineFit};

const MODELS: [(&str, Model); 2] = [
    ("sine", Model::SINE),
    (
        "drift+rate",
        Model {
            offset_drift: true,
            rate_error: true,
        },
    ),
];

#[entry]
fn main() -> ! {
    let mut ok = true;
    for rec in crosscheck::RECORDS.iter() {
        for axis in 0..3usize {
            let Some(spec) = crosscheck::spec(rec, axis) else {
                hprintln!("error: no spec for {}", rec.name);
                exit(false)
            };
            let mut fits = MODELS.map(|(_, model)| {
                SineFit::<f32>::new(FitConfig {
                    model,
                    ..FitConfig::sine(spec.step, spec.clock)
                })
            });
            let mut sum = Checksum::default();
            for s in Synth::new(spec) {
                sum.add(&s);
                let y = s.counts.map(f32::from);
                for fit in fits.iter_mut() {
                    if let Err(e) = fit.update(s.t, y) {
                        hprintln!("error: update: {:?}", e);
                        ok = false;
                    }
                }
            }
            for ((name, _), fit) in MODELS.iter().zip(fits.iter()) {
                hprintln!(
                    "record {} {} {} n={} sum={:016x}",
                    rec.name,
                    axis,
                    name,
                    fit.len(),
                    sum.0
                );
                match fit.solve() {
                    Ok(r) => {
                        for (ch, c) in r.channels.iter().enumerate() {
                            let [a, b, k, ..] = c.coef;
                            let [sa, sb, sc, ..] = c.se;
                            hprintln!(
                                "fit {} {} {} {} {:08x} {:08x} {:08x} {:08x} {:08x} {:08x} {:08x} {:08x} {:08x} {:08x}",
                                rec.name, axis, name, ch,
                                a.hi.to_bits(), a.lo.to_bits(), b.hi.to_bits(), b.lo.to_bits(),
                                k.hi.to_bits(), k.lo.to_bits(),
                                sa.to_bits(), sb.to_bits(), sc.to_bits(), c.sigma.to_bits()
                            );
                        }
                    }
                    Err(e) => {
                        hprintln!("error: solve {}: {:?}", rec.name, e);
                        ok = false;
                    }
                }
            }
        }
    }
    hprintln!("crosscheck done");
    exit(ok)
}
