//! Bit-reproducible synthetic records of one rotation condition.
//!
//! Used where the host and an emulated or real device must see the *same* samples
//! without a file between them: the Cortex-M4F cross-check, and later the firmware's
//! simulated sensor stream. All arithmetic is IEEE f64 through libm (pure Rust) and an
//! integer PRNG, so x86-64 and Cortex-M4F produce identical samples; a checksum in the
//! cross-check proves it on every run. The full experiment simulator lives in the host.

use crate::phase::PhaseStep;
use crate::time::{TickRate, Ticks};

/// What to synthesise: `y_j = round(A_j sin α + B_j cos α + C_j + σ·n)` in counts,
/// clamped to the i16 range like a sensor's output register.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SynthSpec {
    /// Per channel (u, v, w): A, B, C in counts.
    pub coef: [[f64; 3]; 3],
    /// White-noise standard deviation per sample, in counts.
    pub noise_sigma: f64,
    /// True rotation per tick (may differ from the nominal one a fit assumes).
    pub step: PhaseStep,
    /// The timestamp clock.
    pub clock: TickRate,
    /// Sample rate in millihertz (16 Hz = 16 000).
    pub sample_rate_mhz: u32,
    /// Samples to produce (before drops).
    pub n_samples: u32,
    /// Probability, per million, that a sample is dropped (a gap in the record).
    pub drop_per_million: u32,
    /// PRNG seed.
    pub seed: u64,
}

/// One synthetic sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SynthSample {
    /// Index of the sample in the undropped sequence.
    pub seq: u32,
    /// Timestamp.
    pub t: Ticks,
    /// Raw counts u, v, w.
    pub counts: [i16; 3],
}

/// SplitMix64 (Steele, Lea & Flood 2014): tiny, integer-only, and the same on every
/// target, which is all a reproducible test stream needs.
#[derive(Clone, Debug)]
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in (0, 1], 53 bits.
    fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 1.0) / 9_007_199_254_740_992.0
    }
}

/// Iterator over the samples of a [`SynthSpec`].
#[derive(Clone, Debug)]
pub struct Synth {
    spec: SynthSpec,
    rng: SplitMix64,
    i: u32,
    spare: Option<f64>,
}

impl Synth {
    /// Start the stream.
    pub fn new(spec: SynthSpec) -> Synth {
        Synth {
            spec,
            rng: SplitMix64(spec.seed),
            i: 0,
            spare: None,
        }
    }

    /// Standard normal deviate (Box–Muller, both values used).
    fn normal(&mut self) -> f64 {
        if let Some(z) = self.spare.take() {
            return z;
        }
        let r = libm::sqrt(-2.0 * libm::log(self.rng.uniform()));
        let theta = core::f64::consts::TAU * self.rng.uniform();
        self.spare = Some(r * libm::sin(theta));
        r * libm::cos(theta)
    }
}

impl Iterator for Synth {
    type Item = SynthSample;

    fn next(&mut self) -> Option<SynthSample> {
        loop {
            if self.i >= self.spec.n_samples {
                return None;
            }
            let seq = self.i;
            self.i += 1;
            // Exact tick of sample `seq`: seq · clock / rate, in integers.
            let t = u64::from(seq) * u64::from(self.spec.clock.hz()) * 1000
                / u64::from(self.spec.sample_rate_mhz.max(1));
            let t = Ticks(t);
            let alpha = self.spec.step.phase_at(t).radians();
            let (s, c) = (libm::sin(alpha), libm::cos(alpha));
            let mut counts = [0i16; 3];
            for (out, [a, b, off]) in counts.iter_mut().zip(self.spec.coef) {
                let y = a * s + b * c + off + self.spec.noise_sigma * self.normal();
                *out = libm::round(y).clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16;
            }
            let dropped = (self.rng.next_u64() % 1_000_000) < u64::from(self.spec.drop_per_million);
            if !dropped {
                return Some(SynthSample { seq, t, counts });
            }
        }
    }
}

/// FNV-1a over a sample stream's ticks and counts: equal checksums on host and device
/// show they fitted the same samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Checksum(pub u64);

impl Default for Checksum {
    fn default() -> Self {
        Checksum(0xcbf2_9ce4_8422_2325)
    }
}

impl Checksum {
    /// Fold one sample in.
    pub fn add(&mut self, s: &SynthSample) {
        let mut eat = |bytes: &[u8]| {
            for b in bytes {
                self.0 ^= u64::from(*b);
                self.0 = self.0.wrapping_mul(0x0000_0100_0000_01B3);
            }
        };
        eat(&s.t.0.to_le_bytes());
        for c in s.counts {
            eat(&c.to_le_bytes());
        }
    }
}

