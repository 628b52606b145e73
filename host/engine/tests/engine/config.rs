//! The simulator's configuration (`simulate::Config`): every preset in host/presets/ is
//! accepted, and each bad field is refused with a message that starts with its key. Each
//! refusal changes one field of a configuration that is accepted, and the values just
//! inside each limit are accepted, so a check that is missing, misnamed or off by its
//! boundary fails here.

use std::path::{Path, PathBuf};

use rotacal_engine::simulate::{Config, Simulation, PRESETS};

/// A rotation configuration (16 Hz, counts).
const ROT: &str = "preset = \"paper-10mhz\"\n";
/// A stepped static configuration (1 Hz, volts, 5° steps).
const STAT: &str = "preset = \"metrologia-static\"\n";
/// A free-method configuration (16 Hz, counts); top-level keys only, so that a case can
/// add tables after it.
const FREE: &str = "method = \"free\"\nunits = \"counts\"\n\
    device = { sensitivity = [1669.32, 1669.10, 1676.46], angles_deg = [90.077, 90.095, \
    89.910], offsets = [525.1, 99.6, 442.4] }\n";

/// (base, what the case adds, the key its message must start with).
const REFUSED: &[(&str, &str, &str)] = &[
    (ROT, "g_loc = 0.0", "g_loc"),
    (ROT, "g_loc = nan", "g_loc"),
    (
        ROT,
        "[device]\nsensitivity = [1669.32, -1.0, 1676.46]",
        "device.sensitivity",
    ),
    (
        ROT,
        "[device]\nsensitivity = [inf, 1669.10, 1676.46]",
        "device.sensitivity",
    ),
    (
        ROT,
        "[device]\nangles_deg = [90.0, 180.0, 90.0]",
        "device.angles_deg",
    ),
    (
        ROT,
        "[device]\nangles_deg = [0.0, 90.0, 90.0]",
        "device.angles_deg",
    ),
    (ROT, "[device]\noffsets = [0.0, nan, 0.0]", "device.offsets"),
    (
        ROT,
        "[device]\nmatrix = [[nan, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]",
        "device.matrix",
    ),
    (ROT, "[mounting]\naxis = [0.0, 0.0, 0.0]", "mounting.axis"),
    (ROT, "[mounting]\naxis = [inf, 0.0, 1.0]", "mounting.axis"),
    (ROT, "[mounting]\nangle_deg = nan", "mounting.angle_deg"),
    (
        ROT,
        "[mounting]\nangle_deg = 2.0\nmatrix = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]",
        "mounting",
    ),
    (
        ROT,
        "[mounting]\nmatrix = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]",
        "mounting.matrix",
    ),
    (
        ROT,
        "[mounting]\nmatrix = [[1.000001, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]",
        "mounting.matrix",
    ),
    (ROT, "[sensor]\nnoise_sigma = -1.0", "sensor.noise_sigma"),
    (ROT, "units = \"V\"", "sensor.noise_sigma"),
    (ROT, "[sensor]\nlsb = -1.0", "sensor.lsb"),
    (
        ROT,
        "[sensor]\nfull_scale = [1.0, 1.0]",
        "sensor.full_scale",
    ),
    (
        ROT,
        "[sensor]\nfull_scale = [-inf, 1.0]",
        "sensor.full_scale",
    ),
    (
        ROT,
        "[sensor]\nnoise_sigma = 3.0\n[sensor.noise]\nsd = 3.0",
        "sensor.noise_sigma and sensor.noise.sd",
    ),
    (ROT, "[sensor.noise]\nsd = -1.0", "sensor.noise.sd"),
    (
        ROT,
        "[sensor.noise]\nsd = [1.0, nan, 1.0]",
        "sensor.noise.sd",
    ),
    (ROT, "[sensor.noise]\nar = [1.2]", "sensor.noise.ar"),
    (
        ROT,
        "[sensor.noise]\nflicker_floor_ug = -1.0",
        "sensor.noise.flicker_floor_ug",
    ),
    (
        ROT,
        "[sensor.noise]\nflicker_floor_ug = [1.0, inf, 1.0]",
        "sensor.noise.flicker_floor_ug",
    ),
    (
        ROT,
        "[sensor.noise]\nrandom_walk_ug_per_sqrt_s = [1.0, 2.0, -0.1]",
        "sensor.noise.random_walk_ug_per_sqrt_s",
    ),
    (
        ROT,
        "[sensor.noise]\nlowpass_hz = 8.0",
        "sensor.noise.lowpass_hz",
    ),
    (
        ROT,
        "[sensor.noise]\nar = [0.5]\nlowpass_hz = 2.0",
        "sensor.noise.ar and sensor.noise.lowpass_hz",
    ),
    (
        ROT,
        "[timing]\nsample_rate_hz = 0.0",
        "timing.sample_rate_hz",
    ),
    (
        ROT,
        "[timing]\nclock_error_ppm = 1e5",
        "timing.clock_error_ppm",
    ),
    (
        ROT,
        "[timing]\nclock_error_ppm = -1e5",
        "timing.clock_error_ppm",
    ),
    // 0.05 of the 16 Hz sample period is 3.125 ms.
    (ROT, "[timing]\njitter_s = 0.0032", "timing.jitter_s"),
    (ROT, "[timing]\njitter_s = -1e-6", "timing.jitter_s"),
    (
        ROT,
        "[timing]\ndrop_probability = 1.0",
        "timing.drop_probability",
    ),
    (
        ROT,
        "[timing]\ndrop_probability = -0.1",
        "timing.drop_probability",
    ),
    (ROT, "[timing]\ntick_hz = 15.9", "timing.tick_hz"),
    (ROT, "[timing]\ngap_s = -1.0", "timing.gap_s"),
    (ROT, "[poses]\ncount = 4", "poses"),
    (ROT, "[table]\nrates_hz = [0.01, 0.0]", "table.rates_hz"),
    (ROT, "[table]\nrates_hz = []", "table.rates_hz"),
    (ROT, "[table]\nrates_hz = [inf]", "table.rates_hz"),
    (
        ROT,
        "[table]\nduration_s = 60.0\nsamples_per_condition = 100",
        "table",
    ),
    (ROT, "[table]\nduration_s = -1.0", "table.duration_s"),
    (
        ROT,
        "[table]\nsamples_per_condition = 7",
        "table.samples_per_condition",
    ),
    // 0.4 s at 16 Hz is 6 samples.
    (
        ROT,
        "[table]\nduration_s = 0.4",
        "table.samples_per_condition",
    ),
    (
        ROT,
        "[table]\nstart_angle_deg = [0.0, nan, 0.0]",
        "table.start_angle_deg",
    ),
    (
        ROT,
        "[effects.step_error]\nangle_sd_deg = 0.1",
        "effects.step_error",
    ),
    (
        ROT,
        "[table]\nangles_deg = [0.0, 90.0, 180.0]",
        "table.angles_deg",
    ),
    (ROT, "[table]\nangle_step_deg = 5.0", "table.angle_step_deg"),
    (
        ROT,
        "[table]\nreadings_per_angle = 1",
        "table.readings_per_angle",
    ),
    (ROT, "[table]\ndwell_s = 1.0", "table.dwell_s"),
    (ROT, "[temperature]\nt0_c = nan", "temperature"),
    (ROT, "[temperature]\nperiod_s = 0.0", "temperature.period_s"),
    (
        ROT,
        "[temperature]\nresolution_c = -0.01",
        "temperature.resolution_c",
    ),
    (
        ROT,
        "[effects.rate_error]\nrelative = 0.1",
        "effects.rate_error.relative",
    ),
    (
        ROT,
        "[effects.rate_error]\nrelative = -0.1",
        "effects.rate_error.relative",
    ),
    (
        ROT,
        "[effects.offset_drift]\nper_s = [0.0, inf, 0.0]",
        "effects.offset_drift.per_s",
    ),
    (
        ROT,
        "[effects.temperature_offset]\nper_c = [nan, 0.0, 0.0]",
        "effects.temperature_offset.per_c",
    ),
    (
        ROT,
        "[effects.nonlinearity_2nd]\nk2 = [inf, 0.0, 0.0]",
        "effects.nonlinearity_2nd.k2",
    ),
    (
        ROT,
        "[effects.nonlinearity_3rd]\nk3 = [0.0, 0.0, nan]",
        "effects.nonlinearity_3rd.k3",
    ),
    (
        ROT,
        "[effects.saturation]\nrails = [5.0, 1.0]",
        "effects.saturation.rails",
    ),
    (
        ROT,
        "[effects.saturation]\nrails = [nan, 1.0]",
        "effects.saturation.rails",
    ),
    (
        ROT,
        "[effects.centripetal]\nradius_m = -0.1",
        "effects.centripetal.radius_m",
    ),
    (
        ROT,
        "[effects.centripetal]\nradius_m = 0.1\n\
         directions = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]",
        "effects.centripetal.directions",
    ),
    (
        ROT,
        "[effects.axis_time_skew]\nskew_s = [0.0, nan, 0.0]",
        "effects.axis_time_skew.skew_s",
    ),
    (
        ROT,
        "[effects.rate_ripple]\nrelative = 1.0",
        "effects.rate_ripple.relative",
    ),
    (
        ROT,
        "[effects.rate_ripple]\nrelative = 0.1\nphase_deg = nan",
        "effects.rate_ripple",
    ),
    // Static: the rotation keys, and the angle list.
    (STAT, "[table]\nrates_hz = [0.01]", "table.rates_hz"),
    (
        STAT,
        "[table]\nsamples_per_condition = 100",
        "table.samples_per_condition",
    ),
    (STAT, "[table]\nduration_s = 60.0", "table.duration_s"),
    (
        STAT,
        "[table]\nstart_angle_deg = [0.0, 0.0, 0.0]",
        "table.start_angle_deg",
    ),
    (
        STAT,
        "[effects.rate_error]\nrelative = 1e-4",
        "effects.rate_error",
    ),
    (
        STAT,
        "[effects.centripetal]\nradius_m = 0.1",
        "effects.centripetal",
    ),
    (
        STAT,
        "[effects.axis_time_skew]\nskew_s = [0.0, 0.0, 0.0]",
        "effects.axis_time_skew",
    ),
    (
        STAT,
        "[effects.rate_ripple]\nrelative = 0.01",
        "effects.rate_ripple",
    ),
    (
        STAT,
        "[table]\nangles_deg = [0.0, 90.0, 180.0]\nangle_step_deg = 30.0",
        "table",
    ),
    (
        STAT,
        "[table]\nangle_step_deg = 0.0",
        "table.angle_step_deg",
    ),
    (
        STAT,
        "[table]\nangle_step_deg = 120.5",
        "table.angle_step_deg",
    ),
    (
        STAT,
        "[table]\nangles_deg = [0.0, 90.0]",
        "table.angles_deg",
    ),
    (
        STAT,
        "[table]\nangles_deg = [0.0, nan, 180.0]",
        "table.angles_deg",
    ),
    (
        STAT,
        "[table]\nreadings_per_angle = 0",
        "table.readings_per_angle",
    ),
    (STAT, "[table]\ndwell_s = -1.0", "table.dwell_s"),
    (
        STAT,
        "[effects.step_error]\nangle_sd_deg = 5.5",
        "effects.step_error",
    ),
    (
        STAT,
        "[effects.step_error]\ntilt_sd_deg = -0.1",
        "effects.step_error",
    ),
    // 0.05 of the 1 Hz sample period is 50 ms.
    (STAT, "[timing]\njitter_s = 0.06", "timing.jitter_s"),
    // Free: the table's keys and the poses.
    (FREE, "[table]\nrates_hz = [0.01]", "table.rates_hz"),
    (
        FREE,
        "[table]\nsamples_per_condition = 100",
        "table.samples_per_condition",
    ),
    (FREE, "[table]\nduration_s = 60.0", "table.duration_s"),
    (
        FREE,
        "[table]\nstart_angle_deg = [0.0, 0.0, 0.0]",
        "table.start_angle_deg",
    ),
    (
        FREE,
        "[table]\nangles_deg = [0.0, 90.0, 180.0]",
        "table.angles_deg",
    ),
    (
        FREE,
        "[table]\nangle_step_deg = 5.0",
        "table.angle_step_deg",
    ),
    (
        FREE,
        "[table]\nreadings_per_angle = 1",
        "table.readings_per_angle",
    ),
    (FREE, "[table]\ndwell_s = 1.0", "table.dwell_s"),
    (
        FREE,
        "[effects.rate_error]\nrelative = 1e-4",
        "effects.rate_error",
    ),
    (
        FREE,
        "[effects.step_error]\nangle_sd_deg = 0.1",
        "effects.step_error",
    ),
    (
        FREE,
        "[effects.centripetal]\nradius_m = 0.1",
        "effects.centripetal",
    ),
    (
        FREE,
        "[effects.axis_time_skew]\nskew_s = [0.0, 0.0, 0.0]",
        "effects.axis_time_skew",
    ),
    (
        FREE,
        "[effects.rate_ripple]\nrelative = 0.01",
        "effects.rate_ripple",
    ),
    (FREE, "[poses]\ncount = 0", "poses"),
    (FREE, "[poses]\ndirections = []", "poses"),
    (
        FREE,
        "[poses]\ndirections = [[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]",
        "poses.directions",
    ),
    (
        FREE,
        "[poses]\ndirections = [[nan, 0.0, 1.0]]",
        "poses.directions",
    ),
    (FREE, "[poses]\nstill_s = 0.0", "poses.still_s"),
    (FREE, "[poses]\nmove_s = -1.0", "poses.move_s"),
    (FREE, "[poses]\nnoise_spread = 0.99", "poses.noise_spread"),
    (FREE, "[poses]\nsettle_ms2 = -1.0", "poses.settle_ms2"),
    (FREE, "[poses]\ntremor_ms2 = -0.1", "poses.tremor_ms2"),
    (FREE, "[poses]\ntremor_hz = 1.0", "poses.tremor_hz"),
    // At 16 Hz the 10 Hz band lies above half the sample rate.
    (FREE, "[poses]\ntremor_ms2 = 0.05", "poses.tremor_hz"),
    (
        FREE,
        "[poses]\ncount = 3\nmoved = { pose = 3, deg = 10.0 }",
        "poses.moved",
    ),
    (
        FREE,
        "[poses]\nmoved = { pose = 0, deg = inf }",
        "poses.moved",
    ),
];

