//! A recording's Allan analysis, as `rotacal allan` prints and writes it (the Allan JSON,
//! docs/formats.md): each still record and channel, its overlapping Allan deviation with
//! 1σ intervals, and the fitted IEEE noise terms.

use super::{fit_terms, oadev, series_of, to_micro_g, AllanError, Fit, Point, Scale, TermKind};
use crate::recording::{Method, Recording};

/// One channel's results.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ChannelOut {
    /// u, v or w.
    pub channel: &'static str,
    /// The mean reading, in the results' units.
    pub mean: f64,
    /// The Allan deviation at each τ.
    pub points: Vec<Point>,
    /// The fitted noise terms, if the fit could be made.
    pub terms: Option<Fit>,
    /// √h0: the one-sided noise density (= √2·N), units/√Hz.
    pub noise_density_one_sided: Option<f64>,
    /// Why the terms could not be fitted.
    pub terms_error: Option<String>,
}

/// One record's results.
#[derive(Clone, Debug, serde::Serialize)]
pub struct GroupOut {
    /// The record (condition, pose, or the free series).
    pub name: String,
    /// Its sample rate, Hz.
    pub rate_hz: f64,
    /// Its samples.
    pub samples: usize,
    /// Its first and last times, s.
    pub t_first_s: Option<f64>,
    /// See `t_first_s`.
    pub t_last_s: Option<f64>,
    /// u, v, w.
    pub channels: Vec<ChannelOut>,
}

/// The whole analysis (the Allan JSON without its traceability block).
#[derive(Clone, Debug, serde::Serialize)]
pub struct AllanJson {
    /// The recording's name.
    pub file: String,
    /// Its method.
    pub method: Method,
    /// The results' units.
    #[serde(flatten)]
    pub scale: Scale,
    /// Each still record.
    pub groups: Vec<GroupOut>,
}

/// Why a recording could not be analysed: each names the recording.
#[derive(Debug, thiserror::Error)]
pub enum AnalysisError {
    /// Its still records could not be taken (a gap, no sample rate).
    #[error("{source_name}: {error}")]
    Records {
        /// The recording.
        source_name: String,
        /// Why.
        error: Box<AllanError>,
    },
    /// No samples in the window.
    #[error("{source_name}: no samples (in the --from/--to window)")]
    Empty {
        /// The recording.
        source_name: String,
    },
    /// One record's channel could not be analysed.
    #[error("{source_name}: {record}, channel {channel}: {error}")]
    Channel {
        /// The recording.
        source_name: String,
        /// The record.
        record: String,
        /// The channel.
        channel: &'static str,
        /// Why.
        error: Box<AllanError>,
    },
}

/// The Allan analysis of `rec` (named `source` in the output and messages), restricted to
/// `from_s ≤ t_s ≤ to_s`.
pub fn analyse(
    rec: &Recording,
    source: &str,
    from_s: Option<f64>,
    to_s: Option<f64>,
) -> Result<AllanJson, AnalysisError> {
    let stills = series_of(rec, from_s, to_s).map_err(|error| AnalysisError::Records {
        source_name: source.into(),
        error: Box::new(error),
    })?;
    if stills.is_empty() {
        return Err(AnalysisError::Empty {
            source_name: source.into(),
        });
    }
    let scale = to_micro_g(rec.meta.units.as_deref());
    let factor = scale.micro_g_per_unit.unwrap_or(1.0);
    let mut groups = Vec::with_capacity(stills.len());
    for s in &stills {
        let mut channels = Vec::with_capacity(3);
        for ch in &s.channels {
            let y: Vec<f64> = ch.y.iter().map(|v| v * factor).collect();
            let points =
                oadev(&y, s.rate_hz, None, true).map_err(|error| AnalysisError::Channel {
                    source_name: source.into(),
                    record: s.name.clone(),
                    channel: ch.name,
                    error: Box::new(error),
                })?;
            let (terms, terms_error) = match fit_terms(&points, y.len(), s.rate_hz) {
                Ok(f) => (Some(f), None),
                Err(e) => (None, Some(e.to_string())),
            };
            let noise_density_one_sided = terms.as_ref().and_then(|f| {
                f.terms
                    .iter()
                    .find(|t| t.kind == TermKind::White)
                    .map(|t| t.h.sqrt())
            });
            channels.push(ChannelOut {
                channel: ch.name,
                mean: y.iter().sum::<f64>() / y.len() as f64,
                points,
                terms,
                noise_density_one_sided,
                terms_error,
            });
        }
        groups.push(GroupOut {
            name: s.name.clone(),
            rate_hz: s.rate_hz,
            samples: s.t_s.len(),
            t_first_s: s.t_s.first().copied(),
            t_last_s: s.t_s.last().copied(),
            channels,
        });
    }
    Ok(AllanJson {
        file: source.into(),
        method: rec.method,
        scale,
        groups,
    })
}
