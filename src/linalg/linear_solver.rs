//! The linear-solver seam: what a contact method asks of a linear solver,
//! in faer's three phases.
//!
//! - **analyse** ([`analyse`]): the pattern of the matrices to come (values
//!   not read), their [`MatrixKind`] (SPD, symmetric quasi-definite saddle
//!   point, general), the interior groups to condense and how many solves
//!   each matrix serves; returns a [`LinearSolver`] for that pattern;
//! - **factor** ([`LinearSolver::factor`], [`LinearSolver::factor_and_solve`]):
//!   the numeric phase for one matrix of that pattern (a factorisation; a
//!   multigrid setup would go here), checked on a solve;
//! - **solve** ([`Factors::solve_in_place`]): one right-hand side, refined to
//!   the solver's accuracy; the checked first solve also returns its
//!   relative residual.
//!
//! The contact methods see only these traits and [`LinearOptions`], which
//! name the solver (`solver.linear`) and its threads (`solver.threads`).
//! The sparse direct solver of this module's parent ([`ReusableFactorization`]:
//! Cholesky, signed-regularised LDLᵀ or LU, with its fallbacks, condensation
//! and the tuned paths behind `Changed::Declared`) is the one implementation.

use super::{Changed, Factorization, InteriorGroups, MatrixKind, ReusableFactorization, Solves};
use crate::error::Result;
use faer::sparse::SparseColMat;
use serde::Deserialize;
use std::sync::Arc;

/// The linear solver a run's methods use (`solver.linear`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LinearMethod {
    /// Sparse direct factorisation ([`ReusableFactorization`]).
    #[default]
    Direct,
}

impl LinearMethod {
    /// The scene's spelling.
    pub fn name(self) -> &'static str {
        match self {
            LinearMethod::Direct => "direct",
        }
    }
}

/// How a method's linear systems are solved: which solver, on how many
/// threads. Travels in every method's options.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LinearOptions {
    pub method: LinearMethod,
    /// Threads of the factorisations and of the large kernels they and the
    /// methods call (products with A, measures): 1 sequential, 2 or more two.
    pub threads: usize,
}

impl Default for LinearOptions {
    /// What a scene that names neither gets: direct, two threads.
    fn default() -> Self {
        LinearOptions {
            method: LinearMethod::Direct,
            threads: 2,
        }
    }
}

/// What the analysis reads: the pattern of the matrices to come, which it
/// fixes (values are not read), and what they are.
#[derive(Clone, Copy)]
pub struct SystemPattern<'a> {
    /// A matrix with the pattern (a symmetric kind may be its lower triangle).
    pub matrix: &'a SparseColMat<usize, f64>,
    pub kind: MatrixKind,
    /// How many solves each matrix serves (the saddle point's ordering).
    pub solves: Solves,
    /// Unknowns coupled only inside their group, condensed by every setup.
    pub interior: Option<&'a InteriorGroups>,
    /// The matrix's name in error messages.
    pub what: &'a str,
}

/// The work a solver did, for reports and benchmarks.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SolverCounts {
    /// Analyses of the pattern (more than 1: a fallback re-analysed it).
    pub symbolic_analyses: usize,
    pub numeric_factorizations: usize,
    /// The numeric phases' work in whole factorisations (less than their
    /// count where a setup reused part of the last one).
    pub factorized_work: f64,
    /// The order of the system factorised (A's, or the Schur complement's).
    pub factorized_order: usize,
}

/// A solver analysed for one pattern: its numeric phase, once per matrix.
pub trait LinearSolver {
    /// The numeric phase for `a` (the analysed pattern), checked on one
    /// test solve.
    fn factor(&mut self, a: &SparseColMat<usize, f64>) -> Result<Box<dyn Factors>>;

    /// The numeric phase for `a`, checked on the solve of A x = b instead
    /// of a test solve: the factors, x and ‖b − A x‖∞/‖b‖∞. The factors
    /// keep what they need of `a` (a copy, for the refinement).
    fn factor_and_solve(
        &mut self,
        a: &SparseColMat<usize, f64>,
        b: &[f64],
    ) -> Result<(Box<dyn Factors>, Vec<f64>, f64)>;

    /// [`LinearSolver::factor_and_solve`] of a matrix the factors share
    /// instead of copying (the caller changes its values only after
    /// dropping them); `changed` says what changed since the last matrix
    /// given ([`Changed::Declared`]: only the positions of
    /// [`LinearSolver::declare_changing`]).
    fn factor_and_solve_shared(
        &mut self,
        a: &Arc<SparseColMat<usize, f64>>,
        b: &[f64],
        changed: Changed,
    ) -> Result<(Box<dyn Factors>, Vec<f64>, f64)>;

    /// The value positions that alone change between the matrices to come,
    /// so that their setups may reuse the rest.
    fn declare_changing(&mut self, positions: &[usize]);

    fn counts(&self) -> SolverCounts;
}

/// The numeric phase's result for one matrix A: solves with it (Send:
/// a multigrid level may be set up on a second thread).
pub trait Factors: Send {
    /// A x = b in place (b becomes x), to the solver's accuracy.
    fn solve_in_place(&self, b: &mut [f64]);

    /// [`Factors::solve_in_place`], returning A x when the solve computed it
    /// (its refinement), else None.
    fn solve_with_product(&self, b: &mut [f64]) -> Option<Vec<f64>>;

    /// A cheaper solve without refinement (a direction, or a caller that
    /// refines against another matrix); the full solve where there is none.
    fn solve_unrefined_in_place(&self, b: &mut [f64]) {
        self.solve_in_place(b);
    }

