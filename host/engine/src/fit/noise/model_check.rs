//! The noise model against the data (docs/uncertainty.md, "The model against the data,
//! checked"): the scatter of the residuals' sine and cosine coefficients over each whole turn,
//! against what the estimated model (AR, flicker and walk) predicts for them through the
//! fit. These coefficients are what the amplitudes are made of, so a model that
//! understates the noise near the rotation frequency shows here first.

use super::{NoiseModel, SlowDesign, SlowFit};
use nalgebra::DMatrix;
use statrs::distribution::{ChiSquared, ContinuousCDF, FisherSnedecor};

/// The check's level on each side: a model is called wrong when the scatter lies beyond
/// what it gives with probability 10⁻³ (one-sided, 3.09 σ), as the other tests do.
pub const ALPHA: f64 = 1e-3;

/// One group's share of a channel's check.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PeriodScatter {
    /// Whole turns in the group.
    pub periods: usize,
    /// Σ over the turns of the residuals' cosine and sine coefficients squared.
    pub observed: f64,
    /// Its expectation under the model: tr S, S the coefficients' covariance.
    pub expected: f64,
    /// tr S² (its variance under the model, Gaussian noise, is 2·tr S²).
    pub trace2: f64,
    /// tr S's terms: the AR model's, and unit flicker's and unit walk's.
    pub terms: [f64; 3],
    /// The covariance of the model's terms (AR scale, Q̂, q̂): the AR scale the group's
    /// own, the levels shared by the channel's groups.
    pub terms_cov: [[f64; 3]; 3],
}

impl SlowDesign {
    /// The residuals' cosine and sine coefficients over each whole turn, against the model.
    ///
    /// - `weighted_resid`: the residuals of the fit this design describes (weighted rows);
    /// - `ar` and `slow`: the AR model (rescaled for the fit) and the slow levels (signed,
    ///   as estimated) with their covariance;
    /// - `cycles`: each row's table angle in turns (rate × time).
    ///
    /// With x_p the weighted cos and sin of the angle over turn p, the coefficients are
    /// c = Xᵀr = ((I − P)X)ᵀe, so S = X̃ᵀΓX̃ + Q·X̃ᵀ(WT_flW)X̃ + q·X̃ᵀ(WT_rwW)X̃ with
    /// X̃ = (I − P)X, a contrast (the fit has an offset). `None` below two whole turns:
    /// one turn's coefficients are what the fit itself took out.
    pub fn period_scatter(
        &self,
        weighted_resid: &[f64],
        ar: &NoiseModel,
        slow: &SlowFit,
        cycles: &[f64],
    ) -> Option<PeriodScatter> {
        let [_, q_fl, q_rw] = slow.theta;
        let n = weighted_resid.len();
        if cycles.len() != n || self.weights().len() != n {
            return None;
        }
        let first = *cycles.first()?;
        let span = cycles.last()? - first;
        if !span.is_finite() || span < 2.0 {
            return None;
        }
        let periods = span.floor() as usize;
        let mut x = DMatrix::zeros(n, 2 * periods);
        for (t, (c, w)) in cycles.iter().zip(self.weights()).enumerate() {
            let turn = (c - first).floor();
            if !(0.0..periods as f64).contains(&turn) {
                continue;
            }
            let p = turn as usize;
            let (s, co) = (std::f64::consts::TAU * c).sin_cos();
            if let Some(v) = x.get_mut((t, 2 * p)) {
                *v = w * co;
            }
            if let Some(v) = x.get_mut((t, 2 * p + 1)) {
                *v = w * s;
            }
        }
        let observed: f64 = x
            .column_iter()
            .map(|col| {
                let c: f64 = col.iter().zip(weighted_resid).map(|(a, b)| a * b).sum();
                c * c
            })
            .sum();
        let xt = self.off_fit(&x);
        let [fl, rw] = self.slow_gram(&xt);
        let short = self.ar_gram(ar, &xt);
        let terms = [short.trace(), fl.trace(), rw.trace()];
        let s = short + fl * q_fl + rw * q_rw;
        Some(PeriodScatter {
            periods,
            observed,
            expected: s.trace(),
            trace2: (&s * &s).trace(),
            terms,
            terms_cov: slow.cov,
        })
    }
}

