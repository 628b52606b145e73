//! A tested effect's parameters as linear functions of the readings: the weights the fit
//! gives each reading in their estimates, at the solution. The slow-noise test
//! ([`crate::discrepancy::slow`]) needs them to carry noise the AR model does not describe
//! into the parameters' covariance.

use super::{noise_of, whitened_system, Data, Effect, Fit, Layout, ModelError, Param, Params};
use crate::fit::batch::BatchError;
use crate::fit::noise::NoiseModel;
use nalgebra::{DMatrix, DVector};
use rotacal_shared::{Channel, Condition};

/// A tested effect's parameters in a fit.
#[derive(Clone, Debug)]
pub struct Tested {
    /// Their values.
    pub values: Vec<f64>,
    /// Their covariance under the AR noise model (the generalised least squares one,
    /// before any scaling by χ²/dof).
    pub gls_cov: DMatrix<f64>,
    /// Per parameter and channel: the estimate's weights on the channel's readings, group
    /// after group in the data's order (Σ weight × reading is the estimate's linear part).
    pub weights: Vec<[Vec<f64>; 3]>,
    /// Which parameter each is.
    targets: Vec<Target>,
}

impl Tested {
    /// Linear functionals of the readings that are no model's parameters (the verdict's
    /// parts of a generic fit): their values, covariance under the AR model and weights.
    pub fn linear(values: Vec<f64>, gls_cov: DMatrix<f64>, weights: Vec<[Vec<f64>; 3]>) -> Self {
        Tested {
            values,
            gls_cov,
            weights,
            targets: Vec::new(),
        }
    }

    /// Write one number per parameter (a standard uncertainty, say) into their places in
    /// `into`, a [`Params`] of the fit's shape.
    pub fn write(&self, numbers: &[f64], into: &mut Params) {
        for (t, &x) in self.targets.iter().zip(numbers) {
            match *t {
                Target::Delta => {
                    if let Some(d) = into.delta.as_mut() {
                        *d = x;
                    }
                }
                Target::Local(param, ch) => {
                    if let Some(slot) = into.slot_mut(param, ch) {
                        *slot = x;
                    }
                }
            }
        }
    }
}

/// Which parameter: a channel's local one, or δ.
#[derive(Clone, Copy, Debug)]
enum Target {
    Local(Param, Channel),
    Delta,
}

/// The parameters an effect adds (none for saturation, whose rails are read off the data).
fn targets(e: Effect) -> Vec<Target> {
    let per_channel = |p: Param| Channel::ALL.map(|ch| Target::Local(p, ch)).to_vec();
    match e {
        Effect::RateError => vec![Target::Delta],
        Effect::OffsetDrift => per_channel(Param::Drift),
        Effect::TemperatureOffset => per_channel(Param::Temp),
        Effect::Nonlinearity2nd => per_channel(Param::K2),
        Effect::Nonlinearity3rd => per_channel(Param::K3),
        Effect::Saturation => Vec::new(),
        Effect::Centripetal => Condition::ALL
            .into_iter()
            .flat_map(|c| per_channel(Param::Centripetal(c)))
            .collect(),
    }
}

/// One channel's whitened system, factored.
struct Factored {
    q: DMatrix<f64>,
    r: DMatrix<f64>,
    /// δ's derivatives, and the same with the local parameters' span taken out (zero
    /// without δ).
    z: DVector<f64>,
    z_off: DVector<f64>,
    /// Per group, which whitened rows are kept.
    keep: Vec<Vec<bool>>,
}

