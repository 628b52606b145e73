//! The poses from the readings: repeated readings at one orientation averaged into a
//! pose mean, with its standard error from the readings' own noise.

use super::{Pose, PoseError, PoseNoise, StaticCondition, NOISE_MODEL_MIN};
use crate::allan::powerlaw::flicker_structure;
use crate::calibrate::still::median;
use crate::fit::noise::NoiseModel;
use crate::recording::Oriented;
use rotacal_shared::Channel;

/// Each channel's noise model at a pose, when it has enough readings: the mean's variance
/// is the AR sandwich for a regressor of ones. A channel whose model cannot be made (a
/// constant reading, say) keeps std/√n.
fn pose_noise(rows: &[[f64; 3]], mean: &[f64; 3]) -> Option<[Option<PoseNoise>; 3]> {
    if rows.len() < NOISE_MODEL_MIN {
        return None;
    }
    let n = rows.len();
    let ones = nalgebra::DMatrix::from_element(n, 1, 1.0);
    Some(Channel::ALL.map(|j| {
        let resid: Vec<f64> = rows.iter().map(|r| j.of(r) - j.of(mean)).collect();
        let raw = NoiseModel::estimate(&resid, &[]).ok()?;
        let (m, cov) = raw.clone().regression_cov(&ones).ok()?;
        let var = *cov.get((0, 0))?;
        let unit = slow_lag_sums(n, raw.order()).map(|s| s.iter().map(|v| v / n as f64).collect());
        let slow_slope = slope(var, n, &shifted(&raw, unit, |s| s.rescaled(&ones).ok()));
        Some(PoseNoise {
            lag1: m.autocorrelation(1),
            order: m.order(),
            se: var.max(0.0).sqrt(),
            n_eff: m.var / var,
            dof: n.saturating_sub(1) as f64,
            slow_slope,
        })
    }))
}

/// The expected lag sums Σ_t r_t·r_{t+k} (k = 0 … `lags`) of `n` readings one sample apart
/// about their mean, per unit level of flicker and of a random walk (the levels of
/// [`crate::fit::noise::slow`]): with G_ab = −½·D(|a − b|) their generalised covariance
/// and P = I − 11ᵀ/n, Σ_t (PGP)_{t,t+k}.
fn slow_lag_sums(n: usize, lags: usize) -> [Vec<f64>; 2] {
    let structure = [flicker_structure, |k: u64| k as f64];
    structure.map(|d| {
        let g = |a: usize, b: usize| -0.5 * d(a.abs_diff(b) as u64);
        // Row sums Σ_b G_ab from the running sum of D (long poses: O(n), not O(n²)).
        let mut run = Vec::with_capacity(n);
        let mut acc = 0.0;
        for k in 0..n {
            acc += d(k as u64);
            run.push(acc);
        }
        let at = |m: usize| run.get(m).copied().unwrap_or(0.0);
        let rows: Vec<f64> = (0..n)
            .map(|a| -0.5 * (at(a) + at(n - 1 - a) - d(0)))
            .collect();
        let total: f64 = rows.iter().sum();
        let nf = n as f64;
        (0..=lags.min(n.saturating_sub(1)))
            .map(|k| {
                rows.iter()
                    .zip(rows.iter().skip(k))
                    .enumerate()
                    .map(|(t, (ra, rb))| g(t, t + k) - (ra + rb) / nf + total / (nf * nf))
                    .sum()
            })
            .collect()
    })
}

/// The slow terms' expected share of the autocovariances pooled over records of `lengths`
/// (each about its mean, the sums over the readings used), per unit level, lags 0 … `lags`.
fn pooled_unit(lengths: &[usize], lags: usize) -> [Vec<f64>; 2] {
    let used: usize = lengths.iter().sum();
    let mut unit = [vec![0.0; lags + 1], vec![0.0; lags + 1]];
    for &len in lengths {
        for (u, s) in unit.iter_mut().zip(slow_lag_sums(len, lags)) {
            for (a, b) in u.iter_mut().zip(s) {
                *a += b / used as f64;
            }
        }
    }
    unit
}

