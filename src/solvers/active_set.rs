//! Primal–dual active set method (Hintermüller–Ito–Kunisch), i.e. the
//! semismooth Newton method on the complementarity function
//!
//! ```text
//!     A x − Cᵀλ = F,     λ − max(0, λ − c ḡ(x)) = 0,     ḡ_i = (C x − g)_i / w_i,
//! ```
//!
//! on the full system (docs/formulation.md §3 "beyond the thesis"). Given the active set
//! 𝒜_k = {i : λ_i − c_i ḡ_i > 0} of the previous iterate, step k solves
//!
//! ```text
//!     [ A     Cᵀ S ] [x]   [F  ]     active i:   s_i (C x)_i = s_i g_i
//!     [ S C   −D   ] [μ] = [ĝ  ]     inactive i: s_i (C x)_i − d_off μ_i = 0,
//! ```
//!
//! λ = −S μ on 𝒜 (0 off it), with S = diag(s_i) a row (and multiplier)
//! scaling that gives the constraint rows and multiplier columns the
//! magnitude of A's entries (s_i = max|A| / max_j |C_ij|), and D = diag(0 on
//! 𝒜, d_off off it). An inactive constraint is switched off by its diagonal
//! alone: d_off = max|A| / ε² (ε the machine epsilon) leaves it the
//! multiplier μ_i = s_i (C x)_i / d_off, whose force on x, s_i² C_iᵀ C_i x /
//! d_off, is ε² max|A| |C_i x|. (ε is not enough: the thin shell's F is far
//! below max|A| ‖x‖, and max|A|/ε moved its stationarity at n = 64 from
//! 4.3e-11 to 2.8e-10; with ε² it is 4.3e-11 again, and at n = 128 the
//! active set is the same, u within 1.3e-12 and λ within 1e-10 relative of
//! the zeroed rows' solution.) So every step's matrix has the same entries
//! off the multiplier diagonal (the interior-point steps' too, whose
//! diagonal is −s_i² t_i/λ_i): the
//! element bubbles, which the P0 constraints touch, are eliminated once
//! for the whole solve and each factorisation updates S on that diagonal
//! ([`Changed::Declared`]). Measured on the thesis shell at n = 128: a step
//! with a new active set took 0.47 s when the bubbles were eliminated
//! anew, 0.34 s now (an interior-point step: 0.35 s). The matrix is
//! symmetric and quasi-definite in sign (multipliers, ψ's included,
//! negative), so it is factorised by the signed-regularised LDLᵀ when A is
//! symmetric ([`MatrixKind::SymmetricSaddle`]), by LU otherwise. Its pattern
//! is fixed: the symbolic analysis is done once and each step is a numeric
//! refactorisation only ([`LinearSolver`]), checked on the Newton
//! solve itself (its residual), which the LDLᵀ refines against the true
//! matrix (LU: `refinement_steps` more).
//!
//! **The constant c.** With an exact Newton step the active set after the
//! first step does not depend on c (λ_i = 0 off the set and ḡ_i = 0 on it).
//! c matters only when the caller gives an initial primal iterate: then
//! c_i = 1/S̃_ii with S̃ = W⁻¹ C diag(A)⁻¹ Cᵀ, the Jacobi estimate of the
//! mean-form dual operator, so that c_i ḡ_i is the multiplier change that
//! would close the gap of constraint i alone (the units of λ). A scalar c
//! can be given instead.
//!
//! **Start.** Without warm start the iteration starts from (x, λ) = (0, 0):
//! 𝒜_1 = {i : g_i > 0} (constraints violated by x = 0). With
//! `initial_lambda` only, 𝒜_1 = {λ⁰_i > 0}; with `initial_x` (and
//! optionally `initial_lambda`), 𝒜_1 = {λ⁰_i − c_i ḡ_i(x⁰) > 0}. For nested
//! iteration, pass the prolonged coarse solution.
//!
//! **Depth bisection** (`ColdStart::DepthBisection`, cold starts only). On
//! the shell, plain PDAS from the free solution activates every penetrating
//! triangle P (1016 of 2048 at n = 32) and then sheds a fringe of a few
//! hundred triangles per step while the core shrinks slowly: 13, 27, 47, 67
//! steps at n = 16 … 128 (the exact zone has a ragged fringe of its own,
//! P0 multipliers oscillating between neighbours). Instead, each i ∈ P is
//! scored by its depth in layers inside P (neighbours: rows of C sharing a
//! column) and the nested sets {depth > ℓ} are probed by bisection on ℓ: a
//! probe with more negative multipliers than penetrating constraints is too
//! large, else too small. After at most `probes` probes (or when the next
//! set would repeat a bracket end) plain PDAS takes over from the PDAS
//! proposal of the least violating probe, with the stagnation and cycling
//! checks on. Measured (tol 1e-10, same solutions to 12 digits): 7, 10, 13,
//! 20, 38 Newton solves at n = 16, 32, 64, 128, 256; the PDAS finish (4, 6,
//! 8, 13, 31 steps) is what still grows with n.
//!
//! **Interior-point start** (`ColdStart::InteriorPoint`, cold starts only).
//! The PDAS finish above grows with n because it resolves the ragged rim a
//! few layers per step. A primal–dual interior-point method does not
//! guess sets: Mehrotra predictor–corrector steps on
//!
//! ```text
//!     A x − Cᵀλ = F,   C x − g − t = 0,   λ_i t_i = σμ,   (λ, t) > 0,
//! ```
//!
//! (t the slacks) factorise the same Newton matrix with every constraint
//! on and the multiplier diagonal −s_i² t_i/λ_i (s_i the row scaling
//! above): the pattern, the symbolic analysis and the condensation are
//! those of the PDAS steps; the corrector is one more solve with the
//! same factorisation. The start is the free solution with a centred
//! (λ, t): λ = κ p + ε_λ on the penetration p = (g − C x)⁺, t = μ₀/λ, where
//! κ = pᵀp / pᵀ C A⁻¹ Cᵀ p (one solve with the free factorisation) sets the
//! multiplier scale. When the relative KKT measure of the iterate is below
//! `handover` and the set the PDAS rule predicts there (λ_i − c_i ḡ_i > 0)
//! changed by at most 5 % in the last step, or differs by at most 5 % from
//! the rule's set at the step's affine-scaling point, PDAS continues from that set,
//! nearly exact: one to four steps. Like every step, an interior-point
//! step changes the multiplier diagonal only (see above). Measured on the
//! thesis shell (tol 1e-10; 1e-8 at n = 512): 8, 11, 13, 14, 16, 15 Newton
//! solves at n = 16, 32, 64, 128, 256, 512 against the depth bisection's 7,
//! 10, 13, 20, 38, 61 — the interior-point count does not grow with n.
//!
//! **Stopping.** Only on the relative KKT measure (`tol`). An active set that
//! does not change while the KKT measure is above `tol` is stagnation (the
//! linear solves are not accurate enough for `tol`); an active set seen at
//! an earlier iteration is cycling (possible when A is not an M-matrix);
//! both are errors that say so. `max_iter` gives a non-converged report.

