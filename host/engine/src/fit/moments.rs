//! The sufficient statistics of a record's sine fits, gathered in one pass without keeping
//! the rows, and the fits at any rate near the pass's own (docs/streaming.md).
//!
//! A pass fixes a phase step S₀ (the expansion point). At a nearby step S the angle of a
//! conversion at time u (s from the group's first row) is α + εu, with ε = (S − S₀)
//! rad/s exactly, so every regressor is a Taylor series in ε whose coefficients are sums
//! over the rows: for f(α) = (sin α, cos α, 1), f(α + εu) = Σ_m (εu)^m/m! · D^m f(α), D
//! the derivative in α. Gathering v_m = mean over the row's conversions of u^m·f(α) and
//! their cross products gives the normal equations at S, and the derivative in ε the IEEE
//! 1057 rate fit needs, with an error of order (εT)³ (T the record's length): to second
//! order for the sine (the rate fit and the budget's refits) and to first order for the
//! noise model's widened fit, whose residuals are taken in a second pass at the exact step.
//! [`Moments::within`] says whether a step is near enough for that.

use crate::fit::batch::BatchError;
use crate::fit::block::{self, Angles, Block, Vals, BLOCK, LANES};
use nalgebra::{DMatrix, Matrix3, SMatrix, SVector, Vector3};
use rotacal_shared::{Aperture, PhaseStep, TickRate, Ticks};
use std::f64::consts::TAU;

/// Columns of the widened fit: sin α, cos α, 1, a trend (u, s), then sin kα, cos kα for
/// k = 2, 3, 4 (the noise model's cleaning harmonics).
pub const WIDE: usize = 10;

/// The harmonic of each wide column (0 for the constant and the trend): its frequency in
/// multiples of the rotation's.
pub const WIDE_HARMONIC: [u32; WIDE] = [1, 1, 0, 0, 2, 2, 3, 3, 4, 4];

type M10 = SMatrix<f64, WIDE, WIDE>;
type X10 = SMatrix<f64, WIDE, 3>;

/// The rate of `a` less that of `b`, rad/s: exactly the difference of their phases per
/// second (steps are exact fractions of a turn per tick).
pub fn eps_between(a: PhaseStep, b: PhaseStep, clock: TickRate) -> f64 {
    // One step unit's rate is exact (a power of two times the clock), and so is d < 2⁵³.
    let d = a.0 as i128 - b.0 as i128;
    d as f64 * PhaseStep(1).to_hz(clock) * TAU
}

/// The widened regressors of one conversion at angle α (its sine and cosine `s`, `c`)
/// and time `u` s, in the order of [`WIDE_HARMONIC`] (harmonics by angle addition).
pub fn wide_row(s: f64, c: f64, u: f64) -> [f64; WIDE] {
    let (s2, c2) = (2.0 * s * c, c * c - s * s);
    let (s3, c3) = (s2 * c + c2 * s, c2 * c - s2 * s);
    let (s4, c4) = (2.0 * s2 * c2, c2 * c2 - s2 * s2);
    [s, c, 1.0, u, s2, c2, s3, c3, s4, c4]
}

/// D, the derivative in α, as a matrix on the wide columns: d/dα f = D f.
pub fn wide_d() -> M10 {
    // Row a, column b: how much of column b is in d/dα of column a.
    grid(&COLS, &COLS, |a, b| match (a, b) {
        (Col::Sin(k), Col::Cos(l)) if k == l => k as f64, // d/dα sin kα = k cos kα
        (Col::Cos(k), Col::Sin(l)) if k == l => -(k as f64), // d/dα cos kα = −k sin kα
        _ => 0.0,
    })
}

/// The matrix of `f(a, b)` for the columns `a` of its rows and `b` of its columns.
fn grid<const R: usize, const C: usize>(
    rows: &[Col; R],
    cols: &[Col; C],
    f: impl Fn(Col, Col) -> f64,
) -> SMatrix<f64, R, C> {
    SMatrix::from(cols.map(|b| rows.map(|a| f(a, b))))
}

/// [`grid`] of a function that may fail (`None` if `f` fails anywhere).
fn try_grid<const R: usize, const C: usize>(
    rows: &[Col; R],
    cols: &[Col; C],
    f: impl Fn(Col, Col) -> Option<f64>,
) -> Option<SMatrix<f64, R, C>> {
    let mut out = SMatrix::<f64, R, C>::zeros();
    for (mut row, a) in out.row_iter_mut().zip(rows) {
        for (x, b) in row.iter_mut().zip(cols) {
            *x = f(*a, *b)?;
        }
    }
    Some(out)
}

/// D on the sine fit's columns (sin α, cos α, 1).
fn sine_d() -> Matrix3<f64> {
    Matrix3::new(0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0)
}

/// The sums over a group's rows, each row weighted by its number of conversions (an
/// average of n conversions has variance σ²/n): see the module's documentation.
#[derive(Clone, Debug)]
pub struct Moments {
    /// The expansion point.
    step: PhaseStep,
    clock: TickRate,
    /// Rows and conversions so far.
    rows: u64,
    /// Σ n·v₀v₀ᵀ, Σ n·v₀v₁ᵀ over the wide columns.
    p00: M10,
    p01: M10,
    /// Σ n·v₀y, Σ n·v₁y (wide columns × channels).
    x0: X10,
    x1: X10,
    /// Second order, sine columns only: Σ n·v₀v₂ᵀ, v₁v₁ᵀ, v₁v₂ᵀ, v₂v₂ᵀ and Σ n·v₂y.
    p02: Matrix3<f64>,
    p11: Matrix3<f64>,
    p12: Matrix3<f64>,
    p22: Matrix3<f64>,
    x2: Matrix3<f64>,
    /// Σ n·y² per channel.
    yy: [f64; 3],
    /// The last tick seen: the record's extent for [`Moments::within`].
    t_max: u64,
    /// The rows of one conversion, as sums of u^p·cos mα, u^p·sin mα and u^p·g(α)·y:
    /// every product of two columns is one of these (see [`Harmonic`]).
    harm: Option<Box<Harmonic>>,
}

