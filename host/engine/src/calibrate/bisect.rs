//! Bisection of a decreasing function, shared by the calibrations' one-dimensional solves.

/// Bisection of the decreasing `f(x) = target` from the bracket `(lo, hi)` (f(lo) > target
/// ≥ f(hi)): the last bracket, after at most `steps` halvings, once it no longer narrows,
/// or once `hi` is below `floor`.
pub(crate) fn bracket(
    f: &impl Fn(f64) -> f64,
    target: f64,
    (mut lo, mut hi): (f64, f64),
    steps: usize,
    floor: f64,
) -> (f64, f64) {
    for _ in 0..steps {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi || hi < floor {
            break;
        }
        if f(mid) > target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    (lo, hi)
}
