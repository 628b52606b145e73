//! The noise model's residual sums taken while the sums are gathered, without a residual
//! pass (docs/streaming.md, "One pass where the data allow").
//!
//! Each piece of a streamed group (the rows one thread read) fits a pilot: the widened fit
//! on its first [`PILOT_ROWS`] rows, at the rate its pass gathers sums about (nominal in
//! pass 1, the rate pass 1 fitted in a correcting pass). From then on every row's residual
//! from the pilot, r⁰, goes into lagged sums as it is read. The fitted model differs from
//! the pilot by Δ = cᵀV, V = (f, u·f, …): the wide columns and their first power of u at
//! that rate, and u²·(sin α, cos α) (the expansion in the rate's change to first order,
//! and to second for harmonic 1), so the residuals r = r⁰ − Δ have
//!
//! Σ r_k r_{k−l} = Σ r⁰_k r⁰_{k−l} − Σ r⁰_k Δ_{k−l} − Σ Δ_k r⁰_{k−l} + Σ Δ_k Δ_{k−l}.
//!
//! Δ at the row l back is Δ at the time τ_l back, τ_l the middle of the spans the piece's
//! rows l apart cover: V(t − τ) = Q(τ)·V(t) exactly, so the three corrections come from
//! Σ r⁰V and Σ V Vᵀ ([`Moments::pair_sums`]), less the rows at the piece's ends. Their
//! error is bounded from the data ([`corrected`]): the spread of the spans, the size of
//! Δ and its slope, and the expansion's remainder. When the bound is not far below the
//! lagged sums' own scatter, the residual pass runs as before.

use super::CLOCK;
use crate::fit::block::{self, Angles, Block, Vals, BLOCK, LANES};
use crate::fit::moments::{
    self, pair_row, wide_d, wide_row, Moments, PairSums, PAIR, TREND, WIDE, WIDE_HARMONIC,
};
use crate::fit::noise::{behind, LaggedSums, LAGS};
use nalgebra::Matrix2;
use nalgebra::{SMatrix, SVector};
use rotacal_shared::{Aperture, Channel, PhaseStep, Ticks};

/// Rows of a piece the pilot is fitted to (80 s at 104 Hz).
pub const PILOT_ROWS: usize = 8192;

/// The corrections' error bound may be at most this share of the lagged sums' own
/// standard error, γ₀·√N (and of the residual sum of squares' own, RSS·√(2/N)).
pub const KAPPA: f64 = 0.01;

type VecP = SVector<f64, PAIR>;
type MatP = SMatrix<f64, PAIR, PAIR>;

/// A row as read: its tick from the piece's first row and its readings.
type Row = (u64, [f64; 3]);

/// A piece's pilot, as pass 1 leaves it.
#[derive(Default)]
pub(super) enum Pilot {
    /// The first rows, until the pilot is fitted.
    Gathering(Vec<Row>),
    Running(Box<Run>),
    /// A row of several conversions, or a pilot that could not be fitted: the residual
    /// pass runs.
    #[default]
    Off,
}

/// The sums after the pilot is fitted.
pub(super) struct Run {
    beta: [[f64; WIDE]; 3],
    lagged: [LaggedSums; 3],
    /// The first LAGS rows, and the last LAGS (at `n mod LAGS`).
    head: Vec<Row>,
    tail: Vec<Row>,
    /// The newest LAGS ticks, each at two slots LAGS apart (as in [`LaggedSums`]).
    ticks: [f64; 2 * LAGS],
    pos: usize,
    /// The least and greatest span, in ticks, of rows l apart.
    lo: [f64; LAGS],
    hi: [f64; LAGS],
    n: usize,
}

/// A streamed group's rows one thread read: its sums from its own first row (about the
/// nominal step in pass 1, about pass 1's fitted step in a correcting pass), its pilot,
/// and its first row's tick from the group's.
pub(super) struct Piece {
    moments: Moments,
    pilot: Pilot,
    offset: u64,
}

/// A group's pilots on one thread: its own while it reads, and once the parts other
/// threads read are joined to it, each part's sums and pilot in file order.
#[derive(Default)]
pub(super) struct Pilots {
    own: Pilot,
    parts: Vec<Piece>,
}

impl Pilots {
    /// Gathering its first rows, or (`on` false) off.
    pub fn new(on: bool) -> Self {
        Pilots {
            own: if on {
                Pilot::Gathering(Vec::new())
            } else {
                Pilot::Off
            },
            parts: Vec::new(),
        }
    }

    /// The next row, as [`Moments::add`] took it (`f`, what it gave back) into the sums
    /// `moments`.
    #[inline]
    pub fn add(&mut self, tick: u64, f: Option<&[f64; WIDE]>, y: [f64; 3], moments: &Moments) {
        self.own.add(tick, f, y, moments);
    }