/// (base, what the case adds): values at or just inside each limit.
const ACCEPTED: &[(&str, &str)] = &[
    (
        ROT,
        "[sensor.noise]\nflicker_floor_ug = 0.0\nrandom_walk_ug_per_sqrt_s = [0.0, 5.0, 10.0]",
    ),
    (ROT, ""),
    (ROT, "g_loc = 1e-3"),
    (ROT, "[device]\nangles_deg = [0.001, 90.0, 179.999]"),
    (
        ROT,
        "[mounting]\nmatrix = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]",
    ),
    (ROT, "[mounting]\naxis = [0.0, 0.0, 1e-9]\nangle_deg = 2.0"),
    (ROT, "[sensor]\nnoise_sigma = 0.0\nlsb = 0.0"),
    (ROT, "[sensor.noise]\nsd = [1.0, 0.0, 2.0]\nar = [0.9]"),
    (ROT, "[sensor.noise]\nlowpass_hz = 7.9"),
    (
        ROT,
        "[timing]\njitter_s = 0.003125\ndrop_probability = 0.999",
    ),
    (ROT, "[timing]\ntick_hz = 16.0\ngap_s = 0.0"),
    (ROT, "[timing]\nclock_error_ppm = 99999.0"),
    (ROT, "[timing]\nclock_error_ppm = -99999.0"),
    (ROT, "[table]\nsamples_per_condition = 8"),
    (ROT, "[table]\nduration_s = 0.5"),
    (ROT, "[temperature]\nresolution_c = 0.0"),
    (ROT, "[effects.rate_error]\nrelative = 0.0999"),
    (ROT, "[effects.rate_ripple]\nrelative = -0.999"),
    (ROT, "[effects.saturation]\nrails = [-1.0, 1.0]"),
    (ROT, "[effects.centripetal]\nradius_m = 0.0"),
    (
        ROT,
        "[effects.centripetal]\nradius_m = 0.1\n\
         directions = [[0.0, 1.0, 0.0], [1.0, 1.0, 1.0], [1.0, 0.0, 0.0]]",
    ),
    (STAT, ""),
    (
        STAT,
        "[table]\nangle_step_deg = 120.0\nreadings_per_angle = 1\ndwell_s = 0.0",
    ),
    (STAT, "[table]\nangles_deg = [0.0, 120.0, 240.0]"),
    (
        STAT,
        "[effects.step_error]\nangle_sd_deg = 5.0\ntilt_sd_deg = 5.0",
    ),
    (STAT, "[timing]\njitter_s = 0.05"),
    (FREE, ""),
    (
        FREE,
        "[poses]\nnoise_spread = 1.0\nmove_s = 0.0\nsettle_ms2 = 0.0",
    ),
    (FREE, "[poses]\nmoved = { pose = 11, deg = 10.0 }"),
    (
        FREE,
        "[timing]\nsample_rate_hz = 104.0\n[poses]\ntremor_ms2 = 0.05\ntremor_hz = 50.9",
    ),
    (
        FREE,
        "[poses]\ndirections = [[0.0, 0.0, 2.0], [1.0, 0.0, 0.0]]",
    ),
];

