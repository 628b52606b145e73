//! The overlapping Allan deviation of a still record, its confidence intervals and the
//! IEEE 952/1554 noise terms (docs/allan.md).
//!
//! - here: [`oadev`] (allantools `oadev` with `data_type="freq"`, ported literally), the
//!   octave τ list and [`AllanError`];
//! - `ci`: the lag-1 ACF noise id, Greenhall's EDF and the χ² interval (allantools
//!   `ci.confidence_interval_noiseID`);
//! - `terms`: the weighted least-squares fit of white, flicker and random-walk terms to the
//!   octave points, with the exact discrete expected Allan variance of each;
//! - `series`: a recording's groups and channels as uniformly sampled series;
//! - [`powerlaw`]: the terms' structure functions, the exact expected Allan variance from
//!   them, and an exact flicker generator (the simulator's too).

pub mod analysis;
mod ci;
pub mod powerlaw;
mod series;
mod terms;

pub(crate) use ci::interval_of;
pub use ci::{chi2_quantile, confidence_interval, edf_greenhall, noise_id, Interval, ONE_SIGMA_CI};
pub use series::{series_of, to_micro_g, Channel, Gap, Scale, Still, MICRO_G, STANDARD_GRAVITY};
pub use terms::{expected_avar, fit_terms, Fit, Term, TermKind};

/// What went wrong, with where.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum AllanError {
    /// Fewer than 3 samples: no Allan variance at any τ.
    #[error("{len} samples: the Allan deviation needs at least 3")]
    TooShort {
        /// Number of samples.
        len: usize,
    },
    /// A sample is NaN or infinite.
    #[error("sample {index} is not a finite number")]
    NotFinite {
        /// 0-based index of the sample.
        index: usize,
    },
    /// The sample rate is not a positive finite number.
    #[error("sample rate {rate_hz} Hz: expected a positive number")]
    BadRate {
        /// The rate given.
        rate_hz: f64,
    },
    /// An explicit averaging factor is 0 or beyond the N + 1 phase points (allantools
    /// drops these silently; a caller who lists one made a mistake). Factors that leave
    /// n ≤ 1 differences are dropped as allantools does.
    #[error("averaging factor m = {m} for {len} samples: expected 1 ≤ m ≤ N")]
    BadFactor {
        /// The factor.
        m: usize,
        /// Number of samples.
        len: usize,
    },
    /// A record has a gap (dropped samples) or irregular timing.
    #[error(transparent)]
    Gap(#[from] Gap),
    /// A record has neither a t_s spacing nor a `sample_rate_hz` to give its rate.
    #[error("{group}: no sample interval (no t_s column with two rows, no sample_rate_hz)")]
    NoRate {
        /// The record's name.
        group: String,
    },
    /// The terms fit had too few points with an EDF.
    #[error("{points} octave points: the terms fit needs at least {needed}")]
    TooFewPoints {
        /// Points available.
        points: usize,
        /// Points needed.
        needed: usize,
    },
    /// The fit's normal equations are singular.
    #[error("the terms fit is singular ({0})")]
    Singular(&'static str),
}

/// One τ of the overlapping Allan deviation.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Point {
    /// τ = m/fs, seconds.
    pub tau_s: f64,
    /// Averaging factor (samples per block).
    pub m: usize,
    /// Number of second differences averaged: N + 1 − 2m.
    pub n: usize,
    /// The overlapping Allan deviation, in the series' units.
    pub adev: f64,
    /// allantools' naive error adev/√n (not an interval; kept for comparison).
    pub naive_err: f64,
    /// The 1σ interval, noise id and EDF; `None` with fewer than 30 blocks of m
    /// (allantools raises there) or when the noise id leaves no Greenhall case.
    pub interval: Option<Interval>,
}

/// Octave averaging factors as allantools `taus="octave"` makes them for `len` freq
/// samples: m = 2^k, 0 < m < N + 1 (N + 1 phase points).
pub fn octave_factors(len: usize) -> Vec<usize> {
    let phase_len = len.saturating_add(1);
    (0..usize::BITS)
        .map_while(|k| 1usize.checked_shl(k))
        .take_while(|m| *m < phase_len)
        .collect()
}

