//! The rotacal application over the calibration engine ([`rotacal_engine`], whose modules
//! are re-exported here: `rotacal::calibrate` is `rotacal_engine::calibrate`).
//! docs/architecture.md. In the order the data passes through them:
//!
//! - [`link`]: the connection to a device (Bluetooth LE, or the device logic simulated);
//! - [`record`]: driving a device through a session and writing its recording, with gap
//!   backfill, reconnection and the raw capture;
//! - the engine: [`recording`], [`fit`], [`verify`], [`calibrate`], [`correct`],
//!   [`simulate`], [`discrepancy`], [`allan`];
//! - [`report`]: the report folders with plots (calibration and discrepancy);
//! - [`demo`]: the main job without hardware, wiring the rest together;
//! - [`output`]: writing to the terminal; [`BUILD`]: this build, for the traceability
//!   block of every output ([`trace`]).
pub use rotacal_engine::{
    allan, atomic, calibrate, correct, discrepancy, fit, recording, reference, simulate, trace,
    verify,
};

/// This build of rotacal: its version, and the commit the build script read.
pub const BUILD: trace::Build = trace::Build {
    version: env!("CARGO_PKG_VERSION"),
    commit: env!("ROTACAL_COMMIT"),
};

pub mod check_board;
pub mod demo;
pub mod link;
pub mod output;
pub mod record;
pub mod report;
