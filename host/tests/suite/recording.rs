//! The recording CSV reader and writer (`rotacal::recording`, formats.md "Recording CSV").
//!
//! Valid files live in `tests/data/recording/good/`, one malformed case per file in
//! `tests/data/recording/bad/` with its expected line and message in [`BAD_CASES`].

use std::collections::BTreeMap;
use std::io::{self, Read};
use std::path::{Path, PathBuf};

use proptest::prelude::*;
use rotacal::recording::{
    self, Columns, Group, Metadata, Method, Recording, RecordingErrorKind, Row, Writer,
};
use rotacal_shared::{Aperture, Condition, Ticks};

fn data_dir(sub: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/recording")
        .join(sub)
}

fn good(name: &str) -> Recording {
    let path = data_dir("good").join(name);
    recording::read(&path).unwrap_or_else(|e| panic!("{e}"))
}

fn parse(text: &str) -> Result<Recording, recording::RecordingError> {
    recording::read_from(text.as_bytes(), "mem.csv")
}

fn parse_ok(text: &str) -> Recording {
    parse(text).unwrap_or_else(|e| panic!("{e}"))
}

fn err(text: &str) -> recording::RecordingError {
    match parse(text) {
        Ok(r) => panic!("expected an error, read {} rows", r.rows()),
        Err(e) => e,
    }
}

// ---------------------------------------------------------------------------------------
// Valid files

#[test]
fn valid_rotation_file() {
    let r = good("rotation.csv");
    assert_eq!(r.method, Method::Rotation);
    assert_eq!(r.meta.method, Some(Method::Rotation));
    assert_eq!(r.meta.rate_hz, Some(0.01));
    assert_eq!(r.meta.g_loc, Some(9.80101));
    assert_eq!(r.meta.units.as_deref(), Some("counts"));
    assert!(r.meta.other.is_empty());
    assert!(r.source.ends_with("rotation.csv"));
    let conds: Vec<_> = r.groups.iter().map(|g| g.condition).collect();
    assert_eq!(conds, Condition::ALL);
    assert_eq!(r.rates(), vec![None]);
    assert_eq!(r.rows(), 12);
    assert_eq!(r.nominal_rate(&r.groups[0]), Some(0.01));
    for (k, g) in r.groups.iter().enumerate() {
        assert_eq!(g.rate_hz, None);
        assert_eq!(g.first_line, 7 + 4 * k as u64);
        assert_eq!(g.t_s, vec![0.0, 0.0625, 0.125, 0.1875]);
        assert_eq!(g.u, vec![-12.0, -11.0, -10.0, -9.0]);
        assert_eq!(g.v, vec![16377.0, 16376.0, 16375.0, 16374.0]);
        assert_eq!(g.w, vec![-231.0, -230.0, -229.0, -228.0]);
        assert_eq!(g.temp_c, Some(vec![24.91; 4]));
        assert_eq!(g.seq, None);
        assert!(g.angle_deg.is_empty());
    }
}

#[test]
fn multi_rate_file() {
    let r = good("multirate.csv");
    assert_eq!(r.method, Method::Rotation);
    assert_eq!(r.meta.rate_hz, None);
    assert_eq!(r.groups.len(), 6);
    assert_eq!(r.rates(), vec![Some(0.01), Some(0.25)]);
    let g = r.group(Condition::Y, Some(0.25)).expect("y at 0.25 Hz");
    assert_eq!(g.first_line, 17);
    assert_eq!(g.t_s, vec![0.0, 0.5, 1.0]);
    assert_eq!(g.u, vec![0.0, 1.0, 2.0]);
    assert_eq!(g.w, vec![0.0, 3.0, 6.0]);
    assert!(r.group(Condition::Y, None).is_none());
    assert_eq!(r.nominal_rate(g), Some(0.25));
    // Each rate's groups start their own clock: time may restart between groups.
    assert_eq!(r.group(Condition::X, Some(0.01)).map(|g| g.len()), Some(3));
}

#[test]
fn static_file() {
    let r = good("static.csv");
    assert_eq!(r.method, Method::Static);
    assert_eq!(r.meta.units.as_deref(), Some("V"));
    assert_eq!(r.groups.len(), 3);
    for g in &r.groups {
        assert!(g.t_s.is_empty());
        assert_eq!(g.rate_hz, None);
        assert_eq!(g.angle_deg, vec![0.0, 0.0, 90.0, 180.0, 270.0]);
        assert_eq!(g.v, vec![0.2; 5]);
    }
}

#[test]
fn static_file_with_time_and_rate_columns() {
    // Method from metadata beats the t_s default; static rows group by condition only and
    // their t_s need not increase.
    let r = parse_ok(
        "# method=static\ncondition,t_s,angle_deg,rate_hz,u,v,w\n\
         x,5,0,0.1,1,2,3\nx,1,90,0.2,1,2,3\ny,0,0,0.1,1,2,3\nz,0,0,0.1,1,2,3\n",
    );
    assert_eq!(r.method, Method::Static);
    assert_eq!(r.groups.len(), 3);
    assert_eq!(r.groups[0].t_s, vec![5.0, 1.0]);
    assert_eq!(r.groups[0].angle_deg, vec![0.0, 90.0]);
}

#[test]
fn metadata_parsing_and_unknown_keys() {
    let r = parse_ok(
        "# rotacal recording v1\n\
         #method=rotation\n\
         #   rate_hz =  0.25  \n\
         # g_loc=9.80101\n\
         # units=counts\n\
         # sample_rate_hz=104\n\
         # noise_sigma=4.17\n\
         # device = Feather nRF52840 Sense (LSM6DS33)\n\
         # operator=J. Doe\n\
         # note.v2=a=b\n\
         # run with g=9.8 and some words\n\
         # a plain comment\n\
         # rate_hz=0.25\n\
         # operator=someone else\n\
         condition,t_s,u,v,w\nx,0,1,2,3\ny,0,1,2,3\nz,0,1,2,3\n",
    );
    let m = &r.meta;
    assert_eq!(m.method, Some(Method::Rotation));
    assert_eq!(m.rate_hz, Some(0.25));
    assert_eq!(m.g_loc, Some(9.80101));
    assert_eq!(m.units.as_deref(), Some("counts"));
    assert_eq!(m.sample_rate_hz, Some(104.0));
    assert_eq!(m.noise_sigma, Some(4.17));
    assert_eq!(
        m.device.as_deref(),
        Some("Feather nRF52840 Sense (LSM6DS33)")
    );
    let other: BTreeMap<String, String> = [("note.v2", "a=b"), ("operator", "someone else")]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    assert_eq!(m.other, other);
    assert_eq!(r.groups[0].first_line, 16);
}

