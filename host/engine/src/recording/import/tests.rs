//! The import's errors name the place: the input, the 1-based line (skipped, blank and
//! comment lines counted), the field and its text; and render as they always have.

use super::*;
use crate::recording::Metadata;
use std::io::BufRead;

/// A spec for `map`, with `conditions` (letters) and `skip` header lines.
fn spec(map: &str, conditions: &str, skip: usize) -> ImportSpec {
    ImportSpec {
        columns: map.parse().unwrap(),
        conditions: conditions
            .chars()
            .map(|c| Condition::from_letter(c).unwrap())
            .collect(),
        skip,
        time_scale: 1.0,
        scale: 1.0,
        meta: Metadata::default(),
        poses: None,
    }
}

/// Import `inputs` (name, text) by `spec`: the error.
fn fails(inputs: &[(&str, &str)], spec: &ImportSpec) -> ImportError {
    let readers: Vec<Input<'_>> = inputs
        .iter()
        .map(|(name, text)| {
            let r: Box<dyn BufRead> = Box::new(text.as_bytes());
            Input::text(*name, r)
        })
        .collect();
    import(readers, spec, Vec::new()).unwrap_err()
}

#[test]
fn a_bad_field_names_its_line_field_and_text() {
    // Line 1 skipped (a header), 3 blank, 4 a comment: the bad field is on line 6.
    let text = "time u v w\n0 1 2 3\n\n# note\n1 1 2 3\n2 1 x 3\n";
    let e = fails(&[("a.txt", text)], &spec("t=0,u=1,v=2,w=3", "x", 1));
    assert_eq!(e.source_name, "a.txt");
    assert_eq!(e.line, Some(6));
    assert!(
        matches!(&e.kind, K::NotFinite { field: 2, column: "v", text } if text == "x"),
        "{e:?}"
    );
    assert_eq!(
        e.to_string(),
        "a.txt:6: v (field 2) 'x' is not a finite number"
    );
}

#[test]
fn a_short_line_names_the_missing_field() {
    let e = fails(
        &[("b.txt", "0;1;2;3\n1;1;2\n")],
        &spec("t=0,u=1,v=2,w=3", "y", 0),
    );
    assert_eq!(e.line, Some(2));
    assert!(matches!(
        e.kind,
        K::NoField {
            field: 3,
            column: "w",
            fields: 3
        }
    ));
    assert_eq!(
        e.to_string(),
        "b.txt:2: no field 3 for w: the line has 3 fields"
    );
}

#[test]
fn the_second_input_is_named_with_its_own_line() {
    let e = fails(
        &[
            ("x.txt", "0 1 2 3\n"),
            ("y.txt", "0 1 2 3\n1 1 2 3\n0.5 1 2 3\n"),
        ],
        &spec("t=0,u=1,v=2,w=3", "xy", 0),
    );
    assert_eq!((e.source_name.as_str(), e.line), ("y.txt", Some(3)));
    assert!(matches!(
        e.kind,
        K::TimeWentBackwards {
            condition: Some(Condition::Y),
            ..
        }
    ));
    assert_eq!(
        e.to_string(),
        "y.txt:3: time went backwards in condition y: 0.5 s after 1 s"
    );
}

#[test]
fn condition_and_seq_fields_name_their_field() {
    let map = "t=0,u=1,v=2,w=3,condition=4,seq=5";
    let e = fails(
        &[("c.txt", "0,1,2,3,x,0\n1,1,2,3,q,1\n")],
        &spec(map, "", 0),
    );
    assert_eq!(e.line, Some(2));
    assert!(matches!(&e.kind, K::BadCondition { field: 4, text } if text == "q"));
    assert_eq!(e.to_string(), "c.txt:2: condition 'q': expected x, y or z");
    let e = fails(&[("c.txt", "0,1,2,3,x,-1\n")], &spec(map, "", 0));
    assert_eq!(e.line, Some(1));
    assert!(matches!(&e.kind, K::NotWhole { field: 5, text } if text == "-1"));
    assert_eq!(
        e.to_string(),
        "c.txt:1: seq (field 5) '-1' is not a whole number"
    );
}

#[test]
fn a_row_the_writer_refuses_names_its_line() {
    let mut s = spec("t=0,u=1,v=2,w=3", "x", 0);
    s.time_scale = 1e300;
    let e = fails(&[("d.txt", "0 1 2 3\n1e10 1 2 3\n")], &s);
    assert_eq!(e.line, Some(2));
    assert!(matches!(e.kind, K::Write(_)));
    assert_eq!(e.to_string(), "d.txt:2: t_s=inf is not finite");
}

#[test]
fn whole_input_problems_have_no_line() {
    let e = fails(
        &[("e.txt", "# nothing\n\n")],
        &spec("t=0,u=1,v=2,w=3", "x", 0),
    );
    assert_eq!(
        (e.line, e.to_string().as_str()),
        (None, "e.txt: no data lines")
    );
    let e = fails(
        &[("e.txt", "0 1 2 3\n"), ("f.txt", "0 1 2 3\n")],
        &spec("t=0,u=1,v=2,w=3", "x", 0),
    );
    assert_eq!(e.line, None);
    assert_eq!(
        e.kind.to_string(),
        SpecError::Conditions {
            inputs: 2,
            conditions: 1
        }
        .to_string()
    );
    assert_eq!(
        e.to_string(),
        "import: 2 input(s) but 1 condition(s): give one --condition per input, or a \
         condition column"
    );
}