fn text(base: &str, case: &str) -> String {
    format!("{base}{case}\n")
}

#[test]
fn each_bad_field_is_refused_naming_its_key() {
    let mut failures = Vec::new();
    for (base, case, key) in REFUSED {
        // The case alone is what is wrong: its base is accepted.
        assert!(Config::from_toml(base).is_ok(), "base:\n{base}");
        match Config::from_toml(&text(base, case)) {
            Ok(_) => failures.push(format!("accepted:\n{case}")),
            Err(e) => {
                let msg = e.to_string();
                let why = msg.strip_prefix(&format!("{key}: ")).unwrap_or("");
                if why.trim().is_empty() {
                    failures.push(format!("{case}\n  got {msg:?}, want \"{key}: …\""));
                }
            }
        }
    }
    assert!(failures.is_empty(), "\n{}", failures.join("\n"));
}

#[test]
fn values_at_each_limit_are_accepted() {
    let failures: Vec<String> = ACCEPTED
        .iter()
        .filter_map(|(base, case)| {
            Config::from_toml(&text(base, case))
                .err()
                .map(|e| format!("{case}\n  refused: {e}"))
        })
        .collect();
    assert!(failures.is_empty(), "\n{}", failures.join("\n"));
}

/// Mistakes that are not a bad value: an unknown key (a typo must not silently turn an
/// effect off), a device given neither or both ways, an unknown preset.
#[test]
fn unknown_keys_and_incomplete_devices_are_refused() {
    let cases: &[(&str, &str)] = &[
        (
            "preset = \"paper-10mhz\"\n[sensor]\nnois_sigma = 1.0\n",
            "nois_sigma",
        ),
        (
            "preset = \"paper-10mhz\"\n[effects.rate_eror]\nrelative = 1e-4\n",
            "rate_eror",
        ),
        ("[device]\noffsets = [0.0, 0.0, 0.0]\n", "device: "),
        (
            "[device]\nsensitivity = [1.0, 1.0, 1.0]\nangles_deg = [90.0, 90.0, 90.0]\n\
             matrix = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]\n",
            "device: ",
        ),
        ("[device]\nsensitivity = [1.0, 1.0, 1.0]\n", "device: "),
        (
            "preset = \"nope\"\n",
            "unknown preset 'nope' (presets: paper-10mhz, paper-multirate, metrologia-static)",
        ),
        ("preset = 3\n", "preset: "),
    ];
    for (text, want) in cases {
        let msg = Config::from_toml(text)
            .err()
            .unwrap_or_else(|| panic!("accepted:\n{text}"))
            .to_string();
        assert!(msg.contains(want), "{text}\n  got {msg:?}");
    }
    // Both refusals above and this acceptance differ only in the device.
    let ok = "[device]\nsensitivity = [1.0, 1.0, 1.0]\nangles_deg = [90.0, 90.0, 90.0]\n";
    Config::from_toml(ok).unwrap();
}

