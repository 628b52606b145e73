//! The recording readers (`recording::read`, `read_from`) and the writer: each problem gives
//! its `RecordingErrorKind` and the 1-based physical line (comment and blank lines count),
//! the same from a file (the fast reader first) as from memory (the csv crate's), with LF
//! or CRLF line endings; and what the writer writes reads back bit for bit.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};

use proptest::prelude::*;
use rotacal_engine::recording::{
    self, Columns, Metadata, Method, Recording, RecordingError, RecordingErrorKind as K, Row,
    Writer,
};
use rotacal_shared::Condition;

/// A fresh file name in the temporary folder, unique to this process and call.
fn temp_path() -> PathBuf {
    static N: AtomicUsize = AtomicUsize::new(0);
    let n = N.fetch_add(1, Ordering::Relaxed);
    std::env::temp_dir().join(format!(
        "rotacal-engine-reader-{}-{n}.csv",
        std::process::id()
    ))
}

/// `bytes` read from memory and from a file; the two must agree (but for the source name).
fn read_two_ways(bytes: &[u8]) -> Result<Recording, RecordingError> {
    let path = temp_path();
    std::fs::write(&path, bytes).unwrap();
    let from_file = recording::read(&path);
    std::fs::remove_file(&path).ok();
    let from_memory = recording::read_from(bytes, "mem.csv");
    match (from_memory, from_file) {
        (Ok(m), Ok(mut f)) => {
            assert_eq!(f.source, path.display().to_string());
            f.source = m.source.clone();
            assert_eq!(m, f, "memory and file differ");
            Ok(m)
        }
        (Err(m), Err(f)) => {
            assert_eq!(format!("{:?}", m.kind), format!("{:?}", f.kind));
            assert_eq!(m.line, f.line, "{m} / {f}");
            assert_eq!(f.source_name, path.display().to_string());
            Err(m)
        }
        (m, f) => panic!(
            "memory: {:?}\nfile: {:?}",
            m.map(|r| r.rows()),
            f.map(|r| r.rows())
        ),
    }
}

/// The error `text` gives, read every way: LF and CRLF, from memory and from a file. Its
/// message starts `mem.csv:LINE: `.
fn error(text: &str) -> RecordingError {
    let crlf = text.replace('\n', "\r\n");
    let (e, e2) = match (
        read_two_ways(text.as_bytes()),
        read_two_ways(crlf.as_bytes()),
    ) {
        (Err(e), Err(e2)) => (e, e2),
        (a, b) => panic!(
            "read:\n{text}\n{:?} / {:?}",
            a.map(|r| r.rows()),
            b.map(|r| r.rows())
        ),
    };
    assert_eq!(format!("{:?}", e.kind), format!("{:?}", e2.kind), "CRLF");
    assert_eq!(e.line, e2.line, "CRLF");
    let prefix = match e.line {
        Some(l) => format!("mem.csv:{l}: "),
        None => "mem.csv: ".to_string(),
    };
    assert!(e.to_string().starts_with(&prefix), "{e}");
    e
}

fn ok(text: &str) -> Recording {
    read_two_ways(text.as_bytes()).unwrap_or_else(|e| panic!("{e}\n{text}"))
}

#[test]
fn a_missing_column_is_named_at_the_header_line() {
    let text = "# rotacal recording v1\n# method=rotation\n\n# rate_hz=0.01\n\
                condition,t_s,u,w\nx,0,1,2\ny,0,1,2\nz,0,1,2\n";
    let e = error(text);
    assert!(matches!(e.kind, K::MissingColumn("v")), "{e}");
    assert_eq!(e.line, Some(5));
    // A name differing only in case is named as found.
    let e = error(
        &text
            .replace("t_s,u,w", "t_s,u,V,w")
            .replace(",2\n", ",2,3\n"),
    );
    assert!(
        matches!(e.kind, K::WrongCaseColumn { expected: "v", ref found } if found == "V"),
        "{e}"
    );
    assert_eq!(e.line, Some(5));
    // No condition column and no free method.
    let e = error("# comment\nt_s,u,v,w\n0,1,2,3\n");
    assert!(matches!(e.kind, K::MissingColumn("condition")), "{e}");
    assert_eq!(e.line, Some(2));
}

