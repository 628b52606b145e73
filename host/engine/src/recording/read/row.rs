//! One row's fields into a [`Row`], with every check formats.md makes of a field.

use rotacal_shared::{Aperture, Condition, Ticks, MAX_CONVERSIONS};

use super::head::ColumnIndex;
use super::number::parse_number;
use super::Parse;
use crate::recording::{pose_name_ok, snippet, RecordingErrorKind, Row, UNIT_TOLERANCE};

/// A record's fields, from the csv reader or from the fast line reader (text), or a row
/// of columns held in memory ([`super::columns`]: numbers where the columns hold them).
pub(super) trait Fields {
    /// Field `i`, untrimmed (`None` past the last, or where the field is a number).
    fn raw(&self, i: usize) -> Option<&[u8]>;
    /// Field `i` as the number its column holds, if it holds numbers rather than text.
    fn number(&self, _i: usize) -> Option<f64> {
        None
    }
}

/// An integer field: the column's number when it is a whole number, else the text parsed.
fn integer<F: Fields + ?Sized, T: std::str::FromStr + TryFrom<u64>>(
    rec: &F,
    i: usize,
) -> Result<T, Vec<u8>> {
    if let Some(x) = rec.number(i) {
        let whole = x.is_finite() && x >= 0.0 && x.fract() == 0.0 && x < u64::MAX as f64;
        return whole
            .then(|| T::try_from(x as u64).ok())
            .flatten()
            .ok_or_else(|| format!("{x}").into_bytes());
    }
    let f = field(rec, i);
    std::str::from_utf8(f)
        .ok()
        .and_then(|s| s.parse::<T>().ok())
        .ok_or_else(|| f.to_vec())
}

impl Fields for csv::ByteRecord {
    fn raw(&self, i: usize) -> Option<&[u8]> {
        self.get(i)
    }
}

fn field<F: Fields + ?Sized>(rec: &F, i: usize) -> &[u8] {
    rec.raw(i).unwrap_or(b"").trim_ascii()
}

fn parse_f64<F: Fields + ?Sized>(
    rec: &F,
    i: usize,
    column: &'static str,
) -> Result<f64, RecordingErrorKind> {
    let x = match rec.number(i) {
        Some(x) => x,
        None => {
            let f = field(rec, i);
            parse_number(f).ok_or_else(|| RecordingErrorKind::NotANumber {
                column,
                text: snippet(f),
            })?
        }
    };
    if x.is_finite() {
        Ok(x)
    } else {
        Err(RecordingErrorKind::NotFinite { column })
    }
}

fn parse_opt<F: Fields + ?Sized>(
    rec: &F,
    i: Option<usize>,
    column: &'static str,
) -> Result<Option<f64>, RecordingErrorKind> {
    i.map(|i| parse_f64(rec, i, column)).transpose()
}

