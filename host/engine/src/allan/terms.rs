//! White, flicker and random-walk terms fitted to the octave Allan variances by iterated
//! weighted least squares (docs/allan.md).
//!
//! σ²(m) = θ_w·g_w(m) + θ_f·g_f(m) + θ_rw·g_rw(m), with the exact expected Allan variance of
//! each discrete term per unit parameter: white iid of variance θ_w (g = 1/m), Kasdin flicker
//! of innovation variance θ_f ([`super::powerlaw::allan_variance`] of D(k) = (4/π)Σ_{j≤k} 1/(2j−1)), and
//! a random walk of increment variance θ_rw (g = (2m² + 1)/(6m)). Weights EDF/(2·model²):
//! Var(σ̂²) = 2σ⁴/EDF; the EDF is Greenhall's for the term that dominates the model at m.

use nalgebra::{DMatrix, DVector};

use super::powerlaw::FlickerIncrements;
use super::{ci::edf_greenhall, AllanError, Point};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// √(2 ln 2 / π): the flicker floor of σ over B (IEEE 952 Annex C).
pub const FLOOR_OVER_B: f64 = 0.664_282_154_307_551_4;

/// IRLS iterations at most; the weights settle in a few.
const MAX_ITER: usize = 50;

/// Which power-law term.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TermKind {
    /// White (α = 0): velocity random walk N.
    White,
    /// Flicker (α = −1): bias instability B.
    Flicker,
    /// Random walk (α = −2): acceleration random walk K.
    RandomWalk,
}

impl TermKind {
    /// The three, in fit order.
    pub const ALL: [TermKind; 3] = [TermKind::White, TermKind::Flicker, TermKind::RandomWalk];

    /// Power-law exponent α of the one-sided PSD S_y(f) ∝ f^α.
    pub const fn alpha(self) -> i32 {
        match self {
            TermKind::White => 0,
            TermKind::Flicker => -1,
            TermKind::RandomWalk => -2,
        }
    }
}

/// One fitted term, in the series' units u (µg when the recording allows it).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Term {
    /// Which term.
    pub kind: TermKind,
    /// False when the fit set it to zero (its unconstrained estimate was negative).
    pub resolved: bool,
    /// The discrete parameter: white variance per sample σ_s² (u²), flicker innovation
    /// variance Q (u²), random-walk increment variance q (u²).
    pub theta_u2: f64,
    /// Its standard error (`None` when not resolved).
    pub theta_se_u2: Option<f64>,
    /// IEEE coefficient: N (u·√s = u/√Hz two-sided), B (u), K (u/√s).
    pub ieee: f64,
    /// Its standard error.
    pub ieee_se: Option<f64>,
    /// One-sided PSD coefficient h0 (u²/Hz), h₋₁ (u²), h₋₂ (u²·Hz).
    pub h: f64,
    /// Its standard error.
    pub h_se: Option<f64>,
}

/// The fit.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Fit {
    /// White, flicker, random walk.
    pub terms: Vec<Term>,
    /// Octave points used.
    pub points: usize,
    /// IRLS iterations done.
    pub iterations: usize,
    /// Σ w·(σ̂² − model)² / (points − terms): about 1 when model and EDF weights fit (the
    /// points are not quite independent, so it is indicative).
    pub reduced_chi2: f64,
    /// The flicker floor √(2 ln2/π)·B, u.
    pub flicker_floor: f64,
}

impl Fit {
    /// The model's Allan variance at factor m, u².
    pub fn avar(&self, m: usize) -> f64 {
        self.terms
            .iter()
            .map(|t| t.theta_u2 * expected_avar(t.kind, m))
            .sum()
    }

    /// One term's Allan variance at factor m, u².
    pub fn term_avar(&self, kind: TermKind, m: usize) -> f64 {
        self.terms
            .iter()
            .filter(|t| t.kind == kind)
            .map(|t| t.theta_u2 * expected_avar(kind, m))
            .sum()
    }
}