/// Sums over rows of one conversion (the usual row) from which every entry of the
/// dense sums follows by the product-to-sum formulas: Σ u^p cos mα and Σ u^p sin mα for
/// p ≤ 4 and m ≤ 8, and Σ u^p·g(α)·y for the columns' functions g (1, sin kα, cos kα,
/// k ≤ 4) and p ≤ 2. About half the operations of the dense sums per row.
#[derive(Clone, Debug, Default)]
struct Harmonic {
    cos: [[f64; 9]; 5],
    sin: [[f64; 9]; 5],
    /// [p][g][channel], g: 0 for 1, then sin kα and cos kα for k = 1 … 4 in turn.
    y: [[[f64; 3]; 9]; 3],
}

/// What a wide column is: its function of α and its power of u.
#[derive(Clone, Copy)]
enum Col {
    One(usize),
    Sin(usize),
    Cos(usize),
}

/// The wide columns (in the order of [`WIDE_HARMONIC`]).
const COLS: [Col; WIDE] = [
    Col::Sin(1),
    Col::Cos(1),
    Col::One(0),
    Col::One(1),
    Col::Sin(2),
    Col::Cos(2),
    Col::Sin(3),
    Col::Cos(3),
    Col::Sin(4),
    Col::Cos(4),
];

impl Harmonic {
    /// Σ u^e·a·b over the rows, for columns a and b: `None` if that needs a power of u or
    /// a harmonic beyond the sums (not for the columns and powers this module asks for).
    fn product(&self, a: Col, b: Col, e: usize) -> Option<f64> {
        let c = |p: usize, m: usize| self.cos.get(p)?.get(m).copied();
        let s = |p: usize, m: isize| {
            let v = *self.sin.get(p)?.get(m.unsigned_abs())?;
            Some(if m < 0 { -v } else { v })
        };
        Some(match (a, b) {
            (Col::One(pa), Col::One(pb)) => c(pa + pb + e, 0)?,
            (Col::One(pa), Col::Sin(l)) | (Col::Sin(l), Col::One(pa)) => s(pa + e, l as isize)?,
            (Col::One(pa), Col::Cos(l)) | (Col::Cos(l), Col::One(pa)) => c(pa + e, l)?,
            (Col::Sin(k), Col::Sin(l)) => (c(e, k.abs_diff(l))? - c(e, k + l)?) / 2.0,
            (Col::Cos(k), Col::Cos(l)) => (c(e, k.abs_diff(l))? + c(e, k + l)?) / 2.0,
            (Col::Sin(k), Col::Cos(l)) | (Col::Cos(l), Col::Sin(k)) => {
                (s(e, (k + l) as isize)? + s(e, k as isize - l as isize)?) / 2.0
            }
        })
    }

    /// Σ u^e·a·y over the rows, per channel (`None` as for [`Harmonic::product`]).
    fn with_y(&self, a: Col, e: usize) -> Option<[f64; 3]> {
        let (p, g) = match a {
            Col::One(pa) => (pa + e, 0),
            Col::Sin(k) => (e, (2 * k).checked_sub(1)?),
            Col::Cos(k) => (e, 2 * k),
        };
        self.y.get(p)?.get(g).copied()
    }

    /// Σ u^e·a·y over the rows for the columns `a` of `rows` (a row each), per channel
    /// (a column each).
    fn with_y_grid<const R: usize>(&self, rows: &[Col; R], e: usize) -> Option<SMatrix<f64, R, 3>> {
        let mut out = SMatrix::<f64, R, 3>::zeros();
        for (mut row, a) in out.row_iter_mut().zip(rows) {
            for (x, v) in row.iter_mut().zip(self.with_y(*a, e)?) {
                *x = v;
            }
        }
        Some(out)
    }

