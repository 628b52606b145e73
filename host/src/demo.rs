//! `rotacal demo`: the main job without hardware, the whole chain.
//!
//! 1. Simulate Gaitan & Geist's (2022) 10 mHz session (`paper-10mhz`, with the sensor at its own
//!    104 Hz output rate): truth = Gaitan & Geist (2022) Table 1's DC intrinsic properties.
//! 2. Run it through the firmware's hardware-independent logic on this host
//!    ([`crate::link::simulated`]: sampler, ring, packetiser, f32 fit, quick-look).
//! 3. Decode its packets and 4. record them with `rotacal record`'s code (one condition
//!    at a time, appending, as at the table), into a recording, a fit log and a capture.
//! 5. Calibrate in f64, 6. cross-check the device's fits, 7. write the report folder.
//! 8. Check every statement it prints about its numbers ([`checks`]): `rotacal demo` prints
//!    everything, then exits with status 1, naming each failed check, if any fails.
//!
//! The session runs on a paused tokio clock: 13 minutes of device time in seconds.

use crate::calibrate::json::{CalibrationJson, Quantity, PROPERTY_NAMES};
use crate::link::simulated::{Faults, SimulatedDevice};
use crate::record::{self, Options, Outcome, Paths, Plan, Quiet};
use crate::recording::from_device::LogLine;
use crate::recording::{Metadata, Method};
use crate::reference::{PAPER_10MHZ, PAPER_DC_ANGLES_DEG, PAPER_DC_SENSITIVITY, PAPER_G_LOC};
use crate::simulate::{Config, Simulation};
use crate::verify::recorded::CrosscheckReport;
use rotacal_shared::Condition;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// A fault put into the demo's chain on purpose (`rotacal demo --inject NAME`, a hidden
/// option). It exists only to prove that the demo can fail: its tests use it to see the
/// cross-check, and so `rotacal demo`, fail.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Inject {
    /// `corrupt-device-fit`: the first device fit report in the recorded fit log
    /// (`recording.fits.jsonl`) gets its u channel's A shifted by one of its standard
    /// errors, about 100 times the cross-check's threshold, before the cross-check reads it.
    CorruptDeviceFit,
}

impl Inject {
    /// Its name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Inject::CorruptDeviceFit => "corrupt-device-fit",
        }
    }
}

impl std::str::FromStr for Inject {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        [Inject::CorruptDeviceFit]
            .into_iter()
            .find(|i| i.name() == s)
            .ok_or_else(|| format!("'{s}': the only fault is corrupt-device-fit"))
    }
}

/// The demo's results.
#[derive(Clone, Debug)]
pub struct Demo {
    /// Where the files are.
    pub dir: PathBuf,
    /// The fault injected, if any.
    pub injected: Option<Inject>,
    /// The simulated truth: s_u, s_v, s_w (counts per m/s²), φ_uv, φ_vw, φ_wu (°).
    pub truth: [f64; 6],
    /// The sensor's output rate, Hz.
    pub sensor_hz: f64,
    /// Sensor conversions per condition (at `sensor_hz`).
    pub conversions: usize,
    /// What recording each condition gave.
    pub recorded: Vec<(Condition, Outcome)>,
    /// The f64 calibration of the recording.
    pub calibration: CalibrationJson,
    /// The device's fits against the recording.
    pub crosscheck: CrosscheckReport,
    /// The report's Markdown file.
    pub report: PathBuf,
    /// The calibration applied to the recording (device frame), written as
    /// recording-ms2.csv.
    pub applied: crate::correct::apply::Summary,
    /// Mean over the recording's rows of 1/n, n the conversions a row averages: a
    /// reading's noise variance is the fits' per-conversion variance times this.
    pub mean_inv_count: f64,
    /// The paper's puzzle, worked by the discrepancy workflow.
    pub puzzle: Puzzle,
}

