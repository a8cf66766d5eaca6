//! Sparse SPD factorization shared by the solvers (Y2V shape fit, PD global
//! step): faer's symbolic Cholesky once per sparsity pattern, the numeric
//! factor when values change, solves on many right-hand sides. Numeric
//! factorization and solves are sequential so the same inputs give
//! bit-identical results whatever the thread count (callers parallelise
//! across frames or tets instead).

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::cholesky::{factorize_symbolic_cholesky, LltRef, SymbolicCholesky};
use faer::sparse::SparseColMatRef;
use faer::{MatMut, Par};

/// A Cholesky factor L L^T of a sparse SPD matrix given by its lower triangle.
#[derive(Debug)]
pub struct SparseCholesky {
    symbolic: SymbolicCholesky<usize>,
    values: Vec<f64>,
}

impl SparseCholesky {
    /// Symbolic analysis of the pattern of `lower` (lower triangle of the matrix).
    pub fn symbolic(
        lower: SparseColMatRef<'_, usize, f64>,
    ) -> Result<SymbolicCholesky<usize>, String> {
        factorize_symbolic_cholesky(
            lower.symbolic(),
            faer::Side::Lower,
            Default::default(),
            Default::default(),
        )
        .map_err(|e| format!("{e:?}"))
    }

    /// Numeric factorization of `lower` with a symbolic analysis of its pattern.
    pub fn numeric(
        symbolic: SymbolicCholesky<usize>,
        lower: SparseColMatRef<'_, usize, f64>,
    ) -> Result<Self, String> {
        let par = Par::Seq;
        let mut values = vec![0.0; symbolic.len_val()];
        symbolic
            .factorize_numeric_llt::<f64>(
                &mut values,
                lower,
                faer::Side::Lower,
                Default::default(),
                par,
                MemStack::new(&mut MemBuffer::new(
                    symbolic.factorize_numeric_llt_scratch::<f64>(par, Default::default()),
                )),
                Default::default(),
            )
            .map_err(|e| format!("{e:?}"))?;
        Ok(SparseCholesky { symbolic, values })
    }

    /// Symbolic and numeric factorization in one go.
    pub fn new(lower: SparseColMatRef<'_, usize, f64>) -> Result<Self, String> {
        Self::numeric(Self::symbolic(lower)?, lower)
    }

    /// Gives back the symbolic analysis, to refactor a matrix with the same pattern.
    pub fn into_symbolic(self) -> SymbolicCholesky<usize> {
        self.symbolic
    }

    /// Solves A X = B in place for every column of `rhs`.
    pub fn solve_in_place(&self, rhs: MatMut<'_, f64>) {
        let ncols = rhs.ncols();
        LltRef::new(&self.symbolic, &self.values).solve_in_place_with_conj(
            faer::Conj::No,
            rhs,
            Par::Seq,
            MemStack::new(&mut MemBuffer::new(
                self.symbolic.solve_in_place_scratch::<f64>(ncols, Par::Seq),
            )),
        );
    }
}
