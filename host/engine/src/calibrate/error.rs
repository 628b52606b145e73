//! Why a calibration failed: [`CalibrateError`] names the file and, where it applies, the
//! line; its [`CalibrateErrorKind`] says what, with the condition, channel or rate as
//! fields. A broken invariant of the engine is an [`CalibrateErrorKind::Internal`], not a
//! problem of the user's data.

use crate::calibrate::correction::CorrectionError;
use crate::calibrate::free::FreeError;
use crate::calibrate::methods::StaticError;
use crate::calibrate::poses::PoseError;
use crate::calibrate::still::StillError;
use crate::fit::batch::BatchError;
use crate::fit::moments::SingularWide;
use crate::fit::noise::NoiseError;
use crate::recording::{Method, Recording, RecordingErrorKind};
use rotacal_shared::intrinsic::IntrinsicError;
use rotacal_shared::{Channel, Condition, FitError};

/// A calibration failure, naming the file and, where it applies, the line.
#[derive(Debug, thiserror::Error)]
#[error("{source_name}{}: {kind}", line.map(|l| format!(":{l}")).unwrap_or_default())]
pub struct CalibrateError {
    /// The recording.
    pub source_name: String,
    /// First line of the data concerned.
    pub line: Option<u64>,
    /// What is wrong (boxed: some kinds carry a whole detection summary).
    pub kind: Box<CalibrateErrorKind>,
}

/// What is wrong.
#[derive(Debug, thiserror::Error)]
pub enum CalibrateErrorKind {
    /// Neither the command line nor the file gives local gravity.
    #[error("local gravity unknown: give --g-loc or a '# g_loc=' line")]
    NoGravity,
    /// Local gravity that is not a positive number.
    #[error("g_loc {0} is not a positive number")]
    BadGravity(f64),
    /// A stated standard uncertainty that is negative or not finite.
    #[error("{option} {value} is not a standard uncertainty (a finite number ≥ 0)")]
    BadUncertainty {
        /// The command-line option that gives it.
        option: &'static str,
        /// Its value.
        value: f64,
    },
    /// A rotation file whose rate neither the command line, the file nor a column gives.
    #[error("rotation rate unknown: give --rate-hz, a '# rate_hz=' line or a rate_hz column")]
    NoRate,
    /// A rate without one of the three conditions.
    #[error("condition {} missing at {rate_hz} Hz", condition.letter())]
    MissingCondition {
        /// The condition missing.
        condition: Condition,
        /// The nominal rate, Hz.
        rate_hz: f64,
    },
    /// A file of poses or a free recording where conditions are needed.
    #[error("{0}")]
    NeedsConditions(RecordingErrorKind),
    /// Rotation without timestamps.
    #[error("rotation needs a t_s column")]
    NoTime,
    /// Angle steps without their angles.
    #[error("static calibration needs an angle_deg column")]
    NoAngle,
    /// Still poses to find without timestamps or a sample rate.
    #[error("finding still poses needs t_s or '# sample_rate_hz='")]
    NoClock,
    /// A row's conversions out of the range the fits take.
    #[error("{0}")]
    Row(&'static str),
    /// A rate no phase step represents.
    #[error("rotation rate {0} Hz is not usable")]
    UnusableRate(f64),
    /// The IEEE 1057 fit gave a rate no phase step represents.
    #[error("fitted rate unusable")]
    UnusableFittedRate,
    /// A condition's fit failed.
    #[error("condition {}: {source}", condition.letter())]
    Group {
        /// The condition.
        condition: Condition,
        /// Why.
        source: GroupError,
    },
    /// `--noise-from` for a method that has no slow levels to pool it into.
    #[error("--noise-from applies to rotation recordings only; this one is {0}")]
    NoiseFromMethod(Method),
    /// `--noise-from`: the still recording is in other units than the recording.
    #[error(
        "--noise-from {file}: its units are {still}, the recording's {recording}: record the \
         still data in the same units"
    )]
    NoiseFromUnits {
        /// The still recording.
        file: String,
        /// Its units.
        still: String,
        /// The recording's.
        recording: String,
    },
    /// `--noise-from`: the still recording's rows are not as far apart as the recording's.
    #[error(
        "--noise-from {file}: its rows are {still_s:.6} s apart, condition {}'s \
         {recording_s:.6} s: record the still data at the same rate",
        condition.letter()
    )]
    NoiseFromInterval {
        /// The still recording.
        file: String,
        /// Its row interval, s.
        still_s: f64,
        /// The condition whose rows differ.
        condition: Condition,
        /// Their interval, s.
        recording_s: f64,
    },
    /// A rate's properties, budget or correction could not be computed.
    #[error("at {rate_hz} Hz: {source}")]
    Rate {
        /// The nominal rate, Hz.
        rate_hz: f64,
        /// Why.
        source: RateError,
    },
    /// The Monte Carlo propagation failed (at a rate, for rotation).
    #[error("Monte Carlo{}: {cause}", rate_hz.map(|r| format!(" at {r} Hz")).unwrap_or_default())]
    MonteCarlo {
        /// The nominal rate, Hz (rotation).
        rate_hz: Option<f64>,
        /// Why.
        cause: IntrinsicError,
    },
    /// Several rates whose offsets against ω² no line fits.
    #[error(
        "condition {}, channel {}: the offsets against ω² cannot be fitted",
        condition.letter(),
        channel.letter()
    )]
    OffsetsAtRest {
        /// The condition.
        condition: Condition,
        /// The channel.
        channel: Channel,
    },
    /// The intrinsic properties of the free fit's G.
    #[error("intrinsic properties: {0}")]
    Intrinsic(IntrinsicError),
    /// `--monte-carlo` with method free.
    #[error("--monte-carlo is not available for method free")]
    MonteCarloFree,
    /// The static methods' fit failed.
    #[error(transparent)]
    Static(#[from] StaticError),
    /// A pose's direction is unusable.
    #[error(transparent)]
    Pose(#[from] PoseError),
    /// The static methods' budget failed.
    #[error("{0}")]
    StaticBudget(IntrinsicError),
    /// No correction could be made.
    #[error(transparent)]
    Correction(#[from] CorrectionError),
    /// Still intervals could not be found in a stretch (`at` names it, or is empty).
    #[error("{at}{source}")]
    Still {
        /// "condition x: " or empty.
        at: String,
        /// Why.
        source: StillError,
    },
    /// The free fit failed; `detections` says what was found.
    #[error("{source}.\n{detections}")]
    Free {
        /// Why.
        source: FreeError,
        /// The still-interval detection in a few lines.
        detections: String,
    },
    /// `--slow-noise` on a free recording with too few poses to see the scatter between
    /// placements that slow noise gives their means.
    #[error(
        "--slow-noise: {kept} poses kept, and a free calibration under slow noise needs at \
         least {}: flicker and bias wander make the poses' means scatter beyond their own \
         noise, and that scatter is estimated from the fit's P − 9 = {} residual degrees of \
         freedom, too few to tell it from none (docs/uncertainty.md, \"Free poses under slow \
         noise\", gives the coverage measured with fewer). Record more poses, or calibrate \
         without --slow-noise, whose U does not count that scatter beyond what the poses \
         show.\n{detections}",
        super::free_method::SLOW_MIN_POSES,
        kept.saturating_sub(9)
    )]
    FreeSlowPoses {
        /// Poses kept by the fit.
        kept: usize,
        /// The still-interval detection in a few lines.
        detections: String,
    },
    /// A streamed file's rows changed between two readings.
    #[error("the file changed while it was read")]
    FileChanged,
    /// An invariant of the engine failed: a bug in rotacal, not a problem of the data.
    #[error("internal: {0} (a bug in rotacal; please report it)")]
    Internal(&'static str),
}

/// Why one condition's fit failed.
#[derive(Debug, thiserror::Error)]
pub enum GroupError {
    /// The sine fit.
    #[error("{0}")]
    Fit(FitError),
    /// The IEEE 1057 rate fit.
    #[error("rate fit: {0}")]
    RateFit(BatchError),
    /// A sine fit from a streamed record's sums.
    #[error(transparent)]
    Sums(#[from] BatchError),
    /// The widened fit from a streamed record's sums.
    #[error(transparent)]
    Wide(#[from] SingularWide),
    /// The noise model of the residuals.
    #[error(transparent)]
    Noise(#[from] NoiseError),
    /// A refit at a rate no phase step represents.
    #[error("rate {0} Hz unusable")]
    Rate(f64),
    /// The IEEE 1057 fit gave a rate no phase step represents.
    #[error("fitted rate unusable")]
    FittedRate,
    /// A streamed record's rate moved beyond its sums' reach even after a correcting pass.
    #[error(
        "the rate fit moved {reach:.2e} rad over the record after a correcting pass: the rate \
         is not steady enough to fit"
    )]
    Unsteady {
        /// How far, rad over the record.
        reach: f64,
    },
    /// A refit beyond a streamed record's sums' reach.
    #[error(
        "the refit at {rate_hz} Hz is {reach:.2e} rad over the record from the streamed sums' \
         rate, beyond their reach ({limit})"
    )]
    OutOfReach {
        /// The rate, Hz.
        rate_hz: f64,
        /// Its distance from the sums' rate, rad over the record.
        reach: f64,
        /// The sums' reach, rad over the record.
        limit: f64,
    },
    /// More rows than one fit counts.
    #[error("too many rows for one fit")]
    TooManyRows,
}

