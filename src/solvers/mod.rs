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
mod monitor;
pub mod multigrid_newton;
pub mod spectrum;
pub mod uzawa;
pub mod uzawa_split;

use crate::error::Result;
use crate::linalg::{factor_once, Factors, InteriorGroups, MatrixKind, Solves, SystemPattern};
use crate::progress::IterationProgress;
use active_set::{active_set, ActiveSetOptions};
use dual_accelerated::{dual_accelerated, DualAcceleratedOptions};
use faer::sparse::SparseColMat;
use multigrid_newton::{multigrid_newton, MultigridNewtonOptions};
use serde::Deserialize;
use spectrum::SpectrumEstimate;
use std::time::Instant;
use uzawa::{uzawa, UzawaOptions};
use uzawa_split::{uzawa_split, UzawaSplitOptions};

pub use crate::linalg::{LinearMethod, LinearOptions};
pub use measures::{History, KktMeasures};

/// The inequality constraint C x ≥ g with its multiplier space.
#[derive(Clone)]
pub struct Constraint {
    /// m × n, one row per multiplier dof.
    pub matrix: SparseColMat<usize, f64>,
    /// g, length m.
    pub obstacle: Vec<f64>,
    /// Diagonal Riesz map of the multiplier space, length m, all > 0.
    pub weights: Vec<f64>,
}

impl Constraint {
    /// Takes C out, leaving a 0 × 0 matrix: the Newton multigrid holds C in
    /// its condensed rows through its solve and puts it back at its end.
    pub(crate) fn take_matrix(&mut self) -> SparseColMat<usize, f64> {
        taken(&mut self.matrix)
    }

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
#[derive(Clone)]
pub struct ContactProblem {
    /// The n × n system matrix A (stiffness, or a saddle-point matrix);
    /// of a symmetric kind, whole or its lower triangle alone
    /// ([`ContactProblem::store_lower_triangle`]): read it through
    /// [`ContactProblem::product`].
    pub matrix: SparseColMat<usize, f64>,
    pub kind: MatrixKind,
    /// F, length n.
    pub rhs: Vec<f64>,
    /// Unknowns [0, n_primal) are primal; the rest are equality multipliers,
    /// whose rows of A x − F are reported as the tangency measure.
    pub n_primal: usize,
    /// None: no obstacle, the problem is one linear solve.
    pub constraint: Option<Constraint>,
    /// Unknowns that couple only inside their group (an element's
    /// bubbles), declared by the model: every factorisation of A (and of
    /// the active-set Newton matrix) condenses them. None: A is factorised
    /// as it is.
    pub interior: Option<InteriorGroups>,
}

impl ContactProblem {
    pub fn n(&self) -> usize {
        self.rhs.len()
    }
    pub fn n_multipliers(&self) -> usize {
        self.constraint.as_ref().map_or(0, |c| c.obstacle.len())
    }

    /// A x, whichever way A is stored (a large A on `threads`).
    pub fn product(&self, x: &[f64], threads: usize) -> Vec<f64> {
        assert_eq!(
            self.matrix.ncols(),
            self.n(),
            "A is read while the active set holds it (`ContactProblem::take_matrix`)"
        );
        crate::linalg::product(&self.matrix, self.kind, x, threads)
    }

    /// The strain energy ½ Uᵀ K U and the external work Fᵀ U of the primal
    /// part U of x (the first `n_primal` unknowns; K is A's primal block, so
    /// the equality multipliers' coupling is left out); K U on `threads`.
    pub fn energies(&self, x: &[f64], threads: usize) -> (f64, f64) {
        let np = self.n_primal;
        let mut primal = x.to_vec();
        primal[np..].fill(0.0);
        let ku = self.product(&primal, threads);
        let strain: f64 = 0.5 * (0..np).map(|i| x[i] * ku[i]).sum::<f64>();
        let work: f64 = (0..np).map(|i| x[i] * self.rhs[i]).sum();
        (strain, work)
    }

    /// Keeps a symmetric A as its lower triangle, the part every
    /// factorisation reads (a general A stays whole): half of A's memory
    /// through the solve (the shell's active set at n = 256: peak RSS
    /// 4838 → 4254 MB).
    pub fn store_lower_triangle(&mut self) {
        if self.kind != MatrixKind::General {
            let whole = self.take_matrix();
            self.matrix = crate::linalg::into_lower_triangle(whole);
        }
    }