/// Gaitan & Geist (2022)'s unexplained 0.5 Hz deviation, reproduced and explained: `paper-multirate`
/// (10, 50, 100, 500 mHz, 22 cm from the axis) with K2 = 2e-4 /(m/s²) on w.
#[derive(Clone, Debug)]
pub struct Puzzle {
    /// The rates calibrated, Hz, in order.
    pub rates_hz: Vec<f64>,
    /// The simulated K2 of w, /(m/s²).
    pub true_k2_w: f64,
    /// The simulated distance from the axis, m.
    pub true_radius_m: f64,
    /// The effects named, in order.
    pub named: Vec<String>,
    /// χ²/dof of the baseline and of the final model.
    pub chi2_dof: (f64, f64),
    /// K2_w: value and U.
    pub k2_w: (f64, f64),
    /// Radius per condition: value and U.
    pub radius: Vec<(f64, f64)>,
    /// s_w(last rate) − s_w(first rate) and its U, from per-rate fits (the paper's
    /// analysis).
    pub deviation_per_rate: (f64, f64),
    /// The same with the confirmed effects modelled (the workflow's result).
    pub deviation_modelled: (f64, f64),
    /// The discrepancy report.
    pub report: PathBuf,
    /// The workflow's verdict: explained, and its summary.
    pub verdict: (bool, String),
    /// The named effects the workflow confirmed.
    pub confirmed: Vec<String>,
}

/// The puzzle's simulation.
/// Its file does not state its noise (`[sensor.noise] state = false`), as a real recording
/// does not: the discrepancy workflow estimates it.
pub const PUZZLE: &str = "preset = \"paper-multirate\"\n[sensor.noise]\nstate = false\n\
                          [effects.nonlinearity_2nd]\nk2 = [0.0, 0.0, 2e-4]\n";

fn puzzle(seed: u64, dir: &Path) -> anyhow::Result<Puzzle> {
    let mut cfg = Config::from_toml(PUZZLE)?;
    cfg.seed = seed;
    let sim = Simulation::new(cfg)?;
    let effects = &sim.config().effects;
    let true_k2_w = effects.nonlinearity_2nd.as_ref().map(|e| {
        let [_, _, w] = e.k2;
        w
    });
    let true_radius_m = effects.centripetal.as_ref().map(|e| e.radius_m);
    let (Some(true_k2_w), Some(true_radius_m)) = (true_k2_w, true_radius_m) else {
        anyhow::bail!("the puzzle's simulation has no K2 or no centripetal term");
    };
    let csv = dir.join("puzzle.csv");
    sim.write_file(&csv)
        .map_err(|e| anyhow::anyhow!("{}: {e}", csv.display()))?;
    let rec = crate::recording::read(&csv)?;
    let cal = crate::calibrate::calibrate(&rec, &Default::default())?;
    let a = crate::discrepancy::run(&rec, &Default::default())?;
    let trace = crate::trace::Traceability::of_recording(crate::BUILD, &csv, None, None, None)?;
    crate::atomic::write(&dir.join("puzzle.discrepancy.json"), trace.json(&a)?)?;
    let report = crate::report::discrepancy::write(&a, &dir.join("puzzle-report"), "counts")?;
    let dev = |lo: &crate::calibrate::json::Quantity, hi: &crate::calibrate::json::Quantity| {
        (hi.value - lo.value, lo.expanded_unc.hypot(hi.expanded_unc))
    };
    let (first, last) = match (cal.by_rate.first(), cal.by_rate.last()) {
        (Some(f), Some(l)) => (f, l),
        _ => anyhow::bail!("the puzzle's calibration has no rates"),
    };
    let deviation_per_rate = dev(
        &first.intrinsic.sensitivity.w,
        &last.intrinsic.sensitivity.w,
    );
    let deviation_modelled = match (a.intrinsic_confirmed.first(), a.intrinsic_confirmed.last()) {
        (Some(f), Some(l)) => dev(&f.sensitivity[2], &l.sensitivity[2]),
        _ => anyhow::bail!("the puzzle's analysis has no rates"),
    };
    // A parameter's value and U; NaN for one the analysis did not name.
    let pick = |v: Option<&serde_json::Value>| {
        let number = |key: &str| v.and_then(|v| v.get(key)?.as_f64()).unwrap_or(f64::NAN);
        (number("value"), number("expanded_unc"))
    };
    let fp = &a.final_parameters;
    let param = |effect: &str, name: &str| fp.get(effect).and_then(|p| p.get(name));
    Ok(Puzzle {
        rates_hz: cal.by_rate.iter().filter_map(|r| r.rate_hz).collect(),
        true_k2_w,
        true_radius_m,
        named: a.named_effects.clone(),
        chi2_dof: (a.baseline.chi2_dof, a.final_.chi2_dof),
        k2_w: pick(param("nonlinearity_2nd", "k2").and_then(|k2| k2.get("w"))),
        radius: ["x", "y", "z"]
            .iter()
            .map(|c| pick(param("centripetal", "radius_m").and_then(|r| r.get(*c))))
            .collect(),
        deviation_per_rate,
        deviation_modelled,
        report,
        verdict: (a.verdict.explained, a.verdict.summary.clone()),
        confirmed: a.confirmed_effects.clone(),
    })
}

