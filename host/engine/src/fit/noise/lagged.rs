//! The residuals' lagged sums, gathered one residual at a time and joined across parts
//! of a series: the streaming engine's autocovariances.

use super::MAX_ORDER;
use crate::fit::block::{self, Vals, BLOCK, LANES};

/// The sample autocovariances of a series of residuals at lags 0 … [`MAX_ORDER`], gathered
/// one residual at a time (as [`NoiseModel::estimate`] computes them from the whole
/// series: about the mean of the samples used, pairs with a flagged sample left out,
/// divided by the samples used).
///
/// The last lags' residuals sit in a window stored twice over, so that the newest
/// [`LAGS`] are always contiguous and each sample's products are one vectorised loop.
/// Without flagged samples, the sums that centre the products come from the series'
/// total and its first and last [`LAGS`] values.
///
/// [`NoiseModel::estimate`]: super::NoiseModel::estimate
#[derive(Clone, Debug)]
pub struct LaggedSums {
    /// Residuals (0 for a flagged one), each at two slots LAGS apart: from `pos` on, the
    /// newest LAGS, newest first.
    win: [f64; 2 * LAGS],
    /// 1 for a sample used, 0 for a flagged one, stored as `win`.
    ok: [f64; 2 * LAGS],
    pos: usize,
    /// Σ e_t e_{t−k} over pairs of samples used.
    prod: [f64; LAGS],
    /// With flagged samples: Σ e_{t−k}, Σ e_t and the count, over pairs used.
    earlier: [f64; LAGS],
    later: [f64; LAGS],
    pairs: [f64; LAGS],
    /// Whether a sample has been flagged: the centring sums are then kept pair by pair.
    pairwise: bool,
    /// The first LAGS residuals (for the centring sums without flags, and for joining a
    /// series read in parts), and 1 or 0 for each as it was used or flagged.
    head: Vec<f64>,
    head_ok: Vec<f64>,
    n: usize,
    used: usize,
    sum: f64,
}

/// Lags 0 … [`MAX_ORDER`].
pub const LAGS: usize = MAX_ORDER + 1;

/// A block's values with the LAGS − 1 before it in front: `ext[LAGS − 1 + i]` is the
/// block's value i, `ext[LAGS − 2 − k]` the value k + 1 back.
pub(crate) type Behind = [f64; LAGS - 1 + BLOCK];

/// [`Behind`] of `block`, the values before it from a window stored twice over as
/// [`LaggedSums`] keeps its residuals (`window[pos + k]` the value k back from the newest):
/// the lagged sums' residuals, the pilots' ticks.
#[inline(always)]
pub(crate) fn behind(
    window: &[f64; 2 * LAGS],
    pos: usize,
    block: impl IntoIterator<Item = f64>,
) -> Behind {
    let mut ext = [0.0; LAGS - 1 + BLOCK];
    let newest = window.get(pos..pos + LAGS - 1).unwrap_or(&[]);
    for (x, w) in ext.iter_mut().take(LAGS - 1).rev().zip(newest) {
        *x = *w;
    }
    for (x, v) in ext.iter_mut().skip(LAGS - 1).zip(block) {
        *x = v;
    }
    ext
}

// LaggedSums::add takes the lags after 0 in pairs.
const _: () = assert!(MAX_ORDER % 2 == 0, "the lags after 0 go in pairs");

impl Default for LaggedSums {
    fn default() -> Self {
        LaggedSums {
            win: [0.0; 2 * LAGS],
            ok: [0.0; 2 * LAGS],
            pos: 0,
            prod: [0.0; LAGS],
            earlier: [0.0; LAGS],
            later: [0.0; LAGS],
            pairs: [0.0; LAGS],
            pairwise: false,
            head: Vec::with_capacity(LAGS),
            head_ok: Vec::with_capacity(LAGS),
            n: 0,
            used: 0,
            sum: 0.0,
        }
    }
}