    /// Takes A out, leaving a 0 × 0 matrix: a solve that owns the problem
    /// builds its own matrix in A's arrays and puts A back at its end.
    pub(crate) fn take_matrix(&mut self) -> SparseColMat<usize, f64> {
        taken(&mut self.matrix)
    }
}

/// `matrix` taken out, a 0 × 0 matrix left in its place.
fn taken(matrix: &mut SparseColMat<usize, f64>) -> SparseColMat<usize, f64> {
    let empty = SparseColMat::try_new_from_triplets(0, 0, &[]).expect("an empty matrix");
    std::mem::replace(matrix, empty)
}

/// A method and its parameters: what [`solve`] runs. Each method's options
/// carry the linear solver it uses ([`LinearOptions`]).
#[derive(Debug, Clone)]
pub enum SolverOptions {
    /// The thesis' Uzawa iteration (one factorisation of A, done by [`solve`]).
    Uzawa(UzawaOptions),
    UzawaSplit(UzawaSplitOptions),
    DualAccelerated(DualAcceleratedOptions),
    ActiveSet(ActiveSetOptions),
    /// Newton multigrid with grid sequencing over a nested hierarchy.
    Multigrid(MultigridNewtonOptions),
}

impl SolverOptions {
    /// The linear solver the method uses.
    pub fn linear(&self) -> LinearOptions {
        match self {
            SolverOptions::Uzawa(o) => o.linear,
            SolverOptions::UzawaSplit(o) => o.linear,
            SolverOptions::DualAccelerated(o) => o.linear,
            SolverOptions::ActiveSet(o) => o.linear,
            SolverOptions::Multigrid(o) => o.cycle.coarse,
        }
    }
}

/// Solves a contact problem by the method of `options`; a problem without
/// constraint is one linear solve, whatever the method. `probes` are
/// recorded per iteration by the methods that take them (Uzawa). The
/// kernels run on the linear solver's threads (`LinearOptions::threads`).
/// The solve owns the problem
/// and gives it back unchanged with the report: the active set builds its
/// Newton matrix in A's arrays meanwhile ([`active_set`]).
pub fn solve(
    problem: ContactProblem,
    options: &SolverOptions,
    probes: &[Probe],
) -> Result<(ContactProblem, SolveReport)> {
    let linear = options.linear();
    if problem.constraint.is_none() {
        let report = uzawa::solve_unconstrained(&problem, &linear)?;
        return Ok((problem, report));
    }
    let report = match options {
        SolverOptions::Uzawa(o) => {
            // One factorisation, reused by every iteration.
            let (factors, seconds) = factorize_system(&problem, Solves::Many, &linear)?;
            uzawa(&problem, factors.as_ref(), seconds, o, probes)
        }
        SolverOptions::UzawaSplit(o) => uzawa_split(&problem, o),
        SolverOptions::DualAccelerated(o) => dual_accelerated(&problem, o),
        SolverOptions::ActiveSet(o) => return active_set(problem, o),
        SolverOptions::Multigrid(o) => return multigrid_newton(problem, o),
    }?;
    Ok((problem, report))
}

/// The checked factors of A by the `linear` solver, and the seconds they took.
pub(crate) fn factorize_system(
    problem: &ContactProblem,
    solves: Solves,
    linear: &LinearOptions,
) -> Result<(Box<dyn Factors>, f64)> {
    let t = Instant::now();
    // Condensation pays per solve (fewer, denser factor entries) but its plan
    // costs more than faer's symbolic analysis, and AMD eliminates the bubbles
    // first anyway: for one solve the whole matrix is faster
    // (docs/work-precision.md, "Condensation and threads").
    let interior = match solves {
        Solves::Many => problem.interior.as_ref(),
        Solves::Few => None,
    };
    let pattern = SystemPattern {
        matrix: &problem.matrix,
        kind: problem.kind,
        solves,
        interior,
        what: problem.kind.describe(),
    };
    let factors = factor_once(pattern, linear)?;
    Ok((factors, t.elapsed().as_secs_f64()))
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
    /// Uzawa's fixed step α (None for the other methods: their steps are
    /// among the `parameters`).
    pub alpha: Option<f64>,
    /// The Lanczos estimate Uzawa's α was chosen from (and judged against).
    pub spectrum: Option<SpectrumEstimate>,
    /// The constraints an interior-point iterate predicts in contact (the
    /// PDAS rule's set), where the run ended inside the active set's
    /// interior-point start: its λ_i are all > 0. None for every other
    /// answer, whose λ is zero off contact.
    pub predicted_contact: Option<Vec<bool>>,
}

impl SolveReport {
    /// The constraints in contact: λ_i > 0, or the interior point's
    /// prediction where the answer is an interior iterate
    /// (`predicted_contact`).
    pub fn contact(&self) -> Vec<bool> {
        match &self.predicted_contact {
            Some(set) => set.clone(),
            None => self.lambda.iter().map(|&l| l > 0.0).collect(),
        }
    }

    /// The named scalar parameter (`parameters`), if the method reports it.
    pub fn parameter(&self, name: &str) -> Option<f64> {
        self.parameters
            .iter()
            .find(|(n, _)| n == name)
            .map(|&(_, v)| v)
    }

