//! What can be wrong with an import, and where: [`ImportError`] names the input, its
//! 1-based line where one applies, and the problem ([`ImportErrorKind`]), with the field
//! (0-based, as the column map counts) and its text as fields. The command line's own
//! arguments have theirs: [`ColumnMapError`], [`PoseMapError`], [`SpecError`].

use rotacal_shared::Condition;

/// A problem with an import: which input (`import` for the spec and the output as a
/// whole), which line if one applies, and what.
#[derive(Debug, thiserror::Error)]
#[error("{source_name}{}: {kind}", line.map(|l| format!(":{l}")).unwrap_or_default())]
pub struct ImportError {
    /// The input's path or name.
    pub source_name: String,
    /// 1-based physical line of the input (skipped, blank and comment lines count); for a
    /// section list, the line its JSON parser names.
    pub line: Option<usize>,
    /// The problem.
    pub kind: ImportErrorKind,
}

impl ImportError {
    /// `kind` at `line` of `source` (`None`: about the whole of it).
    pub(super) fn at(source: &str, line: Option<usize>, kind: ImportErrorKind) -> ImportError {
        ImportError {
            source_name: source.to_string(),
            line,
            kind,
        }
    }
}

/// What is wrong.
#[derive(Debug, thiserror::Error)]
pub enum ImportErrorKind {
    /// The spec does not fit the inputs.
    #[error("{0}")]
    Spec(SpecError),
    /// The recording could not be started, written or flushed (the writer refuses what the
    /// reader would).
    #[error("{0}")]
    Write(std::io::Error),
    /// An input could not be read.
    #[error("cannot read: {0}")]
    Read(std::io::Error),
    /// A line has too few fields for the column map.
    #[error("no field {field} for {column}: the line has {fields} fields")]
    NoField {
        /// The field the map names (0-based).
        field: usize,
        /// The column it holds (`u`, `t`, `condition`, …).
        column: &'static str,
        /// The line's fields.
        fields: usize,
    },
    /// A field that must be a finite number.
    #[error("{column} (field {field}) '{text}' is not a finite number")]
    NotFinite {
        /// The field (0-based).
        field: usize,
        /// The column it holds.
        column: &'static str,
        /// The field's text.
        text: String,
    },
    /// A `seq` field that is not a non-negative whole number.
    #[error("seq (field {field}) '{text}' is not a whole number")]
    NotWhole {
        /// The field (0-based).
        field: usize,
        /// The field's text.
        text: String,
    },
    /// A condition field other than `x`, `y` or `z`.
    #[error("condition '{text}': expected x, y or z")]
    BadCondition {
        /// The field (0-based).
        field: usize,
        /// The field's text.
        text: String,
    },
    /// No condition for the input (neither a column nor `--condition`).
    #[error("no condition for this input")]
    NoCondition,
    /// Time decreased within a condition (`None`: a section list's poses, which share one
    /// clock).
    #[error(
        "time went backwards{}: {t_s} s after {previous} s",
        condition.map(|c| format!(" in condition {}", c.letter())).unwrap_or_default()
    )]
    TimeWentBackwards {
        /// The condition.
        condition: Option<Condition>,
        /// This line's time, s.
        t_s: f64,
        /// The previous line's, s.
        previous: f64,
    },
    /// A section ends after the input's last data row.
    #[error(
        "section '{section}' ends at data row {end} (exclusive), but the input has only \
         {rows} data rows"
    )]
    SectionPastEnd {
        /// The section.
        section: String,
        /// Its end, exclusive.
        end: usize,
        /// The input's data rows.
        rows: usize,
    },
    /// An input without data lines.
    #[error("no data lines")]
    NoData,
    /// No line with a number among the first lines.
    #[error("no line with a number in the first {lines} lines: is this a log of readings?")]
    NoDataLine {
        /// Lines read.
        lines: usize,
    },
    /// A line with zero bytes: a binary file.
    #[error(
        "a binary file, not text (rotacal import reads delimited text and spreadsheets: \
         .xlsx, .xls, .xlsb, .ods)"
    )]
    Binary,
    /// A spreadsheet that could not be read.
    #[error("cannot read the spreadsheet: {0}")]
    Spreadsheet(String),
    /// A sheet the workbook does not have.
    #[error("no sheet '{sheet}' (the workbook has: {sheets})")]
    NoSheet {
        /// The sheet asked for.
        sheet: String,
        /// The workbook's sheets.
        sheets: String,
    },
    /// A column named in the map, and no header line to find it in.
    #[error(
        "{column}={name} names a column, but the input has no header line before its first \
         line of numbers: give the field's number (from 0) instead"
    )]
    NoHeader {
        /// The column (`u`, `t`, …).
        column: &'static str,
        /// The name given.
        name: String,
    },
    /// A column named in the map that the header lacks.
    #[error("{column}={name}: the header has no such column (it has: {header})")]
    NoSuchColumn {
        /// The column (`u`, `t`, …).
        column: &'static str,
        /// The name given.
        name: String,
        /// The header's names.
        header: String,
    },
    /// The first data line did not read: perhaps it is not data.
    #[error("{error}; if this line is not data, skip the lines up to it with --skip {skip}")]
    FirstLine {
        /// What is wrong with it.
        error: Box<ImportErrorKind>,
        /// Lines to skip to leave it out.
        skip: usize,
    },
    /// A section list that is not JSON.
    #[error("not a JSON section list: {0}")]
    NotJson(serde_json::Error),
    /// JSON, but not an object of sections.
    #[error("expected an object of sections: {{\"name\": {{\"start\": N, \"end\": M}}, ...}}")]
    NotSections,
    /// A section without `start` or `end`.
    #[error("section '{section}': no '{key}'")]
    NoBound {
        /// The section.
        section: String,
        /// `start` or `end`.
        key: &'static str,
    },
    /// A section's `start` or `end` that is not a whole number ≥ 0.
    #[error("section '{section}': '{key}' {text} is not a row index (a whole number ≥ 0)")]
    NotRowIndex {
        /// The section.
        section: String,
        /// `start` or `end`.
        key: &'static str,
        /// The value, as JSON.
        text: String,
    },
    /// A section whose end is not after its start.
    #[error("section '{section}': end {end} is not after start {start}")]
    EmptySection {
        /// The section.
        section: String,
        /// Its first data row.
        start: usize,
        /// One past its last.
        end: usize,
    },
    /// An empty section list.
    #[error("no sections")]
    NoSections,
    /// Two sections that share rows.
    #[error("sections '{first}' and '{second}' overlap")]
    Overlap {
        /// The section that starts first.
        first: String,
        /// The other.
        second: String,
    },
}

