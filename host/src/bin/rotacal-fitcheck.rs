//! Developer check behind the test and benchmark scripts: compares the emulated device's
//! f32 fits (tests/qemu `crosscheck` output) with f64 batch fits of the same samples,
//! optionally merges the QEMU instruction-count benchmark and host throughput, and
//! writes JSON. Exits 1 if the ratio exceeds the threshold or the runs disagree.

use anyhow::{Context, Result};
use clap::Parser;
use rotacal::verify::emulated;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::PathBuf;

#[derive(Parser)]
#[command(about = "Check the device's f32 fits against host f64 fits (issue 2's cross-check)")]
struct Args {
    /// Output of the QEMU `crosscheck` binary.
    #[arg(long)]
    crosscheck: Option<PathBuf>,
    /// Output of the QEMU `session` binary (the device logic through a simulated session).
    #[arg(long)]
    session: Option<PathBuf>,
    /// Fail the session check above this max |device − host f64| / σ_CRLB: the accuracy
    /// the fit showed on its own (bench/fit.json: 5.8e-6 at worst).
    #[arg(long, default_value_t = 1e-5)]
    session_threshold: f64,
    /// Output of the QEMU `bench` binary (run with -icount shift=0), to include.
    #[arg(long)]
    bench: Option<PathBuf>,
    /// Also measure host fit throughput.
    #[arg(long)]
    throughput: bool,
    /// Fail above this max |f32 − f64| / σ_CRLB.
    #[arg(long, default_value_t = 0.01)]
    threshold: f64,
    /// Print every compared value, not only the summary.
    #[arg(long)]
    table: bool,
    /// Write the results here as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
}

fn main() -> std::process::ExitCode {
    match run(Args::parse()) {
        Ok(true) => std::process::ExitCode::SUCCESS,
        Ok(false) => {
            eprintln!("cross-check FAILED");
            std::process::ExitCode::FAILURE
        }
        Err(e) => {
            eprintln!("rotacal-fitcheck: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run(args: Args) -> Result<bool> {
    let mut json = serde_json::Map::new();
    let mut o = String::new();
    let mut ok = true;
    if args.crosscheck.is_none() && args.session.is_none() {
        anyhow::bail!("give --crosscheck LOG, --session LOG or both");
    }
    if let Some(path) = &args.crosscheck {
        ok &= crosscheck(&args, path, &mut o, &mut json)?;
    }
    if let Some(path) = &args.session {
        ok &= session(&args, path, &mut o, &mut json)?;
    }
    if let Some(path) = &args.json {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir)?;
        }
        std::fs::write(path, serde_json::to_string_pretty(&json)? + "\n")
            .with_context(|| format!("writing {}", path.display()))?;
        let _ = writeln!(o, "wrote {}", path.display());
    }
    rotacal::output::emit(&o)?;
    if ok {
        rotacal::output::emit("cross-check passed\n")?;
    }
    Ok(ok)
}

type Json = serde_json::Map<String, serde_json::Value>;

fn read(path: &std::path::Path) -> Result<String> {
    std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))
}

fn session(args: &Args, path: &std::path::Path, o: &mut String, json: &mut Json) -> Result<bool> {
    let text = read(path)?;
    let packets = rotacal::verify::session::parse_log(&text, &path.display().to_string())?;
    let rep = rotacal::verify::session::check(&packets)?;
    let finals = rep.fits.iter().filter(|f| f.is_final).count();
    let _ = writeln!(
        o,
        "session: {} packets, {} samples, seq contiguous: {}, bit-identical to the host's run: {}",
        rep.packets, rep.samples, rep.seq_contiguous, rep.bit_identical_to_host
    );
    let _ = writeln!(
        o,
        "session: {} fit reports ({finals} final): max |device − f64 batch| / σ_CRLB = {:.2e} (threshold {:.0e})",
        rep.fits.len(),
        rep.max_ratio_crlb,
        args.session_threshold
    );
    match rep.quick_look_max_ratio_u {
        Some(r) => {
            let _ = writeln!(
                o,
                "session: quick-look vs host Gram form: max |Δ| / u = {r:.2e}"
            );
        }
        None => {
            let _ = writeln!(o, "session: no quick-look");
        }
    }
    let ok = rep.bit_identical_to_host
        && rep.seq_contiguous
        && finals == 3
        && rep.max_ratio_crlb <= args.session_threshold
        && rep.quick_look_max_ratio_u.is_some_and(|r| r <= 1e-4);
    json.insert("session".into(), serde_json::to_value(&rep)?);
    Ok(ok)
}

