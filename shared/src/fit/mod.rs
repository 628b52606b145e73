//! Streaming least-squares fit of `y = A sin α + B cos α + C` (plus optional terms) to
//! every channel of a triaxial record, with O(1) state and no sample buffer.
//!
//! # Form
//! The fit accumulates the normal equations: the information matrix `HᵀH` once for all
//! channels (they share regressors), and `Hᵀy` and `Σy²` per channel. Every product is
//! formed exactly (Dekker's TwoProd) and every sum kept in double-word form
//! ([`Accumulator`]). Exactness matters twice: the residual sum of squares
//! `Σy² − xᵀHᵀy` cancels from ~N·A² down to ~N·σ², which amplifies any rounding in the
//! sums by (A/σ)²/√N (in f32 at the LSM6DS33's SNR that would put σ̂ off by ~1 %); and
//! an hour of sums would otherwise drift. The system is solved only when a result is read out, by an equilibrated
//! Cholesky factorisation refined in double-word arithmetic. docs/method.md §6 explains why
//! not covariance-form RLS (erratic in f32) or Givens QR-RLS (loses accuracy over an
//! hour); docs/fit.md shows the measured accuracy.
//!
//! # Regressors
//! In this order, by [`Model`]: `sin α`, `cos α`, `1`, then `τ` (offset drift), then
//! `τ·sin α`, `τ·cos α` (linearised rotation-rate error), where α is the exact integer
//! [`Phase`](crate::Phase) at the sample's tick and τ is seconds since the first sample.
//! With any τ term, results are re-referenced to the record's centroid time
//! [`FitResult::t_ref`], where they are least correlated with the τ terms.

mod linalg;

use crate::dword::{Accumulator, DoubleWord, Split};
use crate::phase::PhaseStep;
use crate::real::Real;
use crate::time::{Aperture, TickRate, Ticks};
use linalg::{at, at_mut, el, el_mut, Cholesky, Mat, Vector};

/// Most parameters any [`Model`] has.
pub const MAX_PARAMS: usize = 6;
const PACKED: usize = MAX_PARAMS * (MAX_PARAMS + 1) / 2;
/// Samples between renormalisations of the running sums (see `Accumulator::renormalise`).
const RENORMALISE_EVERY: u32 = 64;

/// Which terms the fit has beyond `A sin α + B cos α + C`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Model {
    /// An offset drift `D·τ`.
    pub offset_drift: bool,
    /// Linearised rate error `E·τ·sin α + F·τ·cos α`: a phase that ramps because the
    /// true rotation rate (or the tick clock) differs from nominal.
    pub rate_error: bool,
}

/// A fit parameter, for looking it up in a [`ChannelFit`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Param {
    /// Coefficient of `sin α`.
    A,
    /// Coefficient of `cos α`.
    B,
    /// Constant offset.
    C,
    /// Offset drift, per second.
    D,
    /// Coefficient of `τ·sin α`, per second.
    E,
    /// Coefficient of `τ·cos α`, per second.
    F,
}

impl Model {
    /// The papers' model: `A sin α + B cos α + C`.
    pub const SINE: Model = Model {
        offset_drift: false,
        rate_error: false,
    };

    /// Number of parameters.
    pub const fn n_params(self) -> usize {
        3 + self.offset_drift as usize + 2 * self.rate_error as usize
    }

    /// Whether any regressor depends on τ.
    pub const fn has_time_terms(self) -> bool {
        self.offset_drift || self.rate_error
    }

    /// Position of `param` in the parameter vector, or `None` if the model lacks it.
    pub const fn index(self, param: Param) -> Option<usize> {
        let d = self.offset_drift as usize;
        match param {
            Param::A => Some(0),
            Param::B => Some(1),
            Param::C => Some(2),
            Param::D if self.offset_drift => Some(3),
            Param::E if self.rate_error => Some(3 + d),
            Param::F if self.rate_error => Some(4 + d),
            _ => None,
        }
    }

