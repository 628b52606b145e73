//! The model the discrepancy workflow fits to a rotation recording, and its fit.
//!
//! Channel j in group g (condition c at nominal rate f, ω = 2πf), τ seconds into the group,
//! at session time t and temperature T (docs/discrepancy.md, the same physics as
//! docs/simulator.md):
//!
//! ```text
//! φ = ω(1 + δ)τ
//! a = (A_gj sin φ + B_gj cos φ)/s_j + b_cj ω²/s_j                acceleration along the axis
//! y = s_j (a + K2_j a² + K3_j a³) + O_cj + D_j (t − t̄) + c_j (T − T̄), clipped to the rails
//! ```
//!
//! A and B are the amplitudes the linear sensitivity sees, so the intrinsic properties come
//! from them with every modelled effect taken out. s_j = √(Σ_c (A²+B²)_cj / 2g²) is the
//! channel's sensitivity from the current A, B (its Gram-form value). The baseline has
//! δ = b = K2 = K3 = D = c = 0 and no rails; each effect switches its parameters on.
//! O is per condition, shared by all rates (the baseline's "constant offsets").
//!
//! The fit is Gauss–Newton, channel by channel (QR of each channel's Jacobian), with the
//! one parameter shared by all channels, δ, solved through the Schur complement. It is
//! generalised least squares under each group's and channel's AR(p) noise model
//! ([`Data::noise`]) by prewhitening: the residuals and every Jacobian column of a group's
//! channel go through its filter (x_t − Σ φ_k x_{t−k})/σ_ε, so χ² is the sum of squared
//! whitened residuals, which has expectation equal to the whitened degrees of freedom.
//! A group's first p rows (no complete filter window) and the rows whose window touches
//! a reading the model puts at a rail (fixed by the rail: no residual degree of freedom)
//! are left out, and not counted in the degrees of freedom.

use crate::fit::batch::BatchError;
use crate::fit::noise::NoiseModel;
use nalgebra::{DMatrix, DVector};
use rotacal_shared::{Channel, Condition};
use std::f64::consts::TAU;

mod stream;
mod weights;
pub(super) use stream::{Triangle, Whitener};
pub use weights::{tested, Tested};

/// Why the model could not be fitted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ModelError {
    /// Not more rows than parameters.
    #[error("too few rows for the model")]
    TooFewRows,
    /// The Jacobian is (numerically) rank deficient: some effect is not determined. The
    /// cause is kept but not a `source`: its text would only repeat this one's.
    #[error("the model's parameters are not all determined by the data")]
    Undetermined(BatchError),
    /// [`Data::noise`] has no model for a group ([`super::data_from`] and
    /// [`Data::set_white`] give every group one).
    #[error("no noise model for group {group}, channel {}", channel.index())]
    NoNoiseModel {
        /// The group's place in [`Data::groups`].
        group: usize,
        /// The channel.
        channel: Channel,
    },
    /// An invariant of the fit failed: a bug in rotacal, not a problem of the data.
    #[error("internal: {0} (a bug in rotacal; please report it)")]
    Internal(&'static str),
}

/// The effects the workflow can add (formats.md names).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Effect {
    /// δ: the true rate is (1 + δ) times nominal (table or device clock).
    RateError,
    /// D_j: offsets change linearly in time.
    OffsetDrift,
    /// c_j: offsets change with temperature.
    TemperatureOffset,
    /// K2_j: y = s(a + K2 a²).
    Nonlinearity2nd,
    /// K3_j: y = s(a + K3 a³).
    Nonlinearity3rd,
    /// Readings clip at rails [low, high].
    Saturation,
    /// b_cj ω²: a constant centripetal acceleration at each rate (several rates only).
    Centripetal,
}

impl Effect {
    /// Every effect, in the order formats.md lists them.
    pub const ALL: [Effect; 7] = [
        Effect::RateError,
        Effect::OffsetDrift,
        Effect::TemperatureOffset,
        Effect::Nonlinearity2nd,
        Effect::Nonlinearity3rd,
        Effect::Saturation,
        Effect::Centripetal,
    ];

    /// The formats.md name.
    pub fn name(self) -> &'static str {
        match self {
            Effect::RateError => "rate_error",
            Effect::OffsetDrift => "offset_drift",
            Effect::TemperatureOffset => "temperature_offset",
            Effect::Nonlinearity2nd => "nonlinearity_2nd",
            Effect::Nonlinearity3rd => "nonlinearity_3rd",
            Effect::Saturation => "saturation",
            Effect::Centripetal => "centripetal",
        }
    }
}

