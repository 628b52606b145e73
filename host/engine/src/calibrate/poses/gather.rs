//! The poses from the readings: repeated readings at one orientation averaged into a
//! pose mean, with its standard error from the readings' own noise.

use super::{Pose, PoseError, PoseNoise, StaticCondition, NOISE_MODEL_MIN};
use crate::calibrate::still::median;
use crate::recording::Oriented;
use rotacal_shared::Channel;

/// Each channel's noise model at a pose, when it has enough readings: the mean's variance
/// is the AR sandwich for a regressor of ones. A channel whose model cannot be made (a
/// constant reading, say) keeps std/√n.
fn pose_noise(rows: &[[f64; 3]], mean: &[f64; 3]) -> Option<[Option<PoseNoise>; 3]> {
    if rows.len() < NOISE_MODEL_MIN {
        return None;
    }
    let ones = nalgebra::DMatrix::from_element(rows.len(), 1, 1.0);
    Some(Channel::ALL.map(|j| {
        let resid: Vec<f64> = rows.iter().map(|r| j.of(r) - j.of(mean)).collect();
        let (m, cov) = crate::fit::noise::NoiseModel::estimate(&resid, &[])
            .ok()?
            .regression_cov(&ones)
            .ok()?;
        let var = *cov.get((0, 0))?;
        Some(PoseNoise {
            lag1: m.autocorrelation(1),
            order: m.order(),
            se: var.max(0.0).sqrt(),
            n_eff: m.var / var,
            dof: rows.len().saturating_sub(1) as f64,
        })
    }))
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
        let model = crate::fit::noise::NoiseModel::pooled_about_means(&records).ok()?;
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
        Some((model, dof))
    });
    if models.iter().all(Option::is_none) {
        return;
    }
    for (pose, _) in poses.iter_mut().filter(|(p, _)| short(p)) {
        let n = pose.n;
        pose.noise = Some(Channel::ALL.map(|j| {
            let (m, dof) = j.of(&models).as_ref()?;
            let var = m.mean_variance(n).ok()?;
            Some(PoseNoise {
                lag1: m.autocorrelation(1),
                order: m.order(),
                se: var.max(0.0).sqrt(),
                n_eff: m.var / var,
                dof: *dof,
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