    /// ‖λ^k − λ^{k−1}‖ of the last iteration (the thesis criterion); 0 without iterations.
    pub fn last_dual_step(&self) -> f64 {
        self.history
            .column("dual_step")
            .and_then(|c| c.last().copied())
            .unwrap_or(0.0)
    }
}

/// The stop reason of the one direct solve of a problem without contact.
const LINEAR: &str = "linear";

/// The stop reason of an iteration that ran `max_iter` times without
/// meeting its stop rule.
pub const STOP_MAX_ITER: &str = "max_iter";

/// The bookkeeping every method shares from its start to its
/// [`SolveReport`] (the one place a report is built): the clock, the
/// per-iteration history and progress display, the last measures and why
/// the iteration stopped.
pub(crate) struct ReportBuilder {
    algorithm: &'static str,
    clock: Instant,
    /// Seconds spent before `clock` started that count as the solver's
    /// (Uzawa's factorisation, done before its step is chosen).
    offset: f64,
    tol: f64,
    progress: IterationProgress,
    history: History,
    stop_reason: &'static str,
    pub iterations: usize,
    pub measures: KktMeasures,
    pub factor_seconds: f64,
    pub alpha: Option<f64>,
    pub spectrum: Option<SpectrumEstimate>,
}

impl ReportBuilder {
    /// A run of `algorithm` timed from `clock`, plus `offset` seconds spent
    /// before it; `factor_seconds` of the time so far factorised. Until
    /// [`ReportBuilder::stop`] its stop reason is "max_iter".
    pub(crate) fn new(
        algorithm: &'static str,
        clock: Instant,
        offset: f64,
        factor_seconds: f64,
    ) -> Self {
        ReportBuilder {
            algorithm,
            clock,
            offset,
            tol: f64::INFINITY,
            progress: IterationProgress::new(algorithm, 1, 0.0, false),
            history: History::default(),
            stop_reason: STOP_MAX_ITER,
            iterations: 0,
            measures: KktMeasures::default(),
            factor_seconds,
            alpha: None,
            spectrum: None,
        }
    }

    /// The history of an iterative method: the KKT columns, then its own.
    pub(crate) fn with_history(mut self, extra_columns: &[&str]) -> Self {
        self.history = History::for_solver(extra_columns);
        self
    }

    /// At most `max_iter` iterations to the KKT tolerance `tol`, shown as
    /// `label` on the progress display when `show_progress`.
    pub(crate) fn iterating(
        mut self,
        label: &str,
        max_iter: usize,
        tol: f64,
        show_progress: bool,
    ) -> Self {
        self.tol = tol;
        self.progress = IterationProgress::new(label, max_iter, tol, show_progress);
        self
    }

    /// The one linear solve of a problem without constraint (no history),
    /// after a factorisation of `factor_seconds`.
    pub(crate) fn linear(factor_seconds: f64) -> Self {
        let mut b = ReportBuilder::new(LINEAR, Instant::now(), factor_seconds, factor_seconds);
        b.stop_reason = LINEAR;
        b.iterations = 1;
        b
    }

    /// Records iteration k: its dual step, measures and the method's own
    /// history values; updates the progress display.
    pub(crate) fn record(
        &mut self,
        k: usize,
        dual_step: f64,
        measures: KktMeasures,
        extra: &[f64],
    ) {
        self.iterations = k;
        self.measures = measures;
        self.history.push_iteration(k, dual_step, &measures, extra);
        self.progress.update(k, measures.kkt, dual_step);
    }

    /// The iteration stopped for `reason` ("kkt", "thesis").
    pub(crate) fn stop(&mut self, reason: &'static str) {
        self.stop_reason = reason;
    }

    /// The report of the last iterate (x, λ); converged when its KKT
    /// measure is below `tol` (or for the direct solve without contact).
    pub(crate) fn finish(
        mut self,
        x: Vec<f64>,
        lambda: Vec<f64>,
        parameters: Vec<(String, f64)>,
    ) -> SolveReport {
        self.progress.finish();
        SolveReport {
            algorithm: self.algorithm.into(),
            x,
            lambda,
            iterations: self.iterations,
            converged: self.stop_reason == LINEAR || self.measures.kkt <= self.tol,
            stop_reason: self.stop_reason.into(),
            measures: self.measures,
            history: self.history,
            factor_seconds: self.factor_seconds,
            wall_seconds: self.offset + self.clock.elapsed().as_secs_f64(),
            parameters,
            alpha: self.alpha,
            spectrum: self.spectrum,
            predicted_contact: None,
        }
    }
}

/// The first multiplier of a dual method: the warm start's λ (projected on
/// λ ≥ 0) or zero; a warm start of the wrong length is refused.
pub(crate) fn initial_multiplier(
    stage: &str,
    initial: Option<&[f64]>,
    m: usize,
) -> Result<Vec<f64>> {
    match initial {
        Some(l) if l.len() != m => Err(crate::error::Error::numerical(
            stage,
            "initial_lambda",
            format!("length {}, expected {m}", l.len()),
        )),
        Some(l) => Ok(l.iter().map(|v| v.max(0.0)).collect()),
        None => Ok(vec![0.0; m]),
    }
}

/// Named parameters of a report from (name, value) pairs.
pub(crate) fn named(values: &[(&str, f64)]) -> Vec<(String, f64)> {
    values.iter().map(|(n, v)| (n.to_string(), *v)).collect()
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