    /// Whether [`Factors::solve_in_place`] refines against A by itself;
    /// else a caller that needs round-off refines (`linalg::refine`).
    fn refines_itself(&self) -> bool;

    /// Bᵀ A⁻¹ B for sparse columns B (see `Factorization::inverse_gram`),
    /// for a caller that then solves `solves` times with these factors;
    /// None where the solver has no cheaper way than `columns.len()` solves.
    fn inverse_gram(
        &self,
        _columns: &[Vec<(usize, f64)>],
        _n: usize,
        _solves: usize,
    ) -> Option<Vec<f64>> {
        None
    }
}

/// The analysis phase: a solver of `options.method` for the matrices of
/// `pattern`.
pub fn analyse(
    pattern: SystemPattern<'_>,
    options: &LinearOptions,
) -> Result<Box<dyn LinearSolver>> {
    match options.method {
        LinearMethod::Direct => Ok(Box::new(DirectSolver::analyse(pattern, options.threads)?)),
    }
}

/// [`analyse`] and [`LinearSolver::factor`] of the one matrix of
/// `pattern`: its factors, checked on a test solve.
pub fn factor_once(
    pattern: SystemPattern<'_>,
    options: &LinearOptions,
) -> Result<Box<dyn Factors>> {
    analyse(pattern, options)?.factor(pattern.matrix)
}

/// The sparse direct solver: [`ReusableFactorization`] on its threads.
struct DirectSolver {
    factorizer: ReusableFactorization,
    what: String,
}

impl DirectSolver {
    fn analyse(pattern: SystemPattern<'_>, threads: usize) -> Result<Self> {
        let SystemPattern {
            matrix,
            kind,
            solves,
            interior,
            what,
        } = pattern;
        let factorizer =
            ReusableFactorization::analyze_with(matrix, kind, solves, interior, what, threads)?;
        Ok(DirectSolver {
            factorizer,
            what: what.to_string(),
        })
    }

    fn factors(&self, factorization: Factorization) -> Box<dyn Factors> {
        Box::new(DirectFactors {
            factorization,
            refines_itself: self.factorizer.method() != "LU",
        })
    }
}

impl LinearSolver for DirectSolver {
    fn factor(&mut self, a: &SparseColMat<usize, f64>) -> Result<Box<dyn Factors>> {
        let (f, _) = self.factorizer.factorize(a, &self.what)?;
        Ok(self.factors(f))
    }

    fn factor_and_solve(
        &mut self,
        a: &SparseColMat<usize, f64>,
        b: &[f64],
    ) -> Result<(Box<dyn Factors>, Vec<f64>, f64)> {
        let (f, x, residual) = self.factorizer.factorize_and_solve(a, b, &self.what)?;
        Ok((self.factors(f), x, residual))
    }

    fn factor_and_solve_shared(
        &mut self,
        a: &Arc<SparseColMat<usize, f64>>,
        b: &[f64],
        changed: Changed,
    ) -> Result<(Box<dyn Factors>, Vec<f64>, f64)> {
        let (f, x, residual) = self
            .factorizer
            .factorize_and_solve_shared(a, b, changed, &self.what)?;
        Ok((self.factors(f), x, residual))
    }

    fn declare_changing(&mut self, positions: &[usize]) {
        self.factorizer.keep_eliminations(Some(positions));
    }

    fn counts(&self) -> SolverCounts {
        let f = &self.factorizer;
        SolverCounts {
            symbolic_analyses: f.symbolic_analyses(),
            numeric_factorizations: f.numeric_factorizations(),
            factorized_work: f.factorized_work(),
            factorized_order: f.factorized_order(),
        }
    }
}

/// A direct factorisation's solves, on the threads it was made for (a
/// caller that factorised it itself, outside a [`LinearSolver`]).
impl Factors for Factorization {
    fn solve_in_place(&self, b: &mut [f64]) {
        Factorization::solve_in_place(self, b);
    }

    fn solve_with_product(&self, b: &mut [f64]) -> Option<Vec<f64>> {
        Factorization::solve_with_product(self, b)
    }

    fn solve_unrefined_in_place(&self, b: &mut [f64]) {
        Factorization::solve_unrefined_in_place(self, b);
    }

    /// Cholesky solves need none; LDLᵀ and condensed ones refine; LU does not.
    fn refines_itself(&self) -> bool {
        !matches!(self, Factorization::Lu(_))
    }

    fn inverse_gram(
        &self,
        columns: &[Vec<(usize, f64)>],
        n: usize,
        solves: usize,
    ) -> Option<Vec<f64>> {
        Factorization::inverse_gram(self, columns, n, solves)
    }
}

/// A direct factorisation of a [`LinearSolver`] (its solves run on the
/// solver's threads, which the factorisation keeps).
struct DirectFactors {
    factorization: Factorization,
    /// Whether the factoriser ended on LDLᵀ or Cholesky rather than LU
    /// (`ReusableFactorization::method`, of S when condensed).
    refines_itself: bool,
}

impl Factors for DirectFactors {
    fn solve_in_place(&self, b: &mut [f64]) {
        self.factorization.solve_in_place(b);
    }

    fn solve_with_product(&self, b: &mut [f64]) -> Option<Vec<f64>> {
        self.factorization.solve_with_product(b)
    }

    fn solve_unrefined_in_place(&self, b: &mut [f64]) {
        self.factorization.solve_unrefined_in_place(b);
    }

    fn refines_itself(&self) -> bool {
        self.refines_itself
    }

    fn inverse_gram(
        &self,
        columns: &[Vec<(usize, f64)>],
        n: usize,
        solves: usize,
    ) -> Option<Vec<f64>> {
        self.factorization.inverse_gram(columns, n, solves)
    }
}