#[test]
fn a_bad_number_is_named_at_its_line() {
    // Line 4 is blank and line 5 a comment: both count.
    let text = "# rotacal recording v1\ncondition,t_s,u,v,w\nx,0.0,1,2,3\n\n\
                # a comment among the rows\ny,0.0,1,1.2.3,3\nz,0.0,1,2,3\n";
    let e = error(text);
    assert!(
        matches!(e.kind, K::NotANumber { column: "v", ref text } if text == "1.2.3"),
        "{e}"
    );
    assert_eq!(e.line, Some(6));
    for (field, column) in [("nan", "w"), ("1e999", "w")] {
        let e = error(&text.replace("1.2.3,3", &format!("2,{field}")));
        assert!(
            matches!(e.kind, K::NotFinite { column: c } if c == column),
            "{e}"
        );
        assert_eq!(e.line, Some(6));
    }
    let e = error(&text.replace("1.2.3,3", "2"));
    assert!(
        matches!(
            e.kind,
            K::WrongFieldCount {
                expected: 5,
                got: 4
            }
        ),
        "{e}"
    );
    assert_eq!(e.line, Some(6));
    let e = error(&text.replace("y,0.0", "q,0.0"));
    assert!(
        matches!(e.kind, K::UnknownCondition(ref c) if c == "q"),
        "{e}"
    );
    assert_eq!(e.line, Some(6));
    // Without the bad field the same file reads.
    assert_eq!(ok(&text.replace("1.2.3", "2")).rows(), 3);
}

#[test]
fn time_going_backwards_is_named_at_its_line() {
    // Time runs per condition: y at 0 after x at 1 is not backwards, x at 0.5 is.
    let text = "condition,t_s,u,v,w\nx,0.0,1,2,3\ny,0.0,1,2,3\nx,1.0,1,2,3\n\
                z,0.0,1,2,3\ny,0.5,1,2,3\nx,0.5,1,2,3\n";
    let e = error(text);
    assert!(
        matches!(
            e.kind,
            K::TimeWentBackwards { condition: Condition::X, rate_hz: None, previous, got }
                if previous == 1.0 && got == 0.5
        ),
        "{e}"
    );
    assert_eq!(e.line, Some(7));
    // A time repeated is not backwards.
    assert_eq!(ok(&text.replace("x,0.5", "x,1.0")).rows(), 6);
    // Per condition and rate: x at 0.05 Hz may start before x at 0.01 Hz ends.
    let multi = "# method=rotation\ncondition,rate_hz,t_s,u,v,w\nx,0.01,5.0,1,2,3\n\
                 x,0.05,0.0,1,2,3\ny,0.01,0,1,2,3\nz,0.01,0,1,2,3\ny,0.05,0,1,2,3\n\
                 z,0.05,0,1,2,3\nx,0.01,4.0,1,2,3\n";
    let e = error(multi);
    assert!(
        matches!(
            e.kind,
            K::TimeWentBackwards { condition: Condition::X, rate_hz: Some(r), previous, got }
                if r == 0.01 && previous == 5.0 && got == 4.0
        ),
        "{e}"
    );
    assert_eq!(e.line, Some(9));
    // A free recording is one record: any decrease.
    let free = "# method=free\nt_s,u,v,w\n0.0,1,2,3\n0.5,1,2,3\n\n0.25,1,2,3\n";
    let e = error(free);
    assert!(
        matches!(e.kind, K::TimeWentBackwardsFree { previous, got } if previous == 0.5 && got == 0.25),
        "{e}"
    );
    assert_eq!(e.line, Some(6));
}