    /// Add a row of one conversion at angle (sin, cos) = (`s`, `c`), time `u`; its wide
    /// columns ([`wide_row`]'s, to the bit: the same products) come back.
    fn add(&mut self, s: f64, c: f64, u: f64, y: [f64; 3]) -> [f64; WIDE] {
        // cos mα, sin mα by the angle-sum formulas, in three rounds (2; 3, 4; 5 to 8)
        // rather than a chain of eight: each round's products wait only on the last.
        let turn =
            |(c1, s1): (f64, f64), (c2, s2): (f64, f64)| (c1 * c2 - s1 * s2, s1 * c2 + c1 * s2);
        let h1 = (c, s);
        let h2 = turn(h1, h1);
        let (h3, h4) = (turn(h2, h1), turn(h2, h2));
        let (h5, h6, h7, h8) = (turn(h4, h1), turn(h4, h2), turn(h4, h3), turn(h4, h4));
        let hs = [(1.0, 0.0), h1, h2, h3, h4, h5, h6, h7, h8];
        let (cm, sm) = (hs.map(|h| h.0), hs.map(|h| h.1));
        let pw = [1.0, u, u * u, u * u * u, u * u * u * u];
        // Only the sums [`Harmonic::product`] reads (the others stay 0): the wide columns
        // (harmonics to 4, u to the first power) meet at first order, and the pilot's
        // corrections (`calibrate::pilot`, [`Moments::pair_sums`]) need them at second and
        // harmonic 1 with u² against them, so harmonics 3 to 8 need u² and 3 to 5 need u³;
        // the sine's columns (harmonic 1, u⁰) go to fourth order, so harmonics 0 to 2 need
        // u⁴.
        fn powers<const M: usize>(c: &mut [f64; 9], s: &mut [f64; 9], p: f64, cs: &[[f64; 9]; 2]) {
            let [cm, sm] = cs;
            for ((a, b), (x, z)) in c
                .iter_mut()
                .zip(s.iter_mut())
                .zip(cm.iter().zip(sm))
                .take(M)
            {
                *a += p * x;
                *b += p * z;
            }
        }
        let cs = [cm, sm];
        let ([c0, c1, c2, c3, c4], [s0, s1, s2, s3, s4]) = (&mut self.cos, &mut self.sin);
        powers::<9>(c0, s0, pw[0], &cs);
        powers::<9>(c1, s1, pw[1], &cs);
        powers::<9>(c2, s2, pw[2], &cs);
        powers::<6>(c3, s3, pw[3], &cs);
        powers::<3>(c4, s4, pw[4], &cs);
        // With y: every column at first order, the sine's (1, sin α, cos α) at second.
        fn with_y<const G: usize>(rows: &mut [[f64; 3]; 9], p: f64, g: &[f64; 9], y: [f64; 3]) {
            for (acc, gv) in rows.iter_mut().zip(g).take(G) {
                let w = p * gv;
                for (a, v) in acc.iter_mut().zip(y) {
                    *a += w * v;
                }
            }
        }
        let g = [1.0, sm[1], cm[1], sm[2], cm[2], sm[3], cm[3], sm[4], cm[4]];
        let [y0, y1, y2] = &mut self.y;
        with_y::<9>(y0, pw[0], &g, y);
        with_y::<9>(y1, pw[1], &g, y);
        with_y::<3>(y2, pw[2], &g, y);
        [s, c, 1.0, u, sm[2], cm[2], sm[3], cm[3], sm[4], cm[4]]
    }
}

impl Harmonic {
    /// [`Harmonic::add`] of a full block's rows, each sum a block's dot product
    /// ([`block`]).
    #[inline(always)]
    fn add_block(&mut self, a: &Angles, y: &[Vals; 3]) {
        let u = &a.u;
        let mut pw = [[0.0; BLOCK]; 5];
        let [p0, p1, p2, p3, p4] = &mut pw;
        for (((((u, p0), p1), p2), p3), p4) in u
            .iter()
            .zip(p0.iter_mut())
            .zip(p1.iter_mut())
            .zip(p2.iter_mut())
            .zip(p3.iter_mut())
            .zip(p4.iter_mut())
        {
            (*p0, *p1, *p2, *p3, *p4) = (1.0, *u, u * u, u * u * u, u * u * u * u);
        }
        // The sums Harmonic::add keeps: harmonics 0 … 8 to u², 0 … 5 at u³, 0 … 2 at u⁴.
        // Every sum's lanes first, then their folds (block::dot_lanes).
        const KEPT: [usize; 5] = [9, 9, 9, 6, 3];
        let mut lanes = [[[[0.0; LANES]; 9]; 2]; 5];
        for ((p, [lc, ls]), m) in pw.iter().zip(lanes.iter_mut()).zip(KEPT) {
            for ((lc, ls), (cm, sm)) in lc
                .iter_mut()
                .zip(ls.iter_mut())
                .zip(a.cos.iter().zip(&a.sin))
                .take(m)
            {
                *lc = block::dot_lanes(p, cm);
                *ls = block::dot_lanes(p, sm);
            }
        }
        for (([lc, ls], (cos, sin)), m) in lanes
            .iter()
            .zip(self.cos.iter_mut().zip(self.sin.iter_mut()))
            .zip(KEPT)
        {
            for ((c, s), (lc, ls)) in cos
                .iter_mut()
                .zip(sin.iter_mut())
                .zip(lc.iter().zip(ls))
                .take(m)
            {
                *c += block::fold(*lc);
                *s += block::fold(*ls);
            }
        }
        let g = |k: usize| -> Option<&Vals> {
            match k {
                0 => a.cos.first(),
                _ if k % 2 == 1 => a.sin.get(k.div_ceil(2)),
                _ => a.cos.get(k / 2),
            }
        };
        // With y: [p][g][channel], g as `Harmonic::y` orders them.
        const WITH_Y: [usize; 3] = [9, 9, 3];
        let mut lanes = [[[[0.0; LANES]; 3]; 9]; 3];
        for ((p, rows), n) in pw.iter().zip(lanes.iter_mut()).zip(WITH_Y) {
            for (k, acc) in rows.iter_mut().enumerate().take(n) {
                let Some(gk) = g(k) else {
                    continue;
                };
                let mut w = [0.0; BLOCK];
                for ((w, p), gv) in w.iter_mut().zip(p).zip(gk) {
                    *w = p * gv;
                }
                for (acc, yc) in acc.iter_mut().zip(y) {
                    *acc = block::dot_lanes(&w, yc);
                }
            }
        }
        for ((rows, lanes), n) in self.y.iter_mut().zip(&lanes).zip(WITH_Y) {
            for (acc, lanes) in rows.iter_mut().zip(lanes).take(n) {
                for (a, l) in acc.iter_mut().zip(lanes) {
                    *a += block::fold(*l);
                }
            }
        }
    }
}

