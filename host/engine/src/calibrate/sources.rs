//! The budget lines and helpers every method shares.

use super::budget::{Budget, Kind};
use super::json;
use nalgebra::SMatrix;
use rotacal_shared::intrinsic;

/// The diagonal of the six properties' covariance (`Intrinsic::cov`): their variances.
pub(super) fn variances6(cov: &[[f64; 6]; 6]) -> [f64; 6] {
    // nalgebra takes the arrays for columns: the transpose, whose diagonal is the same.
    SMatrix::<f64, 6, 6>::from(*cov).diagonal().into()
}

/// The six properties' values.
pub(super) fn values6(i: &intrinsic::Intrinsic) -> [f64; 6] {
    let [s0, s1, s2] = i.sensitivity.map(|e| e.value);
    let [a0, a1, a2] = i.angle_deg.map(|e| e.value);
    [s0, s1, s2, a0, a1, a2]
}

/// An empty budget for the six properties, and the offsets too when `offsets`.
pub(super) fn new_budget(units: &str, offsets: bool) -> Budget {
    let su = format!("{units} per m/s^2");
    let mut unit_of = vec![su.clone(), su.clone(), su];
    unit_of.extend(["deg", "deg", "deg"].map(String::from));
    if offsets {
        unit_of.extend([units, units, units].map(String::from));
        Budget::new(&json::PROPERTY_NAMES_WITH_OFFSETS, &unit_of)
    } else {
        Budget::new(&json::PROPERTY_NAMES, &unit_of)
    }
}

/// The budget's g_loc line: a sensitivity of −s/g_loc per sensitivity, or, when its
/// uncertainty is not given, a line that says so (and a note the terminal warns with).
pub(super) fn gravity_source(b: &mut Budget, g: f64, u_g_loc: Option<f64>, cg: &[f64]) {
    match u_g_loc {
        Some(u) => b.scalar(
            "g_loc",
            Kind::B,
            format!("local gravity g_loc = {g} m/s²: every sensitivity is ∝ 1/g_loc, the angles and offsets do not depend on it"),
            (u, "m/s^2"),
            cg,
            None,
        ),
        None => {
            b.scalar(
                "g_loc",
                Kind::B,
                format!("local gravity g_loc = {g} m/s²: its uncertainty was NOT GIVEN (--u-g-loc or '# u_g_loc='), so it is taken as exact: a gravity model or map gives about 1e-5 relative, a formula from latitude and height about 1e-4, an absolute gravimeter 1e-8"),
                (0.0, "m/s^2"),
                cg,
                None,
            );
            b.notes.push(
                "g_loc's uncertainty was not given: the budget has no term for it".into(),
            );
        }
    }
}
