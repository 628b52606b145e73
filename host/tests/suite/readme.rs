//! The README's quick start, run as a user pastes it: its three commands, from a folder
//! that holds the repository's `examples/`, each exiting 0; the calibration within U of the
//! example's truth (examples/serial-dump/README.md).
use std::path::Path;
use std::process::Command;

/// The commands of the README's section `heading`: its indented lines starting `rotacal `.
fn commands(readme: &str, heading: &str) -> Vec<Vec<String>> {
    let start = readme.find(heading).unwrap();
    let section = &readme[start + heading.len()..];
    let section = &section[..section.find("\n## ").unwrap_or(section.len())];
    section
        .lines()
        .filter_map(|l| l.strip_prefix("    rotacal "))
        .map(|l| l.split_whitespace().map(String::from).collect())
        .collect()
}

#[test]
fn the_quick_start_works_as_pasted() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
    let steps = commands(&readme, "## Quick start");
    assert_eq!(steps.len(), 3, "{steps:?}");
    let d = std::env::temp_dir().join(format!("rotacal-readme-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    std::os::unix::fs::symlink(
        root.join("examples").canonicalize().unwrap(),
        d.join("examples"),
    )
    .unwrap();
    for args in &steps {
        let out = Command::new(env!("CARGO_BIN_EXE_rotacal"))
            .args(args)
            .current_dir(&d)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "rotacal {}:\n{}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    assert!(d.join("report/report.md").is_file());
    let cal: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("cal.json")).unwrap()).unwrap();
    let i = &cal["by_rate"][0]["intrinsic"];
    let truth = [
        (&i["sensitivity"]["u"], 1669.32),
        (&i["sensitivity"]["v"], 1669.10),
        (&i["sensitivity"]["w"], 1676.46),
        (&i["angle_deg"]["uv"], 90.077),
        (&i["angle_deg"]["vw"], 90.095),
        (&i["angle_deg"]["wu"], 89.910),
    ];
    for (q, t) in truth {
        let (v, u) = (
            q["value"].as_f64().unwrap(),
            q["expanded_unc"].as_f64().unwrap(),
        );
        assert!((v - t).abs() <= u, "{v} ± {u} vs truth {t}");
    }
    std::fs::remove_dir_all(&d).ok();
}