/// One group's rows.
#[derive(Clone, Debug)]
pub struct GroupData {
    /// The platter axis.
    pub condition: Condition,
    /// Nominal rate, Hz.
    pub rate_hz: f64,
    /// Seconds into the group.
    pub tau: Vec<f64>,
    /// Session time minus the session's mean time, s.
    pub t: Vec<f64>,
    /// Temperature minus its mean, °C (zeros without a temp_c column).
    pub temp: Vec<f64>,
    /// Readings u, v, w.
    pub y: [Vec<f64>; 3],
}

impl GroupData {
    /// ω = 2πf, rad/s.
    pub fn omega(&self) -> f64 {
        TAU * self.rate_hz
    }

    /// The rows as channel `ch` sees them.
    fn rows(&self, ch: Channel) -> impl Iterator<Item = Row> + '_ {
        self.tau
            .iter()
            .zip(&self.t)
            .zip(&self.temp)
            .zip(ch.of(&self.y))
            .map(|(((&tau, &t), &temp), &y)| Row { tau, t, temp, y })
    }

    /// Whether every column has a value for each time (else [`GroupData::rows`] would
    /// stop short).
    fn complete(&self) -> bool {
        let n = self.tau.len();
        self.t.len() >= n && self.temp.len() >= n && self.y.iter().all(|y| y.len() >= n)
    }
}

/// One row of a group, as one channel sees it.
struct Row {
    /// Seconds into the group.
    tau: f64,
    /// Session time minus the session's mean time, s.
    t: f64,
    /// Temperature minus its mean, °C.
    temp: f64,
    /// The channel's reading.
    y: f64,
}

/// Channel `ch`'s element of a per-channel array, to change it ([`Channel::of`]).
fn of_channel_mut<T>(ch: Channel, per_channel: &mut [T; 3]) -> &mut T {
    let [u, v, w] = per_channel;
    match ch {
        Channel::U => u,
        Channel::V => v,
        Channel::W => w,
    }
}

/// A recording as the model sees it.
#[derive(Clone, Debug)]
pub struct Data {
    /// Groups in file order.
    pub groups: Vec<GroupData>,
    /// Local gravity, m/s².
    pub g_loc: f64,
    /// One sample's noise sd per channel over all groups (the root of the mean variance,
    /// weighted by rows), output units: for summaries.
    pub sigma: [f64; 3],
    /// The noise model per group and channel (u, v, w), held fixed through every fit.
    pub noise: Vec<[NoiseModel; 3]>,
    /// The generic fits the noise models come from, and the structure found in them.
    pub generic: super::structure::Generic,
}

/// A group's channel's rows through its noise filter: rows `t ≥ p` whose window
/// `t − p … t` holds no flagged reading become (x_t − Σ φ_k x_{t−k})/σ_ε; the others 0.
/// `keep[t]` says which rows were kept (a row without one is not). In place, from the end
/// (so x_{t−k} is still raw).
pub(super) fn whiten(m: &NoiseModel, x: &mut [f64], keep: &[bool]) {
    let w = 1.0 / m.innovation_var.sqrt().max(f64::MIN_POSITIVE);
    let (mut rest, beyond) = x.split_at_mut(keep.len().min(x.len()));
    beyond.fill(0.0);
    for &k in keep.iter().take(rest.len()).rev() {
        // The last row left, and the rows before it, still raw.
        let Some((now, before)) = std::mem::take(&mut rest).split_last_mut() else {
            break;
        };
        *now = if k {
            let mut v = *now;
            for (f, x) in m.ar.iter().zip(before.iter().rev()) {
                v -= f * x;
            }
            v * w
        } else {
            0.0
        };
        rest = before;
    }
}

/// Which whitened rows are kept: t ≥ p and no flagged reading in t − p … t.
pub(super) fn kept(p: usize, flagged: &[bool]) -> Vec<bool> {
    let mut last_flag: Option<usize> = None;
    flagged
        .iter()
        .enumerate()
        .map(|(t, &f)| {
            if f {
                last_flag = Some(t);
            }
            t >= p && last_flag.is_none_or(|l| t - l > p)
        })
        .collect()
}

/// Σ of squared whitened residuals and the rows kept (`r` is whitened in place). What a
/// reading flagged in `flagged` holds never counts: every window that touches it is left out.
pub(super) fn whitened_ss(m: &NoiseModel, r: &mut [f64], flagged: &[bool]) -> (f64, usize) {
    let keep = kept(m.order(), flagged);
    whiten(m, r, &keep);
    (
        r.iter().map(|v| v * v).sum(),
        keep.iter().filter(|&&k| k).count(),
    )
}

impl Data {
    /// White noise of sd `sigma[j]` on every group's channel j (for noise-free tests).
    pub fn set_white(&mut self, sigma: [f64; 3]) {
        self.sigma = sigma;
        self.noise = self
            .groups
            .iter()
            .map(|g| sigma.map(|s| NoiseModel::white(s * s, g.tau.len())))
            .collect();
    }