#[test]
fn whole_file_problems_have_no_line_or_the_header_line() {
    let e = error("condition,t_s,u,v,w\nx,0,1,2,3\ny,0,1,2,3\n");
    assert!(
        matches!(
            e.kind,
            K::MissingCondition {
                condition: Condition::Z,
                rate_hz: None
            }
        ),
        "{e}"
    );
    assert_eq!(e.line, None);
    let e = error("# just a comment\n\n");
    assert!(matches!(e.kind, K::Empty), "{e}");
    let e = error("# method=rotation\ncondition,t_s,u,v,w\n");
    assert!(matches!(e.kind, K::NoData), "{e}");
    let e = error("gx,gy,gz,u,v,w\n1,1,0,1,2,3\n");
    assert!(matches!(e.kind, K::NotUnitVector { norm } if (norm - 2f64.sqrt()).abs() < 1e-12));
    assert_eq!(e.line, Some(2));
}

/// Numbers whose decimal form is easy to get wrong.
const AWKWARD: [f64; 12] = [
    0.1,
    -0.0,
    5e-324,
    -2.2250738585072014e-308,
    f64::MAX,
    f64::MIN,
    1e21,
    1e-7,
    123_456_789_012_345_680.0,
    0.300_000_000_000_000_04,
    1.0 / 3.0,
    -9_007_199_254_740_991.0,
];

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn awkward_numbers_round_trip_bit_for_bit() {
    let meta = Metadata {
        method: Some(Method::Static),
        g_loc: Some(9.801018),
        units: Some("V".into()),
        noise_sigma: Some(1e-4),
        ..Metadata::default()
    };
    let mut w = Writer::new(Vec::new(), &meta, &Columns::STATIC).unwrap();
    for (i, x) in AWKWARD.iter().enumerate() {
        for c in Condition::ALL {
            let row = Row {
                angle_deg: Some(*x),
                ..Row::new(c, *x, -x, AWKWARD[(i + 1) % AWKWARD.len()])
            };
            w.write_row(&row).unwrap();
        }
    }
    let r = read_two_ways(&w.into_inner().unwrap()).unwrap();
    assert_eq!(r.meta, meta);
    for g in &r.groups {
        assert_eq!(bits(&g.u), bits(&AWKWARD));
        assert_eq!(bits(&g.angle_deg), bits(&AWKWARD));
        assert_eq!(bits(&g.v), bits(&AWKWARD.map(|x| -x)));
    }
}

/// The shapes of file the writer makes.
#[derive(Clone, Copy, Debug)]
enum Shape {
    /// Conditions and times, one rate or several (`rate_hz` column).
    Rotation { rates: usize },
    /// Conditions and table angles.
    Static,
    /// Gravity directions and pose names.
    Oriented,
    /// One record of times, no conditions.
    Free,
}

/// One row's draws: condition and rate index, time step, the channels, a second number
/// (start time, angle or temperature) and `seq`.
type Draw = (usize, usize, f64, [f64; 3], f64, u64);

fn finite() -> impl Strategy<Value = f64> {
    use proptest::num::f64 as F;
    prop_oneof![
        F::POSITIVE | F::NEGATIVE | F::NORMAL | F::SUBNORMAL | F::ZERO,
        -1e5..1e5f64,
        (-1000i32..1000).prop_map(f64::from),
    ]
}

fn draws() -> impl Strategy<Value = Vec<Draw>> {
    let step = prop_oneof![Just(0.0), 0.0..10.0f64];
    prop::collection::vec(
        (
            0..3usize,
            0..3usize,
            step,
            [finite(), finite(), finite()],
            finite(),
            any::<u64>(),
        ),
        0..40,
    )
}

fn shape() -> impl Strategy<Value = Shape> {
    prop_oneof![
        (1..4usize).prop_map(|rates| Shape::Rotation { rates }),
        Just(Shape::Static),
        Just(Shape::Oriented),
        Just(Shape::Free),
    ]
}

const AXES: [[f64; 3]; 6] = [
    [1.0, 0.0, 0.0],
    [-1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, -1.0, 0.0],
    [0.0, 0.0, 1.0],
    [0.0, 0.0, -1.0],
];
const POSES: [&str; 6] = ["+x", "-x", "+y", "-y", "+z", "-z"];
const RATES: [f64; 3] = [0.01, 0.05, 0.5];

