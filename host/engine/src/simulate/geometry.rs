//! Rotations of the device on the platter (mounting misalignment).

/// The rotation by `deg` degrees about `axis` (any non-zero length), by Rodrigues'
/// formula.
pub fn rotation(axis: [f64; 3], deg: f64) -> [[f64; 3]; 3] {
    let n = (axis[0].powi(2) + axis[1].powi(2) + axis[2].powi(2)).sqrt();
    let [x, y, z] = axis.map(|v| v / n);
    let (s, c) = deg.to_radians().sin_cos();
    let t = 1.0 - c;
    [
        [c + x * x * t, x * y * t - z * s, x * z * t + y * s],
        [y * x * t + z * s, c + y * y * t, y * z * t - x * s],
        [z * x * t - y * s, z * y * t + x * s, c + z * z * t],
    ]
}

/// The sensitivity matrix seen in the platter frame when a device with matrix `s` (rows
/// S_j in its own frame) is mounted rotated by `r`: a platter vector p reaches the device
/// as Rᵀp, so S' = S·Rᵀ. Intrinsic properties are unchanged.
pub fn mounted(s: &[[f64; 3]; 3], r: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    s.map(|row| r.map(|ra| row.iter().zip(ra).map(|(x, y)| x * y).sum()))
}

/// A sensitivity matrix with the given intrinsic properties, in the device's own frame:
/// u along x, v in the xy plane (docs/method.md §1; any rotation of it has the same
/// intrinsic properties).
pub fn sensitivity_from_intrinsic(s: [f64; 3], angles_deg: [f64; 3]) -> [[f64; 3]; 3] {
    let [uv, vw, wu] = angles_deg.map(f64::to_radians);
    let u = [1.0, 0.0, 0.0];
    let v = [uv.cos(), uv.sin(), 0.0];
    let wx = wu.cos();
    let wy = (vw.cos() - uv.cos() * wu.cos()) / uv.sin();
    let w = [wx, wy, (1.0 - wx * wx - wy * wy).sqrt()];
    [
        u.map(|c| c * s[0]),
        v.map(|c| c * s[1]),
        w.map(|c| c * s[2]),
    ]
}
