//! Statistical proofs at two sizes (docs/testing.md), for the engine's tests and the
//! application's suite alike.
//!
//! A proof of a coverage or a detection rate needs thousands of simulated sessions, which
//! test-all cannot afford on every run. So each proof keeps a record,
//! `bench/proofs/NAME.json`, written when it runs in full (`scripts/bench-proofs`, which
//! sets `ROTACAL_PROOFS=full`): its size, its verdict, and a witness of its first sessions.
//! Otherwise a proof runs only those first sessions and requires them to be the ones the
//! record measured, so that the record speaks for the code under test. A change of
//! behaviour fails until the proof is run in full again on it.
// A test harness: it fails a test by panicking, as `assert!` does.
#![allow(clippy::panic)]

use serde::{Deserialize, Serialize};
use std::fmt::Debug;
use std::path::PathBuf;
use std::time::Instant;

/// Sessions of each proof that test-all runs again and compares with its record.
pub const WITNESSES: usize = 8;

/// What a proof's record keeps.
#[derive(Debug, Serialize, Deserialize)]
struct Record {
    /// The test that makes the proof.
    name: String,
    /// Its sessions (trials).
    trials: usize,
    /// Whether every check held.
    passed: bool,
    /// The checks that failed.
    failures: Vec<String>,
    /// Wall time of the full run, s.
    seconds: f64,
    /// The first sessions' results, digested.
    witness: Vec<Digest>,
}

/// A session's result in brief: its `Debug` text with every number taken out (hashed), the
/// count of numbers, and a random projection of them on a scale-free axis, so that a change
/// of any number beyond rounding shows while the last bit of a sum does not.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Digest {
    /// FNV-1a of the text less its numbers, hexadecimal.
    text: String,
    /// How many numbers the text holds.
    numbers: usize,
    /// Σ wᵢ·sign(xᵢ)·ln(1 + |xᵢ|/10⁻¹²), wᵢ fixed pseudo-random weights of size ~1.
    projection: f64,
}

impl Digest {
    /// Whether `other` is the same result: the same text and count, the projection within
    /// 10⁻¹⁰ per number (the scale-free terms move by ~10⁻¹⁵ each for a last-bit change,
    /// and by 10⁻⁶ for a number changed by a part in a million).
    fn matches(&self, other: &Digest) -> bool {
        self.text == other.text
            && self.numbers == other.numbers
            && (self.projection - other.projection).abs() <= 1e-10 * self.numbers.max(1) as f64
    }
}

/// The weight of the k-th number: SplitMix64, mapped to ±[0.5, 1.5).
fn weight(k: usize) -> f64 {
    let mut z = (k as u64).wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    let size = 0.5 + (z >> 11) as f64 / (1u64 << 53) as f64;
    if z & 1 == 0 {
        size
    } else {
        -size
    }
}

/// The digest of a result's `Debug` text.
pub fn digest<T: Debug>(result: &T) -> Digest {
    let text = format!("{result:?}");
    let b = text.as_bytes();
    let mut hash: u64 = 0xCBF2_9CE4_8422_2325;
    let mut put = |c: u8| {
        hash ^= u64::from(c);
        hash = hash.wrapping_mul(0x0000_0100_0000_01B3);
    };
    let (mut numbers, mut projection) = (0usize, 0.0f64);
    let at = |j: usize| b.get(j).copied().unwrap_or(b' ');
    let mut i = 0;
    while i < b.len() {
        let c = at(i);
        let in_word = i > 0 && (at(i - 1).is_ascii_alphanumeric() || at(i - 1) == b'_');
        let starts = c.is_ascii_digit() || (c == b'-' && at(i + 1).is_ascii_digit());
        if starts && !in_word {
            let start = i;
            i += 1;
            while i < b.len() {
                let d = at(i);
                let exp_sign = (d == b'-' || d == b'+') && matches!(at(i - 1), b'e' | b'E');
                if d.is_ascii_digit() || d == b'.' || d == b'e' || d == b'E' || exp_sign {
                    i += 1;
                } else {
                    break;
                }
            }
            let token = text.get(start..i).unwrap_or("");
            if let Ok(x) = token.parse::<f64>() {
                projection += weight(numbers) * x.signum() * (x.abs() / 1e-12).ln_1p();
                numbers += 1;
                put(b'#');
            } else {
                token.bytes().for_each(&mut put);
            }
            continue;
        }
        put(c);
        i += 1;
    }
    Digest {
        text: format!("{hash:016x}"),
        numbers,
        projection,
    }
}

