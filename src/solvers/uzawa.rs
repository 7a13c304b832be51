//! The thesis' Uzawa iteration (Algorithm 1, "second splitting", docs/formulation.md §3):
//! A is factorised once; iteration k solves A x^k = F + Cᵀλ^{k−1} and takes
//! a projected dual step
//!
//! ```text
//!     mean form:      λ^k_i = max(0, λ^{k−1}_i − α ḡ_i(x^k))
//!     integral form:  λ^k_i = max(0, λ^{k−1}_i − α w_i ḡ_i(x^k))
//! ```
//!
//! (penetration ḡ < 0 raises λ). The reported iterate after k iterations is
//! (x^k, λ^k), and its KKT measures are computed honestly for that pair.

use super::check_finite;
use super::measures::{dual_step_norm, kkt_measures, History};
use super::spectrum::estimate_dual_spectrum;
use super::{ContactProblem, SolveReport};
use crate::error::{Error, Result};
use crate::linalg::Factorization;
use crate::linalg::{mat_t_vec, mat_vec, norm_inf};
use crate::progress::IterationProgress;
use crate::solvers::{DualNorm, Probe, StepForm, StopRule};
use std::time::Instant;

#[derive(Debug, Clone)]
pub struct UzawaOptions {
    pub alpha: f64,
    pub step_form: StepForm,
    pub max_iter: usize,
    /// Bound on the relative KKT measure.
    pub tol: f64,
    pub stop: StopRule,
    pub thesis_tol: f64,
    pub dual_norm: DualNorm,
    pub show_progress: bool,
}

/// One linear solve: the problem without contact.
pub fn solve_linear(
    problem: &ContactProblem,
    factorization: &Factorization,
    factor_seconds: f64,
) -> Result<SolveReport> {
    let start = Instant::now();
    let mut x = problem.rhs.clone();
    factorization.solve_in_place(&mut x);
    check_finite("linear solve", 1, "solution", &x)?;
    let measures = kkt_measures(problem, &x, &[], None);
    Ok(SolveReport {
        algorithm: "linear".into(),
        x,
        lambda: vec![],
        iterations: 1,
        converged: true,
        stop_reason: "linear".into(),
        measures,
        history: History::default(),
        factor_seconds,
        wall_seconds: factor_seconds + start.elapsed().as_secs_f64(),
        parameters: vec![],
    })
}

