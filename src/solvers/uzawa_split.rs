//! The thesis' "first splitting" (Ch. 4, scheme (4.25); docs/formulation.md §3): for the
//! saddle matrix A = [[K, Bᵀ], [B, 0]] (unknowns x = (U, ψ), ψ the equality
//! multiplier, here the shell's tangency multiplier) only the primal block K
//! is factorised (Cholesky: K_ρ is SPD for ρ > 0 on the clamped space), and
//! both multipliers take Richardson steps:
//!
//! ```text
//!     K U^{k}   = F_U − Bᵀψ^{k−1} + Cᵀλ^{k−1}
//!     ψ^{k}     = ψ^{k−1} + β R⁻¹ (B U^{k} − F_ψ)
//!     λ^{k}     = max(0, λ^{k−1} − α ḡ(U^{k}))          (mean form, W Riesz map)
//! ```
//!
//! Corollary 4.3.2 of the thesis: the linear scheme converges when
//!
//! ```text
//!     α s_max(S_C) + β s_max(S_B) < 2,     S_C = W⁻¹ C K⁻¹ Cᵀ,  S_B = R⁻¹ B K⁻¹ Bᵀ   (4.26)
//! ```
//!
//! (the thesis writes it with Euclidean Riesz maps). Both s_max are Lanczos
//! estimates with the one Cholesky factorisation of K
//! ([`estimate_dual_spectrum`]), reported as `s_max_c`, `s_max_b`. (4.26)
//! comes from Weyl's inequality s_max(S_{α,β}) ≤ α s_max(S_C) + β s_max(S_B)
//! for the joint operator S_{α,β} of both multipliers; the exact condition
//! for the linear scheme (and, the projection being non-expansive in the
//! same metric, for the projected one) is s_max(S_{α,β}) < 2. Choices
//! ([`SplitSteps`]):
//!
//! - `Shares` (the thesis' bound): α = a/s_max(S_C), β = b/s_max(S_B) with
//!   a + b < 2, e.g. 0.9 each. Without ψ (the membrane) the scheme is Uzawa
//!   on λ alone and α = (a + b)/s_max(S_C).
//! - `Joint` (the default, θ = 1.8): α = θ/(μ s_max(S_C)), β = θ/(μ s_max(S_B)),
//!   μ = s_max(S_{α₀,β₀}) for α₀ = 1/s_max(S_C), β₀ = 1/s_max(S_B), a third
//!   Lanczos estimate (1 ≤ μ ≤ 2), reported as `joint_mu`. Then
//!   s_max(S_{α,β}) = θ < 2. On the 16×16 thesis shell μ = 1.0002 (C and B
//!   are almost orthogonal in the K⁻¹ inner product), so both steps are twice
//!   the 0.9-shares ones; α s_C + β s_B = 3.6 although (4.26) asks < 2, and the
//!   iteration count to KKT 1e-8 drops from about 57000 to 28800.
//! - `Given` steps.
//!
//! **Riesz map of ψ.** The thesis' M-Riesz map is the Gram matrix of the ψ
//! space, which the algebraic problem does not carry. `PsiRiesz::Jacobi`
//! (the default) uses the diagonal R_jj = Σ_i B_ji²/K_ii, the diagonal of
//! S_B with K replaced by its diagonal: a mass-type diagonal weight in the
//! units of S_B, so that R⁻¹S_B (hence β) does not change under a diagonal
//! scaling of the ψ unknowns (such as σ of `scale_tangency_multiplier`).
//! `PsiRiesz::Euclidean` is R = I, the thesis' literal (4.25). On the
//! σ-scaled 16×16 thesis shell without contact the ψ iteration alone
//! reaches KKT 1e-10 in 2136 (Jacobi) and 2180 (Euclidean) iterations: the
//! ψ part is not what limits the contact problem, λ is (as for Uzawa).
//!
//! Stops on the relative KKT measure only; errors on non-finite values,
//! divergence and stagnation (as [`super::dual_accelerated()`]).