/// Σ V Vᵀ, Σ V·y (a column per channel) and Σ V over a group's rows, with
/// V = (f, u·f, u²·sin α, u²·cos α) and f the wide columns at the sums' step:
/// [`Moments::pair_sums`].
#[derive(Clone, Debug)]
pub struct PairSums {
    pub p: SMatrix<f64, PAIR, PAIR>,
    pub y: SMatrix<f64, PAIR, 3>,
    pub v: SVector<f64, PAIR>,
}

/// The trend's index among the wide columns.
pub const TREND: usize = 3;

/// The length of V = (f, u·f, u²·sin α, u²·cos α).
pub const PAIR: usize = 2 * WIDE + 2;

/// V of a conversion at angle (sin, cos) = (`s`, `c`) and time `u` s.
pub fn pair_row(s: f64, c: f64, u: f64) -> [f64; PAIR] {
    let f = wide_row(s, c, u);
    let mut v = [0.0; PAIR];
    let parts = f.iter().copied().chain(f.map(|x| u * x));
    for (a, x) in v.iter_mut().zip(parts.chain([u * u * s, u * u * c])) {
        *a = x;
    }
    v
}

/// The sine fit's normal equations at one step: Σ h hᵀ, Σ h dhᵀ and Σ dh dhᵀ (dh the
/// derivative in the rate, rad/s), Σ h·y and Σ dh·y per channel (columns), Σ y².
#[derive(Clone, Copy, Debug)]
pub struct SineNormal {
    /// Σ n·h hᵀ.
    pub g: Matrix3<f64>,
    /// Σ n·h dhᵀ.
    pub k: Matrix3<f64>,
    /// Σ n·dh dhᵀ.
    pub l: Matrix3<f64>,
    /// Σ n·h y (a column per channel).
    pub xh: Matrix3<f64>,
    /// Σ n·dh y (a column per channel).
    pub xd: Matrix3<f64>,
    /// Σ n·y² per channel.
    pub yy: [f64; 3],
    /// Rows.
    pub rows: u64,
}

impl Moments {
    /// Empty, expanded about `step` of a `clock`-tick clock.
    pub fn new(step: PhaseStep, clock: TickRate) -> Self {
        Moments {
            step,
            clock,
            rows: 0,
            p00: M10::zeros(),
            p01: M10::zeros(),
            x0: X10::zeros(),
            x1: X10::zeros(),
            p02: Matrix3::zeros(),
            p11: Matrix3::zeros(),
            p12: Matrix3::zeros(),
            p22: Matrix3::zeros(),
            x2: Matrix3::zeros(),
            yy: [0.0; 3],
            t_max: 0,
            harm: None,
        }
    }

    /// The last time seen, s.
    fn u_max(&self) -> f64 {
        self.t_max as f64 / f64::from(self.clock.hz())
    }

    /// The expansion point.
    pub fn step(&self) -> PhaseStep {
        self.step
    }

    /// Rows added.
    pub fn rows(&self) -> u64 {
        self.rows
    }

    /// ε of `step` relative to the expansion point, rad/s.
    pub fn eps(&self, step: PhaseStep) -> f64 {
        eps_between(step, self.step, self.clock)
    }

    /// |ε|·T for `step`: how far it is, in radians over the record, from the expansion
    /// point. The sine's normal equations carry an error of order (εT)³/6 relative, the
    /// widened fit's (εT)²/2.
    pub fn reach(&self, step: PhaseStep) -> f64 {
        (self.eps(step) * self.u_max()).abs()
    }

    /// Whether `step` is within `radius` (|ε|·T, rad) of the expansion point.
    pub fn within(&self, step: PhaseStep, radius: f64) -> bool {
        self.reach(step) <= radius
    }

    /// The per-conversion regressors of a row, averaged: v₀ (wide), v₁ (wide) and v₂
    /// (sine columns), and the conversion count.
    fn row_vectors(&self, ap: &Aperture) -> ([f64; WIDE], [f64; WIDE], [f64; 3], f64) {
        let hz = f64::from(self.clock.hz());
        let (mut v0, mut v1, mut v2) = ([0.0; WIDE], [0.0; WIDE], [0.0; 3]);
        for t in ap.ticks() {
            let (s, c) = self.step.phase_at(t).sin_cos::<f64>();
            let u = t.0 as f64 / hz;
            let f = wide_row(s.hi, c.hi, u);
            for ((a, b), x) in v0.iter_mut().zip(v1.iter_mut()).zip(f) {
                *a += x;
                *b += u * x;
            }
            for (a, x) in v2.iter_mut().zip(f) {
                *a += u * u * x;
            }
        }
        let n = ap.len().max(1) as f64;
        if n > 1.0 {
            for v in v0.iter_mut().chain(v1.iter_mut()).chain(v2.iter_mut()) {
                *v /= n;
            }
        }
        (v0, v1, v2, n)
    }

    /// Add a row: the conversions it averages (ticks from the group's first row) and its
    /// u, v, w. A row of one conversion gives back its wide columns at the step.
    pub fn add(&mut self, ap: &Aperture, y: [f64; 3]) -> Option<[f64; WIDE]> {
        if ap.len() == 1 {
            return Some(self.add_point(ap.first(), y));
        }
        let (v0, v1, v2, n) = self.row_vectors(ap);
        self.accumulate(&v0, &v1, &v2, n, y);
        self.rows += 1;
        // The latest time in ticks; its seconds (the same maximum) when asked.
        self.t_max = self.t_max.max(ap.last().0);
        None
    }