/// The model `raw` had its autocovariances been lower by ε times `unit` (per level: the
/// level's expected share of them), at its order, corrected by `correct` as it was: with ε,
/// per flicker and walk level. ε takes 1 % of the variance (the map is smooth, and its
/// fixed point settles to 10⁻⁶). `None` where a level's share is not positive or the refit
/// fails.
fn shifted(
    raw: &NoiseModel,
    unit: [Vec<f64>; 2],
    correct: impl Fn(NoiseModel) -> Option<NoiseModel>,
) -> [Option<(NoiseModel, f64)>; 2] {
    unit.map(|u| {
        let share = u.first().copied().unwrap_or(0.0);
        if !(share > 0.0 && raw.var > 0.0) {
            return None;
        }
        let eps = 0.01 * raw.var / share;
        let shift: Vec<f64> = u.iter().map(|v| v * eps).collect();
        Some((correct(raw.shifted(&shift).ok()?)?, eps))
    })
}

/// The mean variance's growth per unit flicker and walk level at `n` readings, (D −
/// D(shifted))/ε, from its value `var` and the [`shifted`] models; zero where there is none.
fn slope(var: f64, n: usize, shifted: &[Option<(NoiseModel, f64)>; 2]) -> [f64; 2] {
    shifted.each_ref().map(|s| {
        s.as_ref()
            .and_then(|(m, eps)| Some((var - m.mean_variance(n).ok()?) / eps))
            .unwrap_or(0.0)
    })
}

/// The noise of the poses too short for a model of their own (2 to [`NOISE_MODEL_MIN`]
/// − 1 readings): one AR model per channel pooled over all of them (the same sensor, so the
/// same noise), each pose's mean's variance under it. Without it, std/√n understates the
/// variance of a mean of correlated readings (20 readings with AR(1) ρ = 0.6: by a factor
/// of about 3.4). A channel whose pooled model cannot be made keeps std/√n.
fn pool_short_poses(poses: &mut [(Pose, Vec<[f64; 3]>)]) {
    let short = |p: &Pose| p.noise.is_none() && p.n >= 2;
    let models = Channel::ALL.map(|j| {
        let resid: Vec<Vec<f64>> = poses
            .iter()
            .filter(|(p, _)| short(p))
            .map(|(p, rows)| rows.iter().map(|r| j.of(r) - j.of(&p.mean)).collect())
            .collect();
        let records: Vec<&[f64]> = resid.iter().map(Vec::as_slice).collect();
        let model = NoiseModel::pooled_about_means(&records).ok()?;
        // Its degrees of freedom at the poses' median length.
        let lengths: Vec<usize> = records.iter().map(|r| r.len()).collect();
        let n = median(&mut lengths.iter().map(|&l| l as f64).collect::<Vec<_>>()).round() as usize;
        let ceiling = records
            .iter()
            .map(|r| r.len().saturating_sub(1))
            .sum::<usize>() as f64;
        // Repeatable: seeded by the channel and the readings.
        let seed = records
            .iter()
            .flat_map(|r| r.iter())
            .fold(j as u64, |h, v| h.rotate_left(7) ^ v.to_bits());
        let dof = model
            .pooled_mean_variance_dof(&lengths, n, seed)
            .map_or(ceiling, |d| d.min(ceiling));
        let unit = pooled_unit(&lengths, model.order());
        let without = shifted(&model, unit, |s| s.pooled_corrected(&lengths).ok());
        Some((model, dof, without))
    });
    if models.iter().all(Option::is_none) {
        return;
    }
    for (pose, _) in poses.iter_mut().filter(|(p, _)| short(p)) {
        let n = pose.n;
        pose.noise = Some(Channel::ALL.map(|j| {
            let (m, dof, without) = j.of(&models).as_ref()?;
            let var = m.mean_variance(n).ok()?;
            let slow_slope = slope(var, n, without);
            Some(PoseNoise {
                lag1: m.autocorrelation(1),
                order: m.order(),
                se: var.max(0.0).sqrt(),
                n_eff: m.var / var,
                dof: *dof,
                slow_slope,
            })
        }));
    }
}

fn mean_std(rows: &[[f64; 3]]) -> ([f64; 3], Option<[f64; 3]>) {
    let n = rows.len() as f64;
    let mean = Channel::ALL.map(|c| rows.iter().map(|r| c.of(r)).sum::<f64>() / n);
    let std = (rows.len() >= 2).then(|| {
        Channel::ALL.map(|c| {
            (rows
                .iter()
                .map(|r| (c.of(r) - c.of(&mean)).powi(2))
                .sum::<f64>()
                / (n - 1.0))
                .sqrt()
        })
    });
    (mean, std)
}