use super::measures::{jacobi_dual_diagonal, kkt_measures_with, KktMeasures, Products};
use super::monitor::check_finite;
use super::uzawa::solve_unconstrained;
use super::{named, Constraint, ContactProblem, ReportBuilder, SolveReport};
use crate::error::{Error, Result};
use crate::linalg::{
    analyse, refine, Changed, Factors, LinearOptions, LinearSolver, MatrixKind, Solves,
    SystemPattern,
};
use crate::linalg::{mat_t_vec, mat_vec, norm_inf};
use faer::sparse::{SparseColMat, SymbolicSparseColMat};
use std::sync::Arc;
use std::time::Instant;

/// History columns after the KKT ones (`History::for_solver`). Row k is the iterate
/// of Newton step k: `active` = |𝒜_k|, the set used in step k; `changes` =
/// `added` + `removed` = |𝒜_k Δ 𝒜_{k−1}| (𝒜_0 = ∅); `linear_residual` =
/// ‖b − Mz‖∞/‖b‖∞ of the Newton solve after refinement; `dual_step` =
/// ‖λ^k − λ^{k−1}‖∞.
pub const EXTRA_COLUMNS: [&str; 5] = ["active", "changes", "added", "removed", "linear_residual"];

#[derive(Debug, Clone)]
pub struct ActiveSetOptions {
    /// Bound on the relative KKT measure.
    pub tol: f64,
    /// Maximum number of Newton steps (linear solves).
    pub max_iter: usize,
    /// Scalar c of the active-set rule; None: c_i = 1/S̃_ii (module docs).
    pub c: Option<f64>,
    /// Warm start: the initial multiplier (length m).
    pub initial_lambda: Option<Vec<f64>>,
    /// Warm start: the initial x (length n), used with c.
    pub initial_x: Option<Vec<f64>>,
    /// How a cold start (no initial λ or x) finds its first active sets.
    pub cold_start: ColdStart,
    /// Steps of iterative refinement after each solve (LU; the LDLᵀ solve
    /// refines itself to round-off).
    pub refinement_steps: usize,
    /// A PDAS step whose active set differs from the last factorised one
    /// in few constraints is solved with that factorisation
    /// ([`SwitchedSolve`]) instead of a new one.
    pub switched_steps: bool,
    pub show_progress: bool,
    pub linear: LinearOptions,
}

impl Default for ActiveSetOptions {
    fn default() -> Self {
        ActiveSetOptions {
            tol: 1e-10,
            max_iter: 50,
            c: None,
            initial_lambda: None,
            initial_x: None,
            cold_start: ColdStart::DEPTH_BISECTION,
            refinement_steps: 1,
            switched_steps: true,
            show_progress: false,
            linear: LinearOptions::default(),
        }
    }
}

const STAGE: &str = "primal-dual active set";

/// The first active sets of a cold start (module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ColdStart {
    /// Plain PDAS from the free solution.
    Plain,
    /// Bisection on the layer depth inside the free solution's penetration
    /// set, at most `probes` probes, then plain PDAS.
    DepthBisection { probes: usize },
    /// Interior-point steps from the free solution until the relative KKT
    /// measure is ≤ `handover` and the predicted set has settled (or
    /// `max_steps` steps), then PDAS from the set they predict.
    InteriorPoint { handover: f64, max_steps: usize },
}

impl ColdStart {
    /// The depth bisection with its measured budget: 3, 4, 6, 8 probes give
    /// 27, 21, 20, 20 Newton solves on the shell at n = 128.
    pub const DEPTH_BISECTION: ColdStart = ColdStart::DepthBisection { probes: 6 };
    /// The interior-point start with its measured handover: at 1e-6, 1e-7,
    /// 1e-8 the shell at n = 128 took 17, 15, 16 Newton solves (n = 64: 14,
    /// 14, 15).
    pub const INTERIOR_POINT: ColdStart = ColdStart::InteriorPoint {
        handover: 1e-7,
        max_steps: 40,
    };
}

/// The Newton matrix with its fixed entries and the positions of the
/// multiplier diagonal, the one part that changes from step to step.
/// Symmetric (A symmetric): stored as its lower triangle, the storage
/// every symmetric factorisation reads (`linalg`). Its leading block is a
/// copy of the problem's A, which the active set only reads.
struct NewtonMatrix {
    /// Shared with each step's factorisation for its refinement.
    matrix: Arc<SparseColMat<usize, f64>>,
    kind: MatrixKind,
    /// The order n of A, the leading block.
    n: usize,
    /// Value position of the diagonal entry (n + i, n + i).
    diagonal: Vec<usize>,
    /// The diagonal d_off of an inactive row (module docs).
    switched_off: f64,
    /// The scaling s_i (λ_i = s_i μ_i).
    scale: Vec<f64>,
    /// S̃ of A for the measures ([`jacobi_dual_diagonal`]), which cannot
    /// read A while it is lent.
    compliance: Vec<f64>,
}

impl NewtonMatrix {
    /// The Newton matrix of `problem`: A (its lower triangle when
    /// symmetric), then C's rows scaled and the multiplier columns, in
    /// arrays allocated once at their final size.
    fn of(problem: &ContactProblem, kind: MatrixKind, compliance: Vec<f64>) -> Result<Self> {
        let lower = kind != MatrixKind::General;
        let (n, m) = (problem.n(), problem.n_multipliers());
        let a = &problem.matrix;
        let a_rows = a.symbolic();
        // Column j of A as the Newton matrix holds it; rows are sorted
        // within each column, as in every matrix `linalg` reads.
        let a_column = |j: usize| {
            a_rows
                .row_idx_of_col(j)
                .zip(a.val_of_col(j))
                .filter(move |&(i, _)| !lower || i >= j)
        };
        let a_max = (0..n)
            .flat_map(a_column)
            .fold(0.0f64, |s, (_, v)| s.max(v.abs()))
            .max(f64::MIN_POSITIVE);
        let c = problem.constraint.as_ref().expect("a constrained problem");
        let scale = constraint_scaling(c, a_max)?;
        // The rows of C, for a whole matrix's multiplier columns.
        let c_rows = match lower {
            true => None,
            false => Some(constraint_rows(c)?),
        };
        let cs = c.matrix.symbolic();
        // Columns 0..n: A's column, then the rows n + i of C's column j,
        // s_i C_ij. Columns n..n+m: s_i (row i of C)ᵀ (whole only), then
        // the diagonal (set by each step).
        let mut col_ptr = Vec::with_capacity(n + m + 1);
        col_ptr.push(0);
        for j in 0..n {
            col_ptr.push(col_ptr[j] + a_column(j).count() + cs.row_idx_of_col_raw(j).len());
        }
        let nnz = col_ptr[n] + m + c_rows.as_ref().map_or(0, |rows| rows.val().len());
        let (mut row_idx, mut values) = (Vec::with_capacity(nnz), Vec::with_capacity(nnz));
        for j in 0..n {
            for (i, &v) in a_column(j) {
                row_idx.push(i);
                values.push(v);
            }
            for (i, &v) in cs.row_idx_of_col(j).zip(c.matrix.val_of_col(j)) {
                row_idx.push(n + i);
                values.push(scale[i] * v);
            }
        }
        let mut diagonal = Vec::with_capacity(m);
        for i in 0..m {
            if let Some(rows) = &c_rows {
                for (j, &v) in rows.symbolic().row_idx_of_col(i).zip(rows.val_of_col(i)) {
                    row_idx.push(j);
                    values.push(scale[i] * v);
                }
            }
            diagonal.push(row_idx.len());
            row_idx.push(n + i);
            values.push(0.0);
            col_ptr.push(row_idx.len());
        }
        let symbolic = SymbolicSparseColMat::new_checked(n + m, n + m, col_ptr, None, row_idx);
        Ok(NewtonMatrix {
            matrix: Arc::new(SparseColMat::new(symbolic, values)),
            kind,
            n,
            diagonal,
            switched_off: a_max / (f64::EPSILON * f64::EPSILON),
            scale,
            compliance,
        })
    }