    /// The same group read on by another thread: `later`, whose sums are `later_moments`
    /// and whose first row is `offset` ticks after this one's, follows this one's part
    /// (whose sums are `moments`).
    pub fn join(&mut self, moments: &Moments, later: Pilots, later_moments: &Moments, offset: u64) {
        self.own_part(moments);
        for mut piece in later.into_parts(later_moments) {
            piece.offset = piece.offset.saturating_add(offset);
            self.parts.push(piece);
        }
    }

    /// Each part's sums and pilot, every pilot fitted by now (a part shorter than
    /// [`PILOT_ROWS`] is fitted here); `moments` are this thread's own sums.
    pub fn into_pieces(self, moments: &Moments) -> Vec<Piece> {
        let mut parts = self.into_parts(moments);
        for piece in &mut parts {
            piece.pilot.finish(&piece.moments);
        }
        parts
    }

    fn into_parts(mut self, moments: &Moments) -> Vec<Piece> {
        self.own_part(moments);
        self.parts
    }

    /// This thread's own pilot as the first part, if no part has joined yet.
    fn own_part(&mut self, moments: &Moments) {
        if self.parts.is_empty() {
            self.parts.push(Piece {
                moments: moments.clone(),
                pilot: std::mem::take(&mut self.own),
                offset: 0,
            });
        }
    }
}

/// Add a row to a piece's sums `moments` and its `pilots`: a row of one conversion waits
/// in `block` and goes in with a block's rows ([`settle`]); one of several goes in at once,
/// after the rows waiting.
#[inline]
pub(super) fn feed(
    moments: &mut Moments,
    pilots: &mut Pilots,
    block: &mut Block,
    ap: &Aperture,
    y: [f64; 3],
) {
    if ap.len() == 1 {
        if block.push(ap.first().0, y) {
            settle(moments, pilots, block);
        }
        return;
    }
    settle(moments, pilots, block);
    let f = moments.add(ap, y);
    pilots.add(ap.first().0, f.as_ref(), y, moments);
}

/// The rows waiting in `block` into the sums and the pilots: a full block's together,
/// fewer one at a time. Before anything reads the sums.
pub(super) fn settle(moments: &mut Moments, pilots: &mut Pilots, block: &mut Block) {
    if block.is_full() {
        // On the widest vectors there are: the sums are the same on any (fit::block).
        pulp::Arch::new().dispatch(FullBlock {
            moments,
            pilot: &mut pilots.own,
            block,
        });
    } else {
        for (tick, y) in block.rows() {
            let f = moments.add(&Aperture::point(Ticks(tick)), y);
            pilots.add(tick, f.as_ref(), y, moments);
        }
    }
    block.clear();
}

/// A full block into a piece's sums and pilot, compiled for each instruction set
/// [`pulp`] dispatches to (everything it calls is inlined into it).
struct FullBlock<'a> {
    moments: &'a mut Moments,
    pilot: &'a mut Pilot,
    block: &'a Block,
}

impl pulp::WithSimd for FullBlock<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let angles = Angles::of(self.block, self.moments.step(), CLOCK);
        self.moments.add_block(self.block, &angles);
        self.pilot.add_block(self.block, &angles, self.moments);
    }
}

impl Pilot {
    /// [`Pilot::add`] of a full block of rows whose angles are `a`.
    #[inline(always)]
    fn add_block(&mut self, block: &Block, a: &Angles, moments: &Moments) {
        match self {
            Pilot::Running(run) => run.add_block(block, a),
            Pilot::Gathering(rows) => {
                rows.extend(block.rows());
                if rows.len() >= PILOT_ROWS {
                    self.start(moments);
                }
            }
            Pilot::Off => {}
        }
    }
}

impl Pilot {
    /// The next row: its tick, its wide columns at the step the piece's sums are about
    /// (`None` for a row of several conversions) and its readings; `moments` holds the
    /// piece's rows so far, this one included.
    #[inline]
    fn add(&mut self, tick: u64, f: Option<&[f64; WIDE]>, y: [f64; 3], moments: &Moments) {
        match (&mut *self, f) {
            (Pilot::Running(run), Some(f)) => run.add(tick, f, y),
            (Pilot::Gathering(rows), Some(_)) => {
                rows.push((tick, y));
                if rows.len() >= PILOT_ROWS {
                    self.start(moments);
                }
            }
            (Pilot::Off, _) => {}
            (_, None) => *self = Pilot::Off,
        }
    }

    /// Fit the pilot now if it is still gathering (a piece shorter than [`PILOT_ROWS`]).
    fn finish(&mut self, moments: &Moments) {
        if matches!(self, Pilot::Gathering(_)) {
            self.start(moments);
        }
    }

