//! allantools `ci.confidence_interval_noiseID` for `oadev` of freq data, ported literally:
//! Riley's lag-1 ACF noise id (EFTF 2004), Greenhall & Riley's EDF (PTTI 2003), and the χ²
//! interval of NIST SP 1065 eq. 45.

use statrs::distribution::{ChiSquared, ContinuousCDF};
use statrs::function::gamma::ln_gamma;

use super::pairwise_sum;

/// The 1σ coverage, erf(1/√2), as allantools' `ONE_SIGMA_CI`.
pub const ONE_SIGMA_CI: f64 = 0.682_689_492_137_085_9;

/// Fewest blocks of m the noise id works with (allantools raises below).
const MIN_BLOCKS: usize = 30;

/// A point's 1σ interval and what it rests on.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Interval {
    /// Lower end, series units.
    pub lo: f64,
    /// Upper end, series units.
    pub hi: f64,
    /// Power-law noise id α (S_y ∝ f^α): 0 white, −1 flicker, −2 random walk.
    pub alpha: i32,
    /// Greenhall's equivalent degrees of freedom.
    pub edf: f64,
}

/// The interval of `adev` at factor `m` for freq samples `y`, as allantools computes it,
/// or `None` where allantools raises (fewer than 30 blocks, or no Greenhall case).
pub(crate) fn interval_of(y: &[f64], adev: f64, m: usize) -> Option<Interval> {
    let alpha = noise_id(y, m)?;
    let edf = edf_greenhall(alpha, m, y.len())?;
    let (lo, hi) = confidence_interval(adev, edf, ONE_SIGMA_CI)?;
    Some(Interval { lo, hi, alpha, edf })
}

/// Riley's lag-1 ACF noise id of freq samples at factor `m` (allantools
/// `autocorr_noise_id(y, m, "freq", dmin=0, dmax=2)`): block means, detrended by a line,
/// differenced until ρ < 0.25 or d = 2; α = −round_half_even(2ρ) − 2d.
/// `None` with fewer than 30 blocks.
pub fn noise_id(y: &[f64], m: usize) -> Option<i32> {
    if m == 0 {
        return None;
    }
    let mut z: Vec<f64> = y
        .chunks_exact(m)
        .map(|c| pairwise_sum(c) / m as f64)
        .collect();
    if z.len() < MIN_BLOCKS {
        return None;
    }
    detrend_line(&mut z);
    let mut d = 0i32;
    loop {
        let r1 = lag1_acf(&z);
        let rho = r1 / (1.0 + r1);
        if rho < 0.25 || d >= 2 {
            // numpy's np.round rounds half to even.
            let a = -(2.0 * rho).round_ties_even() - 2.0 * f64::from(d);
            return Some(a as i32);
        }
        z = z.iter().zip(z.iter().skip(1)).map(|(a, b)| b - a).collect();
        d += 1;
    }
}

/// Remove the least-squares line through (i, z_i) (np.polyfit deg 1, in a centred form:
/// the same line up to rounding).
fn detrend_line(z: &mut [f64]) {
    let n = z.len() as f64;
    let t_mean = (n - 1.0) / 2.0;
    let z_mean = z.iter().sum::<f64>() / n;
    let (sxy, sxx) = z.iter().enumerate().fold((0.0, 0.0), |(sxy, sxx), (i, v)| {
        let t = i as f64 - t_mean;
        (sxy + t * (v - z_mean), sxx + t * t)
    });
    let slope = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    for (i, v) in z.iter_mut().enumerate() {
        *v -= z_mean + slope * (i as f64 - t_mean);
    }
}

/// Riley 2004 eq. 2 (allantools `lag1_acf`, sequential sums as there).
fn lag1_acf(x: &[f64]) -> f64 {
    let mu = pairwise_sum(x) / x.len() as f64;
    let a = x
        .iter()
        .zip(x.iter().skip(1))
        .fold(0.0, |a, (p, q)| a + (p - mu) * (q - mu));
    let b = x.iter().fold(0.0, |b, v| b + (v - mu).powi(2));
    a / b
}

/// Greenhall's sw (eq. 7).
fn sw(t: f64, alpha: i32) -> f64 {
    let ln_term = |p: i32| {
        if t == 0.0 {
            0.0
        } else {
            t.powi(p) * t.abs().ln()
        }
    };
    match alpha {
        2 => -t.abs(),
        1 => ln_term(2),
        0 => t.abs().powi(3),
        -1 => ln_term(4),
        -2 => t.abs().powi(5),
        -3 => ln_term(6),
        _ => t.abs().powi(7),
    }
}

/// Greenhall's sx (eq. 8); `f = None` is F = ∞.
fn sx(t: f64, f: Option<f64>, alpha: i32) -> f64 {
    match f {
        None => sw(t, alpha + 2),
        Some(f) => f * f * (2.0 * sw(t, alpha) - sw(t - 1.0 / f, alpha) - sw(t + 1.0 / f, alpha)),
    }
}

/// Greenhall's sz for d = 2 (eq. 9).
fn sz(t: f64, f: Option<f64>, alpha: i32) -> f64 {
    6.0 * sx(t, f, alpha) - 4.0 * sx(t - 1.0, f, alpha) - 4.0 * sx(t + 1.0, f, alpha)
        + sx(t - 2.0, f, alpha)
        + sx(t + 2.0, f, alpha)
}

