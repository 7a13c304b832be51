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

use super::measures::{
    dual_step_norm, jacobi_dual_diagonal, kkt_measures, kkt_measures_with, Products,
};
use super::monitor::{check_finite, Monitor};
use super::spectrum::{estimate_dual_spectrum, SpectrumEstimate};
use super::{
    factorize_system, initial_multiplier, named, ContactProblem, ReportBuilder, SolveReport,
};
use crate::error::{Error, Result};
use crate::linalg::{mat_t_vec, mat_vec, norm_inf};
use crate::linalg::{Factors, LinearOptions, Solves};
use crate::solvers::{DualNorm, Probe, StepForm, StopRule};
use std::time::Instant;

/// How Uzawa's fixed step α is chosen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum UzawaStep {
    /// A given α.
    Given(f64),
    /// 2/(s_max + s_min), the optimal fixed Richardson step, capped at 95%
    /// of the stability bound 2/s_max; 1 without an estimate.
    Auto,
    /// factor × 2/s_max: a multiple of the stability bound (the hard cases).
    StabilityFactor(f64),
}

impl UzawaStep {
    /// α from the Lanczos estimate of the spectrum of S; None for a
    /// multiple of 2/s_max without an estimate (no constraint rows).
    pub fn alpha(self, spectrum: Option<SpectrumEstimate>) -> Option<f64> {
        match (self, spectrum) {
            (UzawaStep::Given(a), _) => Some(a),
            (UzawaStep::Auto, Some(s)) => Some((2.0 / (s.s_max + s.s_min)).min(1.9 / s.s_max)),
            (UzawaStep::Auto, None) => Some(1.0),
            (UzawaStep::StabilityFactor(factor), Some(s)) => Some(factor * 2.0 / s.s_max),
            (UzawaStep::StabilityFactor(_), None) => None,
        }
    }
}

/// Lanczos steps of the estimate α is chosen from and judged against.
pub const LANCZOS_STEPS: usize = 50;

const STAGE: &str = "Uzawa";

#[derive(Debug, Clone)]
pub struct UzawaOptions {
    pub step: UzawaStep,
    pub step_form: StepForm,
    pub max_iter: usize,
    /// Bound on the relative KKT measure.
    pub tol: f64,
    pub stop: StopRule,
    pub thesis_tol: f64,
    pub dual_norm: DualNorm,
    pub show_progress: bool,
    /// λ⁰ (e.g. an adaptive step's multiplier carried to the new mesh); zero if absent.
    pub initial_lambda: Option<Vec<f64>>,
    pub linear: LinearOptions,
}

/// α by `step`, and the Lanczos estimate of the spectrum of S it comes from
/// (made for every rule, with the one factorisation of A: the report
/// records it and divergence is judged against it).
pub fn uzawa_alpha(
    problem: &ContactProblem,
    factorization: &dyn Factors,
    step: UzawaStep,
    step_form: StepForm,
) -> Result<(f64, Option<SpectrumEstimate>)> {
    let spectrum = estimate_dual_spectrum(problem, factorization, step_form, LANCZOS_STEPS);
    let alpha = step.alpha(spectrum).ok_or_else(|| {
        Error::numerical(
            STAGE,
            "α = factor × 2/s_max",
            "no estimate of s_max (no constraint rows): give α instead",
        )
    })?;
    Ok((alpha, spectrum))
}

/// [`uzawa_alpha`] for a problem not factorised yet (the FreeFEM twin's α).
pub fn uzawa_alpha_of(
    problem: &ContactProblem,
    step: UzawaStep,
    step_form: StepForm,
    linear: &LinearOptions,
) -> Result<f64> {
    let (factors, _) = factorize_system(problem, Solves::Many, linear)?;
    Ok(uzawa_alpha(problem, factors.as_ref(), step, step_form)?.0)
}

