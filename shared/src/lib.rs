//! What the rotacal device and host both run, in `no_std` with no allocator.
//!
//! The data path is `time` (device ticks, extended to 64 bits) → `phase` (exact integer
//! rotation phase and its sine/cosine) → `fit` (streaming least-squares sine fit).
//! `synth` makes bit-reproducible test records, and `selftest` holds test cases that run
//! both on the host and on an emulated Cortex-M4F, so that the device's f32 arithmetic is
//! tested where it runs.
//!
//! Everything here is generic over [`Real`] (`f32` on the device, `f64` on the host).
#![no_std]

pub mod condition;
pub mod device;
pub mod dword;
pub mod fit;
pub mod intrinsic;
pub mod packet;
pub mod phase;
pub mod real;
#[cfg(feature = "selftest")]
pub mod selftest;
pub mod synth;
pub mod time;

pub use condition::{Channel, Condition};
pub use dword::DoubleWord;
pub use fit::{ChannelFit, FitConfig, FitError, FitResult, Model, Param, SineFit, MAX_PARAMS};
pub use phase::{Phase, PhaseStep};
pub use real::Real;
pub use time::{Aperture, TickExtender, TickRate, Ticks, MAX_CONVERSIONS};