/// Exact expected Allan variance at factor m (τ = m/fs) of the discrete term with unit
/// parameter (θ = 1).
pub fn expected_avar(kind: TermKind, m: usize) -> f64 {
    let mf = m as f64;
    match kind {
        TermKind::White => 1.0 / mf,
        TermKind::RandomWalk => (2.0 * mf * mf + 1.0) / (6.0 * mf),
        TermKind::Flicker => {
            super::powerlaw::allan_variance(m as u64, super::powerlaw::flicker_structure)
        }
    }
}

/// Replicates of the parametric bootstrap behind each term's standard error.
pub const BOOTSTRAP_REPLICATES: usize = 100;

/// The bootstrap's seed: the same file gives the same standard errors.
const BOOTSTRAP_SEED: u64 = 0xA11A_0952;

/// Fit the three terms to `points` (of a series of `len` samples at `rate_hz`).
///
/// Each term's standard error comes from a parametric bootstrap: [`BOOTSTRAP_REPLICATES`]
/// series of `len` samples drawn from the fitted terms (white, exact Kasdin flicker, random
/// walk), each through the same Allan deviation at the same factors and the same fit; the
/// standard deviation of their estimates. The weighted fit's own covariance treats the
/// octave points as independent, and they are not (neighbouring factors share the data):
/// over 40 records it understated the spread by 25–80 %.
pub fn fit_terms(points: &[Point], len: usize, rate_hz: f64) -> Result<Fit, AllanError> {
    let pts = fit_points(points, &[]);
    let est = estimate(&pts, len)?;
    let se = bootstrap_se(&est, &pts, len, rate_hz)?;
    let terms: Vec<Term> = TermKind::ALL
        .iter()
        .zip(est.theta)
        .zip(est.active)
        .zip(se)
        .map(|(((kind, th), on), se)| term(*kind, th, se.filter(|_| on), rate_hz))
        .collect();
    let flicker_floor = terms
        .iter()
        .find(|t| t.kind == TermKind::Flicker)
        .map_or(0.0, |t| FLOOR_OVER_B * t.ieee);
    Ok(Fit {
        terms,
        points: pts.len(),
        iterations: est.iterations,
        reduced_chi2: est.reduced_chi2,
        flicker_floor,
    })
}

/// One octave point as the fit uses it: its factor, σ̂², and each term's expected Allan
/// variance per unit parameter there (white, flicker, random walk).
#[derive(Clone, Copy)]
struct Pt {
    m: usize,
    var: f64,
    shape: [f64; 3],
}

/// The usable points of `points`, the term shapes taken from `known` (points of the same
/// factors, already computed) where they are there: the flicker's costs O(m), and the
/// bootstrap refits the same factors many times.
fn fit_points(points: &[Point], known: &[Pt]) -> Vec<Pt> {
    points
        .iter()
        .filter(|p| p.adev.is_finite() && p.adev > 0.0)
        .map(|p| Pt {
            m: p.m,
            var: p.adev * p.adev,
            shape: known
                .iter()
                .find(|k| k.m == p.m)
                .map_or_else(|| TermKind::ALL.map(|k| expected_avar(k, p.m)), |k| k.shape),
        })
        .collect()
}

/// The fit's estimate before its standard errors.
struct Estimate {
    theta: [f64; 3],
    active: [bool; 3],
    iterations: usize,
    reduced_chi2: f64,
}

