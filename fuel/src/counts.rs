//! Tables of counts with row-normalised point estimates: the Dirichlet statistics of the
//! categorical components (eq. 12, 15) and of the switching model (eq. 16, 17) are the same
//! object, a table `count[row][col]` with `P(col | row) = count[row][col] / sum_s count[row][s]`.
//!
//! Erratum (seed-notes): eq. (15) as printed sums over components `s = 1..m_c` in the
//! denominator; the estimate of `P(z_t = l | psi = q)` normalises over the categories `s in z*`.

/// Counts `rows x cols`, with the prior each row starts from (for stabilised forgetting).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CountTable {
    cols: usize,
    counts: Vec<f64>,
    row_sums: Vec<f64>,
    prior: Vec<f64>,
}

impl CountTable {
    /// A table whose prior count in `[row][col]` is `prior(row, col)` (all must be > 0).
    pub fn new(rows: usize, cols: usize, prior: impl Fn(usize, usize) -> f64) -> Self {
        let mut counts = Vec::with_capacity(rows * cols);
        for r in 0..rows {
            for c in 0..cols {
                counts.push(prior(r, c));
            }
        }
        let mut t = CountTable {
            cols,
            prior: counts.clone(),
            counts,
            row_sums: vec![0.0; rows],
        };
        t.refresh_row_sums();
        t
    }

    fn refresh_row_sums(&mut self) {
        for (r, s) in self.row_sums.iter_mut().enumerate() {
            *s = self.counts[r * self.cols..(r + 1) * self.cols].iter().sum();
        }
    }

    pub fn rows(&self) -> usize {
        self.row_sums.len()
    }

    pub fn cols(&self) -> usize {
        self.cols
    }

    pub fn count(&self, row: usize, col: usize) -> f64 {
        self.counts[row * self.cols + col]
    }

    /// Point estimate `P(col | row)` (eq. 15 corrected, eq. 17).
    pub fn probability(&self, row: usize, col: usize) -> f64 {
        self.count(row, col) / self.row_sums[row]
    }

    /// `ln P(col | row)`.
    pub fn log_probability(&self, row: usize, col: usize) -> f64 {
        self.count(row, col).ln() - self.row_sums[row].ln()
    }

    /// `ln P(col | row)` of every column of `row`, into `out`: the row sum's logarithm is taken
    /// once (each value is [`log_probability`](Self::log_probability)'s, to the bit).
    pub fn log_probabilities_into(&self, row: usize, out: &mut [f64]) {
        let ln_sum = self.row_sums[row].ln();
        let counts = &self.counts[row * self.cols..(row + 1) * self.cols];
        for (o, c) in out.iter_mut().zip(counts) {
            *o = c.ln() - ln_sum;
        }
    }

    /// Eq. (12) / (16): `count[row][col] += weight`.
    pub fn add(&mut self, row: usize, col: usize, weight: f64) {
        self.counts[row * self.cols + col] += weight;
        self.row_sums[row] += weight;
    }

    /// Stabilised forgetting of one row: `count <- lambda count + (1 - lambda) prior`.
    pub fn forget_row(&mut self, row: usize, lambda: f64) {
        let range = row * self.cols..(row + 1) * self.cols;
        for (c, p) in self.counts[range.clone()]
            .iter_mut()
            .zip(&self.prior[range])
        {
            *c = lambda * *c + (1.0 - lambda) * p;
        }
        self.row_sums[row] = self.counts[row * self.cols..(row + 1) * self.cols]
            .iter()
            .sum();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_normalise_over_columns() {
        let mut t = CountTable::new(2, 3, |_, _| 1.0);
        t.add(0, 2, 3.0);
        assert!((t.probability(0, 2) - 4.0 / 6.0).abs() < 1e-15);
        assert!((t.probability(1, 2) - 1.0 / 3.0).abs() < 1e-15);
        let s: f64 = (0..3).map(|c| t.probability(0, c)).sum();
        assert!((s - 1.0).abs() < 1e-15);
        t.forget_row(0, 0.5);
        assert!((t.count(0, 2) - 2.5).abs() < 1e-15);
        assert!((t.log_probability(0, 2) - (2.5f64 / 4.5).ln()).abs() < 1e-15);
        // A whole row at once: the same bits.
        let mut row = [0.0; 3];
        t.log_probabilities_into(0, &mut row);
        for (c, v) in row.iter().enumerate() {
            assert_eq!(v.to_bits(), t.log_probability(0, c).to_bits());
        }
    }
}
