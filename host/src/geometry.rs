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