    /// A x, from the leading block: the product with (x, 0).
    fn a_product(&self, x: &[f64]) -> Vec<f64> {
        let mut z = x.to_vec();
        z.resize(self.matrix.ncols(), 0.0);
        let mut y = crate::linalg::product(&self.matrix, self.kind, &z);
        y.truncate(self.n);
        y
    }

    /// The multiplier diagonal −Δ_i of an interior-point step.
    fn set_barrier(&mut self, delta: &[f64]) {
        self.set_diagonal(|i| -delta[i]);
    }

    /// The multiplier diagonal of the active set: 0 on it, −d_off off it.
    fn set_active(&mut self, active: &[bool]) {
        let off = self.switched_off;
        self.set_diagonal(|i| if active[i] { 0.0 } else { -off });
    }

    fn set_diagonal(&mut self, value: impl Fn(usize) -> f64) {
        let values = Arc::get_mut(&mut self.matrix)
            .expect("the previous step's factorisation is dropped")
            .val_mut();
        for (i, &pos) in self.diagonal.iter().enumerate() {
            values[pos] = value(i);
        }
    }
}

/// The row scaling s_i = max|A| / max_j |C_ij| of the Newton matrix.
fn constraint_scaling(c: &Constraint, a_max: f64) -> Result<Vec<f64>> {
    let m = c.obstacle.len();
    let cs = c.matrix.symbolic();
    let mut row_max = vec![0.0f64; m];
    for j in 0..c.matrix.ncols() {
        for (i, v) in cs.row_idx_of_col(j).zip(c.matrix.val_of_col(j)) {
            row_max[i] = row_max[i].max(v.abs());
        }
    }
    let mut scale = Vec::with_capacity(m);
    for (i, &row_max) in row_max.iter().enumerate() {
        if row_max == 0.0 || !row_max.is_finite() {
            return Err(Error::numerical(
                STAGE,
                "constraint matrix",
                format!("row {i} of C is empty or not finite"),
            ));
        }
        scale.push(a_max / row_max);
    }
    Ok(scale)
}

/// Solves a contact problem by the primal–dual active set method (module
/// docs), its Newton steps by the linear solver of `options.linear`.
pub fn active_set(problem: &ContactProblem, options: &ActiveSetOptions) -> Result<SolveReport> {
    options.linear.run(|| semismooth_newton(problem, options))
}

/// [`active_set`] on the linear solver's threads.
fn semismooth_newton(problem: &ContactProblem, options: &ActiveSetOptions) -> Result<SolveReport> {
    let start = Instant::now();
    let Some(c) = problem.constraint.as_ref() else {
        return solve_unconstrained(problem, &options.linear);
    };
    let (n, m) = (problem.n(), c.obstacle.len());
    for (name, len, want) in [
        (
            "initial_lambda",
            options.initial_lambda.as_ref().map(Vec::len),
            m,
        ),
        ("initial_x", options.initial_x.as_ref().map(Vec::len), n),
    ] {
        if let Some(len) = len.filter(|&l| l != want) {
            return Err(Error::numerical(
                STAGE,
                name,
                format!("length {len}, expected {want}"),
            ));
        }
    }

    // c_i: the scalar option, or the Jacobi estimate 1/S̃_ii.
    let compliance = jacobi_dual_diagonal(problem);
    let c_rule: Vec<f64> = match options.c {
        Some(v) => vec![v; m],
        None => compliance
            .iter()
            .map(|&s| if s > 0.0 { 1.0 / s } else { 1.0 })
            .collect(),
    };
    if c_rule.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
        return Err(Error::numerical(STAGE, "c", "must be finite and > 0"));
    }

    let t = Instant::now();
    // The Newton matrix is symmetric when A is; its multipliers (A's own,
    // then μ) take negative pivots.
    let kind = match problem.kind {
        MatrixKind::General => MatrixKind::General,
        MatrixKind::SymmetricPositiveDefinite | MatrixKind::SymmetricSaddle { .. } => {
            MatrixKind::SymmetricSaddle {
                n_primal: problem.n_primal,
            }
        }
    };
    let mut newton = NewtonMatrix::of(problem, kind, compliance)?;
    newton_steps(problem, &mut newton, &c_rule, options, (start, t))
}