    /// Add a row of one conversion at tick `t`: [`Moments::add`] of its aperture.
    fn add_point(&mut self, t: Ticks, y: [f64; 3]) -> [f64; WIDE] {
        let hz = f64::from(self.clock.hz());
        let (s, c) = self.step.phase_at(t).sin_cos::<f64>();
        let f = self
            .harm
            .get_or_insert_with(Box::default)
            .add(s.hi, c.hi, t.0 as f64 / hz, y);
        for (a, v) in self.yy.iter_mut().zip(y) {
            *a += v * v;
        }
        self.rows += 1;
        self.t_max = self.t_max.max(t.0);
        f
    }

    /// [`Moments::add`] of a full block of rows of one conversion each, whose angles at
    /// the sums' step are `angles`.
    #[inline(always)]
    pub fn add_block(&mut self, block: &Block, angles: &Angles) {
        self.harm
            .get_or_insert_with(Box::default)
            .add_block(angles, &block.y);
        for (a, y) in self.yy.iter_mut().zip(&block.y) {
            *a += block::dot(y, y);
        }
        self.rows += block.len() as u64;
        self.t_max = block.tick.iter().fold(self.t_max, |m, t| m.max(*t));
    }

    /// With every row a single conversion (else `None`): the sums over the rows of
    /// V = (f, u·f, u²·sin α, u²·cos α), f the wide columns at the step, that the pilot's
    /// corrections take (`calibrate::pilot`).
    pub fn pair_sums(&self) -> Option<PairSums> {
        let h = self.harm.as_ref()?;
        // Σ 1 over the rows of one conversion: all of them, or some went to the dense sums.
        let [[ones, ..], ..] = h.cos;
        if ones != self.rows as f64 || self.rows == 0 {
            return None;
        }
        let mut out = PairSums {
            p: SMatrix::zeros(),
            y: SMatrix::zeros(),
            v: SVector::zeros(),
        };
        // Column and power of u of each entry of V, in order.
        let entries: Vec<(Col, usize)> = COLS
            .iter()
            .map(|a| (*a, 0))
            .chain(COLS.iter().map(|a| (*a, 1)))
            .chain([(Col::Sin(1), 2), (Col::Cos(1), 2)])
            .collect();
        let rows = out.p.row_iter_mut().zip(out.y.row_iter_mut());
        for (((mut p_row, mut y_row), v), (a, pa)) in rows.zip(out.v.iter_mut()).zip(&entries) {
            for (x, (b, pb)) in p_row.iter_mut().zip(&entries) {
                *x = h.product(*a, *b, pa + pb)?;
            }
            for (x, y) in y_row.iter_mut().zip(h.with_y(*a, *pa)?) {
                *x = y;
            }
            *v = h.product(*a, Col::One(0), *pa)?;
        }
        Some(out)
    }

    /// The same sums with the rows of one conversion folded into the dense ones.
    pub fn dense(&self) -> Moments {
        let mut m = self.clone();
        let Some(h) = m.harm.take() else {
            return m; // folded already, or no row of one conversion
        };
        if m.fold(&h).is_none() {
            // Not reached: the fold reads only sums `Harmonic::add` gathers. Were one
            // missing, sums of NaN make every fit from them fail rather than leave the
            // rows of one conversion out unseen.
            m.poison();
        }
        m
    }

    /// Add `h`'s sums to the dense ones (`None`, and nothing added, if `h` lacks one).
    fn fold(&mut self, h: &Harmonic) -> Option<()> {
        let wide = |e| try_grid(&COLS, &COLS, |a, b| h.product(a, b, e));
        let (p00, p01) = (wide(0)?, wide(1)?);
        let (x0, x1) = (h.with_y_grid(&COLS, 0)?, h.with_y_grid(&COLS, 1)?);
        // The sine's columns: sin α, cos α, 1.
        let [s1, c1, one, ..] = COLS;
        let sine = [s1, c1, one];
        let narrow = |e| try_grid(&sine, &sine, |a, b| h.product(a, b, e));
        let (q2, q3, q4) = (narrow(2)?, narrow(3)?, narrow(4)?);
        let x2 = h.with_y_grid(&sine, 2)?;
        self.p00 += p00;
        self.p01 += p01;
        self.x0 += x0;
        self.x1 += x1;
        self.p02 += q2;
        self.p11 += q2;
        self.p12 += q3;
        self.p22 += q4;
        self.x2 += x2;
        Some(())
    }

    /// Every dense sum NaN (see [`Moments::dense`]).
    fn poison(&mut self) {
        self.p00.fill(f64::NAN);
        self.p01.fill(f64::NAN);
        self.x0.fill(f64::NAN);
        self.x1.fill(f64::NAN);
        for m in [
            &mut self.p02,
            &mut self.p11,
            &mut self.p12,
            &mut self.p22,
            &mut self.x2,
        ] {
            m.fill(f64::NAN);
        }
    }

    /// Add a row's contributions, weighted by its `w` conversions.
    fn accumulate(
        &mut self,
        v0: &[f64; WIDE],
        v1: &[f64; WIDE],
        v2: &[f64; 3],
        w: f64,
        y: [f64; 3],
    ) {
        let (v0m, v1m) = (SVector::from(*v0), SVector::from(*v1));
        let (v03, v13, v2m) = (
            v0m.fixed_rows::<3>(0).into_owned(),
            v1m.fixed_rows::<3>(0).into_owned(),
            Vector3::from(*v2),
        );
        let ym = Vector3::from(y);
        // Rank-one updates on fixed-size matrices: unrolled and vectorised.
        self.p00.ger(w, &v0m, &v0m, 1.0);
        self.p01.ger(w, &v0m, &v1m, 1.0);
        self.x0.ger(w, &v0m, &ym, 1.0);
        self.x1.ger(w, &v1m, &ym, 1.0);
        self.p02.ger(w, &v03, &v2m, 1.0);
        self.p11.ger(w, &v13, &v13, 1.0);
        self.p12.ger(w, &v13, &v2m, 1.0);
        self.p22.ger(w, &v2m, &v2m, 1.0);
        self.x2.ger(w, &v2m, &ym, 1.0);
        for (a, v) in self.yy.iter_mut().zip(y) {
            *a += w * v * v;
        }
    }

