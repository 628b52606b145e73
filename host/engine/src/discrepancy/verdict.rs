//! The verdict of a run (docs/discrepancy.md, "The verdict"): whether the named effects
//! and the noise account for the data, and where they do not.
//!
//! Two things make a recording unexplained:
//! - structure the generic fit would have left, found before the noise was estimated
//!   ([`super::structure`]: harmonics above the fourth, a step);
//! - the final model's lack of fit against the generic fit: each generic fit's χ² under
//!   its own noise model equals its degrees of freedom D by construction, so the final
//!   model's excess χ² − D over the q coefficients it lacks is F(q, D) if it explains what
//!   the generic fit does. Where it fails, the generic fit's parts in its residuals (offset,
//!   trend, each harmonic, …), each by its Wald χ², say where.

use super::locate::Place;
use super::model::{Data, Fit, Tested};
use super::noise;
use super::slow::SlowLevels;
use super::structure::{self, Kind};
use rotacal_shared::Channel;
use serde::Serialize;
use statrs::distribution::{ChiSquared, ContinuousCDF, FisherSnedecor};

/// The final model against the generic fits.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LackOfFit {
    /// The final model's χ² (whitened) over the rows the generic fits kept.
    pub chi2: f64,
    /// The generic fits' χ², equal to their degrees of freedom.
    pub generic_dof: f64,
    /// Coefficients the generic fits have beyond the final model.
    pub k: usize,
    /// F = (χ² − D)/k.
    pub f: f64,
    /// P(F(k, D) ≥ f).
    pub p_value: f64,
    /// Whether the verdict counts it: not under `--slow-noise`, where the AR model's χ²
    /// reads the slow power as misfit and the parts are judged one by one instead.
    pub counted: bool,
}

/// One thing the model does not explain.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Unexplained {
    /// Condition, rate and channel.
    pub at: Place,
    /// What: a harmonic of the table angle, a step with its time, a trend, …
    pub what: String,
    /// Its size, output units (a trend: its change over the group; temperature: per °C).
    pub size: f64,
    /// Its size over one reading's noise sd in that group's channel.
    pub size_in_sd: f64,
    /// Its size over its standard error (√χ² for a pair's amplitude).
    pub z: f64,
    /// The chance of so large a χ² from noise, times the tests made (Bonferroni).
    pub p_value: f64,
}

/// The verdict.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Verdict {
    /// The named effects and the noise account for the data.
    pub explained: bool,
    /// One sentence, computed from the fields below.
    pub summary: String,
    /// The final model against the generic fits.
    pub lack_of_fit: LackOfFit,
    /// What is not explained: the structure the scan found first, then the final model's
    /// misfit, each by z, largest first.
    pub unexplained: Vec<Unexplained>,
}

/// The noise sd of group `gi`'s channel.
fn sd_of(data: &Data, gi: usize, ch: Channel) -> f64 {
    data.noise
        .get(gi)
        .map_or(*ch.of(&data.sigma), |m| ch.of(m).sd())
}

/// A part's p-value with the slow terms in its coefficients' covariance: Wald's F against
/// F(k, D), the slow variance raised as in the effects' tests ([`SlowLevels::test`]).
fn slow_p(
    data: &Data,
    levels: &SlowLevels,
    (gi, ch): (usize, Channel),
    c: &noise::Component,
) -> Option<(f64, f64)> {
    let offset: usize = data.groups.iter().take(gi).map(|g| g.tau.len()).sum();
    let rows = data.rows();
    let weights = c
        .weights
        .iter()
        .map(|w| {
            let mut per = [vec![0.0; rows], vec![0.0; rows], vec![0.0; rows]];
            if let Some(slot) = ch.of_mut(&mut per).get_mut(offset..offset + w.len()) {
                slot.copy_from_slice(w);
            }
            per
        })
        .collect();
    let t = Tested::linear(c.values.clone(), c.cov.clone(), weights);
    let dof = data.generic.dof.max(1.0);
    let test = levels.test(data, &t, 1.0, dof)?;
    let p = FisherSnedecor::new(c.k as f64, dof)
        .map(|d| d.sf(test.f))
        .unwrap_or(1.0);
    Some((p, (test.f * c.k as f64).sqrt()))
}

/// A part's p-value and z: its χ² under the AR model, or with `levels` the slow terms in
/// its covariance (a scanned step's maximum read again with the scan's own multiplicity);
/// `None` where it cannot be tested.
fn part_p(
    data: &Data,
    levels: Option<&SlowLevels>,
    (gi, ch, at): (usize, Channel, Place),
    c: &noise::Component,
) -> Option<(f64, f64)> {
    // A scanned step's decorrelation, as its scan measured it at `at`.
    let lambda_at = |at: Place| {
        data.generic.structure.iter().find_map(|s| match s.what {
            Kind::Step { lambda, .. } if s.at == at => Some(lambda),
            _ => None,
        })
    };
    match levels {
        Some(l) => match slow_p(data, l, (gi, ch), c)? {
            (_, z) if c.extra.is_some() => {
                lambda_at(at).map(|lambda| (structure::scan_max_p(z, lambda), z))
            }
            pz => Some(pz),
        },
        None => Some((
            ChiSquared::new(c.k as f64)
                .map(|d| d.sf(c.chi2))
                .unwrap_or(1.0),
            c.chi2.sqrt(),
        )),
    }
}

