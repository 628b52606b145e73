//! `--noise-from FILE`: a still recording of the same device, pooled with the recording's own
//! groups in the estimate of each channel's flicker and random walk (docs/uncertainty.md,
//! "Slow noise"). A few periods of rotation tell the slow levels poorly; a still recording of
//! many minutes, as a lab would make one, adds the averaging lengths they lack (how much it
//! helps is measured there).
//!
//! Each still stretch of the file is one more part of the pooled estimate: its rows less an
//! offset and a trend (as the rotation groups' widened fit takes a trend out, so a slow
//! thermal drift is not read as a walk), its own AR model, the same flicker Q and walk q per
//! row. So the still rows must be as far apart as the recording's rows, and in its units.

use super::CalibrateErrorKind;
use crate::fit::noise::{self, NoiseError, NoiseModel, SlowDesign, SlowPart};
use crate::recording::Recording;
use nalgebra::DMatrix;
use rotacal_shared::{Channel, Condition};

/// A still stretch needs this many rows (the slow estimate's averaging lengths).
pub const MIN_ROWS: usize = 256;

/// Still stretches' rates, and theirs against the recording's, may differ by this much,
/// relative.
const EVEN: f64 = 0.01;

/// What is wrong with a still recording.
#[derive(Debug, thiserror::Error)]
pub enum NoiseFromError {
    /// Its timing: a gap or an irregular step, with its place.
    #[error(transparent)]
    Series(#[from] crate::allan::AllanError),
    /// No still stretch long enough.
    #[error("no still stretch of at least {MIN_ROWS} rows; the longest has {longest}")]
    TooShort {
        /// The longest stretch's rows.
        longest: usize,
    },
    /// The still stretches are not all sampled alike.
    #[error("still stretches sampled at {first_hz} Hz and {other_hz} Hz: one rate is needed")]
    Rates {
        /// The first stretch's rate, Hz.
        first_hz: f64,
        /// Another's, Hz.
        other_hz: f64,
    },
    /// A channel's noise could not be modelled.
    #[error("{stretch}, channel {}: {source}", channel.letter())]
    Noise {
        /// The stretch.
        stretch: String,
        /// The channel.
        channel: Channel,
        /// Why.
        source: NoiseError,
    },
}

/// Which still recording a channel's slow levels were pooled with.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct StillSource {
    /// The file.
    pub file: String,
    /// Its rows used, over all its still stretches.
    pub rows: usize,
    /// Seconds between them.
    pub row_interval_s: f64,
}

/// One still group's share of a channel's slow estimate.
#[derive(Debug)]
struct StillPart {
    design: std::sync::Arc<SlowDesign>,
    resid: Vec<f64>,
    ar: NoiseModel,
}

/// A still recording prepared for the slow estimate: per channel, each group's residuals
/// from an offset and a trend, with its AR model.
#[derive(Debug)]
pub struct NoiseFrom {
    /// Where it came from (for the JSON and the terminal).
    pub source: String,
    /// Its units.
    pub units: Option<String>,
    /// Seconds between rows.
    pub row_interval_s: f64,
    /// Rows used, over all groups.
    pub rows: usize,
    parts: [Vec<StillPart>; 3],
}

impl NoiseFrom {
    /// From a still recording: its still stretches as `rotacal allan` reads them (each
    /// condition, pose or free series, uniformly sampled; a gap is an error naming its
    /// place), those of at least [`MIN_ROWS`] rows.
    pub fn new(rec: &Recording) -> Result<NoiseFrom, NoiseFromError> {
        let mut parts: [Vec<StillPart>; 3] = Default::default();
        let (mut rate, mut rows, mut longest) = (None::<f64>, 0, 0);
        for still in crate::allan::series_of(rec, None, None)? {
            let n = still.t_s.len();
            longest = longest.max(n);
            if n < MIN_ROWS {
                continue;
            }
            match rate {
                None => rate = Some(still.rate_hz),
                Some(first) if ((still.rate_hz - first) / first).abs() > EVEN => {
                    return Err(NoiseFromError::Rates {
                        first_hz: first,
                        other_hz: still.rate_hz,
                    })
                }
                Some(_) => {}
            }
            let failed = |channel: Channel| {
                let stretch = still.name.clone();
                move |source| NoiseFromError::Noise {
                    stretch,
                    channel,
                    source,
                }
            };
            let h = DMatrix::from_fn(n, 2, |t, j| {
                if j == 0 {
                    1.0
                } else {
                    t as f64 / n as f64 - 0.5
                }
            });
            let design = std::sync::Arc::new(
                SlowDesign::new(&h, &vec![1.0; n]).map_err(failed(Channel::U))?,
            );
            let gram = h
                .tr_mul(&h)
                .try_inverse()
                .ok_or(NoiseError::Singular)
                .map_err(failed(Channel::U))?;
            for ((ch, list), series) in Channel::ALL
                .into_iter()
                .zip(&mut parts)
                .zip(&still.channels)
            {
                let y = nalgebra::DVector::from_column_slice(&series.y);
                let resid = &y - &h * (&gram * h.tr_mul(&y));
                let flags = noise::clipped(&series.y);
                let ar = NoiseModel::estimate(resid.as_slice(), &flags)
                    .and_then(|m| m.rescaled(&h))
                    .map_err(failed(ch))?;
                list.push(StillPart {
                    design: design.clone(),
                    resid: resid.as_slice().to_vec(),
                    ar,
                });
            }
            rows += n;
        }
        let Some(rate_hz) = rate else {
            return Err(NoiseFromError::TooShort { longest });
        };
        Ok(NoiseFrom {
            source: rec.source.clone(),
            units: rec.meta.units.clone(),
            row_interval_s: 1.0 / rate_hz,
            rows,
            parts,
        })
    }

    /// What the JSON and the terminal name.
    pub fn summary(&self) -> StillSource {
        StillSource {
            file: self.source.clone(),
            rows: self.rows,
            row_interval_s: self.row_interval_s,
        }
    }

    /// Whether these still data fit a recording in `units` whose held groups' rows are
    /// `intervals` (condition, s) apart: the slow levels are per row.
    pub(crate) fn check(
        &self,
        units: &str,
        intervals: impl Iterator<Item = (Condition, f64)>,
    ) -> Result<(), CalibrateErrorKind> {
        let still_units = self.units.as_deref().unwrap_or("output units");
        if still_units != units {
            return Err(CalibrateErrorKind::NoiseFromUnits {
                file: self.source.clone(),
                still: still_units.into(),
                recording: units.into(),
            });
        }
        for (condition, dt) in intervals {
            if ((dt - self.row_interval_s) / dt).abs() > EVEN {
                return Err(CalibrateErrorKind::NoiseFromInterval {
                    file: self.source.clone(),
                    still_s: self.row_interval_s,
                    condition,
                    recording_s: dt,
                });
            }
        }
        Ok(())
    }

    /// Channel `ch`'s still parts, for [`noise::estimate_pooled`].
    pub(crate) fn parts(&self, ch: Channel) -> impl Iterator<Item = SlowPart<'_>> {
        ch.of(&self.parts).iter().map(|p| SlowPart {
            design: &p.design,
            resid: &p.resid,
            ar: &p.ar,
        })
    }
}