pub(super) fn parse_row<'r, F: Fields + ?Sized>(
    rec: &'r F,
    cols: &ColumnIndex,
    columns: Parse,
) -> Result<Row<'r>, RecordingErrorKind> {
    let all = columns == Parse::All;
    // Files with gravity directions need no condition; one that is there is ignored.
    let condition = match (cols.condition, cols.gravity) {
        (Some(i), None) => {
            let c = field(rec, i);
            match c {
                [b] => Condition::from_letter(char::from(*b)),
                _ => None,
            }
            .ok_or_else(|| RecordingErrorKind::UnknownCondition(snippet(c)))?
        }
        _ => Condition::X,
    };
    let gravity = match cols.gravity {
        Some([x, y, z]) => {
            let g = [
                parse_f64(rec, x, "gx")?,
                parse_f64(rec, y, "gy")?,
                parse_f64(rec, z, "gz")?,
            ];
            let norm = g.iter().map(|c| c * c).sum::<f64>().sqrt();
            if (norm - 1.0).abs() > UNIT_TOLERANCE {
                return Err(RecordingErrorKind::NotUnitVector { norm });
            }
            Some(g.map(|c| c / norm))
        }
        None => None,
    };
    let pose = match cols.pose {
        Some(i) => {
            let f = field(rec, i);
            let text = std::str::from_utf8(f)
                .map_err(|_| RecordingErrorKind::BadPose("not UTF-8 text"))?;
            if text.is_empty() {
                return Err(RecordingErrorKind::BadPose("empty pose name"));
            }
            if !pose_name_ok(text) {
                return Err(RecordingErrorKind::BadPose(
                    "a pose name may not hold commas, quotes, '#' or line breaks",
                ));
            }
            Some(text)
        }
        None => None,
    };
    let t_s = parse_opt(rec, cols.t_s, "t_s")?;
    let angle_deg = match all {
        true => parse_opt(rec, cols.angle_deg, "angle_deg")?,
        false => None,
    };
    let u = parse_f64(rec, cols.u, "u")?;
    let v = parse_f64(rec, cols.v, "v")?;
    let w = parse_f64(rec, cols.w, "w")?;
    let seq = match cols.seq.filter(|_| all) {
        Some(i) => {
            Some(
                integer::<_, u64>(rec, i).map_err(|f| RecordingErrorKind::NotAnInteger {
                    column: "seq",
                    text: snippet(&f),
                })?,
            )
        }
        None => None,
    };
    let temp_c = parse_opt(rec, cols.temp_c.filter(|_| all), "temp_c")?;
    let rate_hz = parse_opt(rec, cols.rate_hz, "rate_hz")?;
    let conv_gaps = match cols.conv_gaps {
        Some(i) => Some(parse_gaps(field(rec, i))?),
        None => None,
    };
    let conv_missed = match cols.conv_missed.map(|i| (i, rec.number(i))) {
        // A number column's NaN is a text file's empty field: not counted.
        Some((_, Some(x))) if x.is_nan() => None,
        Some((i, Some(x))) => Some(
            integer::<_, u8>(rec, i)
                .ok()
                .filter(|m| *m <= 7)
                .ok_or_else(|| RecordingErrorKind::BadMissed(format!("{x}")))?,
        ),
        Some((i, None)) => parse_missed(field(rec, i))?,
        None => None,
    };
    let boot = match cols.boot {
        Some(i) if rec.number(i).is_some() => {
            Some(
                integer::<_, u32>(rec, i).map_err(|f| RecordingErrorKind::NotAnInteger {
                    column: "boot",
                    text: snippet(&f),
                })?,
            )
        }
        Some(i) => Some(parse_boot(field(rec, i))?),
        None => None,
    };
    if let Some(r) = rate_hz {
        if r <= 0.0 {
            return Err(RecordingErrorKind::NotPositive {
                column: "rate_hz",
                value: r,
            });
        }
    }
    Ok(Row {
        condition,
        t_s,
        angle_deg,
        u,
        v,
        w,
        seq,
        temp_c,
        rate_hz,
        gravity,
        pose,
        conv_gaps,
        conv_missed,
        boot,
        unc: match cols.unc.filter(|_| all) {
            Some([a, b, c]) => Some([
                parse_f64(rec, a, "u_unc")?,
                parse_f64(rec, b, "v_unc")?,
                parse_f64(rec, c, "w_unc")?,
            ]),
            None => None,
        },
    })
}

/// A `conv_missed` field: a whole number of conversions from 0 to 7, or empty (not
/// counted).
pub(super) fn parse_missed(f: &[u8]) -> Result<Option<u8>, RecordingErrorKind> {
    let f = f.trim_ascii();
    if f.is_empty() {
        return Ok(None);
    }
    std::str::from_utf8(f)
        .ok()
        .and_then(|s| s.parse::<u8>().ok())
        .filter(|m| *m <= 7)
        .map(Some)
        .ok_or_else(|| RecordingErrorKind::BadMissed(snippet(f)))
}

/// A `boot` field: a whole number (0 to 2³² − 1).
pub(super) fn parse_boot(f: &[u8]) -> Result<u32, RecordingErrorKind> {
    std::str::from_utf8(f.trim_ascii())
        .ok()
        .and_then(|s| s.parse::<u32>().ok())
        .ok_or_else(|| RecordingErrorKind::NotAnInteger {
            column: "boot",
            text: snippet(f),
        })
}

/// A `conv_gaps` field: tick counts separated by single spaces (empty: one conversion).
pub(super) fn parse_gaps(f: &[u8]) -> Result<Aperture, RecordingErrorKind> {
    let bad = |why: &str| RecordingErrorKind::BadConversions(format!("'{}': {why}", snippet(f)));
    let text = std::str::from_utf8(f).map_err(|_| bad("not text"))?;
    let mut gaps = Vec::new();
    if !text.is_empty() {
        for g in text.split(' ') {
            let v: u16 = g
                .parse()
                .map_err(|_| bad("each gap is a whole number of ticks, 1 to 65535"))?;
            gaps.push(v);
        }
    }
    Aperture::new(Ticks(0), &gaps).ok_or_else(|| {
        bad(&format!(
            "at most {} gaps (conversions {MAX_CONVERSIONS}), none 0",
            MAX_CONVERSIONS - 1
        ))
    })
}