/// A channel's check, its groups' shares pooled: the ratio R of the observed scatter to
/// its expectation, and how probable a ratio that far out is under the model.
///
/// - The scatter T is Σλᵢχ²₁ with λ the eigenvalues of S (block-diagonal over the
///   groups): Satterthwaite's χ²_ν/ν·E with ν = (tr S)²/tr S².
/// - The expectation E = tr S is itself estimated: the AR model's level with its ν, the
///   slow levels with their bootstrap covariance. Taking it as known made the check widen
///   U in 18 of 500 AR(1) sessions at 10 mHz (nominal about 3), where the levels of 2.6
///   turns a condition are uncertain. So Ê/E is taken as χ²_νE/νE (Welch–Satterthwaite,
///   νE = 2Ê²/Var Ê), independent of T, and R = T/Ê as F(ν, νE).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModelCheck {
    /// Whole turns over the groups.
    pub periods: usize,
    /// Observed scatter over expected.
    pub ratio: f64,
    /// The scatter's degrees of freedom (tr S)²/tr S².
    pub dof: f64,
    /// The expectation's degrees of freedom (infinite: known).
    pub dof_model: f64,
    /// P(ratio ≥ observed): small when the data scatter more than the model says.
    pub p_above: f64,
    /// P(ratio ≤ observed): small when they scatter less.
    pub p_below: f64,
}

impl ModelCheck {
    /// Pool the groups' shares; `None` without any (too few turns) or where the model
    /// expects no scatter (signed levels far below zero).
    pub fn pool(shares: &[PeriodScatter]) -> Option<ModelCheck> {
        let first = shares.first()?;
        let sum = |f: fn(&PeriodScatter) -> f64| shares.iter().map(f).sum::<f64>();
        let (o, c1, c2) = (sum(|s| s.observed), sum(|s| s.expected), sum(|s| s.trace2));
        if !(c1 > 0.0 && c2 > 0.0) {
            return None;
        }
        let dof = c1 * c1 / c2;
        // Var Ê: each group's AR scale, then the shared slow levels on the pooled terms.
        let ar_var = sum(|s| {
            let ([t, _, _], [[c, _, _], _, _]) = (s.terms, s.terms_cov);
            t * t * c
        });
        let fl = sum(|s| {
            let [_, f, _] = s.terms;
            f
        });
        let rw = sum(|s| {
            let [_, _, r] = s.terms;
            r
        });
        let [_, [_, c_ff, c_fw], [_, _, c_ww]] = first.terms_cov;
        let var_e = ar_var + fl * fl * c_ff + 2.0 * fl * rw * c_fw + rw * rw * c_ww;
        let dof_model = if var_e > 0.0 {
            2.0 * c1 * c1 / var_e
        } else {
            f64::INFINITY
        };
        let ratio = o / c1;
        let below = if dof_model.is_finite() {
            FisherSnedecor::new(dof, dof_model).ok()?.cdf(ratio)
        } else {
            ChiSquared::new(dof).ok()?.cdf(dof * ratio)
        };
        Some(ModelCheck {
            periods: shares.iter().map(|s| s.periods).sum(),
            ratio,
            dof,
            dof_model,
            p_above: 1.0 - below,
            p_below: below,
        })
    }

    /// What the check does: widen where the data scatter more than the model allows,
    /// narrow where less.
    pub fn verdict(&self) -> Verdict {
        if self.p_above < ALPHA {
            Verdict::Widened
        } else if self.p_below < ALPHA {
            Verdict::Narrowed
        } else {
            Verdict::None
        }
    }

    /// The factor the channel's noise terms are multiplied by: R where the check acts,
    /// else 1.
    pub fn factor(&self) -> f64 {
        match self.verdict() {
            Verdict::None => 1.0,
            Verdict::Widened | Verdict::Narrowed => self.ratio,
        }
    }
}

/// What the model check did to a channel's noise terms.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// The data agree with the model within chance.
    None,
    /// The data scatter more than the model allows: multiplied by the ratio.
    Widened,
    /// They scatter less than it allows: multiplied by the ratio.
    Narrowed,
}