/// The verdict on `last`, the final model, at significance `alpha` for each of its two
/// parts (the scan's structure and the lack of fit); with `levels` (`--slow-noise`), the
/// parts of the generic fit in its residuals and the scan's steps are tested with the slow
/// terms in their covariance, and the overall lack of fit is not counted.
pub fn judge(data: &Data, last: &Fit, alpha: f64, levels: Option<&SlowLevels>) -> Verdict {
    let k = data.generic.coefficients.saturating_sub(last.n_params);
    let mut chi2 = 0.0;
    for (gi, g) in data.groups.iter().enumerate() {
        for ch in Channel::ALL {
            if let Some(m) = data.noise.get(gi) {
                let r = last.residuals(data, gi, ch);
                chi2 += noise::chi2_on_generic_rows(g, ch, ch.of(m), r);
            }
        }
    }
    let excess = chi2 - data.generic.dof;
    let f = if k > 0 {
        (excess / k as f64).max(0.0)
    } else {
        0.0
    };
    let p_value = FisherSnedecor::new(k.max(1) as f64, data.generic.dof.max(1.0))
        .map(|d| d.sf(f))
        .unwrap_or(1.0);
    let lack_of_fit = LackOfFit {
        chi2,
        generic_dof: data.generic.dof,
        k,
        f,
        p_value,
        counted: levels.is_none(),
    };
    let misfit = levels.is_none() && p_value < alpha;
    let mut unexplained: Vec<Unexplained> = data
        .generic
        .structure
        .iter()
        // Under slow noise the scan's steps are judged again below, with the slow terms.
        .filter(|s| levels.is_none() || !matches!(s.what, Kind::Step { .. }))
        .map(|s| {
            let gi = data.groups.iter().position(|g| match s.at {
                Place::Group {
                    condition, rate_hz, ..
                } => g.condition == condition && g.rate_hz == rate_hz,
                _ => false,
            });
            let sd = match (gi, s.at) {
                (Some(gi), Place::Group { channel, .. }) => sd_of(data, gi, channel),
                _ => f64::NAN,
            };
            Unexplained {
                at: s.at,
                what: s.what.to_string(),
                size: s.size,
                size_in_sd: s.size.abs() / sd,
                z: s.z,
                p_value: s.p_value,
            }
        })
        .collect();
    if misfit || levels.is_some() {
        let mut parts = Vec::new();
        for (gi, g) in data.groups.iter().enumerate() {
            for ch in Channel::ALL {
                let (Some(m), Some(extras)) = (data.noise.get(gi), data.generic.extras.get(gi))
                else {
                    continue;
                };
                let at = Place::Group {
                    condition: g.condition,
                    rate_hz: g.rate_hz,
                    channel: ch,
                };
                let sd = ch.of(m).sd();
                let found = noise::components(
                    g,
                    ch,
                    ch.of(extras).as_slice(),
                    ch.of(m),
                    &last.residuals(data, gi, ch),
                    levels.is_some(),
                );
                for mut c in found {
                    // The scan's harmonics stand on their own test; its steps are judged
                    // here only under slow noise.
                    let step = matches!(c.extra, Some(noise::Extra::Step(_)));
                    if c.extra.is_none() || (levels.is_some() && step) {
                        // Tested now, so that no part holds its weights (rows each) longer.
                        let Some((p, z)) = part_p(data, levels, (gi, ch, at), &c) else {
                            continue;
                        };
                        c.weights = Vec::new();
                        parts.push((at, c, sd, p, z));
                    }
                }
            }
        }
        let tests = parts.iter().filter(|p| p.1.extra.is_none()).count().max(1) as f64;
        let channels = (3 * data.groups.len()).max(1) as f64;
        for (at, c, sd, p, z) in parts {
            let count = if c.extra.is_some() { channels } else { tests };
            if p * count < alpha {
                unexplained.push(Unexplained {
                    at,
                    what: c.what,
                    size: c.size,
                    size_in_sd: c.size.abs() / sd,
                    z,
                    p_value: (p * count).min(1.0),
                });
            }
        }
    }
    // The scan's structure first (no catalogue effect can make it, and what the final model
    // then misses is often what a wrongly named effect bent to fit it), each part by z.
    let scanned = |u: &Unexplained| {
        data.generic
            .structure
            .iter()
            .any(|s| s.at == u.at && s.what.to_string() == u.what)
    };
    unexplained.sort_by(|a, b| {
        scanned(b)
            .cmp(&scanned(a))
            .then_with(|| b.z.total_cmp(&a.z))
    });
    let explained = unexplained.is_empty() && !misfit;
    let summary = if explained {
        format!(
            "explained: the named effects and the noise account for the data (lack of fit \
             F = {f:.3} on {k} and {:.0} dof, p = {p_value:.3})",
            data.generic.dof
        )
    } else {
        match unexplained.first() {
            Some(u) => format!(
                "unexplained: {} at {}, of size {:.3} ({:.1} noise sd, z = {:.1}){}",
                u.what,
                u.at,
                u.size,
                u.size_in_sd,
                u.z,
                match unexplained.len() {
                    1 => String::new(),
                    n => format!(", and {} more", n - 1),
                }
            ),
            None => format!(
                "unexplained: the final model misses what the generic fit holds (F = {f:.3} on \
                 {k} and {:.0} dof, p = {p_value:.2e}), spread over the groups",
                data.generic.dof
            ),
        }
    };
    Verdict {
        explained,
        summary,
        lack_of_fit,
        unexplained,
    }
}
