//! `rotacal calibrate`: from a recording to the calibration JSON and a terminal table.
//!
//! Rotation files: per nominal rate and condition, the IEEE 1057 fit tests whether the
//! data's rotation rate differs from nominal (by more than 3 standard errors); if so that
//! rate is used (and reported as `rate_hz_fitted`). Each channel is then fitted with the
//! streaming fit in f64, and the intrinsic properties come from the Gram matrix.
//! Timestamps are converted to ticks of a 1 MHz clock (t_s has microsecond resolution in
//! every writer we know of).

use crate::batch;
use crate::calibrate::{self, StaticCondition};
use crate::calibration_file::{self, CalibrationJson, CorrectionJson, FitJson};
use crate::correction;
use crate::orientation;
use crate::recording::{Group, Method, Recording};
use nalgebra::DMatrix;
use rotacal_shared::{Condition, FitConfig, FitResult, Param, PhaseStep, SineFit, TickRate, Ticks};
use std::fmt::Write as _;

/// Command-line choices, which override the file's metadata.
#[derive(Clone, Debug, Default)]
pub struct Options {
    /// Force the method.
    pub method: Option<Method>,
    /// Nominal rotation rate, Hz.
    pub rate_hz: Option<f64>,
    /// Local gravity, m/s².
    pub g_loc: Option<f64>,
    /// Also propagate by Monte Carlo (GUM Supplement 1) with this many trials.
    pub monte_carlo: Option<usize>,
    /// Static data: pose weighting and offset estimator.
    pub poses: orientation::Options,
}

/// A calibration failure, naming the file and, where it applies, the line.
#[derive(Debug, thiserror::Error)]
#[error("{source_name}{}: {message}", line.map(|l| format!(":{l}")).unwrap_or_default())]
pub struct CalibrateError {
    /// The recording.
    pub source_name: String,
    /// First line of the data concerned.
    pub line: Option<u64>,
    /// What is wrong.
    pub message: String,
}

/// The clock rotation timestamps are converted to (t_s has microsecond resolution).
pub const CLOCK: TickRate = TickRate::MHZ_1;

fn err(rec: &Recording, line: Option<u64>, message: impl Into<String>) -> CalibrateError {
    CalibrateError {
        source_name: rec.source.clone(),
        line,
        message: message.into(),
    }
}

/// A group's samples as (ticks of the 1 MHz clock from its first row, [u, v, w]): the
/// times and phases every rotation fit here uses.
pub fn samples(rec: &Recording, g: &Group) -> Result<Vec<(Ticks, [f64; 3])>, CalibrateError> {
    let t0 = g.t_s.first().copied().unwrap_or(0.0);
    g.t_s
        .iter()
        .zip(g.u.iter().zip(g.v.iter().zip(g.w.iter())))
        .map(|(t, (u, (v, w)))| {
            let ticks = ((t - t0) * f64::from(CLOCK.hz())).round();
            if !(0.0..1.8e19).contains(&ticks) {
                return Err(err(rec, Some(g.first_line), "t_s out of range"));
            }
            Ok((Ticks(ticks as u64), [*u, *v, *w]))
        })
        .collect()
}