/// numpy's pairwise summation (`np.sum` of a contiguous f64 array), so that sums match
/// allantools' to the last bit where the order of the other operations matches too.
pub(crate) fn pairwise_sum(a: &[f64]) -> f64 {
    const BLOCK: usize = 128;
    if a.len() < 8 {
        return a.iter().fold(0.0, |s, v| s + v);
    }
    if a.len() <= BLOCK {
        let mut r = [0.0f64; 8];
        let chunks = a.chunks_exact(8);
        let rest = chunks.remainder();
        for c in chunks {
            for (ri, ci) in r.iter_mut().zip(c) {
                *ri += ci;
            }
        }
        let [r0, r1, r2, r3, r4, r5, r6, r7] = r;
        let s = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7));
        return rest.iter().fold(s, |s, v| s + v);
    }
    let mut half = a.len() / 2;
    half -= half % 8;
    let (lo, hi) = a.split_at(half);
    pairwise_sum(lo) + pairwise_sum(hi)
}

/// Check the inputs every estimator needs.
fn check(y: &[f64], rate_hz: f64) -> Result<(), AllanError> {
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        return Err(AllanError::BadRate { rate_hz });
    }
    if y.len() < 3 {
        return Err(AllanError::TooShort { len: y.len() });
    }
    if let Some(index) = y.iter().position(|v| !v.is_finite()) {
        return Err(AllanError::NotFinite { index });
    }
    Ok(())
}

/// Phase x = [0, cumsum(y − mean) / fs] (allantools `frequency2phase`: cumsum first,
/// then × dt, as there).
fn phase_of(y: &[f64], rate_hz: f64) -> Vec<f64> {
    let mean = pairwise_sum(y) / y.len() as f64;
    let dt_s = 1.0 / rate_hz;
    let mut x = Vec::with_capacity(y.len() + 1);
    x.push(0.0);
    let mut acc = 0.0;
    for v in y {
        acc += v - mean;
        x.push(acc * dt_s);
    }
    x
}

/// The overlapping Allan deviation of freq-type samples `y` taken at `rate_hz`, at the
/// octave factors (`factors = None`) or the given ones (each 1 ≤ m; factors leaving
/// n ≤ 1 are dropped, as allantools does). With `intervals`, each point's 1σ interval.
pub fn oadev(
    y: &[f64],
    rate_hz: f64,
    factors: Option<&[usize]>,
    intervals: bool,
) -> Result<Vec<Point>, AllanError> {
    check(y, rate_hz)?;
    let x = phase_of(y, rate_hz);
    let mut ms: Vec<usize> = match factors {
        Some(f) => {
            if let Some(m) = f.iter().find(|m| **m == 0 || **m >= x.len()) {
                return Err(AllanError::BadFactor {
                    m: *m,
                    len: y.len(),
                });
            }
            f.to_vec()
        }
        None => octave_factors(y.len()),
    };
    // allantools de-duplicates and sorts (np.unique).
    ms.sort_unstable();
    ms.dedup();
    let mut out = Vec::with_capacity(ms.len());
    let mut v = Vec::with_capacity(x.len());
    for m in ms {
        let n = x.len().saturating_sub(2 * m);
        if n <= 1 {
            continue;
        }
        v.clear();
        v.extend(
            x.iter()
                .zip(x.iter().skip(m))
                .zip(x.iter().skip(2 * m))
                .map(|((x0, x1), x2)| {
                    let d = x2 - 2.0 * x1 + x0;
                    d * d
                }),
        );
        let s = pairwise_sum(&v);
        let adev = (s / (2.0 * n as f64)).sqrt() / m as f64 * rate_hz;
        let interval = if intervals {
            ci::interval_of(y, adev, m)
        } else {
            None
        };
        out.push(Point {
            tau_s: m as f64 / rate_hz,
            m,
            n,
            adev,
            naive_err: adev / (n as f64).sqrt(),
            interval,
        });
    }
    Ok(out)
}
