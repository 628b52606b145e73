//! `rotacal help`: a subcommand's help, or a topic: one of the project's documents, built in,
//! so that the binary alone documents what it reads and writes.

use clap::Command;

/// The topics: a name and the document it prints.
pub const TOPICS: [(&str, &str); 4] = [
    ("formats", include_str!("../../../docs/formats.md")),
    ("simulator", include_str!("../../../docs/simulator.md")),
    ("recording", include_str!("../../../docs/recording.md")),
    ("protocol", include_str!("../../../docs/protocol.md")),
];

/// The topics' list, for the top-level help.
pub const TOPIC_LIST: &str = "\
Topics (rotacal help TOPIC):
  formats    the files rotacal reads and writes: recording CSV, calibration JSON, exports
  simulator  the simulator: its presets and every configuration key (rotacal simulate)
  recording  recording over BLE: the files it writes, the capture's format (record, decode)
  protocol   the BLE packets, commands and fit log (rotacal record, decode, crosscheck)";

/// For the commands that read a calibration JSON.
macro_rules! calibration_text {
    () => {
        "\
The calibration is the JSON `rotacal calibrate --json` writes; its keys: rotacal help formats."
    };
}

/// For the commands that read a calibration JSON.
pub const CALIBRATION: &str = calibration_text!();

/// For `rotacal simulate`.
pub const SIMULATOR: &str = "\
The configuration's keys, their units and defaults, and the model sample by sample:
rotacal help simulator. The recording it writes: rotacal help formats.";

/// For `rotacal decode`.
pub const CAPTURE: &str = "\
The capture (`# rotacal capture v1`, one received or written value per line, as hex) is
described under \"Files\" in rotacal help recording; the packets in it in rotacal help
protocol.";

/// The recording CSV in brief (a macro, so that it can be joined to other texts).
macro_rules! recording_text {
    () => {
        "\
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
Other logs (delimited text, spreadsheets, other column names): rotacal import."
    };
}

/// The recording CSV in brief, for the help of the commands that read one.
pub const RECORDING: &str = recording_text!();

/// For `rotacal apply`: a calibration and a recording.
pub const APPLY: &str = concat!(calibration_text!(), "\n\n", recording_text!());

/// `rotacal help` arguments.
#[derive(clap::Args)]
pub struct Args {
    /// A topic (formats, simulator, recording, protocol), or a subcommand's name.
    pub topic: Option<String>,
}

/// Why a topic is refused.
#[derive(Debug, thiserror::Error)]
#[error("no help on '{topic}': the topics are {topics} and the subcommands ({subcommands})")]
pub struct UnknownTopic {
    topic: String,
    topics: String,
    subcommands: String,
}

/// Print the help asked for; `cli` is the whole command line's definition.
pub fn run(a: Args, mut cli: Command) -> anyhow::Result<()> {
    match a.topic.as_deref() {
        None => cli.print_long_help()?,
        Some(name) if TOPICS.iter().any(|t| t.0 == name) => {
            for (_, text) in TOPICS.iter().filter(|t| t.0 == name) {
                rotacal::output::emit(text)?;
            }
        }
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
                        topics: TOPICS.map(|t| t.0).join(", "),
                        subcommands,
                    }
                    .into())
                }
            }
        }
    }
    Ok(())
}
