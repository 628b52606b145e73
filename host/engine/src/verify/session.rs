//! Checks the device logic's output for the simulated session (tests/qemu `session`,
//! `rotacal_shared::device::simulated::SessionSpec::PAPER`): the emulated Cortex-M4F must
//! send the same bytes as the host running the same code, and every fit it reports must
//! equal an f64 batch fit (nalgebra QR, independent of the streaming fit) of exactly the
//! samples of its window; the quick-look must equal the Gram form on those f64 fits.

use crate::fit::batch::{BatchChannel, BatchFit};
use crate::recording::from_device::FitLine;
use rotacal_shared::device::simulated::SessionSpec;
use rotacal_shared::device::{Config, Device, RING};
use rotacal_shared::intrinsic::{self, ConditionFit};
use rotacal_shared::packet::{Packet, MAX_PACKET};
use rotacal_shared::{Aperture, Condition, TickRate, Ticks};

/// The device's clock in the simulated session (`Config::FEATHER`).
const CLOCK: TickRate = Config::FEATHER.clock;
use serde::Serialize;

/// A log line that is not a packet.
#[derive(Debug, thiserror::Error)]
#[error("{source_name}:{line}: {message}")]
pub struct LogError {
    /// The log.
    pub source_name: String,
    /// 1-based line.
    pub line: usize,
    /// What is wrong.
    pub message: String,
}