#[cfg(test)]
#[allow(clippy::indexing_slicing)]
mod tests {
    use super::super::slow::tests::{tests_residuals, tests_wide_at};
    use super::*;
    use crate::allan::powerlaw::FlickerIncrements;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    /// The p-values (above, below) of the check on each of `records` records of white
    /// noise of variance `white` plus flicker `q_fl`, checked against white noise of
    /// variance `model_white` plus the same flicker: the proof `name`, whose verdict on
    /// the counts below 0.05 and 0.01 is `check`.
    fn rejections(
        name: &str,
        turns_per_row: f64,
        (white, q_fl): (f64, f64),
        model_white: f64,
        records: usize,
        check: impl FnOnce(((usize, usize), usize)) -> Vec<String>,
    ) {
        let n = 4200;
        let d = SlowDesign::new(&tests_wide_at(n, turns_per_row), &vec![1.0; n]).unwrap();
        let cycles: Vec<f64> = (0..n).map(|t| turns_per_row * t as f64).collect();
        let model = NoiseModel::white(model_white, n);
        // The model known exactly: no uncertainty in its terms.
        let known = SlowFit {
            theta: [1.0, q_fl, 0.0],
            cov: [[0.0; 3]; 3],
        };
        let gen = FlickerIncrements::new(n - 1);
        let trial = |seed: usize| {
            let mut rng = ChaCha8Rng::seed_from_u64(0xC4EC_0000 + seed as u64);
            let r = tests_residuals(&d, (white, q_fl, 0.0), &gen, &mut rng);
            let share = d.period_scatter(&r, &model, &known, &cycles).unwrap();
            let c = ModelCheck::pool(&[share]).unwrap();
            (c.p_above, c.p_below)
        };
        rotacal_proof::prove(name, records, trial, |ps| {
            let count = |f: &dyn Fn(&(f64, f64)) -> bool| ps.iter().filter(|p| f(p)).count();
            check((
                (count(&|p| p.0 < 0.05), count(&|p| p.0 < 0.01)),
                count(&|p| p.1 < 0.05),
            ))
        });
    }

    /// Under the model p_above is uniform: over 1000 records each of white noise and of
    /// white noise with flicker, at 2.6 and 13 turns, the share below 0.05 and below 0.01
    /// is within 4 binomial σ of the level; p_below is below 0.05 in at most that many
    /// (conservative). A model with half the white variance is found (p_above < 0.05) in
    /// most records at 13 turns.
    #[test]
    fn the_check_holds_its_level_and_finds_a_model_too_small() {
        let name =
            "fit::noise::model_check::tests::the_check_holds_its_level_and_finds_a_model_too_small";
        let records = 1000;
        let z = |k: usize, level: f64| {
            (k as f64 - level * records as f64) / (level * (1.0 - level) * records as f64).sqrt()
        };
        for turns_per_row in [0.01 / 16.0, 0.05 / 16.0] {
            for q_fl in [0.0, 0.05] {
                let at = format!("{turns_per_row} turns a row, Q {q_fl}");
                let case = format!("{name}#turns_{}_q_{q_fl}", turns_per_row * 16.0);
                rejections(
                    &case,
                    turns_per_row,
                    (16.0, q_fl),
                    16.0,
                    records,
                    |((a5, a1), b5)| {
                        println!("{at}: above {a5} {a1}, below {b5}");
                        let mut failures = Vec::new();
                        if z(a5, 0.05).abs() >= 4.0 {
                            failures.push(format!("{at}: p_above < 0.05 in {a5} of {records}"));
                        }
                        if z(a1, 0.01).abs() >= 4.0 {
                            failures.push(format!("{at}: p_above < 0.01 in {a1} of {records}"));
                        }
                        if z(b5, 0.05) >= 4.0 {
                            failures.push(format!("{at}: p_below < 0.05 in {b5} of {records}"));
                        }
                        failures
                    },
                );
            }
        }
        let case = format!("{name}#half_the_variance");
        rejections(
            &case,
            0.05 / 16.0,
            (16.0, 0.0),
            8.0,
            400,
            |((found, _), _)| {
                println!("half the variance found in {found} of 400");
                if found > 300 {
                    vec![]
                } else {
                    vec![format!("half the variance found in {found} of 400")]
                }
            },
        );
    }
}