    /// The sine fit's normal equations at `step`, to second order in its ε.
    pub fn sine_at(&self, step: PhaseStep) -> SineNormal {
        self.dense().sine_at_dense(step)
    }

    fn sine_at_dense(&self, step: PhaseStep) -> SineNormal {
        let e = self.eps(step);
        let d = sine_d();
        let d2 = d * d;
        let sub = |m: &M10| m.fixed_view::<3, 3>(0, 0).into_owned();
        let (p00, p01) = (sub(&self.p00), sub(&self.p01));
        // Blocks of Q = Σ n·V Vᵀ, V = (v₀, v₁, v₂) on the sine columns.
        let q = |a: usize, b: usize| -> Matrix3<f64> {
            match (a, b) {
                (0, 0) => p00,
                (0, 1) => p01,
                (1, 0) => p01.transpose(),
                (0, 2) => self.p02,
                (2, 0) => self.p02.transpose(),
                (1, 1) => self.p11,
                (1, 2) => self.p12,
                (2, 1) => self.p12.transpose(),
                _ => self.p22,
            }
        };
        // h = Σ_m T_h[m] v_m and dh = Σ_m T_d[m] v_m.
        let th = [Matrix3::identity(), d * e, d2 * (e * e / 2.0)];
        let td = [Matrix3::zeros(), d, d2 * e];
        let xv = |m: usize| -> Matrix3<f64> {
            match m {
                0 => self.x0.fixed_view::<3, 3>(0, 0).into_owned(),
                1 => self.x1.fixed_view::<3, 3>(0, 0).into_owned(),
                _ => self.x2,
            }
        };
        let mut out = SineNormal {
            g: Matrix3::zeros(),
            k: Matrix3::zeros(),
            l: Matrix3::zeros(),
            xh: Matrix3::zeros(),
            xd: Matrix3::zeros(),
            yy: self.yy,
            rows: self.rows,
        };
        for (a, (tha, tda)) in th.into_iter().zip(td).enumerate() {
            out.xh += tha * xv(a);
            out.xd += tda * xv(a);
            for (b, (thb, tdb)) in th.into_iter().zip(td).enumerate() {
                let qab = q(a, b);
                out.g += tha * qab * thb.transpose();
                out.k += tha * qab * tdb.transpose();
                out.l += tda * qab * tdb.transpose();
            }
        }
        out
    }

    /// The widened fit's normal equations at `step`, to first order in its ε: Σ n·h hᵀ
    /// and Σ n·h y (a column per channel).
    pub fn wide_at(&self, step: PhaseStep) -> (DMatrix<f64>, DMatrix<f64>) {
        let this = self.dense();
        let e = this.eps(step);
        let d = wide_d();
        let g = this.p00 + (d * this.p01.transpose() + this.p01 * d.transpose()) * e;
        let x = this.x0 + d * this.x1 * e;
        (
            DMatrix::from_iterator(WIDE, WIDE, g.iter().copied()),
            DMatrix::from_iterator(WIDE, 3, x.iter().copied()),
        )
    }

    /// The same sums over only the rows of `other` (gathered about the same step) taken
    /// out: for readings left out of a channel's fit.
    pub fn without(&self, other: &Moments) -> Moments {
        self.plus(other, -1.0)
    }

    /// These sums and `other`'s (about the same step and origin) together.
    pub fn merged(&self, other: &Moments) -> Moments {
        self.plus(other, 1.0)
    }

    /// These sums with `sign` times `other`'s added (1: rows joined; −1: rows taken out).
    fn plus(&self, other: &Moments, sign: f64) -> Moments {
        let (mut m, other) = (self.dense(), other.dense());
        m.rows = if sign > 0.0 {
            m.rows + other.rows
        } else {
            m.rows.saturating_sub(other.rows)
        };
        m.p00 += other.p00 * sign;
        m.p01 += other.p01 * sign;
        m.x0 += other.x0 * sign;
        m.x1 += other.x1 * sign;
        m.p02 += other.p02 * sign;
        m.p11 += other.p11 * sign;
        m.p12 += other.p12 * sign;
        m.p22 += other.p22 * sign;
        m.x2 += other.x2 * sign;
        for (a, b) in m.yy.iter_mut().zip(other.yy) {
            *a += sign * b;
        }
        if sign > 0.0 {
            m.t_max = m.t_max.max(other.t_max);
        }
        m
    }
}

/// The widened fit's normal equations are singular.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("singular fit: the regressors do not determine every coefficient")]
pub struct SingularWide;