fn presets_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../presets")
}

/// Every file in host/presets/ is a preset by its name, and is accepted: as a file, by
/// name, and by the simulator.
#[test]
fn every_preset_file_is_accepted() {
    let mut files: Vec<PathBuf> = std::fs::read_dir(presets_dir())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    files.sort();
    assert_eq!(files.len(), PRESETS.len(), "{files:?}");
    for path in &files {
        let name = path.file_stem().unwrap().to_str().unwrap();
        let text = std::fs::read_to_string(path).unwrap();
        let cfg = Config::from_toml(&text).unwrap_or_else(|e| panic!("{name}: {e}"));
        let (_, embedded) = PRESETS
            .iter()
            .find(|(n, _)| *n == name)
            .unwrap_or_else(|| panic!("{name} is not in PRESETS"));
        assert_eq!(*embedded, text, "{name}");
        // By name, the same but for the `preset` key that names it.
        let by_name = Config::preset(name).unwrap();
        assert_eq!(by_name.preset.as_deref(), Some(name));
        assert_eq!(
            Config {
                preset: None,
                ..by_name
            },
            cfg,
            "{name}"
        );
        assert_eq!(Config::load(name).unwrap(), Config::preset(name).unwrap());
        assert_eq!(Config::load(path.to_str().unwrap()).unwrap(), cfg, "{name}");
        Simulation::new(cfg).unwrap_or_else(|e| panic!("{name}: {e}"));
    }
}

/// A file's message names the file, then the key.
#[test]
fn load_names_the_file_then_the_key() {
    let dir = std::env::temp_dir().join(format!("rotacal-engine-config-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("bad.toml");
    std::fs::write(&path, "preset = \"paper-10mhz\"\n[timing]\ngap_s = -1.0\n").unwrap();
    let p = path.to_str().unwrap();
    let msg = Config::load(p).unwrap_err().to_string();
    assert!(msg.starts_with(&format!("{p}: timing.gap_s: ")), "{msg}");
    let msg = Config::load("no-such-preset").unwrap_err().to_string();
    assert!(
        msg.starts_with("no-such-preset: no such file, and not a preset"),
        "{msg}"
    );
    for (name, _) in PRESETS {
        assert!(msg.contains(name), "{msg}");
    }
    std::fs::remove_dir_all(&dir).ok();
}
