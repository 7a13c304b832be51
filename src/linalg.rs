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
    check_test_solve(a, &f, what)?;
    Ok(f)
}

/// Relative residual ‖Ax − b‖∞/‖b‖∞ of a factorisation on the fixed test
/// right-hand side of [`factorize_checked`]; an error when the solve is not
/// finite or the residual is above 1e-6.
pub fn check_test_solve(
    a: &SparseColMat<usize, f64>,
    f: &Factorization,
    what: &str,
) -> Result<f64> {
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
    let r = residual(a, &x, &b);
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
    Ok(rel)
}

/// r = b − A x.
pub fn residual(a: &SparseColMat<usize, f64>, x: &[f64], b: &[f64]) -> Vec<f64> {
    let ax = mat_vec(a, x);
    b.iter().zip(&ax).map(|(p, q)| p - q).collect()
}

/// Solves A x = b in place and then takes `steps` steps of iterative
/// refinement x ← x + A⁻¹(b − A x) with the same factorisation. Returns
/// ‖b − A x‖∞/‖b‖∞ of the final x (0 for b = 0).
pub fn solve_refined(
    a: &SparseColMat<usize, f64>,
    f: &Factorization,
    b: &mut [f64],
    steps: usize,
) -> f64 {
    let rhs = b.to_vec();
    f.solve_in_place(b);
    let mut r = residual(a, b, &rhs);
    for _ in 0..steps {
        let mut d = r;
        f.solve_in_place(&mut d);
        b.iter_mut().zip(&d).for_each(|(x, dx)| *x += dx);
        r = residual(a, b, &rhs);
    }
    let scale = norm_inf(&rhs);
    if scale > 0.0 {
        norm_inf(&r) / scale
    } else {
        norm_inf(&r)
    }
}

/// Index of the first non-finite entry of `v`, if any.
pub fn first_non_finite(v: &[f64]) -> Option<usize> {
    v.iter().position(|x| !x.is_finite())
}

/// An LU factorisation whose symbolic analysis (fill-reducing column
/// ordering, elimination structure) is computed once for a sparsity pattern
/// and reused by every numeric refactorisation of a matrix with that exact
/// pattern (explicit zeros included). Counts both, so callers can report
/// (and tests check) that only numeric refactorisations follow the first.
pub struct ReusableLu {
    symbolic: SymbolicLu<usize>,
    nrows: usize,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    symbolic_analyses: usize,
    numeric_factorizations: usize,
}

impl ReusableLu {
    /// The symbolic analysis of the pattern of `a` (values are not read).
    pub fn analyze(a: &SparseColMat<usize, f64>, what: &str) -> Result<Self> {
        if a.nrows() != a.ncols() {
            return Err(Error::numerical(
                what,
                "shape",
                format!("{}×{} is not square", a.nrows(), a.ncols()),
            ));
        }
        let symbolic = SymbolicLu::try_new(a.symbolic())
            .map_err(|e| Error::numerical(what, "LU (symbolic)", format!("{e:?}")))?;
        let (col_ptr, row_idx) = pattern_of(a);
        Ok(ReusableLu {
            symbolic,
            nrows: a.nrows(),
            col_ptr,
            row_idx,
            symbolic_analyses: 1,
            numeric_factorizations: 0,
        })
    }

    /// Numeric LU of `a`, which must have the analysed pattern; checked on a
    /// test solve as [`factorize_checked`] does. Returns the factorisation
    /// and its test residual.
    pub fn factorize(
        &mut self,
        a: &SparseColMat<usize, f64>,
        what: &str,
    ) -> Result<(Factorization, f64)> {
        let (col_ptr, row_idx) = pattern_of(a);
        if a.nrows() != self.nrows || col_ptr != self.col_ptr || row_idx != self.row_idx {
            return Err(Error::numerical(
                what,
                "sparsity pattern",
                "the matrix does not have the pattern of the symbolic analysis",
            ));
        }
        if let Some(k) = first_non_finite(a.val()) {
            return Err(Error::numerical(
                what,
                "matrix entries",
                format!("entry {k} is not finite"),
            ));
        }
        let lu = Lu::try_new_with_symbolic(self.symbolic.clone(), a.as_ref())
            .map_err(|e| Error::numerical(what, "LU", format!("singular matrix ({e:?})")))?;
        self.numeric_factorizations += 1;
        let f = Factorization::Lu(Box::new(lu));
        let rel = check_test_solve(a, &f, what)?;
        Ok((f, rel))
    }

