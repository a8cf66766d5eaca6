//! The free-free lower triangle of the Newton matrix in compressed-column
//! form, assembled from the terms' [`Triplets`] by a counting sort (linear
//! in the entries; the buffers live across Newton iterations, so a solve
//! allocates them once).
//!
//! Duplicates are summed in the order the terms pushed them, so the values
//! do not depend on the thread count. Every column carries its diagonal
//! (explicit zero where no term reaches), always as the column's first
//! entry: a diagonal shift then changes values only, never the pattern.

use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};

use super::term::Triplets;

/// Reusable compressed-column lower triangle over the free coordinates.
#[derive(Debug, Default, Clone)]
pub struct LowerCsc {
    n: usize,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    vals: Vec<f64>,
    /// Diagonal entries as assembled (before any shift).
    diag: Vec<f64>,
    /// Scratch: per column fill position, then the bucketed entries.
    fill: Vec<usize>,
    bucket: Vec<(u32, f64)>,
    /// Scratch: one column's distinct rows with their sums, and where each
    /// row sits in it (valid only where `uniq[pos[r]].0 == r`).
    uniq: Vec<(u32, f64)>,
    pos: Vec<u32>,
}

impl LowerCsc {
    pub fn new() -> LowerCsc {
        LowerCsc::default()
    }

    /// Rebuilds the matrix from `trip` (both triangles, global indices):
    /// `index[i]` is the free index of global coordinate `i`, `usize::MAX`
    /// when fixed; entries touching a fixed coordinate or above the
    /// diagonal are dropped. Returns the sum of the diagonal entries.
    pub fn assemble(&mut self, trip: &Triplets, index: &[usize], nf: usize) -> f64 {
        self.n = nf;
        let keep = |r: u32, c: u32| -> Option<(usize, usize)> {
            let (fr, fc) = (index[r as usize], index[c as usize]);
            (fr != usize::MAX && fc != usize::MAX && fr >= fc).then_some((fr, fc))
        };
        // Count per column (one slot for the diagonal in each).
        self.fill.clear();
        self.fill.resize(nf + 1, 0);
        for c in 0..nf {
            self.fill[c + 1] = 1;
        }
        for (&r, &c) in trip.rows.iter().zip(&trip.cols) {
            if let Some((_, fc)) = keep(r, c) {
                self.fill[fc + 1] += 1;
            }
        }
        for c in 0..nf {
            self.fill[c + 1] += self.fill[c];
        }
        let total = self.fill[nf];
        // Bucket by column, the diagonal first, then the entries in push order
        // (every slot below `total` is written, so stale ones need no zeroing).
        if self.bucket.len() < total {
            self.bucket.resize(total, (0, 0.0));
        }
        let mut start = std::mem::take(&mut self.col_ptr);
        start.clear();
        start.extend_from_slice(&self.fill);
        for c in 0..nf {
            self.bucket[self.fill[c]] = (c as u32, 0.0);
            self.fill[c] += 1;
        }
        for ((&r, &c), &v) in trip.rows.iter().zip(&trip.cols).zip(&trip.vals) {
            if let Some((fr, fc)) = keep(r, c) {
                self.bucket[self.fill[fc]] = (fr as u32, v);
                self.fill[fc] += 1;
            }
        }
        // Per column: sum the duplicates in push order (a row's sum is the
        // same, bit for bit, as summing after a stable sort), then sort the
        // distinct rows. Columns hold ~100 entries in block order for a few
        // dozen rows: sorting them all took a third of the assembly.
        self.row_idx.clear();
        self.vals.clear();
        self.col_ptr.clear();
        self.col_ptr.push(0);
        self.diag.clear();
        self.pos.resize(nf, 0);
        for c in 0..nf {
            self.uniq.clear();
            for &(r, v) in &self.bucket[start[c]..start[c + 1]] {
                let p = self.pos[r as usize] as usize;
                match self.uniq.get_mut(p) {
                    Some(e) if e.0 == r => e.1 += v,
                    _ => {
                        self.pos[r as usize] = self.uniq.len() as u32;
                        self.uniq.push((r, v));
                    }
                }
            }
            // Rows are distinct: an unstable sort is deterministic here.
            self.uniq.sort_unstable_by_key(|e| e.0);
            for &(r, v) in &self.uniq {
                self.row_idx.push(r as usize);
                self.vals.push(v);
            }
            // The diagonal is the column's smallest row (lower triangle).
            self.diag.push(self.vals[self.col_ptr[c]]);
            self.col_ptr.push(self.row_idx.len());
        }
        self.diag.iter().sum()
    }

    /// Sets every diagonal entry to its assembled value plus `shift`.
    pub fn shift_diagonal(&mut self, shift: f64) {
        for c in 0..self.n {
            self.vals[self.col_ptr[c]] = self.diag[c] + shift;
        }
    }

    /// Order of the matrix (free coordinates).
    pub fn dim(&self) -> usize {
        self.n
    }

