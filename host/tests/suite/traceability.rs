//! Issue 34: the traceability block is in every JSON, report, export and corrected
//! recording: rotacal's version and commit, the date, the input's SHA-256 (checked against
//! `sha256sum`), the device and firmware from the recording's `# device=`, the temperature
//! range, g_loc with its source and uncertainty, and the command line.
use crate::common::run;
use std::path::{Path, PathBuf};

fn sha256sum(p: &Path) -> String {
    let out = std::process::Command::new("sha256sum")
        .arg(p)
        .output()
        .unwrap();
    String::from_utf8(out.stdout).unwrap()[..64].to_string()
}

fn dir() -> PathBuf {
    let d = std::env::temp_dir().join(format!("rotacal-trace-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn every_output_carries_the_traceability_block() {
    let d = dir();
    let ex = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/serial-dump");
    let rec = d.join("session.csv");
    let mut args: Vec<String> = vec!["import".into()];
    args.extend(["x", "y", "z"].map(|c| ex.join(format!("{c}.txt")).display().to_string()));
    args.extend(
        [
            "--columns",
            "t=micros,u=ax,v=ay,w=az,temp=temp",
            "--time-scale",
            "0.000001",
            "--condition",
            "x,y,z",
            "--rate-hz",
            "0.1",
            "--g-loc",
            "9.80101",
            "--units",
            "counts",
            "--device",
            "LSM6DS33 firmware 0.2.0 (BLE device F1:23:45:67:89:AB)",
            "--out",
        ]
        .map(String::from),
    );
    args.push(rec.display().to_string());
    let (ok, o, e) = run(&args);
    assert!(ok, "{o}{e}");
    // An uncertainty of g_loc in the recording (the device came with --device).
    let text = std::fs::read_to_string(&rec).unwrap().replacen(
        "# units=counts\n",
        "# units=counts\n# u_g_loc=0.0002\n",
        1,
    );
    std::fs::write(&rec, text).unwrap();
    let sha = sha256sum(&rec);
    let p = |name: &str| d.join(name).display().to_string();
    let r = rec.display().to_string();
    let (ok, o, e) = run(&["calibrate", &r, "--json", &p("cal.json")]);
    assert!(ok, "{o}{e}");
    let json = |name: &str| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(d.join(name)).unwrap()).unwrap()
    };
    let cal = json("cal.json");
    let t = &cal["traceability"];
    assert_eq!(t["rotacal"], env!("CARGO_PKG_VERSION"));
    assert!(!t["commit"].as_str().unwrap().is_empty());
    assert!(t["date_utc"].as_str().unwrap().starts_with("20"));
    assert_eq!(t["inputs"][0]["sha256"], sha.as_str());
    assert_eq!(
        t["device"],
        "LSM6DS33 firmware 0.2.0 (BLE device F1:23:45:67:89:AB)"
    );
    assert_eq!(t["firmware"], "0.2.0");
    assert_eq!(t["temperature_c"]["min"], 25.0);
    assert_eq!(t["g_loc"]["value"], 9.80101);
    assert_eq!(t["g_loc"]["source"], "the recording's g_loc");
    assert_eq!(t["g_loc"]["std_unc"], 0.0002);
    assert_eq!(t["g_loc"]["std_unc_source"], "the recording's u_g_loc");
    let cmd: Vec<&str> = t["command_line"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert_eq!(
        &cmd[1..],
        &["calibrate", r.as_str(), "--json", p("cal.json").as_str()]
    );
    // The keys before it as they were: traceability is added last.
    let keys: Vec<&String> = cal.as_object().unwrap().keys().collect();
    assert!(keys.contains(&&"by_rate".to_string()));

    // A flag's g_loc is named as such.
    let (ok, o, e) = run(&["calibrate", &r, "--g-loc", "9.8", "--json", &p("cal2.json")]);
    assert!(ok, "{o}{e}");
    assert_eq!(
        json("cal2.json")["traceability"]["g_loc"]["source"],
        "--g-loc"
    );

    // The report's Markdown, the other JSONs, the exports.
    let (ok, o, e) = run(&["report", &r, "--out", &p("report")]);
    assert!(ok, "{o}{e}");
    let md = std::fs::read_to_string(d.join("report/report.md")).unwrap();
    assert!(md.contains("## Traceability") && md.contains(&sha), "{md}");
    assert!(md.contains("| firmware | 0.2.0 |"), "{md}");
    let (ok, o, e) = run(&["allan", &r, "--json", &p("allan.json")]);
    assert!(ok, "{o}{e}");
    assert_eq!(
        json("allan.json")["traceability"]["inputs"][0]["sha256"],
        sha.as_str()
    );
    let (_, o, e) = run(&["discrepancy", &r, "--json", &p("disc.json")]);
    assert!(d.join("disc.json").exists(), "{o}{e}");
    assert_eq!(
        json("disc.json")["traceability"]["inputs"][0]["sha256"],
        sha.as_str()
    );
    let cal_sha = sha256sum(&d.join("cal.json"));
    for format in ["c", "rust", "json"] {
        let out = p(&format!("export.{format}"));
        let (ok, o, e) = run(&["export", &p("cal.json"), "--format", format, "--out", &out]);
        assert!(ok, "{o}{e}");
        let text = std::fs::read_to_string(&out).unwrap();
        assert!(text.contains(&cal_sha), "{format}: {text}");
        assert!(
            text.contains(&sha),
            "{format}: the recording's SHA-256 is missing"
        );
        assert!(text.contains("0.2.0"), "{format}");
    }
    // A corrected recording names its calibration and recording by SHA-256, and keeps the
    // recording's device line.
    let (ok, o, e) = run(&["apply", &p("cal.json"), &r, "--out", &p("ms2.csv")]);
    assert!(ok, "{o}{e}");
    let text = std::fs::read_to_string(d.join("ms2.csv")).unwrap();
    let meta: Vec<&str> = text.lines().take_while(|l| l.starts_with('#')).collect();
    for line in [
        format!("# calibration_sha256={cal_sha}"),
        format!("# recording_sha256={sha}"),
        format!("# rotacal={}", env!("CARGO_PKG_VERSION")),
    ] {
        assert!(meta.contains(&line.as_str()), "{line} not in {meta:?}");
    }
    for key in [
        "# rotacal_commit=",
        "# date_utc=20",
        "# command_line=",
        "# device=",
    ] {
        assert!(
            meta.iter().any(|l| l.starts_with(key)),
            "{key} not in {meta:?}"
        );
    }
    // A file without conditions (here a free series; poses alike) is not scanned row by
    // row: its facts came out empty before (device and g_loc null).
    let free =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/imutk-xsens/xsens_acc_free.csv");
    let (ok, o, e) = run(&[
        "calibrate",
        &free.display().to_string(),
        "--json",
        &p("free.json"),
    ]);
    assert!(ok, "{o}{e}");
    let t = &json("free.json")["traceability"];
    assert_eq!(
        t["device"],
        "Xsens MTi (imu_tk test_data/xsens_acc.mat, A. Pretto, BSD)"
    );
    assert_eq!(t["g_loc"]["source"], "the recording's g_loc");
    assert_eq!(t["inputs"][0]["sha256"], sha256sum(&free).as_str());
    std::fs::remove_dir_all(&d).ok();
}
