//! The rotacal application: recording a device, reports with plots, the demo and the
//! command line, over the calibration engine ([`rotacal_engine`], re-exported here so that
//! `rotacal::calibrate_recording` and the like keep their paths). docs/architecture.md.
//!
//! - [`link`], [`record`], [`capture`]: recording a device over BLE (or a simulated one)
//!   with gap backfill and reconnection;
//! - [`report`]: the report folder with plots; [`discrepancy::report`] its discrepancy
//!   counterpart;
//! - [`demo`]: the main job without hardware, wiring the rest together;
//! - [`output`]: writing to the terminal.
pub use rotacal_engine::{
    acquire, apply, batch, budget, calibrate, calibrate_recording, calibration_file, correction,
    crosscheck, export, fitcheck, geometry, harmonics, import, noise, orientation, recording,
    reference, session_check, simulate,
};

pub mod capture;
pub mod demo;
pub mod link;
pub mod output;
pub mod record;
pub mod report;

/// The discrepancy workflow ([`rotacal_engine::discrepancy`]) and its report with plots.
pub mod discrepancy {
    pub use rotacal_engine::discrepancy::*;
    pub mod report;
}