/// `e`'s parameters in `fit` with their weights, or `None` if it adds none.
///
/// Generalised least squares makes every estimate Σ_t g_t·y_t near the solution. In the
/// whitened rows the weights of a local parameter i are Q·R⁻ᵀeᵢ less its share of δ, and
/// δ's are z⊥/‖z⊥‖² over all channels (z⊥: δ's derivatives with the channel's local span
/// taken out, the Schur complement the fit solves by). The readings' weights follow by
/// the whitening filter's transpose.
pub fn tested(data: &Data, fit: &Fit, e: Effect) -> Result<Option<Tested>, ModelError> {
    let targets = targets(e);
    if targets.is_empty() {
        return Ok(None);
    }
    let p = &fit.params;
    let layout = Layout::new(p, data);
    let s = p.sensitivity(data);
    let n_rows = data.rows();
    let with_delta = p.delta.is_some();
    let singular = || ModelError::Undetermined(BatchError::Singular);
    let mut chans = Vec::with_capacity(3);
    let mut zz = 0.0;
    for (ch, sj) in Channel::ALL.into_iter().zip(s) {
        let system = whitened_system(data, p, &layout, ch, sj)?;
        let x = DMatrix::from_vec(n_rows, layout.n(), system.xs);
        let qr = x.qr();
        let q = qr.q();
        let z = DVector::from_vec(system.z);
        let z_off = if with_delta {
            &z - &q * q.tr_mul(&z)
        } else {
            DVector::zeros(n_rows)
        };
        zz += z_off.dot(&z_off);
        chans.push(Factored {
            q,
            z,
            r: qr.r(),
            z_off,
            keep: system.keep,
        });
    }
    let delta_weights = |scale: f64| -> Vec<DVector<f64>> {
        chans
            .iter()
            .map(|c| &c.z_off * if zz > 0.0 { scale / zz } else { 0.0 })
            .collect()
    };
    let mut values = Vec::with_capacity(targets.len());
    let mut read = p.clone(); // the values are read through the slots' one accessor
    let mut whitened: Vec<Vec<DVector<f64>>> = Vec::with_capacity(targets.len());
    for t in &targets {
        match *t {
            Target::Delta => {
                values.push(p.delta.unwrap_or(0.0));
                whitened.push(delta_weights(1.0));
            }
            Target::Local(param, ch) => {
                let i = layout
                    .cols
                    .iter()
                    .position(|c| *c == param)
                    .ok_or(ModelError::Internal("a tested parameter is not in the fit"))?;
                let c = chans
                    .get(ch.index())
                    .ok_or(ModelError::Internal("a channel without a system"))?;
                let mut unit = DVector::zeros(layout.n());
                if let Some(x) = unit.get_mut(i) {
                    *x = 1.0;
                }
                let a =
                    c.r.transpose()
                        .solve_lower_triangular(&unit)
                        .ok_or_else(singular)?;
                let own = &c.q * a;
                // β_i = own·(r − z·δ̂): δ's weights times −own·z on every channel.
                let share = if with_delta { own.dot(&c.z) } else { 0.0 };
                let mut w = delta_weights(-share);
                if let Some(mine) = w.get_mut(ch.index()) {
                    *mine += own;
                }
                values.push(read.slot_mut(param, ch).map_or(0.0, |v| *v));
                whitened.push(w);
            }
        }
    }
    let k = targets.len();
    let gls_cov = DMatrix::from_fn(k, k, |a, b| match (whitened.get(a), whitened.get(b)) {
        (Some(wa), Some(wb)) => wa.iter().zip(wb).map(|(x, y)| x.dot(y)).sum(),
        _ => 0.0,
    });
    let mut weights = Vec::with_capacity(k);
    for w in &whitened {
        let mut per_channel: [Vec<f64>; 3] = Default::default();
        for ((ch, out), (wc, c)) in Channel::ALL
            .into_iter()
            .zip(per_channel.iter_mut())
            .zip(w.iter().zip(&chans))
        {
            out.reserve(n_rows);
            let mut rest = wc.as_slice();
            for ((gi, g), keep) in data.groups.iter().enumerate().zip(&c.keep) {
                let n = g.tau.len().min(rest.len());
                let (part, tail) = rest.split_at(n);
                rest = tail;
                out.extend(unwhiten(noise_of(data, gi, ch)?, part, keep));
            }
        }
        weights.push(per_channel);
    }
    Ok(Some(Tested {
        values,
        gls_cov,
        weights,
        targets,
    }))
}

/// The whitening filter's transpose ([`super::whiten`]): the readings' weights of a linear
/// function with weights `y` on the whitened rows.
fn unwhiten(m: &NoiseModel, y: &[f64], keep: &[bool]) -> Vec<f64> {
    let w = 1.0 / m.innovation_var.sqrt().max(f64::MIN_POSITIVE);
    let mut out = vec![0.0; y.len()];
    for (t, (&v, &k)) in y.iter().zip(keep).enumerate() {
        if !k {
            continue;
        }
        let v = v * w;
        if let Some(o) = out.get_mut(t) {
            *o += v;
        }
        for (lag, f) in m.ar.iter().enumerate() {
            if let Some(o) = t.checked_sub(lag + 1).and_then(|s| out.get_mut(s)) {
                *o -= f * v;
            }
        }
    }
    out
}

