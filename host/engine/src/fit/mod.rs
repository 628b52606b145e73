//! Fits of a record, in f64 on the host: [`batch`] (least squares by QR, the IEEE 1057
//! rate fit: the reference the device's streaming fit is checked against), [`noise`] (the
//! AR noise model of a fit's residuals and the coefficients' covariance under it) and
//! [`harmonics`] (what each harmonic of the table angle leaves in the residuals),
//! [`structure`] (harmonics and steps in the residuals that are not noise) and
//! [`segments`] (a condition recorded across restarts of the device's clock, joined).

pub mod batch;
pub mod block;
pub mod harmonics;
pub mod moments;
pub mod noise;
pub mod segments;
pub mod structure;