#[test]
fn metadata_method_upper_case_and_empty_text() {
    let r = parse_ok(
        "# method=Static\n# units=\ncondition,angle_deg,u,v,w\nx,0,1,2,3\ny,0,1,2,3\nz,0,1,2,3\n",
    );
    assert_eq!(r.method, Method::Static);
    assert_eq!(r.meta.units.as_deref(), Some(""));
}

#[test]
fn columns_in_odd_order_extra_column_upper_case_conditions() {
    let r = good("odd_order_extra_column.csv");
    assert_eq!(r.method, Method::Rotation);
    assert_eq!(r.groups.len(), 3);
    for g in &r.groups {
        assert_eq!(g.t_s, vec![0.0, 1.0, 2.0]);
        assert_eq!(g.u, vec![0.0, 1.0, 2.0]);
        assert_eq!(g.v, vec![0.0, 2.0, 4.0]);
        assert_eq!(g.w, vec![0.0, 3.0, 6.0]);
        assert_eq!(g.seq, Some(vec![0, 1, 2]));
        assert_eq!(g.temp_c, None);
    }
    assert_eq!(r.groups[2].condition, Condition::Z);
    assert_eq!(r.groups[2].first_line, 8);
}

#[test]
fn crlf_blank_lines_and_spaces() {
    let r = good("crlf_blank_lines.csv");
    assert_eq!(r.meta.rate_hz, Some(0.02));
    assert_eq!(r.groups.len(), 3);
    assert_eq!(r.groups[0].first_line, 7);
    assert_eq!(r.groups[1].first_line, 9);
    for g in &r.groups {
        assert_eq!(g.t_s, vec![0.0, 1.0]);
        assert_eq!(g.w, vec![3.0, 3.0]);
    }
}

#[test]
fn blank_lines_and_comments_inside_the_data() {
    let r = parse_ok(
        "\n\n# rate_hz=0.01\n\ncondition,t_s,u,v,w\n\nx,0,1,2,3\n   \n# paused\nx,1,1,2,3\n\
         \t\ny,0,1,2,3\nz,0,1,2,3\n\n\n",
    );
    assert_eq!(r.meta.rate_hz, Some(0.01));
    assert_eq!(r.groups[0].t_s, vec![0.0, 1.0]);
    assert_eq!(r.groups[0].first_line, 7);
    assert_eq!(r.groups[1].first_line, 12);
    // Metadata after the header is a plain comment.
    let r = parse_ok("condition,t_s,u,v,w\n# rate_hz=5\nx,0,1,2,3\ny,0,1,2,3\nz,0,1,2,3\n");
    assert_eq!(r.meta.rate_hz, None);
}

#[test]
fn groups_need_not_be_contiguous() {
    let r = parse_ok(
        "condition,t_s,u,v,w\nx,0,1,2,3\ny,0,4,5,6\nx,1,7,8,9\nz,0,0,0,0\ny,0.5,1,1,1\nx,1,2,2,2\n",
    );
    let conds: Vec<_> = r.groups.iter().map(|g| g.condition).collect();
    assert_eq!(conds, Condition::ALL);
    assert_eq!(r.groups[0].t_s, vec![0.0, 1.0, 1.0]); // equal times are allowed
    assert_eq!(r.groups[0].u, vec![1.0, 7.0, 2.0]);
    assert_eq!(r.groups[0].first_line, 2);
    assert_eq!(r.groups[1].u, vec![4.0, 1.0]);
    assert_eq!(r.groups[2].first_line, 5);
}

#[test]
fn bom_quotes_and_no_final_newline() {
    let r = parse_ok(
        "\u{feff}# rate_hz=0.5\r\n\"condition\",\"t_s\",u,v,w\r\n\"x\",\"0\",1,2,3\r\ny,0,1,2,3\r\nz,0,1,2,3",
    );
    assert_eq!(r.meta.rate_hz, Some(0.5));
    assert_eq!(r.groups[2].first_line, 5);
    assert_eq!(r.groups[2].w, vec![3.0]);
    // A BOM directly before the header.
    let r = parse_ok("\u{feff}condition,t_s,u,v,w\nx,0,1,2,3\ny,0,1,2,3\nz,0,1,2,3\n");
    assert_eq!(r.rows(), 3);
}

#[test]
fn number_forms() {
    let r = parse_ok(
        "condition,t_s,u,v,w,seq\nx,1e-3,+1.5,-0,1E3,18446744073709551615\nx,2,.5,5.,-1e-300,0\n\
         y,0,1,2,3,1\nz,0,1,2,3,2\n",
    );
    let g = &r.groups[0];
    assert_eq!(g.t_s, vec![1e-3, 2.0]);
    assert_eq!(g.u, vec![1.5, 0.5]);
    assert_eq!(g.v[0].to_bits(), (-0.0f64).to_bits());
    assert_eq!(g.w, vec![1000.0, -1e-300]);
    assert_eq!(g.seq, Some(vec![u64::MAX, 0]));
}

#[test]
fn every_good_file_reads() {
    for path in files_in(&data_dir("good")) {
        let r = recording::read(&path).unwrap_or_else(|e| panic!("{e}"));
        check_invariants(&r);
    }
}

// ---------------------------------------------------------------------------------------
// Malformed files