    /// Rows over all groups.
    pub fn rows(&self) -> usize {
        self.groups.iter().map(|g| g.tau.len()).sum()
    }

    /// Distinct nominal rates, ascending.
    pub fn rates(&self) -> Vec<f64> {
        let mut r: Vec<f64> = self.groups.iter().map(|g| g.rate_hz).collect();
        r.sort_by(f64::total_cmp);
        r.dedup();
        r
    }

    /// The temperature varies (its spread is more than 0.05 °C).
    pub fn temperature_varies(&self) -> bool {
        let (lo, hi) = self
            .groups
            .iter()
            .flat_map(|g| g.temp.iter())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| {
                (lo.min(x), hi.max(x))
            });
        hi - lo > 0.05
    }

    /// Readings sitting exactly at the lowest (highest) value of the file, if at least
    /// three do: the rails a saturating sensor clips to.
    pub fn rails(&self) -> [Option<f64>; 2] {
        let all = || self.groups.iter().flat_map(|g| g.y.iter().flatten());
        let lo = all().copied().fold(f64::INFINITY, f64::min);
        let hi = all().copied().fold(f64::NEG_INFINITY, f64::max);
        let count = |v: f64| all().filter(|&&x| x == v).count();
        [
            (count(lo) >= 3).then_some(lo),
            (count(hi) >= 3).then_some(hi),
        ]
    }
}

/// Parameter values.
#[derive(Clone, Debug, PartialEq)]
pub struct Params {
    /// (A, B) per group and channel.
    pub ab: Vec<[[f64; 2]; 3]>,
    /// O per condition (x, y, z) and channel.
    pub offset: [[f64; 3]; 3],
    /// b per condition and channel, output units per (rad/s)².
    pub centripetal: Option<[[f64; 3]; 3]>,
    /// K2 per channel, 1/(m/s²).
    pub k2: Option<[f64; 3]>,
    /// K3 per channel, 1/(m/s²)².
    pub k3: Option<[f64; 3]>,
    /// D per channel, output units per s.
    pub drift: Option<[f64; 3]>,
    /// c per channel, output units per °C.
    pub temp: Option<[f64; 3]>,
    /// δ.
    pub delta: Option<f64>,
    /// Rails [low, high] (±∞ where none).
    pub rails: Option<[f64; 2]>,
}

impl Params {
    /// The baseline with these effects switched on, at zero (rails from the data).
    fn new(data: &Data, effects: &[Effect]) -> Self {
        let on = |e| effects.contains(&e);
        let [lo, hi] = data.rails();
        Params {
            ab: vec![[[0.0; 2]; 3]; data.groups.len()],
            offset: [[0.0; 3]; 3],
            centripetal: on(Effect::Centripetal).then_some([[0.0; 3]; 3]),
            k2: on(Effect::Nonlinearity2nd).then_some([0.0; 3]),
            k3: on(Effect::Nonlinearity3rd).then_some([0.0; 3]),
            drift: on(Effect::OffsetDrift).then_some([0.0; 3]),
            temp: on(Effect::TemperatureOffset).then_some([0.0; 3]),
            delta: on(Effect::RateError).then_some(0.0),
            rails: on(Effect::Saturation)
                .then_some([lo.unwrap_or(f64::NEG_INFINITY), hi.unwrap_or(f64::INFINITY)]),
        }
    }

    /// The channel sensitivities s_j from A, B (Gram form; with several rates, the mean
    /// over rates).
    pub fn sensitivity(&self, data: &Data) -> [f64; 3] {
        let mut sum = [0.0; 3];
        for ab in &self.ab {
            for (sj, abj) in sum.iter_mut().zip(ab) {
                *sj += abj[0].powi(2) + abj[1].powi(2);
            }
        }
        let per_rate = data.rates().len().max(1) as f64;
        let g2 = data.g_loc * data.g_loc;
        sum.map(|sj| (sj / per_rate / (2.0 * g2)).sqrt().max(f64::MIN_POSITIVE))
    }

    /// The value of `param` for channel `ch`, if the model has it.
    fn slot_mut(&mut self, param: Param, ch: Channel) -> Option<&mut f64> {
        let per_channel = match param {
            Param::Amp { group, cos } => {
                let [a, b] = of_channel_mut(ch, self.ab.get_mut(group)?);
                return Some(if cos { b } else { a });
            }
            Param::Offset(c) => c.of_mut(&mut self.offset),
            Param::Centripetal(c) => c.of_mut(self.centripetal.as_mut()?),
            Param::K2 => self.k2.as_mut()?,
            Param::K3 => self.k3.as_mut()?,
            Param::Drift => self.drift.as_mut()?,
            Param::Temp => self.temp.as_mut()?,
        };
        Some(of_channel_mut(ch, per_channel))
    }
}

