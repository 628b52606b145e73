//! Clipped samples: the readings piled up at a channel's rails, found in a whole series
//! or gathered one reading at a time.

/// Readings at a channel's rails: the smallest (largest) value, when at least three
/// readings sit exactly on it and more than on the next value inward, as a clipping sensor
/// piles them up.
pub fn clipped(y: &[f64]) -> Vec<bool> {
    let lo = y.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = y.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let count = |v: f64| y.iter().filter(|&&x| x == v).count();
    // The next value inward on each side: noise quantised to a few steps puts several
    // readings on its extreme value too, but fewer than on the value next to it; a rail
    // piles them up.
    let inner_lo = y
        .iter()
        .copied()
        .filter(|&x| x > lo)
        .fold(f64::INFINITY, f64::min);
    let inner_hi = y
        .iter()
        .copied()
        .filter(|&x| x < hi)
        .fold(f64::NEG_INFINITY, f64::max);
    let rail = |v: f64, inner: f64| {
        let c = count(v);
        c >= 3 && c > count(inner)
    };
    let (lo_rail, hi_rail) = (rail(lo, inner_lo), rail(hi, inner_hi));
    y.iter()
        .map(|&x| (lo_rail && x == lo) || (hi_rail && x == hi))
        .collect()
}

/// A channel's rails as [`clipped`] finds them, gathered one reading at a time: the
/// smallest and largest values with their counts, and the next value inward on each side
/// with its count.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rails {
    lo: (f64, u64),
    lo_inner: (f64, u64),
    hi: (f64, u64),
    hi_inner: (f64, u64),
}

impl Default for Rails {
    fn default() -> Self {
        Rails {
            lo: (f64::INFINITY, 0),
            lo_inner: (f64::INFINITY, 0),
            hi: (f64::NEG_INFINITY, 0),
            hi_inner: (f64::NEG_INFINITY, 0),
        }
    }
}

impl Rails {
    /// Add a reading.
    pub fn add(&mut self, x: f64) {
        // The low side; the high side is the same with the order reversed.
        fn side(
            x: f64,
            end: &mut (f64, u64),
            inner: &mut (f64, u64),
            beyond: fn(f64, f64) -> bool,
        ) {
            if beyond(x, end.0) {
                *inner = *end;
                *end = (x, 1);
            } else if x == end.0 {
                end.1 += 1;
            } else if beyond(x, inner.0) {
                *inner = (x, 1);
            } else if x == inner.0 {
                inner.1 += 1;
            }
        }
        side(x, &mut self.lo, &mut self.lo_inner, |a, b| a < b);
        side(x, &mut self.hi, &mut self.hi_inner, |a, b| a > b);
    }

    /// The rails found (as [`clipped`]: at least three readings on the extreme value and
    /// more than on the next value inward): the low and the high one, if any.
    pub fn found(&self) -> (Option<f64>, Option<f64>) {
        let rail = |end: (f64, u64), inner: (f64, u64)| {
            (end.1 >= 3 && end.1 > inner.1 && end.0.is_finite()).then_some(end.0)
        };
        (rail(self.lo, self.lo_inner), rail(self.hi, self.hi_inner))
    }

    /// The rails of this channel's readings and `other`'s together.
    pub fn merged(&self, other: &Rails) -> Rails {
        // The two extreme values on each side, with their counts: those of either.
        fn two(cands: [(f64, u64); 4], lower: bool) -> ((f64, u64), (f64, u64)) {
            let mut merged: Vec<(f64, u64)> = Vec::with_capacity(4);
            for (v, c) in cands {
                if c == 0 {
                    continue;
                }
                match merged.iter_mut().find(|(w, _)| *w == v) {
                    Some((_, k)) => *k += c,
                    None => merged.push((v, c)),
                }
            }
            merged.sort_by(|a, b| {
                if lower {
                    a.0.total_cmp(&b.0)
                } else {
                    b.0.total_cmp(&a.0)
                }
            });
            let far = if lower {
                f64::INFINITY
            } else {
                f64::NEG_INFINITY
            };
            let mut it = merged.into_iter();
            (it.next().unwrap_or((far, 0)), it.next().unwrap_or((far, 0)))
        }
        let (lo, lo_inner) = two([self.lo, self.lo_inner, other.lo, other.lo_inner], true);
        let (hi, hi_inner) = two([self.hi, self.hi_inner, other.hi, other.hi_inner], false);
        Rails {
            lo,
            lo_inner,
            hi,
            hi_inner,
        }
    }

    /// Whether reading `x` is on a rail found.
    pub fn flags(rails: (Option<f64>, Option<f64>), x: f64) -> bool {
        rails.0 == Some(x) || rails.1 == Some(x)
    }
}
