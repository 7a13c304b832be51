//! Sparse direct factorisations (faer), factorised once and reused by every
//! solve of an iteration. The symbolic analysis is kept so a matrix with the
//! same pattern can be refactorised numerically only.

use crate::assembly::{mat_vec, norm_inf};
use crate::error::{Error, Result};
use faer::linalg::solvers::Solve;
use faer::sparse::linalg::solvers::{Llt, Lu, SymbolicLlt, SymbolicLu};
use faer::sparse::SparseColMat;
use faer::{MatMut, Side};

/// What the matrix is known to be; picks the factorisation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MatrixKind {
    /// Symmetric positive definite: Cholesky (LLᵀ).
    SymmetricPositiveDefinite,
    /// Anything else (saddle-point matrices): LU with partial pivoting.
    General,
}

pub enum Factorization {
    Cholesky(Llt<usize, f64>),
    Lu(Box<Lu<usize, f64>>),
}

impl Factorization {
    /// Factorises `a`; `what` names the matrix in error messages.
    pub fn new(a: &SparseColMat<usize, f64>, kind: MatrixKind, what: &str) -> Result<Self> {
        if a.nrows() != a.ncols() {
            return Err(Error::numerical(
                what,
                "shape",
                format!("{}×{} is not square", a.nrows(), a.ncols()),
            ));
        }
        if let Some(k) = a.val().iter().position(|v| !v.is_finite()) {
            return Err(Error::numerical(
                what,
                "matrix entries",
                format!("entry {k} is not finite"),
            ));
        }
        let f = match kind {
            MatrixKind::SymmetricPositiveDefinite => {
                let symbolic = SymbolicLlt::try_new(a.symbolic(), Side::Lower)
                    .map_err(|e| Error::numerical(what, "Cholesky (symbolic)", format!("{e:?}")))?;
                let llt = Llt::try_new_with_symbolic(symbolic, a.as_ref(), Side::Lower).map_err(|e| {
                    Error::numerical(
                        what,
                        "Cholesky",
                        format!("the matrix is not positive definite ({e:?}): is the problem constrained enough (Dirichlet part, coercivity)?"),
                    )
                })?;
                Factorization::Cholesky(llt)
            }
            MatrixKind::General => {
                let symbolic = SymbolicLu::try_new(a.symbolic())
                    .map_err(|e| Error::numerical(what, "LU (symbolic)", format!("{e:?}")))?;
                let lu = Lu::try_new_with_symbolic(symbolic, a.as_ref()).map_err(|e| {
                    Error::numerical(what, "LU", format!("singular matrix ({e:?})"))
                })?;
                Factorization::Lu(Box::new(lu))
            }
        };
        Ok(f)
    }

    /// Solves A x = b in place.
    pub fn solve_in_place(&self, b: &mut [f64]) {
        let n = b.len();
        let rhs = MatMut::from_column_major_slice_mut(b, n, 1);
        match self {
            Factorization::Cholesky(f) => f.solve_in_place(rhs),
            Factorization::Lu(f) => f.solve_in_place(rhs),
        }
    }
}

/// Factorises `a` and checks the factorisation on one solve: a numerically
/// singular matrix shows up as a non-finite or inaccurate solution even when
/// the factorisation itself "succeeds".
pub fn factorize_checked(
    a: &SparseColMat<usize, f64>,
    kind: MatrixKind,
    what: &str,
) -> Result<Factorization> {
    let f = Factorization::new(a, kind, what)?;
    let n = a.nrows();
    // A fixed, dense, non-trivial right-hand side.
    let b: Vec<f64> = (0..n)
        .map(|i| 1.0 + ((i * 7919) % 13) as f64 / 13.0)
        .collect();
    let mut x = b.clone();
    f.solve_in_place(&mut x);
    if x.iter().any(|v| !v.is_finite()) {
        return Err(Error::numerical(
            what,
            "factorisation",
            "solve gives non-finite values: the matrix is singular",
        ));
    }
    let ax = mat_vec(a, &x);
    let r: Vec<f64> = ax.iter().zip(&b).map(|(p, q)| p - q).collect();
    let rel = norm_inf(&r) / norm_inf(&b);
    if rel > 1e-6 {
        return Err(Error::numerical(
            what,
            "factorisation residual",
            format!(
                "‖Ax − b‖∞/‖b‖∞ = {rel:.3e} on a test solve: the matrix is singular or nearly so"
            ),
        ));
    }
    Ok(f)
}