/// The demo's device session: `paper-10mhz` with the sensor converting at 104 Hz for
/// 262.5 s per condition (the Feather streams 4200 samples of it at 16 Hz).
pub fn session_config(seed: u64) -> anyhow::Result<Config> {
    let mut cfg = Config::preset("paper-10mhz")?;
    cfg.seed = seed;
    cfg.timing.sample_rate_hz = 104.0;
    cfg.timing.tick_hz = 1e6;
    cfg.table.samples_per_condition = Some(27_300);
    Ok(cfg)
}

/// A runtime on a paused clock, and recording options for it (nothing synced to disk): the
/// emulated device runs on tokio's time, so a session of hours takes seconds.
pub fn paused() -> anyhow::Result<(tokio::runtime::Runtime, Options)> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .start_paused(true)
        .build()?;
    let opts = Options {
        sync: false,
        ..Options::default()
    };
    Ok((rt, opts))
}

/// Record x, y and z from `device` into `paths` on a paused clock (the emulated device
/// runs on tokio's time, so a session of minutes takes seconds), `duration` each at
/// 0.01 Hz and 16 Hz.
pub fn record_session(
    device: &mut SimulatedDevice,
    paths: &Paths,
    meta: &Metadata,
    duration: Duration,
) -> anyhow::Result<Vec<(Condition, Outcome)>> {
    let (rt, opts) = paused()?;
    rt.block_on(async {
        let mut obs = Quiet::default();
        let (info, info_bytes) = record::connect(device, &opts, &mut obs).await?;
        let mut recorded = Vec::new();
        for (i, condition) in Condition::ALL.into_iter().enumerate() {
            let files =
                record::open_files(paths, meta, &info_bytes, info.tick_hz, condition, i > 0)?;
            let plan = Plan {
                condition,
                rate_uhz: 10_000,
                duration,
                sample_rate_mhz: Some(16_000),
                restart: false,
            };
            let out = record::record(device, info, files, plan, opts, &mut obs)
                .await
                .map_err(|(e, _)| anyhow::anyhow!("recording {}: {e}", condition.letter()))?;
            recorded.push((condition, out));
        }
        anyhow::Ok(recorded)
    })
}