    /// Fit the pilot to the rows gathered (the piece's rows so far, whose sums `moments`
    /// holds), then take their residuals.
    fn start(&mut self, moments: &Moments) {
        let Pilot::Gathering(rows) = std::mem::take(self) else {
            return;
        };
        let step = moments.step();
        let Ok(beta) = moments::wide_betas(moments, &[None, None, None], step) else {
            return; // Off: the residual pass runs
        };
        let mut run = Run::new(beta);
        let hz = f64::from(CLOCK.hz());
        for (tick, y) in rows {
            let (s, c) = step.phase_at(Ticks(tick)).sin_cos::<f64>();
            run.add(tick, &wide_row(s.hi, c.hi, tick as f64 / hz), y);
        }
        *self = Pilot::Running(run);
    }
}

impl Run {
    /// A pilot of coefficients `beta` (per channel), before its first row.
    fn new(beta: [[f64; WIDE]; 3]) -> Box<Run> {
        Box::new(Run {
            beta,
            lagged: Default::default(),
            head: Vec::with_capacity(LAGS),
            tail: Vec::with_capacity(LAGS),
            ticks: [f64::NAN; 2 * LAGS],
            pos: 0,
            lo: [f64::INFINITY; LAGS],
            hi: [f64::NEG_INFINITY; LAGS],
            n: 0,
        })
    }

    #[inline]
    fn add(&mut self, tick: u64, f: &[f64; WIDE], y: [f64; 3]) {
        for ((acc, beta), yv) in self.lagged.iter_mut().zip(&self.beta).zip(y) {
            let pilot: f64 = f.iter().zip(beta).map(|(a, b)| a * b).sum();
            acc.add(yv - pilot, false);
        }
        // The spans of rows 1 … LAGS − 1 apart (NaN before the piece began: a comparison
        // with it is false). Selects, not f64::min and max, whose NaN rules cost a third
        // of this loop.
        let t = tick as f64;
        self.pos = (self.pos + LAGS - 1) % LAGS;
        for slot in [self.pos, self.pos + LAGS] {
            if let Some(w) = self.ticks.get_mut(slot) {
                *w = t;
            }
        }
        if let Some(older) = self.ticks.get(self.pos..self.pos + LAGS) {
            for ((lo, hi), w) in self.lo.iter_mut().zip(self.hi.iter_mut()).zip(older) {
                let d = t - w;
                *lo = if d < *lo { d } else { *lo };
                *hi = if d > *hi { d } else { *hi };
            }
        }
        if self.head.len() < LAGS {
            self.head.push((tick, y));
        }
        if self.tail.len() < LAGS {
            self.tail.push((tick, y));
        } else if let Some(slot) = self.tail.get_mut(self.n % LAGS) {
            *slot = (tick, y);
        }
        self.n += 1;
    }
}

impl Run {
    /// [`Run::add`] of a full block of rows, whose angles at the piece's step are `a`:
    /// the residuals from the pilot row by row as [`Run::add`] takes them (to the bit),
    /// their lagged sums a block's dot products.
    #[inline(always)]
    fn add_block(&mut self, block: &Block, a: &Angles) {
        // The wide columns, as `wide_row` orders them.
        let one = [1.0; BLOCK];
        let [_, c1, c2, c3, c4, ..] = &a.cos;
        let [_, s1, s2, s3, s4, ..] = &a.sin;
        let f: [&Vals; WIDE] = [s1, c1, &one, &a.u, s2, c2, s3, c3, s4, c4];
        for ((acc, beta), y) in self.lagged.iter_mut().zip(&self.beta).zip(&block.y) {
            // Each row's pilot summed over the columns in their order, rows side by side.
            let mut pilot = [0.0; BLOCK];
            for (col, b) in f.iter().zip(beta) {
                for (p, x) in pilot.iter_mut().zip(col.iter()) {
                    *p += x * b;
                }
            }
            let mut r = [0.0; BLOCK];
            for ((r, y), p) in r.iter_mut().zip(y).zip(&pilot) {
                *r = y - p;
            }
            acc.add_block(&r);
        }
        // The spans of rows 1 … LAGS − 1 apart, the newest LAGS − 1 ticks (NaN before
        // the piece began: a comparison with it is false) in front of the block's.
        let ext = behind(&self.ticks, self.pos, block.tick.iter().map(|t| *t as f64));
        let now = ext.get(LAGS - 1..).unwrap_or(&[]);
        for (k, (lo, hi)) in self.lo.iter_mut().zip(self.hi.iter_mut()).enumerate() {
            let then = ext.get(LAGS - 1 - k..).unwrap_or(&[]);
            // In lanes (a least and a greatest each), then across them: selects, which
            // are one vector instruction each (f64::min and max add NaN's rules).
            let (mut l, mut h) = ([*lo; LANES], [*hi; LANES]);
            for (t, w) in block::lanes(now).zip(block::lanes(then)) {
                for (((l, h), t), w) in l.iter_mut().zip(h.iter_mut()).zip(t).zip(w) {
                    let d = t - w;
                    *l = if d < *l { d } else { *l };
                    *h = if d > *h { d } else { *h };
                }
            }
            for (l, h) in l.into_iter().zip(h) {
                *lo = if l < *lo { l } else { *lo };
                *hi = if h > *hi { h } else { *hi };
            }
        }
        self.pos = 0;
        for (k, t) in ext.iter().rev().take(LAGS).enumerate() {
            for slot in [k, k + LAGS] {
                if let Some(w) = self.ticks.get_mut(slot) {
                    *w = *t;
                }
            }
        }
        for (i, row) in block.rows().enumerate() {
            if self.head.len() < LAGS {
                self.head.push(row);
            }
            if self.tail.len() < LAGS {
                self.tail.push(row);
            } else if i + LAGS >= BLOCK {
                if let Some(slot) = self.tail.get_mut((self.n + i) % LAGS) {
                    *slot = row;
                }
            }
        }
        self.n += BLOCK;
    }
}

