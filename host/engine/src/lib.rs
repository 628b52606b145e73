//! rotacal's calibration engine: everything from a recording to a calibration with its
//! uncertainty, with no device, Bluetooth or plotting dependency (docs/architecture.md).
//! The modules, in the order the data passes through them:
//!
//! - packets to files: [`acquire`] (device packets and fit reports into a recording);
//! - files: [`recording`] (the CSV contract, docs/formats.md), [`import`] (other tools'
//!   files), [`calibration_file`] (the calibration JSON);
//! - fits: [`batch`] (f64 least squares, IEEE 1057 rate fit), [`noise`] (the noise model
//!   of fit residuals), [`harmonics`] (residual harmonics);
//! - checks of the device's own fits: [`fitcheck`], [`crosscheck`], [`session_check`];
//! - calibration: [`orientation`] (the pose fit of S and O), [`calibrate`] (rotation and
//!   stepped methods), [`budget`] (the GUM budget), [`calibrate_recording`] (a recording
//!   to a calibration, the `calibrate` command's engine), [`geometry`] (rotations);
//! - using a calibration: [`correction`], [`apply`], [`export`];
//! - the model of the experiment: [`simulate`], [`reference`] (seed 000's values);
//! - where model and data disagree: [`discrepancy`].
pub mod acquire;
pub mod apply;
pub mod batch;
pub mod budget;
pub mod calibrate;
pub mod calibrate_recording;
pub mod calibration_file;
pub mod correction;
pub mod crosscheck;
pub mod discrepancy;
pub mod export;
pub mod fitcheck;
pub mod geometry;
pub mod harmonics;
pub mod import;
pub mod noise;
pub mod orientation;
pub mod recording;
pub mod reference;
pub mod session_check;
pub mod simulate;