    /// Symbolic analyses done (1: the one of [`ReusableLu::analyze`]).
    pub fn symbolic_analyses(&self) -> usize {
        self.symbolic_analyses
    }

    /// Numeric factorisations done with the one symbolic analysis.
    pub fn numeric_factorizations(&self) -> usize {
        self.numeric_factorizations
    }
}

/// Column pointers and row indices of `a` in compact form.
fn pattern_of(a: &SparseColMat<usize, f64>) -> (Vec<usize>, Vec<usize>) {
    let s = a.symbolic();
    let mut col_ptr = Vec::with_capacity(a.ncols() + 1);
    let mut row_idx = Vec::with_capacity(a.val().len());
    col_ptr.push(0);
    for j in 0..a.ncols() {
        row_idx.extend(s.row_idx_of_col(j));
        col_ptr.push(row_idx.len());
    }
    (col_ptr, row_idx)
}

impl Factorization {
    /// Solves A X = B in place for the k columns of B (column-major).
    pub fn solve_block_in_place(&self, b: &mut [f64], k: usize) {
        let n = b.len() / k.max(1);
        let rhs = MatMut::from_column_major_slice_mut(b, n, k);
        match self {
            Factorization::Cholesky(f) => f.solve_in_place(rhs),
            Factorization::Lu(f) => f.solve_in_place(rhs),
        }
    }

    /// Solves Aᵀ X = B in place for the k columns of B (column-major).
    pub fn solve_transpose_block_in_place(&self, b: &mut [f64], k: usize) {
        let n = b.len() / k.max(1);
        let rhs = MatMut::from_column_major_slice_mut(b, n, k);
        match self {
            Factorization::Cholesky(f) => f.solve_transpose_in_place(rhs),
            Factorization::Lu(f) => f.solve_transpose_in_place(rhs),
        }
    }

    /// Solves Aᵀ x = b in place.
    pub fn solve_transpose_in_place(&self, b: &mut [f64]) {
        let n = b.len();
        let rhs = MatMut::from_column_major_slice_mut(b, n, 1);
        match self {
            Factorization::Cholesky(f) => f.solve_transpose_in_place(rhs),
            Factorization::Lu(f) => f.solve_transpose_in_place(rhs),
        }
    }
}

/// A dense LU factorisation with partial pivoting of a small square matrix
/// (row-major), for capacitance matrices of low-rank updates.
pub struct DenseLu {
    n: usize,
    lu: Vec<f64>,
    perm: Vec<usize>,
}

impl DenseLu {
    /// Factorises the n × n row-major `a`; None when a pivot is zero or
    /// not finite (the matrix is singular).
    pub fn new(mut a: Vec<f64>, n: usize) -> Option<Self> {
        assert_eq!(a.len(), n * n);
        let mut perm: Vec<usize> = (0..n).collect();
        for k in 0..n {
            let p = (k..n)
                .max_by(|&i, &j| a[i * n + k].abs().total_cmp(&a[j * n + k].abs()))
                .unwrap_or(k);
            let pivot = a[p * n + k];
            if pivot == 0.0 || !pivot.is_finite() {
                return None;
            }
            if p != k {
                for j in 0..n {
                    a.swap(k * n + j, p * n + j);
                }
                perm.swap(k, p);
            }
            let (top, bottom) = a.split_at_mut((k + 1) * n);
            let row_k = &top[k * n..];
            for row in bottom.chunks_exact_mut(n) {
                let l = row[k] / pivot;
                row[k] = l;
                if l != 0.0 {
                    for j in k + 1..n {
                        row[j] -= l * row_k[j];
                    }
                }
            }
        }
        Some(DenseLu { n, lu: a, perm })
    }

    /// Solves A x = b.
    pub fn solve(&self, b: &[f64]) -> Vec<f64> {
        let n = self.n;
        let mut x: Vec<f64> = self.perm.iter().map(|&p| b[p]).collect();
        for i in 0..n {
            let s: f64 = (0..i).map(|j| self.lu[i * n + j] * x[j]).sum();
            x[i] -= s;
        }
        for i in (0..n).rev() {
            let s: f64 = (i + 1..n).map(|j| self.lu[i * n + j] * x[j]).sum();
            x[i] = (x[i] - s) / self.lu[i * n + i];
        }
        x
    }
}