/// The widened fit's coefficients per channel at `step`, each channel's readings on its
/// rails left out.
pub fn wide_betas(
    m: &Moments,
    flagged: &[Option<Moments>; 3],
    step: PhaseStep,
) -> Result<[[f64; WIDE]; 3], SingularWide> {
    let mut out = [[0.0; WIDE]; 3];
    let all = m.wide_at(step);
    for (ch, (b, f)) in out.iter_mut().zip(flagged).enumerate() {
        let without;
        let (g, x) = match f {
            Some(f) => {
                without = m.without(f).wide_at(step);
                (&without.0, &without.1)
            }
            None => (&all.0, &all.1),
        };
        let chol = g.clone().cholesky().ok_or(SingularWide)?;
        for (o, v) in b
            .iter_mut()
            .zip(chol.solve(&x.column(ch).into_owned()).iter())
        {
            *o = *v;
        }
    }
    Ok(out)
}

/// The widened regressors of a row at `step`, exactly (the residual pass): the mean over
/// its conversions, in the order of [`WIDE_HARMONIC`]; and the sine's (sin, cos, 1) at
/// `other`, a step `shift` rad/s below (by rotating each conversion's angle back by
/// shift·u, in a series exact to rounding while shift·u ≤ 10⁻³; directly beyond).
#[inline]
pub fn wide_regressors(
    ap: &Aperture,
    step: PhaseStep,
    other: (PhaseStep, f64),
    clock: TickRate,
) -> ([f64; WIDE], [f64; 3]) {
    let hz = f64::from(clock.hz());
    let (mut v, mut o) = ([0.0; WIDE], [0.0, 0.0, 1.0]);
    for t in ap.ticks() {
        let (s, c) = step.phase_at(t).sin_cos::<f64>();
        let u = t.0 as f64 / hz;
        let f = wide_row(s.hi, c.hi, u);
        for (a, b) in v.iter_mut().zip(f) {
            *a += b;
        }
        let phi = other.1 * u;
        let (so, co) = if phi.abs() <= 1e-3 {
            let p2 = phi * phi;
            let sin = phi * (1.0 - p2 / 6.0 * (1.0 - p2 / 20.0));
            let cos = 1.0 - p2 / 2.0 * (1.0 - p2 / 12.0 * (1.0 - p2 / 30.0));
            (s.hi * cos - c.hi * sin, c.hi * cos + s.hi * sin)
        } else {
            let (s, c) = other.0.phase_at(t).sin_cos::<f64>();
            (s.hi, c.hi)
        };
        o[0] += so;
        o[1] += co;
    }
    if ap.len() <= 1 {
        return (v, o); // one conversion: nothing to average
    }
    let n = ap.len() as f64;
    (v.map(|a| a / n), [o[0] / n, o[1] / n, 1.0])
}

/// A, B, C per channel of the sine fit at `step` from `m`'s sums (normal equations by
/// Cholesky: the columns are near-orthogonal sines and a constant).
pub fn sine_coefficients(m: &Moments, step: PhaseStep) -> Result<[[f64; 3]; 3], BatchError> {
    let n = m.sine_at(step);
    let chol = n.g.cholesky().ok_or(BatchError::Singular)?;
    let mut out = [[0.0; 3]; 3];
    for (c, xh) in out.iter_mut().zip(n.xh.column_iter()) {
        *c = chol.solve(&xh.into_owned()).into();
    }
    Ok(out)
}

/// The iterated four-parameter fit of IEEE Std 1057 ([`crate::fit::batch::fit_four_param`])
/// from `m`'s sums, starting at `start`: each iteration solves the joint normal equations
/// of (A, B, C) × 3 channels and δω, whose rows for channel j are (sin, cos, 1) and
/// u·(A_j cos α − B_j sin α) (u from the group's start rather than its middle: the
/// difference lies in the span of sin and cos, so δω and its standard error are the same).
/// The caller checks that the rate reached is [`Moments::within`] the sums' reach.
pub fn four_param(m: &Moments, start: PhaseStep, clock: TickRate) -> Result<FourParam, BatchError> {
    const MAX_ITER: usize = 50;
    let rows = m.rows();
    if rows < 8 {
        return Err(BatchError::TooFewSamples {
            n: rows as usize,
            needed: 8,
        });
    }
    let mut rate = start.to_hz(clock);
    let mut last = sine_coefficients(m, start)?;
    for iter in 1..=MAX_ITER {
        let step = PhaseStep::from_hz(rate, clock).ok_or(BatchError::Singular)?;
        let s = m.sine_at(step);
        let mut normal = DMatrix::<f64>::zeros(10, 10);
        let mut rhs = DMatrix::<f64>::zeros(10, 1);
        // The rate's own entries of `normal` and `rhs`: sums over the channels.
        let (mut ll, mut ly) = (0.0, 0.0);
        let mut yy = 0.0;
        let per_channel = s.xh.column_iter().zip(s.xd.column_iter()).zip(s.yy);
        for (ch, (c, ((xh, xd), y2))) in last.iter().zip(per_channel).enumerate() {
            // g_j = (A_j, B_j, 0)·dh: its cross products from K = Σ h dhᵀ and L = Σ dh dhᵀ.
            let [a, b_amp, _] = *c;
            let ab = nalgebra::Vector3::new(a, b_amp, 0.0);
            let b = 3 * ch;
            normal.view_mut((b, b), (3, 3)).copy_from(&s.g);
            let cross = s.k * ab;
            normal.view_mut((b, 9), (3, 1)).copy_from(&cross);
            normal
                .view_mut((9, b), (1, 3))
                .copy_from(&cross.transpose());
            ll += (ab.transpose() * s.l * ab).x;
            rhs.view_mut((b, 0), (3, 1)).copy_from(&xh);
            ly += ab.dot(&xd);
            yy += y2;
        }
        let internal = BatchError::Internal("the joint rate fit is not 10 by 10");
        *normal.get_mut((9, 9)).ok_or(internal.clone())? = ll;
        *rhs.get_mut((9, 0)).ok_or(internal.clone())? = ly;
        let chol = normal.cholesky().ok_or(BatchError::Singular)?;
        let theta = chol.solve(&rhs);
        let inv = chol.inverse();
        let rss = (yy - theta.dot(&rhs)).max(0.0);
        let dof = (3 * rows).saturating_sub(10).max(1) as f64;
        let dw = *theta.get((9, 0)).ok_or(internal.clone())?;
        let se_dw = (rss / dof * inv.get((9, 9)).ok_or(internal)?)
            .max(0.0)
            .sqrt();
        rate += dw / TAU;
        let next = PhaseStep::from_hz(rate, clock).ok_or(BatchError::Singular)?;
        last = sine_coefficients(m, next)?;
        if crate::fit::batch::converged(dw, se_dw, (step, next), clock) {
            return Ok(FourParam {
                rate_hz: rate,
                se_rate_hz: se_dw / TAU,
                coef: last,
                iterations: iter,
            });
        }
    }
    Err(BatchError::NoConvergence(MAX_ITER))
}