fn fit_group(
    rec: &Recording,
    g: &Group,
    nominal_hz: f64,
) -> Result<(FitResult<f64>, Option<f64>), CalibrateError> {
    let cond = g.condition.letter();
    let s = samples(rec, g)?;
    let nominal = PhaseStep::from_hz(nominal_hz, CLOCK).ok_or_else(|| {
        err(
            rec,
            Some(g.first_line),
            format!("rotation rate {nominal_hz} Hz is not usable"),
        )
    })?;
    let streaming = |step| -> Result<FitResult<f64>, CalibrateError> {
        let mut fit = SineFit::<f64>::new(FitConfig::sine(step, CLOCK));
        for (t, y) in &s {
            fit.update(*t, *y)
                .map_err(|e| err(rec, Some(g.first_line), format!("condition {cond}: {e}")))?;
        }
        fit.solve()
            .map_err(|e| err(rec, Some(g.first_line), format!("condition {cond}: {e}")))
    };
    // Fitted first at the nominal rate: this also checks the span, so a short record gets
    // the plain 'too few periods' message rather than a failure of the rate fit.
    let at_nominal = streaming(nominal)?;
    let four = batch::fit_four_param(&s, nominal, CLOCK).map_err(|e| {
        err(
            rec,
            Some(g.first_line),
            format!("condition {cond}: rate fit: {e}"),
        )
    })?;
    if (four.rate_hz - nominal_hz).abs() > 3.0 * four.se_rate_hz {
        let step = PhaseStep::from_hz(four.rate_hz, CLOCK)
            .ok_or_else(|| err(rec, Some(g.first_line), "fitted rate unusable"))?;
        Ok((streaming(step)?, Some(four.rate_hz)))
    } else {
        Ok((at_nominal, None))
    }
}

fn fit_json(cond: Condition, r: &FitResult<f64>, rate: Option<f64>) -> Vec<FitJson> {
    ['u', 'v', 'w']
        .iter()
        .enumerate()
        .map(|(ch, name)| {
            let c = |p| r.coef(ch, p).map(|v| v.to_f64()).unwrap_or(f64::NAN);
            let se = |p| r.se(ch, p).unwrap_or(f64::NAN);
            FitJson {
                condition: cond.letter().to_string(),
                channel: name.to_string(),
                a: c(Param::A),
                b: c(Param::B),
                c: c(Param::C),
                se_a: se(Param::A),
                se_b: se(Param::B),
                se_c: se(Param::C),
                n: u64::from(r.n),
                rms_residual: r.channels[ch].rms_residual,
                rate_hz_fitted: rate,
            }
        })
        .collect()
}