/// The file's columns and metadata, and its rows: every condition (at every rate) first,
/// then the draws, times non-decreasing per group (per file when free).
fn build(shape: Shape, extra: bool, draws: &[Draw]) -> (Metadata, Columns, Vec<Row<'static>>) {
    let mut meta = Metadata {
        g_loc: Some(9.80101),
        units: Some("counts".into()),
        sample_rate_hz: Some(16.0),
        device: Some("bench, unit 3".into()),
        other: BTreeMap::from([("operator".to_string(), "A. N. Other".to_string())]),
        ..Metadata::default()
    };
    let mut columns = Columns {
        seq: extra,
        temp_c: extra,
        ..Columns::default()
    };
    let rates = match shape {
        Shape::Rotation { rates } => {
            columns.t_s = true;
            columns.rate_hz = rates > 1;
            meta.method = Some(Method::Rotation);
            if rates == 1 {
                meta.rate_hz = Some(0.01);
            }
            rates
        }
        Shape::Static => {
            columns.angle_deg = true;
            1
        }
        Shape::Oriented => {
            columns.gravity = true;
            columns.pose = true;
            1
        }
        Shape::Free => {
            columns.t_s = true;
            meta.method = Some(Method::Free);
            1
        }
    };
    let first: Vec<Draw> = (0..rates)
        .flat_map(|r| (0..3).map(move |c| (c, r, 0.0, [1.0, 2.0, 3.0], 0.0, 0)))
        .collect();
    let mut clock: BTreeMap<(usize, usize), f64> = BTreeMap::new();
    let rows = first
        .iter()
        .chain(draws)
        .map(|&(c, r, step, [u, v, w], x, seq)| {
            let r = r % rates;
            let group = if matches!(shape, Shape::Free) {
                (0, 0)
            } else {
                (c, r)
            };
            let t = clock.get(&group).map_or(x.clamp(-1e6, 1e6), |p| p + step);
            clock.insert(group, t);
            let pose = 2 * c + usize::from(seq % 2 == 1);
            Row {
                condition: Condition::ALL[c],
                t_s: columns.t_s.then_some(t),
                angle_deg: columns.angle_deg.then_some(x),
                rate_hz: columns.rate_hz.then_some(RATES[r]),
                gravity: columns.gravity.then_some(AXES[pose]),
                pose: columns.pose.then_some(POSES[pose]),
                seq: columns.seq.then_some(seq),
                temp_c: columns.temp_c.then_some(x),
                ..Row::new(Condition::ALL[c], u, v, w)
            }
        })
        .collect();
    (meta, columns, rows)
}

/// The rows of an oriented or free recording as read, in file order, as bits: a 0, the
/// time or gravity direction, u, v, w, then seq, temp_c and the pose where the file has
/// them.
fn read_rows(r: &Recording) -> Vec<Vec<u64>> {
    let mut out = Vec::new();
    if let Some(o) = &r.oriented {
        for i in 0..o.y.len() {
            let mut row = vec![0];
            row.extend(o.gravity[i].map(f64::to_bits));
            row.extend(o.y[i].map(f64::to_bits));
            row.extend(o.seq.as_ref().map(|s| s[i]));
            row.extend(o.temp_c.as_ref().map(|t| t[i].to_bits()));
            row.push(
                POSES
                    .iter()
                    .position(|p| *p == o.pose.as_ref().unwrap()[i])
                    .unwrap() as u64,
            );
            out.push((o.line[i], row));
        }
    } else if let Some(s) = &r.series {
        for i in 0..s.y.len() {
            let mut row = vec![0, s.t_s[i].to_bits()];
            row.extend(s.y[i].map(f64::to_bits));
            row.extend(s.seq.as_ref().map(|q| q[i]));
            row.extend(s.temp_c.as_ref().map(|t| t[i].to_bits()));
            out.push((s.line[i], row));
        }
    } else {
        panic!("not an oriented or free recording");
    }
    out.sort_by_key(|(line, _)| *line);
    out.into_iter().map(|(_, row)| row).collect()
}