/// The Newton steps of [`active_set`] on the Newton matrix (A x from
/// [`NewtonMatrix::a_product`]); `(start, t)`: the solve's start and its
/// setup's.
fn newton_steps(
    problem: &ContactProblem,
    newton: &mut NewtonMatrix,
    c_rule: &[f64],
    options: &ActiveSetOptions,
    (start, t): (Instant, Instant),
) -> Result<SolveReport> {
    let c = problem.constraint.as_ref().expect("a constrained problem");
    let (n, m) = (problem.n(), c.obstacle.len());
    let kind = newton.kind;
    // The first active set.
    let lambda0 = options
        .initial_lambda
        .clone()
        .unwrap_or_else(|| vec![0.0; m]);
    let mut active: Vec<bool> = match &options.initial_x {
        Some(x0) => pdas_rule(c, c_rule, &mat_vec(&c.matrix, x0), &lambda0),
        None if options.initial_lambda.is_some() => lambda0.iter().map(|&l| l > 0.0).collect(),
        None => c.obstacle.iter().map(|&g| g > 0.0).collect(),
    };

    let pattern = SystemPattern {
        matrix: &newton.matrix,
        kind,
        solves: Solves::Few,
        interior: problem.interior.as_ref(),
        what: "active-set Newton matrix",
    };
    let mut factorizer = analyse(pattern, &options.linear)?;
    // Steps differ in the multiplier diagonal only (module docs): the
    // bubbles are eliminated once, by the first factorisation.
    factorizer.declare_changing(&newton.diagonal);
    let mut report = ReportBuilder::new("active-set", start, 0.0, t.elapsed().as_secs_f64())
        .with_history(&EXTRA_COLUMNS)
        .iterating(
            "Active set",
            options.max_iter,
            options.tol,
            options.show_progress,
        );
    let mut seen: Vec<Vec<bool>> = Vec::new();
    let cold = options.initial_lambda.is_none() && options.initial_x.is_none();
    let mut bisection = match options.cold_start {
        ColdStart::DepthBisection { probes } if cold => Some(DepthBisection::new(probes)),
        _ => None,
    };
    let mut probes = 0usize;
    let mut previous = vec![false; m];
    let mut lambda = lambda0;
    let mut x = vec![0.0; n];
    let mut max_linear_residual = 0.0f64;
    let mut interior_point_steps = 0;
    let mut first_step = 1;
    let mut interior_answer = false;
    if let (
        ColdStart::InteriorPoint {
            handover,
            max_steps,
        },
        true,
    ) = (options.cold_start, cold)
    {
        let start = InteriorPoint {
            problem,
            c_rule,
            handover,
            max_steps: max_steps.min(options.max_iter.saturating_sub(1)),
        };
        let h = start.run(newton, factorizer.as_mut(), &mut report)?;
        max_linear_residual = h.max_linear_residual;
        interior_point_steps = h.steps - 1;
        first_step = h.steps + 1;
        (x, lambda) = (h.x, h.lambda);
        // An interior iterate has every λ_i > 0: PDAS makes the answer
        // complementary (one step from an exact prediction), unless the
        // free solution (λ = 0) already is the answer.
        if h.steps == 1 && report.measures.kkt <= options.tol {
            report.stop("kkt");
            first_step = usize::MAX;
        } else {
            active = h.predicted;
            previous = active.clone();
            interior_answer = first_step > options.max_iter;
        }
    }
    let mut rhs = vec![0.0; n + m];
    // The last factorisation and the set it was made for, while PDAS
    // steps may be solved with it.
    let mut kept: Option<(Box<dyn Factors>, Vec<bool>)> = None;
    let mut switched_steps = 0usize;
    let c_rows = match options.switched_steps {
        true => Some(constraint_rows(c)?),
        false => None,
    };
    // A switched step that took longer than the last factorised one ends
    // switching for the run: where solves cost a large part of a
    // factorisation (the membrane disk p1b-p0 at n = 256: 0.66 s switched
    // against 0.52 s factorised), the bordered system's four do not pay.
    let mut switching = options.switched_steps;
    let mut factorised_seconds = f64::INFINITY;
    for k in first_step..=options.max_iter {
        rhs[..n].copy_from_slice(&problem.rhs);
        for i in 0..m {
            rhs[n + i] = if active[i] {
                newton.scale[i] * c.obstacle[i]
            } else {
                0.0
            };
        }
        let t = Instant::now();
        let switched = match (&kept, &c_rows) {
            (Some((f, factorised)), Some(c_rows)) if switching => {
                SwitchedSolve::new(f.as_ref(), factorised, &active, newton, c_rows)
                    .and_then(|switched| switched.solve(f.as_ref(), newton, &rhs))
            }
            _ => None,
        };
        let (z, linear_residual) = match switched {
            Some(solved) => {
                switched_steps += 1;
                switching = t.elapsed().as_secs_f64() < factorised_seconds;
                solved
            }
            None => {
                // The Newton matrix is shared with the kept factorisation.
                drop(kept.take());
                newton.set_active(&active);
                let (factorization, mut z, solve_residual) =
                    factorizer.factor_and_solve_shared(&newton.matrix, &rhs, Changed::Declared)?;
                // LU: refinement steps on top; LDLᵀ solves refine themselves.
                let steps = match factorization.refines_itself() {
                    true => 0,
                    false => options.refinement_steps,
                };
                // (No steps: the factorisation's own check measured the residual.)
                let linear_residual = match steps {
                    0 => solve_residual,
                    _ => refine(
                        &newton.matrix,
                        kind,
                        factorization.as_ref(),
                        &rhs,
                        &mut z,
                        steps,
                    ),
                };
                kept = Some((factorization, active.clone()));
                factorised_seconds = t.elapsed().as_secs_f64();
                (z, linear_residual)
            }
        };
        report.factor_seconds += t.elapsed().as_secs_f64();
        max_linear_residual = max_linear_residual.max(linear_residual);
        check_finite(STAGE, k, "Newton step", &z)?;
        x.copy_from_slice(&z[..n]);
        let new_lambda: Vec<f64> = (0..m)
            .map(|i| {
                if active[i] {
                    -newton.scale[i] * z[n + i]
                } else {
                    0.0
                }
            })
            .collect();
        let dual_step = new_lambda
            .iter()
            .zip(&lambda)
            .fold(0.0f64, |s, (a, b)| s.max((a - b).abs()));
        lambda = new_lambda;
        let products = IterateProducts::of(newton, problem, &x, &lambda);
        let measures = products.measures(newton, problem, &x, &lambda);
        let cx = products.cx;
        let added = (0..m).filter(|&i| active[i] && !previous[i]).count();
        let removed = (0..m).filter(|&i| !active[i] && previous[i]).count();
        report.record(
            k,
            dual_step,
            measures,
            &[
                active.iter().filter(|&&a| a).count() as f64,
                (added + removed) as f64,
                added as f64,
                removed as f64,
                linear_residual,
            ],
        );
        if measures.kkt <= options.tol {
            report.stop("kkt");
            break;
        }
        // The next active set.
        let gaps: Vec<f64> = (0..m).map(|i| c.mean_gap(&cx, i)).collect();
        let mut next = pdas_rule(c, c_rule, &cx, &lambda);
        if let Some(b) = bisection.as_mut() {
            match b.propose(&c.matrix, &active, &lambda, &gaps, next) {
                Probe::Next(set) => {
                    // A probe, not a step of one Newton sequence: the
                    // stagnation and cycling checks start after the probes.
                    probes += 1;
                    previous = std::mem::replace(&mut active, set);
                    continue;
                }
                Probe::Finish(set) => {
                    bisection = None;
                    next = set;
                }
            }
        }
        if next == active {
            return Err(Error::numerical(
                STAGE,
                "KKT measure",
                format!(
                    "stagnation at iteration {k}: the active set ({} constraints) did not change but the relative KKT measure is {:.3e} > tol {:.1e} (penetration {:.1e}, complementarity {:.1e}, stationarity {:.1e}, gap scale {:.1e}; linear residual {linear_residual:.1e}): the tolerance is below the accuracy of the linear solves",
                    count(&active),
                    measures.kkt,
                    options.tol,
                    measures.penetration,
                    measures.complementarity,
                    measures.stationarity,
                    measures.gap_scale
                ),
            ));
        }
        seen.push(active.clone());
        if let Some(j) = seen.iter().position(|s| *s == next) {
            return Err(Error::numerical(
                STAGE,
                "active set 𝒜",
                format!(
                    "cycling at iteration {k}: the next active set ({} constraints) is the one of iteration {} (relative KKT measure {:.3e}); the semismooth Newton iteration is not globally convergent for this matrix, try a warm start or another solver",
                    count(&next),
                    j + 1,
                    measures.kkt
                ),
            ));
        }
        previous = std::mem::replace(&mut active, next);
    }
    let counts = factorizer.counts();
    let c_min = c_rule.iter().cloned().fold(f64::INFINITY, f64::min);
    let c_max = c_rule.iter().cloned().fold(0.0, f64::max);
    let parameters = named(&[
        ("tol", options.tol),
        ("c_min", c_min),
        ("c_max", c_max),
        ("symbolic_analyses", counts.symbolic_analyses as f64),
        (
            "numeric_factorizations",
            counts.numeric_factorizations as f64,
        ),
        ("factorized_work", counts.factorized_work),
        ("max_linear_residual", max_linear_residual),
        ("bisection_probes", probes as f64),
        ("interior_point_steps", interior_point_steps as f64),
        ("switched_steps", switched_steps as f64),
    ]);
    let mut report = report.finish(x, lambda, parameters);
    // `max_iter` inside the interior-point start: the answer is its iterate
    // (every λ_i > 0), in contact where it predicts.
    if interior_answer {
        report.predicted_contact = Some(active);
    }
    Ok(report)
}