/// What one row of one channel predicts, and its derivatives.
struct Eval {
    y: f64,
    /// dy/da (per unit of a in m/s², times s).
    dyda: f64,
    a: f64,
    sin: f64,
    cos: f64,
    clipped: bool,
}

impl Eval {
    /// dy/dδ (the Jacobian's column for the rate error) with A, B `ab` at sensitivity `sj`,
    /// ω and τ; 0 for a reading at a rail (fixed by the rail).
    fn d_delta(&self, sj: f64, [a_amp, b_amp]: [f64; 2], (omega, tau): (f64, f64)) -> f64 {
        if self.clipped {
            return 0.0;
        }
        let h = self.dyda / sj; // dy/d(amplitude in output units)
        h * (a_amp * self.cos - b_amp * self.sin) * omega * tau
    }
}

/// Channel `ch`'s prediction at `row` of group `g`, whose A and B for the channel are
/// `ab`, at sensitivity `s`.
fn eval(p: &Params, s: f64, ab: [f64; 2], g: &GroupData, ch: Channel, row: &Row) -> Eval {
    eval_at(p, s, ab, g, ch, row, phase(p, g, row.tau))
}

/// sin φ and cos φ at `tau` seconds into group `g` (one for all three channels).
fn phase(p: &Params, g: &GroupData, tau: f64) -> (f64, f64) {
    let phi = g.omega() * (1.0 + p.delta.unwrap_or(0.0)) * tau;
    phi.sin_cos()
}

/// [`eval`] at the phase's sine and cosine ([`phase`]).
fn eval_at(
    p: &Params,
    s: f64,
    ab: [f64; 2],
    g: &GroupData,
    ch: Channel,
    row: &Row,
    (sin, cos): (f64, f64),
) -> Eval {
    let omega = g.omega();
    let [a_amp, b_amp] = ab;
    let c = g.condition;
    let a0 = p
        .centripetal
        .map_or(0.0, |b| *ch.of(c.of(&b)) * omega * omega / s);
    let a = (a_amp * sin + b_amp * cos) / s + a0;
    let k2 = p.k2.map_or(0.0, |k| *ch.of(&k));
    let k3 = p.k3.map_or(0.0, |k| *ch.of(&k));
    let mut y = s * (a + k2 * a * a + k3 * a * a * a) + *ch.of(c.of(&p.offset));
    y += p.drift.map_or(0.0, |d| *ch.of(&d) * row.t);
    y += p.temp.map_or(0.0, |t| *ch.of(&t) * row.temp);
    let mut clipped = false;
    if let Some([lo, hi]) = p.rails {
        if y <= lo || y >= hi {
            clipped = true;
            y = y.clamp(lo, hi);
        }
    }
    Eval {
        y,
        dyda: s * (1.0 + 2.0 * k2 * a + 3.0 * k3 * a * a),
        a,
        sin,
        cos,
        clipped,
    }
}

/// A channel's local parameter: what a column of its Jacobian is the derivative in.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Param {
    /// A group's A (`cos` false: with sin φ) or B (`cos` true: with cos φ).
    Amp { group: usize, cos: bool },
    /// O of a condition.
    Offset(Condition),
    /// b of a condition.
    Centripetal(Condition),
    /// K2.
    K2,
    /// K3.
    K3,
    /// D.
    Drift,
    /// c.
    Temp,
}

impl Param {
    /// Whether the parameter's column has values in group `g`'s rows (its place `gi`):
    /// where [`Param::derivative`] gives one.
    fn touches(self, g: &GroupData, gi: usize) -> bool {
        match self {
            Param::Amp { group, .. } => group == gi,
            Param::Offset(c) | Param::Centripetal(c) => c == g.condition,
            Param::K2 | Param::K3 | Param::Drift | Param::Temp => true,
        }
    }

    /// dy/d(this parameter) at `row` of group `g` (its place `gi`) with the prediction `e`
    /// at sensitivity `sj`: `None` where the parameter is another group's or condition's.
    fn derivative(self, g: &GroupData, gi: usize, sj: f64, row: &Row, e: &Eval) -> Option<f64> {
        let h = e.dyda / sj; // dy/d(amplitude in output units)
        let omega = g.omega();
        match self {
            Param::Amp { group, cos } => {
                (group == gi).then_some(h * if cos { e.cos } else { e.sin })
            }
            Param::Offset(c) => (c == g.condition).then_some(1.0),
            Param::Centripetal(c) => (c == g.condition).then_some(h * omega * omega),
            Param::K2 => Some(sj * e.a * e.a),
            Param::K3 => Some(sj * e.a * e.a * e.a),
            Param::Drift => Some(row.t),
            Param::Temp => Some(row.temp),
        }
    }
}