    /// The regressor row for one sample, in double word for the sine and cosine (whose
    /// rounding would repeat from period to period); τ never repeats, so its products
    /// need no more than `T`.
    #[inline(always)]
    fn regressors<T: Real>(
        self,
        s: DoubleWord<T>,
        c: DoubleWord<T>,
        tau: T,
    ) -> Vector<DoubleWord<T>> {
        let mut h = [DoubleWord::ZERO; MAX_PARAMS];
        let [h0, h1, h2, h3, h4, h5] = &mut h;
        let times = |x: DoubleWord<T>| DoubleWord {
            hi: tau * x.hi,
            lo: tau * x.lo,
        };
        *h0 = s;
        *h1 = c;
        *h2 = DoubleWord::from_t(T::ONE);
        match (self.offset_drift, self.rate_error) {
            (false, false) => {}
            (true, false) => *h3 = DoubleWord::from_t(tau),
            (false, true) => {
                *h3 = times(s);
                *h4 = times(c);
            }
            (true, true) => {
                *h3 = DoubleWord::from_t(tau);
                *h4 = times(s);
                *h5 = times(c);
            }
        }
        h
    }
}

/// What a fit is of.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FitConfig {
    /// Nominal rotation per tick.
    pub step: PhaseStep,
    /// The clock the timestamps count.
    pub clock: TickRate,
    /// Terms beyond the sine and offset.
    pub model: Model,
    /// Fewest rotation periods the record must span, in thousandths (default 1500: below
    /// about 1.5 periods the sine and offset are poorly separated, docs/method.md §5).
    pub min_milli_periods: u32,
}

impl FitConfig {
    /// The papers' 3-parameter model with the default minimum span.
    pub const fn sine(step: PhaseStep, clock: TickRate) -> FitConfig {
        FitConfig {
            step,
            clock,
            model: Model::SINE,
            min_milli_periods: 1500,
        }
    }
}

/// Why a sample was refused or a fit has no result. A refused sample leaves the fit as
/// it was.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FitError {
    /// A sample value was NaN or infinite (channel index).
    NonFiniteSample {
        /// 0-based channel index.
        channel: u8,
    },
    /// A sample value's magnitude exceeded [`Real::MAX_SAMPLE`] (channel index).
    SampleOutOfRange {
        /// 0-based channel index.
        channel: u8,
    },
    /// A timestamp was earlier than the one before it.
    TimeWentBackwards {
        /// Timestamp of the previous accepted sample.
        previous: Ticks,
        /// The refused timestamp.
        got: Ticks,
    },
    /// Not enough samples for the model's parameters and a residual.
    TooFewSamples {
        /// Samples accepted.
        n: u32,
        /// Samples needed.
        needed: u32,
    },
    /// The record spans too little of a rotation.
    TooFewPeriods {
        /// Span in thousandths of a period.
        milli_periods: u64,
        /// Span needed, in thousandths of a period.
        needed: u32,
    },
    /// The regressors are (nearly) linearly dependent: e.g. all samples at one angle.
    Singular,
    /// More samples than the counter holds (2³² − 1).
    Full,
    /// An internal index was out of range: a bug in rotacal; please report it.
    Internal,
}

impl core::fmt::Display for FitError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            FitError::NonFiniteSample { channel } => {
                write!(f, "sample of channel {channel} is not a finite number")
            }
            FitError::SampleOutOfRange { channel } => {
                write!(f, "sample of channel {channel} is implausibly large")
            }
            FitError::TimeWentBackwards { previous, got } => write!(
                f,
                "time went backwards: tick {} after tick {}",
                got.0, previous.0
            ),
            FitError::TooFewSamples { n, needed } => {
                write!(f, "too few samples: {n}, need at least {needed}")
            }
            FitError::TooFewPeriods {
                milli_periods,
                needed,
            } => write!(
                f,
                "record spans {}.{:03} rotation periods, need at least {}.{:03}",
                milli_periods / 1000,
                milli_periods % 1000,
                needed / 1000,
                needed % 1000
            ),
            FitError::Singular => write!(
                f,
                "singular fit: the samples do not determine every parameter"
            ),
            FitError::Full => write!(f, "fit holds the maximum number of samples"),
            FitError::Internal => write!(f, "internal error in the fit (a bug)"),
        }
    }
}

impl core::error::Error for FitError {}

