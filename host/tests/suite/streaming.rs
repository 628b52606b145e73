//! The streaming calibration (`calibrate::stream`, docs/streaming.md) through its public
//! entry, `calibrate_file`: its coverage on long correlated records, and the fast reader
//! against the csv reader on the test corpus and on simulated files. The comparisons of the streaming engine with
//! the engine that holds every row, and of one pass with two, are the engine's own tests
//! (`cargo test --release -p rotacal-engine -- stream::`).

use rotacal::calibrate::stream::calibrate_file;
use rotacal::calibrate::Options;
use rotacal::recording;
use rotacal::simulate::{Config, Noise, NoiseSd, Simulation};
use std::path::PathBuf;

/// A rotation recording of `rows` rows per condition at 104 Hz, paper-10mhz's device,
/// noise of a different level per channel and unstated (as on a real recording).
fn config(seed: u64, rows: u64, ar: Option<Vec<f64>>, lowpass_hz: Option<f64>) -> Config {
    let mut cfg = Config::preset("paper-10mhz").unwrap();
    cfg.seed = seed;
    cfg.table.rates_hz = Some(vec![0.25]);
    cfg.table.samples_per_condition = Some(rows);
    cfg.table.duration_s = None;
    cfg.timing.sample_rate_hz = 104.0;
    cfg.mounting.axis = [1.0, 2.0, 2.0];
    cfg.mounting.angle_deg = 3.0;
    cfg.sensor.noise = Some(Noise {
        sd: Some(NoiseSd::PerChannel([10.6, 8.5, 12.5])),
        ar,
        lowpass_hz,
        state: false,
        flicker_floor_ug: None,
        random_walk_ug_per_sqrt_s: None,
    });
    cfg
}

/// A folder of this process's own for `test`.
fn tmp(test: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("rotacal-streaming-{}-{test}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Text the fast reader must read exactly as the csv reader does (or hand back).
const TEXTS: &[&str] = &[
    "condition,t_s,u,v,w,seq\nx,1e-3,+1.5,-0,1E3,18446744073709551615\nx,2,.5,5.,-1e-300,0\n\
     y,0,1,2,3,1\nz,0,1,2,3,2\n",
    "condition,t_s,u,v,w\r\nx,0.000001,1.0,2.0,3.0\r\n\r\n  \r\ny, 1 ,2,3,4\r\nz,2,3,4,5",
    "# rate_hz=0.1\ncondition,t_s,u,v,w\nx,0,1,2,3\n# a comment\n,,,,\ny,0,1,2,3\nz,0,1,2,3\n",
    "condition,t_s,u,v,w\nx,0,1,2,3\nx,-1,1,2,3\ny,0,1,2,3\nz,0,1,2,3\n",
    "condition,t_s,u,v,w\nx,0,1,2,3\nx,1,1,2\ny,0,1,2,3\nz,0,1,2,3\n",
    "condition,t_s,u,v,w\nx,0,1,2,3\nx,1,1,2,nan\ny,0,1,2,3\nz,0,1,2,3\n",
    "condition,t_s,u,v,w\nx,0,1,2,3\ny,0,1.23456789012345678,2,3\nz,0,1,2,3\n",
    "condition,t_s,u,v,w\nx,0,1,2,3\ny,0,\"1\",2,3\nz,0,1,2,3\n",
    "condition,t_s,u,v,w\nx,0,1,2,3\nq,0,1,2,3\nz,0,1,2,3\n",
    "condition,t_s,u,v,w\nx,0,1,2,3\ny,0,1,2,3\n",
    "condition,t_s,u,v,w,rate_hz\nx,0,1,2,3,0.1\ny,0,1,2,3,0.1\nz,0,1,2,3,0.1\nx,0,1,2,3,0.2\n",
    "condition,t_s,u,v,w\nx,0,12345678901234567890,2,3\ny,0,-0.000000000000001,2,3\nz,0,1,2,3\n",
];

#[test]
fn the_fast_reader_reads_as_the_csv_reader_does() {
    let dir = tmp("reader");
    let corpus = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data");
    let mut paths: Vec<PathBuf> = ["recording/good", "recording/bad", "malformed"]
        .iter()
        .filter_map(|d| std::fs::read_dir(corpus.join(d)).ok())
        .flatten()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    for (i, t) in TEXTS.iter().enumerate() {
        let p = dir.as_path().join(format!("text{i}.csv"));
        std::fs::write(&p, t).unwrap();
        paths.push(p);
    }
    assert!(paths.len() > TEXTS.len() + 10, "the corpus was not found");
    for p in &paths {
        let fast = recording::read(p).map_err(|e| e.to_string());
        let name = p.display().to_string();
        let file = std::fs::File::open(p).unwrap();
        let csv = recording::read_from(file, &name).map_err(|e| e.to_string());
        assert_eq!(fast, csv, "{name}");
        // The same bytes held in memory (as `Simulation::recording` reads them).
        let held = recording::read_bytes(&std::fs::read(p).unwrap(), &name);
        assert_eq!(held.map_err(|e| e.to_string()), csv, "{name} from memory");
    }
    // Every preset's file, and a 104 Hz one with every optional column the simulator
    // writes, read from memory by both readers.
    let mut configs: Vec<Config> = rotacal::simulate::config::PRESETS
        .iter()
        .map(|(name, _)| Config::preset(name).unwrap())
        .collect();
    configs.push(config(7, 3000, Some(vec![0.6]), None));
    for cfg in configs {
        let (_, bytes) = Simulation::new(cfg).unwrap().write(Vec::new()).unwrap();
        let csv = recording::read_from(&bytes[..], "simulated").unwrap();
        assert_eq!(recording::read_bytes(&bytes, "simulated").unwrap(), csv);
    }
}

/// The streaming engine's uncertainties on long correlated records, by Monte Carlo as
/// coverage.rs checks the held engine's: 1000 runs of 70 000 rows per condition (above the
/// hold limit, so every group is calibrated from sums, as `rotacal calibrate` does), AR(1)
/// ρ = 0.6 at a different level per channel, unstated. Each property's fraction of
/// expanded-uncertainty intervals that hold the truth must lie in [0.93, 0.97]: two-sided,
/// ±2.9 binomial σ around 0.95 at 1000 runs, so an understated U fails and so does one
/// overstated by 10 % (coverage 0.972) in most runs.
#[test]
fn streamed_coverage_on_long_correlated_records() {
    let dir = tmp("coverage");
    let runs = 1000;
    let trial = |t: usize| {
        let cfg = config(0x57E4_0000 + t as u64, 70_000, Some(vec![0.6]), None);
        let sim = Simulation::new(cfg).unwrap();
        let path = dir.join(format!("run-{t}.csv"));
        sim.write_file(&path).unwrap();
        let cal = calibrate_file(&path, &Options::default()).unwrap();
        std::fs::remove_file(&path).unwrap();
        (cal.by_rate, sim.truth().clone())
    };
    rotacal_proof::prove(
        "streaming::streamed_coverage_on_long_correlated_records",
        runs,
        trial,
        |results| {
            crate::coverage::rotation_tally(
                "streamed, 70 000 rows a condition, AR(1) ρ = 0.6",
                results,
            )
        },
    );
    std::fs::remove_dir_all(&dir).ok();
}