/// The fitted model a group's residuals are taken from, at the group's origin.
pub(super) struct Fitted<'a> {
    pub nominal: PhaseStep,
    pub fitted: PhaseStep,
    /// The fitted rate less the nominal, rad/s.
    pub eps: f64,
    /// The widened fit at the fitted rate, and the sine fits at the fitted and the
    /// nominal rate, per channel.
    pub wide: &'a [[f64; WIDE]; 3],
    pub sine_fitted: &'a [[f64; 3]; 3],
    pub sine_nominal: &'a [[f64; 3]; 3],
}

/// What a piece's corrected sums give for a channel, with the bounds of their errors.
pub(super) struct ChannelSums {
    pub lagged: LaggedSums,
    /// The sine fits' residual sums of squares at the fitted and the nominal rate.
    pub rss: [f64; 2],
    /// The bound on each lag's error, and on each residual sum of squares'.
    pub bound: [f64; LAGS],
    pub rss_bound: [f64; 2],
}

/// A piece's corrected sums, per channel.
pub(super) type PieceSums = [ChannelSums; 3];

/// The wide coefficients `b` of a model at `step` about the group's first row, moved to a
/// piece's first row `offset` ticks later (its own angle and time at that step): each
/// harmonic k turned by k times the phase at `offset`, the trend's value there added to
/// the constant.
fn moved(b: &[f64; WIDE], step: PhaseStep, offset: u64) -> [f64; WIDE] {
    let (s, c) = step.phase_at(Ticks(offset)).sin_cos::<f64>();
    let f = wide_row(s.hi, c.hi, 0.0); // sin kφ, cos kφ
    let mut out = *b;
    for (i, k) in WIDE_HARMONIC.iter().enumerate().step_by(2) {
        if *k == 0 {
            continue;
        }
        let (Some(a), Some(bc), Some(sk), Some(ck)) =
            (b.get(i), b.get(i + 1), f.get(i), f.get(i + 1))
        else {
            continue;
        };
        // A sin k(α + φ) + B cos k(α + φ) = (A cos kφ − B sin kφ) sin kα + (A sin kφ + B cos kφ) cos kα
        if let Some(x) = out.get_mut(i) {
            *x = a * ck - bc * sk;
        }
        if let Some(x) = out.get_mut(i + 1) {
            *x = a * sk + bc * ck;
        }
    }
    let u = offset as f64 / f64::from(CLOCK.hz());
    if let (Some(trend), Some(one)) = (b.get(TREND).copied(), out.get_mut(2)) {
        *one += trend * u;
    }
    out
}

/// The sine's (A, B, C) as wide coefficients.
fn widened(sine: &[f64; 3]) -> [f64; WIDE] {
    let mut out = [0.0; WIDE];
    for (o, x) in out.iter_mut().zip(sine) {
        *o = *x;
    }
    out
}