impl GroupError {
    /// This failure of the fit of `condition` in `rec`, whose rows start at `line`.
    pub(crate) fn of(
        self,
        rec: &Recording,
        line: Option<u64>,
        condition: Condition,
    ) -> CalibrateError {
        err(
            rec,
            line,
            CalibrateErrorKind::Group {
                condition,
                source: self,
            },
        )
    }
}

impl From<FitError> for GroupError {
    fn from(e: FitError) -> Self {
        GroupError::Fit(e)
    }
}

/// Why a rate's properties, budget or correction could not be computed.
#[derive(Debug, thiserror::Error)]
pub enum RateError {
    /// The intrinsic properties.
    #[error("{0}")]
    Intrinsic(IntrinsicError),
    /// A refit the budget needs.
    #[error(transparent)]
    Refit(#[from] GroupError),
    /// The correction.
    #[error(transparent)]
    Correction(#[from] CorrectionError),
}

impl From<IntrinsicError> for RateError {
    fn from(e: IntrinsicError) -> Self {
        RateError::Intrinsic(e)
    }
}

/// The error `kind` of recording `rec` at `line`.
pub(crate) fn err(
    rec: &Recording,
    line: Option<u64>,
    kind: impl Into<CalibrateErrorKind>,
) -> CalibrateError {
    CalibrateError {
        source_name: rec.source.clone(),
        line,
        kind: Box::new(kind.into()),
    }
}
