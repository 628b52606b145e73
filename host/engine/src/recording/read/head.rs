//! A file's head: the preamble's metadata and the header's columns, with their checks.

use std::collections::BTreeMap;
use std::io::{self, BufRead};

use crate::recording::{
    check_meta_number, is_key, snippet, tick_hz, Metadata, MetadataError, Method, Recording,
    RecordingError, RecordingErrorKind, COLUMN_NAMES, KNOWN_KEYS, UNCERTAINTY_KEYS,
};

/// Where each known column is in the header.
#[derive(Debug)]
pub(super) struct ColumnIndex {
    pub(super) n: usize,
    /// Absent only in files with `gx, gy, gz`.
    pub(super) condition: Option<usize>,
    /// `gx, gy, gz`: all three or none.
    pub(super) gravity: Option<[usize; 3]>,
    pub(super) pose: Option<usize>,
    /// `u_unc, v_unc, w_unc`: all three or none.
    pub(super) unc: Option<[usize; 3]>,
    pub(super) u: usize,
    pub(super) v: usize,
    pub(super) w: usize,
    pub(super) t_s: Option<usize>,
    pub(super) angle_deg: Option<usize>,
    pub(super) seq: Option<usize>,
    pub(super) temp_c: Option<usize>,
    pub(super) rate_hz: Option<usize>,
    pub(super) conv_gaps: Option<usize>,
    pub(super) conv_missed: Option<usize>,
    pub(super) boot: Option<usize>,
}

pub(super) struct Parser<'a> {
    pub(super) source: &'a str,
    /// Require all three conditions for every rate.
    pub(super) complete: bool,
    /// Physical lines consumed before the csv reader took over.
    pub(super) line_offset: u64,
    /// The method to read as, overriding the file's (a command line's `--method`).
    pub(super) method: Option<Method>,
}

pub(super) type Res<T> = Result<T, RecordingError>;

