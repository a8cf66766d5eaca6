//! Sparse entries grouped by row, each row's in their original order: the
//! layout of the Gauss-Newton CG's products with `C`, `G` and `Cᵀ`
//! ([`super::gauss_newton::gn_solve_cg`]). A product is then a gather with
//! sequential writes over 12-byte entries instead of a scatter over 24-byte
//! triplets, and each output sums its terms in the entries' order from
//! zero, exactly as the scatter did: the products are the same bit for bit.

use super::error::SolveError;

/// `(row, col, value)` entries bucketed by row (a stable counting sort).
#[derive(Debug, Clone, PartialEq)]
pub(super) struct RowLists {
    ptr: Vec<usize>,
    col: Vec<u32>,
    val: Vec<f64>,
}

impl RowLists {
    /// The entries of a matrix with `rows` rows; columns must fit in `u32`.
    pub(super) fn new<I>(rows: usize, entries: I) -> Result<RowLists, SolveError>
    where
        I: Iterator<Item = (usize, usize, f64)> + Clone,
    {
        let mut ptr = vec![0usize; rows + 1];
        for (r, c, _) in entries.clone() {
            if r >= rows || c > u32::MAX as usize {
                return Err(SolveError::RowEntryOutOfRange {
                    row: r,
                    col: c,
                    rows,
                });
            }
            ptr[r + 1] += 1;
        }
        for r in 0..rows {
            ptr[r + 1] += ptr[r];
        }
        let mut fill = ptr.clone();
        let mut col = vec![0u32; ptr[rows]];
        let mut val = vec![0.0; ptr[rows]];
        for (r, c, v) in entries {
            col[fill[r]] = c as u32;
            val[fill[r]] = v;
            fill[r] += 1;
        }
        Ok(RowLists { ptr, col, val })
    }

    /// `y[r] = Σ val · x[col]` over row `r`'s entries in their order, for
    /// every row (`y` has one value per row).
    pub(super) fn mul(&self, x: &[f64], y: &mut [f64]) {
        for (r, out) in y.iter_mut().enumerate() {
            let (a, b) = (self.ptr[r], self.ptr[r + 1]);
            let mut s = 0.0;
            for (&c, &v) in self.col[a..b].iter().zip(&self.val[a..b]) {
                s += v * x[c as usize];
            }
            *out = s;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn products_equal_the_scatter_bit_for_bit() {
        // Duplicates, empty rows and terms whose sum depends on the order.
        let entries = [
            (2, 0, 1e16),
            (0, 1, 0.1),
            (2, 1, 1.0),
            (0, 1, 0.2),
            (2, 0, -1e16),
            (0, 2, 0.3),
            (3, 2, -0.7),
        ];
        let x = [1.0, 3.0, 0.5];
        let mut scatter = [0.0; 5];
        for &(r, c, v) in &entries {
            scatter[r] += v * x[c];
        }
        let lists = RowLists::new(5, entries.iter().copied()).unwrap();
        let mut y = [f64::NAN; 5];
        lists.mul(&x, &mut y);
        assert_eq!(y.map(f64::to_bits), scatter.map(f64::to_bits));
        assert!(RowLists::new(2, entries.iter().copied()).is_err());
    }
}
