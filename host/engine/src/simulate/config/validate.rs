//! Every key's range and the combinations allowed, section by section in a fixed order,
//! so the first error reported is always the same one.

use super::{
    Centripetal, Config, ConfigError, Device, Effects, FreePoses, Mounting, Table, Temperature,
    Timing,
};
use crate::recording::Method;

impl Config {
    /// Checks every key's range and the combinations allowed, one section after another
    /// in a fixed order, so the first error reported is always the same one.
    pub(super) fn validate(&self) -> Result<(), ConfigError> {
        if !(self.g_loc.is_finite() && self.g_loc > 0.0) {
            return bad("g_loc", "must be a positive number of m/s²");
        }
        self.device.validate()?;
        self.mounting.validate()?;
        self.validate_sensor()?;
        self.timing.validate()?;
        self.validate_noise_model()?;
        self.validate_method()?;
        self.temperature.validate()?;
        self.effects.validate()
    }

    /// `[sensor]`: the white noise, the quantisation and the range. The noise model is
    /// checked after `[timing]`, as it needs the sample rate.
    fn validate_sensor(&self) -> Result<(), ConfigError> {
        let s = &self.sensor;
        if let Some(n) = s.noise_sigma {
            if !(n.is_finite() && n >= 0.0) {
                return bad("sensor.noise_sigma", "must be ≥ 0");
            }
        }
        self.noise_sd()?;
        if !(s.lsb.is_finite() && s.lsb >= 0.0) {
            return bad("sensor.lsb", "must be ≥ 0 (0: no quantisation)");
        }
        finite("sensor.full_scale", &s.full_scale)?;
        if s.full_scale[0] >= s.full_scale[1] {
            return bad("sensor.full_scale", "low must be below high");
        }
        Ok(())
    }

    /// `[sensor.noise]`: one level given, not two, and a process that can be built at
    /// the sample rate.
    fn validate_noise_model(&self) -> Result<(), ConfigError> {
        let Some(nz) = &self.sensor.noise else {
            return Ok(());
        };
        if self.sensor.noise_sigma.is_some() && nz.sd.is_some() {
            return bad(
                "sensor.noise_sigma and sensor.noise.sd",
                "give one, not both (sd is the marginal level of [sensor.noise])",
            );
        }
        if self
            .noise_sd()?
            .iter()
            .any(|x| !(x.is_finite() && *x >= 0.0))
        {
            return bad("sensor.noise.sd", "must be ≥ 0");
        }
        for (key, level) in [
            ("sensor.noise.flicker_floor_ug", &nz.flicker_floor_ug),
            (
                "sensor.noise.random_walk_ug_per_sqrt_s",
                &nz.random_walk_ug_per_sqrt_s,
            ),
        ] {
            let bad_level = level.as_ref().is_some_and(|l| {
                l.per_channel()
                    .iter()
                    .any(|x| !(x.is_finite() && *x >= 0.0))
            });
            if bad_level {
                return bad(key, "must be ≥ 0 µg");
            }
        }
        crate::simulate::NoiseProcess::new(nz, self.timing.sample_rate_hz)?;
        Ok(())
    }

    /// The keys of the method chosen, and none that belong to another method only.
    fn validate_method(&self) -> Result<(), ConfigError> {
        if self.method != Method::Free && self.poses.is_some() {
            return bad("poses", "applies to method = \"free\" only");
        }
        match self.method {
            Method::Rotation => self.validate_rotation(),
            Method::Free => self.validate_free(),
            Method::Static => self.validate_static(),
        }
    }

    /// Rotation: the rates, how long each condition lasts and the start angles.
    fn validate_rotation(&self) -> Result<(), ConfigError> {
        let tb = &self.table;
        let rates = self.rates_hz();
        if rates.is_empty() || rates.iter().any(|r| !(r.is_finite() && *r > 0.0)) {
            return bad("table.rates_hz", "give one or more positive rates");
        }
        if tb.duration_s.is_some() && tb.samples_per_condition.is_some() {
            return bad(
                "table",
                "give samples_per_condition or duration_s, not both",
            );
        }
        if let Some(d) = tb.duration_s {
            if !(d.is_finite() && d > 0.0) {
                return bad("table.duration_s", "must be positive");
            }
        }
        if self.samples_per_condition() < 8 {
            return bad("table.samples_per_condition", "must be at least 8");
        }
        if let Some(a) = tb.start_angle_deg {
            finite("table.start_angle_deg", &a)?;
        }
        only_for(
            "static",
            &[&self.effects.static_keys()[..], &tb.static_keys()].concat(),
        )
    }

