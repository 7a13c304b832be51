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
//! (`Changed::Declared`). Measured on the thesis shell at n = 128: a step
//! with a new active set takes 0.34 s this way and 0.47 s with the bubbles
//! eliminated anew at each step (an interior-point step: 0.35 s). The matrix is
//! symmetric and quasi-definite in sign (multipliers, ψ's included,
//! negative), so it is factorised by the signed-regularised LDLᵀ when A is
//! symmetric ([`MatrixKind::SymmetricSaddle`]), by LU otherwise. Its pattern
//! is fixed: the symbolic analysis is done once and each step is a numeric
//! refactorisation only (`linalg::LinearSolver`), checked on the Newton
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

mod cold_start;
mod newton;

use super::measures::{jacobi_dual_diagonal, kkt_measures_with, KktMeasures, Products};
use super::monitor::check_finite;
use super::uzawa::solve_unconstrained;
use super::{named, Constraint, ContactProblem, ReportBuilder, SolveReport};
use crate::error::{Error, Result};
use crate::linalg::{
    analyse, mat_t_vec, mat_vec, LinearOptions, MatrixKind, Solves, SystemPattern,
};
use cold_start::{DepthBisection, InteriorPoint, Probe};
use newton::{NewtonMatrix, PdasSolves};
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
    /// (`newton::SwitchedSolve`) instead of a new one.
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

/// Solves a contact problem by the primal–dual active set method (module
/// docs), its Newton steps by the linear solver of `options.linear`. The
/// solve owns the problem: its Newton matrix is built in A's arrays
/// ([`NewtonMatrix::lend`]), and A goes back into the problem it returns.
pub fn active_set(
    mut problem: ContactProblem,
    options: &ActiveSetOptions,
) -> Result<(ContactProblem, SolveReport)> {
    let start = Instant::now();
    let Some(c) = problem.constraint.as_ref() else {
        let report = solve_unconstrained(&problem, &options.linear)?;
        return Ok((problem, report));
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
    let compliance = jacobi_dual_diagonal(&problem);
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
    let mut newton = NewtonMatrix::lend(&mut problem, kind, compliance, options.linear.threads)?;
    let report = newton_steps(&problem, &mut newton, &c_rule, options, (start, t))?;
    newton.give_back(&mut problem);
    Ok((problem, report))
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
    let mut solves = PdasSolves::new(factorizer.as_mut(), c, options)?;
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
        let (z, linear_residual) = solves.solve(newton, &active, &rhs)?;
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
        check_progress(
            k,
            &active,
            &next,
            &mut seen,
            &measures,
            options.tol,
            linear_residual,
        )?;
        previous = std::mem::replace(&mut active, next);
    }
    let switched_steps = solves.switched_steps;
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

fn count(set: &[bool]) -> usize {
    set.iter().filter(|&&a| a).count()
}

/// Step k's next set `next` after `active` (with its measures above `tol`
/// and its linear residual): an unchanged set is stagnation, a set seen
/// before cycling (module docs), each an error that says so; `seen`
/// records `active`.
fn check_progress(
    k: usize,
    active: &[bool],
    next: &[bool],
    seen: &mut Vec<Vec<bool>>,
    measures: &KktMeasures,
    tol: f64,
    linear_residual: f64,
) -> Result<()> {
    if next == active {
        return Err(Error::numerical(
            STAGE,
            "KKT measure",
            format!(
                "stagnation at iteration {k}: the active set ({} constraints) did not change but the relative KKT measure is {:.3e} > tol {:.1e} (penetration {:.1e}, complementarity {:.1e}, stationarity {:.1e}, gap scale {:.1e}; linear residual {linear_residual:.1e}): the tolerance is below the accuracy of the linear solves",
                count(active),
                measures.kkt,
                tol,
                measures.penetration,
                measures.complementarity,
                measures.stationarity,
                measures.gap_scale
            ),
        ));
    }
    seen.push(active.to_vec());
    if let Some(j) = seen.iter().position(|s| *s == next) {
        return Err(Error::numerical(
            STAGE,
            "active set 𝒜",
            format!(
                "cycling at iteration {k}: the next active set ({} constraints) is the one of iteration {} (relative KKT measure {:.3e}); the semismooth Newton iteration is not globally convergent for this matrix, try a warm start or another solver",
                count(next),
                j + 1,
                measures.kkt
            ),
        ));
    }
    Ok(())
}

/// The PDAS rule's set {i : λ_i − c_i ḡ_i > 0}, ḡ the mean gaps of C x.
fn pdas_rule(c: &Constraint, c_rule: &[f64], cx: &[f64], lambda: &[f64]) -> Vec<bool> {
    (0..lambda.len())
        .map(|i| lambda[i] - c_rule[i] * c.mean_gap(cx, i) > 0.0)
        .collect()
}

/// A x (from the Newton matrix), C x and Cᵀλ of an iterate: its
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
        kkt_measures_with(problem, x, lambda, products, newton.threads)
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(p, q)| p * q).sum()
}