fn crosscheck(
    args: &Args,
    path: &std::path::Path,
    o: &mut String,
    json: &mut Json,
) -> Result<bool> {
    let text = read(path)?;
    let log = emulated::parse_log(&text).with_context(|| format!("{}", path.display()))?;
    let rep = emulated::check(&log)?;
    // Output is collected and written once, through a writer that survives a closed pipe.
    macro_rules! out {
        ($($a:tt)*) => { let _ = writeln!(o, $($a)*); };
    }
    if args.table {
        out!(
            "{:<12} {:<4} {:<10} {:>3} {:>16} {:>16} {:>10} {:>10}",
            "record",
            "cond",
            "model",
            "ch·p",
            "device f32",
            "host f64",
            "Δ/σ_CRLB",
            "Δ/se"
        );
    }
    for v in rep.values.iter().filter(|_| args.table) {
        out!(
            "{:<12} {:<4} {:<10} {}·{} {:>16.6} {:>16.6} {:>10.2e} {:>10.2e}",
            v.record,
            v.condition,
            v.model,
            v.channel,
            v.param,
            v.device,
            v.host_f64,
            v.ratio_crlb,
            v.ratio_se
        );
    }
    out!("samples per condition: {:?}", rep.records);
    for rec in rep.records.keys() {
        let worst = rep
            .values
            .iter()
            .filter(|v| &v.record == rec && v.model == "sine")
            .map(|v| v.ratio_crlb)
            .fold(0.0, f64::max);
        out!("  {rec}: max |f32 − f64| / σ_CRLB = {worst:.2e}");
    }
    out!("checksums match: {}", rep.checksums_match);
    out!(
        "host f32 bit-identical to the emulated Cortex-M4F: {}",
        rep.host_f32_bit_identical
    );
    out!(
        "max |f32 − f64| / σ_CRLB (3-parameter fit): {:.2e}  (threshold {:.0e})",
        rep.max_ratio_crlb_sine,
        args.threshold
    );
    out!(
        "max |f32 − f64| / se (drift+rate fit): {:.2e}",
        rep.max_ratio_se_drift_rate
    );

    json.insert("crosscheck".into(), serde_json::to_value(&rep)?);
    if let Some(path) = &args.bench {
        let text = read(path)?;
        let mut bench = BTreeMap::new();
        for (i, line) in text.lines().enumerate() {
            if let Some(rest) = line.strip_prefix("bench ") {
                let (k, v) = rest.split_once(' ').with_context(|| {
                    format!("{}:{}: expected 'bench KEY VALUE'", path.display(), i + 1)
                })?;
                let v: u64 = v
                    .trim()
                    .parse()
                    .with_context(|| format!("{}:{}: not an integer", path.display(), i + 1))?;
                bench.insert(k.to_string(), v);
            }
        }
        for (k, v) in &bench {
            out!("cortex-m4f {k}: {v}");
        }
        json.insert("cortex_m4f".into(), serde_json::to_value(&bench)?);
    }
    if args.throughput {
        let t = emulated::measure_throughput().context("no throughput record")?;
        out!(
            "host throughput: f64 streaming {:.3e} samples/s, f32 streaming {:.3e}, f64 batch QR {:.3e}",
            t.f64_samples_per_s, t.f32_samples_per_s, t.f64_batch_samples_per_s
        );
        json.insert("host_throughput".into(), serde_json::to_value(&t)?);
    }
    Ok(rep.checksums_match
        && rep.host_f32_bit_identical
        && rep.max_ratio_crlb_sine <= args.threshold)
}