/// Why the session's packets could not be checked.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// A packet the device sent does not decode.
    #[error("packet {index}: {cause}")]
    Packet {
        /// Its place among the device's packets, from 0.
        index: usize,
        /// Why it does not decode.
        cause: rotacal_shared::packet::DecodeError,
    },
    /// A fit report could not be refitted on the host.
    #[error(transparent)]
    Refit(#[from] crate::verify::VerifyError),
    /// The host's refit lacks the three channels of A, B, C (a bug of the engine).
    #[error("internal: the host fit has not three channels of A, B, C (a bug of rotacal)")]
    NotThreeChannels,
    /// The Gram form on the host's fits failed.
    #[error(transparent)]
    Intrinsic(#[from] rotacal_shared::intrinsic::IntrinsicError),
}

/// The packets of a `session` log: every `P <hex>` line, in order. Other lines are
/// ignored except `session done`, which must be there (a run that died is incomplete).
pub fn parse_log(text: &str, source_name: &str) -> Result<Vec<Vec<u8>>, LogError> {
    let err = |line, message: String| LogError {
        source_name: source_name.into(),
        line,
        message,
    };
    let mut out = Vec::new();
    let mut done = false;
    for (i, line) in text.lines().enumerate() {
        if let Some(hex) = line.strip_prefix("P ") {
            let hex = hex.trim();
            if hex.len() % 2 != 0 || hex.len() > 2 * MAX_PACKET {
                return Err(err(
                    i + 1,
                    format!("{} hex digits is not a packet", hex.len()),
                ));
            }
            let bytes = crate::recording::from_device::from_hex(hex)
                .ok_or_else(|| err(i + 1, "not hex".into()))?;
            out.push(bytes);
        } else if line.starts_with("session done") {
            done = true;
        }
    }
    if !done {
        return Err(err(
            text.lines().count(),
            "no 'session done' line: the run did not finish".into(),
        ));
    }
    Ok(out)
}

/// The same session run on this host through the same code.
pub fn host_packets() -> Vec<Vec<u8>> {
    let mut dev = Device::<RING>::new(Config::FEATHER);
    let mut out = Vec::new();
    SessionSpec::PAPER.run(&mut dev, &mut |p: Packet| {
        out.push(crate::recording::from_device::encode(&p))
    });
    out
}

/// One reported fit against the f64 batch fit of its window.
#[derive(Clone, Debug, Serialize)]
pub struct FitComparison {
    /// x, y or z.
    pub condition: Condition,
    /// Final (at stop) or periodic.
    pub is_final: bool,
    /// Samples in the window.
    pub n: u32,
    /// max over channels and A, B, C of |device − host| / σ_CRLB (from the host fit's σ̂).
    pub max_ratio_crlb: f64,
    /// max over channels and A, B, C of |device se − host se| / host se.
    pub max_se_rel: f64,
}

/// The check's findings.
#[derive(Clone, Debug, Serialize)]
pub struct SessionReport {
    /// Packets the device sent.
    pub packets: usize,
    /// Byte-identical to the host's run of the same code.
    pub bit_identical_to_host: bool,
    /// Index of the first packet that differs, if any.
    pub first_difference: Option<usize>,
    /// Live samples streamed.
    pub samples: usize,
    /// Sequence numbers 0, 1, 2, … with no gap or repeat.
    pub seq_contiguous: bool,
    /// Every fit report.
    pub fits: Vec<FitComparison>,
    /// Worst over all fit reports.
    pub max_ratio_crlb: f64,
    /// max over s and φ of |device − host| / host standard uncertainty.
    pub quick_look_max_ratio_u: Option<f64>,
}

/// The (A, B) part of a host fit of the 3-parameter model (the Gram form's input): A and
/// B per channel, and their covariance σ̂²·(HᵀH)⁻¹.
fn condition_fit(r: &BatchFit) -> Result<ConditionFit, SessionError> {
    let broken = || SessionError::NotThreeChannels;
    let at = |i: usize, j: usize| r.unscaled_cov.get((i, j)).copied().ok_or_else(broken);
    let ab = [[at(0, 0)?, at(0, 1)?], [at(1, 0)?, at(1, 1)?]];
    let channels: &[BatchChannel; 3] = r.channels.as_slice().try_into().map_err(|_| broken())?;
    let mut fit = ConditionFit {
        a: [0.0; 3],
        b: [0.0; 3],
        cov: [[[0.0; 2]; 2]; 3],
    };
    let out = fit.a.iter_mut().zip(&mut fit.b).zip(&mut fit.cov);
    for (ch, ((a, b), cov)) in channels.iter().zip(out) {
        let &[ca, cb, ..] = ch.coef.as_slice() else {
            return Err(broken());
        };
        (*a, *b) = (ca, cb);
        *cov = ab.map(|row| row.map(|x| ch.sigma.powi(2) * x));
    }
    Ok(fit)
}

/// Decode and check the device's packets.
pub fn check(device: &[Vec<u8>]) -> Result<SessionReport, SessionError> {
    let host = host_packets();
    let first_difference = device
        .iter()
        .zip(&host)
        .position(|(a, b)| a != b)
        .or((device.len() != host.len()).then_some(device.len().min(host.len())));
    let mut packets = Vec::with_capacity(device.len());
    for (i, bytes) in device.iter().enumerate() {
        packets
            .push(Packet::decode(bytes).map_err(|cause| SessionError::Packet { index: i, cause })?);
    }
    let mut samples: Vec<(u32, Aperture, [f64; 3])> = Vec::new();
    for p in &packets {
        match p {
            Packet::Samples(b) => samples.extend(
                b.iter()
                    .map(|(seq, t, s)| (seq, Aperture::point(Ticks(t)), s.counts.map(f64::from))),
            ),
            Packet::Averages(b) => samples.extend(b.iter().map(|(seq, ap, s)| (seq, ap, s.mean()))),
            _ => {}
        }
    }
    let seq_contiguous = samples.iter().enumerate().all(|(i, s)| s.0 as usize == i);
    let mut fits = Vec::new();
    let mut finals: [Option<ConditionFit>; 3] = [None; 3];
    for p in &packets {
        let Packet::Fit(f) = p else { continue };
        let window: Vec<crate::fit::batch::Sample> = samples
            .iter()
            .filter(|s| s.0 >= f.first_seq && s.0 <= f.last_seq)
            .map(|s| (s.1, s.2))
            .collect();
        let line = FitLine::new(f, CLOCK.hz());
        let c = crate::verify::compare(&window, &line)?;
        let r = &c.host;
        let worst = if window.len() == f.n as usize {
            c.max_delta_crlb
        } else {
            f64::INFINITY
        };
        let mut se_rel = 0.0f64;
        for (host, se) in r.channels.iter().zip(&f.se) {
            for (se, host) in se.iter().zip(&host.se) {
                se_rel = se_rel.max((f64::from(*se) - host).abs() / host);
            }
        }
        fits.push(FitComparison {
            condition: f.condition,
            is_final: f.is_final,
            n: f.n,
            max_ratio_crlb: worst,
            max_se_rel: se_rel,
        });
        if f.is_final {
            if let Some(slot) = finals.get_mut(f.condition.index()) {
                *slot = Some(condition_fit(r)?);
            }
        }
    }
    let quick = packets.iter().find_map(|p| match p {
        Packet::QuickLook(q) => Some(*q),
        _ => None,
    });
    let quick_look_max_ratio_u = match (quick, finals) {
        (Some(q), [Some(x), Some(y), Some(z)]) => {
            let h = intrinsic::from_gram(&[x, y, z], q.g_loc, 0.0)?;
            let mut worst = 0.0f64;
            let host = h.sensitivity.iter().zip(&h.angle_deg);
            for ((s, a), (qs, qa)) in host.zip(q.sensitivity.iter().zip(&q.angle_deg)) {
                worst = worst.max((qs - s.value).abs() / s.std_unc);
                worst = worst.max((qa - a.value).abs() / a.std_unc);
            }
            Some(worst)
        }
        _ => None,
    };
    let max_ratio_crlb = fits.iter().map(|f| f.max_ratio_crlb).fold(0.0, f64::max);
    Ok(SessionReport {
        packets: device.len(),
        bit_identical_to_host: first_difference.is_none(),
        first_difference,
        samples: samples.len(),
        seq_contiguous,
        fits,
        max_ratio_crlb,
        quick_look_max_ratio_u,
    })
}