/// The rows of C, each as a column: (C's transpose, column-major).
fn constraint_rows(c: &Constraint) -> Result<SparseColMat<usize, f64>> {
    c.matrix
        .as_ref()
        .transpose()
        .to_col_major()
        .map_err(|e| Error::numerical(STAGE, "constraint matrix", format!("its transpose: {e:?}")))
}

/// A PDAS step solved with the factorisation of the last factorised
/// Newton matrix M, whose active set differs from this step's in r
/// constraints. The step's matrix M' differs from M only in those
/// multipliers' diagonal entries (0 on the set, −d_off off it), so M' z = b
/// is the bordered system
///
///   [M  W] [z]   [b_M]
///   [Wᵀ 0] [ω] = [h  ],
///
/// one column per switched constraint: a constraint switched off pins its
/// multiplier (w = e_(n+i), h = 0; M's equation of that row is relaxed by
/// ω_i); one switched on adds its row of the Newton matrix, s_j C_j, as a
/// column (h = its right-hand side; M decouples its old row, whose right
/// side is set to 0), and ω_j is its multiplier. Through the Schur
/// complement G = Wᵀ M⁻¹ W (r × r): ω = G⁻¹ (Wᵀ M⁻¹ b_M − h), z = M⁻¹ (b_M −
/// W ω), two solves with M's factors. G comes from the columns' forward
/// sweeps over the paths of the elimination tree they reach
/// ([`Factors::inverse_gram`]), a fraction of a factorisation when r
/// is small (the fringe the last PDAS steps switch). Exact in exact
/// arithmetic; refined against M' like any solve.
struct SwitchedSolve {
    /// Constraints switched on and off against the factorised set.
    on: Vec<usize>,
    off: Vec<usize>,
    /// W's columns: the off ones (e_(n+i)), then the on ones (s_j C_j).
    columns: Vec<Vec<(usize, f64)>>,
    /// s_i C_i of the constraints switched off: their rows of M' read
    /// s_i C_i x − d_off μ_i = 0.
    off_rows: Vec<Vec<(usize, f64)>>,
    switched_off: f64,
    n: usize,
    g: nalgebra::LU<f64, nalgebra::Dyn, nalgebra::Dyn>,
}

/// A switched solve is refined once (kept unless its residual grew), and
/// again while its relative residual ‖b − M'z‖∞ / ‖b‖∞ is above
/// [`SWITCHED_ROUND_OFF`] and halves (at most this many steps):
/// the multipliers ω come out of G's solve, and a small residual alone
/// does not make them accurate (the shell at n = 128: unrefined 1.6e-15
/// left the KKT measure at 2.0e-10 and PDAS stagnated; refined once, 6e-16
/// and 1.7e-11). A solve that ends above [`SWITCHED_ACCEPTED`] is refused:
/// the step is factorised instead.
const SWITCHED_REFINEMENTS: usize = 4;
/// Solves with M's factors in a switched step: the bordered solve and
/// one refinement, two each.
const SWITCHED_SOLVES: usize = 4;
const SWITCHED_ACCEPTED: f64 = 1e-12;
/// The relative residual from which a switched solve's refinement stops
/// after its first step: at it, a second step never halved it (the shell
/// at n = 256, every switched step: unrefined 2.4e-15 … 2.6e-15, refined
/// once 6.1e-16, twice 4.9e-16 … 6.1e-16), and each step is two solves
/// and a product, 0.85 s there.
const SWITCHED_ROUND_OFF: f64 = 1e-15;

impl SwitchedSolve {
    /// None when nothing switched or the sweep of the columns would cost
    /// too much ([`Factors::inverse_gram`]).
    fn new(
        f: &dyn Factors,
        factorised: &[bool],
        active: &[bool],
        newton: &NewtonMatrix,
        c_rows: &SparseColMat<usize, f64>,
    ) -> Option<Self> {
        let n = newton.n;
        let on: Vec<usize> = (0..active.len())
            .filter(|&i| active[i] && !factorised[i])
            .collect();
        let off: Vec<usize> = (0..active.len())
            .filter(|&i| !active[i] && factorised[i])
            .collect();
        let r = on.len() + off.len();
        if r == 0 {
            return None;
        }
        let row = |i: usize| -> Vec<(usize, f64)> {
            let s = newton.scale[i];
            let rows = c_rows.symbolic().row_idx_of_col(i);
            rows.zip(c_rows.val_of_col(i))
                .map(|(j, &v)| (j, s * v))
                .collect()
        };
        let mut columns: Vec<Vec<(usize, f64)>> = off.iter().map(|&i| vec![(n + i, 1.0)]).collect();
        columns.extend(on.iter().map(|&j| row(j)));
        let gram = f.inverse_gram(&columns, newton.matrix.nrows(), SWITCHED_SOLVES)?;
        Some(SwitchedSolve {
            off_rows: off.iter().map(|&i| row(i)).collect(),
            on,
            off,
            columns,
            switched_off: newton.switched_off,
            n,
            g: nalgebra::DMatrix::from_column_slice(r, r, &gram).lu(),
        })
    }

    /// One bordered solve (two with M's factors), not refined; None when
    /// G is singular.
    fn raw(&self, f: &dyn Factors, b: &[f64]) -> Option<Vec<f64>> {
        let n = self.n;
        let n_off = self.off.len();
        let mut b_m = b.to_vec();
        let mut h = vec![0.0; self.columns.len()];
        for (q, &j) in self.on.iter().enumerate() {
            h[n_off + q] = std::mem::take(&mut b_m[n + j]);
        }
        let mut y = b_m.clone();
        f.solve_unrefined_in_place(&mut y);
        let schur_rhs = nalgebra::DVector::from_iterator(
            h.len(),
            self.columns
                .iter()
                .zip(&h)
                .map(|(column, h)| column.iter().map(|&(i, v)| v * y[i]).sum::<f64>() - h),
        );
        let omega = self.g.solve(&schur_rhs)?;
        for (column, w) in self.columns.iter().zip(omega.iter()) {
            for &(i, v) in column {
                b_m[i] -= v * w;
            }
        }
        f.solve_unrefined_in_place(&mut b_m);
        let mut z = b_m;
        for (&i, row) in self.off.iter().zip(&self.off_rows) {
            z[n + i] = row.iter().map(|&(j, v)| v * z[j]).sum::<f64>() / self.switched_off;
        }
        for (q, &j) in self.on.iter().enumerate() {
            z[n + j] = omega[n_off + q];
        }
        Some(z)
    }

    /// M' z from M's matrix: the switched multipliers never meet M's
    /// diagonal entries (0 or −d_off, the other of M''s: their difference
    /// would swamp the rest of the row), they are multiplied apart.
    fn product(&self, newton: &NewtonMatrix, z: &[f64]) -> Vec<f64> {
        let n = self.n;
        let mut masked = z.to_vec();
        for &i in self.on.iter().chain(&self.off) {
            masked[n + i] = 0.0;
        }
        let mut y = crate::linalg::product(&newton.matrix, newton.kind, &masked);
        let n_off = self.off.len();
        for (q, &j) in self.on.iter().enumerate() {
            for &(k, v) in &self.columns[n_off + q] {
                y[k] += v * z[n + j];
            }
        }
        for (&i, row) in self.off.iter().zip(&self.off_rows) {
            for &(k, v) in row {
                y[k] += v * z[n + i];
            }
            y[n + i] -= self.switched_off * z[n + i];
        }
        y
    }