/// Run the chain, writing into `dir` (created if missing), with `inject`'s fault if any.
pub fn run(seed: u64, dir: &Path, inject: Option<Inject>) -> anyhow::Result<Demo> {
    std::fs::create_dir_all(dir).map_err(|e| anyhow::anyhow!("{}: {e}", dir.display()))?;
    let sim = Simulation::new(session_config(seed)?)?;
    let conversions = sim.config().samples_per_condition();
    let sensor_hz = sim.config().timing.sample_rate_hz;
    let truth = sim.truth().properties();
    let mut device = SimulatedDevice::new(&sim, Faults::default())?;
    let paths = Paths::beside(&dir.join("recording.csv"));
    // The demo's own folder: a previous run's recording is replaced.
    paths.remove()?;
    let meta = Metadata {
        method: Some(Method::Rotation),
        rate_hz: Some(0.01),
        g_loc: Some(sim.config().g_loc),
        units: Some("counts".into()),
        sample_rate_hz: Some(16.0),
        noise_sigma: None,
        device: Some("simulated Feather nRF52840 Sense (rotacal demo)".into()),
        other: Default::default(),
    };
    let duration = Duration::from_secs_f64(conversions as f64 / sensor_hz);
    let recorded = record_session(&mut device, &paths, &meta, duration)?;
    let (rec_path, fits_path) = (&paths.recording, &paths.fits);
    if inject == Some(Inject::CorruptDeviceFit) {
        corrupt_first_fit(fits_path)?;
    }
    let rec = crate::recording::read(rec_path)?;
    let calibration = crate::calibrate::calibrate(&rec, &Default::default())?;
    let (inv_sum, rows) = rec.groups.iter().fold((0.0, 0usize), |(s, n), g| {
        let inv: f64 = match &g.conversions {
            Some(c) => c.iter().map(|a| 1.0 / a.len().max(1) as f64).sum(),
            None => g.len() as f64,
        };
        (s + inv, n + g.len())
    });
    let mean_inv_count = inv_sum / rows.max(1) as f64;
    let log_text = std::fs::read_to_string(fits_path)?;
    let log =
        crate::recording::from_device::read_fit_log(&log_text, &fits_path.display().to_string())?;
    let crosscheck = crate::verify::recorded::crosscheck(
        &rec,
        &log,
        crate::verify::recorded::DEFAULT_THRESHOLD,
    )?;
    let mut trace =
        crate::trace::Traceability::of_recording(crate::BUILD, rec_path, None, None, None)?;
    crate::atomic::write(&dir.join("calibration.json"), trace.json(&calibration)?)?;
    trace.inputs.push(crate::trace::input(fits_path)?);
    crate::atomic::write(&dir.join("crosscheck.json"), trace.json(&crosscheck)?)?;
    let (report, _) = crate::report::write(&rec, &Default::default(), &dir.join("report"))?;
    let correction = calibration
        .by_rate
        .first()
        .and_then(|r| r.correction.as_ref())
        .ok_or_else(|| anyhow::anyhow!("the calibration has no correction"))?;
    let provenance =
        crate::trace::Traceability::new(crate::BUILD, &[&dir.join("calibration.json"), rec_path])?
            .as_metadata(&["calibration", "recording"]);
    let job = crate::correct::apply::Job {
        correction: &correction.device_frame,
        units_in: &correction.units_in,
        k: correction.k,
        cal_name: "calibration.json",
        g_loc: Some(PAPER_G_LOC),
        out_name: "recording-ms2.csv",
        provenance: &provenance,
    };
    let applied = crate::atomic::write_with(&dir.join("recording-ms2.csv"), |w| {
        anyhow::Ok(crate::correct::apply::apply(&rec, &job, w)?)
    })?;
    let puzzle = puzzle(seed, dir)?;
    let [s0, s1, s2, a0, a1, a2, ..] = truth;
    Ok(Demo {
        dir: dir.to_path_buf(),
        injected: inject,
        truth: [s0, s1, s2, a0, a1, a2],
        sensor_hz,
        conversions: conversions as usize,
        recorded,
        calibration,
        crosscheck,
        report,
        applied,
        mean_inv_count,
        puzzle,
    })
}

/// [`Inject::CorruptDeviceFit`]: rewrite only the first fit report's line, so the rest of
/// the log stays byte for byte what the recorder wrote.
fn corrupt_first_fit(path: &Path) -> anyhow::Result<()> {
    let at = |e: &dyn std::fmt::Display| anyhow::anyhow!("{}: {e}", path.display());
    let text = std::fs::read_to_string(path).map_err(|e| at(&e))?;
    let mut out = String::with_capacity(text.len());
    let mut done = false;
    for line in text.lines() {
        match serde_json::from_str::<LogLine>(line) {
            Ok(LogLine::Fit(mut f)) if !done => {
                let [[a, ..], ..] = &mut f.coef;
                let [[se, ..], ..] = f.se;
                *a += se;
                out += &serde_json::to_string(&LogLine::Fit(f)).map_err(|e| at(&e))?;
                done = true;
            }
            _ => out += line,
        }
        out.push('\n');
    }
    if !done {
        anyhow::bail!("{}: no device fit report to corrupt", path.display());
    }
    crate::atomic::write(path, out).map_err(|e| at(&e))
}

/// How many U a property may miss the simulated truth by before the demo fails.
pub const TRUTH_LIMIT_U: f64 = 3.0;

/// One statement the demo prints about its numbers, checked against them.
#[derive(Clone, Debug, PartialEq)]
pub struct Check {
    /// The statement, short enough to name it.
    pub claim: String,
    /// It holds.
    pub passed: bool,
    /// What was measured, against what limit.
    pub measured: String,
}

/// The calibration applied to the recording against the noise of one reading.
struct Applied {
    /// RMS of |a| − g, m/s².
    after: f64,
    /// The noise of one reading: the fits' pooled residual RMS (per conversion), each
    /// channel through its own sensitivity, over the root of the conversions averaged, m/s².
    noise: f64,
    /// Three standard deviations of after / noise when only noise is left.
    tolerance: f64,
}