    /// Free: no table or table effect, and poses that can be simulated.
    fn validate_free(&self) -> Result<(), ConfigError> {
        let (tb, fx) = (&self.table, &self.effects);
        only_for(
            "rotation or static",
            &[
                &tb.rotation_keys()[..],
                &tb.static_keys(),
                &fx.rotation_keys(),
                &fx.static_keys(),
            ]
            .concat(),
        )?;
        let poses = self.poses.clone().unwrap_or_default();
        poses.validate()?;
        if poses.tremor_ms2 > 0.0 && poses.tremor_hz + 1.0 >= self.timing.sample_rate_hz / 2.0 {
            return bad(
                "poses.tremor_hz",
                "the tremor's band (±1 Hz) must lie below half timing.sample_rate_hz",
            );
        }
        Ok(())
    }

    /// Static: the angle list or step, the readings per angle and the dwell.
    fn validate_static(&self) -> Result<(), ConfigError> {
        let tb = &self.table;
        only_for(
            "rotation",
            &[&tb.rotation_keys()[..], &self.effects.rotation_keys()].concat(),
        )?;
        if tb.angles_deg.is_some() && tb.angle_step_deg.is_some() {
            return bad("table", "give angles_deg or angle_step_deg, not both");
        }
        if let Some(step) = tb.angle_step_deg {
            if !(step.is_finite() && step > 0.0 && step <= 120.0) {
                return bad("table.angle_step_deg", "must lie in (0, 120]");
            }
        }
        if let Some(a) = &tb.angles_deg {
            finite("table.angles_deg", a)?;
            if a.len() < 3 {
                return bad("table.angles_deg", "give at least 3 angles");
            }
        }
        if tb.readings_per_angle == Some(0) {
            return bad("table.readings_per_angle", "must be at least 1");
        }
        if let Some(d) = tb.dwell_s {
            if !(d.is_finite() && d >= 0.0) {
                return bad("table.dwell_s", "must be ≥ 0");
            }
        }
        Ok(())
    }
}

impl Device {
    /// Either sensitivities and angles in range, or a matrix; finite offsets.
    fn validate(&self) -> Result<(), ConfigError> {
        match (self.sensitivity, self.angles_deg, self.matrix) {
            (Some(s), Some(a), None) => {
                finite("device.sensitivity", &s)?;
                finite("device.angles_deg", &a)?;
                if s.iter().any(|x| *x <= 0.0) {
                    return bad("device.sensitivity", "must be positive");
                }
                if a.iter().any(|x| *x <= 0.0 || *x >= 180.0) {
                    return bad("device.angles_deg", "must lie between 0 and 180");
                }
            }
            (None, None, Some(m)) => finite("device.matrix", m.as_flattened())?,
            _ => {
                return bad(
                    "device",
                    "give either sensitivity and angles_deg, or matrix",
                )
            }
        }
        finite("device.offsets", &self.offsets)
    }
}

impl Mounting {
    /// An axis and angle, or a rotation matrix, not both.
    fn validate(&self) -> Result<(), ConfigError> {
        finite("mounting.axis", &self.axis)?;
        finite("mounting.angle_deg", &[self.angle_deg])?;
        if self.matrix.is_none() && self.axis.iter().all(|x| *x == 0.0) {
            return bad("mounting.axis", "must not be zero");
        }
        if self.matrix.is_some() && self.angle_deg != 0.0 {
            return bad("mounting", "give axis and angle_deg, or matrix, not both");
        }
        if let Some(m) = &self.matrix {
            finite("mounting.matrix", m.as_flattened())?;
            if !is_rotation(m) {
                return bad(
                    "mounting.matrix",
                    "is not a rotation (needs RᵀR = I to 1e-9 and det R = +1)",
                );
            }
        }
        Ok(())
    }
}

impl Timing {
    /// Rates, clock error, jitter, drops and gaps that keep the timestamps in order.
    fn validate(&self) -> Result<(), ConfigError> {
        if !(self.sample_rate_hz.is_finite() && self.sample_rate_hz > 0.0) {
            return bad("timing.sample_rate_hz", "must be positive");
        }
        if !(self.clock_error_ppm.is_finite() && self.clock_error_ppm.abs() < 1e5) {
            return bad("timing.clock_error_ppm", "must be finite and below 1e5");
        }
        if !(self.jitter_s.is_finite()
            && self.jitter_s >= 0.0
            && self.jitter_s <= 0.05 / self.sample_rate_hz)
        {
            return bad(
                "timing.jitter_s",
                "must be ≥ 0 and at most 0.05 of the sample period (so timestamps stay in order)",
            );
        }
        if !(0.0..1.0).contains(&self.drop_probability) {
            return bad("timing.drop_probability", "must lie in [0, 1)");
        }
        if !(self.tick_hz.is_finite() && self.tick_hz >= self.sample_rate_hz) {
            return bad("timing.tick_hz", "must be at least the sample rate");
        }
        if !(self.gap_s.is_finite() && self.gap_s >= 0.0) {
            return bad("timing.gap_s", "must be ≥ 0");
        }
        Ok(())
    }
}