/// The fit of one channel.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ChannelFit<T> {
    /// Parameters in [`Model`] order, in double-word precision; unused entries are zero.
    pub coef: [DoubleWord<T>; MAX_PARAMS],
    /// Standard errors `√(σ̂²·[(HᵀH)⁻¹]ᵢᵢ)`, as LINEST reports them.
    pub se: [T; MAX_PARAMS],
    /// Residual sum of squares.
    pub rss: T,
    /// σ̂ = √(RSS/(n − p)): the residual standard deviation the standard errors use.
    pub sigma: T,
    /// Residual RMS √(RSS/n).
    pub rms_residual: T,
}

impl<T: Real> ChannelFit<T> {
    const ZERO: Self = ChannelFit {
        coef: [DoubleWord::ZERO; MAX_PARAMS],
        se: [T::ZERO; MAX_PARAMS],
        rss: T::ZERO,
        sigma: T::ZERO,
        rms_residual: T::ZERO,
    };
}

/// A fit's result for every channel.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FitResult<T, const CH: usize = 3> {
    /// The model fitted.
    pub model: Model,
    /// Samples fitted.
    pub n: u32,
    /// Time of the first sample.
    pub t_first: Ticks,
    /// Time of the last sample.
    pub t_last: Ticks,
    /// Reference time of A, B, C when the model has τ terms (the samples' centroid);
    /// `None` for the 3-parameter model, whose parameters don't depend on it.
    pub t_ref: Option<Ticks>,
    /// `(HᵀH)⁻¹`, the covariance of the parameters per unit σ̂²; the same for every
    /// channel. Channel k's covariance is `σ̂ₖ²·unscaled_cov`.
    pub unscaled_cov: [[T; MAX_PARAMS]; MAX_PARAMS],
    /// Per channel, in input order.
    pub channels: [ChannelFit<T>; CH],
}

impl<T: Real, const CH: usize> FitResult<T, CH> {
    /// Parameter `param` of channel `ch`, if both exist.
    pub fn coef(&self, ch: usize, param: Param) -> Option<DoubleWord<T>> {
        let i = self.model.index(param)?;
        self.channels.get(ch)?.coef.get(i).copied()
    }

    /// Standard error of parameter `param` of channel `ch`, if both exist.
    pub fn se(&self, ch: usize, param: Param) -> Option<T> {
        let i = self.model.index(param)?;
        self.channels.get(ch)?.se.get(i).copied()
    }

    /// Covariance of parameters `a` and `b` of channel `ch`.
    pub fn covariance(&self, ch: usize, a: Param, b: Param) -> Option<T> {
        let (i, j) = (self.model.index(a)?, self.model.index(b)?);
        let s = self.channels.get(ch)?.sigma;
        Some(s * s * *self.unscaled_cov.get(i)?.get(j)?)
    }
}

/// The streaming fit. `CH` channels (3 for u, v, w) share the regressors.
#[derive(Clone, Debug)]
pub struct SineFit<T, const CH: usize = 3> {
    cfg: FitConfig,
    n: u32,
    t_first: Ticks,
    t_last: Ticks,
    /// Conversions in the samples (each sample's aperture length), for the centroid.
    conversions: u64,
    /// Upper triangle of HᵀH (weighted), row by row, over the model's parameters.
    info: [Accumulator<T>; PACKED],
    rhs: [[Accumulator<T>; MAX_PARAMS]; CH],
    yy: [Accumulator<T>; CH],
}

impl<T: Real, const CH: usize> SineFit<T, CH> {
    /// An empty fit.
    pub fn new(cfg: FitConfig) -> Self {
        SineFit {
            cfg,
            n: 0,
            t_first: Ticks(0),
            t_last: Ticks(0),
            conversions: 0,
            info: [Accumulator::ZERO; PACKED],
            rhs: [[Accumulator::ZERO; MAX_PARAMS]; CH],
            yy: [Accumulator::ZERO; CH],
        }
    }

    /// The configuration.
    pub fn config(&self) -> &FitConfig {
        &self.cfg
    }

    /// Samples accepted so far.
    pub fn len(&self) -> u32 {
        self.n
    }

    /// Whether no sample has been accepted.
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// Start again with the same configuration.
    pub fn reset(&mut self) {
        *self = Self::new(self.cfg);
    }

