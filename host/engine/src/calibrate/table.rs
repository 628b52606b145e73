//! The terminal summary of a calibration (`rotacal calibrate` without `--quiet`): the
//! intrinsic properties with their expanded uncertainties, the correction, the noise model
//! per channel, the pose fit's scatter and the uncertainty budget, all from the
//! calibration JSON it summarises, so the table and the file cannot disagree.

use super::budget::{Budget, Kind};
use super::json::{self, CalibrationJson, FreeJson, NoiseJson, PosesJson, RateJson};
use super::methods::McSummary;
use super::poses;
use rotacal_shared::Channel;
use std::collections::BTreeMap;
use std::fmt::Write as _;

fn render_poses(p: &json::PosesJson, units: &str) -> String {
    let mut o = String::new();
    let tau = format!(
        "τ = {:.2e} {:.2e} {:.2e} {units}",
        p.tau[0], p.tau[1], p.tau[2]
    );
    let scatter = match (p.scatter, p.chi2_dof_joint) {
        (poses::Scatter::None, Some(q)) => format!("{} (joint χ²/dof = {q:.2})", p.scatter),
        (poses::Scatter::None, None) => p.scatter.to_string(),
        (poses::Scatter::Slow, _) => format!(
            "{}; the offsets are the bias averaged over the readings",
            p.scatter
        ),
        _ => format!("{}: {tau}", p.scatter),
    };
    let _ = writeln!(
        o,
        "  {} poses, condition number {:.2}; weights {}; {scatter}",
        p.list.len(),
        p.condition_number,
        match (
            p.weights,
            p.chi2_dof_joint.is_some() || p.scatter != poses::Scatter::PerChannel
        ) {
            (poses::Weights::Equal, _) => "equal",
            _ if p.scatter == poses::Scatter::Slow => "1/se² (the readings' own noise)",
            (_, true) => "the inverse of each pose mean's covariance (u, v, w together)",
            (_, false) => "1/(se² + τ²)",
        },
    );
    if let Some(slow) = &p.slow_noise {
        o += &render_poses_slow(slow);
    }
    if let Some(s) = &p.suggestion {
        let _ = writeln!(
            o,
            "  WARNING: poorly conditioned (> {}): add a pose with gravity along {s}",
            poses::WELL_CONDITIONED
        );
    }
    if !p.not_still.is_empty() {
        let _ = writeln!(
            o,
            "  WARNING: not still (std > {}× the median pose's): {}",
            poses::NOT_STILL_FACTOR,
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
            poses::direction_name(&q.gravity),
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

/// The budget as a table: each source's contribution (standard uncertainty) per property,
/// then the combined u, ν_eff, k and the dominant source; and a warning for what it lacks.
pub fn render_budget(b: &Budget) -> String {
    let mut o = String::new();
    let _ = writeln!(
        o,
        "  uncertainty budget: each source's standard uncertainty in each property (JSON uncertainty_budget)"
    );
    let mut head = format!("    {:<12} {:<4} {:>16}", "source", "type", "u(input)");
    for name in &b.quantities {
        let _ = write!(head, " {name:>9}");
    }
    let _ = writeln!(o, "{head}");
    for s in &b.sources {
        let input = match (&s.std_unc, &s.unit) {
            (Some(u), Some(unit)) => format!("{u:.2e} {unit}"),
            _ => "(covariance)".into(),
        };
        let kind = match s.kind {
            Kind::A => "A",
            Kind::B => "B",
        };
        let mut line = format!("    {:<12} {kind:<4} {input:>16}", s.source);
        for c in &s.contribution {
            let _ = write!(line, " {c:>9.2e}");
        }
        let _ = writeln!(o, "{line}");
    }
    let row = |label: &str, f: &dyn Fn(&crate::calibrate::budget::Combined) -> String| {
        let mut line = format!("    {label:<12} {:<4} {:>16}", "", "");
        for c in &b.combined {
            let _ = write!(line, " {:>9}", f(c));
        }
        line + "\n"
    };
    o += &row("combined u", &|c| format!("{:.2e}", c.std_unc));
    o += &row("ν_eff", &|c| match c.nu_eff {
        Some(n) if n < 1e6 => format!("{n:.0}"),
        _ => "∞".into(),
    });
    o += &row("k", &|c| format!("{:.2}", c.k));
    o += &row("dominant", &|c| c.dominant.clone());
    for n in &b.notes {
        let _ = writeln!(o, "  WARNING: {n}");
    }
    o
}

/// The noise models, one line per condition and channel.
fn render_noise(n: &[NoiseJson]) -> String {
    let mut o = String::new();
    let _ = writeln!(
        o,
        "  noise from the fit residuals (AR model, JSON noise): sd, lag-1 autocorrelation, variance factor at ω, n_eff"
    );
    for x in n {
        let _ = writeln!(
            o,
            "    {} {}: sd {:.3}, ρ₁ {:+.3}, AR({}), factor {:.2}, n_eff {:.0} of {}{}",
            x.condition,
            x.channel,
            x.sd,
            x.lag1_autocorrelation,
            x.ar.len(),
            x.variance_factor,
            x.n_eff,
            x.n,
            if x.n_excluded > 0 {
                format!(" ({} at a rail left out)", x.n_excluded)
            } else {
                String::new()
            }
        );
        if let Some(s) = &x.slow {
            let _ = writeln!(
                o,
                "      slow: flicker Allan variance {}, random walk K² {}, ν {:.0} for the amplitudes{}",
                slow_level(&s.terms.flicker_allan_variance, "²"),
                slow_level(&s.terms.random_walk_k2, "²/s"),
                s.dof_amplitude,
                s.noise_from.as_ref().map_or(String::new(), |f| format!(
                    "; pooled with {} still rows of {}",
                    f.rows, f.file
                ))
            );
        }
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
    let _ = writeln!(
        o,
        "method {}, g_loc = {} m/s²; ± is the expanded uncertainty U (95 %, k = 2 unless stated; k from the\n\
         budget's effective degrees of freedom)",
        c.method, c.g_loc
    );
    for r in &c.by_rate {
        o += &render_rate(r, &c.units);
    }
    if let Some(check) = &c.residual_structure {
        o += &render_structure(check, &c.units);
    }
    o
}

/// The residuals' structure check: a warning per finding, or what was scanned.
fn render_structure(c: &crate::calibrate::json::StructureCheckJson, units: &str) -> String {
    let mut o = String::new();
    let unscanned = if c.groups_not_scanned > 0 {
        format!(
            "; {} group(s) calibrated from the file's sums were not scanned",
            c.groups_not_scanned
        )
    } else {
        String::new()
    };
    if !c.found {
        let _ = writeln!(
            o,
            "\nresidual structure: none beyond the noise in {} group(s) scanned (α = {} per \
             kind of test over the file){unscanned}",
            c.groups_scanned, c.alpha
        );
        return o;
    }
    let _ = writeln!(
        o,
        "\nwarning: the residuals hold structure that is not noise; the noise model has taken \
         it in, and U is not to be trusted (docs/uncertainty.md, \"Structure beyond the \
         noise\"; `rotacal discrepancy` locates it){unscanned}:",
    );
    let steps = c.structure.iter().filter(|s| s.at_s.is_some()).count();
    if steps >= 2 && !c.slow_noise {
        let _ = writeln!(
            o,
            "  ({steps} steps: steps in several channels are more often slow noise, flicker or a \
             bias random walk, than steps; --slow-noise models it and tests them against it)"
        );
    }
    for s in &c.structure {
        let what = match (s.harmonic, s.at_s) {
            (Some(k), _) => format!("harmonic {k} of the table angle, amplitude"),
            (None, Some(t)) => format!("a step in the level {t:.1} s into the group, height"),
            (None, None) => s.kind.to_string(),
        };
        let _ = writeln!(
            o,
            "  {} at {} Hz, channel {}: {what} {:.3} {units} (z = {:.1}, p = {:.1e})",
            s.condition, s.rate_hz, s.channel, s.size, s.z, s.p_value
        );
    }
    o
}

/// One entry of `by_rate`, its readings in `units`: every part its JSON has, in order.
fn render_rate(r: &RateJson, units: &str) -> String {
    let mut o = String::new();
    let _ = writeln!(o, "\n{}", rate_title(r));
    if let Some(f) = &r.free {
        o += &render_free(f);
    }
    if let Some(p) = &r.poses {
        o += &render_k(p);
    }
    let su = format!("{units} per m/s²");
    o += &render_uvw("s", &r.intrinsic.sensitivity, &su);
    o += &render_angles(&r.intrinsic.angle_deg);
    if let Some(off) = &r.intrinsic.offset {
        o += &render_uvw("O", off, units);
    }
    if let Some(b) = &r.uncertainty_budget {
        o += &render_budget(b);
    }
    if let Some(n) = &r.noise {
        o += &render_noise(n);
    }
    if let Some(p) = &r.poses {
        o += &render_poses(p, units);
    }
    if let Some(cj) = &r.correction {
        o += &render_correction(cj);
    }
    if let Some(p) = &r.angle_deg_phase_method {
        let _ = writeln!(
            o,
            "  phase-difference angles (Gaitan & Geist (2022) eqs. 12–16, for comparison; biased when tilted):"
        );
        o += &render_angles(p);
    }
    if let Some(mc) = &r.monte_carlo {
        o += &render_monte_carlo(r, mc);
    }
    o + &render_fitted_rates(&r.fits)
}

/// What one entry of `by_rate` is: a rotation rate, static or free poses.
fn rate_title(r: &RateJson) -> String {
    r.rate_hz
        .map(|f| format!("rotation at {f} Hz"))
        .unwrap_or_else(|| {
            if r.free.is_some() {
                "free poses (unknown orientation)".into()
            } else {
                "static".into()
            }
        })
}

/// The free poses' fit, the still intervals left out and a conditioning warning.
fn render_free(f: &FreeJson) -> String {
    let mut o = String::new();
    let found: usize = f.detection.iter().map(|d| d.intervals.len()).sum();
    let _ = writeln!(
        o,
        "  {} poses fitted of {found} still intervals found (JSON free.detection); \
         χ² = {:.1} on {} degrees of freedom, τ = {:.2e} m/s², condition number {:.1}",
        f.poses.len(),
        f.chi2,
        f.dof,
        f.tau_ms2,
        f.condition_number
    );
    for d in &f.detection {
        for i in d
            .intervals
            .iter()
            .filter(|i| i.interval.verdict != crate::calibrate::still::Verdict::Kept)
        {
            let _ = writeln!(
                o,
                "  left out: {} ({:.2}–{:.2} s): {}",
                i.interval.name, i.interval.span_s.0, i.interval.span_s.1, i.reason
            );
        }
    }
    if let Some(s) = &f.suggestion {
        let _ = writeln!(o, "  badly conditioned: add poses with gravity near {s}");
    }
    o
}

/// A slow level ± its standard uncertainty, in µg (`unit` the power: "²", "²/s") where the
/// sensitivity gives it, else in output units (unnamed, as the noise lines above).
fn slow_level(t: &json::SlowTerm, unit: &str) -> String {
    match (t.value_ug, t.u_ug) {
        (Some(v), Some(u)) => format!("{v:.3e} ± {u:.1e} µg{unit}"),
        _ => format!("{:.3e} ± {:.1e}", t.value, t.u),
    }
}

/// The slow noise between the poses: each channel's flicker floor and walk, in µg where
/// the sensitivity gives them, each ± its standard uncertainty.
fn render_poses_slow(s: &json::PosesSlowJson) -> String {
    let mut o = String::new();
    for c in &s.channels {
        let _ = writeln!(
            o,
            "    slow noise {}: flicker Allan variance {}, walk K² {} (ρ = {:.2}; signed \
             estimates, standard uncertainties)",
            c.channel,
            slow_level(&c.terms.flicker_allan_variance, "²"),
            slow_level(&c.terms.random_walk_k2, "²/s"),
            c.correlation
        );
    }
    o
}

/// The pose fit's coverage factor and the degrees of freedom behind it, when it is not
/// [`json::K`]; else nothing.
fn render_k(p: &PosesJson) -> String {
    let mut o = String::new();
    if (p.k - json::K).abs() > 1e-12 {
        let nu = p.nu.iter().fold(f64::INFINITY, |a, b| a.min(*b));
        let why = match p.scatter {
            poses::Scatter::PerChannel => format!(
                "the poses' scatter about the model, estimated from {} poses − 4",
                p.list.len()
            ),
            poses::Scatter::Slow => {
                "the readings' scatter within the poses and the slow levels' estimate from \
                 the pose residuals"
                    .to_string()
            }
            _ if p.chi2_dof_joint.is_some() => format!(
                "the poses' scatter in the joint fit, 3 × {} poses − 12",
                p.list.len()
            ),
            _ => "the readings' scatter within the poses".to_string(),
        };
        let _ = writeln!(o, "  k = {:.2}: Student's t for ν = {nu} ({why})", p.k);
    }
    o
}

/// One quantity's line: value ± U in `unit`, U to two significant digits, and k when it
/// is not [`json::K`].
fn render_quantity(name: &str, x: &json::Quantity, unit: &str) -> String {
    let d = decimals(x.expanded_unc);
    let k = if (x.k - json::K).abs() > 1e-12 {
        format!(" (k = {:.2})", x.k)
    } else {
        String::new()
    };
    format!(
        "  {name:<7} {:>16.d$} ± {:<12.d$} {unit}{k}\n",
        x.value, x.expanded_unc
    )
}

/// The lines of a quantity per channel, named `{symbol}_u`, `{symbol}_v`, `{symbol}_w`.
fn render_uvw(symbol: &str, x: &json::Uvw, unit: &str) -> String {
    render_quantity(&format!("{symbol}_u"), &x.u, unit)
        + &render_quantity(&format!("{symbol}_v"), &x.v, unit)
        + &render_quantity(&format!("{symbol}_w"), &x.w, unit)
}

/// The lines of the three angles between the channels, degrees.
fn render_angles(a: &json::Pairs) -> String {
    render_quantity("φ_uv", &a.uv, "°")
        + &render_quantity("φ_vw", &a.vw, "°")
        + &render_quantity("φ_wu", &a.wu, "°")
}

/// The correction matrix and offsets, one line per row.
fn render_correction(cj: &json::CorrectionJson) -> String {
    let mut o = String::new();
    let d = &cj.device_frame;
    let _ = writeln!(
        o,
        "  correction a = M·(y − O) to m/s² (device frame; JSON 'correction'; rotacal apply/export):"
    );
    for (i, (row, offset)) in d.matrix.iter().zip(&d.offset).enumerate() {
        let _ = writeln!(
            o,
            "    M[{i}] = [{:+.8} {:+.8} {:+.8}]  O[{i}] = {:+.6} {}",
            row[0], row[1], row[2], offset, cj.units_in
        );
    }
    o
}

/// The Monte Carlo check `mc` of entry `r`: each property's standard uncertainty and 95 %
/// interval beside the budget's linear type-A one.
fn render_monte_carlo(r: &RateJson, mc: &BTreeMap<String, McSummary>) -> String {
    let mut o = String::new();
    let (s, a) = (&r.intrinsic.sensitivity, &r.intrinsic.angle_deg);
    let _ = writeln!(
        o,
        "  Monte Carlo (GUM S1) check of the type-A term: standard uncertainty and 95 % interval"
    );
    // The draws are of the fits (or the pose fit) only: compare with the budget's
    // type-A line, not with the combined uncertainty.
    let type_a = r.uncertainty_budget.as_ref().and_then(|b| {
        b.sources
            .iter()
            .find(|x| x.kind == Kind::A && (x.source == "fits" || x.source == "poses"))
    });
    // The type-A source's contribution to each property in turn.
    let mut type_a = type_a
        .into_iter()
        .flat_map(|x| x.contribution.iter().copied());
    for (key, q) in json::MC_KEYS
        .iter()
        .zip([&s.u, &s.v, &s.w, &a.uv, &a.vw, &a.wu])
    {
        let linear = type_a.next().unwrap_or(q.std_unc);
        if let Some(m) = mc.get(*key) {
            let _ = writeln!(
                o,
                "  {key:<7} u = {:.6} (linear {:.6}), [{:.6}, {:.6}]",
                m.std_unc, linear, m.low_95, m.high_95
            );
        }
    }
    o
}

/// The rates fitted where they differ from nominal, one per condition; else nothing.
fn render_fitted_rates(fits: &[json::FitJson]) -> String {
    let mut o = String::new();
    let fitted: Vec<String> = fits
        .iter()
        .filter(|f| f.channel == Channel::U)
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
    let joined: Vec<String> = fits
        .iter()
        .filter(|f| f.channel == Channel::U)
        .filter_map(|f| f.boots.map(|b| format!("{} in {b}", f.condition)))
        .collect();
    if !joined.is_empty() {
        let _ = writeln!(
            o,
            "  recorded across restarts of the device, each boot's phase fitted with the rate \
             (JSON fits.boots): {} boots",
            joined.join(", ")
        );
    }
    o
}
