//! Instruction counts of the f32 streaming fit on the emulated Cortex-M4F. Run under
//! `-icount shift=0` (scripts/bench-fit) for counts that repeat exactly.
//!
//! Prints `bench KEY VALUE` lines.
#![no_std]
#![no_main]

use core::mem::size_of;
use cortex_m_rt::entry;
use panic_semihosting as _;
use rotacal_qemu_tests::{exit, hprintln, Counter};
use rotacal_shared::synth::{crosscheck, Synth};
use rotacal_shared::{FitConfig, Model, SineFit, Ticks};

const N: usize = 4200;

#[entry]
fn main() -> ! {
    let Some(cp) = cortex_m::Peripherals::take() else {
        hprintln!("error: peripherals taken");
        exit(false)
    };
    let mut counter = Counter::start(cp.SYST);
    let q10 = counter.calibrate();
    hprintln!("bench instructions_per_tick_q10 {}", q10);

    let Some(spec) = crosscheck::spec(&crosscheck::RECORDS[0], 0) else {
        exit(false)
    };
    // Samples prepared first so that only the update is measured.
    let mut samples = [(Ticks(0), [0f32; 3]); N];
    for (slot, s) in samples.iter_mut().zip(Synth::new(spec)) {
        *slot = (s.t, s.counts.map(f32::from));
    }

    let mut ok = true;
    for (name, model) in [
        ("sine", Model::SINE),
        (
            "drift",
            Model {
                offset_drift: true,
                rate_error: false,
            },
        ),
        (
            "rate",
            Model {
                offset_drift: false,
                rate_error: true,
            },
        ),
        (
            "drift+rate",
            Model {
                offset_drift: true,
                rate_error: true,
            },
        ),
    ] {
        let mut fit = SineFit::<f32>::new(FitConfig {
            model,
            ..FitConfig::sine(spec.step, spec.clock)
        });
        let t0 = counter.now();
        for (t, y) in samples.iter() {
            ok &= core::hint::black_box(fit.update(*t, *y)).is_ok();
        }
        let total = counter.instructions(counter.now() - t0);
        let t1 = counter.now();
        let r = core::hint::black_box(fit.solve());
        let solve = counter.instructions(counter.now() - t1);
        ok &= r.is_ok();
        hprintln!(
            "bench update_instructions_per_sample[{}] {}",
            name,
            total / N as u64
        );
        hprintln!("bench solve_instructions[{}] {}", name, solve);
    }
    hprintln!("bench state_bytes_3ch {}", size_of::<SineFit<f32, 3>>());
    hprintln!(
        "bench result_bytes_3ch {}",
        size_of::<rotacal_shared::FitResult<f32, 3>>()
    );
    exit(ok)
}