/// What [`four_param`] gives.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FourParam {
    /// The rotation rate, Hz.
    pub rate_hz: f64,
    /// Its standard error, Hz.
    pub se_rate_hz: f64,
    /// A, B, C per channel at that rate.
    pub coef: [[f64; 3]; 3],
    /// Iterations used.
    pub iterations: usize,
}

impl Moments {
    /// The same sums about an origin `ticks` earlier: the rows' times (and the phase from
    /// which their angles count) move by `ticks`. Rows gathered by another thread from its
    /// own first row are brought to the group's first row so: each row's angle turns by
    /// φ = step·ticks (exactly, as a fraction of a turn) and its time grows by Δ.
    pub fn shifted(&self, ticks: u64) -> Moments {
        self.dense().shifted_dense(ticks)
    }

    fn shifted_dense(&self, ticks: u64) -> Moments {
        let hz = f64::from(self.clock.hz());
        let delta = ticks as f64 / hz;
        let (sp, cp) = self.step.phase_at(Ticks(ticks)).sin_cos::<f64>();
        let (sp, cp) = (sp.hi, cp.hi);
        // f' = A f: each harmonic pair turned by kφ, the trend moved by Δ times the constant.
        // sin(kα + kφ) = sin kα cos kφ + cos kα sin kφ; cos(kα + kφ) = cos kα cos kφ − sin kα sin kφ.
        let turn = |k: usize| {
            let (mut sk, mut ck) = (0.0, 1.0);
            for _ in 0..k {
                (sk, ck) = (sk * cp + ck * sp, ck * cp - sk * sp);
            }
            (sk, ck)
        };
        let a = grid(&COLS, &COLS, |row, col| match (row, col) {
            (Col::One(p), Col::One(q)) if p == q => 1.0,
            (Col::One(1), Col::One(0)) => delta, // trend: u + Δ
            (Col::Sin(k), Col::Sin(l)) | (Col::Cos(k), Col::Cos(l)) if k == l => turn(k).1,
            (Col::Sin(k), Col::Cos(l)) if k == l => turn(k).0,
            (Col::Cos(k), Col::Sin(l)) if k == l => -turn(k).0,
            _ => 0.0,
        });
        let r3 = a.fixed_view::<3, 3>(0, 0).into_owned();
        let mut m = self.clone();
        // v₀' = A v₀, v₁' = A(v₁ + Δv₀); for the sine, v₂' = R(v₂ + 2Δv₁ + Δ²v₀).
        m.p00 = a * self.p00 * a.transpose();
        m.p01 = a * (self.p01 + self.p00 * delta) * a.transpose();
        m.x0 = a * self.x0;
        m.x1 = a * (self.x1 + self.x0 * delta);
        let sub = |x: &M10| x.fixed_view::<3, 3>(0, 0).into_owned();
        let (q00, q01) = (sub(&self.p00), sub(&self.p01));
        let q10 = q01.transpose();
        let d2 = delta * delta;
        // With w₁ = v₁ + Δv₀ and w₂ = v₂ + 2Δv₁ + Δ²v₀ (before turning by R):
        let w1w1 = self.p11 + (q10 + q01) * delta + q00 * d2;
        let v0w2 = self.p02 + q01 * (2.0 * delta) + q00 * d2;
        let w1w2 = self.p12
            + self.p11 * (2.0 * delta)
            + q10 * d2
            + (self.p02 + q01 * (2.0 * delta) + q00 * d2) * delta;
        let w2w2 = {
            let (p02, p12) = (self.p02, self.p12);
            let (p20, p21) = (p02.transpose(), p12.transpose());
            self.p22
                + (p21 + p12) * (2.0 * delta)
                + (p20 + p02) * d2
                + self.p11 * (4.0 * d2)
                + (q10 + q01) * (2.0 * d2 * delta)
                + q00 * (d2 * d2)
        };
        m.p11 = r3 * w1w1 * r3.transpose();
        m.p02 = r3 * v0w2 * r3.transpose();
        m.p12 = r3 * w1w2 * r3.transpose();
        m.p22 = r3 * w2w2 * r3.transpose();
        let x03 = self.x0.fixed_view::<3, 3>(0, 0).into_owned();
        let x13 = self.x1.fixed_view::<3, 3>(0, 0).into_owned();
        m.x2 = r3 * (self.x2 + x13 * (2.0 * delta) + x03 * d2);
        m.t_max = self.t_max.saturating_add(ticks);
        m
    }
}
