//! The engine's integration tests, one binary (`cargo test --release -p rotacal-engine
//! --test engine`; one module: `... --test engine -- poses::`). They use only the engine's
//! public API, so they build without the application and its device crates (tokio,
//! btleplug, dbus, plotters, clap, indicatif): `scripts/test-all` checks that with
//! `cargo tree`. One binary links once.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

mod allan;
mod budget;
mod columns;
mod config;
mod poses;
mod reader;
mod slow_noise;