/// A channel's local parameters in the order of its Jacobian's columns: A and B of each
/// group (group gi's at 2gi and 2gi + 1), O of each condition in the order the groups
/// first show it, b of x, y and z, K2, K3, D and c: those the model has.
struct Layout {
    cols: Vec<Param>,
}

impl Layout {
    fn new(p: &Params, data: &Data) -> Self {
        let mut cols: Vec<Param> = (0..data.groups.len())
            .flat_map(|group| [false, true].map(|cos| Param::Amp { group, cos }))
            .collect();
        for g in &data.groups {
            if !cols.contains(&Param::Offset(g.condition)) {
                cols.push(Param::Offset(g.condition));
            }
        }
        if p.centripetal.is_some() {
            cols.extend(Condition::ALL.map(Param::Centripetal));
        }
        let on = [
            (p.k2.is_some(), Param::K2),
            (p.k3.is_some(), Param::K3),
            (p.drift.is_some(), Param::Drift),
            (p.temp.is_some(), Param::Temp),
        ];
        cols.extend(on.into_iter().filter_map(|(on, param)| on.then_some(param)));
        Layout { cols }
    }

    /// Parameters per channel.
    fn n(&self) -> usize {
        self.cols.len()
    }
}

/// A fitted model.
#[derive(Clone, Debug)]
pub struct Fit {
    /// The effects on.
    pub effects: Vec<Effect>,
    /// Values.
    pub params: Params,
    /// Standard uncertainties in the same shape (A, B, O, … and δ).
    pub unc: Params,
    /// Covariance of (A, B) per group and channel (for the intrinsic properties).
    pub ab_cov: Vec<[[[f64; 2]; 2]; 3]>,
    /// Σ of the squared whitened residuals over all rows and channels.
    pub chi2: f64,
    /// Whitened rows kept (rows × 3 less each group's first p rows per channel and those
    /// next to readings at a rail) − parameters.
    pub dof: f64,
    /// Parameters fitted.
    pub n_params: usize,
    /// Residual RMS per channel, output units.
    pub rms: [f64; 3],
}

impl Fit {
    /// χ²/dof.
    pub fn chi2_dof(&self) -> f64 {
        self.chi2 / self.dof
    }

    /// Residual RMS over all channels.
    pub fn rms_all(&self) -> f64 {
        (self.rms.iter().map(|r| r * r).sum::<f64>() / 3.0).sqrt()
    }

    /// Group `gi`'s residuals (reading less prediction) in channel `ch`, made again from
    /// the parameters when asked (a fit does not hold rows × 3 of them); empty for a group
    /// the data do not have.
    pub fn residuals(&self, data: &Data, gi: usize, ch: Channel) -> Vec<f64> {
        let s = self.params.sensitivity(data);
        residuals_of(data, &self.params, *ch.of(&s), gi, ch).0
    }
}

/// Group `gi`'s residuals in channel `ch` under `p` at sensitivity `sj`, and which readings
/// the model puts at a rail.
fn residuals_of(data: &Data, p: &Params, sj: f64, gi: usize, ch: Channel) -> (Vec<f64>, Vec<bool>) {
    let (Some(g), Some(ab)) = (data.groups.get(gi), p.ab.get(gi)) else {
        return (Vec::new(), Vec::new());
    };
    g.rows(ch)
        .map(|row| {
            let e = eval(p, sj, *ch.of(ab), g, ch, &row);
            (row.y - e.y, e.clipped)
        })
        .unzip()
}