/// A direction as text: `+x` for an axis, else the vector.
pub fn direction_name(g: &[f64; 3]) -> String {
    for (k, (axis, &c)) in ['x', 'y', 'z'].iter().zip(g).enumerate() {
        let others = g
            .iter()
            .enumerate()
            .filter(|&(i, _)| i != k)
            .all(|(_, v)| v.abs() < 1e-9);
        if others {
            if (c - 1.0).abs() < 1e-9 {
                return format!("+{axis}");
            }
            if (c + 1.0).abs() < 1e-9 {
                return format!("-{axis}");
            }
        }
    }
    let [x, y, z] = g;
    format!("({x:.4}, {y:.4}, {z:.4})")
}

/// The poses of a file with gravity directions: by the `pose` column, else by direction.
pub fn poses_from_oriented(o: &Oriented) -> Result<Vec<Pose>, PoseError> {
    // (key, gravity, rows, first line, times)
    type Group = (String, [f64; 3], Vec<[f64; 3]>, u64, Vec<f64>);
    let mut groups: Vec<Group> = Vec::new();
    for (i, (g, y)) in o.gravity.iter().zip(&o.y).enumerate() {
        let line = o.line.get(i).copied().unwrap_or(0);
        let t = o.t_s.as_ref().and_then(|t| t.get(i).copied());
        // Without names, a pose is one exact direction (named after grouping).
        let key = match &o.pose {
            Some(names) => names.get(i).cloned().unwrap_or_default(),
            None => format!("{:?}", g.map(f64::to_bits)),
        };
        match groups.iter_mut().find(|p| p.0 == key) {
            Some(p) => {
                if p.1.iter().zip(g).any(|(a, b)| (a - b).abs() > 1e-9) {
                    return Err(PoseError::PoseDirection {
                        name: key,
                        first: p.3,
                        line,
                    });
                }
                p.2.push(*y);
                p.4.extend(t);
            }
            None => groups.push((key, *g, vec![*y], line, t.into_iter().collect())),
        }
    }
    let named = o.pose.is_some();
    let mut names: Vec<String> = Vec::new();
    let mut poses: Vec<(Pose, Vec<[f64; 3]>)> = groups
        .into_iter()
        .map(|(key, gravity, rows, first_line, times_s)| {
            let (mean, std) = mean_std(&rows);
            let noise = pose_noise(&rows, &mean);
            let name = if named {
                key
            } else {
                // Directions that print alike get the line of their first reading too.
                let d = direction_name(&gravity);
                let name = if names.contains(&d) {
                    format!("{d} (line {first_line})")
                } else {
                    d
                };
                names.push(name.clone());
                name
            };
            let pose = Pose {
                name,
                gravity,
                n: rows.len(),
                mean,
                std,
                first_line,
                noise,
                angle_direction: None,
                times_s,
            };
            (pose, rows)
        })
        .collect();
    pool_short_poses(&mut poses);
    Ok(poses.into_iter().map(|(p, _)| p).collect())
}

