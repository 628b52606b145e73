//! Using a calibration: [`apply`] it to a recording's readings (acceleration in m/s², with
//! its uncertainty), or [`export`] its correction as constants to embed in firmware. Both
//! read the calibration JSON ([`crate::calibrate::json`]).

pub mod apply;
pub mod export;