/// (file in `bad/`, expected line (None: the message names the file only), a substring
/// of the message).
const BAD_CASES: &[(&str, Option<u64>, &str)] = &[
    ("gravity_not_unit.csv", Some(5), "must be a unit vector"),
    ("gravity_missing_gz.csv", Some(3), "missing column 'gz'"),
    (
        "gravity_with_method_rotation.csv",
        Some(4),
        "method rotation, but the file has gx, gy, gz",
    ),
    ("pose_empty.csv", Some(4), "empty pose name"),
    ("bad_metadata_duplicate.csv", Some(4), "rate_hz given twice"),
    (
        "bad_metadata_method.csv",
        Some(2),
        "method: expected 'rotation' or 'static', got 'spin'",
    ),
    (
        "bad_metadata_negative_rate.csv",
        Some(2),
        "rate_hz: -0.01 is not positive",
    ),
    (
        "bad_metadata_number.csv",
        Some(3),
        "g_loc: '9.8o1' is not a number",
    ),
    ("bare_cr.csv", Some(1), "bare carriage return"),
    ("binary_garbage.csv", Some(1), "no header line"),
    (
        "blank_condition_line_spaces.csv",
        Some(9),
        "unknown condition 'w'",
    ),
    (
        "comment_after_header_then_error.csv",
        Some(10),
        "column w: '' is not a number",
    ),
    ("comments_only.csv", None, "empty recording"),
    (
        "default_static_missing_angle_deg.csv",
        Some(1),
        "missing column 'angle_deg'",
    ),
    ("duplicate_column.csv", Some(4), "column 'v' appears twice"),
    ("empty.csv", None, "empty recording"),
    ("empty_condition.csv", Some(8), "unknown condition ''"),
    (
        "fractional_seq.csv",
        Some(5),
        "column seq: '1.5' is not a non-negative integer",
    ),
    ("header_only.csv", None, "no data rows"),
    // What `rotacal record` leaves when the device refused to start (calibrate's
    // streaming engine called it an empty calibration with exit 0 before).
    ("header_only_recorder.csv", None, "no data rows"),
    ("inf_value.csv", Some(5), "column t_s: value is not finite"),
    ("invalid_utf8.csv", Some(8), "unknown condition"),
    ("missing_column_u.csv", Some(4), "missing column 'u'"),
    ("missing_condition_z.csv", None, "condition z missing"),
    (
        "multiline_field_then_error.csv",
        Some(7),
        "column w: 'oops' is not a number",
    ),
    (
        "multirate_missing_x.csv",
        None,
        "condition x missing: no rows for it at rate_hz=0.02",
    ),
    (
        "nan_angle_static.csv",
        Some(4),
        "column angle_deg: value is not finite",
    ),
    ("nan_value.csv", Some(11), "column u: value is not finite"),
    (
        "negative_seq.csv",
        Some(6),
        "column seq: '-3' is not a non-negative integer",
    ),
    (
        "no_final_newline.csv",
        Some(12),
        "column w: 'x' is not a number",
    ),
    ("no_header.csv", Some(2), "no header line"),
    (
        "not_a_number.csv",
        Some(6),
        "column v: 'abc' is not a number",
    ),
    (
        "overflow_value.csv",
        Some(8),
        "column w: value is not finite",
    ),
    ("rotation_missing_t_s.csv", Some(2), "missing column 't_s'"),
    (
        "static_missing_angle_deg.csv",
        Some(4),
        "missing column 'angle_deg'",
    ),
    (
        "time_backwards.csv",
        Some(10),
        "time went backwards in condition y: t_s=1.25 after t_s=1.5",
    ),
    (
        "time_backwards_crlf.csv",
        Some(12),
        "time went backwards in condition z",
    ),
    (
        "time_backwards_noncontiguous.csv",
        Some(9),
        "time went backwards in condition x",
    ),
    ("unknown_condition.csv", Some(7), "unknown condition 'q'"),
    (
        "wrong_case_column.csv",
        Some(4),
        "missing column 'u': found 'U'",
    ),
    (
        "wrong_field_count.csv",
        Some(6),
        "wrong number of fields: 5, but the header has 6",
    ),
    (
        "wrong_field_count_extra.csv",
        Some(8),
        "wrong number of fields: 6, but the header has 5",
    ),
    (
        "zero_rate_column.csv",
        Some(6),
        "column rate_hz: 0 is not positive",
    ),
];

fn files_in(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("directory entry").path())
        .filter(|p| p.extension().is_some_and(|x| x == "csv"))
        .collect();
    v.sort();
    v
}

#[test]
fn every_bad_file_gives_its_error() {
    let dir = data_dir("bad");
    let files = files_in(&dir);
    assert!(files.len() >= 13);
    let mut failures = Vec::new();
    for path in &files {
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("?");
        let Some(&(_, line, needle)) = BAD_CASES.iter().find(|c| c.0 == name) else {
            failures.push(format!("{name}: not in BAD_CASES"));
            continue;
        };
        let outcome = std::panic::catch_unwind(|| recording::read(path));
        let e = match outcome {
            Err(_) => {
                failures.push(format!("{name}: PANICKED"));
                continue;
            }
            Ok(Ok(_)) => {
                failures.push(format!("{name}: read without error"));
                continue;
            }
            Ok(Err(e)) => e,
        };
        let msg = e.to_string();
        let prefix = match line {
            Some(l) => format!("{}:{l}: ", path.display()),
            None => format!("{}: ", path.display()),
        };
        if e.line != line || !msg.starts_with(&prefix) || !msg.contains(needle) {
            failures.push(format!(
                "{name}: got {msg:?} (line {:?}), want prefix {prefix:?}, line {line:?}, \
                 containing {needle:?}",
                e.line
            ));
        }
    }
    for (name, _, _) in BAD_CASES {
        if !dir.join(name).exists() {
            failures.push(format!("{name}: in BAD_CASES but no such file"));
        }
    }
    assert!(failures.is_empty(), "\n{}", failures.join("\n"));
}