/// c for a model `model` (wide, at the piece's origin, its rate `eps` rad/s above
/// nominal) less the pilot `pilot`, by the expansion in εu: (model − pilot) on f,
/// ε·Dᵀ·model on u·f, and harmonic 1's second order, −ε²/2·(A, B), on u²·(sin α, cos α).
fn difference(model: &[f64; WIDE], pilot: &[f64; WIDE], eps: f64) -> VecP {
    let m = SVector::<f64, WIDE>::from(*model);
    let mut c = VecP::zeros();
    c.fixed_rows_mut::<WIDE>(0)
        .copy_from(&(m - SVector::<f64, WIDE>::from(*pilot)));
    c.fixed_rows_mut::<WIDE>(WIDE)
        .copy_from(&(wide_d().transpose() * m * eps));
    c.fixed_rows_mut::<2>(2 * WIDE)
        .copy_from(&(m.fixed_rows::<2>(0) * (-eps * eps / 2.0)));
    c
}

/// Q(τ): V(t − τ) = Q(τ)·V(t), for V at a step of `omega` rad/s, τ in seconds.
fn shift(tau: f64, omega: f64) -> MatP {
    let mut r = SMatrix::<f64, WIDE, WIDE>::zeros();
    for (i, k) in WIDE_HARMONIC.iter().enumerate().step_by(2) {
        if *k == 0 {
            continue;
        }
        let (s, c) = (f64::from(*k) * omega * tau).sin_cos();
        // sin k(α − θ) = sin kα cos kθ − cos kα sin kθ; cos k(α − θ) = cos kα cos kθ + sin kα sin kθ
        r.fixed_view_mut::<2, 2>(i, i)
            .copy_from(&Matrix2::new(c, -s, s, c));
    }
    // The constant (column 2) and the trend after it: u − τ.
    const _: () = assert!(TREND == 3);
    r.fixed_view_mut::<2, 2>(2, TREND - 1)
        .copy_from(&Matrix2::new(1.0, 0.0, -tau, 1.0));
    let mut q = MatP::zeros();
    q.fixed_view_mut::<WIDE, WIDE>(0, 0).copy_from(&r);
    q.fixed_view_mut::<WIDE, WIDE>(WIDE, WIDE).copy_from(&r);
    q.fixed_view_mut::<WIDE, WIDE>(WIDE, 0)
        .copy_from(&(r * -tau));
    // (u − τ)²·h(α − θ) = R(u²h) − 2τ·R(u·h) + τ²·R(h), h = (sin α, cos α).
    let r1 = r.fixed_view::<2, 2>(0, 0).into_owned();
    let w = 2 * WIDE;
    q.fixed_view_mut::<2, 2>(w, w).copy_from(&r1);
    q.fixed_view_mut::<2, 2>(w, WIDE)
        .copy_from(&(r1 * (-2.0 * tau)));
    q.fixed_view_mut::<2, 2>(w, 0)
        .copy_from(&(r1 * (tau * tau)));
    q
}

/// Bounds on |Δ| and |dΔ/du| over a piece of `span` s, for Δ = cᵀV at `omega` rad/s.
fn size_and_slope(c: &VecP, omega: f64, span: f64) -> (f64, f64) {
    let (mut size, mut slope) = (0.0, 0.0);
    for (i, k) in WIDE_HARMONIC.iter().enumerate() {
        let kw = f64::from(*k) * omega;
        let (m0, d0, m1, d1) = match i {
            2 => (1.0, 0.0, span, 1.0),                    // 1; u
            TREND => (span, 1.0, span * span, 2.0 * span), // u; u²
            _ => (1.0, kw, span, 1.0 + kw * span),         // h(kα); u·h(kα)
        };
        let (a, b) = (c[i].abs(), c[i + WIDE].abs());
        size += a * m0 + b * m1;
        slope += a * d0 + b * d1;
    }
    // u²·h(α).
    let a = c[2 * WIDE].abs() + c[2 * WIDE + 1].abs();
    size += a * span * span;
    slope += a * (2.0 * span + omega * span * span);
    (size, slope)
}

/// The expansion's remainder: a bound on |model(α + εu) − (the terms [`difference`]
/// keeps)| over a piece of `span` s: harmonic 1 from the third order, the others from
/// the second.
fn remainder(model: &[f64; WIDE], eps: f64, span: f64) -> f64 {
    let x = (eps * span).abs();
    WIDE_HARMONIC
        .iter()
        .zip(model)
        .map(|(k, b)| match k {
            0 => 0.0,
            1 => b.abs() * x * x * x / 6.0,
            _ => f64::from(k * k) * b.abs() * x * x / 2.0,
        })
        .sum()
}