/// One linear solve: the problem without contact (its measures' product
/// with A on `threads`).
pub fn solve_linear(
    problem: &ContactProblem,
    factorization: &dyn Factors,
    factor_seconds: f64,
    threads: usize,
) -> Result<SolveReport> {
    let mut report = ReportBuilder::linear(factor_seconds);
    let mut x = problem.rhs.clone();
    factorization.solve_in_place(&mut x);
    check_finite("linear solve", 1, "solution", &x)?;
    report.measures = kkt_measures(problem, &x, &[], None, threads);
    Ok(report.finish(x, vec![], vec![]))
}

/// The problem without contact factorised and solved once.
pub fn solve_unconstrained(
    problem: &ContactProblem,
    linear: &LinearOptions,
) -> Result<SolveReport> {
    let (factors, seconds) = factorize_system(problem, Solves::Few, linear)?;
    solve_linear(problem, factors.as_ref(), seconds, linear.threads)
}

/// Uzawa with the one factorisation of A (`factor_seconds` spent on it):
/// chooses α ([`uzawa_alpha`]), then iterates (module docs).
pub fn uzawa(
    problem: &ContactProblem,
    factorization: &dyn Factors,
    factor_seconds: f64,
    options: &UzawaOptions,
    probes: &[Probe],
) -> Result<SolveReport> {
    let (alpha, spectrum) = uzawa_alpha(problem, factorization, options.step, options.step_form)?;
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
    let mut report = ReportBuilder::new("uzawa", Instant::now(), factor_seconds, factor_seconds)
        .with_history(&probe_names)
        .iterating(STAGE, options.max_iter, options.tol, options.show_progress);
    report.alpha = Some(alpha);
    report.spectrum = spectrum;
    let mut lambda = initial_multiplier(STAGE, options.initial_lambda.as_deref(), m)?;
    let mut x = vec![0.0; problem.n()];
    let mut monitor =
        Monitor::new(STAGE, "dual step ‖λ^k − λ^{k−1}‖").with_cycle_window(CYCLE_WINDOW);
    // The stability bound 2/s_max of the fixed-step iteration. The Ritz
    // value s_max^(k) is a lower bound on s_max, so α > 2/s_max^(k) proves
    // α > 2/s_max.
    let bound = spectrum
        .map(|s| 2.0 / s.s_max)
        .filter(|b| b.is_finite() && *b > 0.0);
    // Cᵀ λ^{k−1}: the right-hand side of iteration k and, computed at the
    // end of iteration k−1, its stationarity measure; one product serves both.
    let mut ct_lambda = mat_t_vec(&c.matrix, &lambda);
    let compliance = jacobi_dual_diagonal(problem);
    for k in 1..=options.max_iter {
        // x^k = A⁻¹ (F + Cᵀ λ^{k−1})
        x.iter_mut()
            .zip(&ct_lambda)
            .zip(&problem.rhs)
            .for_each(|((xi, ci), fi)| *xi = ci + fi);
        // A x^k as the solve's refinement computed it (the KKT measures' one).
        let ax = factorization.solve_with_product(&mut x);
        monitor.finite(k, "primal iterate", &x)?;
        // λ^k = max(0, λ^{k−1} − α D ḡ(x^k))
        let cx = mat_vec(&c.matrix, &x);
        let new_lambda: Vec<f64> = (0..m)
            .map(|i| {
                let mean_gap = c.mean_gap(&cx, i);
                (lambda[i] - alpha * step_weights[i] * mean_gap).max(0.0)
            })
            .collect();
        monitor.finite(k, "multiplier λ", &new_lambda)?;
        let step = dual_step_norm(&new_lambda, &lambda, &c.weights, options.dual_norm);
        lambda = new_lambda;
        ct_lambda = mat_t_vec(&c.matrix, &lambda);
        let products = Products {
            ax: ax.as_deref(),
            cx: Some(&cx),
            ct_lambda: Some(&ct_lambda),
            compliance: Some(&compliance),
        };
        let measures = kkt_measures_with(problem, &x, &lambda, products, options.linear.threads);
        let probe_values: Vec<f64> = probes.iter().map(|p| (p.evaluate)(&x, &lambda)).collect();
        report.record(k, step, measures, &probe_values);

        let lambda_max = norm_inf(&lambda);
        let mut verdict = monitor
            .growth(0, k, step, lambda_max)
            .or_else(|| monitor.cycles(step, lambda_max, measures.kkt));
        let stalled = monitor.stalled(STALL_WINDOW, k, step, lambda_max);
        let unconverged_end = k == options.max_iter && measures.kkt > options.tol;
        if verdict.is_none() && (stalled || unconverged_end) {
            // Judged against the bounds (see `STALL_WINDOW`): α above
            // 2/s_max of S and of S restricted to the current active set.
            if let Some(b) = bound.filter(|b| alpha > *b) {
                let (active, b_active) =
                    active_set_bound(problem, factorization, options.step_form, &lambda);
                if let Some(ba) = b_active.filter(|ba| alpha > *ba) {
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
                        alpha / b,
                        alpha / ba,
                    ));
                }
            }
        }
        if let Some(reason) = verdict {
            let bound = bound
                .map(|b| format!("; the stability bound 2/s_max ≈ {b:.4e} (Lanczos)"))
                .unwrap_or_default();
            return Err(monitor.diverged(
                k,
                &reason,
                measures.kkt,
                &format!("α = {alpha} is too large{bound}"),
            ));
        }
        let done = match options.stop {
            StopRule::Kkt => measures.kkt <= options.tol,
            StopRule::Thesis => step < options.thesis_tol,
        };
        if done {
            report.stop(match options.stop {
                StopRule::Kkt => "kkt",
                StopRule::Thesis => "thesis",
            });
            break;
        }
    }
    Ok(report.finish(x, lambda, named(&[("alpha", alpha)])))
}

