//! The signed-regularised LDLᵀ of the shell's saddle-point matrix
//! [[K_ρ, Bᵀ], [B, 0]] against faer's LU on the same matrix: the same
//! solution to round-off over the penalty range, and the fallback to LU
//! taken when the refined solve misses its accuracy.

use obstacle_fem::assembly::norm_inf;
use obstacle_fem::gmsh::run_gmsh;
use obstacle_fem::linalg::{residual, Factorization, MatrixKind, ReusableFactorization};
use obstacle_fem::mesh::Mesh;
use obstacle_fem::models::naghdi::forms::{
    assemble_shell, balanced_tangency_scale, scale_tangency_multiplier,
};
use obstacle_fem::models::naghdi::geometry::{Chart, Material};
use obstacle_fem::solvers::ContactProblem;
use std::path::Path;

fn thesis_shell(n: usize, rho: f64, scaled: bool) -> ContactProblem {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("diamond.msh");
    run_gmsh(
        Path::new("meshes/diamond.geo"),
        &out,
        &[("n".into(), n as f64)],
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let mesh = Mesh::read_msh(&out).unwrap();
    let chart = Chart::HyperbolicParaboloid {
        r: 50.0 * std::f64::consts::SQRT_2,
        offset: 1.4,
    };
    let material = Material {
        young: 2.85e4,
        poisson: 0.4,
        thickness: 0.8,
    };
    let (mut problem, _) = assemble_shell(&mesh, &chart, &material, rho, [0.0, 0.0, -0.25], None);
    if scaled {
        let sigma = balanced_tangency_scale(&problem);
        scale_tangency_multiplier(&mut problem, sigma);
    }
    problem
}

/// Solves with the chain and with LU; returns (method, max|x − x_LU|/max|x_LU|,
/// relative residuals of the chain's and of LU's solve, symbolic analyses).
fn against_lu(problem: &ContactProblem) -> (&'static str, f64, f64, f64, usize) {
    let kind = problem.kind;
    assert!(matches!(kind, MatrixKind::SymmetricSaddle { .. }));
    let mut chain = ReusableFactorization::analyze(&problem.matrix, kind, "shell").unwrap();
    let (f, _) = chain.factorize(&problem.matrix, "shell").unwrap();
    let mut x = problem.rhs.clone();
    f.solve_in_place(&mut x);
    let lu = Factorization::new(&problem.matrix, MatrixKind::General, "shell").unwrap();
    let mut x_lu = problem.rhs.clone();
    lu.solve_in_place(&mut x_lu);
    let diff: Vec<f64> = x.iter().zip(&x_lu).map(|(a, b)| a - b).collect();
    let rel =
        |x: &[f64]| norm_inf(&residual(&problem.matrix, x, &problem.rhs)) / norm_inf(&problem.rhs);
    (
        chain.method(),
        norm_inf(&diff) / norm_inf(&x_lu),
        rel(&x),
        rel(&x_lu),
        chain.symbolic_analyses(),
    )
}

#[test]
fn ldlt_matches_lu_on_the_shell() {
    // The pipeline's matrices (ψ rows balanced) over the penalty range, and
    // one without the ψ scaling (the equilibration inside the LDLᵀ copes).
    for (rho, scaled) in [
        (0.0, true),
        (1.0, true),
        (1e3, true),
        (1e9, true),
        (1e12, true),
        (1e3, false),
    ] {
        let (method, diff, res, res_lu, analyses) = against_lu(&thesis_shell(16, rho, scaled));
        println!(
            "ρ = {rho:e}, scaled {scaled}: {method}, |x − x_LU| {diff:.2e}, residual {res:.2e} (LU {res_lu:.2e})"
        );
        // At ρ = 1e12 (κ₂ ≈ 4e10) the refined LDLᵀ leaves a test residual
        // above its 1e-8 bound and the chain takes LU.
        let expected = if rho > 1e10 { ("LU", 2) } else { ("LDLᵀ", 1) };
        assert_eq!((method, analyses), expected, "ρ = {rho}");
        // Forward differences within what the conditioning allows (the
        // unscaled matrix is the worst conditioned).
        assert!(
            diff < if scaled { 1e-11 } else { 1e-7 },
            "ρ = {rho}: {diff:e}"
        );
        assert!(
            res <= 10.0 * res_lu + 1e-11,
            "ρ = {rho}: {res:e} vs LU {res_lu:e}"
        );
    }
}

#[test]
fn ldlt_falls_back_to_lu_when_the_signs_are_wrong() {
    // Declared with every unknown primal, the ψ pivots are forced positive:
    // the factors are of a different matrix, refinement cannot recover, and
    // the chain moves to LU, which then solves it as LU does.
    let mut problem = thesis_shell(16, 1e3, true);
    problem.kind = MatrixKind::SymmetricSaddle {
        n_primal: problem.n(),
    };
    let (method, diff, res, _, analyses) = against_lu(&problem);
    assert_eq!(method, "LU");
    assert_eq!(analyses, 2);
    assert_eq!(diff, 0.0);
    assert!(res < 1e-10, "{res:e}");
}