#[test]
fn error_kinds() {
    use RecordingErrorKind as K;
    let body = "x,0,1,2,3\ny,0,1,2,3\nz,0,1,2,3\n";
    let e = err(&format!(
        "condition,t_s,u,v,w\nx,0,1,2,3\nx,-1,1,2,3\n{body}"
    ));
    assert!(matches!(
        e.kind,
        K::TimeWentBackwards { condition: Condition::X, rate_hz: None, previous, got }
            if previous == 0.0 && got == -1.0
    ));
    assert_eq!(e.line, Some(3));
    let e = err("condition,rate_hz,t_s,u,v,w\nx,1,0,1,2,3\ny,1,0,1,2,3\nz,2,0,1,2,3\n");
    assert!(matches!(
        e.kind,
        K::MissingCondition { condition: Condition::Z, rate_hz: Some(r) } if r == 1.0
    ));
    assert!(matches!(
        err("condition,t_s,u,w\n").kind,
        K::MissingColumn("v")
    ));
    assert!(matches!(
        err("t_s,u,v,w\n").kind,
        K::MissingColumn("condition")
    ));
    assert!(matches!(
        err("condition,t_s,u,v,w,t_s\n").kind,
        K::DuplicateColumn(ref c) if c == "t_s"
    ));
    // Duplicate unknown columns are harmless.
    assert_eq!(
        parse_ok(&format!(
            "condition,t_s,u,v,w,note,note\n{}",
            body.replace('\n', ",a,b\n")
        ))
        .rows(),
        3
    );
    assert!(matches!(
        err(&format!("condition,t_s,u,v,w\nx,0,1,2\n{body}")).kind,
        K::WrongFieldCount {
            expected: 5,
            got: 4
        }
    ));
    assert!(matches!(
        err(&format!("condition,t_s,u,v,w\nx,0,1,2,-inf\n{body}")).kind,
        K::NotFinite { column: "w" }
    ));
    assert!(matches!(
        err(&format!("condition,t_s,u,v,w\nx,0,1,2, 3 4\n{body}")).kind,
        K::NotANumber { column: "w", ref text } if text == "3 4"
    ));
    assert!(matches!(
        err(&format!("condition,t_s,u,v,w\nxy,0,1,2,3\n{body}")).kind,
        K::UnknownCondition(ref c) if c == "xy"
    ));
    assert!(matches!(err("# g_loc=nan\n").kind, K::BadMetadata(_)));
    assert!(matches!(err("# noise_sigma=-1\n").kind, K::BadMetadata(_)));
    assert!(matches!(err("# sample_rate_hz=\n").kind, K::BadMetadata(_)));
    assert!(matches!(err("").kind, K::Empty));
    assert!(matches!(err("condition,t_s,u,v,w\n\n").kind, K::NoData));
    assert!(matches!(err("a,b,c\n").kind, K::NoHeader));
    // A long bad field is shortened in the message.
    let long = "9".repeat(100) + "z";
    let e = err(&format!("condition,t_s,u,v,w\nx,0,1,2,{long}\n{body}"));
    assert!(e.to_string().len() < 120, "{e}");
}

#[test]
fn nonexistent_file_is_an_io_error_naming_the_path() {
    let path = data_dir("no/such/file.csv");
    let e = recording::read(&path).expect_err("no such file");
    assert!(matches!(e.kind, RecordingErrorKind::Io(_)));
    assert_eq!(e.line, None);
    let msg = e.to_string();
    assert!(
        msg.starts_with(&format!("{}: cannot read", path.display())),
        "{msg}"
    );
    // A directory is not a recording either.
    let e = recording::read(&data_dir("")).expect_err("a directory");
    assert!(matches!(e.kind, RecordingErrorKind::Io(_)));
}

/// A reader that hands out its data in small pieces, then fails.
struct Failing {
    data: Vec<u8>,
    pos: usize,
}

impl Read for Failing {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let rest = &self.data[self.pos..];
        if rest.is_empty() {
            return Err(io::Error::other("device unplugged"));
        }
        let n = rest.len().min(buf.len()).min(7);
        buf[..n].copy_from_slice(&rest[..n]);
        self.pos += n;
        Ok(n)
    }
}

#[test]
fn read_errors_midway_are_io_errors() {
    for text in ["# rate", "condition,t_s,u,v,w\nx,0,1,2,3\n"] {
        let r = Failing {
            data: text.as_bytes().to_vec(),
            pos: 0,
        };
        let e = recording::read_from(r, "ble").expect_err("fails");
        assert!(matches!(e.kind, RecordingErrorKind::Io(_)));
        assert!(e.to_string().contains("device unplugged"), "{e}");
    }
}

// ---------------------------------------------------------------------------------------
// Writer

#[test]
fn writer_output_matches_formats_md() {
    let meta = Metadata {
        method: Some(Method::Rotation),
        rate_hz: Some(0.01),
        g_loc: Some(9.80101),
        units: Some("counts".into()),
        other: [("operator".to_string(), "  J. Doe ".to_string())].into(),
        ..Metadata::default()
    };
    let cols = Columns {
        temp_c: true,
        ..Columns::ROTATION
    };
    let mut w = Writer::new(Vec::new(), &meta, &cols).expect("header");
    for (t, u) in [(0.0, -12.0), (0.0625, -11.0)] {
        let row = Row {
            t_s: Some(t),
            temp_c: Some(24.91),
            ..Row::new(Condition::X, u, 16377.0, -231.0)
        };
        w.write_row(&row).expect("row");
    }
    let text = String::from_utf8(w.into_inner().expect("flush")).expect("utf-8");
    assert_eq!(
        text,
        "# rotacal recording v1\n# method=rotation\n# rate_hz=0.01\n# g_loc=9.80101\n\
         # units=counts\n# operator=J. Doe\ncondition,t_s,u,v,w,temp_c\n\
         x,0.0,-12.0,16377.0,-231.0,24.91\nx,0.0625,-11.0,16377.0,-231.0,24.91\n"
    );
    // All columns, in the writer's order.
    let all = Columns {
        t_s: true,
        angle_deg: true,
        seq: true,
        temp_c: true,
        rate_hz: true,
        ..Columns::default()
    };
    assert_eq!(
        all.names().join(","),
        "condition,rate_hz,seq,t_s,angle_deg,u,v,w,temp_c"
    );
}

