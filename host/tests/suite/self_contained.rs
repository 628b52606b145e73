//! The documentation stands alone (issue 34): the binary prints the file formats it reads
//! and writes, and nothing the project ships points outside its repository.
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

#[test]
fn help_formats_prints_docs_formats_md() {
    let out = Command::new(env!("CARGO_BIN_EXE_rotacal"))
        .args(["help", "formats"])
        .output()
        .unwrap();
    assert!(out.status.success());
    let doc = std::fs::read_to_string(root().join("docs/formats.md")).unwrap();
    assert_eq!(String::from_utf8(out.stdout).unwrap(), doc);
    // A subcommand's help lists the columns it reads.
    let out = Command::new(env!("CARGO_BIN_EXE_rotacal"))
        .args(["help", "calibrate"])
        .output()
        .unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    for column in [
        "condition",
        "t_s",
        "angle_deg",
        "gx, gy, gz",
        "rotacal help formats",
    ] {
        assert!(
            text.contains(column),
            "calibrate's help lacks {column}:\n{text}"
        );
    }
    // Every topic the top-level help lists prints its document, byte for byte.
    let out = Command::new(env!("CARGO_BIN_EXE_rotacal"))
        .arg("--help")
        .output()
        .unwrap();
    let top = String::from_utf8(out.stdout).unwrap();
    let listed: Vec<&str> = top
        .split("Topics (rotacal help TOPIC):")
        .nth(1)
        .expect("the top-level help lists the topics")
        .lines()
        .filter_map(|l| l.split_whitespace().next())
        .collect();
    assert_eq!(listed, ["formats", "simulator", "recording", "protocol"]);
    for topic in listed {
        let file = format!("{topic}.md");
        let out = Command::new(env!("CARGO_BIN_EXE_rotacal"))
            .args(["help", topic])
            .output()
            .unwrap();
        assert!(out.status.success(), "help {topic}");
        let doc = std::fs::read_to_string(root().join("docs").join(&file)).unwrap();
        assert_eq!(String::from_utf8(out.stdout).unwrap(), doc, "help {topic}");
    }
    // The commands that read something other than a recording say where its format is.
    for (command, says) in [
        ("simulate", "rotacal help simulator"),
        ("decode", "rotacal help recording"),
        ("export", "its keys: rotacal help formats"),
        ("apply", "its keys: rotacal help formats"),
        ("apply", "gx, gy, gz"),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_rotacal"))
            .args(["help", command])
            .output()
            .unwrap();
        let text = String::from_utf8(out.stdout).unwrap();
        assert!(
            text.contains(says),
            "{command}'s help lacks {says}:\n{text}"
        );
    }
    // An unknown topic is an error naming the topics.
    let out = Command::new(env!("CARGO_BIN_EXE_rotacal"))
        .args(["help", "format"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(
        err.contains(
            "the topics are formats, simulator, recording, protocol and the subcommands (calibrate"
        ),
        "{err}"
    );
}

/// Every text file under `dir` (recursively) with one of `exts`, but build output.
fn files(dir: &Path, exts: &[&str], out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_string_lossy().to_string();
        if p.is_dir() {
            if name != "target" && !name.starts_with('.') {
                files(&p, exts, out);
            }
        } else if exts.iter().any(|x| name.ends_with(x)) {
            out.push(p);
        }
    }
}

#[test]
fn nothing_points_outside_the_repository() {
    let root = root();
    let mut all = Vec::new();
    for d in [
        "host", "shared", "firmware", "sensor", "tests", "docs", "python",
    ] {
        files(
            &root.join(d),
            &[".rs", ".md", ".toml", ".py", ".sh"],
            &mut all,
        );
    }
    // The scripts have no extension.
    files(&root.join("scripts"), &[""], &mut all);
    all.push(root.join("README.md"));
    let mut bad = Vec::new();
    for p in &all {
        let Ok(text) = std::fs::read_to_string(p) else {
            continue;
        };
        let in_docs = p.parent().is_some_and(|d| d.ends_with("docs"));
        for (i, line) in text.lines().enumerate() {
            // The repository's own shared/ is a crate (no docs, reference or data in it).
            // (The patterns are spelt in pieces, so that this file does not match itself.)
            let outside = [
                concat!("shared", "/docs"),
                concat!("shared", "/reference"),
                concat!("shared", "/data"),
                concat!("/wo", "rk/"),
            ]
            .iter()
            .any(|s| line.contains(s));
            // The method is the project's own docs/method.md (in docs/, a link beside it).
            let method = line.match_indices(concat!("method", ".md")).any(|(at, _)| {
                let before = line.get(..at).unwrap_or("");
                !(before.ends_with("docs/") || (in_docs && before.ends_with('(')))
            });
            if outside || method {
                bad.push(format!("{}:{}: {line}", p.display(), i + 1));
            }
        }
    }
    assert!(root.join("docs/method.md").is_file());
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}
