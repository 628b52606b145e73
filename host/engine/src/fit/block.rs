//! Rows of one conversion each, summed a block at a time: the streaming engine's per-row
//! sums ([`super::moments`], the pilots' residuals and their lagged sums) over [`BLOCK`]
//! rows together, column by column, so that each sum is a dot product the compiler
//! vectorises (docs/streaming.md, "Blocks").
//!
//! A block's sums are taken in [`LANES`] interleaved partial sums, added in a fixed order:
//! the same on every machine, whatever its vector width, so a calibration's numbers do
//! not depend on the processor it ran on.

use rotacal_shared::{PhaseStep, TickRate, Ticks};

/// Rows in a block.
pub const BLOCK: usize = 64;

/// Partial sums per dot product.
pub const LANES: usize = 8;

const _: () = assert!(BLOCK % LANES == 0, "a block is whole chunks of lanes");

/// A column of a block: a value per row.
pub type Vals = [f64; BLOCK];

/// Up to [`BLOCK`] rows of one conversion each: their tick (from their group's or piece's
/// first row) and their u, v, w.
#[derive(Clone, Debug)]
pub struct Block {
    pub tick: [u64; BLOCK],
    pub y: [Vals; 3],
    len: usize,
}

impl Default for Block {
    fn default() -> Self {
        Block {
            tick: [0; BLOCK],
            y: [[0.0; BLOCK]; 3],
            len: 0,
        }
    }
}

impl Block {
    /// Add a row; true when the block is then full.
    #[inline]
    pub fn push(&mut self, tick: u64, y: [f64; 3]) -> bool {
        if let Some(t) = self.tick.get_mut(self.len) {
            *t = tick;
            for (col, v) in self.y.iter_mut().zip(y) {
                if let Some(x) = col.get_mut(self.len) {
                    *x = v;
                }
            }
            self.len += 1;
        }
        self.len == BLOCK
    }

    /// Rows held.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn is_full(&self) -> bool {
        self.len == BLOCK
    }

    /// The rows held, in order: tick and u, v, w.
    pub fn rows(&self) -> impl Iterator<Item = (u64, [f64; 3])> + '_ {
        let [u, v, w] = &self.y;
        self.tick
            .iter()
            .zip(u.iter().zip(v).zip(w))
            .take(self.len)
            .map(|(t, ((u, v), w))| (*t, [*u, *v, *w]))
    }

    /// Empty it.
    pub fn clear(&mut self) {
        self.len = 0;
    }
}

/// A full block's rows at a phase step: their time u (s) and cos mα, sin mα for
/// m = 0 … 8, by the angle-sum formulas from cos α and sin α, as
/// [`super::moments::wide_row`] and the per-row sums build them (to the bit).
pub struct Angles {
    pub u: Vals,
    pub cos: [Vals; 9],
    pub sin: [Vals; 9],
}

impl Angles {
    /// The angles of `block`'s rows (all [`BLOCK`] of them) at `step` of a `clock`-tick
    /// clock.
    #[inline(always)]
    pub fn of(block: &Block, step: PhaseStep, clock: TickRate) -> Angles {
        // On the stack: a block's angles are 10 KiB, made and dropped once a block.
        let mut a = Angles {
            u: [0.0; BLOCK],
            cos: [[0.0; BLOCK]; 9],
            sin: [[0.0; BLOCK]; 9],
        };
        let hz = f64::from(clock.hz());
        let Angles { u, cos, sin } = &mut a;
        let ([c0, c1, ..], [_, s1, ..]) = (&mut *cos, &mut *sin);
        for ((((t, u), c0), c1), s1) in block
            .tick
            .iter()
            .zip(u.iter_mut())
            .zip(c0.iter_mut())
            .zip(c1.iter_mut())
            .zip(s1.iter_mut())
        {
            let (s, c) = step.phase_at(Ticks(*t)).sin_cos::<f64>();
            *u = *t as f64 / hz;
            *c0 = 1.0;
            (*c1, *s1) = (c.hi, s.hi);
        }
        // cos mα, sin mα in the rounds of the per-row sums: 2 = 1 + 1; 3 = 2 + 1,
        // 4 = 2 + 2; 5 … 8 = 4 + 1 … 4.
        for (m, (a, b)) in [(2, (1, 1)), (3, (2, 1)), (4, (2, 2))]
            .into_iter()
            .chain((5..=8).map(|m| (m, (4, m - 4))))
        {
            turn(cos, sin, m, a, b);
        }
        a
    }
}

/// cos mα, sin mα from harmonics a and b below m (a + b = m):
/// (c_a c_b − s_a s_b, s_a c_b + c_a s_b).
#[inline(always)]
fn turn(cos: &mut [Vals; 9], sin: &mut [Vals; 9], m: usize, a: usize, b: usize) {
    let ((cl, ch), (sl, sh)) = (cos.split_at_mut(m), sin.split_at_mut(m));
    let (Some(ca), Some(sa), Some(cb), Some(sb), Some(cm), Some(sm)) = (
        cl.get(a),
        sl.get(a),
        cl.get(b),
        sl.get(b),
        ch.first_mut(),
        sh.first_mut(),
    ) else {
        return;
    };
    for ((((o, ca), sa), cb), sb) in cm.iter_mut().zip(ca).zip(sa).zip(cb).zip(sb) {
        *o = ca * cb - sa * sb;
    }
    for ((((o, ca), sa), cb), sb) in sm.iter_mut().zip(ca).zip(sa).zip(cb).zip(sb) {
        *o = sa * cb + ca * sb;
    }
}

/// A slice in chunks of [`LANES`] values (a remainder left out), typed so that a loop
/// over a chunk's lanes is one vector operation.
#[inline(always)]
pub fn lanes(x: &[f64]) -> impl Iterator<Item = &[f64; LANES]> {
    x.chunks_exact(LANES)
        .filter_map(|c| <&[f64; LANES]>::try_from(c).ok())
}

/// Σ a·b over a block, in [`LANES`] partial sums ([`dot_lanes`]) added pairwise in a fixed
/// order ([`fold`]).
#[inline(always)]
pub fn dot(a: &Vals, b: &Vals) -> f64 {
    fold(dot_lanes(a, b))
}

/// Σ a over a block, as [`dot`] adds.
#[inline(always)]
pub fn total(a: &Vals) -> f64 {
    let mut acc = [0.0; LANES];
    for x in lanes(a) {
        for (s, x) in acc.iter_mut().zip(x) {
            *s += x;
        }
    }
    fold(acc)
}

/// The [`LANES`] partial sums of Σ a[i]·b[i] over the whole chunks both slices have (a
/// block's length for the lagged sums, whose lagged side starts before the block): lane l
/// adds the rows i ≡ l (mod [`LANES`]) in order. A kernel takes all its sums' lanes first
/// and [`fold`]s them after: a fold beside the loop keeps the compiler from the widest
/// vectors.
#[inline(always)]
pub fn dot_lanes(a: &[f64], b: &[f64]) -> [f64; LANES] {
    let mut acc = [0.0; LANES];
    for (x, y) in lanes(a).zip(lanes(b)) {
        for ((s, x), y) in acc.iter_mut().zip(x).zip(y) {
            *s += x * y;
        }
    }
    acc
}

/// The partial sums of [`dot_lanes`] added: pairwise, in a fixed order.
#[inline(always)]
pub fn fold(acc: [f64; LANES]) -> f64 {
    let [a, b, c, d, e, f, g, h] = acc;
    ((a + e) + (c + g)) + ((b + f) + (d + h))
}
