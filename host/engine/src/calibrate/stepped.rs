//! The static methods (Gaitan et al. (2021)): angle steps about the three axes, or poses of known
//! orientation; their entry, budget and corrections.

use super::budget::{Budget, Kind};
use super::json::{self, CorrectionJson};
use super::poses::{self, StaticCondition};
use super::sources::{gravity_source, new_budget, values6, variances6};
use super::{
    correction, err, methods, CalibrateError, CalibrateErrorKind, Options, Preflight, TypeB,
};
use crate::recording::Recording;
use nalgebra::{DMatrix, Vector3};
use rotacal_shared::intrinsic::{self, IntrinsicError};

/// The pose fit's options with the stated table-angle uncertainty.
fn pose_options(opts: &Options, inputs: &TypeB) -> poses::Options {
    poses::Options {
        u_angle_rad: inputs.u_angle_deg.map(f64::to_radians),
        slow: opts.slow_noise,
        ..opts.poses
    }
}

/// The static methods' entry: from angle steps about the three axes, or from poses of known
/// orientation (`gx, gy, gz` columns).
pub(super) fn entry(
    rec: &Recording,
    opts: &Options,
    pre: &Preflight,
) -> Result<json::RateJson, CalibrateError> {
    let options = pose_options(opts, &pre.inputs);
    let cal = match &rec.oriented {
        Some(oriented) => {
            let poses = poses::poses_from_oriented(oriented).map_err(|e| {
                let line = match &e {
                    poses::PoseError::PoseDirection { line, .. } => Some(*line),
                    _ => None,
                };
                err(rec, line, e)
            })?;
            methods::from_poses(poses, pre.g_loc, options)
        }
        None => {
            let mut conds = Vec::with_capacity(rec.groups.len());
            for grp in &rec.groups {
                if grp.angle_deg.len() != grp.u.len() {
                    return Err(err(rec, Some(grp.first_line), CalibrateErrorKind::NoAngle));
                }
                conds.push(StaticCondition {
                    condition: grp.condition,
                    angle_deg: &grp.angle_deg,
                    y: [&grp.u, &grp.v, &grp.w],
                    t_s: &grp.t_s,
                    first_line: grp.first_line,
                });
            }
            methods::static_method(&conds, pre.g_loc, options)
        }
    }
    .map_err(|e| err(rec, None, e))?;
    static_json(rec, &cal, opts, pre)
}

/// The entry of a static calibration: its budget, Monte Carlo if asked, and corrections.
fn static_json(
    rec: &Recording,
    cal: &methods::StaticCalibration,
    opts: &Options,
    pre: &Preflight,
) -> Result<json::RateJson, CalibrateError> {
    let units = pre.units.as_str();
    let budget = static_budget(cal, pre.g_loc, &pre.inputs, units)
        .map_err(|e| err(rec, None, CalibrateErrorKind::StaticBudget(e)))?;
    let mut entry = json::static_entry(cal, &budget).ok_or_else(|| {
        err(
            rec,
            None,
            CalibrateErrorKind::Internal("a budget without a line per property"),
        )
    })?;
    entry.uncertainty_budget = Some(budget);
    if let Some(trials) = opts.monte_carlo {
        let mc = methods::monte_carlo_static(cal, trials, 1).map_err(|cause| {
            err(
                rec,
                None,
                CalibrateErrorKind::MonteCarlo {
                    rate_hz: None,
                    cause,
                },
            )
        })?;
        entry.monte_carlo = Some(json::mc_map(mc));
    }
    let (device, platter) = static_correction(cal).map_err(|e| err(rec, None, e))?;
    let source = match cal.pose_fit.options.offsets {
        poses::OffsetEstimator::Joint => "the joint fit of S and O to all poses",
        poses::OffsetEstimator::AxisPairs => {
            "the up/down pair of each channel's own axis (imucal's estimator)"
        }
    };
    entry.correction = Some(CorrectionJson::new(
        units,
        device,
        Some(platter),
        cal.pose_fit.k,
        source,
    ));
    Ok(entry)
}

/// Both corrections of a static calibration. The covariance of (S, O) is the pose fit's,
/// with the variances the JSON reports for S and O ([`poses::PoseFit::cov_weighed`]);
/// imucal's offsets are taken as uncorrelated with S (with balanced up/down poses their
/// correlation is zero).
pub fn static_correction(
    cal: &methods::StaticCalibration,
) -> Result<(correction::Correction, correction::Correction), correction::CorrectionError> {
    let joint = cal.pose_fit.options.offsets == poses::OffsetEstimator::Joint;
    let full = &cal.pose_fit.cov_weighed();
    let (rows, cols) = full.shape();
    let mut cov = DMatrix::from_iterator(rows, cols, full.iter().copied());
    if !joint {
        // imucal's offsets: S's block kept, the offsets' rows and columns their variances.
        cov.view_mut((9, 0), (3, 12)).fill(0.0);
        cov.view_mut((0, 9), (12, 3)).fill(0.0);
        cov.view_mut((9, 9), (3, 3))
            .set_diagonal(&Vector3::from(cal.offsets.map(|o| o.std_unc.powi(2))));
    }
    correction::from_matrix(&cal.s, cal.offsets.map(|o| o.value), &cov)
}