fn applied(d: &Demo) -> Option<Applied> {
    let after = d.applied.rms_after?;
    let r = d.calibration.by_rate.first()?;
    let s = &r.intrinsic.sensitivity;
    let (mut ss, mut n) = (0.0, 0.0);
    for f in &r.fits {
        let sens = *f.channel.of(&[s.u.value, s.v.value, s.w.value]);
        ss += f.n as f64 * (f.rms_residual / sens).powi(2);
        n += f.n as f64;
    }
    // With only white noise left, |a| − g of a reading is its noise along g (the channels'
    // noise is alike, so any direction has the pooled variance). An RMS of N such values
    // has relative standard deviation 1/√(2N). Treating the two RMS as independent
    // overstates the spread of their ratio, as both come from the same samples.
    let rows = d.applied.rows as f64;
    Some(Applied {
        after,
        noise: (ss / n * d.mean_inv_count).sqrt(),
        tolerance: 3.0 * (0.5 / rows + 0.5 / n).sqrt(),
    })
}

/// `x` with up to six decimals and no trailing zeros.
fn short(x: f64) -> String {
    let t = format!("{x:.6}");
    t.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// A U ratio as the table prints it.
fn ratio(x: f64) -> String {
    match x {
        x if x >= 10.0 => format!("{x:.0}"),
        x if x >= 1.0 => format!("{x:.1}"),
        x => format!("{x:.2}"),
    }
}

/// The sentence on the U ratio column (Gaitan & Geist's (2022) over rotacal's), its comparison word
/// chosen from the ratios.
fn ratio_sentence(ratios: &[f64]) -> String {
    if ratios.is_empty() || ratios.iter().any(|r| !r.is_finite()) {
        return "the U ratios could not all be computed".into();
    }
    let lo = ratios.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = ratios.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let range = match (ratio(lo), ratio(hi)) {
        (a, b) if a == b => a,
        (a, b) => format!("{a}–{b}"),
    };
    if lo > 1.0 {
        format!("rotacal's U is {range} times smaller than the stated uncertainties of Gaitan & Geist (2022)")
    } else if hi < 1.0 {
        format!("rotacal's U is larger than the stated uncertainties of Gaitan & Geist (2022) ({range} times it)")
    } else {
        format!("the stated uncertainties of Gaitan & Geist (2022) are {range} times rotacal's U, not all above it")
    }
}

/// "k = 2", or the range when the quantities' coverage factors differ.
fn k_phrase(qs: &[&Quantity]) -> String {
    let lo = qs.iter().map(|q| q.k).fold(f64::INFINITY, f64::min);
    let hi = qs.iter().map(|q| q.k).fold(f64::NEG_INFINITY, f64::max);
    match (short(lo), short(hi)) {
        (a, b) if a == b => format!("k = {a}"),
        (a, b) => format!("k = {a}–{b} by quantity"),
    }
}

/// Whether a difference is within its U (|v| ≤ U), and by how much.
fn against_u((v, u): (f64, f64)) -> String {
    let r = v.abs() / u;
    if v.abs() <= u {
        format!("within its U ({r:.2} U)")
    } else {
        format!("not within its U ({r:.1} U)")
    }
}

/// "0.5 Hz", "10 mHz".
fn rate_label(hz: f64) -> String {
    if hz < 0.1 {
        format!("{} mHz", short(hz * 1e3))
    } else {
        format!("{} Hz", short(hz))
    }
}

/// "s_w(0.5 Hz) − s_w(10 mHz)": the last rate's against the first's.
fn deviation_label(rates_hz: &[f64]) -> String {
    match (rates_hz.first(), rates_hz.last()) {
        (Some(&lo), Some(&hi)) => format!("s_w({}) − s_w({})", rate_label(hi), rate_label(lo)),
        _ => "s_w(last rate) − s_w(first rate)".into(),
    }
}

/// The truth is Gaitan & Geist (2022) Table 1's DC column (as the first sentence says).
fn truth_is_paper_dc(truth: &[f64; 6]) -> bool {
    let paper = PAPER_DC_SENSITIVITY.iter().chain(&PAPER_DC_ANGLES_DEG);
    truth
        .iter()
        .zip(paper)
        .all(|(t, p)| (t - p).abs() <= 1e-9 * p.abs())
}

/// `f` summed over the conditions recorded.
fn total(d: &Demo, f: fn(&Outcome) -> u64) -> u64 {
    d.recorded.iter().map(|(_, o)| f(o)).sum()
}

/// Everything the demo states about its numbers, as checks: `rotacal demo` prints them and
/// fails if any does not hold.
pub fn checks(d: &Demo) -> Vec<Check> {
    let mut c = Vec::new();
    let lost = total(d, |o| o.summary.lost_samples());
    let undecodable = total(d, |o| o.undecodable);
    let finals = d.recorded.iter().filter(|(_, o)| o.final_fit).count();
    let conditions = Condition::ALL.len();
    c.push(Check {
        claim: "chain: nothing lost".into(),
        passed: lost == 0 && undecodable == 0 && finals == conditions,
        measured: format!(
            "{lost} samples lost, {undecodable} values undecodable, final fit of \
             {finals} of {conditions} conditions received"
        ),
    });
    let x = &d.crosscheck;
    c.push(Check {
        claim: "cross-check: the device's fits match f64 re-fits".into(),
        passed: x.passed,
        measured: format!(
            "{} of {} fits outside the threshold; max |Δ| = {:.1e} σ_CRLB, threshold {:e}",
            x.fits.iter().filter(|f| !f.passed).count(),
            x.fits.len(),
            x.max_delta_crlb,
            x.threshold
        ),
    });
    match d.calibration.by_rate.first() {
        Some(r) => {
            let ours = r.intrinsic.quantities();
            for (k, ((name, q), t)) in PROPERTY_NAMES.iter().zip(ours).zip(d.truth).enumerate() {
                let digits = if k < 3 { 4 } else { 5 };
                let err = (q.value - t).abs();
                c.push(Check {
                    claim: format!("{name} within {TRUTH_LIMIT_U} U of the truth"),
                    passed: err <= TRUTH_LIMIT_U * q.expanded_unc,
                    measured: format!(
                        "|{:.*} − {}| = {:.2} U (U = {:.*}, k = {})",
                        digits,
                        q.value,
                        short(t),
                        err / q.expanded_unc,
                        digits,
                        q.expanded_unc,
                        short(q.k)
                    ),
                });
            }
        }
        None => c.push(Check {
            claim: "calibration: a result".into(),
            passed: false,
            measured: "calibration.json has no rate".into(),
        }),
    }
    let a = applied(d);
    c.push(Check {
        claim: "applied: RMS of |a| − g is the noise of one reading".into(),
        passed: a
            .as_ref()
            .is_some_and(|a| (a.after / a.noise - 1.0).abs() <= a.tolerance),
        measured: a.map_or("not computed".into(), |a| {
            format!(
                "{:.2e} / {:.2e} m/s² = {:.3}, 1 ± {:.3} expected (3σ)",
                a.after,
                a.noise,
                a.after / a.noise,
                a.tolerance
            )
        }),
    });
    let p = &d.puzzle;
    let label = deviation_label(&p.rates_hz);
    for (claim, (v, u), passed) in [
        (
            "puzzle: the deviation per rate is not within its U",
            p.deviation_per_rate,
            p.deviation_per_rate.0.abs() > p.deviation_per_rate.1,
        ),
        (
            "puzzle: the deviation modelled is within its U",
            p.deviation_modelled,
            p.deviation_modelled.0.abs() <= p.deviation_modelled.1,
        ),
    ] {
        c.push(Check {
            claim: claim.into(),
            passed,
            measured: format!("{label} = {v:+.4} ± {u:.4}, {:.2} U", v.abs() / u),
        });
    }
    c.push(Check {
        claim: "puzzle: the discrepancy workflow's verdict is \"explained\", its named \
                effects confirmed"
            .into(),
        passed: p.verdict.0 && !p.named.is_empty() && p.confirmed.len() == p.named.len(),
        measured: format!(
            "{}; confirmed {} of {} named ({})",
            p.verdict.1,
            p.confirmed.len(),
            p.named.len(),
            p.confirmed.join(", ")
        ),
    });
    let in_u = |(v, u): (f64, f64), t: f64| (v - t).abs() / u;
    let k2 = in_u(p.k2_w, p.true_k2_w);
    let radii: Vec<f64> = p.radius.iter().map(|&r| in_u(r, p.true_radius_m)).collect();
    c.push(Check {
        claim: format!("puzzle: the simulated effects recovered within {TRUTH_LIMIT_U} U"),
        passed: !radii.is_empty() && [k2].iter().chain(&radii).all(|e| *e <= TRUTH_LIMIT_U),
        measured: format!(
            "K2_w {k2:.2} U from {:e}; radius {} U from {} m",
            p.true_k2_w,
            radii
                .iter()
                .map(|e| format!("{e:.2}"))
                .collect::<Vec<_>>()
                .join(", "),
            short(p.true_radius_m)
        ),
    });
    c
}

/// Ok when every check holds; otherwise what `rotacal demo` exits with: each failed check
/// and its numbers.
pub fn verdict(checks: &[Check]) -> Result<(), String> {
    let failed: Vec<&Check> = checks.iter().filter(|c| !c.passed).collect();
    if failed.is_empty() {
        return Ok(());
    }
    let mut m = format!(
        "the demo failed {} of {} checks:",
        failed.len(),
        checks.len()
    );
    for c in failed {
        let _ = write!(m, "\n  {}: {}", c.claim, c.measured);
    }
    Err(m)
}

/// `rotacal demo`: run the chain and print everything, then fail, naming each failed
/// check, if any failed (the numbers are on screen before the verdict).
pub fn command(seed: u64, dir: &Path, inject: Option<Inject>) -> anyhow::Result<()> {
    let d = run(seed, dir, inject)?;
    crate::output::emit(&render(&d))?;
    verdict(&checks(&d)).map_err(anyhow::Error::msg)
}

/// The demo's terminal output, its checks and verdict last.
pub fn render(d: &Demo) -> String {
    let mut o = String::new();
    if let Some(i) = d.injected {
        let _ = writeln!(
            o,
            "Fault injected on purpose: {} (to prove the demo can fail).\n",
            i.name()
        );
    }
    let rows = total(d, |o| o.summary.rows);
    let lost = total(d, |o| o.summary.lost_samples());
    let fits = total(d, |o| o.summary.fit_lines);
    let _ = writeln!(
        o,
        "Simulated Gaitan & Geist (2022) session: 10 mHz about x, y, z; LSM6DS33 at {} Hz ({} conversions per\n\
         condition), truth {}, g = {} m/s².\n\
         Device logic (the firmware's, on this host) → BLE packets → decoded → recorded:\n\
         {rows} samples at 16 Hz, {lost} lost, {fits} fit-log lines (device fit reports and quick-look).",
        short(d.sensor_hz),
        d.conversions,
        if truth_is_paper_dc(&d.truth) {
            "= Gaitan & Geist (2022) Table 1 DC"
        } else {
            "≠ Gaitan & Geist (2022) Table 1 DC"
        },
        d.calibration.g_loc
    );
    let x = &d.crosscheck;
    let _ = writeln!(
        o,
        "Cross-check: {} device fits (the firmware's f32 fit, run on this host) against f64 re-fits\n\
         of the same samples: max |Δ| = {:.1e} σ_CRLB (threshold {:e}): {}.",
        x.fits.len(),
        x.max_delta_crlb,
        x.threshold,
        if x.passed { "pass" } else { "FAIL" }
    );
    if let Some(r) = d.calibration.by_rate.first() {
        render_intrinsic(&mut o, d, r);
    }
    let _ = writeln!(
        o,
        "\nFiles in {}: recording.csv, recording.fits.jsonl (device fits), recording.capture (every\n\
         value received), calibration.json, crosscheck.json.\nReport: {}",
        d.dir.display(),
        d.report.display()
    );
    if let Some(a) = applied(d) {
        let _ = writeln!(
            o,
            "\nApplied (rotacal apply, device frame, a = L⁻¹·(y − O) with G = L·Lᵀ): {} rows in m/s² with\n\
             their uncertainties in recording-ms2.csv; RMS of |a| − g = {:.2e} m/s², {:.3} times the\n\
             noise of one reading ({:.2e} m/s²: the fits' residual RMS per conversion over √n for an\n\
             average of n conversions; 1 ± {:.3} expected, 3σ).",
            d.applied.rows,
            a.after,
            a.after / a.noise,
            a.noise,
            a.tolerance
        );
    }
    render_puzzle(&mut o, &d.puzzle);
    let checks = checks(d);
    let _ = writeln!(
        o,
        "\nChecks (rotacal demo exits with status 1 if any fails):"
    );
    for c in &checks {
        let mark = if c.passed { "ok  " } else { "FAIL" };
        let _ = writeln!(o, "  {mark} {}: {}", c.claim, c.measured);
    }
    let failed: Vec<&str> = checks
        .iter()
        .filter(|c| !c.passed)
        .map(|c| c.claim.as_str())
        .collect();
    let _ = if failed.is_empty() {
        writeln!(o, "All {} checks passed.", checks.len())
    } else {
        writeln!(
            o,
            "FAILED {} of {} checks: {}.",
            failed.len(),
            checks.len(),
            failed.join("; ")
        )
    };
    o
}

/// The intrinsic properties' table and the sentence on its U ratio column.
fn render_intrinsic(o: &mut String, d: &Demo, r: &crate::calibrate::json::RateJson) {
    let ours = r.intrinsic.quantities();
    let _ = writeln!(
        o,
        "\nIntrinsic properties (f64, exact Gram form, docs/method.md §2; ± is U, {};\n\
         s in counts/(m/s²), φ in degrees):",
        k_phrase(&ours)
    );
    let _ = writeln!(
        o,
        "{:<5} {:>22} {:>9} {:>8} {:>20} {:>9} {:>20}",
        "", "rotacal", "truth", "|err|/U", "G&G 2022 (10 mHz)", "U ratio", "phase method"
    );
    let phase = r
        .angle_deg_phase_method
        .as_ref()
        .map(|p| [&p.uv, &p.vw, &p.wu]);
    let mut ratios = Vec::new();
    let rows = PROPERTY_NAMES
        .iter()
        .zip(&ours)
        .zip(d.truth)
        .zip(PAPER_10MHZ);
    for (k, (((name, q), t), (pv, pu))) in rows.enumerate() {
        let (digits, pd) = if k < 3 { (4, 2) } else { (5, 3) };
        let ph = k
            .checked_sub(3)
            .and_then(|i| phase.as_ref()?.get(i))
            .map_or("—".to_string(), |p| {
                format!("{:.*} ± {:.*}", digits, p.value, digits, p.expanded_unc)
            });
        let ur = pu / q.expanded_unc;
        ratios.push(ur);
        let _ = writeln!(
            o,
            "{:<5} {:>22} {:>9} {:>8.2} {:>20} {:>8}× {:>20}",
            name,
            format!("{:.*} ± {:.*}", digits, q.value, digits, q.expanded_unc),
            format!("{:.*}", pd, t),
            (q.value - t).abs() / q.expanded_unc,
            format!("{:.*} ± {:.*}", pd, pv, pd, pu),
            ratio(ur),
            ph
        );
    }
    let _ = writeln!(
        o,
        "U ratio: the stated uncertainty of Gaitan & Geist (2022) over rotacal's U. With sensor noise the only\n\
         simulated effect, {};\nthe missing effects are what the discrepancy workflow is for.",
        ratio_sentence(&ratios)
    );
}

/// The paper's puzzle, every comparison word from its numbers.
fn render_puzzle(o: &mut String, p: &Puzzle) {
    let label = deviation_label(&p.rates_hz);
    let rates: Vec<String> = p.rates_hz.iter().map(|r| short(r * 1e3)).collect();
    let _ = writeln!(
        o,
        "\nThe paper's puzzle: Gaitan & Geist (2022) saw s_w deviate at 0.5 Hz and could not say why. Simulated:\n\
         paper-multirate ({} mHz; sensor {} cm off the axis) with K2 = {:e} /(m/s²) on w.\n\
         Fitting each rate on its own (the paper's analysis): {label} = {:+.4} ± {:.4},\n\
         {}. rotacal discrepancy names {}\n\
         (χ²/dof {:.0} → {:.3}): K2_w = {:.3e} ± {:.1e} /(m/s²),\n\
         radius {} m.\n\
         With them modelled: {label} = {:+.4} ± {:.4}, {}.\n\
         Verdict: {}.\n\
         Report: {}",
        rates.join(", "),
        short(p.true_radius_m * 100.0),
        p.true_k2_w,
        p.deviation_per_rate.0,
        p.deviation_per_rate.1,
        against_u(p.deviation_per_rate),
        if p.named.is_empty() {
            "no effect".to_string()
        } else {
            p.named.join(" then ")
        },
        p.chi2_dof.0,
        p.chi2_dof.1,
        p.k2_w.0,
        p.k2_w.1,
        p.radius
            .iter()
            .map(|(v, u)| format!("{v:.5} ± {u:.5}"))
            .collect::<Vec<_>>()
            .join(", "),
        p.deviation_modelled.0,
        p.deviation_modelled.1,
        against_u(p.deviation_modelled),
        p.verdict.1,
        p.report.display()
    );
}
