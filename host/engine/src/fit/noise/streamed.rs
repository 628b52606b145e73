//! [`NoiseModel::rescaled`] for regressors given row by row, so that a long record's design
//! (an hour at 104 Hz: 374 400 rows × a dozen columns, 36 MB, and four such matrices in the
//! computation) is never held: the same expected autocovariances, from two streamed passes
//! over the rows per step of the fixed point.
//!
//! The backward filter Z = A⁻ᵀH runs first over the whole record, from its end, gathering
//! the meat ZᵀZ and keeping its state (the p rows after each chunk) at chunk boundaries; the
//! forward pass then makes each chunk's Z again from its state, filters it forward
//! (ΣH = σ_ε²·A⁻¹Z), and gathers the lagged sums from the rows as they pass.

use super::{NoiseError, NoiseModel};
use nalgebra::DMatrix;

/// Rows of a long record's regressors, made on demand.
pub trait Rows {
    /// Rows in the record.
    fn len(&self) -> usize;
    /// No rows.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Columns (regressors).
    fn cols(&self) -> usize;
    /// Row `t`'s values into `out` (its first [`Rows::cols`] entries).
    fn row(&self, t: usize, out: &mut [f64]);
}

/// Rows per chunk of the forward pass.
const CHUNK: usize = 1024;

impl NoiseModel {
    /// [`Self::rescaled`] for regressors given row by row, with `inv` = (HᵀH)⁻¹.
    pub fn rescaled_rows(
        self,
        h: &impl Rows,
        inv: &DMatrix<f64>,
    ) -> Result<NoiseModel, NoiseError> {
        let (n, q) = (h.len(), h.cols());
        if n != self.n {
            return Err(NoiseError::Length(n, self.n));
        }
        if inv.shape() != (q, q) || inv.iter().any(|v| !v.is_finite()) {
            return Err(NoiseError::Singular);
        }
        self.fixed_point(n, q, |m| m.expected_residual_autocov_rows(h, inv))
    }

    /// The expected sample autocovariances at lags 0 … p of the residuals of a fit of the
    /// regressors `h` under this model (what `expected_residual_autocov` gives for a held
    /// design).
    fn expected_residual_autocov_rows(&self, h: &impl Rows, inv: &DMatrix<f64>) -> Vec<f64> {
        let (n, q, p) = (h.len(), h.cols(), self.order());
        let chunks = n.div_ceil(CHUNK);
        let mut hbuf = vec![0.0; CHUNK * q];
        let mut zbuf = vec![0.0; CHUNK * q];
        // Pass 1, from the end: each chunk's Z from the state after it, the meat ZᵀZ, and
        // the state before it (z_a … z_{a+p−1}) for the next chunk back.
        let mut states = vec![Vec::new(); chunks];
        let mut state = vec![0.0; p * q];
        let mut meat = DMatrix::<f64>::zeros(q, q);
        for c in (0..chunks).rev() {
            let (a, b) = (c * CHUNK, ((c + 1) * CHUNK).min(n));
            fill_rows(h, a, b, &mut hbuf);
            self.back_chunk((a, b, n, q), &hbuf, &state, &mut zbuf);
            for z in zbuf.chunks_exact(q).take(b - a) {
                for (j, &zj) in z.iter().enumerate() {
                    for (i, &zi) in z.iter().enumerate().skip(j) {
                        if let Some(m) = meat.get_mut((i, j)) {
                            *m += zi * zj;
                        }
                    }
                }
            }
            if let Some(slot) = states.get_mut(c) {
                *slot = state.clone();
            }
            let before: Vec<f64> = (0..p)
                .flat_map(|i| {
                    let row = if a + i < b {
                        zbuf.get((i * q)..((i + 1) * q))
                    } else {
                        state.get(((a + i - b) * q)..((a + i - b + 1) * q))
                    };
                    row.map_or_else(|| vec![0.0; q], <[f64]>::to_vec)
                })
                .collect();
            state = before;
        }
        for j in 0..q {
            for i in 0..j {
                let lower = meat.get((j, i)).copied().unwrap_or(0.0);
                if let Some(m) = meat.get_mut((i, j)) {
                    *m = lower;
                }
            }
        }
        let meat = meat * self.innovation_var;
        let c = inv * meat * inv;
        // Pass 2, from the start: each chunk's Z again, x_t = z_t + Σ φ_k x_{t−k−1} (t ≥ p),
        // b_t = σ_ε²·inv·x_t and hc_t = C·h_t, and the lagged sums with the p rows before.
        let mut acc = vec![0.0; p + 1];
        // The last p rows of h, b and hc (row t at t mod p), and of x.
        let mut ring_h = vec![0.0; p * q];
        let mut ring_b = vec![0.0; p * q];
        let mut ring_hc = vec![0.0; p * q];
        let mut ring_x = vec![0.0; p * q];
        let (mut x, mut bt, mut hc) = (vec![0.0; q], vec![0.0; q], vec![0.0; q]);
        for c_i in 0..chunks {
            let (a, b) = (c_i * CHUNK, ((c_i + 1) * CHUNK).min(n));
            fill_rows(h, a, b, &mut hbuf);
            let state = states.get(c_i).map_or(&[][..], Vec::as_slice);
            self.back_chunk((a, b, n, q), &hbuf, state, &mut zbuf);
            let rows = hbuf.chunks_exact(q).zip(zbuf.chunks_exact(q)).take(b - a);
            for (t, (ht, zt)) in (a..).zip(rows) {
                x.copy_from_slice(zt);
                if t >= p {
                    for (k, f) in self.ar.iter().enumerate() {
                        let slot = (t - k - 1) % p;
                        if let Some(earlier) = ring_x.get(slot * q..(slot + 1) * q) {
                            for (v, e) in x.iter_mut().zip(earlier) {
                                *v += f * e;
                            }
                        }
                    }
                }
                for (j, (bj, hcj)) in bt.iter_mut().zip(hc.iter_mut()).enumerate() {
                    let (mut sb, mut sc) = (0.0, 0.0);
                    for (i, (xi, hi)) in x.iter().zip(ht).enumerate() {
                        sb += xi * self.innovation_var * inv.get((i, j)).copied().unwrap_or(0.0);
                        sc += hi * c.get((i, j)).copied().unwrap_or(0.0);
                    }
                    *bj = sb;
                    *hcj = sc;
                }
                // Lag 0, then lags 1 … p with the rows before.
                let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
                if let Some(s) = acc.get_mut(0) {
                    *s += dot(&hc, ht) - dot(ht, &bt) - dot(ht, &bt);
                }
                for k in 1..=p.min(t) {
                    let slot = ((t - k) % p) * q..((t - k) % p + 1) * q;
                    let (Some(h0), Some(b0), Some(hc0)) = (
                        ring_h.get(slot.clone()),
                        ring_b.get(slot.clone()),
                        ring_hc.get(slot),
                    ) else {
                        continue;
                    };
                    if let Some(s) = acc.get_mut(k) {
                        *s += dot(hc0, ht) - dot(h0, &bt) - dot(ht, b0);
                    }
                }
                if p > 0 {
                    let slot = (t % p) * q..(t % p + 1) * q;
                    for (ring, row) in [
                        (&mut ring_h, ht),
                        (&mut ring_b, &bt[..]),
                        (&mut ring_hc, &hc[..]),
                        (&mut ring_x, &x[..]),
                    ] {
                        if let Some(dst) = ring.get_mut(slot.clone()) {
                            dst.copy_from_slice(row);
                        }
                    }
                }
            }
        }
        acc.iter()
            .enumerate()
            .map(|(k, s)| ((n - k) as f64 * self.var * self.autocorrelation(k) + s) / n as f64)
            .collect()
    }

