//! What the structure scan ([`crate::fit::structure`]) finds in the generic fits, as the
//! verdict reports it, and the regressors it adds to them so that the noise model does not
//! take it in (docs/discrepancy.md, "The verdict").

use super::place::Place;
use serde::Serialize;
use std::fmt;

pub use crate::fit::structure::{harmonics, scan_max_p, step_by, StepTest};

/// What was found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Kind {
    /// The k-th harmonic of the table angle.
    Harmonic(usize),
    /// The level changes `tau_s` seconds into the group.
    Step {
        /// Seconds into the group.
        tau_s: f64,
        /// The scan's decorrelation Λ ([`crate::fit::structure::scan_max_p`]), with which
        /// the step is tested again under slow noise.
        lambda: f64,
    },
    /// The noise's sd differs between the group's halves.
    NoiseChange {
        /// One reading's noise sd in the first half, output units.
        first_sd: f64,
        /// The same in the second half.
        second_sd: f64,
    },
}

impl fmt::Display for Kind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Kind::Harmonic(k) => write!(f, "harmonic {k} of the table angle"),
            Kind::Step { tau_s, .. } => {
                write!(f, "a step in the level {tau_s:.1} s into the group")
            }
            Kind::NoiseChange {
                first_sd,
                second_sd,
            } => write!(
                f,
                "the noise's sd changes between the group's halves, {first_sd:.3} to {second_sd:.3}"
            ),
        }
    }
}

impl Serialize for Kind {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

/// Structure found in one group's channel.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Structure {
    /// Condition, rate and channel.
    pub at: Place,
    /// What.
    pub what: Kind,
    /// Amplitude of the harmonic or height of the step, output units.
    pub size: f64,
    /// Size over its standard error under the noise around it.
    pub z: f64,
    /// The chance that noise alone shows something as large anywhere among the tests made
    /// on the file (Bonferroni).
    pub p_value: f64,
}

/// A regressor the structure scan adds to a group's channel's generic fit
/// ([`super::structure`]), so that the noise model does not take in what it found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Extra {
    /// sin kωτ and cos kωτ.
    Harmonic(usize),
    /// 1 from this row on.
    Step(usize),
}

/// What the generic fits held beyond their fixed regressors, and their degrees of freedom.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Generic {
    /// Per group, per channel u, v, w: the regressors the structure scan added.
    pub extras: Vec<[Vec<Extra>; 3]>,
    /// What the scan found, as the verdict reports it.
    pub structure: Vec<Structure>,
    /// Σ over groups and channels of the whitened rows kept less the generic fit's
    /// coefficients: the χ² each generic fit has under its own noise model (the level is
    /// set so), against which a physical model's χ² shows its lack of fit.
    pub dof: f64,
    /// The generic fits' coefficients over all groups and channels.
    pub coefficients: usize,
}
