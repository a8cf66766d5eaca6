//! Compressed sparse row matrices for the iterative parts of the global step
//! (Jacobi / Chebyshev iterations on the CPU and the GPU share this layout).

use super::error::LinalgError;

/// A square sparse matrix in CSR form with `f64` values. Row `r` holds the
/// columns `col[row_ptr[r]..row_ptr[r + 1]]` (sorted, distinct) with the
/// values at the same positions. Symmetric matrices store both triangles.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CsrMatrix {
    /// Number of rows (= columns).
    pub n: usize,
    /// Row starts, length `n + 1`, non-decreasing, `row_ptr[n] = col.len()`.
    pub row_ptr: Vec<usize>,
    /// Column index of every stored entry.
    pub col: Vec<usize>,
    /// Value of every stored entry.
    pub val: Vec<f64>,
}

impl CsrMatrix {
    /// Builds the matrix from `(row, col, value)` entries; duplicates are
    /// summed. Entries out of range are an error naming the first one.
    pub fn from_triplets(
        n: usize,
        entries: &[(usize, usize, f64)],
    ) -> Result<CsrMatrix, LinalgError> {
        if let Some(&(r, c, _)) = entries.iter().find(|(r, c, _)| *r >= n || *c >= n) {
            return Err(LinalgError::EntryOutOfRange { row: r, col: c, n });
        }
        let mut sorted: Vec<(usize, usize, f64)> = entries.to_vec();
        sorted.sort_by_key(|a| (a.0, a.1));
        let mut row_ptr = vec![0usize; n + 1];
        let mut col = Vec::with_capacity(sorted.len());
        let mut val: Vec<f64> = Vec::with_capacity(sorted.len());
        let mut last: Option<(usize, usize)> = None;
        for (r, c, v) in sorted {
            if last == Some((r, c)) {
                if let Some(x) = val.last_mut() {
                    *x += v;
                }
                continue;
            }
            last = Some((r, c));
            row_ptr[r + 1] += 1;
            col.push(c);
            val.push(v);
        }
        for r in 0..n {
            row_ptr[r + 1] += row_ptr[r];
        }
        Ok(CsrMatrix {
            n,
            row_ptr,
            col,
            val,
        })
    }

    /// The diagonal (zero where no entry is stored).
    pub fn diagonal(&self) -> Vec<f64> {
        (0..self.n)
            .map(|r| {
                (self.row_ptr[r]..self.row_ptr[r + 1])
                    .find(|&k| self.col[k] == r)
                    .map_or(0.0, |k| self.val[k])
            })
            .collect()
    }

    /// `y = A x` for `m` right-hand sides stored row-major (`x[r * m + k]`).
    pub fn mul_rows(&self, x: &[f64], m: usize, y: &mut [f64]) {
        debug_assert_eq!(x.len(), self.n * m);
        debug_assert_eq!(y.len(), self.n * m);
        for r in 0..self.n {
            for k in 0..m {
                let mut s = 0.0;
                for e in self.row_ptr[r]..self.row_ptr[r + 1] {
                    s += self.val[e] * x[self.col[e] * m + k];
                }
                y[r * m + k] = s;
            }
        }
    }
}

/// Triplets of the `n x n` tridiagonal matrix with `diag` on the diagonal
/// and -1 beside it (both triangles): the 1D test matrix of the solvers.
#[cfg(test)]
pub(crate) fn tridiagonal_triplets(n: usize, diag: f64) -> Vec<(usize, usize, f64)> {
    let mut t = Vec::new();
    for i in 0..n {
        t.push((i, i, diag));
        if i + 1 < n {
            t.push((i, i + 1, -1.0));
            t.push((i + 1, i, -1.0));
        }
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn triplets_sum_duplicates_and_multiply() {
        let a = CsrMatrix::from_triplets(
            3,
            &[
                (0, 0, 2.0),
                (1, 1, 3.0),
                (0, 1, 1.0),
                (1, 0, 1.0),
                (0, 0, 1.0),
                (2, 2, 4.0),
            ],
        )
        .unwrap();
        assert_eq!(a.row_ptr, vec![0, 2, 4, 5]);
        assert_eq!(a.diagonal(), vec![3.0, 3.0, 4.0]);
        let x = [1.0, 10.0, 2.0, 20.0, 3.0, 30.0];
        let mut y = [0.0; 6];
        a.mul_rows(&x, 2, &mut y);
        assert_eq!(y, [5.0, 50.0, 7.0, 70.0, 12.0, 120.0]);
        assert!(CsrMatrix::from_triplets(2, &[(2, 0, 1.0)]).is_err());
    }
}
