//! Test cases that run both as host unit tests and on the emulated Cortex-M4F
//! (tests/qemu), so that the device's own f32 arithmetic is what gets tested.
//!
//! Each case returns `Err(what failed)`. Runners: `shared/tests/selftest.rs` on the host,
//! `tests/qemu/src/bin/selftest.rs` under QEMU; both print one line per case.

use crate::dword::{two_prod, two_sum, DoubleWord};
use crate::fit::{FitConfig, FitError, Model, Param, SineFit};
use crate::phase::{Phase, PhaseStep};
use crate::real::Real;
use crate::synth::{Checksum, Synth, SynthSpec};
use crate::time::{TickExtender, TickRate, Ticks};

/// One named test case.
pub struct Case {
    /// Name printed by the runners.
    pub name: &'static str,
    /// The test; `Err` says which check failed.
    pub run: fn() -> Result<(), &'static str>,
}

/// Every case, in a fixed order.
pub const CASES: &[Case] = &[
    Case {
        name: "dword_error_free_transforms",
        run: dword_error_free_transforms,
    },
    Case {
        name: "tick_extender_wraps",
        run: tick_extender_wraps,
    },
    Case {
        name: "phase_step_is_exact",
        run: phase_step_is_exact,
    },
    Case {
        name: "phase_quadrants_f32",
        run: phase_quadrants::<f32>,
    },
    Case {
        name: "phase_quadrants_f64",
        run: phase_quadrants::<f64>,
    },
    Case {
        name: "phase_kernel_accuracy_f32",
        run: phase_kernel_accuracy::<f32>,
    },
    Case {
        name: "phase_kernel_accuracy_f64",
        run: phase_kernel_accuracy::<f64>,
    },
    Case {
        name: "fit_noise_free_f32",
        run: fit_noise_free::<f32>,
    },
    Case {
        name: "fit_noise_free_f64",
        run: fit_noise_free::<f64>,
    },
    Case {
        name: "fit_drift_and_rate_terms_f32",
        run: fit_drift_and_rate_terms::<f32>,
    },
    Case {
        name: "fit_drift_and_rate_terms_f64",
        run: fit_drift_and_rate_terms::<f64>,
    },
    Case {
        name: "fit_refuses_bad_input_f32",
        run: fit_refuses_bad_input::<f32>,
    },
    Case {
        name: "fit_refuses_bad_input_f64",
        run: fit_refuses_bad_input::<f64>,
    },
    Case {
        name: "fit_noisy_record_f32",
        run: fit_noisy_record::<f32>,
    },
    Case {
        name: "fit_noisy_record_f64",
        run: fit_noisy_record::<f64>,
    },
    Case {
        name: "fit_estimates_rate_error_f32",
        run: fit_estimates_rate_error::<f32>,
    },
    Case {
        name: "synth_is_reproducible",
        run: synth_is_reproducible,
    },
    Case {
        name: "intrinsic_gram_exact_when_tilted",
        run: intrinsic_gram_exact_when_tilted,
    },
    Case {
        name: "device_counts_missed_conversions",
        run: device_counts_missed_conversions,
    },
    Case {
        name: "reads_are_paired_with_their_instants",
        run: reads_are_paired_with_their_instants,
    },
];

fn check(ok: bool, what: &'static str) -> Result<(), &'static str> {
    if ok {
        Ok(())
    } else {
        Err(what)
    }
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    libm::fabs(a - b) <= tol
}

fn dword_error_free_transforms() -> Result<(), &'static str> {
    // 4097² = 2²⁴ + 8193: f32 rounds it to 2²⁴ + 8192, TwoProd recovers the 1.
    let (p, e) = two_prod(4097.0f32, 4097.0);
    check(p == 16_785_408.0 && e == 1.0, "two_prod f32 not exact")?;
    let (s, e) = two_sum(1.0f32, 1e-10);
    check(s == 1.0 && e == 1e-10, "two_sum f32 not exact")?;
    let (s, e) = two_sum(1e16f64, 1.0);
    check(s == 1e16 && e == 1.0, "two_sum f64 not exact")?;
    // (1 + 2⁻³⁰)² in double-word f32 keeps the 2⁻³⁰ term that plain f32 loses.
    let x = DoubleWord::normalised(1.0f32, 9.313_226e-10);
    let sq = (x * x).to_f64();
    check(
        close(sq, 1.0 + 2.0 * 9.313_226e-10, 1e-15),
        "double-word product",
    )
}

