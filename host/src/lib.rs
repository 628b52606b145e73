//! The rotacal host library. The `rotacal` binary is a thin command-line layer over it.
//!
//! - [`batch`]: f64 reference fits over a whole record (nalgebra QR), including the
//!   iterated four-parameter fit of IEEE 1057 that estimates the rotation rate.
//! - [`fitcheck`]: checks the device's f32 streaming fit (run on the emulated Cortex-M4F)
//!   against the f64 batch fit of the same samples.
//! - [`session_check`]: checks the device logic's packets from the emulated Cortex-M4F.
//! - [`demo`]: the main job without hardware.
//! - [`link`], [`record`], [`capture`]: recording a device over BLE (or a simulated one)
//!   with gap backfill and reconnection; [`acquire`] turns its packets into files.
//! - [`simulate`]: the forward model of the experiment that writes recordings.
pub mod acquire;
pub mod apply;
pub mod batch;
pub mod budget;
pub mod calibrate;
pub mod calibrate_recording;
pub mod calibration_file;
pub mod capture;
pub mod correction;
pub mod crosscheck;
pub mod demo;
pub mod discrepancy;
pub mod export;
pub mod fitcheck;
pub mod geometry;
pub mod import;
pub mod link;
pub mod noise;
pub mod orientation;
pub mod output;
pub mod record;
pub mod recording;
pub mod report;
pub mod session_check;
pub mod simulate;