/// Iterated weighted least squares on (m, σ̂²) points of a series of `len` samples.
fn estimate(pts: &[Pt], len: usize) -> Result<Estimate, AllanError> {
    let mut active: [bool; 3];
    let mut iterations = 0;
    // Start from relative least squares (weights 1/σ̂⁴), then IRLS with model weights.
    let mut weights: Vec<f64> = pts.iter().map(|p| 1.0 / (p.var * p.var)).collect();
    let mut theta = [0.0f64; 3];
    loop {
        // The active set is chosen afresh at each weighting: a term dropped under the
        // first, relative weights may be needed under the model's.
        active = [true; 3];
        let t = solve_active(pts, &weights, &mut active)?;
        let change = t
            .iter()
            .zip(&theta)
            .map(|(a, b)| (a - b).abs() / a.abs().max(f64::MIN_POSITIVE))
            .fold(0.0f64, f64::max);
        theta = t;
        iterations += 1;
        let model: Vec<(f64, i32)> = pts.iter().map(|p| model_at(&theta, p)).collect();
        weights = pts
            .iter()
            .zip(&model)
            .map(|(Pt { m, .. }, (v, alpha))| {
                // α is 0, −1 or −2 and M = N − 2m ≥ 1 here, for which Greenhall's EDF
                // always exists (≥ 1); 1, the least it can be, only guards the type.
                let edf = edf_greenhall(*alpha, *m, len).unwrap_or(1.0);
                edf / (2.0 * v * v)
            })
            .collect();
        if (iterations > 1 && change < 1e-10) || iterations >= MAX_ITER {
            break;
        }
    }
    let n_active = active.iter().filter(|a| **a).count();
    let rss: f64 = pts
        .iter()
        .zip(&weights)
        .map(|(p, w)| w * (p.var - model_at(&theta, p).0).powi(2))
        .sum();
    let dof = pts.len().saturating_sub(n_active).max(1) as f64;
    Ok(Estimate {
        theta,
        active,
        iterations,
        reduced_chi2: rss / dof,
    })
}

/// Each term's standard error by the parametric bootstrap of [`fit_terms`] (`None` for a
/// term the fit left out, or when fewer than half the replicates could be fitted).
fn bootstrap_se(
    est: &Estimate,
    pts: &[Pt],
    len: usize,
    rate_hz: f64,
) -> Result<[Option<f64>; 3], AllanError> {
    let factors: Vec<usize> = pts.iter().map(|p| p.m).collect();
    let mut rng = ChaCha8Rng::seed_from_u64(BOOTSTRAP_SEED);
    let flicker = FlickerIncrements::new(len.saturating_sub(1));
    let [white, q_flicker, q_walk] = est.theta.map(|t| t.max(0.0).sqrt());
    let mut draws: Vec<[f64; 3]> = Vec::with_capacity(BOOTSTRAP_REPLICATES);
    for _ in 0..BOOTSTRAP_REPLICATES {
        let fl = if q_flicker > 0.0 {
            flicker.draw(&mut rng)
        } else {
            Vec::new()
        };
        let (mut level_f, mut level_w) = (0.0, 0.0);
        let y: Vec<f64> = (0..len)
            .map(|i| {
                if i > 0 {
                    level_f += fl.get(i - 1).copied().unwrap_or(0.0);
                    if q_walk > 0.0 {
                        level_w += rng.sample::<f64, _>(StandardNormal);
                    }
                }
                let n: f64 = rng.sample(StandardNormal);
                white * n + q_flicker * level_f + q_walk * level_w
            })
            .collect();
        let replicate = fit_points(&super::oadev(&y, rate_hz, Some(&factors), false)?, pts);
        if let Ok(e) = estimate(&replicate, len) {
            draws.push(e.theta);
        }
    }
    if draws.len() * 2 < BOOTSTRAP_REPLICATES {
        return Ok([None; 3]);
    }
    let k = draws.len() as f64;
    Ok([0, 1, 2].map(|i| {
        let vals = draws.iter().filter_map(|d| d.get(i).copied());
        let mean = vals.clone().sum::<f64>() / k;
        let var = vals.map(|v| (v - mean).powi(2)).sum::<f64>() / (k - 1.0);
        Some(var.sqrt())
    }))
}

/// The model variance at m and the α of its largest term (for that point's EDF).
fn model_at(theta: &[f64; 3], p: &Pt) -> (f64, i32) {
    let mut best = (f64::NEG_INFINITY, 0);
    let mut total = 0.0;
    for ((kind, g), th) in TermKind::ALL.iter().zip(p.shape).zip(theta) {
        let v = th * g;
        total += v;
        if v > best.0 {
            best = (v, kind.alpha());
        }
    }
    (total, best.1)
}