/// Fit the model with `effects` on, starting from `start` where given.
pub fn fit(data: &Data, effects: &[Effect], start: Option<&Params>) -> Result<Fit, ModelError> {
    // The effects' derivatives vanish at A = B = 0: start them from the baseline's A, B.
    let base;
    let start = match start {
        None if !effects.is_empty() => {
            base = fit(data, &[], None)?;
            Some(&base.params)
        }
        s => s,
    };
    let mut p = Params::new(data, effects);
    if let Some(s) = start {
        p.ab.clone_from(&s.ab);
        p.offset = s.offset;
        let keep = |mine: &mut Option<[f64; 3]>, theirs: Option<[f64; 3]>| {
            if let (Some(m), Some(t)) = (mine.as_mut(), theirs) {
                *m = t;
            }
        };
        keep(&mut p.k2, s.k2);
        keep(&mut p.k3, s.k3);
        keep(&mut p.drift, s.drift);
        keep(&mut p.temp, s.temp);
        if let (Some(m), Some(t)) = (p.centripetal.as_mut(), s.centripetal) {
            *m = t;
        }
        if let (Some(m), Some(t)) = (p.delta.as_mut(), s.delta) {
            *m = t;
        }
    }
    if data.groups.iter().any(|g| !g.complete()) {
        return Err(ModelError::Internal(
            "a group's columns are shorter than its times",
        ));
    }
    if p.ab.len() < data.groups.len() {
        return Err(ModelError::Internal(
            "starting values for fewer groups than the data's",
        ));
    }
    let layout = Layout::new(&p, data);
    let n_rows = data.rows();
    if n_rows * 3 <= layout.n() * 3 + 1 {
        return Err(ModelError::TooFewRows);
    }
    let mut last_chi2 = f64::INFINITY;
    let mut result = None;
    for iter in 0..30 {
        let s = if iter == 0 && start.is_none() {
            [1.0; 3] // A, B start at 0: any scale gives the same linear solution
        } else {
            p.sensitivity(data)
        };
        let step = gauss_newton_step(data, &p, &layout, s)?;
        apply(&mut p, &layout, &step);
        let chi2 = step.chi2_before;
        let done = iter > 0 && (last_chi2 - chi2).abs() <= 1e-9 * chi2.max(1.0);
        last_chi2 = chi2;
        result = Some(step);
        if done && iter >= 2 {
            break;
        }
    }
    let step = result.ok_or(ModelError::Internal("the fit made no iteration"))?;
    let s = p.sensitivity(data);
    // Residuals and χ² (whitened) at the final parameters. Readings the model puts at a
    // rail are fixed by the rail, not fitted: no residual degree of freedom, and the
    // whitened rows whose window touches them are left out.
    let mut chi2 = 0.0;
    let mut ss = [0.0; 3];
    let mut used = 0usize;
    for gi in 0..data.groups.len() {
        for (ch, (ssj, sj)) in Channel::ALL.into_iter().zip(ss.iter_mut().zip(s)) {
            let (mut r, clipped) = residuals_of(data, &p, sj, gi, ch);
            *ssj += r.iter().map(|v| v * v).sum::<f64>();
            let m = noise_of(data, gi, ch)?;
            let (c, n) = whitened_ss(m, &mut r, &clipped);
            chi2 += c;
            used += n;
        }
    }
    let n_params = layout.n() * 3 + usize::from(p.delta.is_some());
    let dof = used as f64 - n_params as f64;
    let mut unc = Params::new(data, effects);
    let mut ab_cov = vec![[[[0.0; 2]; 2]; 3]; data.groups.len()];
    for (ch, cov) in Channel::ALL.into_iter().zip(&step.cov) {
        for (param, var) in layout.cols.iter().zip(cov.diagonal().iter()) {
            if let Some(x) = unc.slot_mut(*param, ch) {
                *x = var.max(0.0).sqrt();
            }
        }
        // Group gi's A and B are the layout's columns 2gi and 2gi + 1.
        let at = |i: usize, j: usize| {
            cov.get((i, j)).copied().ok_or(ModelError::Internal(
                "a group's A and B outside the covariance",
            ))
        };
        for (gi, c) in ab_cov.iter_mut().enumerate() {
            let (a, b) = (2 * gi, 2 * gi + 1);
            *of_channel_mut(ch, c) = [[at(a, a)?, at(a, b)?], [at(b, a)?, at(b, b)?]];
        }
    }
    unc.delta = step.delta_var.map(|v| v.max(0.0).sqrt());
    Ok(Fit {
        effects: effects.to_vec(),
        params: p,
        unc,
        ab_cov,
        chi2,
        dof,
        n_params,
        rms: ss.map(|ssj| (ssj / n_rows as f64).sqrt()),
    })
}

/// Group `gi`'s channel `ch`'s noise model.
fn noise_of(data: &Data, gi: usize, ch: Channel) -> Result<&NoiseModel, ModelError> {
    data.noise
        .get(gi)
        .map(|m| ch.of(m))
        .ok_or(ModelError::NoNoiseModel {
            group: gi,
            channel: ch,
        })
}

/// One Gauss–Newton increment and the covariance at the current point.
struct Step {
    local: [DVector<f64>; 3],
    delta: Option<f64>,
    cov: [DMatrix<f64>; 3],
    delta_var: Option<f64>,
    chi2_before: f64,
}