/// The same for the rows as written.
fn written_rows(shape: Shape, rows: &[Row<'_>]) -> Vec<Vec<u64>> {
    rows.iter()
        .map(|row| {
            let mut out = vec![0];
            match shape {
                Shape::Oriented => out.extend(row.gravity.unwrap().map(f64::to_bits)),
                _ => out.push(row.t_s.unwrap().to_bits()),
            }
            out.extend([row.u, row.v, row.w].map(f64::to_bits));
            out.extend(row.seq);
            out.extend(row.temp_c.map(f64::to_bits));
            if let Some(p) = row.pose {
                out.push(POSES.iter().position(|q| *q == p).unwrap() as u64);
            }
            out
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1024, ..ProptestConfig::default() })]

    /// What the writer writes reads back exactly, from memory and from a file: the
    /// metadata, the method, every number bit for bit, each row at its line.
    #[test]
    fn writer_then_reader_round_trips(shape in shape(), extra in any::<bool>(), draws in draws()) {
        let (meta, columns, rows) = build(shape, extra, &draws);
        let mut w = Writer::new(Vec::new(), &meta, &columns).unwrap();
        for row in &rows {
            w.write_row(row).unwrap();
        }
        let bytes = w.into_inner().unwrap();
        let text = String::from_utf8(bytes.clone()).unwrap();
        let header = text.lines().position(|l| !l.starts_with('#')).unwrap() as u64 + 1;
        let r = read_two_ways(&bytes).unwrap_or_else(|e| panic!("{e}\n{text}"));
        prop_assert_eq!(&r.meta, &meta);
        prop_assert_eq!(r.rows(), rows.len());
        match shape {
            Shape::Oriented | Shape::Free => {
                prop_assert_eq!(r.method, if matches!(shape, Shape::Free) {
                    Method::Free
                } else {
                    Method::Static
                });
                prop_assert!(r.groups.is_empty());
                prop_assert_eq!(read_rows(&r), written_rows(shape, &rows));
                let lines = match (&r.oriented, &r.series) {
                    (Some(o), _) => o.line.clone(),
                    (_, Some(s)) => s.line.clone(),
                    _ => unreachable!(),
                };
                let want: Vec<u64> = (0..rows.len() as u64).map(|i| header + 1 + i).collect();
                prop_assert_eq!(lines, want);
            }
            Shape::Rotation { .. } | Shape::Static => {
                let rotation = matches!(shape, Shape::Rotation { .. });
                prop_assert_eq!(r.method, if rotation { Method::Rotation } else { Method::Static });
                // Each row goes to its (condition, rate) group, in file order.
                for (g, group) in r.groups.iter().enumerate() {
                    let mine: Vec<(usize, &Row<'_>)> = rows
                        .iter()
                        .enumerate()
                        .filter(|(_, row)| {
                            row.condition == group.condition
                                && (!rotation || row.rate_hz == group.rate_hz)
                        })
                        .collect();
                    prop_assert_eq!(group.first_line, header + 1 + mine[0].0 as u64, "group {}", g);
                    let col = |f: fn(&Row<'_>) -> Option<f64>| -> Vec<u64> {
                        mine.iter().filter_map(|(_, row)| f(row)).map(f64::to_bits).collect()
                    };
                    prop_assert_eq!(bits(&group.t_s), col(|r| r.t_s));
                    prop_assert_eq!(bits(&group.angle_deg), col(|r| r.angle_deg));
                    prop_assert_eq!(bits(&group.u), col(|r| Some(r.u)));
                    prop_assert_eq!(bits(&group.v), col(|r| Some(r.v)));
                    prop_assert_eq!(bits(&group.w), col(|r| Some(r.w)));
                    prop_assert_eq!(
                        group.temp_c.as_deref().map(bits),
                        extra.then(|| col(|r| r.temp_c))
                    );
                    prop_assert_eq!(
                        group.seq.clone(),
                        extra.then(|| mine.iter().filter_map(|(_, r)| r.seq).collect::<Vec<u64>>())
                    );
                }
                let groups = match shape {
                    Shape::Rotation { rates } => 3 * rates,
                    _ => 3,
                };
                prop_assert_eq!(r.groups.len(), groups);
            }
        }
    }
}