/// The poses of a stepped (condition, angle) record: one per condition and table angle.
pub fn poses_from_conditions(conds: &[StaticCondition<'_>]) -> Vec<Pose> {
    let mut out = Vec::new();
    for g in conds {
        // (angle's bits, readings, their times)
        type Angle = (u64, Vec<[f64; 3]>, Vec<f64>);
        let mut angles: Vec<Angle> = Vec::new();
        for (i, a) in g.angle_deg.iter().enumerate() {
            let y = g.y.map(|c| c.get(i).copied().unwrap_or(f64::NAN));
            let t = g.t_s.get(i).copied();
            match angles.iter_mut().find(|(k, ..)| *k == a.to_bits()) {
                Some((_, rows, times)) => {
                    rows.push(y);
                    times.extend(t);
                }
                None => angles.push((a.to_bits(), vec![y], t.into_iter().collect())),
            }
        }
        for (bits, rows, times_s) in angles {
            let deg = f64::from_bits(bits);
            let (mean, std) = mean_std(&rows);
            let noise = pose_noise(&rows, &mean);
            let pose = Pose {
                name: format!("{} {deg}°", g.condition.letter()),
                gravity: g.condition.gravity_direction(deg.to_radians()),
                n: rows.len(),
                mean,
                std,
                first_line: g.first_line,
                noise,
                angle_direction: Some(
                    g.condition
                        .gravity_direction(deg.to_radians() + std::f64::consts::FRAC_PI_2),
                ),
                times_s,
            };
            out.push((pose, rows));
        }
    }
    pool_short_poses(&mut out);
    out.into_iter().map(|(p, _)| p).collect()
}

#[cfg(test)]
#[allow(clippy::indexing_slicing)]
mod tests {
    use super::*;
    use crate::allan::powerlaw::FlickerIncrements;
    use nalgebra::DMatrix;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    /// The lag sums against P·G·P built whole.
    #[test]
    fn slow_lag_sums_are_those_of_the_demeaned_covariance() {
        let n = 7;
        let structure: [fn(u64) -> f64; 2] = [flicker_structure, |k| k as f64];
        let sums = slow_lag_sums(n, n - 1);
        for (d, got) in structure.iter().zip(&sums) {
            let g = DMatrix::from_fn(n, n, |a, b| -0.5 * d(a.abs_diff(b) as u64));
            let p = DMatrix::identity(n, n) - DMatrix::from_element(n, n, 1.0 / n as f64);
            let c = &p * g * &p;
            for (k, v) in got.iter().enumerate() {
                let want: f64 = (0..n - k).map(|t| c[(t, t + k)]).sum();
                assert!((v - want).abs() < 1e-12, "lag {k}: {v} against {want}");
            }
        }
    }

    /// 36 records of 20 readings, unit white noise plus flicker at 0.4 of it per sample (a
    /// 100 µg floor under 4 counts): the pooled model's mean variance is high by the
    /// flicker's share, and less `slope` times the level it is the white noise's 1/20
    /// (means over 300 replicates).
    #[test]
    fn slow_slope_takes_out_what_flicker_adds_to_the_pooled_mean_variance() {
        let (records, n, level) = (36, 20, 0.4f64);
        let gen = FlickerIncrements::new(n);
        let mut rng = ChaCha8Rng::seed_from_u64(30);
        let (mut raw, mut corrected) = (Vec::new(), Vec::new());
        for _ in 0..300 {
            let resid: Vec<Vec<f64>> = (0..records)
                .map(|_| {
                    let inc = gen.draw(&mut rng);
                    let mut f = 0.0;
                    let x: Vec<f64> = (0..n)
                        .map(|t| {
                            f += if t > 0 { inc[t - 1] } else { 0.0 };
                            rng.sample::<f64, _>(StandardNormal) + level.sqrt() * f
                        })
                        .collect();
                    let mean = x.iter().sum::<f64>() / n as f64;
                    x.iter().map(|v| v - mean).collect()
                })
                .collect();
            let slices: Vec<&[f64]> = resid.iter().map(Vec::as_slice).collect();
            let model = NoiseModel::pooled_about_means(&slices).unwrap();
            let lengths = vec![n; records];
            let var = model.mean_variance(n).unwrap();
            let unit = pooled_unit(&lengths, model.order());
            let s = slope(
                var,
                n,
                &shifted(&model, unit, |m| m.pooled_corrected(&lengths).ok()),
            );
            raw.push(var);
            corrected.push(var - level * s[0]);
        }
        let stats = |v: &[f64]| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            let sd = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt();
            (m, sd / (v.len() as f64).sqrt())
        };
        let ((mr, er), (mc, ec)) = (stats(&raw), stats(&corrected));
        let white = 1.0 / n as f64;
        println!(
            "mean variance: raw {mr:.5} ± {er:.5}, corrected {mc:.5} ± {ec:.5}, white {white}"
        );
        // The flicker adds 76 % here; the correction takes out all but about 3 % of the white
        // level (the pooled model's order, chosen with the flicker in, stays): at least
        // nine tenths of the excess must go, beyond the replicates' scatter.
        assert!(mr - white > 4.0 * er, "raw {mr} ± {er}");
        assert!(
            (mc - white).abs() < 0.1 * (mr - white) + 4.0 * ec,
            "corrected {mc} ± {ec}"
        );
    }
}