#[test]
fn writer_refuses_what_the_reader_would_reject() {
    let meta = Metadata::default();
    let mut w = Writer::new(Vec::new(), &meta, &Columns::ROTATION).expect("header");
    let ok = Row {
        t_s: Some(0.0),
        ..Row::new(Condition::Y, 1.0, 2.0, 3.0)
    };
    w.write_row(&ok).expect("a good row");
    let bad_rows = [
        Row { u: f64::NAN, ..ok },
        Row {
            w: f64::INFINITY,
            ..ok
        },
        Row { t_s: None, ..ok },
        Row {
            temp_c: Some(20.0),
            ..ok
        },
        Row { seq: Some(1), ..ok },
        Row {
            angle_deg: Some(0.0),
            ..ok
        },
        Row {
            rate_hz: Some(1.0),
            ..ok
        },
    ];
    for row in bad_rows {
        let e = w.write_row(&row).expect_err("a bad row");
        assert_eq!(e.kind(), io::ErrorKind::InvalidInput, "{row:?}");
    }
    let rated = Columns {
        rate_hz: true,
        ..Columns::ROTATION
    };
    let mut w2 = Writer::new(Vec::new(), &meta, &rated).expect("header");
    for r in [0.0, -1.0, f64::NAN] {
        assert!(w2
            .write_row(&Row {
                rate_hz: Some(r),
                ..ok
            })
            .is_err());
    }
    // Nothing but the good row was written.
    let text = String::from_utf8(w.into_inner().expect("flush")).expect("utf-8");
    assert_eq!(text.lines().filter(|l| !l.starts_with('#')).count(), 2);

    let inval = |meta: &Metadata, cols: &Columns| {
        Writer::new(Vec::new(), meta, cols).err().map(|e| e.kind())
    };
    let bad = Some(io::ErrorKind::InvalidInput);
    let static_meta = Metadata {
        method: Some(Method::Static),
        ..Metadata::default()
    };
    assert_eq!(inval(&static_meta, &Columns::ROTATION), bad);
    let rot_meta = Metadata {
        method: Some(Method::Rotation),
        ..Metadata::default()
    };
    assert_eq!(inval(&rot_meta, &Columns::STATIC), bad);
    assert_eq!(inval(&meta, &Columns::default()), bad);
    let with = |f: &dyn Fn(&mut Metadata)| {
        let mut m = Metadata::default();
        f(&mut m);
        m
    };
    assert_eq!(
        inval(&with(&|m| m.rate_hz = Some(0.0)), &Columns::ROTATION),
        bad
    );
    assert_eq!(
        inval(&with(&|m| m.g_loc = Some(f64::NAN)), &Columns::ROTATION),
        bad
    );
    assert_eq!(
        inval(&with(&|m| m.noise_sigma = Some(-1.0)), &Columns::ROTATION),
        bad
    );
    assert_eq!(
        inval(
            &with(&|m| m.device = Some("a\nb".into())),
            &Columns::ROTATION
        ),
        bad
    );
    let other = |k: &str| with(&|m| drop(m.other.insert(k.into(), "1".into())));
    assert_eq!(inval(&other("rate_hz"), &Columns::ROTATION), bad);
    assert_eq!(inval(&other("two words"), &Columns::ROTATION), bad);
    assert_eq!(inval(&other(""), &Columns::ROTATION), bad);
    assert_eq!(inval(&other("ok_key-1.x"), &Columns::ROTATION), None);
}