    /// Add one sample: its tick and one value per channel.
    pub fn update(&mut self, t: Ticks, y: [T; CH]) -> Result<(), FitError> {
        self.admit(t, &y, T::MAX_SAMPLE)?;
        let hs = self.row_at(t).map(|r| (Split::new(r.hi), r.lo));
        self.accumulate(&hs, &hs, y, None);
        self.advance(1, t);
        Ok(())
    }

    /// Add one averaged sample: the instants of the conversions it averages and, per
    /// channel, the *sum* of their readings (on the device an exact integer).
    ///
    /// Its expected value is `H·x` with `H` the sum of the conversions' regressor rows,
    /// each in double word from its exact integer phase; its variance under white
    /// conversion noise is `n·σ²`, so it is weighted by `1/n`. That is the weighted fit of
    /// the averages `Y/n` on the averaged regressors `H/n` with weights `n`, and σ̂ is the
    /// noise of one conversion. The weighted sums `Σ H·Hᵀ/n`, `Σ H·Y/n` and `Σ Y²/n` are
    /// formed from `G = H/n` in double word, so no product loses more than the
    /// unweighted fit's. An aperture of one is [`SineFit::update`].
    pub fn update_sum(&mut self, ap: &Aperture, y: [T; CH]) -> Result<(), FitError> {
        let count = ap.len() as u64;
        if count <= 1 {
            return self.update(ap.first(), y);
        }
        let w = T::from_u64(count);
        self.admit(ap.first(), &y, T::MAX_SAMPLE * w)?;
        let p = self.cfg.model.n_params();
        let mut h = self.row_at(ap.first());
        for ti in ap.ticks().skip(1) {
            for (a, r) in h.iter_mut().zip(self.row_at(ti)).take(p) {
                *a = *a + r;
            }
        }
        // (leading part split for exact products, trailing part)
        let hs = h.map(|r| (Split::new(r.hi), r.lo));
        let gs = h.map(|x| {
            let g = x.div_t(w);
            (Split::new(g.hi), g.lo)
        });
        self.accumulate(&gs, &hs, y, Some(w));
        self.advance(count, ap.last());
        Ok(())
    }

    /// Check a sample starting at `t` (values within `limit`) and take its time.
    #[inline(always)]
    fn admit(&mut self, t: Ticks, y: &[T; CH], limit: T) -> Result<(), FitError> {
        if let Some(channel) = y.iter().position(|v| !v.is_finite()) {
            return Err(FitError::NonFiniteSample {
                channel: u8::try_from(channel).unwrap_or(u8::MAX),
            });
        }
        if let Some(channel) = y.iter().position(|v| v.abs() > limit) {
            return Err(FitError::SampleOutOfRange {
                channel: u8::try_from(channel).unwrap_or(u8::MAX),
            });
        }
        if self.n > 0 && t < self.t_last {
            return Err(FitError::TimeWentBackwards {
                previous: self.t_last,
                got: t,
            });
        }
        if self.n == u32::MAX {
            return Err(FitError::Full);
        }
        if self.n == 0 {
            self.t_first = t;
        }
        Ok(())
    }

    /// The model's regressor row at tick `t`.
    #[inline(always)]
    fn row_at(&self, t: Ticks) -> Vector<DoubleWord<T>> {
        let model = self.cfg.model;
        let tau = if model.has_time_terms() {
            self.tau(t)
        } else {
            T::ZERO
        };
        let (s, c) = self.cfg.step.phase_at(t).sin_cos::<T>();
        model.regressors(s, c, tau)
    }

    /// One more sample of `count` conversions, its last at `t_last`.
    #[inline(always)]
    fn advance(&mut self, count: u64, t_last: Ticks) {
        self.n += 1;
        self.conversions = self.conversions.saturating_add(count);
        self.t_last = t_last;
        if self.n % RENORMALISE_EVERY == 0 {
            let sums = self.info.iter_mut().chain(self.yy.iter_mut());
            for acc in sums.chain(self.rhs.iter_mut().flatten()) {
                acc.renormalise();
            }
        }
    }