    /// Z = A⁻ᵀH over rows a … b − 1 of n (their H in `h`, row-major, q columns), from the end:
    /// z_t = h_t + Σ φ_k z_{t+k+1} over the terms with t + k + 1 < n and ≥ p; `after` holds
    /// z_b … z_{b+p−1} (those below n).
    fn back_chunk(
        &self,
        (a, b, n, q): (usize, usize, usize, usize),
        h: &[f64],
        after: &[f64],
        z: &mut [f64],
    ) {
        let p = self.order();
        let len = b.saturating_sub(a);
        if let (Some(dst), Some(src)) = (z.get_mut(..len * q), h.get(..len * q)) {
            dst.copy_from_slice(src);
        }
        for t in (a..b).rev() {
            for (k, f) in self.ar.iter().enumerate() {
                let s = t + k + 1;
                if s >= n || s < p {
                    continue;
                }
                let (head, tail) = z.split_at_mut((t - a + 1) * q);
                let row = head.get_mut((t - a) * q..);
                let later = if s < b {
                    tail.get((s - t - 1) * q..(s - t) * q)
                } else {
                    after.get((s - b) * q..(s - b + 1) * q)
                };
                if let (Some(row), Some(later)) = (row, later) {
                    for (v, l) in row.iter_mut().zip(later) {
                        *v += f * l;
                    }
                }
            }
        }
    }
}

/// Rows a … b − 1 of `h` into `buf`, row-major.
fn fill_rows(h: &impl Rows, a: usize, b: usize, buf: &mut [f64]) {
    let q = h.cols();
    for (t, out) in (a..b).zip(buf.chunks_exact_mut(q.max(1))) {
        h.row(t, out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Held(DMatrix<f64>);

    impl Rows for Held {
        fn len(&self) -> usize {
            self.0.nrows()
        }
        fn cols(&self) -> usize {
            self.0.ncols()
        }
        fn row(&self, t: usize, out: &mut [f64]) {
            for (o, v) in out.iter_mut().zip(self.0.row(t).iter()) {
                *o = *v;
            }
        }
    }

    /// The streamed rescaling gives the held one's model to rounding, for AR(2) noise and
    /// regressors of a line and two sines over several chunks.
    #[test]
    fn streamed_rescaling_is_the_held_one() {
        let n = 3 * CHUNK + 77;
        let h = DMatrix::from_fn(n, 4, |t, j| {
            let x = t as f64 / n as f64;
            match j {
                0 => 1.0,
                1 => x,
                2 => (40.0 * x).sin(),
                _ => (40.0 * x).cos(),
            }
        });
        let e: Vec<f64> = {
            let mut s = 0.3f64;
            let mut prev = [0.0, 0.0];
            (0..n)
                .map(|_| {
                    // A deterministic pseudo-random innovation.
                    s = (s * 9301.0 + 49297.0) % 233280.0;
                    let eps = s / 233280.0 - 0.5;
                    let v = 0.6 * prev[0] - 0.2 * prev[1] + eps;
                    prev = [v, prev[0]];
                    v
                })
                .collect()
        };
        let flagged = vec![false; n];
        let m = NoiseModel::estimate(&e, &flagged).unwrap();
        assert!(m.order() > 0, "{m:?}");
        let inv = h.tr_mul(&h).try_inverse().unwrap();
        let held = m.clone().rescaled(&h).unwrap();
        let streamed = m.rescaled_rows(&Held(h), &inv).unwrap();
        assert!((held.var - streamed.var).abs() < 1e-12 * held.var);
        for (a, b) in held.ar.iter().zip(&streamed.ar) {
            assert!((a - b).abs() < 1e-10, "{a} {b}");
        }
    }
}