use super::measures::{jacobi_dual_diagonal, kkt_measures_with, Products};
use super::monitor::Monitor;
use super::spectrum::estimate_dual_spectrum;
use super::{Constraint, ContactProblem, ReportBuilder, SolveReport};
use crate::error::{Error, Result};
use crate::linalg::{factor_once, LinearOptions, MatrixKind, Solves, SystemPattern};
use crate::linalg::{mat_t_vec, mat_vec, norm_inf};
use crate::solvers::StepForm;
use faer::sparse::{SparseColMat, Triplet};
use std::time::Instant;

/// The Riesz map of the equality multiplier ψ in its Richardson step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PsiRiesz {
    /// R = diag(B diag(K)⁻¹ Bᵀ) (module docs).
    Jacobi,
    /// R = I (the thesis' scheme (4.25) literally).
    Euclidean,
}

/// How α and β are chosen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SplitSteps {
    /// Weyl's bound (4.26): α = alpha_share/s_max(S_C), β = beta_share/s_max(S_B),
    /// alpha_share + beta_share < 2. Without ψ: α = (alpha_share + beta_share)/s_max(S_C).
    Shares { alpha_share: f64, beta_share: f64 },
    /// The joint bound: with α₀ = 1/s_max(S_C), β₀ = 1/s_max(S_B) and μ the
    /// largest eigenvalue of the joint dual operator for (α₀, β₀) (Lanczos,
    /// 1 ≤ μ ≤ 2 by Weyl), α = θ α₀/μ, β = θ β₀/μ: the joint operator then
    /// has s_max = θ < 2, the exact stability condition that (4.26) bounds.
    Joint { theta: f64 },
    /// Given steps.
    Given { alpha: f64, beta: f64 },
}

#[derive(Debug, Clone)]
pub struct UzawaSplitOptions {
    pub tol: f64,
    pub max_iter: usize,
    pub steps: SplitSteps,
    pub lanczos_steps: usize,
    pub psi_riesz: PsiRiesz,
    /// Iterations without a 1% improvement of the best KKT measure before
    /// the run is declared stagnant.
    pub stall_window: usize,
    pub show_progress: bool,
    pub linear: LinearOptions,
}

impl Default for UzawaSplitOptions {
    fn default() -> Self {
        UzawaSplitOptions {
            tol: 1e-8,
            max_iter: 200_000,
            steps: SplitSteps::Joint { theta: 1.8 },
            lanczos_steps: 50,
            psi_riesz: PsiRiesz::Jacobi,
            stall_window: 20_000,
            show_progress: false,
            linear: LinearOptions::default(),
        }
    }
}

const STAGE: &str = "Uzawa (first splitting)";

/// History columns after the KKT ones: active multipliers and ‖ψ^k − ψ^{k−1}‖∞.
pub const EXTRA_COLUMNS: [&str; 2] = ["active", "psi_step"];

/// The block of `a` with rows in `rows` and columns in `cols`.
fn block(
    a: &SparseColMat<usize, f64>,
    rows: std::ops::Range<usize>,
    cols: std::ops::Range<usize>,
) -> SparseColMat<usize, f64> {
    let mut t = Vec::new();
    for j in cols.clone() {
        for (r, &v) in a.symbolic().row_idx_of_col(j).zip(a.val_of_col(j)) {
            if rows.contains(&r) {
                t.push(Triplet::new(r - rows.start, j - cols.start, v));
            }
        }
    }
    SparseColMat::try_new_from_triplets(rows.len(), cols.len(), &t)
        .expect("indices inside the block")
}

/// Long enough not to take the slow phases of a stable iteration for a
/// cycle: on the 32×32 shell at the joint step (θ = 1.8) the KKT measure
/// falls by only 17% between iterations 2000 and 2500, and windows of 50
/// called that a cycle.
const CYCLE_WINDOW: usize = 250;