fn tick_extender_wraps() -> Result<(), &'static str> {
    let mut ext = TickExtender::new(24);
    check(ext.extend(0xFF_FFF0) == Ticks(0xFF_FFF0), "before wrap")?;
    check(ext.extend(0x00_0010) == Ticks(0x100_0010), "first wrap")?;
    check(ext.extend(0x00_0010) == Ticks(0x100_0010), "same reading")?;
    check(
        ext.extend(0xFF_FFFF) == Ticks(0x1FF_FFFF),
        "within second lap",
    )?;
    check(ext.extend(0x00_0000) == Ticks(0x200_0000), "second wrap")?;
    let mut ext = TickExtender::new(32);
    ext.extend(0xFFFF_FFFF);
    check(ext.extend(5) == Ticks(0x1_0000_0005), "32-bit wrap")
}

fn phase_step_is_exact() -> Result<(), &'static str> {
    // 10 mHz at 1 MHz: 2⁶⁴·10⁻⁸ = 184 467 440 737.095… → 184 467 440 737.
    let step = PhaseStep::from_micro_hz(10_000, TickRate::MHZ_1);
    check(step == Some(PhaseStep(184_467_440_737)), "10 mHz step")?;
    // A quarter-turn-per-tick step at 4 Hz on a 16 Hz clock is exactly 2⁶².
    let clock = TickRate::new(16).ok_or("tick rate")?;
    check(
        PhaseStep::from_micro_hz(4_000_000, clock) == Some(PhaseStep(1 << 62)),
        "quarter-turn step",
    )?;
    check(
        PhaseStep::from_micro_hz(16_000_000, clock).is_none(),
        "rate at the tick rate must be refused",
    )?;
    let back = PhaseStep(184_467_440_737).to_hz(TickRate::MHZ_1);
    check(close(back, 0.01, 1e-14), "to_hz")
}

fn phase_quadrants<T: Real>() -> Result<(), &'static str> {
    let z = DoubleWord::from_t(T::ZERO);
    let one = DoubleWord::from_t(T::ONE);
    let exact = |ph: u64| {
        let (s, c) = Phase(ph).sin_cos::<T>();
        (
            DoubleWord::normalised(s.hi, s.lo),
            DoubleWord::normalised(c.hi, c.lo),
        )
    };
    check(exact(0) == (z, one), "0 turn")?;
    check(exact(1 << 62) == (one, z), "1/4 turn")?;
    check(exact(2 << 62) == (z, -one), "1/2 turn")?;
    check(exact(3 << 62) == (-one, z), "3/4 turn")?;
    let (s, c) = Phase(1 << 61).sin_cos::<T>();
    let h = core::f64::consts::FRAC_1_SQRT_2;
    let tol = 4.0 * T::EPSILON.to_f64();
    check(
        close(s.to_f64(), h, tol) && close(c.to_f64(), h, tol),
        "1/8 turn",
    )
}

fn phase_kernel_accuracy<T: Real>() -> Result<(), &'static str> {
    // 5e-10 (f32's double-word table) or 4u of f64, plus the f64 reference's own error
    // (2π·2⁻⁵³ from `radians`).
    let tol = if T::EPSILON.to_f64() > 1e-10 {
        5e-10
    } else {
        4.0 * T::EPSILON.to_f64()
    } + 1e-15;
    let mut x = 0x0123_4567_89AB_CDEFu64;
    for _ in 0..4096 {
        x = x
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        let ph = Phase(x);
        let (s, c) = ph.sin_cos::<T>();
        let a = ph.radians();
        check(close(s.to_f64(), libm::sin(a), tol), "sin beyond tolerance")?;
        check(close(c.to_f64(), libm::cos(a), tol), "cos beyond tolerance")?;
    }
    Ok(())
}