    /// Add `G·Hᵀ`, `G·y` and `y·y/w` (w = 1 when `None`, then `G = H`) to the sums, each
    /// product exact and summed in double word.
    #[inline(always)]
    fn accumulate(
        &mut self,
        gs: &Vector<(Split<T>, T)>,
        hs: &Vector<(Split<T>, T)>,
        y: [T; CH],
        w: Option<T>,
    ) {
        let p = self.cfg.model.n_params();
        let mut info = self.info.iter_mut();
        for (i, (gi, li)) in gs.iter().take(p).enumerate() {
            for (hj, lj) in hs.iter().take(p).skip(i) {
                if let Some(acc) = info.next() {
                    let (prod, err) = gi.two_prod(*hj);
                    acc.add_dw(prod, err + (gi.value() * *lj + *li * hj.value()));
                }
            }
        }
        for ((rhs, yy), yv) in self.rhs.iter_mut().zip(self.yy.iter_mut()).zip(y) {
            let ys = Split::new(yv);
            for (acc, (gv, lv)) in rhs.iter_mut().zip(gs).take(p) {
                let (prod, err) = gv.two_prod(ys);
                acc.add_dw(prod, err + *lv * yv);
            }
            match w {
                None => {
                    let (sq, err) = ys.two_prod(ys);
                    yy.add_dw(sq, err);
                }
                Some(w) => {
                    let q = DoubleWord::from_t(yv).div_t(w);
                    let (sq, err) = Split::new(q.hi).two_prod(ys);
                    yy.add_dw(sq, err + q.lo * yv);
                }
            }
        }
    }

    /// Seconds from the first sample to `t`, rounded to `T` the same way on every target.
    fn tau(&self, t: Ticks) -> T {
        let dt = t.since(self.t_first).unwrap_or(0);
        T::from_u64(dt) / T::from_u64(u64::from(self.cfg.clock.hz()))
    }

    /// Solve for the parameters of every channel. The fit can go on afterwards.
    pub fn solve(&self) -> Result<FitResult<T, CH>, FitError> {
        let model = self.cfg.model;
        let p = model.n_params();
        let p32 = p as u32;
        if self.n <= p32 {
            return Err(FitError::TooFewSamples {
                n: self.n,
                needed: p32 + 1,
            });
        }
        self.check_span()?;

        let mut m = [[DoubleWord::<T>::ZERO; MAX_PARAMS]; MAX_PARAMS];
        let mut packed = self.info.iter();
        for i in 0..p {
            for j in i..p {
                let v = packed.next().ok_or(FitError::Internal)?.value();
                *at_mut(&mut m, i, j)? = v;
                *at_mut(&mut m, j, i)? = v;
            }
        }
        let mut m_t: Mat<T> = [[T::ZERO; MAX_PARAMS]; MAX_PARAMS];
        for (row_t, row) in m_t.iter_mut().zip(m.iter()) {
            for (x, v) in row_t.iter_mut().zip(row.iter()) {
                *x = v.to_t();
            }
        }
        let chol = Cholesky::new(&m_t, p)?;
        let mut cov = linalg::refined_inverse(&m, &chol)?;

        let (t_ref, tau_ref) = if model.has_time_terms() {
            // Σ1·τ sits at (C, first τ term) = (2, 3) when there is a drift term; with
            // only the rate terms, use Σ sin²τ + cos²τ = Στ over (A,E) and (B,F).
            let sum_tau = if model.offset_drift {
                at(&m, 2, 3)?.to_f64()
            } else {
                at(&m, 0, 3)?.to_f64() + at(&m, 1, 4)?.to_f64()
            };
            // Both sums run over every conversion (weight 1/n times n conversions).
            let mean_ticks =
                sum_tau / self.conversions.max(1) as f64 * f64::from(self.cfg.clock.hz());
            let t_ref = Ticks(
                self.t_first
                    .0
                    .saturating_add(libm::round(mean_ticks) as u64),
            );
            (Some(t_ref), self.tau(t_ref))
        } else {
            (None, T::ZERO)
        };
        if model.has_time_terms() {
            recentre_cov(&mut cov, model, tau_ref)?;
        }

        let n_t = T::from_u64(u64::from(self.n));
        let dof = T::from_u64(u64::from(self.n - p32));
        let mut channels = [ChannelFit::ZERO; CH];
        for ((out, rhs), yy) in channels.iter_mut().zip(self.rhs.iter()).zip(self.yy.iter()) {
            let mut b = [DoubleWord::<T>::ZERO; MAX_PARAMS];
            for (bi, acc) in b.iter_mut().zip(rhs.iter()).take(p) {
                *bi = acc.value();
            }
            let x = linalg::refine(&m, &b, &chol)?;
            // At the solution, RSS = Σy² − xᵀ(Hᵀy); evaluated in double word, so the
            // cancellation of two ~N·A² terms down to ~N·σ² loses nothing that matters.
            let mut fitted = DoubleWord::ZERO;
            for (xi, bi) in x.iter().zip(b.iter()).take(p) {
                fitted = fitted + *xi * *bi;
            }
            let rss = (yy.value() - fitted).to_t();
            let rss = if rss > T::ZERO { rss } else { T::ZERO };
            let var = rss / dof;
            out.coef = if model.has_time_terms() {
                recentre_coef(x, model, tau_ref)?
            } else {
                x
            };
            for (i, se) in out.se.iter_mut().enumerate().take(p) {
                let c = at(&cov, i, i)?;
                *se = (var * if c > T::ZERO { c } else { T::ZERO }).sqrt();
            }
            out.rss = rss;
            out.sigma = var.sqrt();
            out.rms_residual = (rss / n_t).sqrt();
            // Inputs are bounded, so this should not happen; if it does, say so rather
            // than hand out NaN.
            let finite = out
                .coef
                .iter()
                .all(|c| c.hi.is_finite() && c.lo.is_finite())
                && out.se.iter().all(|s| s.is_finite())
                && out.sigma.is_finite();
            if !finite {
                return Err(FitError::Singular);
            }
        }
        Ok(FitResult {
            model,
            n: self.n,
            t_first: self.t_first,
            t_last: self.t_last,
            t_ref,
            unscaled_cov: cov,
            channels,
        })
    }