    /// z with M' z = b, refined against M', and its relative residual;
    /// None (the caller factorises) when it does not reach
    /// [`SWITCHED_ACCEPTED`] or is not finite.
    fn solve(&self, f: &dyn Factors, newton: &NewtonMatrix, b: &[f64]) -> Option<(Vec<f64>, f64)> {
        let b_norm = norm_inf(b).max(f64::MIN_POSITIVE);
        let residual = |z: &[f64]| -> (Vec<f64>, f64) {
            let r: Vec<f64> = b
                .iter()
                .zip(self.product(newton, z))
                .map(|(b, y)| b - y)
                .collect();
            let size = norm_inf(&r) / b_norm;
            (r, size)
        };
        let mut z = self.raw(f, b)?;
        let (mut r, mut size) = residual(&z);
        for step in 0..SWITCHED_REFINEMENTS {
            if step > 0 && size <= SWITCHED_ROUND_OFF {
                break;
            }
            let dz = self.raw(f, &r)?;
            let candidate: Vec<f64> = z.iter().zip(&dz).map(|(a, d)| a + d).collect();
            let (r_new, size_new) = residual(&candidate);
            let pays = match step {
                0 => size_new <= size,
                _ => size_new < 0.5 * size,
            };
            if !pays {
                break;
            }
            (z, r, size) = (candidate, r_new, size_new);
        }
        let finite = z.iter().all(|v| v.is_finite());
        (finite && size <= SWITCHED_ACCEPTED).then_some((z, size))
    }
}

/// Whether the interior point's predicted set has settled
/// ([`SETTLED_SET_CHANGE`]): `changes` of it changed in the last step, and
/// `affine_set` is the PDAS rule's set at that step's affine-scaling point.
fn settled(predicted: &[bool], changes: usize, affine_set: &[bool]) -> bool {
    let allowed = SETTLED_SET_CHANGE * count(predicted) as f64;
    let off_affine = predicted
        .iter()
        .zip(affine_set)
        .filter(|(p, a)| p != a)
        .count();
    changes as f64 <= allowed || off_affine as f64 <= allowed
}

fn count(set: &[bool]) -> usize {
    set.iter().filter(|&&a| a).count()
}

/// The PDAS rule's set {i : λ_i − c_i ḡ_i > 0}, ḡ the mean gaps of C x.
fn pdas_rule(c: &Constraint, c_rule: &[f64], cx: &[f64], lambda: &[f64]) -> Vec<bool> {
    (0..lambda.len())
        .map(|i| lambda[i] - c_rule[i] * c.mean_gap(cx, i) > 0.0)
        .collect()
}

/// What the depth bisection proposes after a solve.
enum Probe {
    /// The next probe.
    Next(Vec<bool>),
    /// The probing is over: plain PDAS continues from this set.
    Finish(Vec<bool>),
}

/// Bisection on nested candidate sets {depth > ℓ} (module docs).
struct DepthBisection {
    max_probes: usize,
    probes: usize,
    /// Layer depth inside the free solution's penetration set; None before
    /// the first (free) solve.
    depth: Option<Vec<f64>>,
    /// Bracket: the level of a too-large set, of a too-small one, and the
    /// level probed now.
    too_large: f64,
    too_small: f64,
    level: f64,
    /// The plain PDAS proposal after the least violating solve so far,
    /// with its count of violations (negative λ + penetrations).
    best: Option<(usize, Vec<bool>)>,
}

impl DepthBisection {
    fn new(max_probes: usize) -> Self {
        DepthBisection {
            max_probes,
            probes: 0,
            depth: None,
            too_large: 0.0,
            too_small: 0.0,
            level: 0.0,
            best: None,
        }
    }

    /// The next set after a solve on `active` that gave (λ, ḡ); `plain` is
    /// the plain PDAS proposal.
    fn propose(
        &mut self,
        c: &SparseColMat<usize, f64>,
        active: &[bool],
        lambda: &[f64],
        gaps: &[f64],
        plain: Vec<bool>,
    ) -> Probe {
        let m = active.len();
        let negative = (0..m).filter(|&i| active[i] && lambda[i] < 0.0).count();
        let penetrating = (0..m).filter(|&i| !active[i] && gaps[i] < 0.0).count();
        if self
            .best
            .as_ref()
            .is_none_or(|(v, _)| negative + penetrating < *v)
        {
            self.best = Some((negative + penetrating, plain));
        }
        match &self.depth {
            None => {
                let inside: Vec<bool> = gaps.iter().map(|&g| g < 0.0).collect();
                let depth = layer_depth(&constraint_neighbours(c), &inside);
                self.too_large = 0.0;
                self.too_small = depth.iter().cloned().fold(0.0, f64::max);
                self.depth = Some(depth);
            }
            Some(_) => {
                self.probes += 1;
                if negative > penetrating {
                    self.too_large = self.level;
                } else {
                    self.too_small = self.level;
                }
            }
        }
        let depth = self.depth.as_ref().expect("set above");
        let set_at = |l: f64| -> Vec<bool> { depth.iter().map(|&d| d > l).collect() };
        let level = 0.5 * (self.too_large + self.too_small);
        let next = set_at(level);
        if self.probes >= self.max_probes
            || next == set_at(self.too_large)
            || next == set_at(self.too_small)
        {
            let (_, set) = self.best.take().expect("one solve recorded");
            return Probe::Finish(set);
        }
        self.level = level;
        Probe::Next(next)
    }
}

/// Neighbouring constraints: rows of C that share a column (for P0 contact,
/// triangles sharing a vertex; for P1, vertices within two edges). Columns shared by more than 24 rows are
/// skipped (not a local neighbourhood).
fn constraint_neighbours(c: &SparseColMat<usize, f64>) -> Vec<Vec<usize>> {
    let mut neighbours: Vec<Vec<usize>> = vec![Vec::new(); c.nrows()];
    for j in 0..c.ncols() {
        let rows: Vec<usize> = c.symbolic().row_idx_of_col(j).collect();
        if rows.len() > 24 {
            continue;
        }
        for &a in &rows {
            neighbours[a].extend(rows.iter().copied().filter(|&b| b != a));
        }
    }
    for list in neighbours.iter_mut() {
        list.sort_unstable();
        list.dedup();
    }
    neighbours
}

/// Graph distance in layers of each member of `inside` to the nearest
/// non-member (1 for the rim); 0 outside; 1 for all when every constraint
/// is inside.
fn layer_depth(neighbours: &[Vec<usize>], inside: &[bool]) -> Vec<f64> {
    let m = inside.len();
    let mut depth = vec![usize::MAX; m];
    let mut queue = std::collections::VecDeque::new();
    for i in (0..m).filter(|&i| !inside[i]) {
        depth[i] = 0;
        queue.push_back(i);
    }
    while let Some(i) = queue.pop_front() {
        for &j in &neighbours[i] {
            if depth[j] == usize::MAX {
                depth[j] = depth[i] + 1;
                queue.push_back(j);
            }
        }
    }
    depth
        .into_iter()
        .map(|d| if d == usize::MAX { 1.0 } else { d as f64 })
        .collect()
}