fn noise_free_fit<T: Real>(model: Model, d: f64, rate_ppm: f64) -> Result<(), &'static str> {
    // 3 periods of 0.1 Hz at 16 Hz, channel values computed in f64 and rounded to T.
    let clock = TickRate::MHZ_1;
    let step = PhaseStep::from_micro_hz(100_000, clock).ok_or("step")?;
    let truth = [
        [12_000.0, -9_000.0, 250.0],
        [-30.5, 16_390.0, -41.0],
        [700.0, 55.0, 16_000.0],
    ];
    let mut fit = SineFit::<T>::new(FitConfig {
        model,
        ..FitConfig::sine(step, clock)
    });
    let w = core::f64::consts::TAU * 0.1 * (1.0 + rate_ppm * 1e-6);
    for i in 0..480u64 {
        let t = Ticks(1_000_000 + i * 62_500);
        let secs = t.0 as f64 * 1e-6;
        let tau = (t.0 - 1_000_000) as f64 * 1e-6;
        let (s, c) = (libm::sin(w * secs), libm::cos(w * secs));
        let y = truth.map(|[a, b, o]| T::from_f64(a * s + b * c + o + d * tau));
        fit.update(t, y).map_err(|_| "update refused")?;
    }
    let r = fit.solve().map_err(|_| "solve failed")?;
    let rel = if T::EPSILON.to_f64() < 1e-10 {
        1e-11
    } else {
        2e-6
    };
    for (ch, [a, b, o]) in truth.iter().enumerate() {
        let got = |p| r.coef(ch, p).map(|v| v.to_f64()).unwrap_or(f64::NAN);
        let scale = 16_400.0;
        if rate_ppm == 0.0 {
            check(close(got(Param::A), *a, rel * scale), "A")?;
            check(close(got(Param::B), *b, rel * scale), "B")?;
        }
        let centre = r
            .t_ref
            .map(|t| (t.0 - 1_000_000) as f64 * 1e-6)
            .unwrap_or(0.0);
        check(close(got(Param::C), *o + d * centre, rel * scale), "C")?;
        if model.offset_drift {
            check(close(got(Param::D), d, rel * scale / 30.0), "drift D")?;
        }
    }
    Ok(())
}

fn fit_noise_free<T: Real>() -> Result<(), &'static str> {
    noise_free_fit::<T>(Model::SINE, 0.0, 0.0)
}

fn fit_drift_and_rate_terms<T: Real>() -> Result<(), &'static str> {
    let drift = Model {
        offset_drift: true,
        rate_error: false,
    };
    noise_free_fit::<T>(drift, 2.5, 0.0)?;
    let both = Model {
        offset_drift: true,
        rate_error: true,
    };
    noise_free_fit::<T>(both, -1.5, 0.0)
}

