//! The contract between the quasi-static solver and its energy terms.

/// Sparse symmetric matrix entries, as pushed by the terms: **both**
/// triangles of every element block (the solver keeps what it needs).
/// Duplicates add up.
#[derive(Debug, Clone, Default)]
pub struct Triplets {
    pub rows: Vec<u32>,
    pub cols: Vec<u32>,
    pub vals: Vec<f64>,
}

impl Triplets {
    pub fn new() -> Triplets {
        Triplets::default()
    }

    pub fn len(&self) -> usize {
        self.vals.len()
    }

    pub fn is_empty(&self) -> bool {
        self.vals.is_empty()
    }

    pub fn clear(&mut self) {
        self.rows.clear();
        self.cols.clear();
        self.vals.clear();
    }

    #[inline]
    pub fn push(&mut self, row: usize, col: usize, val: f64) {
        self.rows.push(row as u32);
        self.cols.push(col as u32);
        self.vals.push(val);
    }

    /// Adds the dense symmetric block `block` (row-major, `dofs.len()`
    /// squared) at the global indices `dofs`.
    pub fn push_block(&mut self, dofs: &[usize], block: &[f64]) {
        let n = dofs.len();
        debug_assert_eq!(block.len(), n * n);
        for (a, &ra) in dofs.iter().enumerate() {
            for (b, &cb) in dofs.iter().enumerate() {
                let v = block[a * n + b];
                if v != 0.0 {
                    self.push(ra, cb, v);
                }
            }
        }
    }

    /// Appends `n` zero entries and returns them as a sink that parallel
    /// element loops fill in disjoint, fixed places (no per-chunk buffers,
    /// no copying; the order of the entries is the order of the elements).
    pub fn reserve_sink(&mut self, n: usize) -> BlockSink<'_> {
        let base = self.len();
        self.rows.resize(base + n, 0);
        self.cols.resize(base + n, 0);
        self.vals.resize(base + n, 0.0);
        BlockSink {
            rows: &mut self.rows[base..],
            cols: &mut self.cols[base..],
            vals: &mut self.vals[base..],
            at: 0,
        }
    }

    /// Appends another set of entries.
    pub fn extend(&mut self, other: &Triplets) {
        self.rows.extend_from_slice(&other.rows);
        self.cols.extend_from_slice(&other.cols);
        self.vals.extend_from_slice(&other.vals);
    }
}

/// A fixed-size region of [`Triplets`] written block by block (every entry
/// of a block, zeros included, so each element's place is known in
/// advance).
#[derive(Debug)]
pub struct BlockSink<'a> {
    rows: &'a mut [u32],
    cols: &'a mut [u32],
    vals: &'a mut [f64],
    at: usize,
}

impl<'a> BlockSink<'a> {
    /// Splits off the first `n` entries (for one parallel work item).
    pub fn split_off_front(&mut self, n: usize) -> BlockSink<'a> {
        let rows = std::mem::take(&mut self.rows);
        let cols = std::mem::take(&mut self.cols);
        let vals = std::mem::take(&mut self.vals);
        let (r0, r1) = rows.split_at_mut(n);
        let (c0, c1) = cols.split_at_mut(n);
        let (v0, v1) = vals.split_at_mut(n);
        self.rows = r1;
        self.cols = c1;
        self.vals = v1;
        BlockSink {
            rows: r0,
            cols: c0,
            vals: v0,
            at: 0,
        }
    }

    /// Entries not yet written.
    pub fn remaining(&self) -> usize {
        self.vals.len() - self.at
    }

    /// Writes the dense symmetric block `block` (row-major, `dofs.len()`
    /// squared) at the global indices `dofs`.
    #[inline]
    pub fn block(&mut self, dofs: &[usize], block: &[f64]) {
        let n = dofs.len();
        debug_assert_eq!(block.len(), n * n);
        let at = self.at;
        for (a, &ra) in dofs.iter().enumerate() {
            for (b, &cb) in dofs.iter().enumerate() {
                let k = at + a * n + b;
                self.rows[k] = ra as u32;
                self.cols[k] = cb as u32;
                self.vals[k] = block[a * n + b];
            }
        }
        self.at += n * n;
    }
}

/// One term of the total potential `E(q) = sum of terms`.
///
/// `eval` must be a pure function of `q` and the term's state; the state
/// changes only in [`EnergyTerm::begin_iteration`] and
/// [`EnergyTerm::accept`], so a line search can evaluate trial points freely.
pub trait EnergyTerm: Send + Sync {
    /// Short name for statistics ("stretch", "bend", "twist", "contact", ...).
    fn name(&self) -> &'static str;

    /// Energy (J) at `q`; adds `dE/dq` into `grad` (same length as `q`); when
    /// `hess` is given, pushes a symmetric positive semi-definite
    /// approximation of `d2E/dq2` (exact where the term is convex, projected
    /// or Gauss-Newton otherwise; each term documents which).
    fn eval(&self, q: &[f64], grad: &mut [f64], hess: Option<&mut Triplets>) -> f64;

    /// Called at the start of every Newton iteration with the current
    /// iterate (contact pairs, lagged friction normals, reference frames).
    fn begin_iteration(&mut self, _q: &[f64]) {}

    /// Largest step fraction in (0, 1] such that `q + alpha dq` stays
    /// admissible for this term (e.g. no pull-through); 1 when unbounded.
    fn max_step(&self, _q: &[f64], _dq: &[f64]) -> f64 {
        1.0
    }

    /// Lowers `caps[v]`, the largest displacement (m) vertex `v` may make in
    /// one iteration, where this term needs it (contact: no yarn may pass
    /// through another within a step). Default: no bound.
    fn limit_vertex_moves(&self, _q: &[f64], _caps: &mut [f64]) {}

    /// Called once a step has been accepted with the new iterate.
    fn accept(&mut self, _q: &[f64]) {}
}