/// Calibrate a recording.
pub fn calibrate(rec: &Recording, opts: &Options) -> Result<CalibrationJson, CalibrateError> {
    let g = opts.g_loc.or(rec.meta.g_loc).ok_or_else(|| {
        err(
            rec,
            None,
            "local gravity unknown: give --g-loc or a '# g_loc=' line",
        )
    })?;
    if !(g.is_finite() && g > 0.0) {
        return Err(err(
            rec,
            None,
            format!("g_loc {g} is not a positive number"),
        ));
    }
    let method = opts.method.unwrap_or(rec.method);
    let units = rec
        .meta
        .units
        .clone()
        .unwrap_or_else(|| "output units".into());
    let mut by_rate = Vec::new();
    match method {
        Method::Rotation => {
            rec.require_conditions("rotation calibration")
                .map_err(|e| err(rec, None, e.kind.to_string()))?;
            for rate in rec.rates() {
                let nominal = rate
                    .or(opts.rate_hz)
                    .or(rec.meta.rate_hz)
                    .ok_or_else(|| err(rec, None, "rotation rate unknown: give --rate-hz, a '# rate_hz=' line or a rate_hz column"))?;
                let mut fits = Vec::new();
                let mut json_fits = Vec::new();
                for cond in Condition::ALL {
                    let grp = rec.group(cond, rate).ok_or_else(|| {
                        err(
                            rec,
                            None,
                            format!("condition {} missing at {nominal} Hz", cond.letter()),
                        )
                    })?;
                    if grp.t_s.len() != grp.u.len() {
                        return Err(err(
                            rec,
                            Some(grp.first_line),
                            "rotation needs a t_s column",
                        ));
                    }
                    let (fit, fitted) = fit_group(rec, grp, nominal)?;
                    json_fits.extend(fit_json(cond, &fit, fitted));
                    fits.push(fit);
                }
                let [fx, fy, fz] = fits.as_slice() else {
                    return Err(err(rec, None, "expected three conditions"));
                };
                let cal = calibrate::rotation([fx, fy, fz], g, 0.0)
                    .map_err(|e| err(rec, None, format!("at {nominal} Hz: {e}")))?;
                let mut entry = calibration_file::rotation_entry(nominal, &cal, json_fits);
                let device = rotation_correction([fx, fy, fz], g)
                    .map_err(|e| err(rec, None, format!("at {nominal} Hz: {e}")))?;
                entry.correction = Some(CorrectionJson::new(
                    &units,
                    device,
                    None,
                    calibration_file::K,
                    "the mean of the three conditions' C at this rate: it includes the \
                     centripetal acceleration ω²·r of a sensor off the axis, which one rate \
                     cannot separate",
                ));
                if let Some(trials) = opts.monte_carlo {
                    let cf = [fx, fy, fz].map(calibrate::condition_fit);
                    let mc = calibrate::monte_carlo_rotation(&cf, g, trials, 1)
                        .map_err(|e| err(rec, None, format!("Monte Carlo at {nominal} Hz: {e}")))?;
                    entry.monte_carlo = Some(calibration_file::mc_map(mc));
                }
                by_rate.push(entry);
            }
            if by_rate.len() >= 2 {
                offsets_at_rest(&mut by_rate).map_err(|e| err(rec, None, e))?;
            }
        }
        Method::Static if rec.oriented.is_some() => {
            let poses = rec
                .oriented
                .as_ref()
                .map(orientation::poses_from_oriented)
                .transpose()
                .map_err(|e| {
                    let line = match &e {
                        orientation::PoseError::PoseDirection { line, .. } => Some(*line),
                        _ => None,
                    };
                    err(rec, line, e.to_string())
                })?
                .unwrap_or_default();
            let cal = calibrate::from_poses(poses, g, opts.poses)
                .map_err(|e| err(rec, None, e.to_string()))?;
            by_rate.push(static_json(rec, &cal, opts, &units)?);
        }
        Method::Static => {
            let mut conds = Vec::new();
            for grp in &rec.groups {
                if grp.angle_deg.len() != grp.u.len() {
                    return Err(err(
                        rec,
                        Some(grp.first_line),
                        "static calibration needs an angle_deg column",
                    ));
                }
                conds.push(StaticCondition {
                    condition: grp.condition,
                    angle_deg: &grp.angle_deg,
                    y: [&grp.u, &grp.v, &grp.w],
                    first_line: grp.first_line,
                });
            }
            let cal = calibrate::static_method(&conds, g, opts.poses)
                .map_err(|e| err(rec, None, e.to_string()))?;
            by_rate.push(static_json(rec, &cal, opts, &units)?);
        }
    }
    Ok(CalibrationJson {
        method: method.as_str().to_string(),
        g_loc: g,
        units,
        by_rate,
    })
}