#[test]
fn a_section_past_the_end_names_the_section() {
    let mut s = spec("t=0,u=1,v=2,w=3", "", 0);
    s.poses = Some(PoseSections {
        sections: vec![("a".into(), 0, 1), ("b".into(), 1, 5)],
        map: PoseSections::map_from_str("a=+x").unwrap(),
    });
    let e = fails(&[("g.txt", "0 1 2 3\n1 1 2 3\n")], &s);
    assert_eq!(e.line, None);
    assert!(matches!(&e.kind, K::SectionPastEnd { section, end: 5, rows: 2 } if section == "b"));
    assert_eq!(
        e.to_string(),
        "g.txt: section 'b' ends at data row 5 (exclusive), but the input has only 2 data rows"
    );
}

#[test]
fn section_lists_name_the_section_and_the_json_line() {
    let e =
        PoseSections::sections_from_json("{\n  \"a\": {\"start\": 0,\n  \"end\": }\n}", "s.json")
            .unwrap_err();
    assert_eq!(e.line, Some(3));
    assert!(matches!(e.kind, K::NotJson(_)));
    assert!(
        e.to_string()
            .starts_with("s.json:3: not a JSON section list: expected value at line 3"),
        "{e}"
    );
    let cases = [
        (
            "[1]",
            "s.json: expected an object of sections: {\"name\": {\"start\": N, \"end\": M}, ...}",
        ),
        ("{\"a\": {\"end\": 2}}", "s.json: section 'a': no 'start'"),
        (
            "{\"a\": {\"start\": 0, \"end\": -2}}",
            "s.json: section 'a': 'end' -2 is not a row index (a whole number ≥ 0)",
        ),
        (
            "{\"a\": {\"start\": 3, \"end\": 3}}",
            "s.json: section 'a': end 3 is not after start 3",
        ),
        ("{}", "s.json: no sections"),
        (
            "{\"b\": {\"start\": 0, \"end\": 4}, \"a\": {\"start\": 3, \"end\": 6}}",
            "s.json: sections 'b' and 'a' overlap",
        ),
    ];
    for (json, want) in cases {
        let e = PoseSections::sections_from_json(json, "s.json").unwrap_err();
        assert_eq!((e.line, e.to_string().as_str()), (None, want), "{json}");
    }
    let e = PoseSections::sections_from_json("{\"a\": {\"start\": 0, \"end\": 1.5}}", "s.json")
        .unwrap_err();
    assert!(
        matches!(&e.kind, K::NotRowIndex { section, key: "end", text } if section == "a" && text == "1.5")
    );
}

#[test]
fn column_maps_name_the_part() {
    let cases = [
        (
            " t0 ,u=1",
            ColumnMapError::NoIndex { part: "t0".into() },
            "'t0': expected NAME=FIELD (the field's number from 0, or its header name)",
        ),
        (
            "t=-1,u=1",
            ColumnMapError::BadIndex {
                part: "t=-1".into(),
            },
            "'t=-1': the index must be a whole number (0-based)",
        ),
        (
            "t=0,x=1",
            ColumnMapError::UnknownColumn { name: "x".into() },
            "unknown column 'x' (known: t, u, v, w, condition, angle, temp, seq)",
        ),
        (
            "t=0, u =1,u=2",
            ColumnMapError::Twice { name: "u".into() },
            "'u' given twice",
        ),
        (
            "t=0,u=1,v=2",
            ColumnMapError::NoChannels,
            "u, v and w are all required",
        ),
        (
            "u=1,v=2,w=3",
            ColumnMapError::NoTimeOrAngle,
            "give t (rotation) or angle (static)",
        ),
    ];
    for (map, kind, want) in cases {
        let e = map.parse::<ColumnMap>().unwrap_err();
        assert_eq!((&e, e.to_string().as_str()), (&kind, want), "{map}");
    }
}

#[test]
fn pose_maps_name_the_part() {
    let cases = [
        (
            "x_p",
            PoseMapError::NoDirection { part: "x_p".into() },
            "'x_p': expected NAME=DIRECTION, e.g. x_p=+x",
        ),
        (
            "x_p=+x, y_p = up",
            PoseMapError::BadDirection {
                part: "y_p = up".into(),
            },
            "'y_p = up': the direction must be ±x, ±y, ±z or gx:gy:gz",
        ),
        (
            "x_p=1:0",
            PoseMapError::NotThree {
                part: "x_p=1:0".into(),
            },
            "'x_p=1:0': a vector direction has three components gx:gy:gz",
        ),
        (
            "x_p=0:0:2",
            PoseMapError::NotUnit {
                part: "x_p=0:0:2".into(),
                norm: 2.0,
            },
            "'x_p=0:0:2': the direction must be a unit vector (length 2)",
        ),
        (
            "a=+x,a=-x",
            PoseMapError::Twice { name: "a".into() },
            "pose 'a' given twice",
        ),
        (" , ", PoseMapError::Empty, "the pose map is empty"),
    ];
    for (map, kind, want) in cases {
        let e = PoseSections::map_from_str(map).unwrap_err();
        assert_eq!((&e, e.to_string().as_str()), (&kind, want), "{map}");
    }
}