impl LaggedSums {
    /// Add the next residual; `flagged` leaves it out.
    #[inline]
    pub fn add(&mut self, e: f64, flagged: bool) {
        if flagged && !self.pairwise {
            // The first flagged sample: from here on the centring sums go pair by pair.
            let (earlier, later, pairs) = self.centring_from_totals();
            (self.earlier, self.later, self.pairs) = (earlier, later, pairs);
            self.pairwise = true;
        }
        let (x, o) = if flagged { (0.0, 0.0) } else { (e, 1.0) };
        // The new sample goes in front of the window (slot pos − 1 mod LAGS, twice), so
        // that win[pos + k] is e_{t−k} (0 before the series began).
        self.pos = (self.pos + LAGS - 1) % LAGS;
        for slot in [self.pos, self.pos + LAGS] {
            if let (Some(w), Some(k)) = (self.win.get_mut(slot), self.ok.get_mut(slot)) {
                (*w, *k) = (x, o);
            }
        }
        if self.head.len() < LAGS {
            self.head.push(x);
            self.head_ok.push(o);
        }
        self.n += 1;
        if flagged {
            return;
        }
        self.used += 1;
        self.sum += x;
        let (Some(lagged), Some(oks)) = (
            self.win.get(self.pos..self.pos + LAGS),
            self.ok.get(self.pos..self.pos + LAGS),
        ) else {
            return;
        };
        // Lag 0 from x itself, not from the slot just written: loading a store still in
        // flight together with its neighbour stalls. Then pairs of lags at a time: two
        // independent lanes the compiler vectorises.
        let (p0, older) = self.prod.split_at_mut(1);
        if let Some(p) = p0.first_mut() {
            *p += x * x;
        }
        let older_lagged = lagged.get(1..).unwrap_or(&[]);
        for (p, l) in older.chunks_exact_mut(2).zip(older_lagged.chunks_exact(2)) {
            if let (Some(p), Some(l)) = (
                <&mut [f64; 2]>::try_from(p).ok(),
                <&[f64; 2]>::try_from(l).ok(),
            ) {
                *p = [p[0] + x * l[0], p[1] + x * l[1]];
            }
        }
        if self.pairwise {
            for (((a, b), c), (l, k)) in self
                .earlier
                .iter_mut()
                .zip(self.later.iter_mut())
                .zip(self.pairs.iter_mut())
                .zip(lagged.iter().zip(oks))
            {
                *a += l;
                *b += x * k;
                *c += k;
            }
        }
    }

    /// [`LaggedSums::add`] of a block of residuals, none flagged: each lag's products
    /// a dot product over the block ([`crate::fit::block`]), with the window's newest
    /// samples in front of it. Once a sample has been flagged, one at a time.
    #[inline(always)]
    pub fn add_block(&mut self, e: &Vals) {
        if self.pairwise {
            for x in e {
                self.add(*x, false);
            }
            return;
        }
        // The newest LAGS − 1 samples (0 before the series began), then the block.
        let ext = behind(&self.win, self.pos, e.iter().copied());
        // Every lag's lanes first, then their folds (block::dot_lanes).
        let mut lanes = [[0.0; LANES]; LAGS];
        for (k, acc) in lanes.iter_mut().enumerate() {
            let lagged = ext.get(LAGS - 1 - k..).unwrap_or(&[]);
            *acc = block::dot_lanes(e, lagged);
        }
        for (p, acc) in self.prod.iter_mut().zip(lanes) {
            *p += block::fold(acc);
        }
        self.sum += block::total(e);
        for x in e {
            if self.head.len() >= LAGS {
                break;
            }
            self.head.push(*x);
            self.head_ok.push(1.0);
        }
        self.n += BLOCK;
        self.used += BLOCK;
        // The window afresh, from its newest sample; those before the series began unused.
        self.pos = 0;
        for (k, x) in ext.iter().rev().take(LAGS).enumerate() {
            let used = if k < self.n { 1.0 } else { 0.0 };
            for slot in [k, k + LAGS] {
                if let (Some(w), Some(o)) = (self.win.get_mut(slot), self.ok.get_mut(slot)) {
                    (*w, *o) = (*x, used);
                }
            }
        }
    }

    /// Without a flagged sample so far: Σ e_{t−k}, Σ e_t and the pair count over t ≥ k,
    /// from the total less the last (first) k samples.
    fn centring_from_totals(&self) -> ([f64; LAGS], [f64; LAGS], [f64; LAGS]) {
        let (mut earlier, mut later, mut pairs) = ([0.0; LAGS], [0.0; LAGS], [0.0; LAGS]);
        let (mut last_k, mut first_k) = (0.0, 0.0);
        // win[pos + k] is e_{n−1−k} (pos < LAGS, so LAGS of them are there); a head
        // shorter than the lags read on as zeros.
        let newest = self.win.iter().skip(self.pos);
        let first = self.head.iter().chain(std::iter::repeat(&0.0));
        for (k, (((a, b), c), (w, h))) in earlier
            .iter_mut()
            .zip(later.iter_mut())
            .zip(pairs.iter_mut())
            .zip(newest.zip(first))
            .enumerate()
        {
            if k >= self.n {
                break;
            }
            *a = self.sum - last_k;
            *b = self.sum - first_k;
            *c = (self.n - k) as f64;
            last_k += w;
            first_k += h;
        }
        (earlier, later, pairs)
    }