fn fit_refuses_bad_input<T: Real>() -> Result<(), &'static str> {
    let clock = TickRate::MHZ_1;
    let step = PhaseStep::from_micro_hz(1_000_000, clock).ok_or("step")?;
    let mut fit = SineFit::<T>::new(FitConfig::sine(step, clock));
    let one = T::ONE;
    fit.update(Ticks(10), [one, one, one])
        .map_err(|_| "first sample")?;
    let nan = T::from_f64(f64::NAN);
    check(
        fit.update(Ticks(20), [one, nan, one]) == Err(FitError::NonFiniteSample { channel: 1 }),
        "NaN accepted",
    )?;
    let inf = T::from_f64(f64::INFINITY);
    check(
        fit.update(Ticks(20), [one, one, inf]) == Err(FitError::NonFiniteSample { channel: 2 }),
        "infinity accepted",
    )?;
    let huge = T::MAX_SAMPLE * T::from_f64(2.0);
    check(
        fit.update(Ticks(20), [huge, one, one]) == Err(FitError::SampleOutOfRange { channel: 0 }),
        "huge sample accepted",
    )?;
    check(
        fit.update(Ticks(5), [one, one, one])
            == Err(FitError::TimeWentBackwards {
                previous: Ticks(10),
                got: Ticks(5),
            }),
        "time going backwards accepted",
    )?;
    check(fit.len() == 1, "a refused sample changed the fit")?;
    check(
        fit.solve().err() == Some(FitError::TooFewSamples { n: 1, needed: 4 }),
        "too few samples",
    )?;
    // Ten samples over a tenth of a period.
    for i in 1..10u64 {
        fit.update(Ticks(10 + i * 10_000), [one, one, one])
            .map_err(|_| "span samples")?;
    }
    check(
        matches!(
            fit.solve(),
            Err(FitError::TooFewPeriods {
                milli_periods: 90,
                needed: 1500
            })
        ),
        "too few periods",
    )?;
    // All samples at one tick: every regressor row equal.
    let mut same = SineFit::<T>::new(FitConfig {
        min_milli_periods: 0,
        ..FitConfig::sine(step, clock)
    });
    for _ in 0..10 {
        same.update(Ticks(123), [one, one, one])
            .map_err(|_| "same-time samples")?;
    }
    check(
        same.solve().err() == Some(FitError::Singular),
        "singular system",
    )
}

/// A paper-like record: 10 mHz, 16 Hz, 4200 samples, σ = 4.2 counts.
fn paper_spec(seed: u64) -> Option<SynthSpec> {
    let clock = TickRate::MHZ_1;
    Some(SynthSpec {
        coef: [
            [16_380.0, 420.0, 35.0],
            [-210.0, 16_395.0, -20.0],
            [60.0, -95.0, 140.0],
        ],
        noise_sigma: 4.2,
        step: PhaseStep::from_micro_hz(10_000, clock)?,
        clock,
        sample_rate_mhz: 16_000,
        n_samples: 4200,
        drop_per_million: 0,
        seed,
    })
}

fn fit_noisy_record<T: Real>() -> Result<(), &'static str> {
    let spec = paper_spec(7).ok_or("spec")?;
    let mut fit = SineFit::<T>::new(FitConfig::sine(spec.step, spec.clock));
    for s in Synth::new(spec) {
        fit.update(s.t, s.counts.map(|c| T::from_f64(f64::from(c))))
            .map_err(|_| "update refused")?;
    }
    let r = fit.solve().map_err(|_| "solve failed")?;
    let n = 4200.0;
    // Quantisation adds 1/12 count² to the noise.
    let sigma = libm::sqrt(4.2 * 4.2 + 1.0 / 12.0);
    let crlb_ab = sigma * libm::sqrt(2.0 / n);
    for (ch, [a, b, c]) in spec.coef.iter().enumerate() {
        let got = |p| r.coef(ch, p).map(|v| v.to_f64()).unwrap_or(f64::NAN);
        let se = |p| r.se(ch, p).map(|v| v.to_f64()).unwrap_or(f64::NAN);
        check(
            close(got(Param::A), *a, 5.0 * se(Param::A)),
            "A beyond 5 se",
        )?;
        check(
            close(got(Param::B), *b, 5.0 * se(Param::B)),
            "B beyond 5 se",
        )?;
        check(
            close(got(Param::C), *c, 5.0 * se(Param::C)),
            "C beyond 5 se",
        )?;
        check(
            close(se(Param::A), crlb_ab, 0.1 * crlb_ab),
            "se(A) not near the CRLB",
        )?;
        let s = r
            .channels
            .get(ch)
            .map(|c| c.sigma.to_f64())
            .unwrap_or(f64::NAN);
        check(
            close(s, sigma, 0.05 * sigma),
            "sigma-hat not near the noise",
        )?;
    }
    Ok(())
}

