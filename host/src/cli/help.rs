//! `rotacal help`: a subcommand's help, or a topic: `formats`, the file formats (the text of
//! docs/formats.md, built in, so that the binary alone documents what it reads and writes).

use clap::Command;

/// The file formats: docs/formats.md.
pub const FORMATS: &str = include_str!("../../../docs/formats.md");

/// The recording CSV in brief, for the help of the commands that read one.
pub const RECORDING: &str = "\
The recording CSV (in full: rotacal help formats):

    # rotacal recording v1
    # method=rotation
    # rate_hz=0.01
    # g_loc=9.80101
    # units=counts
    condition,t_s,u,v,w,temp_c
    x,0.000000,-12.0,16377.0,-231.0,24.91
    ...

Columns, in any order (names exact, lower case):
  condition    x, y or z: the platter axis the table turns (rotation, stepped)
  u, v, w      the readings, in the device's output units (# units=)
  t_s          seconds, increasing within each condition (rotation; free)
  angle_deg    the table angle α, degrees (stepped)
  gx, gy, gz   gravity's direction in the platter frame (poses of known orientation;
               then no condition or angle_deg)
  optional     seq, temp_c, rate_hz (a rate per row), pose, conv_gaps, conv_missed, boot
Metadata (# key=value lines before the header; flags override them): method (rotation,
static or free), rate_hz, g_loc (m/s²), units, sample_rate_hz, noise_sigma, device,
tick_hz, and the standard uncertainties u_g_loc, u_time_s and u_angle_deg.
Other logs (delimited text, spreadsheets, other column names): rotacal import.";

/// `rotacal help` arguments.
#[derive(clap::Args)]
pub struct Args {
    /// `formats` (the files rotacal reads and writes), or a subcommand's name.
    pub topic: Option<String>,
}

/// Why a topic is refused.
#[derive(Debug, thiserror::Error)]
#[error("no help on '{topic}': the topics are formats and the subcommands ({subcommands})")]
pub struct UnknownTopic {
    topic: String,
    subcommands: String,
}

/// Print the help asked for; `cli` is the whole command line's definition.
pub fn run(a: Args, mut cli: Command) -> anyhow::Result<()> {
    match a.topic.as_deref() {
        None => cli.print_long_help()?,
        Some("formats") => rotacal::output::emit(FORMATS)?,
        Some(name) => {
            let subcommands = cli
                .get_subcommands()
                .map(|c| c.get_name().to_string())
                .collect::<Vec<_>>()
                .join(", ");
            match cli.find_subcommand_mut(name) {
                Some(sub) => sub.print_long_help()?,
                None => {
                    return Err(UnknownTopic {
                        topic: name.into(),
                        subcommands,
                    }
                    .into())
                }
            }
        }
    }
    Ok(())
}