    /// Σ e_t e_{t−k} for k = 0 … [`MAX_ORDER`], and Σ e_t, over the samples used.
    pub fn products(&self) -> ([f64; LAGS], f64) {
        (self.prod, self.sum)
    }

    /// The sums of a series of `n` samples, none flagged, whose lagged products `prod`
    /// and total `sum` were found otherwise (the streaming engine's pilot corrections,
    /// docs/streaming.md), with its first samples `head` and its newest `newest` (newest
    /// first), LAGS of each or all there are: for [`LaggedSums::followed_by`] and for
    /// reading out.
    pub fn assembled(
        prod: [f64; LAGS],
        sum: f64,
        head: &[f64],
        newest: &[f64],
        n: usize,
    ) -> LaggedSums {
        let mut out = LaggedSums {
            prod,
            sum,
            n,
            used: n,
            ..LaggedSums::default()
        };
        for (j, e) in newest.iter().take(LAGS.min(n)).enumerate() {
            for slot in [j, j + LAGS] {
                if let (Some(w), Some(k)) = (out.win.get_mut(slot), out.ok.get_mut(slot)) {
                    (*w, *k) = (*e, 1.0);
                }
            }
        }
        for e in head.iter().take(LAGS.min(n)) {
            out.head.push(*e);
            out.head_ok.push(1.0);
        }
        out
    }

    /// Samples added, and those used (not flagged).
    pub fn counts(&self) -> (usize, usize) {
        (self.n, self.used)
    }

    /// The sums of this series followed by `later` (the same series read on, by another
    /// thread from where this one stopped): the pairs that straddle the join added from
    /// this one's last samples and `later`'s first. The result is for reading out, not
    /// for adding to.
    pub fn followed_by(&self, later: &LaggedSums) -> LaggedSums {
        let totals = |a: &LaggedSums| {
            if a.pairwise {
                (a.earlier, a.later, a.pairs)
            } else {
                a.centring_from_totals()
            }
        };
        let (mut earlier, mut lat, mut pairs) = totals(self);
        let (e2, l2, p2) = totals(later);
        let mut prod = self.prod;
        for k in 0..LAGS {
            if let (Some(p), Some(q)) = (prod.get_mut(k), later.prod.get(k)) {
                *p += q;
            }
            let add = |a: &mut [f64; LAGS], b: &[f64; LAGS]| {
                if let (Some(x), Some(y)) = (a.get_mut(k), b.get(k)) {
                    *x += y;
                }
            };
            add(&mut earlier, &e2);
            add(&mut lat, &l2);
            add(&mut pairs, &p2);
        }
        // This one's newest samples: win[pos + j] is e_{n−1−j}.
        let newest = self.win.get(self.pos..self.pos + LAGS).unwrap_or(&[]);
        let newest_ok = self.ok.get(self.pos..self.pos + LAGS).unwrap_or(&[]);
        for k in 1..LAGS {
            // Pairs (later's sample i, this one's sample k − i − 1 from its newest).
            for i in 0..k.min(later.head.len()) {
                let j = k - i - 1;
                if j >= self.n.min(LAGS) {
                    continue;
                }
                let (Some(h), Some(ho), Some(w), Some(wo)) = (
                    later.head.get(i),
                    later.head_ok.get(i),
                    newest.get(j),
                    newest_ok.get(j),
                ) else {
                    continue;
                };
                if let (Some(p), Some(a), Some(b), Some(c)) = (
                    prod.get_mut(k),
                    earlier.get_mut(k),
                    lat.get_mut(k),
                    pairs.get_mut(k),
                ) {
                    *p += h * w;
                    *a += w * ho;
                    *b += h * wo;
                    *c += ho * wo;
                }
            }
        }
        let mut out = self.clone();
        out.prod = prod;
        out.earlier = earlier;
        out.later = lat;
        out.pairs = pairs;
        out.pairwise = true;
        out.n += later.n;
        out.used += later.used;
        out.sum += later.sum;
        out
    }

    /// γ̂₀ … γ̂_K about the mean of the samples used, divided by the samples used.
    pub fn autocovariances(&self) -> Vec<f64> {
        let used = self.used.max(1) as f64;
        let mean = self.sum / used;
        let (earlier, later, pairs) = if self.pairwise {
            (self.earlier, self.later, self.pairs)
        } else {
            self.centring_from_totals()
        };
        self.prod
            .iter()
            .zip(&earlier)
            .zip(&later)
            .zip(&pairs)
            .map(|(((p, f), s), c)| (p - mean * (f + s) + mean * mean * c) / used)
            .collect()
    }
}