#[test]
fn writer_create_sync_and_read_back() {
    let path = Path::new(env!("CARGO_TARGET_TMPDIR")).join("recording_create_sync.csv");
    let meta = Metadata {
        method: Some(Method::Static),
        g_loc: Some(9.801018),
        units: Some("V".into()),
        ..Metadata::default()
    };
    let mut w = Writer::create(&path, &meta, &Columns::STATIC).expect("create");
    for c in Condition::ALL {
        for a in [0.0, 90.0, 180.0, 270.0] {
            let row = Row {
                angle_deg: Some(a),
                ..Row::new(c, 0.1, 0.2, 0.3)
            };
            w.write_row(&row).expect("row");
        }
    }
    w.sync().expect("sync");
    drop(w);
    let r = recording::read(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(r.method, Method::Static);
    assert_eq!(r.meta, meta);
    assert_eq!(r.rows(), 12);
    assert_eq!(r.groups[1].first_line, 10);
    std::fs::remove_file(&path).ok();
}

#[test]
fn method_names() {
    assert_eq!("rotation".parse::<Method>(), Ok(Method::Rotation));
    assert_eq!(" STATIC ".parse::<Method>(), Ok(Method::Static));
    assert!("spin".parse::<Method>().is_err());
    assert_eq!(Method::Static.to_string(), "static");
    assert_eq!(
        serde_json::to_string(&Method::Rotation).expect("json"),
        "\"rotation\""
    );
}

// ---------------------------------------------------------------------------------------
// Large file: read completely and correctly. Its speed is a benchmark figure (issue 3's
// calibrate benchmark), not asserted here.

#[test]
fn large_file_streams() {
    // 1.1 M rows in release (an hour at 104 Hz, three conditions); fewer in debug.
    let per = if cfg!(debug_assertions) {
        20_000
    } else {
        367_000
    };
    let cols = Columns {
        seq: true,
        temp_c: true,
        ..Columns::ROTATION
    };
    let meta = Metadata {
        rate_hz: Some(0.25),
        ..Metadata::default()
    };
    let mut w = Writer::new(Vec::with_capacity(per * 3 * 80), &meta, &cols).expect("header");
    let mut seq = 0;
    for c in Condition::ALL {
        for i in 0..per {
            let t = i as f64 / 104.0;
            let ph = std::f64::consts::TAU * 0.25 * t;
            let row = Row {
                t_s: Some(t),
                seq: Some(seq),
                temp_c: Some(24.91),
                ..Row::new(
                    c,
                    16000.0 * ph.sin() - 12.0,
                    16000.0 * ph.cos() + 3.0,
                    -231.5,
                )
            };
            w.write_row(&row).expect("row");
            seq += 1;
        }
    }
    let bytes = w.into_inner().expect("flush");
    let start = std::time::Instant::now();
    let r = recording::read_from(&bytes[..], "big.csv").unwrap_or_else(|e| panic!("{e}"));
    let secs = start.elapsed().as_secs_f64();
    assert_eq!(r.rows(), 3 * per);
    assert_eq!(r.groups[2].first_line, 4 + 2 * per as u64);
    eprintln!(
        "read {} rows ({:.1} MB) in {secs:.2} s: {:.2} M rows/s",
        3 * per,
        bytes.len() as f64 / 1e6,
        3.0 * per as f64 / secs / 1e6
    );
}

// ---------------------------------------------------------------------------------------
// Properties

/// What any successful read guarantees.
fn check_invariants(r: &Recording) {
    assert!(!r.groups.is_empty());
    for g in &r.groups {
        let n = g.len();
        assert!(n > 0);
        assert_eq!(g.v.len(), n);
        assert_eq!(g.w.len(), n);
        assert!(g.t_s.is_empty() || g.t_s.len() == n);
        assert!(g.angle_deg.is_empty() || g.angle_deg.len() == n);
        assert!(g.seq.as_ref().is_none_or(|s| s.len() == n));
        assert!(g.temp_c.as_ref().is_none_or(|s| s.len() == n));
        assert!(g.first_line >= 2);
        let all =
            g.u.iter()
                .chain(&g.v)
                .chain(&g.w)
                .chain(&g.t_s)
                .chain(&g.angle_deg);
        assert!(all.clone().all(|x| x.is_finite()));
        if r.method == Method::Rotation {
            assert_eq!(g.t_s.len(), n);
            assert!(g.t_s.windows(2).all(|p| p[0] <= p[1]));
        } else {
            assert_eq!(g.angle_deg.len(), n);
            assert_eq!(g.rate_hz, None);
        }
        for c in Condition::ALL {
            assert!(r.group(c, g.rate_hz).is_some());
        }
    }
}

fn finite() -> impl Strategy<Value = f64> {
    use proptest::num::f64 as F;
    prop_oneof![
        F::POSITIVE | F::NEGATIVE | F::NORMAL | F::SUBNORMAL | F::ZERO,
        -1e5..1e5f64,
        (-100i32..100).prop_map(f64::from),
    ]
}

fn positive() -> impl Strategy<Value = f64> {
    use proptest::num::f64 as F;
    prop_oneof![F::POSITIVE | F::NORMAL | F::SUBNORMAL, 1e-4..10.0f64]
}

fn text() -> impl Strategy<Value = String> {
    "\\PC{0,12}".prop_map(|s| s.trim().to_string())
}

fn metadata(method: Option<Method>) -> impl Strategy<Value = Metadata> {
    let other = prop::collection::btree_map("[a-z][a-z0-9_.-]{0,8}", text(), 0..3).prop_map(
        |mut m: BTreeMap<String, String>| {
            m.retain(|k, _| !recording::KNOWN_KEYS.contains(&k.as_str()));
            m
        },
    );
    (
        prop::option::of(positive()),
        prop::option::of(positive()),
        prop::option::of(text()),
        prop::option::of(positive()),
        prop::option::of(prop_oneof![positive(), Just(0.0)]),
        prop::option::of(text()),
        other,
    )
        .prop_map(
            move |(rate_hz, g_loc, units, sample_rate_hz, noise_sigma, device, other)| Metadata {
                method,
                rate_hz,
                g_loc,
                units,
                sample_rate_hz,
                noise_sigma,
                device,
                other,
            },
        )
}

#[derive(Debug, Clone)]
struct Case {
    meta: Metadata,
    columns: Columns,
    method: Method,
    rows: Vec<Row<'static>>,
}

fn case() -> impl Strategy<Value = Case> {
    (any::<[bool; 5]>(), 0..3u8)
        .prop_flat_map(|([t_s, angle_deg, seq, temp_c, rate_hz], m)| {
            let columns = Columns {
                t_s,
                angle_deg: angle_deg || !t_s,
                seq,
                temp_c,
                rate_hz,
                // Averaged rows' conversions, in some of the cases.
                conv_gaps: seq && temp_c,
                // Missed conversions with them, in some of those.
                conv_missed: seq && temp_c && rate_hz,
                // One boot (the device's clock never restarted), with them.
                boot: seq && temp_c && rate_hz,
                ..Columns::default()
            };
            let method = match m {
                1 if columns.t_s => Some(Method::Rotation),
                2 if columns.angle_deg => Some(Method::Static),
                _ => None,
            };
            let resolved = method.unwrap_or(if t_s {
                Method::Rotation
            } else {
                Method::Static
            });
            let nrates = if rate_hz { 1..4usize } else { 1..2 };
            (
                Just(columns),
                Just(resolved),
                metadata(method),
                prop::collection::vec(positive(), nrates),
                prop::collection::vec((0..3usize, 0..3usize), 0..40),
            )
        })
        .prop_flat_map(|(columns, method, meta, rates, extra)| {
            // One row of every (condition, rate), then more, in random order.
            let mut keys: Vec<(usize, usize)> = (0..rates.len())
                .flat_map(|r| (0..3).map(move |c| (c, r)))
                .collect();
            keys.extend(extra.into_iter().map(|(c, r)| (c, r % rates.len())));
            let n = keys.len();
            let values = (
                finite(),
                finite(),
                finite(),
                finite(),
                finite(),
                any::<u64>(),
                finite(),
            );
            (
                Just((columns, method, meta, rates)),
                Just(keys).prop_shuffle(),
                prop::collection::vec(values, n),
                prop::collection::vec(prop_oneof![Just(0.0), 0.0..10.0f64], n),
            )
        })
        .prop_map(
            |((columns, method, mut meta, rates), keys, values, steps)| {
                if columns.conv_gaps {
                    meta.other.insert("tick_hz".into(), "1000000".into());
                }
                let mut clock: BTreeMap<(usize, usize), f64> = BTreeMap::new();
                let rows = keys
                    .iter()
                    .zip(values)
                    .zip(steps)
                    .map(|(((c, r), (t, a, u, v, w, s, temp)), step)| {
                        let condition = Condition::ALL[*c];
                        let rate = rates[*r];
                        let key = (*c, if columns.rate_hz { *r } else { 0 });
                        let t_s = if method == Method::Rotation {
                            // Non-decreasing within each group; groups start at random times.
                            let now = clock.get(&key).map_or(t.clamp(-1e6, 1e6), |p| p + step);
                            clock.insert(key, now);
                            now
                        } else {
                            t
                        };
                        Row {
                            condition,
                            t_s: columns.t_s.then_some(t_s),
                            angle_deg: columns.angle_deg.then_some(a),
                            u,
                            v,
                            w,
                            seq: columns.seq.then_some(s),
                            temp_c: columns.temp_c.then_some(temp),
                            rate_hz: columns.rate_hz.then_some(rate),
                            gravity: None,
                            pose: None,
                            unc: None,
                            // 0 to 6 gaps of 1 to 65535 ticks, from the seq's bits.
                            conv_gaps: columns.conv_gaps.then(|| {
                                let gaps: Vec<u16> = (0..(s % 7))
                                    .map(|k| 1 + ((s >> (3 + 9 * k)) % 65_535) as u16)
                                    .collect();
                                Aperture::new(Ticks(0), &gaps).expect("at most 6 gaps, none 0")
                            }),
                            // Empty (not counted) or 0 to 7, from the seq's bits.
                            conv_missed: if columns.conv_missed {
                                Some(((s >> 5) % 9) as u8).filter(|m| *m < 8)
                            } else {
                                None
                            },
                            boot: columns.boot.then_some(0),
                        }
                    })
                    .collect();
                Case {
                    meta,
                    columns,
                    method,
                    rows,
                }
            },
        )
}

/// The groups a correct reader must return, worked out independently.
fn expected_groups(case: &Case, header_line: u64) -> Vec<Group> {
    let mut groups: Vec<Group> = Vec::new();
    for (i, row) in case.rows.iter().enumerate() {
        let rate = if case.method == Method::Rotation {
            row.rate_hz
        } else {
            None
        };
        let pos = groups.iter().position(|g| {
            g.condition == row.condition && g.rate_hz.map(f64::to_bits) == rate.map(f64::to_bits)
        });
        let g = match pos {
            Some(p) => &mut groups[p],
            None => {
                groups.push(Group {
                    condition: row.condition,
                    rate_hz: rate,
                    t_s: vec![],
                    angle_deg: vec![],
                    u: vec![],
                    v: vec![],
                    w: vec![],
                    seq: case.columns.seq.then(Vec::new),
                    temp_c: case.columns.temp_c.then(Vec::new),
                    unc: None,
                    conversions: case.columns.conv_gaps.then(Vec::new),
                    missed: case.columns.conv_missed.then(Vec::new),
                    boot: case.columns.boot.then(Vec::new),
                    first_line: header_line + 1 + i as u64,
                });
                groups.last_mut().expect("just pushed")
            }
        };
        g.t_s.extend(row.t_s);
        g.angle_deg.extend(row.angle_deg);
        g.u.push(row.u);
        g.v.push(row.v);
        g.w.push(row.w);
        if let (Some(v), Some(s)) = (g.seq.as_mut(), row.seq) {
            v.push(s);
        }
        if let (Some(v), Some(t)) = (g.temp_c.as_mut(), row.temp_c) {
            v.push(t);
        }
        if let (Some(v), Some(a)) = (g.conversions.as_mut(), row.conv_gaps) {
            v.push(a);
        }
        if let Some(v) = g.missed.as_mut() {
            v.push(row.conv_missed);
        }
        if let (Some(v), Some(b)) = (g.boot.as_mut(), row.boot) {
            v.push(b);
        }
    }
    groups
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// Interesting pieces of recordings, for the structured no-panic property.
const TOKENS: &[&str] = &[
    "x",
    "y",
    "z",
    "X",
    "q",
    ",",
    ",",
    ",",
    "\n",
    "\n",
    "\r\n",
    "\r",
    "#",
    "# method=rotation\n",
    "# method=static\n",
    "# rate_hz=0.01\n",
    "# rate_hz=x\n",
    "condition,t_s,u,v,w\n",
    "condition,angle_deg,u,v,w,seq,temp_c,rate_hz\n",
    "condition",
    "t_s",
    "angle_deg",
    "u",
    "v",
    "w",
    "seq",
    "rate_hz",
    "1.5",
    "0",
    "-0",
    "1e999",
    "nan",
    "inf",
    "-3",
    "\"",
    "\"\"",
    "=",
    " ",
    "\t",
    "\u{feff}",
    "\u{fffd}",
    "x,0,1,2,3\n",
    "y,1,1,2,3\n",
    "z,2,1,2,3\n",
    "x,0.5,0.1,2\n",
];

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn writer_then_reader_round_trips(case in case()) {
        let mut w = Writer::new(Vec::new(), &case.meta, &case.columns).expect("header");
        for row in &case.rows {
            w.write_row(row).expect("row");
        }
        let bytes = w.into_inner().expect("flush");
        let text = String::from_utf8(bytes.clone()).expect("utf-8");
        let header_line = text
            .lines()
            .position(|l| !l.starts_with('#'))
            .expect("a header") as u64
            + 1;
        let r = recording::read_from(&bytes[..], "rt.csv")
            .unwrap_or_else(|e| panic!("{e}\n{text}"));
        prop_assert_eq!(&r.meta, &case.meta);
        prop_assert_eq!(r.method, case.method);
        let want = expected_groups(&case, header_line);
        prop_assert_eq!(&r.groups, &want);
        for (g, e) in r.groups.iter().zip(&want) {
            // PartialEq equates 0.0 and -0.0: compare bits too.
            prop_assert_eq!(bits(&g.t_s), bits(&e.t_s));
            prop_assert_eq!(bits(&g.angle_deg), bits(&e.angle_deg));
            prop_assert_eq!(bits(&g.u), bits(&e.u));
            prop_assert_eq!(bits(&g.v), bits(&e.v));
            prop_assert_eq!(bits(&g.w), bits(&e.w));
            prop_assert_eq!(g.rate_hz.map(f64::to_bits), e.rate_hz.map(f64::to_bits));
        }
        check_invariants(&r);
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..2048)) {
        if let Ok(r) = recording::read_from(&bytes[..], "fuzz.csv") {
            check_invariants(&r);
        }
    }

    #[test]
    fn recording_like_text_never_panics(
        tokens in prop::collection::vec(prop::sample::select(TOKENS), 0..120),
    ) {
        let text: String = tokens.concat();
        match recording::read_from(text.as_bytes(), "fuzz.csv") {
            Ok(r) => check_invariants(&r),
            Err(e) => {
                let msg = e.to_string();
                prop_assert!(msg.starts_with("fuzz.csv"), "{}", msg);
                if let Some(line) = e.line {
                    prop_assert!(line >= 1 && line <= text.matches('\n').count() as u64 + 1);
                }
            }
        }
    }

    #[test]
    fn edited_valid_file_never_panics(
        edits in prop::collection::vec((any::<prop::sample::Index>(), prop::sample::select(TOKENS), 0..3u8), 1..6),
    ) {
        let mut text = String::from(
            "# rotacal recording v1\n# rate_hz=0.01\ncondition,t_s,u,v,w,seq\n\
             x,0,1,2,3,0\nx,1,1,2,3,1\ny,0,1,2,3,2\nz,0,1,2,3,3\n",
        );
        for (at, tok, op) in edits {
            let mut i = at.index(text.len() + 1);
            while !text.is_char_boundary(i) {
                i -= 1;
            }
            match op {
                0 => text.insert_str(i, tok),
                1 => {
                    let mut j = (i + tok.len()).min(text.len());
                    while !text.is_char_boundary(j) {
                        j += 1;
                    }
                    text.replace_range(i..j, tok);
                }
                _ => {
                    let mut j = (i + 1).min(text.len());
                    while !text.is_char_boundary(j) {
                        j += 1;
                    }
                    text.replace_range(i..j, "");
                }
            }
        }
        match recording::read_from(text.as_bytes(), "edit.csv") {
            Ok(r) => check_invariants(&r),
            Err(e) => prop_assert!(e.to_string().starts_with("edit.csv")),
        }
    }
}

