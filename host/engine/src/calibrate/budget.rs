//! The uncertainty budget of a calibration result, GUM style (JCGM 100:2008 §5 and
//! Annex G): for each source, its standard uncertainty, its sensitivity coefficient and its
//! contribution to each property, with degrees of freedom; the sources combined in
//! quadrature (they are independent), the effective degrees of freedom by Welch–
//! Satterthwaite, and a coverage factor per property (docs/uncertainty.md).

use serde::Serialize;

/// Type A (evaluated from the data) or type B (from other knowledge).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Kind {
    /// Evaluated from the data.
    A,
    /// From other knowledge (a certificate, a specification).
    B,
}

/// One source of uncertainty.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Source {
    /// Short name, e.g. `fits`, `g_loc`, `rate_x`, `timestamps`.
    pub source: String,
    /// A or B.
    #[serde(rename = "type")]
    pub kind: Kind,
    /// What it is and where its value comes from.
    pub description: String,
    /// The input's standard uncertainty, when the source is one number (null for the fits,
    /// a source of many inputs whose covariance is propagated whole).
    pub std_unc: Option<f64>,
    /// The unit of `std_unc`.
    pub unit: Option<String>,
    /// Per property: ∂property/∂input (null where the source is not one number).
    pub sensitivity: Vec<Option<f64>>,
    /// Per property: its standard uncertainty from this source, |c|·u, in the property's unit.
    pub contribution: Vec<f64>,
    /// Per property: degrees of freedom of the contribution (null: infinite).
    pub dof: Vec<Option<f64>>,
}

/// One property's combined uncertainty.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Combined {
    /// Its name.
    pub quantity: String,
    /// √(Σ contribution²).
    pub std_unc: f64,
    /// Welch–Satterthwaite effective degrees of freedom (null: infinite).
    pub nu_eff: Option<f64>,
    /// Coverage factor for 95 %: Student's t at ν_eff, at least 2.
    pub k: f64,
    /// k·std_unc.
    pub expanded_unc: f64,
    /// The source with the largest contribution.
    pub dominant: String,
}

/// The budget of one result (`uncertainty_budget` in the calibration JSON).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Budget {
    /// The properties, in the order of every per-property list.
    pub quantities: Vec<String>,
    /// Their units.
    pub units: Vec<String>,
    /// The sources.
    pub sources: Vec<Source>,
    /// Per property.
    pub combined: Vec<Combined>,
    /// What the budget leaves out or assumes, each in a sentence.
    pub notes: Vec<String>,
}

/// How a budget's k follows from its effective degrees of freedom.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KFrom {
    /// Student's t: the variance estimate a scaled χ²_ν.
    StudentT,
    /// The variance estimate normal, of relative variance 2/ν, truncated at zero
    /// ([`coverage_factor_normal_variance`]): a variance made of signed slow-noise levels.
    NormalVariance,
}

impl Budget {
    /// An empty budget for these properties.
    pub fn new(quantities: &[&str], units: &[String]) -> Self {
        Budget {
            quantities: quantities.iter().map(|q| q.to_string()).collect(),
            units: units.to_vec(),
            sources: Vec::new(),
            combined: Vec::new(),
            notes: Vec::new(),
        }
    }

    /// Add a source of one input of standard uncertainty `u` (in `unit`) with sensitivity
    /// `c` per property and infinitely many degrees of freedom (a type-B value taken as
    /// exact in its own uncertainty) unless `dof` is given.
    pub fn scalar(
        &mut self,
        name: &str,
        kind: Kind,
        description: impl Into<String>,
        (u, unit): (f64, &str),
        c: &[f64],
        dof: Option<f64>,
    ) {
        self.sources.push(Source {
            source: name.to_string(),
            kind,
            description: description.into(),
            std_unc: Some(u),
            unit: Some(unit.to_string()),
            sensitivity: c.iter().map(|c| Some(*c)).collect(),
            contribution: c.iter().map(|c| (c * u).abs()).collect(),
            dof: vec![dof; c.len()],
        });
    }

    /// Add a source given by its contributions per property (a vector input whose
    /// covariance was propagated whole).
    pub fn vector(
        &mut self,
        name: &str,
        kind: Kind,
        description: impl Into<String>,
        contribution: &[f64],
        dof: &[Option<f64>],
    ) {
        self.sources.push(Source {
            source: name.to_string(),
            kind,
            description: description.into(),
            std_unc: None,
            unit: None,
            sensitivity: vec![None; contribution.len()],
            contribution: contribution.to_vec(),
            dof: dof.to_vec(),
        });
    }

    /// Combine: u_c² = Σ u_i², ν_eff = u_c⁴ / Σ(u_i⁴/ν_i), k = t₉₇.₅(ν_eff) (at least 2).
    pub fn combine(&mut self) {
        self.combine_with(KFrom::StudentT);
    }