fn fit_estimates_rate_error<T: Real>() -> Result<(), &'static str> {
    // The table turns 400 ppm fast: over 40 periods the phase ramps by 0.1 rad.
    let clock = TickRate::MHZ_1;
    let nominal = PhaseStep::from_micro_hz(100_000, clock).ok_or("step")?;
    let true_step = PhaseStep::from_micro_hz(100_040, clock).ok_or("step")?;
    let spec = SynthSpec {
        step: true_step,
        n_samples: 6400,
        noise_sigma: 2.0,
        ..paper_spec(3).ok_or("spec")?
    };
    let model = Model {
        offset_drift: false,
        rate_error: true,
    };
    let mut fit = SineFit::<T>::new(FitConfig {
        model,
        ..FitConfig::sine(nominal, clock)
    });
    for s in Synth::new(spec) {
        fit.update(s.t, s.counts.map(|c| T::from_f64(f64::from(c))))
            .map_err(|_| "update refused")?;
    }
    let r = fit.solve().map_err(|_| "solve failed")?;
    let get = |p| r.coef(0, p).map(|v| v.to_f64()).unwrap_or(f64::NAN);
    let (a, b, e, f) = (get(Param::A), get(Param::B), get(Param::E), get(Param::F));
    // y ≈ A sin α + B cos α + τ·δω·(A cos α − B sin α): F = δω·A, E = −δω·B.
    let dw = (f * a - e * b) / (a * a + b * b);
    let truth = core::f64::consts::TAU * 0.1 * 400e-6;
    check(
        close(dw, truth, 0.02 * truth),
        "rate offset not recovered to 2 %",
    )?;
    // The linear terms capture the phase ramp but not its second order: the amplitude
    // keeps the bias −A·(δω·T)²/24 (docs/fit.md), here 4.2e-4 relative.
    let amp = libm::sqrt(a * a + b * b);
    let span = 6399.0 / 16.0;
    let expected = libm::sqrt(16_380.0f64 * 16_380.0 + 420.0 * 420.0)
        * (1.0 - (truth * span) * (truth * span) / 24.0);
    check(
        close(amp, expected, 0.5),
        "amplitude not as the linearised model predicts",
    )
}

/// FNV-1a of the first 2000 samples of `paper_spec(1)` with 1 % drops, as computed on
/// x86-64; the Cortex-M4F must produce the same.
pub const SYNTH_GOLDEN: u64 = 0x7e03_612f_e856_ab5d;

fn synth_is_reproducible() -> Result<(), &'static str> {
    let spec = SynthSpec {
        n_samples: 2000,
        drop_per_million: 10_000,
        ..paper_spec(1).ok_or("spec")?
    };
    let mut sum = Checksum::default();
    let mut kept = 0u32;
    for s in Synth::new(spec) {
        sum.add(&s);
        kept += 1;
    }
    check(kept > 1940 && kept < 2000, "drop rate")?;
    check(
        sum.0 == SYNTH_GOLDEN,
        "synthetic samples differ from the golden checksum",
    )
}