/// The bound 2/s_max(S_AA) of S restricted to the active multipliers
/// A = {i: λ_i > 0} (S_AA governs the iteration once the active set has
/// settled: the clipped components stay 0), from 60 power-iteration steps on
/// P_A D^{-1/2} C A⁻¹ Cᵀ D^{-1/2} P_A. The power estimate is a lower bound on
/// s_max(S_AA), so α above the returned bound proves α > 2/s_max(S_AA).
/// Returns |A| and the bound (None when A is empty).
fn active_set_bound(
    problem: &ContactProblem,
    factorization: &dyn Factors,
    step_form: StepForm,
    lambda: &[f64],
) -> (usize, Option<f64>) {
    let c = problem.constraint.as_ref().expect("a constraint");
    let active: Vec<bool> = lambda.iter().map(|&l| l > 0.0).collect();
    let n_active = active.iter().filter(|a| **a).count();
    if n_active == 0 {
        return (0, None);
    }
    let scale: Vec<f64> = match step_form {
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

/// How Uzawa's run is judged divergent (the tests of [`Monitor`]) when α is
/// above the stability bound 2/s_max:
///
/// * geometric growth of the step (by 10⁴ over its smallest value), or a
///   bounded cycle in which neither the step nor the KKT measure decreases
///   over 100 iterations ([`Monitor::growth`], [`Monitor::cycles`], any α);
/// * just above the bound (α = 1.01 × 2/s_max) the unstable mode grows by
///   only |1 − α s_max| ≈ 1.02 per iteration and the projection onto λ ≥ 0
///   clips it, so neither test above need fire. There the iteration is judged
///   against two bounds once the step stops contracting (the largest step of
///   the last [`STALL_WINDOW`] iterations is not below the largest of the
///   window before, [`Monitor::stalled`]), or when max_iter is
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
///
/// `STALL_WINDOW` is the window (iterations) of the stall test.
const STALL_WINDOW: usize = 25;

/// Window (iterations) over which a cycle is judged.
const CYCLE_WINDOW: usize = 50;