/// Files of static poses (gravity directions, pose names, apply's uncertainty columns)
/// read back as written; the writer refuses what the reader would.
#[test]
fn oriented_files_round_trip() {
    let meta = Metadata {
        g_loc: Some(9.81),
        units: Some("m/s^2".into()),
        ..Metadata::default()
    };
    let cols = Columns {
        t_s: true,
        seq: true,
        temp_c: true,
        gravity: true,
        pose: true,
        unc: true,
        ..Columns::default()
    };
    let mut w = Writer::new(Vec::new(), &meta, &cols).expect("header");
    let s = 0.5f64.sqrt();
    let rows: Vec<(&str, [f64; 3])> = vec![
        ("up", [0.0, 0.0, 1.0]),
        ("tilted 45°", [s, 0.0, s]),
        ("slightly long", [0.0, 1.0005, 0.0]),
    ];
    for (i, (name, g)) in rows.iter().enumerate() {
        let mut row = Row::new(Condition::X, 0.1 * i as f64, -9.81, 1e-3);
        row.t_s = Some(i as f64 / 102.4);
        row.seq = Some(i as u64);
        row.temp_c = Some(24.5);
        row.gravity = Some(*g);
        row.pose = Some(name);
        row.unc = Some([1e-4, 2e-4, 3e-4]);
        w.write_row(&row).unwrap();
    }
    let text = String::from_utf8(w.into_inner().unwrap()).unwrap();
    let rec = recording::read_from(text.as_bytes(), "poses.csv").unwrap();
    assert!(rec.groups.is_empty());
    assert_eq!(rec.method, Method::Static);
    let o = rec.oriented.unwrap();
    assert_eq!(o.pose.unwrap(), ["up", "tilted 45°", "slightly long"]);
    assert_eq!(o.gravity[1], [s, 0.0, s]);
    assert_eq!(o.gravity[2], [0.0, 1.0, 0.0]); // written normalised
    assert_eq!(o.seq.unwrap(), [0, 1, 2]);
    assert_eq!(o.temp_c.unwrap(), [24.5; 3]);
    assert_eq!(o.unc.unwrap()[2], [1e-4, 2e-4, 3e-4]);
    assert_eq!(o.t_s.unwrap()[2], 2.0 / 102.4);
    assert_eq!(o.y[2], [0.2, -9.81, 1e-3]);
    // What the reader refuses, the writer refuses.
    let mut w = Writer::new(Vec::new(), &meta, &cols).expect("header");
    let mut row = Row::new(Condition::X, 0.0, 0.0, 9.8);
    row.t_s = Some(0.0);
    row.seq = Some(0);
    row.temp_c = Some(20.0);
    row.unc = Some([0.0; 3]);
    for (name, g) in [("a,b", [0.0, 0.0, 1.0]), ("ok", [0.0, 0.0, 0.5])] {
        row.pose = Some(name);
        row.gravity = Some(g);
        assert!(w.write_row(&row).is_err(), "{name} {g:?}");
    }
    let angle = Columns {
        angle_deg: true,
        gravity: true,
        ..Columns::default()
    };
    assert!(Writer::new(Vec::new(), &meta, &angle).is_err());
    let pose_only = Columns {
        pose: true,
        ..Columns::STATIC
    };
    assert!(Writer::new(Vec::new(), &meta, &pose_only).is_err());
}