    /// Column pointers and row indices (the sparsity pattern).
    pub fn pattern(&self) -> (&[usize], &[usize]) {
        (&self.col_ptr, &self.row_idx)
    }

    /// The matrix (lower triangle) as a faer view.
    pub fn as_ref(&self) -> SparseColMatRef<'_, usize, f64> {
        let symbolic = SymbolicSparseColMatRef::new_checked(
            self.n,
            self.n,
            &self.col_ptr,
            None,
            &self.row_idx,
        );
        SparseColMatRef::new(symbolic, &self.vals)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Dense reference: the free lower triangle summed entry by entry.
    fn dense(trip: &Triplets, index: &[usize], nf: usize) -> Vec<Vec<f64>> {
        let mut m = vec![vec![0.0; nf]; nf];
        for ((&r, &c), &v) in trip.rows.iter().zip(&trip.cols).zip(&trip.vals) {
            let (fr, fc) = (index[r as usize], index[c as usize]);
            if fr != usize::MAX && fc != usize::MAX && fr >= fc {
                m[fr][fc] += v;
            }
        }
        m
    }

    #[test]
    fn matches_dense_sum_with_duplicates_fixed_and_empty_columns() {
        let n = 9;
        // Coordinates 2 and 6 fixed.
        let mut index = vec![usize::MAX; n];
        let mut k = 0;
        for (i, slot) in index.iter_mut().enumerate() {
            if i != 2 && i != 6 {
                *slot = k;
                k += 1;
            }
        }
        let nf = k;
        let mut trip = Triplets::new();
        let mut seed = 7u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 33) as usize
        };
        // Random symmetric blocks (global coordinate 8 never touched: its
        // column has only the explicit zero diagonal).
        for _ in 0..40 {
            let dofs: Vec<usize> = (0..3).map(|_| rnd() % 8).collect();
            let mut block = vec![0.0; 9];
            for a in 0..3 {
                for b in a..3 {
                    let v = (rnd() % 1000) as f64 / 100.0 - 5.0;
                    block[a * 3 + b] = v;
                    block[b * 3 + a] = v;
                }
            }
            trip.push_block(&dofs, &block);
        }
        let mut m = LowerCsc::new();
        // Twice: the buffers are reused.
        for _ in 0..2 {
            let diag = m.assemble(&trip, &index, nf);
            let want = dense(&trip, &index, nf);
            let (cp, ri) = m.pattern();
            assert_eq!(cp.len(), nf + 1);
            let mut got = vec![vec![0.0; nf]; nf];
            for c in 0..nf {
                assert_eq!(ri[cp[c]], c, "diagonal first in column {c}");
                for p in cp[c]..cp[c + 1] {
                    if p > cp[c] {
                        assert!(ri[p] > ri[p - 1], "rows sorted, no duplicates");
                    }
                    got[ri[p]][c] = m.vals[p];
                }
            }
            for r in 0..nf {
                for c in 0..=r {
                    assert!((got[r][c] - want[r][c]).abs() < 1e-12, "({r}, {c})");
                }
            }
            let want_diag: f64 = (0..nf).map(|c| want[c][c]).sum();
            assert!((diag - want_diag).abs() < 1e-12);
            m.shift_diagonal(1.0);
            m.shift_diagonal(2.5);
            let mat = m.as_ref();
            assert_eq!(mat.nrows(), nf);
            let d_last = m.vals[m.col_ptr[nf - 1]];
            assert!((d_last - (want[nf - 1][nf - 1] + 2.5)).abs() < 1e-12);
        }
        // Fewer triplets into the same buffers: nothing stale survives.
        let keep = 9 * 15;
        let small = Triplets {
            rows: trip.rows[..keep].to_vec(),
            cols: trip.cols[..keep].to_vec(),
            vals: trip.vals[..keep].to_vec(),
        };
        m.assemble(&small, &index, nf);
        let want = dense(&small, &index, nf);
        let (cp, ri) = m.pattern();
        let mut got = vec![vec![0.0; nf]; nf];
        for c in 0..nf {
            for p in cp[c]..cp[c + 1] {
                got[ri[p]][c] = m.vals[p];
            }
        }
        assert_eq!(got, want);
    }

    /// Each distinct entry is the sum of its duplicates in push order, bit
    /// for bit (what a stable sort by row, then a running sum, gives).
    #[test]
    fn duplicates_sum_in_push_order() {
        let mut trip = Triplets::new();
        let vals = [1e16, 1.0, -1e16, 3.0, 0.5];
        for &v in &vals {
            trip.push_block(&[1, 0], &[v, v, v, v]);
        }
        let mut m = LowerCsc::new();
        m.assemble(&trip, &[0, 1], 2);
        let want = vals.iter().fold(0.0, |a, v| a + v);
        let (cp, ri) = m.pattern();
        assert_eq!((cp, ri), (&[0, 2, 3][..], &[0, 1, 1][..]));
        assert_eq!(m.vals, vec![want, want, want]);
    }
}
