//! Solvers for algebraic contact problems. They know nothing about
//! membranes or shells: a model hands them a [`ContactProblem`].
//!
//! The problem is: find x (primal unknowns, possibly followed by equality
//! multipliers such as the shell's tangency ψ) and λ ≥ 0 with
//!
//! ```text
//!     A x = F + Cᵀ λ,     C x − g ≥ 0,     λ ≥ 0,     λ_i (C x − g)_i = 0,
//! ```
//!
//! where A is factorised once. Row i of C tests the constraint with the i-th
//! multiplier basis function; `weights` are the diagonal Riesz map of the
//! multiplier space (|T| for P0, lumped mass for P1), so that the *mean gap*
//! ḡ_i = (C x − g)_i / w_i is the constraint in the units of the unknown.

pub mod active_set;
pub mod dual_accelerated;
pub mod measures;
pub mod spectrum;
pub mod uzawa;
pub mod uzawa_split;

use crate::linalg::MatrixKind;
use faer::sparse::SparseColMat;
use serde::Deserialize;

pub use measures::{History, KktMeasures};

/// The inequality constraint C x ≥ g with its multiplier space.
pub struct Constraint {
    /// m × n, one row per multiplier dof.
    pub matrix: SparseColMat<usize, f64>,
    /// g, length m.
    pub obstacle: Vec<f64>,
    /// Diagonal Riesz map of the multiplier space, length m, all > 0.
    pub weights: Vec<f64>,
}

impl Constraint {
    /// ḡ_i = ((C x)_i − g_i) / w_i for i, given C x.
    pub fn mean_gap(&self, cx: &[f64], i: usize) -> f64 {
        (cx[i] - self.obstacle[i]) / self.weights[i]
    }

    /// All mean gaps of x.
    pub fn mean_gaps(&self, x: &[f64]) -> Vec<f64> {
        let cx = crate::linalg::mat_vec(&self.matrix, x);
        (0..cx.len()).map(|i| self.mean_gap(&cx, i)).collect()
    }
}

/// An algebraic contact problem (see the module documentation).
pub struct ContactProblem {
    /// The n × n system matrix A (stiffness, or a saddle-point matrix).
    pub matrix: SparseColMat<usize, f64>,
    pub kind: MatrixKind,
    /// F, length n.
    pub rhs: Vec<f64>,
    /// Unknowns [0, n_primal) are primal; the rest are equality multipliers,
    /// whose rows of A x − F are reported as the tangency measure.
    pub n_primal: usize,
    /// None: no obstacle, the problem is one linear solve.
    pub constraint: Option<Constraint>,
}

impl ContactProblem {
    pub fn n(&self) -> usize {
        self.rhs.len()
    }
    pub fn n_multipliers(&self) -> usize {
        self.constraint.as_ref().map_or(0, |c| c.obstacle.len())
    }
}

/// What a solver returns: the last iterate and how it got there.
#[derive(Debug, Clone, Default)]
pub struct SolveReport {
    pub algorithm: String,
    pub x: Vec<f64>,
    pub lambda: Vec<f64>,
    pub iterations: usize,
    /// True only when the relative KKT measures are below the tolerance.
    pub converged: bool,
    /// "kkt", "thesis", "max_iter" or "linear" (no constraint: one solve).
    pub stop_reason: String,
    pub measures: KktMeasures,
    pub history: History,
    pub factor_seconds: f64,
    pub wall_seconds: f64,
    /// Named scalar parameters and estimates (alpha, s_max, ...).
    pub parameters: Vec<(String, f64)>,
}

impl SolveReport {
    /// ‖λ^k − λ^{k−1}‖ of the last iteration (the thesis criterion); 0 without iterations.
    pub fn last_dual_step(&self) -> f64 {
        self.history
            .column("dual_step")
            .and_then(|c| c.last().copied())
            .unwrap_or(0.0)
    }
}

/// An error naming the stage, the quantity and the iteration when `v` holds
/// a non-finite value (divergence, a singular solve).
pub(crate) fn check_finite(
    stage: &str,
    iteration: usize,
    what: &str,
    v: &[f64],
) -> crate::error::Result<()> {
    match crate::linalg::first_non_finite(v) {
        None => Ok(()),
        Some(i) => Err(crate::error::Error::numerical(
            stage,
            what,
            format!("non-finite value at index {i} in iteration {iteration}"),
        )),
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StepForm {
    /// λ_T ← max(0, λ_T − α ḡ_T): the L² Riesz map of the multiplier space.
    Mean,
    /// λ_T ← max(0, λ_T − α |T| ḡ_T): the Euclidean step on coefficients.
    Integral,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum StopRule {
    /// Stop when the relative KKT measures are below `tol`.
    #[default]
    Kkt,
    /// Stop on the thesis criterion ‖λ^{k+1} − λ^k‖ < thesis_tol.
    Thesis,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum DualNorm {
    /// L²(Ω) norm of the multiplier function.
    #[default]
    L2,
    /// Max norm of the coefficients.
    Inf,
}

/// A model-specific scalar recorded every iteration (e.g. the gap at the origin).
pub struct Probe {
    pub name: String,
    /// Evaluated on (x, λ) after each iteration.
    pub evaluate: ProbeFn,
}

pub type ProbeFn = Box<dyn Fn(&[f64], &[f64]) -> f64>;