/// The rows of `a` followed by the rows of `b` (same number of columns).
fn stack_rows(
    a: &SparseColMat<usize, f64>,
    b: &SparseColMat<usize, f64>,
) -> SparseColMat<usize, f64> {
    let mut t = Vec::with_capacity(a.val().len() + b.val().len());
    for (offset, mat) in [(0, a), (a.nrows(), b)] {
        for j in 0..mat.ncols() {
            for (r, &v) in mat.symbolic().row_idx_of_col(j).zip(mat.val_of_col(j)) {
                t.push(Triplet::new(r + offset, j, v));
            }
        }
    }
    SparseColMat::try_new_from_triplets(a.nrows() + b.nrows(), a.ncols(), &t)
        .expect("indices inside the stacked matrix")
}

/// Solves a contact problem by the first splitting (module docs).
pub fn uzawa_split(problem: &ContactProblem, options: &UzawaSplitOptions) -> Result<SolveReport> {
    let start = Instant::now();
    let (n, np) = (problem.n(), problem.n_primal);
    let n_psi = n - np;
    let a = &problem.matrix;
    let k_block = block(a, 0..np, 0..np);
    let b_block = block(a, np..n, 0..np);
    if block(a, np..n, np..n).val().iter().any(|v| *v != 0.0) {
        return Err(Error::numerical(
            STAGE,
            "system matrix",
            "the multiplier block of the saddle matrix is not zero",
        ));
    }
    let t = Instant::now();
    let interior = problem.interior.as_ref().map(|g| g.restricted_to(np));
    let pattern = SystemPattern {
        matrix: &k_block,
        kind: MatrixKind::SymmetricPositiveDefinite,
        solves: Solves::Many,
        interior: interior.as_ref(),
        what: "primal block K",
    };
    let factorization = factor_once(pattern, &options.linear)?;
    let factor_seconds = t.elapsed().as_secs_f64();

    // Riesz weights of ψ.
    let k_diag: Vec<f64> = (0..np)
        .map(|j| {
            k_block
                .symbolic()
                .row_idx_of_col(j)
                .zip(k_block.val_of_col(j))
                .filter(|(r, _)| *r == j)
                .map(|(_, v)| *v)
                .sum()
        })
        .collect();
    let psi_weights: Vec<f64> = match options.psi_riesz {
        PsiRiesz::Euclidean => vec![1.0; n_psi],
        PsiRiesz::Jacobi => {
            let mut r = vec![0.0; n_psi];
            for j in 0..np {
                for (i, v) in b_block
                    .symbolic()
                    .row_idx_of_col(j)
                    .zip(b_block.val_of_col(j))
                {
                    r[i] += v * v / k_diag[j];
                }
            }
            if let Some(i) = r.iter().position(|v| !(v.is_finite() && *v > 0.0)) {
                return Err(Error::numerical(
                    STAGE,
                    "Riesz weights of ψ",
                    format!("row {i} of B is empty: the multiplier ψ_{i} is not determined"),
                ));
            }
            r
        }
    };

    // The constraint restricted to the U columns, and the two dual operators.
    let constraint = problem.constraint.as_ref();
    let c_u = constraint.map(|c| Constraint {
        matrix: block(&c.matrix, 0..c.matrix.nrows(), 0..np),
        obstacle: c.obstacle.clone(),
        weights: c.weights.clone(),
    });
    let m = c_u.as_ref().map_or(0, |c| c.obstacle.len());
    let spectrum = |constraint: Constraint| {
        let sub = ContactProblem {
            matrix: k_block.clone(),
            kind: MatrixKind::SymmetricPositiveDefinite,
            rhs: vec![0.0; np],
            n_primal: np,
            constraint: Some(constraint),
            interior: None,
        };
        estimate_dual_spectrum(
            &sub,
            factorization.as_ref(),
            StepForm::Mean,
            options.lanczos_steps,
        )
    };
    let t = Instant::now();
    let s_c = c_u.as_ref().filter(|_| m > 0).and_then(|c| {
        spectrum(Constraint {
            matrix: c.matrix.clone(),
            obstacle: c.obstacle.clone(),
            weights: c.weights.clone(),
        })
    });
    let s_b = (n_psi > 0)
        .then(|| {
            spectrum(Constraint {
                matrix: b_block.clone(),
                obstacle: vec![0.0; n_psi],
                weights: psi_weights.clone(),
            })
        })
        .flatten();
    let mut joint_mu = None;
    let (alpha, beta) = match (options.steps, s_c, s_b) {
        (SplitSteps::Given { alpha, beta }, _, _) => (alpha, beta),
        (
            SplitSteps::Shares {
                alpha_share,
                beta_share,
            },
            s_c,
            s_b,
        ) => {
            if alpha_share + beta_share >= 2.0 || alpha_share <= 0.0 || beta_share < 0.0 {
                return Err(Error::numerical(
                    STAGE,
                    "step shares",
                    format!("alpha_share = {alpha_share} and beta_share = {beta_share} violate (4.26): both > 0 with a sum < 2"),
                ));
            }
            match (s_c, s_b) {
                (Some(c), Some(b)) => (alpha_share / c.s_max, beta_share / b.s_max),
                (Some(c), None) => ((alpha_share + beta_share) / c.s_max, 0.0),
                (None, Some(b)) => (0.0, (alpha_share + beta_share) / b.s_max),
                (None, None) => (0.0, 0.0),
            }
        }
        (SplitSteps::Joint { theta }, s_c, s_b) => {
            if !(theta > 0.0 && theta < 2.0) {
                return Err(Error::numerical(
                    STAGE,
                    "theta",
                    format!("{theta} must be in (0, 2)"),
                ));
            }
            match (s_c, s_b, &c_u) {
                (Some(sc), Some(sb), Some(c)) => {
                    let (a0, b0) = (1.0 / sc.s_max, 1.0 / sb.s_max);
                    let stacked = stack_rows(&c.matrix, &b_block);
                    let weights: Vec<f64> = c
                        .weights
                        .iter()
                        .map(|w| w / a0)
                        .chain(psi_weights.iter().map(|r| r / b0))
                        .collect();
                    let mu = spectrum(Constraint {
                        matrix: stacked,
                        obstacle: vec![0.0; weights.len()],
                        weights,
                    })
                    .map_or(2.0, |s| s.s_max);
                    joint_mu = Some(mu);
                    (theta * a0 / mu, theta * b0 / mu)
                }
                (Some(sc), None, _) => (theta / sc.s_max, 0.0),
                (None, Some(sb), _) => (0.0, theta / sb.s_max),
                _ => (0.0, 0.0),
            }
        }
    };
    let spectrum_seconds = t.elapsed().as_secs_f64();
    for (name, v) in [("alpha", alpha), ("beta", beta)] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(Error::numerical(
                STAGE,
                name,
                format!("{v} must be finite and ≥ 0"),
            ));
        }
    }

    let f_u = &problem.rhs[..np];
    let f_psi = &problem.rhs[np..];
    let mut psi = vec![0.0; n_psi];
    let mut lambda = vec![0.0; m];
    let mut x = vec![0.0; n];
    let mut report = ReportBuilder::new("uzawa-split", start, 0.0, factor_seconds)
        .with_history(&EXTRA_COLUMNS)
        .iterating(
            "Uzawa split",
            options.max_iter,
            options.tol,
            options.show_progress,
        );
    // Watched steps: 0 is λ's, 1 is ψ's.
    let mut monitor = Monitor::new(STAGE, "multiplier steps")
        .with_cycle_window(CYCLE_WINDOW)
        .with_stagnation_window(options.stall_window);
    let compliance = jacobi_dual_diagonal(problem);
    for k in 1..=options.max_iter {
        // K U = F_U − Bᵀψ + Cᵀλ
        // Bᵀψ from B: A may be stored as its lower triangle.
        let mut u = mat_t_vec(&b_block, &psi);
        u.iter_mut().zip(f_u).for_each(|(ui, fi)| *ui = fi - *ui);
        if let Some(c) = &c_u {
            let ct = mat_t_vec(&c.matrix, &lambda);
            u.iter_mut().zip(&ct).for_each(|(ui, ci)| *ui += ci);
        }
        factorization.solve_in_place(&mut u);
        monitor.finite(k, "primal iterate U", &u)?;
        // ψ ← ψ + β R⁻¹ (B U − F_ψ)
        let bu = mat_vec(&b_block, &u);
        let mut psi_step = 0.0f64;
        for i in 0..n_psi {
            let d = beta * (bu[i] - f_psi[i]) / psi_weights[i];
            psi[i] += d;
            psi_step = psi_step.max(d.abs());
        }
        monitor.finite(k, "multiplier ψ", &psi)?;
        // λ ← max(0, λ − α ḡ(U))
        let mut dual_step = 0.0f64;
        if let Some(c) = &c_u {
            let cu = mat_vec(&c.matrix, &u);
            for i in 0..m {
                let new = (lambda[i] - alpha * c.mean_gap(&cu, i)).max(0.0);
                dual_step = dual_step.max((new - lambda[i]).abs());
                lambda[i] = new;
            }
            monitor.finite(k, "multiplier λ", &lambda)?;
        }
        x[..np].copy_from_slice(&u);
        x[np..].copy_from_slice(&psi);
        let products = Products {
            compliance: Some(&compliance),
            ..Products::default()
        };
        let measures = kkt_measures_with(problem, &x, &lambda, products, options.linear.threads);
        report.record(k, dual_step, measures, &[measures.active as f64, psi_step]);
        if measures.kkt <= options.tol {
            report.stop("kkt");
            break;
        }
        let growth = monitor
            .growth(0, k, dual_step, norm_inf(&lambda))
            .map(|r| format!("λ: {r}"))
            .or_else(|| {
                monitor
                    .growth(1, k, psi_step, norm_inf(&psi))
                    .map(|r| format!("ψ: {r}"))
            })
            .or_else(|| Monitor::kkt_not_finite(measures.kkt))
            .or_else(|| {
                let (step, scale) = if m > 0 {
                    (dual_step, norm_inf(&lambda))
                } else {
                    (psi_step, norm_inf(&psi))
                };
                monitor.cycles(step, scale, measures.kkt)
            });
        if let Some(reason) = growth {
            return Err(monitor.diverged(
                k,
                &reason,
                measures.kkt,
                &format!(
                    "α = {alpha:.4e}, β = {beta:.4e} are too large: {}",
                    match joint_mu {
                        // The joint rule exceeds Weyl's bound by design.
                        Some(mu) => format!(
                            "the joint step was set for s_max(S_αβ) = θ < 2 from a Lanczos estimate μ = {mu:.6} (a lower bound of the true value); choose a smaller θ"
                        ),
                        None => format!(
                            "α s_max(S_C) + β s_max(S_B) = {:.4} (must be < 2 by (4.26))",
                            alpha * s_c.map_or(0.0, |s| s.s_max) + beta * s_b.map_or(0.0, |s| s.s_max)
                        ),
                    }
                ),
            ));
        }
        monitor.stagnation(k, measures.kkt, options.tol)?;
    }
    let mut parameters = vec![
        ("tol".into(), options.tol),
        ("alpha".into(), alpha),
        ("beta".into(), beta),
        ("spectrum_seconds".into(), spectrum_seconds),
    ];
    if let Some(s) = s_c {
        parameters.push(("s_max_c".into(), s.s_max));
        parameters.push(("s_min_c_ritz".into(), s.s_min));
    }
    if let Some(s) = s_b {
        parameters.push(("s_max_b".into(), s.s_max));
        parameters.push(("s_min_b_ritz".into(), s.s_min));
    }
    if let (Some(c), Some(b)) = (s_c, s_b) {
        parameters.push(("bound_4_26".into(), alpha * c.s_max + beta * b.s_max));
    }
    if let Some(mu) = joint_mu {
        parameters.push(("joint_mu".into(), mu));
    }
    Ok(report.finish(x, lambda, parameters))
}
