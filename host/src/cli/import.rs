//! `rotacal import`: the command line of `rotacal::recording::import`.

use anyhow::Context;
use rotacal_shared::Condition;
use std::path::PathBuf;

/// `rotacal import` arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The logs, one per condition unless a condition column is mapped.
    #[arg(required = true)]
    inputs: Vec<PathBuf>,
    /// Which field holds what, 0-based: t=0,u=1,v=2,w=3[,condition=N][,angle=N][,temp=N][,seq=N].
    #[arg(long)]
    columns: rotacal::recording::import::ColumnMap,
    /// The condition of each input, in order (x, y, z), e.g. --condition x,y,z.
    #[arg(long, value_delimiter = ',')]
    condition: Vec<char>,
    /// Header lines to skip at the top of each input.
    #[arg(long, default_value_t = 0)]
    skip: usize,
    /// Seconds per unit of the time column (e.g. 0.001 for milliseconds).
    #[arg(long, default_value_t = 1.0)]
    time_scale: f64,
    /// Nominal rotation rate, Hz (metadata).
    #[arg(long)]
    rate_hz: Option<f64>,
    /// Local gravity, m/s² (metadata).
    #[arg(long)]
    g_loc: Option<f64>,
    /// Output units (metadata), e.g. counts or V.
    #[arg(long)]
    units: Option<String>,
    /// Sample rate, Hz (metadata).
    #[arg(long)]
    sample_rate_hz: Option<f64>,
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
    let mut readers: Vec<(String, Box<dyn std::io::BufRead>)> = Vec::new();
    for p in inputs {
        let f = std::fs::File::open(p).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
        readers.push((
            p.display().to_string(),
            Box::new(std::io::BufReader::new(f)),
        ));
    }
    let spec = rotacal::recording::import::ImportSpec {
        columns,
        conditions,
        skip,
        time_scale,
        meta,
        poses,
    };
    let file = std::fs::File::create(out).map_err(|e| anyhow::anyhow!("{}: {e}", out.display()))?;
    let counts = rotacal::recording::import::import(readers, &spec, file)?;
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