#[cfg(test)]
#[allow(clippy::indexing_slicing)]
mod tests {
    use super::*;
    use crate::discrepancy::model::{fit, kept};
    use crate::discrepancy::{data_from, trials, Options};
    use crate::simulate::{Config, Simulation};

    /// A 10 mHz session with a drift and a rate error, AR(1) noise, as the model sees it.
    fn session() -> Data {
        let toml = format!(
            "{}{}{}{}",
            trials::SINGLE_RATE,
            trials::injection(Effect::OffsetDrift, 0.01).0,
            trials::injection(Effect::RateError, 1e-5).0,
            trials::Noise::Ar1.toml()
        );
        let mut cfg = Config::from_toml(&toml).unwrap();
        cfg.seed = 7;
        let rec = Simulation::new(cfg).unwrap().recording().unwrap();
        data_from(&rec, &Options::default()).unwrap().0
    }

    /// The weights reproduce the fit: the drift, linear in the readings, is Σ weight ×
    /// reading, and every tested parameter's GLS variance is the fit's.
    #[test]
    fn the_weights_are_the_fits() {
        let data = session();
        let only_drift = fit(&data, &[Effect::OffsetDrift], None).unwrap();
        let t = tested(&data, &only_drift, Effect::OffsetDrift)
            .unwrap()
            .unwrap();
        let drift = only_drift.params.drift.unwrap();
        let u = only_drift.unc.drift.unwrap();
        for (a, w) in t.weights.iter().enumerate() {
            let mut sum = 0.0;
            for (ch, wc) in Channel::ALL.into_iter().zip(w) {
                let ys = data.groups.iter().flat_map(|g| ch.of(&g.y).iter());
                sum += wc.iter().zip(ys).map(|(w, y)| w * y).sum::<f64>();
            }
            assert!(
                (sum - drift[a]).abs() < 1e-9 * drift[a].abs(),
                "{sum} {}",
                drift[a]
            );
            assert!((t.gls_cov[(a, a)].sqrt() / u[a] - 1.0).abs() < 1e-9);
        }
        // With δ in the model: δ's variance, and the drift's through δ's Schur complement.
        let both = fit(&data, &[Effect::OffsetDrift, Effect::RateError], None).unwrap();
        let t = tested(&data, &both, Effect::RateError).unwrap().unwrap();
        let ud = both.unc.delta.unwrap();
        assert!((t.gls_cov[(0, 0)].sqrt() / ud - 1.0).abs() < 1e-6, "{t:?}");
        let t = tested(&data, &both, Effect::OffsetDrift).unwrap().unwrap();
        let u = both.unc.drift.unwrap();
        for (a, u) in u.iter().enumerate() {
            assert!((t.gls_cov[(a, a)].sqrt() / u - 1.0).abs() < 1e-6);
        }
    }

    /// The transpose is exact: ⟨whiten(x), y⟩ = ⟨x, unwhiten(y)⟩.
    #[test]
    fn unwhiten_is_the_whitening_filters_transpose() {
        let mut m = NoiseModel::white(2.0, 40);
        m.ar = vec![0.5, -0.2];
        m.innovation_var = 3.0;
        let flagged: Vec<bool> = (0..40).map(|t| t == 17).collect();
        let keep = kept(m.order(), &flagged);
        let x: Vec<f64> = (0..40).map(|t| ((t * 7) % 11) as f64 - 5.0).collect();
        let y: Vec<f64> = (0..40).map(|t| ((t * 3) % 5) as f64 - 2.0).collect();
        let mut wx = x.clone();
        super::super::whiten(&m, &mut wx, &keep);
        let lhs: f64 = wx.iter().zip(&y).map(|(a, b)| a * b).sum();
        let rhs: f64 = x
            .iter()
            .zip(unwhiten(&m, &y, &keep))
            .map(|(a, b)| a * b)
            .sum();
        assert!(
            (lhs - rhs).abs() < 1e-12 * lhs.abs().max(1.0),
            "{lhs} {rhs}"
        );
    }
}
