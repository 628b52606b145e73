//! rotacal's calibration engine: everything from a recording to a calibration with its
//! uncertainty, with no device, Bluetooth or plotting dependency (docs/architecture.md).
//! The modules, in the order the data passes through them; each uses only those above it:
//!
//! - [`recording`]: the recording CSV (docs/formats.md), from the device's packets
//!   ([`recording::from_device`]) or other tools' files ([`recording::import`]);
//! - [`fit`]: least-squares fits of a record, its noise model, residual harmonics;
//! - [`verify`]: the device's own fits against f64 fits of the same samples;
//! - [`calibrate`]: a recording to intrinsic properties with their uncertainty budget, and
//!   the calibration JSON;
//! - [`correct`]: applying and exporting a calibration;
//! - [`simulate`]: the model of the experiment, which writes recordings; [`reference`]:
//!   the paper values it and the tests take as truth;
//! - [`discrepancy`]: where model and measurement disagree, and which effect is missing;
//! - [`allan`]: the overlapping Allan deviation of a still record, its intervals and the
//!   IEEE noise terms (docs/allan.md);
//! - [`atomic`]: writing an output file whole or not at all; [`trace`]: the traceability
//!   block of every output.
pub mod allan;
pub mod atomic;
pub mod calibrate;
pub mod correct;
pub mod discrepancy;
pub mod fit;
pub mod recording;
pub mod reference;
pub mod simulate;
pub mod trace;
pub mod verify;