/// The A, B, C of each channel (rows of `s`, output units per m/s²) for rotation about
/// platter axis `axis` (0 = x, 1 = y, 2 = z) in gravity `g`, by docs/method.md §1: about x,
/// A = g·S_jy and B = g·S_jz; about y, A = g·S_jx, B = g·S_jz; about z, A = g·S_jx,
/// B = g·S_jy. C is the offset.
pub fn coefficients(s: &[[f64; 3]; 3], offsets: &[f64; 3], g: f64, axis: usize) -> [[f64; 3]; 3] {
    let cond = match axis {
        0 => crate::Condition::X,
        1 => crate::Condition::Y,
        _ => crate::Condition::Z,
    };
    let (ia, ib) = cond.sin_cos_axes();
    let mut out = [[0.0; 3]; 3];
    for ((o, row), off) in out.iter_mut().zip(s).zip(offsets) {
        let pick = |i: usize| row.get(i).copied().unwrap_or(0.0);
        *o = [g * pick(ia), g * pick(ib), *off];
    }
    out
}

/// The records of the f32-versus-f64 cross-check (issue 2, docs/fit.md): a device with a
/// realistic sensitivity matrix, turned about x, y and z, with LSM6DS33 noise.
pub mod crosscheck {
    use super::SynthSpec;
    use crate::phase::PhaseStep;
    use crate::time::TickRate;

    /// A named record: rotation rate, sample rate and length.
    #[derive(Clone, Copy, Debug)]
    pub struct Record {
        /// Short name used in logs and JSON.
        pub name: &'static str,
        /// Rotation rate, µHz.
        pub rate_uhz: u64,
        /// Sample rate, mHz.
        pub sample_rate_mhz: u32,
        /// Samples per condition.
        pub n_samples: u32,
    }

    /// Gaitan & Geist (2022)'s run, then an hour at 16 Hz and at 104 Hz (at 0.25 Hz, as docs/method.md §6).
    pub const RECORDS: [Record; 3] = [
        Record {
            name: "paper-10mhz",
            rate_uhz: 10_000,
            sample_rate_mhz: 16_000,
            n_samples: 4200,
        },
        Record {
            name: "hour-16hz",
            rate_uhz: 250_000,
            sample_rate_mhz: 16_000,
            n_samples: 57_600,
        },
        Record {
            name: "hour-104hz",
            rate_uhz: 250_000,
            sample_rate_mhz: 104_000,
            n_samples: 374_400,
        },
    ];

    /// Standard gravity, m/s².
    pub const G: f64 = 9.80665;
    /// LSM6DS33 at ±2 g: 0.061 mg per count, i.e. counts per m/s².
    pub const COUNTS_PER_MS2: f64 = 1.0 / (0.061e-3 * G);
    /// LSM6DS33 noise density, g/√Hz (datasheet: 90 µg/√Hz).
    pub const NOISE_DENSITY_G: f64 = 90e-6;

    /// Sensitivity matrix (rows u, v, w; counts per m/s²) of the simulated device:
    /// about 0.3 % gain spread and 0.2–0.6° axis misalignments.
    pub fn sensitivity() -> [[f64; 3]; 3] {
        let k = COUNTS_PER_MS2;
        [
            [k * 1.0021, k * 0.0035, k * -0.0061],
            [k * -0.0012, k * 0.9974, k * 0.0047],
            [k * 0.0088, k * -0.0029, k * 1.0043],
        ]
    }

    /// Offsets in counts.
    pub const OFFSETS: [f64; 3] = [35.0, -20.0, 140.0];

    /// White-noise σ per sample in counts: density · √(fs/2).
    pub fn noise_sigma(sample_rate_mhz: u32) -> f64 {
        NOISE_DENSITY_G * libm::sqrt(f64::from(sample_rate_mhz) / 2000.0) / 0.061e-3
    }

    /// The A, B, C of each channel for rotation about platter axis `axis`.
    pub fn coefficients(axis: usize) -> [[f64; 3]; 3] {
        super::coefficients(&sensitivity(), &OFFSETS, G, axis)
    }

    /// The spec of `record` for condition `axis`, with a seed of its own.
    pub fn spec(record: &Record, axis: usize) -> Option<SynthSpec> {
        let clock = TickRate::MHZ_1;
        Some(SynthSpec {
            coef: coefficients(axis),
            noise_sigma: noise_sigma(record.sample_rate_mhz),
            step: PhaseStep::from_micro_hz(record.rate_uhz, clock)?,
            clock,
            sample_rate_mhz: record.sample_rate_mhz,
            n_samples: record.n_samples,
            drop_per_million: 0,
            seed: 1000 * record.rate_uhz + u64::from(record.sample_rate_mhz) + axis as u64,
        })
    }
}
