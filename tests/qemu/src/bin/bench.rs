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
use rotacal_shared::device::simulated::SessionSpec;
use rotacal_shared::device::{Config, Device, RING};
use rotacal_shared::packet::Command;
use rotacal_shared::synth::{crosscheck, Synth};
use rotacal_shared::{Condition, FitConfig, Model, SineFit, Ticks};

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
    ok &= device_costs(&mut counter);
    hprintln!("bench state_bytes_3ch {}", size_of::<SineFit<f32, 3>>());
    hprintln!(
        "bench result_bytes_3ch {}",
        size_of::<rotacal_shared::FitResult<f32, 3>>()
    );
    exit(ok)
}

/// The device logic at 104 Hz into 16 Hz (issue 15): instructions per conversion over a
/// whole condition of the paper session (every conversion through `Device::on_sample` and
/// `poll`, the averaging, the f32 fit of each averaged sample, batches, ring, reports), and
/// the same split into the conversions that only join a slot and those that close one
/// (and so carry the fit's update of an average of 6 or 7 conversions).
fn device_costs(counter: &mut Counter) -> bool {
    let spec = SessionSpec::PAPER;
    let Some(sensor) = spec.sensor(Condition::X) else {
        return false;
    };
    let mut dev = Device::<RING>::new(Config::FEATHER);
    let mut packets = 0u32;
    dev.on_command(
        Command::Start {
            condition: Condition::X,
            rate_uhz: spec.rate_uhz,
        },
        &mut |_| packets += 1,
    );
    let (mut join, mut close, mut n_join, mut n_close) = (0u64, 0u64, 0u64, 0u64);
    for s in sensor {
        let before = dev.streamed();
        let t0 = counter.now();
        dev.on_sample(s.t.0, s.counts, false, &mut |_| packets += 1);
        dev.poll(s.t.0, &mut |_| packets += 1);
        let cost = counter.instructions(counter.now() - t0);
        if dev.streamed() != before {
            close += cost;
            n_close += 1;
        } else {
            join += cost;
            n_join += 1;
        }
    }
    let n = n_join + n_close;
    hprintln!(
        "bench device_instructions_per_conversion {}",
        (join + close) / n.max(1)
    );
    hprintln!(
        "bench device_instructions_per_joining_conversion {}",
        join / n_join.max(1)
    );
    hprintln!(
        "bench device_instructions_per_closing_conversion {}",
        close / n_close.max(1)
    );
    hprintln!("bench device_conversions {}", n);
    hprintln!("bench device_samples {}", n_close);
    packets > 0
}
