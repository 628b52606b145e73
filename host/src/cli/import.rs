//! `rotacal import`: the command line of `rotacal::recording::import`. The recording is
//! written whole or not at all (`rotacal::atomic`): a failure leaves no partial file.

use anyhow::Context;
use rotacal_shared::Condition;
use std::path::PathBuf;

/// `rotacal import` arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The logs, one per condition unless a condition column is mapped: delimited text
    /// (semicolons, tabs, commas or spaces; a decimal comma where commas do not separate)
    /// or spreadsheets (.xlsx, .xls, .xlsb, .ods).
    #[arg(required = true)]
    inputs: Vec<PathBuf>,
    /// Which field holds what, by number from 0 or by the header's name:
    /// t=0,u=1,v=2,w=3 or t=time,u=ax,v=ay,w=az [,condition=][,angle=][,temp=][,seq=].
    /// Lines before the first line with a number are a preamble; its last is the header.
    #[arg(long)]
    columns: rotacal::recording::import::ColumnMap,
    /// The condition of each input, in order (x, y, z), e.g. --condition x,y,z.
    #[arg(long, value_delimiter = ',')]
    condition: Vec<char>,
    /// Lines to skip at the top of each input (a header is found without it).
    #[arg(long, default_value_t = 0)]
    skip: usize,
    /// Seconds per unit of the time column (e.g. 0.001 for milliseconds).
    #[arg(long, default_value_t = 1.0)]
    time_scale: f64,
    /// Multiply the readings by this, e.g. 0.000122 to turn an LSM6DS33's counts at ±4 g
    /// into g; --units then names what they are in.
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    scale: f64,
    /// A spreadsheet's sheet to read (default: the first).
    #[arg(long)]
    sheet: Option<String>,
    /// Nominal rotation rate, Hz (metadata).
    #[arg(long)]
    rate_hz: Option<f64>,
    /// Local gravity, m/s² (metadata).
    #[arg(long)]
    g_loc: Option<f64>,
    /// The units of the readings as written to the recording (after --scale), e.g.
    /// counts, g, m/s^2 or V: the recording's `units`, which calibrate's sensitivities
    /// are per m/s² of.
    #[arg(long)]
    units: Option<String>,
    /// Sample rate, Hz (metadata).
    #[arg(long)]
    sample_rate_hz: Option<f64>,
    /// The device: model, serial number, firmware ("… firmware A.B.C …" is read as its
    /// version), as the recording's `# device=` and every output's traceability block.
    #[arg(long)]
    device: Option<String>,
    /// A section list (imucal's JSON: {"name": {"start": N, "end": M}}, data rows from
    /// 0, end exclusive) of static poses; needs --poses.
    #[arg(long, requires = "poses")]
    sections: Option<PathBuf>,
    /// The gravity direction of each section to import: x_p=+x,x_a=-x,... (±x, ±y, ±z:
    /// the axis reading +g or −g; or gx:gy:gz). Unmapped sections are left out.
    #[arg(long, requires = "sections")]
    poses: Option<String>,
    /// The recording to write.
    #[arg(long)]
    out: PathBuf,
}

/// Run `rotacal import`.
pub fn run(a: Args) -> anyhow::Result<()> {
    let meta = rotacal::recording::Metadata {
        rate_hz: a.rate_hz,
        g_loc: a.g_loc,
        units: a.units,
        sample_rate_hz: a.sample_rate_hz,
        device: a.device.clone(),
        ..Default::default()
    };
    let (inputs, columns, condition, skip, time_scale, out) = (
        &a.inputs,
        a.columns,
        &a.condition,
        a.skip,
        a.time_scale,
        &a.out,
    );
    let poses = a.sections.as_deref().zip(a.poses.as_deref());
    let poses = match poses {
        Some((list, map)) => {
            let text = std::fs::read_to_string(list)
                .map_err(|e| anyhow::anyhow!("{}: {e}", list.display()))?;
            Some(rotacal::recording::import::PoseSections {
                sections: rotacal::recording::import::PoseSections::sections_from_json(
                    &text,
                    &list.display().to_string(),
                )?,
                map: rotacal::recording::import::PoseSections::map_from_str(map)
                    .context("--poses")?,
            })
        }
        None => None,
    };
    let conditions = condition
        .iter()
        .map(|c| {
            Condition::from_letter(*c)
                .ok_or_else(|| anyhow::anyhow!("--condition '{c}': expected x, y or z"))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let mut readers = Vec::new();
    for p in inputs {
        readers.push(open(p, a.sheet.as_deref())?);
    }
    let spec = rotacal::recording::import::ImportSpec {
        columns,
        conditions,
        skip,
        time_scale,
        scale: a.scale,
        meta,
        poses,
    };
    let counts = rotacal::atomic::write_with(out, |w| -> anyhow::Result<_> {
        Ok(rotacal::recording::import::import(readers, &spec, w)?)
    })?;
    let total: usize = counts.rows.iter().sum();
    let mut text = format!(
        "wrote {}: {total} rows ({})\n",
        out.display(),
        counts
            .rows
            .iter()
            .zip(inputs)
            .map(|(n, p)| format!("{n} from {}", p.display()))
            .collect::<Vec<_>>()
            .join(", ")
    );
    if !counts.poses.is_empty() {
        let per: Vec<String> = counts
            .poses
            .iter()
            .map(|(p, n)| format!("{p} {n}"))
            .collect();
        text += &format!("poses: {}\n", per.join(", "));
    }
    if !counts.skipped_sections.is_empty() {
        text += &format!(
            "left out (not in the pose map): {}\n",
            counts.skipped_sections.join(", ")
        );
    }
    rotacal::output::emit(&text)?;
    Ok(())
}

/// An input: a spreadsheet (by its first bytes), else delimited text.
fn open(
    p: &std::path::Path,
    sheet: Option<&str>,
) -> anyhow::Result<rotacal::recording::import::Input<'static>> {
    use rotacal::recording::import::{is_spreadsheet, Input};
    use std::io::Read;
    let name = p.display().to_string();
    let mut f = std::fs::File::open(p).map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
    let mut head = [0u8; 8];
    let n = f
        .read(&mut head)
        .map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
    if is_spreadsheet(head.get(..n).unwrap_or(&[])) {
        let bytes = std::fs::read(p).map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
        return Ok(rotacal::recording::import::sheet(&name, bytes, sheet)?);
    }
    if sheet.is_some() {
        anyhow::bail!("{name}: --sheet is for spreadsheets, and this is text");
    }
    let f = std::fs::File::open(p).map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
    Ok(Input::text(name, Box::new(std::io::BufReader::new(f))))
}