    fn check_span(&self) -> Result<(), FitError> {
        let span = self.t_last.since(self.t_first).unwrap_or(0);
        let turns = self.cfg.step.turns_x2_64(span); // turns · 2⁶⁴
        let milli = turns.checked_mul(1000).map(|x| x >> 64);
        let needed = u128::from(self.cfg.min_milli_periods);
        match milli {
            Some(m) if m < needed => Err(FitError::TooFewPeriods {
                milli_periods: u64::try_from(m).unwrap_or(u64::MAX),
                needed: self.cfg.min_milli_periods,
            }),
            _ => Ok(()),
        }
    }
}

/// Pairs (parameter, τ term whose coefficient moves it) when τ is shifted by τ_ref:
/// `C + D·τ = (C + D·τ_ref) + D·(τ − τ_ref)`, likewise A with E and B with F.
fn recentre_pairs(model: Model) -> [Option<(usize, usize)>; 3] {
    let pair = |a: Param, b: Param| Some((model.index(a)?, model.index(b)?));
    [
        pair(Param::A, Param::E),
        pair(Param::B, Param::F),
        pair(Param::C, Param::D),
    ]
}

fn recentre_coef<T: Real>(
    mut x: Vector<DoubleWord<T>>,
    model: Model,
    tau_ref: T,
) -> Result<Vector<DoubleWord<T>>, FitError> {
    for (i, k) in recentre_pairs(model).into_iter().flatten() {
        let shifted = el(&x, i)? + el(&x, k)?.mul_t(tau_ref);
        *el_mut(&mut x, i)? = shifted;
    }
    Ok(x)
}

/// `cov ← J·cov·Jᵀ` for the linear map of [`recentre_coef`].
fn recentre_cov<T: Real>(cov: &mut Mat<T>, model: Model, tau_ref: T) -> Result<(), FitError> {
    let pairs = recentre_pairs(model);
    for (i, k) in pairs.into_iter().flatten() {
        for j in 0..MAX_PARAMS {
            let v = at(cov, i, j)? + tau_ref * at(cov, k, j)?;
            *at_mut(cov, i, j)? = v;
        }
    }
    for (i, k) in pairs.into_iter().flatten() {
        for j in 0..MAX_PARAMS {
            let v = at(cov, j, i)? + tau_ref * at(cov, j, k)?;
            *at_mut(cov, j, i)? = v;
        }
    }
    Ok(())
}