impl Table {
    /// The keys only rotation uses, each with whether it is given.
    fn rotation_keys(&self) -> [(&'static str, bool); 4] {
        [
            ("table.rates_hz", self.rates_hz.is_some()),
            (
                "table.samples_per_condition",
                self.samples_per_condition.is_some(),
            ),
            ("table.duration_s", self.duration_s.is_some()),
            ("table.start_angle_deg", self.start_angle_deg.is_some()),
        ]
    }

    /// The keys only the static method uses, each with whether it is given.
    fn static_keys(&self) -> [(&'static str, bool); 4] {
        [
            ("table.angles_deg", self.angles_deg.is_some()),
            ("table.angle_step_deg", self.angle_step_deg.is_some()),
            (
                "table.readings_per_angle",
                self.readings_per_angle.is_some(),
            ),
            ("table.dwell_s", self.dwell_s.is_some()),
        ]
    }
}

impl FreePoses {
    /// At least one pose, non-zero directions, and times, spread and move in range.
    fn validate(&self) -> Result<(), ConfigError> {
        let n = self.directions.as_ref().map_or(self.count, Vec::len);
        if n == 0 {
            return bad("poses", "give at least one pose");
        }
        if let Some(d) = &self.directions {
            finite("poses.directions", d.as_flattened())?;
            if d.iter()
                .any(|v| v.iter().map(|x| x * x).sum::<f64>() < 1e-12)
            {
                return bad("poses.directions", "each must be a non-zero vector");
            }
        }
        if !(self.still_s.is_finite() && self.still_s > 0.0) {
            return bad("poses.still_s", "must be positive");
        }
        if !(self.move_s.is_finite() && self.move_s >= 0.0) {
            return bad("poses.move_s", "must be ≥ 0");
        }
        if !(self.noise_spread.is_finite() && self.noise_spread >= 1.0) {
            return bad("poses.noise_spread", "must be ≥ 1");
        }
        if !(self.settle_ms2.is_finite() && self.settle_ms2 >= 0.0) {
            return bad("poses.settle_ms2", "must be ≥ 0");
        }
        if !(self.tremor_ms2.is_finite() && self.tremor_ms2 >= 0.0) {
            return bad("poses.tremor_ms2", "must be ≥ 0");
        }
        if !(self.tremor_hz.is_finite() && self.tremor_hz > 1.0) {
            return bad(
                "poses.tremor_hz",
                "must be above 1 Hz (the band is 2 Hz wide)",
            );
        }
        if let Some(m) = &self.moved {
            if m.pose >= n || !m.deg.is_finite() {
                return bad("poses.moved", "pose must be one of the poses, deg finite");
            }
        }
        Ok(())
    }
}

impl Temperature {
    /// Finite values, a positive period and a resolution ≥ 0.
    fn validate(&self) -> Result<(), ConfigError> {
        finite(
            "temperature",
            &[
                self.t0_c,
                self.ramp_c_per_h,
                self.swing_c,
                self.period_s,
                self.resolution_c,
            ],
        )?;
        if self.period_s <= 0.0 {
            return bad("temperature.period_s", "must be positive");
        }
        if self.resolution_c < 0.0 {
            return bad("temperature.resolution_c", "must be ≥ 0");
        }
        Ok(())
    }
}

impl Effects {
    /// The effects only rotation simulates, each with whether it is given.
    fn rotation_keys(&self) -> [(&'static str, bool); 6] {
        [
            ("effects.rate_error", self.rate_error.is_some()),
            ("effects.centripetal", self.centripetal.is_some()),
            ("effects.axis_time_skew", self.axis_time_skew.is_some()),
            ("effects.rate_ripple", self.rate_ripple.is_some()),
            ("effects.axis_wobble", self.axis_wobble.is_some()),
            ("effects.noise_change", self.noise_change.is_some()),
        ]
    }

    /// The effect only the static method simulates, with whether it is given.
    fn static_keys(&self) -> [(&'static str, bool); 1] {
        [("effects.step_error", self.step_error.is_some())]
    }

    /// Each effect given: finite parameters, in the range the simulator handles.
    fn validate(&self) -> Result<(), ConfigError> {
        if let Some(r) = &self.rate_error {
            if !(r.relative.is_finite() && r.relative.abs() < 0.1) {
                return bad(
                    "effects.rate_error.relative",
                    "must be finite and below 0.1 in size",
                );
            }
        }
        if let Some(x) = &self.offset_drift {
            finite("effects.offset_drift.per_s", &x.per_s)?;
        }
        if let Some(x) = &self.step_error {
            let ok = |v: f64| v.is_finite() && (0.0..=5.0).contains(&v);
            if !ok(x.angle_sd_deg) || !ok(x.tilt_sd_deg) {
                return bad(
                    "effects.step_error",
                    "angle_sd_deg and tilt_sd_deg must lie in [0, 5] degrees",
                );
            }
        }
        if let Some(x) = &self.temperature_offset {
            finite("effects.temperature_offset.per_c", &x.per_c)?;
        }
        if let Some(x) = &self.nonlinearity_2nd {
            finite("effects.nonlinearity_2nd.k2", &x.k2)?;
        }
        if let Some(x) = &self.nonlinearity_3rd {
            finite("effects.nonlinearity_3rd.k3", &x.k3)?;
        }
        if let Some(x) = &self.saturation {
            finite("effects.saturation.rails", &x.rails)?;
            if x.rails[0] >= x.rails[1] {
                return bad("effects.saturation.rails", "low must be below high");
            }
        }
        if let Some(x) = &self.centripetal {
            x.validate()?;
        }
        if let Some(x) = &self.axis_time_skew {
            finite("effects.axis_time_skew.skew_s", &x.skew_s)?;
        }
        if let Some(x) = &self.rate_ripple {
            finite("effects.rate_ripple", &[x.relative, x.phase_deg])?;
            if x.relative.abs() >= 1.0 {
                return bad("effects.rate_ripple.relative", "must be below 1 in size");
            }
        }
        if let Some(x) = &self.nonlinearity_high {
            finite("effects.nonlinearity_high.k", &x.k)?;
            if !(4..=7).contains(&x.order) {
                return bad("effects.nonlinearity_high.order", "must be 4, 5, 6 or 7");
            }
        }
        if let Some(x) = &self.offset_step {
            finite("effects.offset_step.size", &x.size)?;
            finite("effects.offset_step.at_s", &[x.at_s])?;
        }
        if let Some(x) = &self.noise_change {
            finite("effects.noise_change", &[x.at_s, x.factor])?;
            if !(x.factor > 0.0 && x.factor <= 100.0) {
                return bad("effects.noise_change.factor", "must lie in (0, 100]");
            }
        }
        if let Some(x) = &self.axis_wobble {
            finite("effects.axis_wobble", &[x.tilt_deg, x.phase_deg])?;
            if x.tilt_deg.abs() > 5.0 {
                return bad("effects.axis_wobble.tilt_deg", "must lie within ±5 degrees");
            }
            if !(1..=20).contains(&x.per_rev) {
                return bad("effects.axis_wobble.per_rev", "must be 1 … 20");
            }
        }
        Ok(())
    }
}

impl Centripetal {
    /// A radius ≥ 0, and directions each with a part across its condition's axis.
    fn validate(&self) -> Result<(), ConfigError> {
        if !(self.radius_m.is_finite() && self.radius_m >= 0.0) {
            return bad("effects.centripetal.radius_m", "must be ≥ 0");
        }
        if let Some(d) = &self.directions {
            finite("effects.centripetal.directions", d.as_flattened())?;
            for (i, dir) in d.iter().enumerate() {
                // The direction with its part along condition i's axis (axis i) zeroed.
                let across = dir
                    .iter()
                    .enumerate()
                    .map(|(k, v)| if k == i { 0.0 } else { *v });
                if across.map(|v| v * v).sum::<f64>() < 1e-12 {
                    return bad(
                        "effects.centripetal.directions",
                        "each must have a part across its condition's axis",
                    );
                }
            }
        }
        Ok(())
    }
}

/// The error for `key`, saying why its value is refused.
fn bad(key: &'static str, why: &'static str) -> Result<(), ConfigError> {
    Err(ConfigError::Invalid { key, why })
}

/// Refuse non-finite values of `key`.
fn finite(key: &'static str, xs: &[f64]) -> Result<(), ConfigError> {
    if xs.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(ConfigError::NotFinite { key })
    }
}

/// Refuse keys that belong to the other method.
fn only_for(method: &'static str, keys: &[(&'static str, bool)]) -> Result<(), ConfigError> {
    match keys.iter().find(|(_, set)| *set) {
        Some(&(key, _)) => Err(ConfigError::OtherMethod { key, method }),
        None => Ok(()),
    }
}

fn is_rotation(m: &[[f64; 3]; 3]) -> bool {
    let [[a, b, c], [d, e, f], [g, h, k]] = *m;
    let columns = [[a, d, g], [b, e, h], [c, f, k]];
    let mut ok = true;
    for (i, ci) in columns.iter().enumerate() {
        for (j, cj) in columns.iter().enumerate() {
            let dot: f64 = ci.iter().zip(cj).map(|(x, y)| x * y).sum();
            let want = if i == j { 1.0 } else { 0.0 };
            ok &= (dot - want).abs() <= 1e-9;
        }
    }
    let det = a * (e * k - f * h) - b * (d * k - f * g) + c * (d * h - e * g);
    ok && (det - 1.0).abs() <= 1e-9
}