fn gauss_newton_step(data: &Data, p: &Params, l: &Layout, s: [f64; 3]) -> Result<Step, ModelError> {
    let with_delta = p.delta.is_some();
    let q = l.n();
    // Per channel: R of the whitened [Jacobian | z | r] (a triangle of q + 2 columns, its
    // last two columns Qᵀz and Qᵀr above the residual parts), gathered group by group
    // ([`factor_group`]): no Q is formed, and no group's rows are held.
    let mut tris = [q, q, q].map(|q| Triangle::new(q + 2));
    let mut chi2 = 0.0;
    for gi in 0..data.groups.len() {
        let (group_tris, rr_sum) = factor_group(data, p, l, s, gi)?;
        chi2 += rr_sum;
        for (tri, g) in tris.iter_mut().zip(&group_tris) {
            tri.push_matrix(g);
        }
    }
    let mut chans = Vec::with_capacity(3);
    let mut zz = 0.0;
    let mut zr = 0.0;
    for tri in tris {
        let aug = tri.finish();
        let at = |i: usize, j: usize| aug.get((i, j)).copied().unwrap_or(0.0);
        if with_delta {
            // z less its projection on the Jacobian has norm |α| = |R[q, q]|, and its dot
            // with r's own such part is α·R[q, q + 1].
            let alpha = at(q, q);
            zz += alpha * alpha;
            zr += alpha * at(q, q + 1);
        }
        let rr = aug.view((0, 0), (q, q)).into_owned();
        let qz = aug.view((0, q), (q, 1)).into_owned();
        let qr = aug.view((0, q + 1), (q, 1)).into_owned();
        chans.push((rr, qz, qr));
    }
    let delta = with_delta.then(|| if zz > 0.0 { zr / zz } else { 0.0 });
    let delta_var = with_delta.then(|| if zz > 0.0 { 1.0 / zz } else { f64::INFINITY });
    let mut local: [DVector<f64>; 3] = Default::default();
    let mut cov: [DMatrix<f64>; 3] = Default::default();
    for (((rr, qz, qr), local), cov) in chans.into_iter().zip(&mut local).zip(&mut cov) {
        let rhs = match delta {
            Some(d) => &qr - &qz * d,
            None => qr,
        };
        let mut cj = crate::fit::batch::unscaled_cov(&rr).map_err(ModelError::Undetermined)?;
        // The solves fail on a zero on R's diagonal, which unscaled_cov refuses first.
        let singular = ModelError::Undetermined(BatchError::Singular);
        let beta = rr
            .solve_upper_triangular(&rhs)
            .ok_or_else(|| singular.clone())?;
        if let Some(v) = delta_var {
            let wv = rr.solve_upper_triangular(&qz).ok_or(singular)?;
            cj += &wv * wv.transpose() * v;
        }
        *local = DVector::from_column_slice(beta.as_slice());
        *cov = cj;
    }
    Ok(Step {
        local,
        delta,
        cov,
        delta_var,
        chi2_before: chi2,
    })
}

/// Group `gi`'s rows of each channel's whitened system [X | z | r], reduced to a triangle
/// as they stream past (sin φ and cos φ once per row for the three channels), over the
/// columns the group's rows touch, then spread into the layout's q + 2 columns; and Σ r²
/// of the whitened residuals over the three channels.
fn factor_group(
    data: &Data,
    p: &Params,
    l: &Layout,
    s: [f64; 3],
    gi: usize,
) -> Result<([DMatrix<f64>; 3], f64), ModelError> {
    let missing = || ModelError::Internal("a group without data or parameters");
    let g = data.groups.get(gi).ok_or_else(missing)?;
    let ab = p.ab.get(gi).ok_or_else(missing)?;
    let with_delta = p.delta.is_some();
    let q = l.n();
    let omega = g.omega();
    // The layout's columns this group's rows touch (the others are zero in them), then z
    // (with δ) and r.
    let own: Vec<(usize, Param)> = (0..q)
        .zip(l.cols.iter().copied())
        .filter(|(_, c)| c.touches(g, gi))
        .collect();
    let w = own.len() + usize::from(with_delta) + 1;
    let models = Channel::ALL.map(|ch| noise_of(data, gi, ch));
    let [mu, mv, mw] = models;
    let models = [mu?, mv?, mw?];
    let mut whiteners = models.map(|m| Whitener::new(m, w));
    let mut tris = [w, w, w].map(Triangle::new);
    let mut rr_sum = 0.0;
    let (mut raw, mut out) = (vec![0.0; w], vec![0.0; w]);
    let rows = g.tau.iter().zip(&g.t).zip(&g.temp).enumerate();
    for (i, ((&tau, &t), &temp)) in rows {
        let sin_cos = phase(p, g, tau);
        let per_channel = whiteners.iter_mut().zip(&mut tris).zip(s);
        for (ch, ((whitener, tri), sj)) in Channel::ALL.into_iter().zip(per_channel) {
            let y = ch.of(&g.y).get(i).copied().ok_or_else(missing)?;
            let row = Row { tau, t, temp, y };
            let [a_amp, b_amp] = *ch.of(ab);
            let e = eval_at(p, sj, [a_amp, b_amp], g, ch, &row, sin_cos);
            let mut values = raw.iter_mut();
            for ((_, param), x) in own.iter().zip(values.by_ref()) {
                *x = match param.derivative(g, gi, sj, &row, &e) {
                    Some(v) if !e.clipped => v,
                    _ => 0.0,
                };
            }
            if with_delta {
                if let Some(x) = values.next() {
                    *x = e.d_delta(sj, [a_amp, b_amp], (omega, tau));
                }
            }
            if let Some(x) = values.next() {
                *x = y - e.y;
            }
            if whitener.push(&raw, e.clipped, &mut out) {
                let r = out.last().copied().unwrap_or(0.0);
                rr_sum += r * r;
                tri.push(&out);
            }
        }
    }
    // Each channel's triangle in the layout's columns: the group's own, z at q, r at q + 1.
    let spread = |tri: Triangle| {
        let local = tri.finish();
        let mut from = vec![None; q + 2];
        let targets = own
            .iter()
            .map(|(j, _)| *j)
            .chain(with_delta.then_some(q))
            .chain([q + 1]);
        for (k, to) in targets.enumerate() {
            if let Some(f) = from.get_mut(to) {
                *f = Some(k);
            }
        }
        DMatrix::from_fn(w, q + 2, |i, j| match from.get(j).copied().flatten() {
            Some(k) => local.get((i, k)).copied().unwrap_or(0.0),
            None => 0.0,
        })
    };
    Ok((tris.map(spread), rr_sum))
}