/// Runs `trial(i)` for i in 0..n on two threads, in order of i.
pub fn parallel_n<T: Send>(n: usize, trial: impl Fn(usize) -> T + Sync) -> Vec<T> {
    let half = n / 2;
    std::thread::scope(|s| {
        let a = s.spawn(|| (0..half).map(&trial).collect::<Vec<_>>());
        let mut out: Vec<T> = (half..n).map(&trial).collect();
        let mut first = a.join().unwrap_or_else(|e| std::panic::resume_unwind(e));
        first.append(&mut out);
        first
    })
}

fn record_path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../bench/proofs")
        .join(format!(
            "{}.json",
            name.replace("::", ".").replace('#', ".")
        ))
}

/// Whether this run makes the proofs in full (`ROTACAL_PROOFS=full`).
pub fn full() -> bool {
    std::env::var("ROTACAL_PROOFS").is_ok_and(|v| v == "full")
}

/// A statistical proof named `name` (the test's path as `cargo test` prints it, and after
/// a `#` the case where one test makes several proofs) over `trials` sessions: `trial(i)` is
/// session i's result, and `check` the proof's verdict on all of them (the failures, empty
/// when it holds; it prints what it measured).
///
/// In full (`ROTACAL_PROOFS=full`) every session runs, `check` judges them, and the record
/// is written before the verdict is asserted. Otherwise the first [`WITNESSES`] sessions
/// run and must match the record, which must be of `trials` sessions and have passed.
pub fn prove<T: Debug + Send>(
    name: &str,
    trials: usize,
    trial: impl Fn(usize) -> T + Sync,
    check: impl FnOnce(&[T]) -> Vec<String>,
) {
    let path = record_path(name);
    let w = WITNESSES.min(trials);
    if full() {
        let t0 = Instant::now();
        let results = parallel_n(trials, trial);
        let failures = check(&results);
        let record = Record {
            name: name.to_string(),
            trials,
            passed: failures.is_empty(),
            failures: failures.clone(),
            seconds: (t0.elapsed().as_secs_f64() * 10.0).round() / 10.0,
            witness: results.iter().take(w).map(digest).collect(),
        };
        let written = path
            .parent()
            .map_or(Ok(()), std::fs::create_dir_all)
            .map_err(|e| e.to_string())
            .and_then(|()| serde_json::to_string_pretty(&record).map_err(|e| e.to_string()))
            .and_then(|text| std::fs::write(&path, text + "\n").map_err(|e| e.to_string()));
        if let Err(e) = written {
            panic!(
                "{name}: its record {} could not be written: {e}",
                path.display()
            );
        }
        assert!(failures.is_empty(), "{name}: {failures:?}");
        return;
    }
    // The test's own path (a proof may be one case of it, after '#'), as `cargo test`
    // filters.
    let test = name.split('#').next().unwrap_or(name);
    let file = path
        .file_name()
        .map_or(name.into(), |f| f.to_string_lossy());
    let again = format!("run `scripts/bench-proofs {test}` and commit bench/proofs/{file}");
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("{name}: no record of its full run ({e}): {again}"));
    let record: Record = serde_json::from_str(&text)
        .unwrap_or_else(|e| panic!("{name}: its record is unreadable ({e}): {again}"));
    assert_eq!(
        record.trials, trials,
        "{name}: the record is of {} sessions, the proof asks {trials}: {again}",
        record.trials
    );
    assert!(
        record.passed,
        "{name}: the proof failed in its last full run: {:?}",
        record.failures
    );
    assert_eq!(
        record.witness.len(),
        w,
        "{name}: the record's witness: {again}"
    );
    let results = parallel_n(w, trial);
    for (i, (now, then)) in results.iter().map(digest).zip(&record.witness).enumerate() {
        assert!(
            now.matches(then),
            "{name}: session {i} differs from the one its proof measured ({now:?} against \
             {then:?}): behaviour changed, so the proof must be made again: {again}"
        );
    }
}

#[cfg(test)]
#[test]
#[allow(clippy::indexing_slicing)]
fn a_digest_sees_a_number_change_and_not_its_last_bit() {
    let a = (
        400.123_456_789_f64,
        1.234e-4_f64,
        "s_u",
        vec![2.0_f64, -3.5],
    );
    let mut b = a.clone();
    b.0 = f64::from_bits(a.0.to_bits() + 1);
    b.1 = f64::from_bits(a.1.to_bits() - 1);
    assert!(digest(&a).matches(&digest(&b)));
    // One number changed by a part in a million, one by a sign, one word.
    let mut c = a.clone();
    c.1 *= 1.0 + 1e-6;
    assert!(!digest(&a).matches(&digest(&c)));
    let mut d = a.clone();
    d.3[1] = 3.5;
    assert!(!digest(&a).matches(&digest(&d)));
    let mut e = a.clone();
    e.2 = "s_v";
    assert!(!digest(&a).matches(&digest(&e)));
    assert_eq!(digest(&a).numbers, 4);
}