/// The interior-point start (module docs): Mehrotra predictor–corrector
/// steps on the Newton matrix with every constraint on.
struct InteriorPoint<'a> {
    problem: &'a ContactProblem,
    /// c_i of the PDAS rule, for the predicted set.
    c_rule: &'a [f64],
    handover: f64,
    max_steps: usize,
}

/// Where the interior-point start hands over to PDAS.
struct Handover {
    x: Vec<f64>,
    lambda: Vec<f64>,
    /// The PDAS rule's set at (x, λ).
    predicted: Vec<bool>,
    /// Newton solves done, the free one included (history rows 1..=steps).
    steps: usize,
    max_linear_residual: f64,
}

/// The fraction of the step to the boundary of (λ, t) > 0 taken. Measured
/// on the thesis shell (tol 1e-10, 1e-8 at n = 256), Newton solves at
/// n = 16, 32, 64, 128, 256: 0.99 gave 8, 13, 14, 16, 17; 0.95 gives 9,
/// 11, 13, 15, 16 (0.93 and 0.97 within one of these at n ≤ 128): the
/// iterates stay nearer the central path, fewer steps are blocked.
const STEP_TO_BOUNDARY: f64 = 0.95;
/// Near the solution (relative KKT measure below `LATE_BELOW`) the steps
/// go nearer the boundary, as the fraction → 1 of the convergence theory:
/// Newton solves at n = 16, 32, 64, 128, 256 went from 9, 11, 13, 15, 16
/// to 8, 11, 13, 14, 16 (0.99 alike; from KKT 1e-3 on alike).
const LATE_STEP_TO_BOUNDARY: f64 = 0.995;
const LATE_BELOW: f64 = 1e-4;
/// The handover waits for the predicted set to settle ([`settled`]): at
/// most this fraction of it changed in the last step, or differs from the
/// PDAS rule's set at the step's affine-scaling point. The KKT bound alone
/// handed over too early at n = 512 (a predicted set of 11,282 triangles
/// for a zone of 133,056: 7 PDAS steps, 18 solves). The last step's change
/// alone waits one interior-point step more where the set jumps to the
/// zone in one step (n = 128: 550 → 6884 for 6806) that the affine point
/// already predicted (30 of the 6884 differ). With the affine test, n =
/// 128 and 256 keep their 14 and 16 Newton solves with one factorisation
/// fewer (one more PDAS step, switched), n = 512 takes 15 against 16
/// (docs/work-precision.md, "Hand over when the affine-scaling point
/// agrees").
const SETTLED_SET_CHANGE: f64 = 0.05;
/// The centring offset of the start, relative to the largest penetration
/// (0.05 … 3 measured: the same Newton solves to ±1).
const START_OFFSET: f64 = 0.5;

impl InteriorPoint<'_> {
    fn run(
        &self,
        newton: &mut NewtonMatrix,
        factorizer: &mut dyn LinearSolver,
        report: &mut ReportBuilder,
    ) -> Result<Handover> {
        let problem = self.problem;
        let c = problem.constraint.as_ref().expect("a constrained problem");
        let (n, m) = (problem.n(), c.obstacle.len());
        // The free solve, and its factorisation for the multiplier scale κ.
        newton.set_active(&vec![false; m]);
        let mut rhs = vec![0.0; n + m];
        rhs[..n].copy_from_slice(&problem.rhs);
        let t = Instant::now();
        let (free, z, mut max_residual) =
            factorizer.factor_and_solve_shared(&newton.matrix, &rhs, Changed::Declared)?;
        report.factor_seconds += t.elapsed().as_secs_f64();
        check_finite(STAGE, 1, "free solve", &z)?;
        let mut x = z[..n].to_vec();
        let mut lambda = vec![0.0; m];
        let mut products = IterateProducts::of(newton, problem, &x, &lambda);
        let mut predicted = pdas_rule(c, self.c_rule, &products.cx, &lambda);
        self.record(
            report,
            (1, 0.0),
            products.measures(newton, problem, &x, &lambda),
            &predicted,
            &vec![false; m],
            max_residual,
        );
        if report.measures.kkt <= self.handover {
            return Ok(Handover {
                x,
                lambda,
                predicted,
                steps: 1,
                max_linear_residual: max_residual,
            });
        }
        let gap: Vec<f64> = (0..m).map(|i| products.cx[i] - c.obstacle[i]).collect();
        let penetration: Vec<f64> = gap.iter().map(|&g| (-g).max(0.0)).collect();
        let p_max = norm_inf(&penetration);
        if p_max == 0.0 {
            // Nothing penetrates: no multiplier scale to start from; PDAS
            // continues from the free solution's set.
            return Ok(Handover {
                x,
                lambda,
                predicted,
                steps: 1,
                max_linear_residual: max_residual,
            });
        }
        let mut y = vec![0.0; n + m];
        y[..n].copy_from_slice(&mat_t_vec(&c.matrix, &penetration));
        free.solve_in_place(&mut y);
        drop(free);
        let dual_p = dot(&penetration, &mat_vec(&c.matrix, &y[..n]));
        let kappa = dot(&penetration, &penetration) / dual_p;
        if !(kappa.is_finite() && kappa > 0.0) {
            return Err(Error::numerical(
                STAGE,
                "interior-point start",
                format!("the multiplier scale κ = pᵀp / pᵀ C A⁻¹ Cᵀ p is {kappa:.3e} (pᵀ C A⁻¹ Cᵀ p = {dual_p:.3e}): A is not positive on the penetration"),
            ));
        }
        let (eps_lambda, eps_gap) = (START_OFFSET * kappa * p_max, START_OFFSET * p_max);
        let mu0 = eps_lambda * eps_gap;
        lambda = gap
            .iter()
            .map(|&g| match g < 0.0 {
                true => -kappa * g + eps_lambda,
                false => mu0 / (g + eps_gap),
            })
            .collect();
        let mut slack: Vec<f64> = lambda.iter().map(|l| mu0 / l).collect();
        products.ct_lambda = mat_t_vec(&c.matrix, &lambda);
        let mut k = 1;
        while k <= self.max_steps {
            k += 1;
            // Residuals: r_d = F + Cᵀλ − A x, r_p = C x − g − t (t: slack).
            let IterateProducts { ax, cx, ct_lambda } = &products;
            let r_d: Vec<f64> = (0..n)
                .map(|j| problem.rhs[j] + ct_lambda[j] - ax[j])
                .collect();
            let r_p: Vec<f64> = (0..m).map(|i| cx[i] - c.obstacle[i] - slack[i]).collect();
            let mu = dot(&slack, &lambda) / m as f64;
            let delta: Vec<f64> = (0..m)
                .map(|i| newton.scale[i].powi(2) * slack[i] / lambda[i])
                .collect();
            newton.set_barrier(&delta);
            let s = &newton.scale;
            // Row n + i: s_i (C dx)_i − Δ_i dμ_i = s_i (r_c,i/λ_i − r_p,i),
            // dλ = −S dμ, dt = C dx + r_p; r_c the complementarity target.
            let rhs_of = |r_c: &dyn Fn(usize) -> f64, rhs: &mut [f64]| {
                rhs[..n].copy_from_slice(&r_d);
                for i in 0..m {
                    rhs[n + i] = s[i] * (r_c(i) / lambda[i] - r_p[i]);
                }
            };
            let direction = |z: &[f64]| -> (Vec<f64>, Vec<f64>) {
                let dl: Vec<f64> = (0..m).map(|i| -s[i] * z[n + i]).collect();
                let cdx = mat_vec(&c.matrix, &z[..n]);
                (dl, (0..m).map(|i| cdx[i] + r_p[i]).collect())
            };
            // Predictor (affine scaling): r_c = −λ∘t.
            rhs_of(&|i| -slack[i] * lambda[i], &mut rhs);
            let t = Instant::now();
            let (f, z, residual) =
                factorizer.factor_and_solve_shared(&newton.matrix, &rhs, Changed::Declared)?;
            report.factor_seconds += t.elapsed().as_secs_f64();
            max_residual = max_residual.max(residual);
            check_finite(STAGE, k, "interior-point predictor", &z)?;
            let (dl_aff, dt_aff) = direction(&z);
            // The PDAS rule's set at the affine-scaling point (x + dx_aff,
            // λ + dλ_aff), a second prediction for the settle test:
            // C(x + dx_aff) = C x + dt_aff − r_p.
            let affine_set = {
                let cx_aff: Vec<f64> = (0..m)
                    .map(|i| products.cx[i] + dt_aff[i] - r_p[i])
                    .collect();
                let lambda_aff: Vec<f64> = (0..m).map(|i| lambda[i] + dl_aff[i]).collect();
                pdas_rule(c, self.c_rule, &cx_aff, &lambda_aff)
            };
            let a_aff = step_to_boundary(&slack, &dt_aff).min(step_to_boundary(&lambda, &dl_aff));
            let mu_aff = (0..m)
                .map(|i| (slack[i] + a_aff * dt_aff[i]) * (lambda[i] + a_aff * dl_aff[i]))
                .sum::<f64>()
                / m as f64;
            let sigma = (mu_aff / mu).powi(3).min(1.0);
            // Corrector: r_c = σμ − λ∘t − dλ_aff∘dt_aff, the same factorisation.
            rhs_of(
                &|i| sigma * mu - slack[i] * lambda[i] - dl_aff[i] * dt_aff[i],
                &mut rhs,
            );
            let mut z = rhs.clone();
            f.solve_unrefined_in_place(&mut z);
            drop(f);
            check_finite(STAGE, k, "interior-point corrector", &z)?;
            let (dl, dt) = direction(&z);
            let fraction = match report.measures.kkt < LATE_BELOW {
                true => LATE_STEP_TO_BOUNDARY,
                false => STEP_TO_BOUNDARY,
            };
            let alpha = (fraction
                * step_to_boundary(&slack, &dt).min(step_to_boundary(&lambda, &dl)))
            .min(1.0);
            x.iter_mut().zip(&z[..n]).for_each(|(v, d)| *v += alpha * d);
            lambda
                .iter_mut()
                .zip(&dl)
                .for_each(|(v, d)| *v += alpha * d);
            slack.iter_mut().zip(&dt).for_each(|(v, d)| *v += alpha * d);
            products = IterateProducts::of(newton, problem, &x, &lambda);
            let next = pdas_rule(c, self.c_rule, &products.cx, &lambda);
            let before = std::mem::replace(&mut predicted, next);
            let changes = self.record(
                report,
                (k, alpha * norm_inf(&dl)),
                products.measures(newton, problem, &x, &lambda),
                &predicted,
                &before,
                residual,
            );
            if report.measures.kkt <= self.handover && settled(&predicted, changes, &affine_set) {
                break;
            }
        }
        Ok(Handover {
            x,
            lambda,
            predicted,
            steps: k,
            max_linear_residual: max_residual,
        })
    }

    /// History row k of an interior-point step (`step` = (k, its dual
    /// step)): `active` is the predicted set, `changes` against the
    /// previous step's, which it returns.
    fn record(
        &self,
        report: &mut ReportBuilder,
        (k, dual_step): (usize, f64),
        measures: KktMeasures,
        predicted: &[bool],
        before: &[bool],
        linear_residual: f64,
    ) -> usize {
        let added = (0..predicted.len())
            .filter(|&i| predicted[i] && !before[i])
            .count();
        let removed = (0..predicted.len())
            .filter(|&i| !predicted[i] && before[i])
            .count();
        report.record(
            k,
            dual_step,
            measures,
            &[
                count(predicted) as f64,
                (added + removed) as f64,
                added as f64,
                removed as f64,
                linear_residual,
            ],
        );
        added + removed
    }
}