/// Noise-free fits of a device tilted 7° on the platter: the Gram form returns its
/// intrinsic properties exactly (f64, as the device's quick-look computes them).
fn intrinsic_gram_exact_when_tilted() -> Result<(), &'static str> {
    use crate::intrinsic::{from_gram, ConditionFit};
    let s_true = [1669.32, 1669.10, 1676.46];
    let (uv, vw, wu) = (
        90.077f64.to_radians(),
        90.095f64.to_radians(),
        89.910f64.to_radians(),
    );
    let wx = libm::cos(wu);
    let wy = (libm::cos(vw) - libm::cos(uv) * libm::cos(wu)) / libm::sin(uv);
    let w = [wx, wy, libm::sqrt(1.0 - wx * wx - wy * wy)];
    let dev = [
        [s_true[0], 0.0, 0.0],
        [s_true[1] * libm::cos(uv), s_true[1] * libm::sin(uv), 0.0],
        w.map(|c| c * s_true[2]),
    ];
    // Rotation by 7° about z then 7° about x, applied as S' = S·Rᵀ.
    let (s7, c7) = (libm::sin(7f64.to_radians()), libm::cos(7f64.to_radians()));
    let tilt = |v: [f64; 3]| {
        let [x, y, z] = v;
        let (x, y) = (c7 * x - s7 * y, s7 * x + c7 * y);
        [x, c7 * y - s7 * z, s7 * y + c7 * z]
    };
    let s = dev.map(tilt);
    let fits = [0usize, 1, 2].map(|axis| {
        let c = crate::synth::coefficients(&s, &[0.0; 3], 9.80101, axis);
        ConditionFit {
            a: c.map(|r| r[0]),
            b: c.map(|r| r[1]),
            cov: [[[0.01, 0.0], [0.0, 0.01]]; 3],
        }
    });
    let r = from_gram(&fits, 9.80101, 0.0).map_err(|_| "from_gram failed")?;
    for (e, t) in r.sensitivity.iter().zip(s_true) {
        check(close(e.value, t, 1e-9 * t), "sensitivity not exact")?;
    }
    for (e, t) in r.angle_deg.iter().zip([90.077, 90.095, 89.910]) {
        check(close(e.value, t, 1e-9), "angle not exact")?;
    }
    Ok(())
}

/// What a run of [`missed_run`] saw.
struct MissedRun {
    /// Conversions the sensor made that were not read.
    skipped: u32,
    /// The device's status `lost`.
    lost: u32,
    /// Missed conversions the samples' flags count.
    flagged: u32,
    /// Samples whose slot holds other than 6 or 7 conversions, read and missed.
    bad_slots: u32,
    samples: u32,
}

/// A condition streamed from a sensor converting `odr_ppm` off 104 Hz, whose conversions
/// `skip` are not read; `hardware_count`: the board counts every data-ready edge (pulsed
/// data-ready), else one edge per read (latched, as on the LSM6DS33).
fn missed_run(skip: fn(u32) -> bool, odr_ppm: i64, hardware_count: bool) -> MissedRun {
    use crate::device::sampler::Conversion;
    use crate::device::{Config, Device};
    use crate::packet::{Command, Packet, SampleFlags};
    let mut dev = Device::<16>::new(Config::FEATHER);
    let start = Command::Start {
        condition: crate::Condition::X,
        rate_uhz: 10_000,
    };
    dev.on_command(start, &mut |_| {});
    let (mut flagged, mut bad_slots, mut samples) = (0u32, 0u32, 0u32);
    let mut tally = |p: Packet| {
        if let Packet::Averages(b) = p {
            for (_, ap, a) in b.iter() {
                let m = u32::from(SampleFlags::missed(a.flags));
                flagged += m;
                samples += 1;
                if !(6..=7).contains(&(ap.len() as u32 + m)) {
                    bad_slots += 1;
                }
            }
        }
    };
    // Conversion k at k / (104 Hz · (1 + odr_ppm·1e-6)), in 1 MHz ticks.
    let period_pico = 1_000_000_000_000i64 * 1_000_000 / (104 * (1_000_000 + odr_ppm));
    let (mut skipped, mut reads) = (0u32, 0u32);
    for k in 0..6000u32 {
        if skip(k) {
            skipped += 1;
            continue;
        }
        reads += 1;
        let t = 1_000 + (i64::from(k) * period_pico / 1_000_000) as u64;
        let c = Conversion {
            capture: t,
            counts: [100, -200, 300],
            late: false,
            edges: Some(if hardware_count { k } else { reads }),
        };
        dev.on_conversion(&c, &mut tally);
    }
    dev.on_command(Command::Stop, &mut tally);
    MissedRun {
        skipped,
        lost: dev.status().lost,
        flagged,
        bad_slots,
        samples,
    }
}

