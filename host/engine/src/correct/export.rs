//! `rotacal export CAL.json --format c|rust|json`: the correction as constants to embed,
//! for example in the firmware.
//!
//! Each form carries the convention (`a = M·(y − O)`), the frame, the units and the
//! standard uncertainties as comments or keys. Values are written with 17 significant
//! digits; as `f32` (the default, for the Cortex-M4F's FPU) they are rounded to about
//! 6e-8 relative, far below any calibration uncertainty seen here (≥ 1e-6).

use crate::calibrate::correction::Correction;
use crate::calibrate::json::CorrectionJson;
use std::fmt::Write as _;

/// Output language.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// A C header.
    C,
    /// A Rust module.
    Rust,
    /// JSON.
    Json,
}

/// Floating-point type of the constants (C and Rust).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Precision {
    /// `float` / `f32`.
    F32,
    /// `double` / `f64`.
    F64,
}

/// Text made safe inside a C block comment and a Rust line comment.
fn clean(s: &str) -> String {
    s.replace(['\n', '\r'], " ").replace("*/", "* /")
}

fn lit(x: f64) -> String {
    format!("{x:.16e}")
}

fn header_lines(json: &CorrectionJson, c: &Correction, source: &str) -> Vec<String> {
    let mut l = vec![
        format!("rotacal calibration constants, from {source}"),
        format!("frame: {}", c.frame.as_str()),
        format!("units: y in {}, a in {}", json.units_in, json.units_out),
    ];
    let mut conv = String::new();
    for word in json.convention.split_whitespace() {
        if conv.len() + word.len() > 90 {
            l.push(std::mem::take(&mut conv));
        }
        if !conv.is_empty() {
            conv.push(' ');
        }
        conv.push_str(word);
    }
    if !conv.is_empty() {
        l.push(conv);
    }
    l.push(format!(
        "standard uncertainties: offset {:?}; matrix {:?}",
        c.offset_std_unc, c.matrix_std_unc
    ));
    l
}

/// The constants in `format`, with `trace` (lines for the header comment, and the same as
/// JSON for the JSON format: the traceability block).
pub fn render(
    json: &CorrectionJson,
    c: &Correction,
    source: &str,
    format: Format,
    precision: Precision,
    trace: (&[String], Option<serde_json::Value>),
) -> String {
    let mut o = String::new();
    let head: Vec<String> = header_lines(json, c, source)
        .iter()
        .chain(trace.0)
        .map(|l| clean(l))
        .collect();
    let units_in = clean(&json.units_in);
    match format {
        Format::Json => {
            let v = serde_json::json!({
                "source": source,
                "convention": json.convention,
                "units_in": json.units_in,
                "units_out": json.units_out,
                "frame": c.frame,
                "offset": c.offset,
                "offset_std_unc": c.offset_std_unc,
                "matrix": c.matrix,
                "matrix_std_unc": c.matrix_std_unc,
                "traceability": trace.1,
            });
            o = serde_json::to_string_pretty(&v).unwrap_or_default();
            o.push('\n');
        }
        Format::C => {
            let ty = match precision {
                Precision::F32 => "float",
                Precision::F64 => "double",
            };
            let suffix = if precision == Precision::F32 { "f" } else { "" };
            o.push_str("/*\n");
            for l in &head {
                let _ = writeln!(o, " * {l}");
            }
            o.push_str(" */\n#ifndef ROTACAL_CALIBRATION_H\n#define ROTACAL_CALIBRATION_H\n\n");
            let _ = writeln!(o, "/* O, in {} */", units_in);
            let _ = writeln!(
                o,
                "static const {ty} ROTACAL_OFFSET[3] = {{{}}};",
                c.offset.map(|x| format!("{}{suffix}", lit(x))).join(", ")
            );
            let _ = writeln!(
                o,
                "/* M, m/s^2 per {}; a[i] = sum_k M[i][k] * (y[k] - O[k]) */",
                units_in
            );
            let _ = writeln!(o, "static const {ty} ROTACAL_MATRIX[3][3] = {{");
            for row in &c.matrix {
                let _ = writeln!(
                    o,
                    "    {{{}}},",
                    row.map(|x| format!("{}{suffix}", lit(x))).join(", ")
                );
            }
            o.push_str("};\n\n");
            let _ = writeln!(
                o,
                "static inline void rotacal_correct(const {ty} y[3], {ty} a[3])\n{{\n    \
                 {ty} d[3];\n    for (int k = 0; k < 3; k++) d[k] = y[k] - ROTACAL_OFFSET[k];\n    \
                 for (int i = 0; i < 3; i++)\n        \
                 a[i] = ROTACAL_MATRIX[i][0] * d[0] + ROTACAL_MATRIX[i][1] * d[1] + ROTACAL_MATRIX[i][2] * d[2];\n}}"
            );
            o.push_str("\n#endif /* ROTACAL_CALIBRATION_H */\n");
        }
        Format::Rust => {
            let ty = match precision {
                Precision::F32 => "f32",
                Precision::F64 => "f64",
            };
            for l in &head {
                let _ = writeln!(o, "//! {l}");
            }
            o.push('\n');
            let _ = writeln!(o, "/// O, in {}.", units_in);
            let _ = writeln!(
                o,
                "pub const OFFSET: [{ty}; 3] = [{}];",
                c.offset.map(lit).join(", ")
            );
            let _ = writeln!(
                o,
                "/// M, m/s² per {}: `a[i] = Σ_k M[i][k]·(y[k] − O[k])`.",
                units_in
            );
            let _ = writeln!(o, "pub const MATRIX: [[{ty}; 3]; 3] = [");
            for row in &c.matrix {
                let _ = writeln!(o, "    [{}],", row.map(lit).join(", "));
            }
            o.push_str("];\n\n");
            let _ = writeln!(
                o,
                "/// The corrected acceleration, m/s², in the {} frame.\n\
                 pub fn correct(y: [{ty}; 3]) -> [{ty}; 3] {{\n    \
                 let d = [y[0] - OFFSET[0], y[1] - OFFSET[1], y[2] - OFFSET[2]];\n    \
                 let row = |m: [{ty}; 3]| m[0] * d[0] + m[1] * d[1] + m[2] * d[2];\n    \
                 [row(MATRIX[0]), row(MATRIX[1]), row(MATRIX[2])]\n}}",
                c.frame.as_str()
            );
        }
    }
    o
}
