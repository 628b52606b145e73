//! `calibrate`'s check of its residuals for structure beyond the noise (docs/uncertainty.md,
//! "Structure beyond the noise"): it warns, with the place, on a 5th-order nonlinearity
//! and on an offset step, and stays silent on clean sessions under white, correlated,
//! per-channel and slow noise. The noise is never stated, and the calibration is told
//! neither the effect nor the noise.
use rotacal::calibrate::json::StructureJson;
use rotacal::calibrate::{calibrate, Options};
use rotacal::discrepancy::trials::{Noise, SINGLE_RATE};
use rotacal::simulate::{Config, Simulation};
use rotacal_proof::prove;

/// A finding: (condition, channel, kind, harmonic, at_s, z).
type Finding = (
    String,
    String,
    &'static str,
    Option<usize>,
    Option<f64>,
    f64,
);

/// What a session's check reported: each finding as (condition, channel, kind, harmonic,
/// at_s, z).
#[derive(Debug)]
struct Outcome {
    found: bool,
    scanned: usize,
    findings: Vec<Finding>,
}

fn calibrated(toml: &str, seed: u64, slow_noise: bool) -> Outcome {
    let mut cfg = Config::from_toml(toml).unwrap();
    cfg.seed = seed;
    let rec = Simulation::new(cfg).unwrap().recording().unwrap();
    let opts = Options {
        slow_noise,
        ..Options::default()
    };
    let check = calibrate(&rec, &opts).unwrap().residual_structure.unwrap();
    let brief = |s: &StructureJson| {
        (
            s.condition.to_string(),
            s.channel.to_string(),
            s.kind,
            s.harmonic,
            s.at_s,
            s.z,
        )
    };
    Outcome {
        found: check.found,
        scanned: check.groups_scanned,
        findings: check.structure.iter().map(brief).collect(),
    }
}

/// Effects the check must find.
#[derive(Clone, Copy, Debug)]
enum Effect {
    /// 5th-order response on v: its 5th harmonic on v in conditions x and z.
    Order5,
    /// v's offset steps by 8 counts at 400 s, 77.5 s into condition y.
    Step,
}

impl Effect {
    fn toml(self) -> &'static str {
        match self {
            Effect::Order5 => "[effects.nonlinearity_high]\norder = 5\nk = [0.0, 5.8e-7, 0.0]\n",
            Effect::Step => "[effects.offset_step]\nat_s = 400.0\nsize = [0.0, 8.0, 0.0]\n",
        }
    }

    /// Whether a finding is this effect's, at its place.
    fn located(self, o: &Outcome) -> bool {
        o.findings
            .iter()
            .any(|(cond, ch, kind, k, at, _)| match self {
                Effect::Order5 => ch == "v" && *kind == "harmonic" && *k == Some(5),
                Effect::Step => {
                    cond == "y"
                        && ch == "v"
                        && *kind == "step"
                        && at.is_some_and(|t| (t - 77.5).abs() <= 5.0)
                }
            })
    }
}

#[test]
fn calibrate_warns_where_structure_is() {
    const SEEDS: usize = 20;
    // (effect, noise, --slow-noise)
    let cases = [
        (Effect::Order5, Noise::White, false),
        (Effect::Order5, Noise::Ar1, false),
        (Effect::Order5, Noise::White, true),
        (Effect::Step, Noise::White, false),
        (Effect::Step, Noise::Ar1, false),
        (Effect::Step, Noise::White, true),
    ];
    let trial = |t: usize| {
        let (e, n, slow) = cases[t / SEEDS];
        let toml = format!("{SINGLE_RATE}{}{}", e.toml(), n.toml());
        calibrated(&toml, (t % SEEDS) as u64 + 1, slow)
    };
    prove(
        "structure_check::calibrate_warns_where_structure_is",
        cases.len() * SEEDS,
        trial,
        |runs| {
            let mut failures = Vec::new();
            for (chunk, (e, n, slow)) in runs.chunks(SEEDS).zip(cases) {
                let located = chunk.iter().filter(|o| o.found && e.located(o)).count();
                println!("{e:?} in {n:?}, slow noise {slow}: warned at its place in {located} of {SEEDS}");
                // At least 95 %: 19 of 20.
                if located * 20 < SEEDS * 19 {
                    failures.push(format!(
                        "{e:?} in {n:?} (slow noise {slow}): warned at its place in {located} \
                         of {SEEDS}; first session: {:?}",
                        chunk.first()
                    ));
                }
            }
            failures
        },
    );
}

#[test]
fn calibrate_is_silent_on_clean_sessions() {
    const SEEDS: usize = 250;
    // The slow kinds with --slow-noise, as their U needs it; without it the check warns on
    // them, rightly (docs/uncertainty.md, "Structure beyond the noise").
    let cases = [
        (Noise::White, false),
        (Noise::Ar1, false),
        (Noise::Levels345, false),
        (Noise::Flicker50, true),
        (Noise::Walk10, true),
    ];
    let trial = |t: usize| {
        let (n, slow) = cases[t / SEEDS];
        let toml = format!("{SINGLE_RATE}{}", n.toml());
        calibrated(&toml, 0x5C4E_0000 + (t % SEEDS) as u64, slow)
    };
    prove(
        "structure_check::calibrate_is_silent_on_clean_sessions",
        cases.len() * SEEDS,
        trial,
        |runs| {
            let mut failures = Vec::new();
            for (chunk, (n, slow)) in runs.chunks(SEEDS).zip(cases) {
                let warned = chunk.iter().filter(|o| o.found).count();
                println!("{n:?}, slow noise {slow}: warned in {warned} of {SEEDS}");
                if let Some(o) = chunk.iter().find(|o| o.scanned != 3) {
                    failures.push(format!("{n:?}: a session scanned {} groups", o.scanned));
                }
            }
            let warned: Vec<&Outcome> = runs.iter().filter(|o| o.found).collect();
            println!(
                "all: warned in {} of {}; e.g. {:?}",
                warned.len(),
                runs.len(),
                warned.first()
            );
            // At most 1 %.
            if warned.len() * 100 > runs.len() {
                failures.push(format!(
                    "warned in {} of {} clean sessions, e.g. {:?}",
                    warned.len(),
                    runs.len(),
                    warned.first()
                ));
            }
            failures
        },
    );
}
