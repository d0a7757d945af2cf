//! A sparse Cholesky factorization (faer), shared by the least-squares
//! conformal maps, their ARAP relaxation and the vector field.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymmetricOrdering,
};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::SparseColMat;
use faer::{Conj, MatMut, Par, Side};

/// A sparse Cholesky factorization (simplicial LLT, AMD ordering, sequential) of a
/// symmetric positive definite matrix given by its upper triangle, for
/// several solves with one factorization.
pub(crate) struct SpdFactor {
    symbolic: faer::sparse::linalg::cholesky::SymbolicCholesky<usize>,
    values: Vec<f64>,
}

impl SpdFactor {
    pub(crate) fn new(h: &SparseColMat<usize, f64>) -> std::result::Result<Self, String> {
        let symbolic = factorize_symbolic_cholesky(
            h.symbolic(),
            Side::Upper,
            SymmetricOrdering::Amd,
            // the simplicial factorization: scalar loops in a fixed order, so
            // the same bits on every CPU (the supernodal one runs dense
            // kernels chosen by instruction set)
            CholeskySymbolicParams {
                supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SIMPLICIAL,
                ..Default::default()
            },
        )
        .map_err(|e| format!("symbolic factorisation failed: {e:?}"))?;
        let mut values = vec![0.0f64; symbolic.len_val()];
        let par = Par::Seq;
        let req = symbolic.factorize_numeric_llt_scratch::<f64>(par, Default::default());
        let mut mem = MemBuffer::try_new(req).map_err(|_| "out of memory".to_string())?;
        symbolic
            .factorize_numeric_llt::<f64>(
                &mut values,
                h.as_ref(),
                Side::Upper,
                LltRegularization::default(),
                par,
                MemStack::new(&mut mem),
                Default::default(),
            )
            .map_err(|e| format!("Cholesky factorisation failed (system not positive definite): {e:?}"))?;
        Ok(SpdFactor { symbolic, values })
    }

    /// x with H x = b.
    pub(crate) fn solve(&self, mut b: Vec<f64>) -> Vec<f64> {
        let n = b.len();
        let par = Par::Seq;
        let req = self.symbolic.solve_in_place_scratch::<f64>(1, par);
        let mut mem = MemBuffer::new(req);
        let llt = LltRef::<usize, f64>::new(&self.symbolic, &self.values);
        llt.solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(&mut b, n, 1),
            par,
            MemStack::new(&mut mem),
        );
        b
    }
}