pub fn uzawa(
    problem: &ContactProblem,
    factorization: &Factorization,
    factor_seconds: f64,
    options: &UzawaOptions,
    probes: &[Probe],
) -> Result<SolveReport> {
    let start = Instant::now();
    let c = problem
        .constraint
        .as_ref()
        .expect("uzawa is called on problems with a constraint");
    let m = c.obstacle.len();
    let step_weights: Vec<f64> = match options.step_form {
        StepForm::Mean => vec![1.0; m],
        StepForm::Integral => c.weights.clone(),
    };
    let probe_names: Vec<&str> = probes.iter().map(|p| p.name.as_str()).collect();
    let mut history = History::for_solver(&probe_names);
    let mut lambda = vec![0.0; m];
    let mut x = vec![0.0; problem.n()];
    let mut measures = Default::default();
    let mut stop_reason = "max_iter";
    let mut divergence = DivergenceMonitor::default();
    // 2/s_max from a Lanczos estimate, computed once and only when needed.
    let mut bound: Option<Option<f64>> = None;
    let mut progress = IterationProgress::new(
        "Uzawa",
        options.max_iter,
        options.tol,
        options.show_progress,
    );
    let mut iterations = 0;
    for k in 1..=options.max_iter {
        iterations = k;
        // x^k = A⁻¹ (F + Cᵀ λ^{k−1})
        x = mat_t_vec(&c.matrix, &lambda);
        x.iter_mut()
            .zip(&problem.rhs)
            .for_each(|(xi, fi)| *xi += fi);
        factorization.solve_in_place(&mut x);
        check_finite("Uzawa", k, "primal iterate", &x)?;
        // λ^k = max(0, λ^{k−1} − α D ḡ(x^k))
        let cx = mat_vec(&c.matrix, &x);
        let new_lambda: Vec<f64> = (0..m)
            .map(|i| {
                let mean_gap = c.mean_gap(&cx, i);
                (lambda[i] - options.alpha * step_weights[i] * mean_gap).max(0.0)
            })
            .collect();
        check_finite("Uzawa", k, "multiplier λ", &new_lambda)?;
        let step = dual_step_norm(&new_lambda, &lambda, &c.weights, options.dual_norm);
        lambda = new_lambda;
        measures = kkt_measures(problem, &x, &lambda, Some(&cx));
        let probe_values: Vec<f64> = probes.iter().map(|p| (p.evaluate)(&x, &lambda)).collect();
        history.push_iteration(k, step, &measures, &probe_values);
        progress.update(k, measures.kkt, step);

        let mut verdict = divergence.check(k, step, measures.kkt, norm_inf(&lambda));
        let stalled = divergence.stalled(k, step, norm_inf(&lambda));
        let unconverged_end = k == options.max_iter && measures.kkt > options.tol;
        if verdict.is_none() && (stalled || unconverged_end) {
            // Judged against the bounds (see `DivergenceMonitor`): α above
            // 2/s_max of S and of S restricted to the current active set.
            let full = *bound.get_or_insert_with(|| lanczos_bound(problem, factorization, options));
            if let Some(b) = full.filter(|b| options.alpha > *b) {
                let (active, b_active) = active_set_bound(problem, factorization, options, &lambda);
                if b_active.is_some_and(|ba| options.alpha > ba) {
                    let ba = b_active.expect("checked");
                    let behaviour = if stalled {
                        format!(
                            "the step ({step:.3e}) has not decreased over the last {} iterations",
                            2 * STALL_WINDOW
                        )
                    } else {
                        format!(
                            "no convergence in max_iter = {} iterations",
                            options.max_iter
                        )
                    };
                    verdict = Some(format!(
                        "α = {:.4} × the stability bound 2/s_max and {:.4} × the bound 2/s_max(S_AA) ≈ {ba:.4e} of the {active} active multipliers, so the iteration cannot settle on this active set; {behaviour}",
                        options.alpha / b,
                        options.alpha / ba,
                    ));
                }
            }
        }
        if let Some(reason) = verdict {
            progress.finish();
            let bound = bound
                .get_or_insert_with(|| lanczos_bound(problem, factorization, options))
                .map(|b| format!("; the stability bound 2/s_max ≈ {b:.4e} (Lanczos)"))
                .unwrap_or_default();
            return Err(Error::numerical(
                "Uzawa",
                "dual step ‖λ^k − λ^{k−1}‖",
                format!(
                    "diverged at iteration {k}: {reason} (KKT measure {:.3e}); α = {} is too large{bound}",
                    measures.kkt, options.alpha
                ),
            ));
        }
        let done = match options.stop {
            StopRule::Kkt => measures.kkt <= options.tol,
            StopRule::Thesis => step < options.thesis_tol,
        };
        if done {
            stop_reason = match options.stop {
                StopRule::Kkt => "kkt",
                StopRule::Thesis => "thesis",
            };
            break;
        }
    }
    progress.finish();
    Ok(SolveReport {
        algorithm: "uzawa".into(),
        x,
        lambda,
        iterations,
        converged: measures.kkt <= options.tol,
        stop_reason: stop_reason.into(),
        measures,
        history,
        factor_seconds,
        wall_seconds: factor_seconds + start.elapsed().as_secs_f64(),
        parameters: vec![("alpha".into(), options.alpha)],
    })
}

/// The stability bound 2/s_max of the fixed-step iteration, from 50 Lanczos
/// steps (the pipeline's estimate). The Ritz value s_max^(k) is a lower bound
/// on s_max, so α > 2/s_max^(k) proves α > 2/s_max.
fn lanczos_bound(
    problem: &ContactProblem,
    factorization: &Factorization,
    options: &UzawaOptions,
) -> Option<f64> {
    estimate_dual_spectrum(problem, factorization, options.step_form, 50)
        .map(|s| 2.0 / s.s_max)
        .filter(|b| b.is_finite() && *b > 0.0)
}

/// The bound 2/s_max(S_AA) of S restricted to the active multipliers
/// A = {i: λ_i > 0} (S_AA governs the iteration once the active set has
/// settled: the clipped components stay 0), from 60 power-iteration steps on
/// P_A D^{-1/2} C A⁻¹ Cᵀ D^{-1/2} P_A. The power estimate is a lower bound on
/// s_max(S_AA), so α above the returned bound proves α > 2/s_max(S_AA).
/// Returns |A| and the bound (None when A is empty).
fn active_set_bound(
    problem: &ContactProblem,
    factorization: &Factorization,
    options: &UzawaOptions,
    lambda: &[f64],
) -> (usize, Option<f64>) {
    let c = problem.constraint.as_ref().expect("a constraint");
    let active: Vec<bool> = lambda.iter().map(|&l| l > 0.0).collect();
    let n_active = active.iter().filter(|a| **a).count();
    if n_active == 0 {
        return (0, None);
    }
    let scale: Vec<f64> = match options.step_form {
        StepForm::Mean => c.weights.iter().map(|w| 1.0 / w.sqrt()).collect(),
        StepForm::Integral => vec![1.0; lambda.len()],
    };
    let mut v: Vec<f64> = (0..lambda.len())
        .map(|i| {
            if active[i] {
                1.0 + 0.5 * ((i * 2654435761usize) % 1000) as f64 / 1000.0
            } else {
                0.0
            }
        })
        .collect();
    let mut estimate = 0.0;
    for _ in 0..60 {
        let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        if !(norm > 0.0 && norm.is_finite()) {
            return (n_active, None);
        }
        let z: Vec<f64> = v.iter().zip(&scale).map(|(a, s)| a / norm * s).collect();
        let mut x = mat_t_vec(&c.matrix, &z);
        factorization.solve_in_place(&mut x);
        let y = mat_vec(&c.matrix, &x);
        let unit: Vec<f64> = v.iter().map(|a| a / norm).collect();
        v = y
            .iter()
            .zip(&scale)
            .zip(&active)
            .map(|((a, s), &on)| if on { a * s } else { 0.0 })
            .collect();
        // Rayleigh quotient (S_AA is symmetric positive semi-definite).
        estimate = v.iter().zip(&unit).map(|(a, b)| a * b).sum::<f64>();
    }
    let bound = 2.0 / estimate;
    (
        n_active,
        (bound.is_finite() && bound > 0.0).then_some(bound),
    )
}