/// Greenhall's basic sum (eq. 10).
fn basic_sum(j: f64, big_m: f64, s: f64, f: Option<f64>, alpha: i32) -> f64 {
    let first = sz(0.0, f, alpha).powi(2);
    let second = (1.0 - j / big_m) * sz(j / s, f, alpha).powi(2);
    let third = (1..j as i64).fold(0.0, |acc, jj| {
        let jj = jj as f64;
        acc + 2.0 * (1.0 - jj / big_m) * sz(jj / s, f, alpha).powi(2)
    });
    first + second + third
}

/// Greenhall & Riley's EDF of the overlapping Allan variance (d = 2, F = S = m) at factor
/// `m` for `len` freq samples, as allantools `edf_greenhall(alpha, 2, m, N=len,
/// overlapping=True, modified=False)` (N the number of freq samples, as there).
/// `None` where allantools raises: α + 4 ≤ 1, α outside −4…2, α = 2 with ⌈r⌉ ≤ 2.
pub fn edf_greenhall(alpha: i32, m: usize, len: usize) -> Option<f64> {
    if !(-4..=2).contains(&alpha) || alpha + 4 <= 1 || m == 0 {
        return None;
    }
    const J_MAX: f64 = 100.0;
    let mf = m as f64;
    let big_l = 1.0 + 2.0 * mf;
    let big_m = 1.0 + (mf * (len as f64 - big_l) / mf).floor();
    let j = big_m.min(3.0 * mf);
    let r = big_m / mf;
    let inv = match alpha {
        a if a <= 0 => {
            if j <= J_MAX {
                let fp = (mf * 3.0 <= J_MAX).then_some(mf);
                basic_sum(j, big_m, mf, fp, a) / (sz(0.0, fp, a).powi(2) * big_m)
            } else if r > 3.0 {
                let (a0, a1) = match a {
                    0 => (2.0 / 3.0, 1.0 / 3.0),
                    -1 => (0.852, 0.375),
                    -2 => (1.079, 0.368),
                    _ => return None,
                };
                (a0 - a1 / r) / r
            } else {
                let mp = J_MAX / r;
                basic_sum(J_MAX, J_MAX, mp, None, a) / (sz(0.0, None, a).powi(2) * J_MAX)
            }
        }
        1 => {
            let (b0, b1) = (15.23, 12.0);
            if j <= J_MAX {
                basic_sum(j, big_m, mf, Some(mf), 1) / (sz(0.0, Some(mf), 1).powi(2) * big_m)
            } else if r > 3.0 {
                (790.0 - 410.0 / r) / ((b0 + b1 * mf.ln()).powi(2) * r)
            } else {
                let mp = J_MAX / r;
                basic_sum(J_MAX, J_MAX, mp, Some(mp), 1) / ((b0 + b1 * mf.ln()).powi(2) * J_MAX)
            }
        }
        _ => {
            if r.ceil() <= 2.0 {
                return None;
            }
            (35.0 / 18.0 - 1.0 / r) / big_m
        }
    };
    let edf = 1.0 / inv;
    (edf.is_finite() && edf > 0.0).then_some(edf)
}

/// The χ² quantile: statrs' `inverse_cdf`, then Newton steps on its CDF with the density
/// taken in log form. statrs 0.18's `inverse_cdf` alone is off by up to 1e-3 relative at
/// edf ≈ 300 (its `pdf` overflows to ∞ there, which stops its Newton steps); this brings
/// it to scipy's within 1e-12.
pub fn chi2_quantile(p: f64, dof: f64) -> Option<f64> {
    let dist = ChiSquared::new(dof).ok()?;
    let half = dof / 2.0;
    let ln_norm = half * std::f64::consts::LN_2 + ln_gamma(half);
    let density = |x: f64| ((half - 1.0) * x.ln() - x / 2.0 - ln_norm).exp();
    let mut x = dist.inverse_cdf(p);
    for _ in 0..20 {
        let dens = density(x);
        if !(dens > 0.0 && x.is_finite()) {
            break;
        }
        let step = (dist.cdf(x) - p) / dens;
        let next = (x - step).max(x / 2.0);
        if (next - x).abs() <= 1e-15 * x.abs() {
            x = next;
            break;
        }
        x = next;
    }
    (x.is_finite() && x > 0.0).then_some(x)
}

/// The interval of deviation `dev` with `edf` degrees of freedom at coverage `ci` (NIST
/// SP 1065 eq. 45; allantools `confidence_interval`).
pub fn confidence_interval(dev: f64, edf: f64, ci: f64) -> Option<(f64, f64)> {
    let p_lo = ci.abs().min((ci - 1.0).abs()) / 2.0;
    let p_hi = 1.0 - p_lo;
    let chi_lo = chi2_quantile(p_lo, edf)?;
    let chi_hi = chi2_quantile(p_hi, edf)?;
    let var = dev * dev;
    Some(((edf * var / chi_hi).sqrt(), (edf * var / chi_lo).sqrt()))
}