/// Multi-rate rotation: each condition's C_j against ω² is a line whose intercept is the
/// offset at rest (the centripetal term grows as ω²·r); O_j is the mean of the three
/// conditions' intercepts, and every rate's correction gets it.
fn offsets_at_rest(by_rate: &mut [calibration_file::RateJson]) -> Result<(), String> {
    let mut offset = [0.0; 3];
    let mut var = [0.0; 3];
    for cond in ["x", "y", "z"] {
        for (j, ch) in ["u", "v", "w"].iter().enumerate() {
            // (ω², C, se_C) over the rates.
            let pts: Vec<(f64, f64, f64)> = by_rate
                .iter()
                .filter_map(|r| {
                    let f = r
                        .fits
                        .iter()
                        .find(|f| f.condition == cond && f.channel == *ch)?;
                    let hz = f.rate_hz_fitted.or(r.rate_hz)?;
                    Some(((std::f64::consts::TAU * hz).powi(2), f.c, f.se_c))
                })
                .collect();
            // Weighted line C = O + b·ω².
            let (mut s, mut sx, mut sxx, mut sy, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for (x, y, se) in &pts {
                let w = 1.0 / (se * se);
                s += w;
                sx += w * x;
                sxx += w * x * x;
                sy += w * y;
                sxy += w * x * y;
            }
            let det = s * sxx - sx * sx;
            if !(det.is_finite() && det > 0.0) {
                return Err(format!(
                    "condition {cond}, channel {ch}: the offsets against ω² cannot be fitted"
                ));
            }
            offset[j] += (sxx * sy - sx * sxy) / det / 3.0;
            var[j] += sxx / det / 9.0;
        }
    }
    let source = format!(
        "each condition's C at ω = 0 from a line C = O + b·ω² over {} rates (the \
         centripetal term removed), averaged over the three conditions",
        by_rate.len()
    );
    for r in by_rate.iter_mut() {
        if let Some(c) = r.correction.as_mut() {
            let d = &mut c.device_frame;
            for j in 0..3 {
                d.offset[j] = offset[j];
                d.offset_std_unc[j] = var[j].sqrt();
                for (k, row) in d.covariance.iter_mut().enumerate() {
                    for (l, x) in row.iter_mut().enumerate() {
                        if k == 9 + j || l == 9 + j {
                            *x = if k == l { var[j] } else { 0.0 };
                        }
                    }
                }
            }
            c.offset_source = source.clone();
        }
    }
    Ok(())
}

fn static_json(
    rec: &Recording,
    cal: &calibrate::StaticCalibration,
    opts: &Options,
    units: &str,
) -> Result<calibration_file::RateJson, CalibrateError> {
    let mut entry = calibration_file::static_entry(cal);
    if let Some(trials) = opts.monte_carlo {
        let mc = calibrate::monte_carlo_static(cal, trials, 1)
            .map_err(|e| err(rec, None, format!("Monte Carlo: {e}")))?;
        entry.monte_carlo = Some(calibration_file::mc_map(mc));
    }
    let (device, platter) = static_correction(cal).map_err(|e| err(rec, None, e.to_string()))?;
    let source = match cal.pose_fit.options.offsets {
        orientation::OffsetEstimator::Joint => "the joint fit of S and O to all poses",
        orientation::OffsetEstimator::AxisPairs => {
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
/// channel by channel; imucal's offsets are taken as uncorrelated with S (with balanced
/// up/down poses their correlation is zero).
pub fn static_correction(
    cal: &calibrate::StaticCalibration,
) -> Result<(correction::Correction, correction::Correction), correction::CorrectionError> {
    let mut cov = DMatrix::zeros(correction::PARAMS, correction::PARAMS);
    let joint = cal.pose_fit.options.offsets == orientation::OffsetEstimator::Joint;
    for (j, ch) in cal.pose_fit.channels.iter().enumerate() {
        let idx = |a: usize| if a < 3 { 3 * j + a } else { 9 + j };
        for a in 0..4 {
            for b in 0..4 {
                if joint || (a < 3 && b < 3) {
                    cov[(idx(a), idx(b))] = ch.cov[a][b];
                }
            }
        }
        if !joint {
            cov[(9 + j, 9 + j)] = cal.offsets[j].std_unc.powi(2);
        }
    }
    correction::from_matrix(&cal.s, cal.offsets.map(|o| o.value), &cov)
}

/// The device-frame correction of a rotation calibration: M from the Gram matrix of the
/// three conditions' (A, B) (method.md §2) with their covariances; O_j the mean of the
/// three conditions' C_j (over whole turns the mean of ĝ is zero, so C_j = O_j).
pub fn rotation_correction(
    fits: [&FitResult<f64>; 3],
    g: f64,
) -> Result<correction::Correction, correction::CorrectionError> {
    let cf = fits.map(calibrate::condition_fit);
    let mut theta = Vec::with_capacity(18);
    let mut cov = DMatrix::zeros(18, 18);
    for (c, f) in cf.iter().enumerate() {
        for j in 0..3 {
            let base = 6 * c + 2 * j;
            theta.extend([f.a[j], f.b[j]]);
            for a in 0..2 {
                for b in 0..2 {
                    cov[(base + a, base + b)] = f.cov[j][a][b];
                }
            }
        }
    }
    let gram = move |t: &[f64]| -> Option<[[f64; 3]; 3]> {
        let mut gm = [[0.0; 3]; 3];
        for c in 0..3 {
            for (j, row) in gm.iter_mut().enumerate() {
                for (k, x) in row.iter_mut().enumerate() {
                    let (aj, bj) = (t.get(6 * c + 2 * j)?, t.get(6 * c + 2 * j + 1)?);
                    let (ak, bk) = (t.get(6 * c + 2 * k)?, t.get(6 * c + 2 * k + 1)?);
                    *x += (aj * ak + bj * bk) / (2.0 * g * g);
                }
            }
        }
        Some(gm)
    };
    let mut offset = [0.0; 3];
    let mut offset_std = [0.0; 3];
    for j in 0..3 {
        let cs: Vec<(f64, f64)> = fits
            .iter()
            .map(|r| {
                (
                    r.coef(j, Param::C).map(|v| v.to_f64()).unwrap_or(f64::NAN),
                    r.se(j, Param::C).unwrap_or(f64::NAN),
                )
            })
            .collect();
        offset[j] = cs.iter().map(|c| c.0).sum::<f64>() / 3.0;
        offset_std[j] = cs.iter().map(|c| c.1 * c.1).sum::<f64>().sqrt() / 3.0;
    }
    correction::from_gram(&gram, &theta, &cov, offset, offset_std)
}

fn render_poses(p: &calibration_file::PosesJson, units: &str) -> String {
    let mut o = String::new();
    let _ = writeln!(
        o,
        "  {} poses, condition number {:.2}; weights {}; between-pose scatter τ = {:.2e} {:.2e} {:.2e} {units}",
        p.list.len(),
        p.condition_number,
        match p.weights {
            orientation::Weights::RandomEffects => "1/(se² + τ²)",
            orientation::Weights::Equal => "equal",
        },
        p.tau[0],
        p.tau[1],
        p.tau[2]
    );
    if let Some(s) = &p.suggestion {
        let _ = writeln!(
            o,
            "  WARNING: poorly conditioned (> {}): add a pose with gravity along {s}",
            orientation::WELL_CONDITIONED
        );
    }
    if !p.not_still.is_empty() {
        let _ = writeln!(
            o,
            "  WARNING: not still (std > {}× the median pose's): {}",
            orientation::NOT_STILL_FACTOR,
            p.not_still.join(", ")
        );
    }
    let _ = writeln!(
        o,
        "    {:<12} {:>9} {:>6}  {:<26}  {:<29}",
        "pose", "ĝ", "n", "std u v w (how still)", "residual u v w (mean − model)"
    );
    for q in &p.list {
        let std = q
            .std
            .map(|s| format!("{:.2e} {:.2e} {:.2e}", s[0], s[1], s[2]))
            .unwrap_or_else(|| "single reading".into());
        let _ = writeln!(
            o,
            "    {:<12} {:>9} {:>6}  {:<26}  {:+.2e} {:+.2e} {:+.2e}",
            q.name,
            orientation::direction_name(&q.gravity),
            q.n,
            std,
            q.residual[0],
            q.residual[1],
            q.residual[2]
        );
    }
    if let (Some(d), Some(a)) = (p.offsets_difference, &p.offsets_axis_pairs) {
        let _ = writeln!(
            o,
            "  offsets, joint fit − up/down pair of each axis (imucal's): {:+.6} {:+.6} {:+.6} {units} \
             (axis pairs: {:.6} {:.6} {:.6})",
            d[0], d[1], d[2], a.u.value, a.v.value, a.w.value
        );
    }
    o
}

/// Decimal places that show `u` to two significant digits (at most 12).
pub fn decimals(u: f64) -> usize {
    if !(u.is_finite() && u > 0.0) {
        return 6;
    }
    (1.0 - u.log10().floor()).clamp(0.0, 12.0) as usize
}

/// The terminal table: value ± U (k = 2) with units, U to two significant digits.
pub fn render(c: &CalibrationJson) -> String {
    let mut o = String::new();
    let su = format!("{} per m/s²", c.units);
    let _ = writeln!(
        o,
        "method {}, g_loc = {} m/s²; ± is the expanded uncertainty U (95 %, k = 2 unless stated)",
        c.method, c.g_loc
    );
    for r in &c.by_rate {
        let rate = r
            .rate_hz
            .map(|f| format!("rotation at {f} Hz"))
            .unwrap_or_else(|| "static".into());
        let _ = writeln!(o, "\n{rate}");
        if let Some(p) = &r.poses {
            if (p.k - calibration_file::K).abs() > 1e-12 {
                let nu = p.nu.iter().fold(f64::INFINITY, |a, b| a.min(*b));
                let why = if p.tau.iter().any(|t| *t > 0.0) {
                    format!(
                        "the poses' scatter about the model, estimated from {} poses − 4",
                        p.list.len()
                    )
                } else {
                    "the readings' scatter within the poses".to_string()
                };
                let _ = writeln!(o, "  k = {:.2}: Student's t for ν = {nu} ({why})", p.k);
            }
        }
        let q = |name: &str, x: &calibration_file::Quantity, unit: &str| {
            let d = decimals(x.expanded_unc);
            format!(
                "  {name:<7} {:>16.d$} ± {:<12.d$} {unit}\n",
                x.value, x.expanded_unc
            )
        };
        let s = &r.intrinsic.sensitivity;
        let a = &r.intrinsic.angle_deg;
        o += &q("s_u", &s.u, &su);
        o += &q("s_v", &s.v, &su);
        o += &q("s_w", &s.w, &su);
        o += &q("φ_uv", &a.uv, "°");
        o += &q("φ_vw", &a.vw, "°");
        o += &q("φ_wu", &a.wu, "°");
        if let Some(off) = &r.intrinsic.offset {
            o += &q("O_u", &off.u, &c.units);
            o += &q("O_v", &off.v, &c.units);
            o += &q("O_w", &off.w, &c.units);
        }
        if let Some(p) = &r.poses {
            o += &render_poses(p, &c.units);
        }
        if let Some(cj) = &r.correction {
            let d = &cj.device_frame;
            let _ = writeln!(
                o,
                "  correction a = M·(y − O) to m/s² (device frame; JSON 'correction'; rotacal apply/export):"
            );
            for (i, row) in d.matrix.iter().enumerate() {
                let _ = writeln!(
                    o,
                    "    M[{i}] = [{:+.8} {:+.8} {:+.8}]  O[{i}] = {:+.6} {}",
                    row[0], row[1], row[2], d.offset[i], cj.units_in
                );
            }
        }
        if let Some(p) = &r.angle_deg_phase_method {
            let _ = writeln!(o, "  phase-difference angles (seed 000 eqs. 12–16, for comparison; biased when tilted):");
            o += &q("φ_uv", &p.uv, "°");
            o += &q("φ_vw", &p.vw, "°");
            o += &q("φ_wu", &p.wu, "°");
        }
        if let Some(mc) = &r.monte_carlo {
            let _ = writeln!(
                o,
                "  Monte Carlo (GUM S1) check: standard uncertainty and 95 % interval"
            );
            for (key, linear) in calibration_file::MC_KEYS
                .iter()
                .zip([&s.u, &s.v, &s.w, &a.uv, &a.vw, &a.wu])
            {
                if let Some(m) = mc.get(*key) {
                    let _ = writeln!(
                        o,
                        "  {key:<7} u = {:.6} (linear {:.6}), [{:.6}, {:.6}]",
                        m.std_unc, linear.std_unc, m.low_95, m.high_95
                    );
                }
            }
        }
        let fitted: Vec<String> = r
            .fits
            .iter()
            .filter(|f| f.channel == "u")
            .filter_map(|f| {
                f.rate_hz_fitted
                    .map(|h| format!("{} {h:.9} Hz", f.condition))
            })
            .collect();
        if !fitted.is_empty() {
            let _ = writeln!(
                o,
                "  rate differs from nominal; fitted: {}",
                fitted.join(", ")
            );
        }
    }
    o
}