/// A x (from the lent Newton matrix), C x and Cᵀλ of an iterate: its
/// measures, the next set and an interior-point step's residuals read them.
struct IterateProducts {
    ax: Vec<f64>,
    cx: Vec<f64>,
    ct_lambda: Vec<f64>,
}

impl IterateProducts {
    fn of(newton: &NewtonMatrix, problem: &ContactProblem, x: &[f64], lambda: &[f64]) -> Self {
        let c = problem.constraint.as_ref().expect("a constrained problem");
        IterateProducts {
            ax: newton.a_product(x),
            cx: mat_vec(&c.matrix, x),
            ct_lambda: mat_t_vec(&c.matrix, lambda),
        }
    }

    fn measures(
        &self,
        newton: &NewtonMatrix,
        problem: &ContactProblem,
        x: &[f64],
        lambda: &[f64],
    ) -> KktMeasures {
        let products = Products {
            ax: Some(&self.ax),
            cx: Some(&self.cx),
            ct_lambda: Some(&self.ct_lambda),
            compliance: Some(&newton.compliance),
        };
        kkt_measures_with(problem, x, lambda, products)
    }
}

/// The largest α ≤ 1 with v + α dv ≥ 0 (v > 0).
fn step_to_boundary(v: &[f64], dv: &[f64]) -> f64 {
    v.iter()
        .zip(dv)
        .filter(|(_, &d)| d < 0.0)
        .fold(1.0f64, |a, (&vi, &d)| a.min(-vi / d))
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(p, q)| p * q).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A set of `size` triangles in contact among 1000, from index `from`.
    fn set(from: usize, size: usize) -> Vec<bool> {
        (0..1000)
            .map(|i| (from..from + size).contains(&i))
            .collect()
    }

    /// The settle test hands over once either prediction agrees: a set
    /// that jumped to the zone in one step (n = 128: 550 → 6884) and that
    /// the affine-scaling point predicts too (30 of 6884 off); not one
    /// that the affine point contradicts (n = 512: 11,282 with 116,762
    /// off), nor a set that is still moving.
    #[test]
    fn the_set_settles_when_either_prediction_agrees() {
        let jumped = set(0, 400);
        // 370 changed in the last step (92 %), 10 differ from the affine
        // point's set (2.5 %): settled.
        assert!(settled(&jumped, 370, &set(5, 400)));
        // The same jump, and the affine point predicts 900 triangles.
        assert!(!settled(&jumped, 370, &set(0, 900)));
        // 20 changed (5 %): settled whatever the affine point says.
        assert!(settled(&jumped, 20, &set(0, 900)));
        assert!(!settled(&jumped, 21, &set(0, 900)));
        // Exactly at the bound on the affine side: 20 differ.
        assert!(settled(&jumped, 370, &set(0, 420)));
        assert!(!settled(&jumped, 370, &set(0, 421)));
        // An empty set that did not change is settled, as before.
        assert!(settled(&set(0, 0), 0, &set(0, 5)));
    }
}