/// Detects the ways a fixed-step projected iteration fails when α is above
/// the stability bound 2/s_max:
///
/// * geometric growth of the step (by 10⁴ over its smallest value), or a
///   bounded cycle in which neither the step nor the KKT measure decreases
///   over 100 iterations ([`DivergenceMonitor::check`], any α);
/// * just above the bound (α = 1.01 × 2/s_max) the unstable mode grows by
///   only |1 − α s_max| ≈ 1.02 per iteration and the projection onto λ ≥ 0
///   clips it, so neither test above need fire. There the iteration is judged
///   against two bounds once the step stops contracting (the largest step of
///   the last [`STALL_WINDOW`] iterations is not below the largest of the
///   window before, [`DivergenceMonitor::stalled`]), or when max_iter is
///   reached unconverged: the run is reported divergent when α exceeds both
///   2/s_max (Lanczos) and 2/s_max(S_AA), S restricted to the current active
///   set (power iteration). Both estimates are lower bounds on the
///   eigenvalues, so exceeding them is proven. α > 2/s_max alone does not
///   make the *projected* iteration diverge: when the active set is small,
///   S_AA has a smaller spectrum and α = 1.01 × 2/s_max can converge
///   (measured on the thesis' shell); once the active set has settled the
///   error on it evolves by I − α S_AA, which grows when α s_max(S_AA) > 2.
///   Below the bounds these tests never report (slow convergence is not
///   divergence).
#[derive(Default)]
struct DivergenceMonitor {
    min_step: f64,
    log_steps: Vec<f64>,
    log_kkt: Vec<f64>,
    steps: Vec<f64>,
}

/// Window (iterations) of the stall test.
const STALL_WINDOW: usize = 25;

/// Window (iterations) over which a cycle is judged.
const CYCLE_WINDOW: usize = 50;

impl DivergenceMonitor {
    /// True every [`STALL_WINDOW`] iterations (from 3 windows on) when the
    /// largest step of the last window is not below the largest step of the
    /// window before it, and the step is well above round-off.
    fn stalled(&mut self, k: usize, step: f64, lambda_max: f64) -> bool {
        self.steps.push(step);
        let n = self.steps.len();
        if !k.is_multiple_of(STALL_WINDOW) || n < 3 * STALL_WINDOW || step <= 1e-10 * lambda_max {
            return false;
        }
        let max = |v: &[f64]| v.iter().fold(0.0f64, |m, x| m.max(*x));
        let last = max(&self.steps[n - STALL_WINDOW..]);
        let before = max(&self.steps[n - 2 * STALL_WINDOW..n - STALL_WINDOW]);
        last >= before
    }

    fn check(&mut self, k: usize, step: f64, kkt: f64, lambda_max: f64) -> Option<String> {
        if k == 1 {
            self.min_step = f64::INFINITY;
        }
        self.min_step = self.min_step.min(step);
        // Well above round-off: a converged iteration stagnating at machine
        // precision must not look like a cycle.
        let significant = step > 1e-10 * lambda_max;
        if k >= 10 && significant && step > 1e4 * self.min_step {
            return Some(format!(
                "the step grew from {:.3e} to {step:.3e}",
                self.min_step
            ));
        }
        self.log_steps.push(step.max(f64::MIN_POSITIVE).ln());
        self.log_kkt.push(kkt.max(f64::MIN_POSITIVE).ln());
        let n = self.log_steps.len();
        if n < 2 * CYCLE_WINDOW || !significant {
            return None;
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let window = |v: &[f64]| {
            (
                mean(&v[n - 2 * CYCLE_WINDOW..n - CYCLE_WINDOW]),
                mean(&v[n - CYCLE_WINDOW..]),
            )
        };
        let ((s0, s1), (k0, k1)) = (window(&self.log_steps), window(&self.log_kkt));
        // Any real convergence, however slow, lowers both means.
        (s1 - s0 > -1e-9 && k1 - k0 > -1e-9).then(|| {
            format!(
                "the iteration cycles without converging: over the last {} iterations neither the step ({:.3e}) nor the KKT measure decreased",
                2 * CYCLE_WINDOW,
                step
            )
        })
    }
}