/// A channel's linearised model over every group's rows, prewhitened.
struct System {
    /// The Jacobian, column-major: a column of all rows per parameter of the layout.
    xs: Vec<f64>,
    /// The derivatives in δ.
    z: Vec<f64>,
    /// Per group, which whitened rows are kept ([`kept`]).
    keep: Vec<Vec<bool>>,
}

/// Channel `ch`'s [`System`] at sensitivity `sj`, each group's rows prewhitened by its
/// noise model (the slow-noise weights need every row's: [`weights`]).
fn whitened_system(
    data: &Data,
    p: &Params,
    l: &Layout,
    ch: Channel,
    sj: f64,
) -> Result<System, ModelError> {
    let n_rows = data.rows();
    let with_delta = p.delta.is_some();
    let mut xs = vec![0.0; n_rows * l.n()];
    let mut z = vec![0.0; n_rows];
    // The rows of each column and of z below the groups done.
    let mut cols: Vec<&mut [f64]> = xs.chunks_exact_mut(n_rows.max(1)).collect();
    let mut z_rest = z.as_mut_slice();
    let mut keeps = Vec::with_capacity(data.groups.len());
    for ((gi, g), ab) in data.groups.iter().enumerate().zip(&p.ab) {
        let omega = g.omega();
        let [a_amp, b_amp] = *ch.of(ab);
        let n = g.tau.len();
        let rows: Vec<(Row, Eval)> = g
            .rows(ch)
            .map(|row| {
                let e = eval(p, sj, [a_amp, b_amp], g, ch, &row);
                (row, e)
            })
            .collect();
        let zg = take_rows(&mut z_rest, n);
        for (zv, (row, e)) in zg.iter_mut().zip(&rows) {
            if with_delta {
                *zv = e.d_delta(sj, [a_amp, b_amp], (omega, row.tau));
            }
        }
        let clipped: Vec<bool> = rows.iter().map(|(_, e)| e.clipped).collect();
        // Prewhiten the group's rows of the residual and of every column.
        let m = noise_of(data, gi, ch)?;
        let keep = kept(m.order(), &clipped);
        if with_delta {
            whiten(m, zg, &keep);
        }
        for (col, param) in cols.iter_mut().zip(&l.cols) {
            let part = take_rows(col, n);
            for (x, (row, e)) in part.iter_mut().zip(&rows) {
                if !e.clipped {
                    if let Some(v) = param.derivative(g, gi, sj, row, e) {
                        *x = v;
                    }
                }
            }
            whiten(m, part, &keep);
        }
        keeps.push(keep);
    }
    Ok(System { xs, z, keep: keeps })
}

/// The first `n` entries of `rest` (all, if it has fewer), leaving it the others.
fn take_rows<'a>(rest: &mut &'a mut [f64], n: usize) -> &'a mut [f64] {
    let all = std::mem::take(rest);
    let (head, tail) = all.split_at_mut(n.min(all.len()));
    *rest = tail;
    head
}

fn apply(p: &mut Params, l: &Layout, st: &Step) {
    for (ch, b) in Channel::ALL.into_iter().zip(&st.local) {
        for (param, d) in l.cols.iter().zip(b.iter()) {
            if let Some(x) = p.slot_mut(*param, ch) {
                *x += d;
            }
        }
    }
    if let (Some(d), Some(x)) = (st.delta, p.delta.as_mut()) {
        *x += d;
    }
}