impl Parser<'_> {
    pub(super) fn err(&self, line: Option<u64>, kind: RecordingErrorKind) -> RecordingError {
        RecordingError {
            source_name: self.source.to_string(),
            line,
            row: None,
            kind,
        }
    }

    /// Read the `#` and blank lines before the header, leaving the reader at the header.
    pub(super) fn preamble<R: BufRead>(&mut self, br: &mut R) -> Res<Metadata> {
        let io_err = |s: &Self, e: io::Error| s.err(None, RecordingErrorKind::Io(e));
        // A UTF-8 byte-order mark.
        {
            let buf = br.fill_buf().map_err(|e| io_err(self, e))?;
            if buf.starts_with(b"\xEF\xBB\xBF") {
                br.consume(3);
            }
        }
        let mut meta = Metadata::default();
        // Line of each known key, for duplicate messages.
        let mut seen: BTreeMap<&'static str, u64> = BTreeMap::new();
        let mut line = Vec::new();
        loop {
            let buf = br.fill_buf().map_err(|e| io_err(self, e))?;
            let first = buf.iter().find(|&&b| !matches!(b, b' ' | b'\t' | b'\r'));
            let comment = match first {
                Some(b'#') => true,
                Some(b'\n') => false,
                // The header (or a whitespace-only buffer: the csv stage skips blank lines).
                _ => break,
            };
            line.clear();
            br.read_until(b'\n', &mut line)
                .map_err(|e| io_err(self, e))?;
            self.line_offset += 1;
            let body = line.strip_suffix(b"\n").unwrap_or(&line);
            let body = body.strip_suffix(b"\r").unwrap_or(body);
            if body.contains(&b'\r') {
                let kind = RecordingErrorKind::BadLineEndings;
                return Err(self.err(Some(self.line_offset), kind));
            }
            if comment {
                self.metadata_line(&line, &mut meta, &mut seen)?;
            }
        }
        Ok(meta)
    }

    fn metadata_line(
        &self,
        raw: &[u8],
        meta: &mut Metadata,
        seen: &mut BTreeMap<&'static str, u64>,
    ) -> Res<()> {
        let lineno = self.line_offset;
        let text = String::from_utf8_lossy(raw);
        let Some(body) = text.trim().strip_prefix('#') else {
            return Ok(());
        };
        let Some((key, value)) = body.split_once('=') else {
            return Ok(());
        };
        let (key, value) = (key.trim(), value.trim());
        if !is_key(key) {
            return Ok(()); // a plain comment that happens to hold '='
        }
        let bad = |m: MetadataError| self.err(Some(lineno), RecordingErrorKind::BadMetadata(m));
        let Some(&known) = KNOWN_KEYS.iter().find(|k| **k == key) else {
            if let Some(&ukey) = UNCERTAINTY_KEYS.iter().find(|k| **k == key) {
                if let (Some(&first), Some(before)) = (seen.get(ukey), meta.other.get(ukey)) {
                    if before != value {
                        return Err(bad(MetadataError::Twice {
                            key: ukey,
                            first_line: first,
                        }));
                    }
                }
                seen.insert(ukey, lineno);
                let x: f64 = value.parse().map_err(|_| {
                    bad(MetadataError::NotANumber {
                        key: ukey,
                        text: snippet(value.as_bytes()),
                    })
                })?;
                if !(x.is_finite() && x >= 0.0) {
                    return Err(bad(MetadataError::NotUncertainty {
                        key: ukey,
                        value: x,
                    }));
                }
            }
            meta.other.insert(key.to_string(), value.to_string());
            return Ok(());
        };
        let before = meta.clone();
        match known {
            "method" => {
                meta.method = Some(
                    value
                        .parse::<Method>()
                        .map_err(|m| bad(MetadataError::Method(m)))?,
                )
            }
            "units" => meta.units = Some(value.to_string()),
            "device" => meta.device = Some(value.to_string()),
            _ => {
                let x: f64 = value.parse().map_err(|_| {
                    bad(MetadataError::NotANumber {
                        key: known,
                        text: snippet(value.as_bytes()),
                    })
                })?;
                check_meta_number(known, x).map_err(bad)?;
                match known {
                    "rate_hz" => meta.rate_hz = Some(x),
                    "g_loc" => meta.g_loc = Some(x),
                    "sample_rate_hz" => meta.sample_rate_hz = Some(x),
                    _ => meta.noise_sigma = Some(x),
                }
            }
        }
        if let Some(&first) = seen.get(known) {
            if before != *meta {
                return Err(bad(MetadataError::Twice {
                    key: known,
                    first_line: first,
                }));
            }
        } else {
            seen.insert(known, lineno);
        }
        Ok(())
    }

    pub(super) fn header(
        &self,
        rec: &csv::ByteRecord,
        line: u64,
        meta: &Metadata,
    ) -> Res<(ColumnIndex, Method)> {
        let at = |kind| self.err(Some(line), kind);
        let names: Vec<String> = rec
            .iter()
            .map(|f| String::from_utf8_lossy(f.trim_ascii()).into_owned())
            .collect();
        if names.iter().any(|n| n.contains('\r')) {
            return Err(at(RecordingErrorKind::BadLineEndings));
        }
        let mut found: [Option<usize>; COLUMN_NAMES.len()] = [None; COLUMN_NAMES.len()];
        for (i, name) in names.iter().enumerate() {
            if let Some(k) = COLUMN_NAMES.iter().position(|c| c == name) {
                if let Some(slot) = found.get_mut(k) {
                    if slot.is_some() {
                        return Err(at(RecordingErrorKind::DuplicateColumn(name.clone())));
                    }
                    *slot = Some(i);
                }
            }
        }
        if found.iter().all(Option::is_none) {
            return Err(at(RecordingErrorKind::NoHeader));
        }
        let idx = |name: &str| {
            COLUMN_NAMES
                .iter()
                .position(|c| *c == name)
                .and_then(|k| found.get(k).copied().flatten())
        };
        let require = |name: &'static str| -> Res<usize> {
            idx(name).ok_or_else(
                || match names.iter().find(|n| n.eq_ignore_ascii_case(name)) {
                    Some(n) => at(RecordingErrorKind::WrongCaseColumn {
                        expected: name,
                        found: n.clone(),
                    }),
                    None => at(RecordingErrorKind::MissingColumn(name)),
                },
            )
        };
        // Gravity directions: all three columns or none.
        let gravity = if ["gx", "gy", "gz"].iter().any(|n| idx(n).is_some()) {
            Some([require("gx")?, require("gy")?, require("gz")?])
        } else {
            None
        };
        let free = self.method.or(meta.method) == Some(Method::Free);
        let condition = match gravity {
            Some(_) => idx("condition"),
            // A free recording needs no condition; one that is there is used (each
            // condition's rows are searched for poses on their own).
            None if free => idx("condition"),
            None => Some(require("condition")?),
        };
        if gravity.is_some() {
            if let Some(c) = ["angle_deg", "rate_hz"]
                .into_iter()
                .find(|c| idx(c).is_some())
            {
                return Err(at(RecordingErrorKind::BadMetadata(
                    MetadataError::ReplacedByGravity { column: c },
                )));
            }
        }
        let unc = if ["u_unc", "v_unc", "w_unc"].iter().any(|n| idx(n).is_some()) {
            Some([require("u_unc")?, require("v_unc")?, require("w_unc")?])
        } else {
            None
        };
        let u = require("u")?;
        let v = require("v")?;
        let w = require("w")?;
        let t_s = idx("t_s");
        let conv_gaps = idx("conv_gaps");
        if conv_gaps.is_some() && tick_hz(meta).is_none() {
            return Err(at(RecordingErrorKind::BadMetadata(
                MetadataError::NoTickRate,
            )));
        }
        let method = self.method.or(meta.method).unwrap_or(if gravity.is_some() {
            Method::Static
        } else if t_s.is_some() {
            Method::Rotation
        } else {
            Method::Static
        });
        match method {
            Method::Rotation if gravity.is_some() => {
                return Err(at(RecordingErrorKind::BadMetadata(
                    MetadataError::RotationWithGravity,
                )));
            }
            Method::Rotation => {
                require("t_s")?;
            }
            Method::Static if gravity.is_none() => {
                require("angle_deg")?;
            }
            Method::Static => {}
            Method::Free if gravity.is_none() && condition.is_none() => {
                require("t_s")?;
            }
            Method::Free => {}
        }
        Ok((
            ColumnIndex {
                n: names.len(),
                condition,
                gravity,
                // A pose name means something only with a gravity direction, or in a free
                // recording (then the names are the poses).
                pose: if gravity.is_some() || (free && condition.is_none()) {
                    idx("pose")
                } else {
                    None
                },
                unc,
                u,
                v,
                w,
                t_s,
                angle_deg: idx("angle_deg"),
                seq: idx("seq"),
                temp_c: idx("temp_c"),
                rate_hz: idx("rate_hz"),
                conv_gaps,
                conv_missed: idx("conv_missed"),
                boot: idx("boot"),
            },
            method,
        ))
    }

    /// The recording of a file with conditions whose rows went to a sink.
    pub(super) fn without_rows(&self, meta: Metadata, method: Method) -> Recording {
        Recording {
            source: self.source.to_string(),
            meta,
            method,
            groups: Vec::new(),
            oriented: None,
            series: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::recording::{read_from, MetadataError, RecordingErrorKind, UnknownMethod};

    const BODY: &str = "condition,t_s,u,v,w\nx,0,1,2,3\n";

    /// The metadata error reading `preamble` then a small body: its line and problem.
    fn bad(preamble: &str) -> (Option<u64>, MetadataError, String) {
        let text = format!("{preamble}{BODY}");
        let e = read_from(text.as_bytes(), "m.csv").unwrap_err();
        let message = e.to_string();
        match e.kind {
            RecordingErrorKind::BadMetadata(m) => (e.line, m, message),
            other => panic!("not bad metadata: {other:?}"),
        }
    }

    #[test]
    fn a_bad_value_names_its_line_and_key() {
        let (line, m, text) = bad("# rotacal recording v1\n# units=counts\n# g_loc=-9.8\n");
        assert_eq!(line, Some(3));
        assert_eq!(
            m,
            MetadataError::NotPositive {
                key: "g_loc",
                value: -9.8
            }
        );
        assert_eq!(text, "m.csv:3: bad metadata: g_loc: -9.8 is not positive");
        let (line, m, text) = bad("#\n# noise_sigma = -0.5\n");
        assert_eq!(line, Some(2));
        assert_eq!(
            m,
            MetadataError::Negative {
                key: "noise_sigma",
                value: -0.5
            }
        );
        assert_eq!(text, "m.csv:2: bad metadata: noise_sigma: -0.5 is negative");
        let (line, m, text) = bad("# rate_hz=inf\n");
        assert_eq!(line, Some(1));
        assert!(
            matches!(m, MetadataError::NotFinite { key: "rate_hz", value } if value.is_infinite())
        );
        assert_eq!(text, "m.csv:1: bad metadata: rate_hz: inf is not finite");
    }

    #[test]
    fn an_unknown_method_names_its_line_and_text() {
        let (line, m, text) = bad("# units=V\n# method= Spin \n");
        assert_eq!(line, Some(2));
        assert_eq!(
            m,
            MetadataError::Method(UnknownMethod {
                text: "Spin".into()
            })
        );
        assert_eq!(
            text,
            "m.csv:2: bad metadata: method: expected 'rotation' or 'static', got 'Spin' (or \
             'free': still poses of unknown orientation)"
        );
    }

    #[test]
    fn a_key_given_twice_names_both_lines() {
        let (line, m, text) = bad("# u_g_loc=0.001\n# device=a\n# u_g_loc=0.002\n");
        assert_eq!(line, Some(3));
        assert_eq!(
            m,
            MetadataError::Twice {
                key: "u_g_loc",
                first_line: 1
            }
        );
        assert_eq!(
            text,
            "m.csv:3: bad metadata: u_g_loc given twice with different values (first on line 1)"
        );
        let (line, m, _) = bad("# method=static\n# method=rotation\n");
        assert_eq!(line, Some(2));
        assert_eq!(
            m,
            MetadataError::Twice {
                key: "method",
                first_line: 1
            }
        );
    }

    #[test]
    fn header_rules_name_the_header_line() {
        let e = read_from(
            &b"# g_loc=9.8\ngx,gy,gz,rate_hz,u,v,w\n0,0,1,1,1,2,3\n"[..],
            "h.csv",
        )
        .unwrap_err();
        assert_eq!(e.line, Some(2));
        assert!(matches!(
            e.kind,
            RecordingErrorKind::BadMetadata(MetadataError::ReplacedByGravity { column: "rate_hz" })
        ));
        assert_eq!(
            e.to_string(),
            "h.csv:2: bad metadata: column rate_hz with gx, gy, gz: the gravity direction \
             replaces it"
        );
    }
}