/// A piece's lagged sums of the residuals from `fit`, and its sine fits' residual sums of
/// squares, from its pilot's sums: `None` when it has no running pilot or its rows are
/// not all single conversions.
pub(super) fn corrected(piece: &Piece, fit: &Fitted) -> Option<PieceSums> {
    let Pilot::Running(run) = &piece.pilot else {
        return None;
    };
    let PairSums { p, y, v } = piece.moments.pair_sums()?;
    let hz = f64::from(CLOCK.hz());
    // V is at the step the piece's sums were gathered about: nominal in pass 1, the rate
    // pass 1 fitted in a correcting pass.
    let basis = piece.moments.step();
    let omega = basis.to_hz(CLOCK) * std::f64::consts::TAU;
    let (eps_f, eps_n) = (
        piece.moments.eps(fit.fitted),
        piece.moments.eps(fit.nominal),
    );
    let n = run.n;
    if n == 0 || piece.moments.rows() != n as u64 {
        return None;
    }
    let span = run.tail.iter().map(|r| r.0).max().unwrap_or(0) as f64 / hz;
    // V and the pilot's residual of the first and the last LAGS rows (newest first).
    let row_v = |(tick, _): &Row| {
        let (s, c) = basis.phase_at(Ticks(*tick)).sin_cos::<f64>();
        VecP::from(pair_row(s.hi, c.hi, *tick as f64 / hz))
    };
    let newest: Vec<&Row> = (0..run.tail.len().min(n))
        .filter_map(|j| run.tail.get((n + LAGS - 1 - j) % LAGS))
        .collect();
    // The exact residual from the fitted model, as the residual pass takes it.
    let exact = |(tick, yv): &Row, ch: Channel| -> f64 {
        let ap = Aperture::point(Ticks(piece.offset.saturating_add(*tick)));
        let (w, _) = moments::wide_regressors(&ap, fit.fitted, (fit.nominal, fit.eps), CLOCK);
        let m: f64 = w.iter().zip(ch.of(fit.wide)).map(|(a, b)| a * b).sum();
        ch.of(yv) - m
    };
    // The spans' middles (τ) and half-widths (h), s; 0 for a lag no pair reached.
    let lags: Vec<(f64, f64)> = run
        .lo
        .iter()
        .zip(&run.hi)
        .enumerate()
        .map(|(l, (lo, hi))| {
            if l == 0 || lo > hi {
                (0.0, 0.0)
            } else {
                ((lo + hi) / 2.0 / hz, (hi - lo) / 2.0 / hz)
            }
        })
        .collect();
    let shifts: Vec<(MatP, MatP)> = lags
        .iter()
        .map(|(tau, _)| (shift(*tau, omega), shift(-*tau, omega)))
        .collect();
    let head_v: Vec<VecP> = run.head.iter().map(row_v).collect();
    let newest_v: Vec<VecP> = newest.iter().map(|r| row_v(r)).collect();
    let mut out = Vec::with_capacity(3);
    for ch in Channel::ALL {
        let (beta0, wide, sf, sn, acc) = (
            ch.of(&run.beta),
            ch.of(fit.wide),
            ch.of(fit.sine_fitted),
            ch.of(fit.sine_nominal),
            ch.of(&run.lagged),
        );
        let model = moved(wide, fit.fitted, piece.offset);
        let c = difference(&model, beta0, eps_f);
        let sine_f = moved(&widened(sf), fit.fitted, piece.offset);
        let gamma_f = difference(&sine_f, beta0, eps_f);
        let sine_n = moved(&widened(sn), fit.nominal, piece.offset);
        let gamma_n = difference(&sine_n, beta0, eps_n);
        // Σ r⁰V = Σ yV − Σ V fᵀ·β₀.
        let b0 = SVector::<f64, WIDE>::from(*beta0);
        let m = y.column(ch.index()).into_owned() - p.fixed_view::<PAIR, WIDE>(0, 0) * b0;
        let r0 = |r: &Row, vr: &VecP| -> f64 {
            let f: f64 = vr.iter().take(WIDE).zip(beta0).map(|(a, b)| a * b).sum();
            ch.of(&r.1) - f
        };
        let (s0, sum0) = acc.products();
        let [s00, ..] = s0;
        let s00 = s00.max(0.0);
        let root = (n as f64 * s00).sqrt();
        let (size, slope) = size_and_slope(&c, omega, span);
        let rem = remainder(&model, eps_f, span);
        let (mut prod, mut bound) = ([0.0; LAGS], [0.0; LAGS]);
        let (mut head_rv, mut head_vv, mut tail_rv) = (VecP::zeros(), MatP::zeros(), VecP::zeros());
        for l in 0..LAGS {
            if l > 0 {
                // Rows l − 1 from the start and from the end join the edges.
                if let (Some(r), Some(vr)) = (run.head.get(l - 1), head_v.get(l - 1)) {
                    head_rv += vr * r0(r, vr);
                    head_vv += vr * vr.transpose();
                }
                if let (Some(r), Some(vr)) = (newest.get(l - 1), newest_v.get(l - 1)) {
                    tail_rv += vr * r0(r, vr);
                }
            }
            let (Some((qb, qf)), Some((_, h)), Some(x0), Some(o), Some(bd)) = (
                shifts.get(l),
                lags.get(l),
                s0.get(l),
                prod.get_mut(l),
                bound.get_mut(l),
            ) else {
                continue;
            };
            let back = c.dot(&(qb * (m - head_rv)));
            let ahead = c.dot(&(qf * (m - tail_rv)));
            let both = c.dot(&((p - head_vv) * qb.transpose() * c));
            *o = x0 - back - ahead + both;
            let e = slope * h;
            *bd = 2.0 * (e + rem) * root + (e + 2.0 * rem) * size * n as f64 + rem * rem * n as f64;
        }
        let sum = sum0 - c.dot(&v);
        let head: Vec<f64> = run.head.iter().map(|r| exact(r, ch)).collect();
        let newest_e: Vec<f64> = newest.iter().map(|r| exact(r, ch)).collect();
        let rss = |g: &VecP| s00 - 2.0 * g.dot(&m) + g.dot(&(p * g));
        let rss = [rss(&gamma_f), rss(&gamma_n)];
        let rem = [
            remainder(&sine_f, eps_f, span),
            remainder(&sine_n, eps_n, span),
        ];
        let mut rss_bound = [0.0; 2];
        for ((b, r), e) in rss_bound.iter_mut().zip(rss).zip(rem) {
            *b = 2.0 * e * (n as f64 * r.max(0.0)).sqrt() + e * e * n as f64;
        }
        out.push(ChannelSums {
            lagged: LaggedSums::assembled(prod, sum, &head, &newest_e, n),
            rss,
            bound,
            rss_bound,
        });
    }
    out.try_into().ok()
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::indexing_slicing)]
mod tests {
    use super::{pair_row, shift, FullBlock, Pilot, Pilots, Run, VecP, CLOCK, LAGS};
    use crate::fit::block::{Angles, Block, BLOCK};
    use crate::fit::moments::{wide_row, Moments, WIDE};
    use rand::{Rng, SeedableRng};
    use rotacal_shared::{Aperture, PhaseStep, Ticks};

