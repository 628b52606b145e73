//! Rows whitened and least-squares systems reduced as the rows stream past, so that a fit
//! holds a few hundred rows at a time and never a group's (an hour at 104 Hz is 374 400
//! rows per group: a dense design of a dozen columns would be 36 MB).

use crate::fit::noise::NoiseModel;
use nalgebra::DMatrix;

/// Rows gathered before each chunk is factored into the triangle.
const CHUNK: usize = 512;

/// A least-squares system of `w` columns reduced to its triangle R (RᵀR = XᵀX) as rows
/// arrive: each chunk of rows is stacked under the triangle so far and factored again (a
/// tall-skinny QR, as stable as one QR of all the rows).
pub(crate) struct Triangle {
    r: DMatrix<f64>,
    /// Rows not yet factored, row-major.
    pending: Vec<f64>,
    w: usize,
}

impl Triangle {
    /// An empty system of `w` columns.
    pub(crate) fn new(w: usize) -> Self {
        Triangle {
            r: DMatrix::zeros(w, w),
            pending: Vec::with_capacity(CHUNK * w),
            w,
        }
    }

    /// One row (its first `w` values).
    pub(crate) fn push(&mut self, row: &[f64]) {
        self.pending.extend(row.iter().take(self.w));
        if self.pending.len() >= CHUNK * self.w {
            self.flush();
        }
    }

    /// Rows given as a matrix of `w` columns (another system's triangle, say).
    pub(crate) fn push_matrix(&mut self, m: &DMatrix<f64>) {
        for row in m.row_iter() {
            let values: Vec<f64> = row.iter().copied().collect();
            self.push(&values);
        }
    }

    fn flush(&mut self) {
        if self.pending.is_empty() || self.w == 0 {
            return;
        }
        let rows = self.pending.len() / self.w;
        let r_rows = self.r.transpose();
        let stacked = DMatrix::from_row_iterator(
            self.w + rows,
            self.w,
            r_rows.iter().chain(&self.pending).copied(),
        );
        self.r = stacked.qr().r();
        self.pending.clear();
    }

    /// The triangle, w × w.
    pub(crate) fn finish(mut self) -> DMatrix<f64> {
        self.flush();
        self.r
    }
}

/// A group's channel's rows through its noise filter as they stream past, as
/// [`super::whiten`] does to a whole column: row t is kept if t ≥ p and no flagged row
/// lies in t − p … t, and then becomes (x_t − Σ φ_k x_{t−k})/σ_ε, column by column (the
/// terms subtracted in the same order, so the same numbers).
pub(crate) struct Whitener<'a> {
    ar: &'a [f64],
    scale: f64,
    w: usize,
    /// Raw rows, row-major, the latest at `len − 1`; slid back to its last p rows when
    /// full, so the rows t − 1 … t − p are always contiguous before t's.
    history: Vec<f64>,
    len: usize,
    t: usize,
    last_flag: Option<usize>,
}

/// Rows the history holds beyond p before it slides.
const SLACK: usize = 256;

impl<'a> Whitener<'a> {
    /// For rows of `w` values under `m`.
    pub(crate) fn new(m: &'a NoiseModel, w: usize) -> Self {
        Whitener {
            ar: &m.ar,
            scale: 1.0 / m.innovation_var.sqrt().max(f64::MIN_POSITIVE),
            w,
            history: vec![0.0; (m.ar.len() + SLACK) * w],
            len: 0,
            t: 0,
            last_flag: None,
        }
    }

    /// The next raw row (`flagged`: a reading at a rail); if it is kept, its whitened
    /// values go to `out` and the answer is true.
    pub(crate) fn push(&mut self, raw: &[f64], flagged: bool, out: &mut [f64]) -> bool {
        let (t, p, w) = (self.t, self.ar.len(), self.w);
        if flagged {
            self.last_flag = Some(t);
        }
        let keep = t >= p && self.last_flag.is_none_or(|l| t - l > p);
        if keep {
            let out = out.get_mut(..w).unwrap_or_default();
            for (o, &x) in out.iter_mut().zip(raw) {
                *o = x;
            }
            for (k, f) in self.ar.iter().enumerate() {
                // Row t − k − 1, the (k + 1)-th latest.
                let at = (self.len - k - 1) * w;
                if let Some(before) = self.history.get(at..at + w) {
                    for (o, b) in out.iter_mut().zip(before) {
                        *o -= f * b;
                    }
                }
            }
            for o in out.iter_mut() {
                *o *= self.scale;
            }
        }
        if p > 0 {
            if (self.len + 1) * w > self.history.len() {
                // Keep the last p rows, at the start.
                let from = (self.len - p) * w;
                self.history.copy_within(from..self.len * w, 0);
                self.len = p;
            }
            if let Some(slot) = self.history.get_mut(self.len * w..(self.len + 1) * w) {
                for (h, &x) in slot.iter_mut().zip(raw) {
                    *h = x;
                }
            }
            self.len += 1;
        }
        self.t += 1;
        keep
    }
}

#[cfg(test)]
#[allow(clippy::indexing_slicing)]
mod tests {
    use super::*;

    /// Streaming whitening gives what [`super::super::whiten`] gives a whole column, rows
    /// left out at the start and around flagged rows alike; and the triangle of the kept
    /// rows, chunk by chunk, has RᵀR = XᵀX.
    #[test]
    fn streamed_rows_match_the_whole_column() {
        let mut m = NoiseModel::white(4.0, 50);
        m.ar = vec![0.5, -0.2, 0.1];
        let n = 1500;
        let flagged: Vec<bool> = (0..n).map(|i| i == 20 || i == 900).collect();
        let cols: Vec<Vec<f64>> = (0..3)
            .map(|c| {
                (0..n)
                    .map(|i| (((i * (7 + c)) % 13) as f64 - 6.0) * 0.3 + c as f64)
                    .collect()
            })
            .collect();
        let keep = super::super::kept(m.order(), &flagged);
        let whole: Vec<Vec<f64>> = cols
            .iter()
            .map(|c| {
                let mut x = c.clone();
                super::super::whiten(&m, &mut x, &keep);
                x
            })
            .collect();
        let mut wh = Whitener::new(&m, 3);
        let mut tri = Triangle::new(3);
        let mut out = [0.0; 3];
        let mut dense = Vec::new();
        for i in 0..n {
            let raw: Vec<f64> = cols.iter().map(|c| c[i]).collect();
            let kept = wh.push(&raw, flagged[i], &mut out);
            assert_eq!(kept, keep[i], "row {i}");
            for (j, w) in whole.iter().enumerate() {
                let expected = if kept { out[j] } else { 0.0 };
                assert!((w[i] - expected).abs() < 1e-12, "row {i} col {j}");
            }
            if kept {
                tri.push(&out);
                dense.extend_from_slice(&out);
            }
        }
        let r = tri.finish();
        let x = DMatrix::from_row_slice(dense.len() / 3, 3, &dense);
        let gram = x.transpose() * &x;
        let rtr = r.transpose() * &r;
        assert!((gram - &rtr).norm() < 1e-9 * rtr.norm());
    }
}