    /// [`Budget::combine`] with k from ν_eff as `k_from` says.
    pub fn combine_with(&mut self, k_from: KFrom) {
        // Per property, each source's (contribution, degrees of freedom, name): a source
        // counts for the properties its lists cover (every source here covers them all).
        let mut per_quantity: Vec<Vec<(f64, Option<f64>, &str)>> = self
            .quantities
            .iter()
            .map(|_| Vec::with_capacity(self.sources.len()))
            .collect();
        for s in &self.sources {
            let terms = s.contribution.iter().zip(&s.dof);
            for (list, (u, nu)) in per_quantity.iter_mut().zip(terms) {
                list.push((*u, *nu, s.source.as_str()));
            }
        }
        self.combined = self
            .quantities
            .iter()
            .zip(per_quantity)
            .map(|(quantity, terms)| {
                let var: f64 = terms.iter().map(|t| t.0 * t.0).sum();
                let denom: f64 = terms
                    .iter()
                    .filter_map(|(u, nu, _)| nu.map(|nu| u.powi(4) / nu))
                    .sum();
                let nu = welch_satterthwaite(var, denom);
                let nu_eff = nu.is_finite().then_some(nu);
                let k = match k_from {
                    KFrom::StudentT => coverage_factor(nu),
                    KFrom::NormalVariance => coverage_factor_normal_variance(nu),
                };
                let dominant = terms
                    .iter()
                    .fold((f64::NEG_INFINITY, ""), |best, t| {
                        if t.0 > best.0 {
                            (t.0, t.2)
                        } else {
                            best
                        }
                    })
                    .1
                    .to_string();
                let std_unc = var.sqrt();
                Combined {
                    quantity: quantity.clone(),
                    std_unc,
                    nu_eff,
                    k,
                    expanded_unc: k * std_unc,
                    dominant,
                }
            })
            .collect();
    }

    /// The source named `name`.
    pub fn source(&self, name: &str) -> Option<&Source> {
        self.sources.iter().find(|s| s.source == name)
    }
}

/// Student's t quantile for a two-sided 95 % interval.
pub fn coverage_factor(nu: f64) -> f64 {
    use statrs::distribution::{ContinuousCDF, StudentsT};
    // k = 2 (the convention of every other result here) unless few degrees of freedom
    // call for more. Below one degree of freedom (a variance dominated by a poorly known
    // slow-noise level, say) k is taken at ν = 1, not back at 2.
    let nu = if nu > 0.0 && nu < 1.0 { 1.0 } else { nu };
    if !(1.0..=1e6).contains(&nu) {
        return 2.0;
    }
    StudentsT::new(0.0, 1.0, nu)
        .map(|t| t.inverse_cdf(0.975).max(2.0))
        .unwrap_or(2.0)
}

/// k for a two-sided 95 % interval when the variance estimate V̂ is normal rather than a
/// scaled χ²: V̂ = V·(1 + δ), δ ~ N(0, 2/ν) truncated where V̂ would be negative, the error
/// N(0, V) independent of it, and k solves E[2Φ(k·√(1 + δ)) − 1] = 0.95. It agrees with
/// Student's t to order 1/ν and exceeds it below, where V̂'s lower tail is heavier than
/// χ²'s: a variance made of signed slow-noise levels (docs/uncertainty.md, "k from the
/// estimate's own degrees of freedom"). At least 2; 2 for ν infinite or not positive.
pub fn coverage_factor_normal_variance(nu: f64) -> f64 {
    use statrs::function::erf::erf;
    if !(nu > 0.0 && nu <= 1e6) {
        return 2.0;
    }
    let sd = (2.0 / nu).sqrt();
    // Simpson's rule over the standard normal x = δ/sd, from where V̂ reaches zero: each
    // node's weight times the normal density, normalised once, and its √(1 + δ).
    let (lo, hi) = ((-1.0 / sd).max(-8.0), 8.0);
    let n = 800;
    let h = (hi - lo) / f64::from(n);
    let nodes: Vec<(f64, f64)> = (0..=n)
        .map(|i| {
            let x = lo + h * f64::from(i);
            let w = match i {
                0 => 1.0,
                _ if i == n => 1.0,
                _ if i % 2 == 1 => 4.0,
                _ => 2.0,
            };
            (w * (-0.5 * x * x).exp(), (1.0 + sd * x).max(0.0).sqrt())
        })
        .collect();
    let total: f64 = nodes.iter().map(|(w, _)| w).sum();
    let covered = |k: f64| {
        nodes
            .iter()
            .map(|(w, r)| w * erf(k * r / std::f64::consts::SQRT_2))
            .sum::<f64>()
            / total
    };
    let top = 1e4;
    if covered(top) < 0.95 {
        return top;
    }
    // Coverage grows with k: bisect its negative, which falls.
    let falls = |k: f64| -covered(k);
    let (_, k) = super::bisect::bracket(&falls, -0.95, (1.9, top), 100, f64::NEG_INFINITY);
    k.max(2.0)
}

/// ν_eff = var² / Σ(u_i⁴/ν_i), given that sum (infinite when it is 0).
pub fn welch_satterthwaite(var: f64, denom: f64) -> f64 {
    if denom > 0.0 && denom.is_finite() {
        var * var / denom
    } else {
        f64::INFINITY
    }
}