#[cfg(test)]
#[allow(clippy::indexing_slicing)]
mod tests {
    use super::{LaggedSums, BLOCK, LAGS};
    use proptest::prelude::*;

    /// γ̂ₖ from its definition (as NoiseModel::estimate has it).
    fn direct(e: &[f64], flagged: &[bool]) -> Vec<f64> {
        let ok = |t: usize| !flagged[t];
        let used = (0..e.len()).filter(|&t| ok(t)).count() as f64;
        let mean = (0..e.len()).filter(|&t| ok(t)).map(|t| e[t]).sum::<f64>() / used;
        (0..LAGS)
            .map(|k| {
                (0..e.len().saturating_sub(k))
                    .filter(|&t| ok(t) && ok(t + k))
                    .map(|t| (e[t] - mean) * (e[t + k] - mean))
                    .sum::<f64>()
                    / used
            })
            .collect()
    }

    fn sums(e: &[f64], flagged: &[bool]) -> LaggedSums {
        let mut s = LaggedSums::default();
        for (x, f) in e.iter().zip(flagged) {
            s.add(*x, *f);
        }
        s
    }

    /// [`sums`], the first `lead` samples one at a time, then each block of [`BLOCK`]
    /// without a flagged sample together (as the streaming calibration's blocks come).
    fn sums_in_blocks(e: &[f64], flagged: &[bool], lead: usize) -> LaggedSums {
        let mut s = LaggedSums::default();
        let lead = lead.min(e.len());
        for (x, f) in e[..lead].iter().zip(&flagged[..lead]) {
            s.add(*x, *f);
        }
        for (block, flags) in e[lead..].chunks(BLOCK).zip(flagged[lead..].chunks(BLOCK)) {
            match <&[f64; BLOCK]>::try_from(block) {
                Ok(b) if !flags.contains(&true) => s.add_block(b),
                _ => block.iter().zip(flags).for_each(|(x, f)| s.add(*x, *f)),
            }
        }
        s
    }

    proptest! {
        /// Whole, and read in two parts joined (as the streaming calibration reads a
        /// file), the sums give the definition's autocovariances: flagged samples or none,
        /// the cut anywhere (within the first lags too); and so do they in blocks, which
        /// change only the order of the additions, the blocks starting anywhere.
        #[test]
        fn lagged_sums_give_the_autocovariances(
            e in prop::collection::vec(-50.0f64..50.0, 40..2600),
            flag_every in prop_oneof![Just(0usize), 2usize..200],
            cut in 0.0f64..1.0,
            lead in 0usize..100,
        ) {
            let n = e.len();
            let flagged: Vec<bool> =
                (0..n).map(|t| flag_every > 0 && t % flag_every == 7).collect();
            prop_assume!(flagged.iter().filter(|f| !**f).count() > 10);
            let want = direct(&e, &flagged);
            let a = (cut * n as f64) as usize;
            let whole = sums(&e, &flagged).autocovariances();
            let two = sums(&e[..a], &flagged[..a])
                .followed_by(&sums(&e[a..], &flagged[a..]))
                .autocovariances();
            // Each part assembled from its products, total, first and newest samples (as
            // the pilots' corrections give them), when nothing is flagged.
            let assembled = |e: &[f64]| {
                let (prod, sum) = sums(e, &vec![false; e.len()]).products();
                let newest: Vec<f64> = e.iter().rev().copied().collect();
                LaggedSums::assembled(prod, sum, e, &newest, e.len())
            };
            let parts = if flag_every == 0 {
                assembled(&e[..a]).followed_by(&assembled(&e[a..])).autocovariances()
            } else {
                two.clone()
            };
            let blocks = sums_in_blocks(&e, &flagged, lead);
            prop_assert_eq!(blocks.counts(), sums(&e, &flagged).counts());
            let blocks_two = sums_in_blocks(&e[..a], &flagged[..a], lead)
                .followed_by(&sums_in_blocks(&e[a..], &flagged[a..], lead))
                .autocovariances();
            let blocks = blocks.autocovariances();
            let scale = want[0].abs().max(1e-300);
            for got in [&whole, &two, &parts, &blocks, &blocks_two] {
                for (k, (g, w)) in got.iter().zip(&want).enumerate() {
                    prop_assert!((g - w).abs() <= 1e-12 * scale, "lag {k}: {g} against {w}");
                }
            }
        }
    }
}
