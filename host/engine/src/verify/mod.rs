//! Checks of the device's own fits: each device fit against the f64 batch fit (nalgebra QR)
//! of exactly its samples, in units of σ_CRLB. One [`compare`] and one [`sigma_crlb`],
//! used by:
//!
//! - [`recorded`]: a recording and its fit log (`rotacal crosscheck`);
//! - [`emulated`]: the emulated Cortex-M4F's f32 fits of synthetic records (QEMU);
//! - [`session`]: the emulated device logic's packets for a whole simulated session.

pub mod emulated;
pub mod recorded;
pub mod session;

use crate::fit::batch;
use crate::recording::from_device::FitLine;
use rotacal_shared::{Model, PhaseStep, TickRate, Ticks};

/// σ_CRLB of A, B and C for `n` samples of white noise `noise_sigma` quantised to whole
/// counts (adding 1/12 count²): √(2σ²/N), √(2σ²/N), √(σ²/N) (docs/method.md §5).
pub fn sigma_crlb(noise_sigma: f64, n: usize) -> [f64; 3] {
    let var = noise_sigma * noise_sigma + 1.0 / 12.0;
    let n = n as f64;
    let ab = (2.0 * var / n).sqrt();
    [ab, ab, (var / n).sqrt()]
}

/// A device fit against the f64 QR fit of the same samples with its regressors.
pub struct Comparison {
    /// The host's fit.
    pub host: batch::BatchFit,
    /// max over channels and A, B, C of |device − host| / host standard error.
    pub max_delta_se: f64,
    /// … / σ_CRLB, from the host fit's σ̂.
    pub max_delta_crlb: f64,
}

/// Why a device fit could not be checked against the recording.
#[derive(Debug, thiserror::Error)]
pub enum VerifyError {
    /// A fit report with a device clock of 0 ticks per second.
    #[error("fit log: tick_hz 0")]
    NoTickRate,
    /// The host's f64 fit of the device's window failed.
    #[error("condition {condition}: host fit: {source}")]
    HostFit {
        /// The condition.
        condition: rotacal_shared::Condition,
        /// Why.
        source: batch::BatchError,
    },
    /// A recording without `seq`, in which the device's windows cannot be found.
    #[error("{source_name}: no seq column, so the device's windows can't be found")]
    NoSeq {
        /// The recording.
        source_name: String,
    },
    /// A recording without `t_s`.
    #[error("recording has no t_s")]
    NoTime,
    /// A row's time beyond the device clock's range.
    #[error("{source_name}: t_s {t_s} out of range")]
    TimeOutOfRange {
        /// The recording.
        source_name: String,
        /// The time, s.
        t_s: f64,
    },
    /// A row's conversions beyond what an aperture holds.
    #[error("{source_name}: conv_gaps of seq {seq}")]
    Conversions {
        /// The recording.
        source_name: String,
        /// The row's seq.
        seq: u64,
    },
    /// A file of poses or a free recording: no conditions to check.
    #[error(transparent)]
    Recording(#[from] crate::recording::RecordingError),
}

/// Fit `window` (conversion instants in ticks of the device clock, averages of u, v, w) in
/// f64 with the device's phase step and clock, weighted as the device weights, and
/// compare with its coefficients. σ_CRLB counts every conversion.
pub fn compare(window: &[batch::Sample], f: &FitLine) -> Result<Comparison, VerifyError> {
    let clock = TickRate::new(f.tick_hz).ok_or(VerifyError::NoTickRate)?;
    let host =
        batch::fit(window, PhaseStep(f.step), clock, Model::SINE, Ticks(0)).map_err(|source| {
            VerifyError::HostFit {
                condition: f.condition,
                source,
            }
        })?;
    let (mut max_se, mut max_crlb) = (0.0f64, 0.0f64);
    let conversions: usize = window.iter().map(|(ap, _)| ap.len()).sum();
    for (h, device) in host.channels.iter().zip(&f.coef) {
        let crlb = sigma_crlb(h.sigma, conversions);
        // A, B, C: the device's three against the host's first three (the model's).
        let params = device.iter().zip(&h.coef).zip(&h.se).zip(&crlb);
        for (((dev, host), se), bound) in params {
            let d = (dev - host).abs();
            max_se = max_se.max(d / se);
            max_crlb = max_crlb.max(d / bound);
        }
    }
    Ok(Comparison {
        host,
        max_delta_se: max_se,
        max_delta_crlb: max_crlb,
    })
}
