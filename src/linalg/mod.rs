//! Sparse linear algebra, in faer's phases: the fill-reducing analysis of a
//! pattern, the numeric factorisation of each matrix of that pattern, and
//! the refined, checked solves; the kernels they and the solvers share; and
//! the linear-solver seam through which every solver factorises.
//!
//! - [`analysis`]: orderings, symbolic factorisations, the analysed pattern;
//! - [`numeric`]: Cholesky, signed-regularised LDLᵀ, LU and their fallbacks,
//!   scaling, [`ReusableFactorization`];
//! - [`condensed`]: static condensation of interior groups;
//! - [`solve`]: refinement to round-off, how a solve is judged;
//! - [`kernels`]: products, norms, entry filters, two-thread column halves;
//! - [`reuse`]: what a factoriser keeps between matrices that differ only
//!   in declared entries (the active set's steps);
//! - [`tree_ldlt`]: the supernodal LDLᵀ and its solves on two threads;
//! - [`linear_solver`]: the seam (analyse → factor → solve);
//! - [`vcycle`]: [`Multigrid`], the V-cycle of an SPD matrix given the
//!   prolongations of a nested hierarchy (Galerkin coarse operators,
//!   Gauss–Seidel or damped Jacobi, the coarsest level through the seam), as
//!   a solver and a preconditioner; [`pcg`]: conjugate gradients with it.
//!   Both know no meshes (`crate::multigrid` builds the prolongations).

mod analysis;
mod condensed;
mod kernels;
mod linear_solver;
mod numeric;
mod pcg;
mod reuse;
mod solve;
mod tree_ldlt;
mod vcycle;

pub use condensed::InteriorGroups;
pub use kernels::{
    beside, first_non_finite, into_lower_triangle, mat_t_vec, mat_vec, norm2, norm_inf, product,
    residual, retain_entries,
};
pub(crate) use kernels::{cut, each_in_halves, on_paired_halves, over_halves};
pub use linear_solver::{
    analyse, factor_once, Factors, LinearMethod, LinearOptions, LinearSolver, SolverCounts,
    SystemPattern,
};
pub use numeric::{
    factorize_checked, factorize_checked_with, keep_freed_memory, Changed, CondensedFactorization,
    Factorization, MatrixKind, RegularizedLdlt, ReusableFactorization, Solves,
};
pub use pcg::{pcg, CgReport};
pub use solve::refine;
pub use vcycle::{CycleReport, Multigrid, MultigridOptions, Smoother, SweepOrder, SweptLevel};

// What the modules read of each other through this one.
use analysis::OrderedEntries;
use kernels::{column_halves, difference, in_column_halves, Storage};
use numeric::{non_finite_entry, ruiz_equilibration, EntryScale, Equilibration};