/// Weighted least squares on the active terms, dropping the most negative term and
/// refitting until all are ≥ 0. Returns θ (0 for inactive).
fn solve_active(
    pts: &[Pt],
    weights: &[f64],
    active: &mut [bool; 3],
) -> Result<[f64; 3], AllanError> {
    loop {
        let columns: Vec<usize> = (0..3).filter(|i| active.get(*i) == Some(&true)).collect();
        let kinds: Vec<TermKind> = columns
            .iter()
            .filter_map(|i| TermKind::ALL.get(*i).copied())
            .collect();
        let p = kinds.len();
        if p == 0 {
            return Err(AllanError::Singular("no term left"));
        }
        if pts.len() < p + 1 {
            return Err(AllanError::TooFewPoints {
                points: pts.len(),
                needed: p + 1,
            });
        }
        let g = DMatrix::from_fn(pts.len(), p, |i, j| {
            let column = columns.get(j).copied().unwrap_or(0);
            pts.get(i)
                .and_then(|pt| pt.shape.get(column).copied())
                .unwrap_or(0.0)
        });
        let w = DVector::from_iterator(weights.len(), weights.iter().copied());
        let y = DVector::from_iterator(pts.len(), pts.iter().map(|p| p.var));
        let gw = DMatrix::from_fn(pts.len(), p, |i, j| {
            g.get((i, j)).copied().unwrap_or(0.0) * w.get(i).copied().unwrap_or(0.0)
        });
        let a = gw.transpose() * &g;
        let b = gw.transpose() * &y;
        // Jacobi scaling: the columns differ by many orders of magnitude.
        let s = DVector::from_iterator(
            p,
            (0..p).map(|i| {
                1.0 / a
                    .get((i, i))
                    .copied()
                    .unwrap_or(1.0)
                    .max(f64::MIN_POSITIVE)
                    .sqrt()
            }),
        );
        let sd = DMatrix::from_diagonal(&s);
        let a_scaled = &sd * &a * &sd;
        let chol = a_scaled.cholesky().ok_or(AllanError::Singular(
            "normal equations not positive definite",
        ))?;
        let x_scaled = chol.solve(&(&sd * &b));
        let x = sd * x_scaled;
        let most_negative = x
            .iter()
            .zip(&kinds)
            .filter(|(v, _)| **v < 0.0)
            .min_by(|a, b| a.0.total_cmp(b.0))
            .map(|(_, k)| *k);
        if let Some(k) = most_negative {
            if let Some(slot) = TermKind::ALL
                .iter()
                .position(|t| *t == k)
                .and_then(|i| active.get_mut(i))
            {
                *slot = false;
            }
            continue;
        }
        let mut theta = [0.0; 3];
        for (v, k) in x.iter().zip(&kinds) {
            if let Some(slot) = TermKind::ALL
                .iter()
                .position(|t| t == k)
                .and_then(|i| theta.get_mut(i))
            {
                *slot = *v;
            }
        }
        return Ok(theta);
    }
}

/// A term's parameter in IEEE and PSD form (docs/allan.md, "Conventions"), with the SEs by the
/// delta method (√: SE/(2√θ)).
fn term(kind: TermKind, theta: f64, se: Option<f64>, rate_hz: f64) -> Term {
    use std::f64::consts::PI;
    let sqrt_se = |scale: f64| {
        se.map(|s| {
            if theta > 0.0 {
                scale * s / (2.0 * theta.sqrt())
            } else {
                f64::NAN
            }
        })
    };
    let (ieee, ieee_se, h, h_se) = match kind {
        // N² = σ_s²·Δ; h0 = 2σ_s²·Δ.
        TermKind::White => {
            let c = 1.0 / rate_hz;
            (
                (theta * c).sqrt(),
                sqrt_se(c.sqrt()),
                2.0 * theta * c,
                se.map(|s| 2.0 * s * c),
            )
        }
        // B² = Q; h₋₁ = Q/π.
        TermKind::Flicker => (theta.sqrt(), sqrt_se(1.0), theta / PI, se.map(|s| s / PI)),
        // K² = q/Δ; h₋₂ = K²/(2π²).
        TermKind::RandomWalk => (
            (theta * rate_hz).sqrt(),
            sqrt_se(rate_hz.sqrt()),
            theta * rate_hz / (2.0 * PI * PI),
            se.map(|s| s * rate_hz / (2.0 * PI * PI)),
        ),
    };
    Term {
        kind,
        resolved: se.is_some(),
        theta_u2: theta,
        theta_se_u2: se,
        ieee,
        ieee_se,
        h,
        h_se,
    }
}
