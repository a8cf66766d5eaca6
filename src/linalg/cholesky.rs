//! Sparse SPD factorization shared by the solvers (Y2V shape fit, PD global
//! step): faer's symbolic Cholesky once per sparsity pattern, the numeric
//! factor when values change, solves on many right-hand sides. Numeric
//! factorization and each column group's solve are sequential so the same
//! inputs give bit-identical results whatever the thread count (callers
//! parallelise across frames or tets; solves split the columns in a fixed
//! way, [`SparseCholesky::solve_in_place`]).

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::perm::{Perm, PermRef};
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky,
    SymmetricOrdering,
};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::SparseColMatRef;
use faer::{MatMut, Par};

use super::error::LinalgError;

/// Systems below this size are solved in one task (the split costs more
/// than it saves).
const PARALLEL_SOLVE_MIN_ROWS: usize = 2000;

/// A Cholesky factor L L^T of a sparse SPD matrix given by its lower triangle.
///
/// `S` holds the symbolic analysis: owned (the default; given back by
/// [`Self::into_symbolic`] for the next refactorization), or shared
/// (`Arc<SymbolicCholesky<usize>>`) by factors that live side by side.
#[derive(Debug)]
pub struct SparseCholesky<S = SymbolicCholesky<usize>> {
    symbolic: S,
    values: Vec<f64>,
}

/// faer's symbolic Cholesky of the lower triangle `lower` with `params`.
fn symbolic_with(
    lower: SparseColMatRef<'_, usize, f64>,
    params: CholeskySymbolicParams<'_>,
) -> Result<SymbolicCholesky<usize>, LinalgError> {
    symbolic_ordered_with(lower, SymmetricOrdering::Amd, params)
}

fn symbolic_ordered_with(
    lower: SparseColMatRef<'_, usize, f64>,
    ordering: SymmetricOrdering<'_, usize>,
    params: CholeskySymbolicParams<'_>,
) -> Result<SymbolicCholesky<usize>, LinalgError> {
    factorize_symbolic_cholesky(lower.symbolic(), faer::Side::Lower, ordering, params)
        .map_err(LinalgError::Symbolic)
}

impl SparseCholesky {
    /// Symbolic analysis of the pattern of `lower` (lower triangle of the matrix).
    pub fn symbolic(
        lower: SparseColMatRef<'_, usize, f64>,
    ) -> Result<SymbolicCholesky<usize>, LinalgError> {
        symbolic_with(lower, Default::default())
    }

    /// [`Self::symbolic`] that always picks faer's supernodal factorization.
    /// For the PD global matrix (a tet mesh's node graph) this refactors
    /// about 1.3x faster than the simplicial one faer's heuristic picks for
    /// a 1,568-node mesh, and PD refactors whenever its contact set grows.
    pub fn symbolic_supernodal(
        lower: SparseColMatRef<'_, usize, f64>,
    ) -> Result<SymbolicCholesky<usize>, LinalgError> {
        symbolic_with(
            lower,
            CholeskySymbolicParams {
                supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
                ..Default::default()
            },
        )
    }

    /// [`Self::symbolic`] with a given fill-reducing `ordering` instead of
    /// AMD's (e.g. the AMD ordering of a nearby pattern: the analysis then
    /// costs about a third).
    pub fn symbolic_ordered(
        lower: SparseColMatRef<'_, usize, f64>,
        ordering: PermRef<'_, usize>,
    ) -> Result<SymbolicCholesky<usize>, LinalgError> {
        symbolic_ordered_with(
            lower,
            SymmetricOrdering::Custom(ordering),
            Default::default(),
        )
    }

    /// The fill-reducing ordering of an analysis (identity when it has none).
    pub fn ordering(symbolic: &SymbolicCholesky<usize>) -> Perm<usize> {
        let n = symbolic.nrows();
        match symbolic.perm() {
            Some(p) => {
                let (fwd, inv) = p.arrays();
                Perm::new_checked(fwd.into(), inv.into(), n)
            }
            None => Perm::new_checked((0..n).collect(), (0..n).collect(), n),
        }
    }

    /// Symbolic and numeric factorization in one go.
    pub fn new(lower: SparseColMatRef<'_, usize, f64>) -> Result<Self, LinalgError> {
        Self::numeric(Self::symbolic(lower)?, lower)
    }
}

impl<S: std::borrow::Borrow<SymbolicCholesky<usize>> + Sync> SparseCholesky<S> {
    /// Numeric factorization of `lower` with a symbolic analysis of its pattern.
    pub fn numeric(
        symbolic: S,
        lower: SparseColMatRef<'_, usize, f64>,
    ) -> Result<Self, LinalgError> {
        Self::numeric_into(symbolic, lower, Vec::new())
    }

    /// [`Self::numeric`] writing the factor into `values` (the values of an
    /// earlier factor, [`Self::into_parts`]: a refactorization then touches
    /// no fresh pages).
    pub fn numeric_into(
        symbolic: S,
        lower: SparseColMatRef<'_, usize, f64>,
        mut values: Vec<f64>,
    ) -> Result<Self, LinalgError> {
        let par = Par::Seq;
        let sym = symbolic.borrow();
        let len = sym.len_val();
        if values.capacity() >= len {
            values.clear();
            values.resize(len, 0.0);
        } else {
            values = vec![0.0; len];
        }
        sym.factorize_numeric_llt::<f64>(
            &mut values,
            lower,
            faer::Side::Lower,
            Default::default(),
            par,
            MemStack::new(&mut MemBuffer::new(
                sym.factorize_numeric_llt_scratch::<f64>(par, Default::default()),
            )),
            Default::default(),
        )?;
        Ok(SparseCholesky { symbolic, values })
    }

    /// Order of the factored matrix.
    pub fn dim(&self) -> usize {
        self.symbolic.borrow().nrows()
    }

    /// Gives back the symbolic analysis, to refactor a matrix with the same pattern.
    pub fn into_symbolic(self) -> S {
        self.symbolic
    }

    /// The symbolic analysis and the factor's value buffer (for
    /// [`Self::numeric_into`]).
    pub fn into_parts(self) -> (S, Vec<f64>) {
        (self.symbolic, self.values)
    }

    /// Solves A X = B in place for every column of `rhs`.
    ///
    /// The first column and the others are solved as two independent tasks
    /// (`rayon::join`): the triangular solves are memory-bound on the factor,
    /// so on two cores this takes about the time of the larger part instead
    /// of the whole. The split does not depend on the thread count, so the
    /// result is the same with any number of threads.
    pub fn solve_in_place(&self, rhs: MatMut<'_, f64>) {
        if rhs.ncols() >= 2 && self.dim() >= PARALLEL_SOLVE_MIN_ROWS {
            let (first, rest) = rhs.split_at_col_mut(1);
            rayon::join(|| self.solve_seq(first), || self.solve_seq(rest));
        } else {
            self.solve_seq(rhs);
        }
    }

    fn solve_seq(&self, rhs: MatMut<'_, f64>) {
        let ncols = rhs.ncols();
        let sym = self.symbolic.borrow();
        LltRef::new(sym, &self.values).solve_in_place_with_conj(
            faer::Conj::No,
            rhs,
            Par::Seq,
            MemStack::new(&mut MemBuffer::new(
                sym.solve_in_place_scratch::<f64>(ncols, Par::Seq),
            )),
        );
    }
}