/// A spec that does not fit its inputs, refused before anything is written.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SpecError {
    /// Neither conditions nor a section list, but not one input with a time column.
    #[error(
        "without conditions or a section list the input is imported as a free recording \
         (method free), which needs one input with a time column (t=)"
    )]
    Free,
    /// Not one condition per input.
    #[error(
        "{inputs} input(s) but {conditions} condition(s): give one --condition per input, or \
         a condition column"
    )]
    Conditions {
        /// Inputs given.
        inputs: usize,
        /// Conditions given.
        conditions: usize,
    },
    /// A time scale that is not a positive number.
    #[error("--time-scale must be positive")]
    TimeScale(f64),
    /// A reading scale that is zero or not finite.
    #[error("--scale must be a finite number other than 0")]
    Scale(f64),
    /// A section list with more than one input.
    #[error("a section list describes one input; {inputs} given")]
    SectionsInputs {
        /// Inputs given.
        inputs: usize,
    },
    /// A section list with conditions or angles.
    #[error(
        "with a section list, poses replace conditions and angles: give neither a condition \
         nor an angle (column or --condition)"
    )]
    PosesAndConditions,
    /// A pose map naming a section the list lacks.
    #[error("the pose map names '{pose}', which the section list lacks")]
    UnknownSection {
        /// The name.
        pose: String,
    },
}

/// A column map (`t=0,u=1,v=2,w=3`) that cannot be used; `part` is the offending
/// `NAME=INDEX` as given (trimmed).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ColumnMapError {
    /// A part without `=`.
    #[error("'{part}': expected NAME=FIELD (the field's number from 0, or its header name)")]
    NoIndex {
        /// The part.
        part: String,
    },
    /// An index that is not a whole number.
    #[error("'{part}': the index must be a whole number (0-based)")]
    BadIndex {
        /// The part.
        part: String,
    },
    /// A name the map does not know.
    #[error("unknown column '{name}' (known: t, u, v, w, condition, angle, temp, seq)")]
    UnknownColumn {
        /// The name.
        name: String,
    },
    /// A name given twice.
    #[error("'{name}' given twice")]
    Twice {
        /// The name.
        name: String,
    },
    /// Not all of `u`, `v` and `w`.
    #[error("u, v and w are all required")]
    NoChannels,
    /// Neither `t` nor `angle`.
    #[error("give t (rotation) or angle (static)")]
    NoTimeOrAngle,
}

/// A pose map (`x_p=+x,x_a=-x`) that cannot be used; `part` is the offending
/// `NAME=DIRECTION` as given (trimmed).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PoseMapError {
    /// A part without `=`.
    #[error("'{part}': expected NAME=DIRECTION, e.g. x_p=+x")]
    NoDirection {
        /// The part.
        part: String,
    },
    /// A direction that is neither an axis nor numbers `gx:gy:gz`.
    #[error("'{part}': the direction must be ±x, ±y, ±z or gx:gy:gz")]
    BadDirection {
        /// The part.
        part: String,
    },
    /// A vector direction without three components.
    #[error("'{part}': a vector direction has three components gx:gy:gz")]
    NotThree {
        /// The part.
        part: String,
    },
    /// A vector direction that is not a unit vector.
    #[error("'{part}': the direction must be a unit vector (length {norm})")]
    NotUnit {
        /// The part.
        part: String,
        /// Its length.
        norm: f64,
    },
    /// A pose given twice.
    #[error("pose '{name}' given twice")]
    Twice {
        /// The pose.
        name: String,
    },
    /// No poses.
    #[error("the pose map is empty")]
    Empty,
}
