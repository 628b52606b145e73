//! The host's integration tests, one binary (`cargo test --release -p rotacal --test suite`;
//! one module: `... --test suite -- coverage::`). One binary links once: nineteen linked
//! separately took most of a fresh clone's test time.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

mod allan_cli;
mod apply;
mod averaging;
mod bluez;
mod boots;
mod budget;
mod calibrate_cli;
mod check_board;
mod common;
mod coverage;
mod crosscheck_cli;
mod demo;
mod discrepancy;
mod fit_vs_batch;
mod free_method;
mod import;
mod imucal;
mod intrinsic;
mod malformed;
mod mounting;
mod mtu;
mod noise;
mod orientation;
mod readme;
mod record;
mod recording;
mod report;
mod self_contained;
mod session_check;
mod simulator;
mod slow_noise;
mod static_method;
mod streaming;
mod structure_check;
mod traceability;
mod verdict;
