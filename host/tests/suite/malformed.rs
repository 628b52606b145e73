//! The malformed-input corpus (tests/data/malformed/cases.toml): files, packets, flags
//! and a misbehaving device, each run through the `rotacal` binary. Every case must end
//! with its documented exit status, a message holding its expected texts, and no panic.
use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::process::Command;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Case {
    name: String,
    args: Vec<String>,
    #[serde(default)]
    expect: Vec<String>,
    #[serde(default)]
    expect_any: Vec<String>,
    #[serde(default = "one")]
    exit: i32,
    each: Option<String>,
}

fn one() -> i32 {
    1
}

#[derive(Deserialize)]
struct Corpus {
    case: Vec<Case>,
}

fn data() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data")
}

/// The files `pattern` (a folder under tests/data and `*.ext`) names, sorted.
fn each(pattern: &str) -> Vec<PathBuf> {
    let (dir, glob) = pattern.rsplit_once('/').unwrap();
    let ext = glob.strip_prefix("*.").unwrap();
    let mut v: Vec<PathBuf> = std::fs::read_dir(data().join(dir))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == ext))
        .collect();
    v.sort();
    assert!(!v.is_empty(), "{pattern} matches nothing");
    v
}

/// Run one case (with `file` for an `each` case); the failures found.
fn check(case: &Case, file: Option<&Path>, n: usize) -> Vec<String> {
    let tmp = std::env::temp_dir().join(format!("rotacal-malformed-{}-{n}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp).unwrap();
    let name = file.map_or(String::new(), |f| {
        f.file_name().unwrap().to_string_lossy().into_owned()
    });
    let subst = |s: &str| {
        s.replace("{data}", &data().to_string_lossy())
            .replace("{tmp}", &tmp.to_string_lossy())
            .replace(
                "{file}",
                &file.map_or(String::new(), |f| f.display().to_string()),
            )
            .replace("{name}", &name)
    };
    let args: Vec<String> = case.args.iter().map(|a| subst(a)).collect();
    let out = Command::new(env!("CARGO_BIN_EXE_rotacal"))
        .args(&args)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    let label = if name.is_empty() {
        case.name.clone()
    } else {
        format!("{} [{name}]", case.name)
    };
    let mut bad = Vec::new();
    if out.status.code() != Some(case.exit) {
        bad.push(format!(
            "{label}: exit {:?}, want {}",
            out.status.code(),
            case.exit
        ));
    }
    if stderr.contains("panicked") || stderr.contains("RUST_BACKTRACE") {
        bad.push(format!("{label}: panicked"));
    }
    for e in &case.expect {
        let e = subst(e);
        if !stderr.contains(&e) {
            bad.push(format!("{label}: stderr lacks {e:?}"));
        }
    }
    if !case.expect_any.is_empty() && !case.expect_any.iter().any(|e| stderr.contains(e)) {
        bad.push(format!("{label}: stderr has none of {:?}", case.expect_any));
    }
    if !bad.is_empty() {
        bad.push(format!("  stderr was: {}", stderr.trim_end()));
    }
    let _ = std::fs::remove_dir_all(&tmp);
    bad
}

#[test]
fn every_malformed_input_gets_a_clear_message_and_no_panic() {
    let text = std::fs::read_to_string(data().join("malformed/cases.toml")).unwrap();
    let corpus: Corpus = toml::from_str(&text).unwrap();
    let mut failures = Vec::new();
    let mut runs = 0;
    for case in &corpus.case {
        assert!(
            !case.expect.is_empty() || !case.expect_any.is_empty(),
            "{}: a case must expect something",
            case.name
        );
        match &case.each {
            Some(p) => {
                for f in each(p) {
                    failures.extend(check(case, Some(&f), runs));
                    runs += 1;
                }
            }
            None => {
                failures.extend(check(case, None, runs));
                runs += 1;
            }
        }
    }
    println!("{} cases, {runs} runs", corpus.case.len());
    assert!(failures.is_empty(), "\n{}", failures.join("\n"));
}