/// The static methods' budget: the parts of the pose fit's covariance (the readings'
/// noise, the poses' tilt, the stated table angles; or each channel's own scatter) and
/// g_loc (S ∝ 1/g_loc; angles and offsets do not depend on it).
pub fn static_budget(
    cal: &methods::StaticCalibration,
    g: f64,
    inputs: &TypeB,
    units: &str,
) -> Result<Budget, IntrinsicError> {
    let mut b = new_budget(units, true);
    let fit = &cal.pose_fit;
    let values = values6(&cal.intrinsic);
    // Each part's variance of the nine properties, and its degrees of freedom.
    let forms = |part: &poses::CovPart| -> Result<[f64; 9], IntrinsicError> {
        let s_part = poses::s_block(&part.theta);
        let prop = intrinsic::from_matrix_cov(&cal.s, &s_part)?;
        let mut var = [0.0; 9];
        for (v, d) in var.iter_mut().zip(variances6(&prop.cov)) {
            *v = d;
        }
        for (v, o) in var.iter_mut().skip(6).zip(fit.offset_var(part)) {
            *v = o;
        }
        Ok(var)
    };
    // Each part's variances (the unit tilt's too), computed once.
    let unit = fit.tilt_scale.as_ref().map(|t| &t.unit);
    let slow_units = fit.slow.iter().flat_map(|s| {
        s.channels
            .iter()
            .flat_map(|c| c.units.iter().chain(&c.noise_slope))
    });
    let cache = fit
        .parts
        .iter()
        .chain(unit)
        .chain(slow_units)
        .map(|c| Ok((c, forms(c)?)))
        .collect::<Result<Vec<_>, IntrinsicError>>()?;
    // Per quantity, each part's variance.
    let mut by_quantity: [Vec<(&poses::CovPart, f64)>; 9] = Default::default();
    for (part, var) in &cache {
        for (list, v) in by_quantity.iter_mut().zip(var) {
            list.push((*part, *v));
        }
    }
    for (part, var) in &cache {
        if part.source == poses::PartSource::TableAngle {
            let u = inputs.u_angle_deg.unwrap_or(f64::NAN);
            let sd: Vec<f64> = var.iter().map(|v| v.max(0.0).sqrt()).collect();
            b.vector(
                "table_angle",
                Kind::B,
                format!(
                    "each table angle off by u = {u} deg (stated; independent from step to \
                     step), moving ĝ along the rotation; through the joint fit"
                ),
                &sd,
                &[None; 9],
            );
        }
    }
    let weigh = fit.weighing();
    let (contribution, dof): (Vec<f64>, Vec<Option<f64>>) = by_quantity
        .iter()
        .map(|list| {
            let of = |c: &poses::CovPart| {
                list.iter()
                    .find(|(p, _)| std::ptr::eq(*p, c))
                    .map_or(0.0, |(_, v)| *v)
            };
            let (var, nu) = weigh.poses(of);
            (var.max(0.0).sqrt(), nu.is_finite().then_some(nu))
        })
        .unzip();
    let description = match fit.scatter {
        poses::Scatter::PerChannel => "the least-squares fit of S and O to the pose means \
             (JSON poses), each channel alone with its variance from the poses' scatter and its \
             degrees of freedom"
            .to_string(),
        poses::Scatter::None
            if fit
                .parts
                .iter()
                .any(|p| matches!(p.source, poses::PartSource::Channel(_))) =>
        {
            "the least-squares fit of S and O to the pose means (JSON poses), each channel alone \
             with its variance from its readings' noise"
                .to_string()
        }
        poses::Scatter::None => format!(
            "the readings' noise within each pose (JSON poses) through the joint fit of S and \
             O; no tilt estimated (joint χ²/dof = {}), so each quantity's share that a tilt \
             would move is scaled by χ²/dof with 3P − 12 degrees of freedom, the rest keeps \
             the readings' (JSON poses.list[].noise[].dof; docs/uncertainty.md)",
            fit.chi2_dof
                .map_or("undefined".to_string(), |q| format!("{q:.3}"))
        ),
        poses::Scatter::Slow => "the least-squares fit of S and O to the pose means (JSON \
             poses) at the weights of their readings' noise, each channel alone; its variance \
             from that noise and from flicker and a bias random walk in session time, their \
             levels estimated from the pose residuals (JSON poses.slow_noise); degrees of \
             freedom by Welch–Satterthwaite from the readings' (JSON poses.list[].noise[].dof) \
             and the levels' covariance. The offsets are the bias averaged over the record's readings \
             (docs/uncertainty.md)"
            .to_string(),
        poses::Scatter::Tilt { sd_deg } => format!(
            "the readings' noise within each pose and a random tilt of each pose off its \
             nominal direction of {sd_deg:.2e}° per axis (standard deviation), estimated so that \
             the joint fit's χ² equals its 3P − 12 degrees of freedom; degrees of freedom \
             between those and the readings' (JSON poses.list[].noise[].dof) by how much a \
             tilt moves each quantity (docs/uncertainty.md)"
        ),
    };
    b.vector("poses", Kind::A, description, &contribution, &dof);
    b.notes.extend(fit.notes.iter().cloned());
    let mut cg = vec![0.0; 9];
    for (c, v) in cg.iter_mut().zip(values.iter().take(3)) {
        *c = -v / g;
    }
    gravity_source(&mut b, g, inputs.u_g_loc, &cg);
    if inputs.u_time_s.is_some() {
        b.notes
            .push("u_time_s was given but a static calibration does not use the timestamps".into());
    }
    b.combine();
    Ok(b)
}