    /// Rows of one conversion at about 104 Hz (jittered by a few µs), at 0.25 Hz a sine
    /// of 10⁴ counts and noise on each channel: ticks from the first row, readings.
    fn rows(n: usize) -> Vec<(u64, [f64; 3])> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        (0..n)
            .map(|i| {
                let t = (i as f64 * 1e6 / 104.0).round() as u64 + rng.gen_range(0..5);
                let a = std::f64::consts::TAU * 0.25 * t as f64 * 1e-6;
                let y =
                    [1e4 * a.sin(), 1e4 * a.cos(), 500.0].map(|m| m + rng.gen_range(-20.0..20.0));
                (t, y)
            })
            .collect()
    }

    fn step() -> PhaseStep {
        PhaseStep::from_hz(0.25, CLOCK).unwrap()
    }

    /// `rows` into sums and a pilot a block at a time, each full block summed by `full`
    /// (on one instruction set), the rows left over one at a time.
    fn in_blocks(rows: &[(u64, [f64; 3])], full: impl Fn(FullBlock)) -> (Moments, Pilots) {
        let (mut m, mut p, mut b) = (
            Moments::new(step(), CLOCK),
            Pilots::new(true),
            Block::default(),
        );
        for (t, y) in rows {
            if b.push(*t, *y) {
                full(FullBlock {
                    moments: &mut m,
                    pilot: &mut p.own,
                    block: &b,
                });
                b.clear();
            }
        }
        super::settle(&mut m, &mut p, &mut b);
        (m, p)
    }

    fn running(p: &Pilots) -> &Run {
        match &p.own {
            Pilot::Running(run) => run,
            _ => panic!("the pilot is not running"),
        }
    }

    /// A block's sums do not depend on the vectors the processor has: the same bits from
    /// the widest instruction set here and from scalar code.
    #[test]
    fn a_block_is_summed_the_same_on_every_instruction_set() {
        let rows = rows(3 * 8192 + 100);
        let (m, p) = in_blocks(&rows, |op| pulp::Arch::new().dispatch(op));
        let (ms, ps) = in_blocks(&rows, |op| pulp::Simd::vectorize(pulp::Scalar::new(), op));
        assert_eq!(format!("{m:?}"), format!("{ms:?}"));
        let (a, b) = (running(&p), running(&ps));
        assert_eq!(format!("{:?}", a.lagged), format!("{:?}", b.lagged));
        assert_eq!(
            (a.lo, a.hi, &a.head, &a.tail, a.n),
            (b.lo, b.hi, &b.head, &b.tail, b.n)
        );
        #[cfg(target_arch = "x86_64")]
        if let Some(v3) = pulp::x86::V3::try_new() {
            let (m3, _) = in_blocks(&rows, |op| pulp::Simd::vectorize(v3, op));
            assert_eq!(format!("{m:?}"), format!("{m3:?}"));
        }
    }

    /// In blocks, the sums are those of the rows one at a time but for the order of the
    /// additions: each within twice the bound of its rounding in order, 2·n·ε·Σ|terms|
    /// (Σ|v_i v_j| ≤ √(Σv_i² Σv_j²)).
    #[test]
    fn blocks_sum_as_rows_do() {
        let rows = rows(5 * BLOCK + 17);
        let (blocks, _) = in_blocks(&rows, |op| pulp::Arch::new().dispatch(op));
        let mut one = Moments::new(step(), CLOCK);
        for (t, y) in &rows {
            one.add(&Aperture::point(Ticks(*t)), *y);
        }
        let (a, b) = (blocks.pair_sums().unwrap(), one.pair_sums().unwrap());
        let bound = 2.0 * rows.len() as f64 * f64::EPSILON;
        let yy: [f64; 3] = [0, 1, 2].map(|c| rows.iter().map(|(_, y)| y[c] * y[c]).sum());
        for i in 0..a.p.nrows() {
            for j in 0..a.p.ncols() {
                let scale = (b.p[(i, i)] * b.p[(j, j)]).sqrt();
                assert!(
                    (a.p[(i, j)] - b.p[(i, j)]).abs() <= bound * scale,
                    "p[{i}][{j}]"
                );
            }
            for (c, yy) in yy.iter().enumerate() {
                let scale = (b.p[(i, i)] * yy).sqrt();
                assert!(
                    (a.y[(i, c)] - b.y[(i, c)]).abs() <= bound * scale,
                    "y[{i}][{c}]"
                );
            }
        }
    }

    /// A pilot's block of rows leaves what its rows one at a time leave: the same spans,
    /// first and last rows (exactly) and lagged sums (within 2·n·ε·Σr², as above).
    #[test]
    fn a_pilot_takes_a_block_as_its_rows() {
        let rows = rows(7 * BLOCK);
        let beta = [[3.0, -2.0, 1.0, 1e-3, 0.5, 0.25, -0.125, 0.0, 1.0, -1.0]; 3]
            .map(|b: [f64; WIDE]| b.map(|x| x * 1e4));
        let (mut by_block, mut by_row) = (Run::new(beta), Run::new(beta));
        for chunk in rows.chunks(BLOCK) {
            let mut b = Block::default();
            for (t, y) in chunk {
                b.push(*t, *y);
            }
            by_block.add_block(&b, &Angles::of(&b, step(), CLOCK));
        }
        for (t, y) in &rows {
            let (s, c) = step().phase_at(Ticks(*t)).sin_cos::<f64>();
            by_row.add(
                *t,
                &wide_row(s.hi, c.hi, *t as f64 / f64::from(CLOCK.hz())),
                *y,
            );
        }
        let (a, b) = (&by_block, &by_row);
        assert_eq!(
            (a.lo, a.hi, &a.head, &a.tail, a.n),
            (b.lo, b.hi, &b.head, &b.tail, b.n)
        );
        assert!(a
            .lo
            .iter()
            .zip(&a.hi)
            .skip(1)
            .all(|(l, h)| l.is_finite() && h >= l));
        let bound = 2.0 * rows.len() as f64 * f64::EPSILON;
        for (x, y) in a.lagged.iter().zip(&b.lagged) {
            let ((px, sx), (py, sy)) = (x.products(), y.products());
            assert_eq!(x.counts(), y.counts());
            for k in 0..LAGS {
                assert!((px[k] - py[k]).abs() <= bound * py[0], "lag {k}");
            }
            assert!((sx - sy).abs() <= bound * (py[0] * rows.len() as f64).sqrt());
        }
    }

    /// V(t − τ) = Q(τ)·V(t): the shift is exact, the one approximation being the τ used.
    #[test]
    fn the_shift_moves_v_back_in_time() {
        let omega = 1.7;
        for (u, tau) in [(0.0, 0.3), (12.5, -0.0961), (3600.0, 0.3077), (77.0, 0.0)] {
            let at = |u: f64| {
                let (s, c) = (omega * u).sin_cos();
                VecP::from(pair_row(s, c, u))
            };
            let moved = shift(tau, omega) * at(u);
            let want = at(u - tau);
            for (a, b) in moved.iter().zip(want.iter()) {
                assert!(
                    (a - b).abs() <= 1e-9 * (1.0 + u * u),
                    "{a} against {b} at u {u}"
                );
            }
        }
    }
}