/// Late and stuck reads, with and without a hardware edge count, the sensor on time and
/// 2 % fast: every conversion not read is counted in the status, and, where a sample's slot
/// holds it, in that sample's flags, so that each sample accounts for the 6 or 7
/// conversions of its slot.
fn device_counts_missed_conversions() -> Result<(), &'static str> {
    // Single late reads and runs of up to 5: every slot keeps a read conversion.
    fn short(k: u32) -> bool {
        k % 97 == 5 || k % 389 == 11 || (1000..1003).contains(&k) || (2500..2505).contains(&k)
    }
    // Stuck reads of 100 and 300 ms: whole slots without a read conversion.
    fn stuck(k: u32) -> bool {
        short(k) || (3000..3010).contains(&k) || (4000..4031).contains(&k)
    }
    for hardware_count in [true, false] {
        for odr_ppm in [0, 20_000, -20_000] {
            let r = missed_run(short, odr_ppm, hardware_count);
            check(r.samples > 900, "a condition's samples streamed")?;
            check(r.lost == r.skipped, "lost counts every conversion not read")?;
            check(r.flagged == r.skipped, "each one is in its sample's flags")?;
            check(
                r.bad_slots == 0,
                "each sample accounts for its 6 or 7 conversions",
            )?;
            let r = missed_run(stuck, odr_ppm, hardware_count);
            check(
                r.lost == r.skipped,
                "stuck: lost counts every conversion not read",
            )?;
            check(
                r.flagged <= r.skipped && r.skipped - r.flagged <= 41,
                "stuck: only those of slots without a read are in no sample's flags",
            )?;
            check(r.bad_slots == 0, "stuck: each sample accounts for its slot")?;
        }
    }
    Ok(())
}

/// [`crate::device::pairing::pair`]: an on-time read keeps its edge's instant; a late read
/// of a latched line takes the latest conversion's instant and is flagged; an edge during
/// the read flags the sample; counters and timers wrap.
fn reads_are_paired_with_their_instants() -> Result<(), &'static str> {
    use crate::device::pairing::{pair, Read};
    const P: u32 = 9615;
    let on_time = Read {
        capture: u32::MAX - 1000,
        capture_after: u32::MAX - 1000,
        read_start: 1999, // 3000 ticks after the capture, across the wrap
        edges: 41,
        edges_after: 41,
        counts: [1, 2, 3],
        latched: true,
    };
    let c = pair(&on_time, P);
    check(
        c.capture == u64::from(u32::MAX - 1000) && !c.late && c.edges.is_none(),
        "latched, on time: the edge's instant",
    )?;
    // Read 2.5 periods after the edge: two newer conversions overwrote it.
    let late = Read {
        read_start: on_time.capture.wrapping_add(P * 5 / 2),
        ..on_time
    };
    let c = pair(&late, P);
    check(
        c.capture == u64::from(on_time.capture.wrapping_add(2 * P)) && c.late,
        "latched, late: the latest conversion's instant, flagged",
    )?;
    let pulsed = Read {
        latched: false,
        read_start: on_time.capture.wrapping_add(P * 5 / 2),
        ..on_time
    };
    let c = pair(&pulsed, P);
    check(
        c.capture == u64::from(on_time.capture) && !c.late && c.edges == Some(41),
        "pulsed: the capture is the latest edge's, with the count",
    )?;
    for during in [
        Read {
            capture_after: pulsed.capture.wrapping_add(P),
            edges_after: 42,
            ..pulsed
        },
        Read {
            capture_after: on_time.capture.wrapping_add(P),
            edges_after: 42,
            ..on_time
        },
    ] {
        check(pair(&during, P).late, "an edge during the read flags it")?;
    }
    Ok(())
}
