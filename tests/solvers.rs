//! The solvers beyond the thesis' Uzawa (docs/formulation.md §3): primal–dual active set
//! (semismooth Newton), FISTA with restart on the dual, and the thesis'
//! first splitting, on the disk membrane (both element pairs) and on the
//! 16×16 thesis hypar with the rigid plane. Each reaches its KKT tolerance,
//! all agree, the active set reuses one symbolic LU analysis, Lanczos' s_max
//! matches a dense eigen-solve, and failures (max_iter, cycling, divergence)
//! give clear reports or errors.
//!
//! Measured figures are printed with eprintln (run with `--nocapture`).

mod common;

use common::{active_set, parameter, solve};
use faer::sparse::{SparseColMat, Triplet};
use obstacle_fem::assembly::{norm_inf, DofNumbering};
use obstacle_fem::gmsh::run_gmsh;
use obstacle_fem::linalg::{
    factorize_checked, factorize_checked_with, into_lower_triangle, refine, residual, Changed,
    MatrixKind, ReusableFactorization, Solves,
};
use obstacle_fem::mesh::Mesh;
use obstacle_fem::models::membrane::MembraneSystem;
use obstacle_fem::models::naghdi::forms::{
    assemble_shell, balanced_tangency_scale, rigid_plane_constraint, scale_tangency_multiplier,
};
use obstacle_fem::models::naghdi::geometry::{Chart, Material};
use obstacle_fem::models::ModelSystem;
use obstacle_fem::pipeline::scene_mesh;
use obstacle_fem::scene::{Scene, StepForm};
use obstacle_fem::solvers::active_set::{ActiveSetOptions, ColdStart};
use obstacle_fem::solvers::dual_accelerated::{dual_accelerated, DualAcceleratedOptions, Restart};
use obstacle_fem::solvers::spectrum::estimate_dual_spectrum;
use obstacle_fem::solvers::uzawa::{UzawaOptions, UzawaStep};
use obstacle_fem::solvers::uzawa_split::{uzawa_split, PsiRiesz, SplitSteps, UzawaSplitOptions};
use obstacle_fem::solvers::{
    Constraint, ContactProblem, DualNorm, SolveReport, SolverOptions, StopRule,
};
use obstacle_fem::Error;
use std::path::Path;

const SCENE: &str = "pipelines/scenes/obstacle-disk.toml";
const R: f64 = 50.0 * std::f64::consts::SQRT_2;

/// The disk membrane (docs/formulation.md §1) with `mesh.n = n` points per quarter circle.
fn membrane(element: &str, n: usize) -> ContactProblem {
    let overrides = vec![format!("element={element}"), format!("mesh.n={n}")];
    let scene = Scene::load(Path::new(SCENE), &overrides).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mesh = scene_mesh(&scene, &dir.path().join("disk.msh")).unwrap();
    let system = MembraneSystem::setup(&mesh, &scene).unwrap();
    system.assemble().unwrap()
}

/// The thesis hypar (docs/formulation.md §2) on the n×n diamond, ρ = 1e3, with the rigid
/// plane, the tangency multiplier rescaled for LU.
fn shell(n: usize) -> ContactProblem {
    shell_with_mesh(n).1
}

fn shell_with_mesh(n: usize) -> (Mesh, ContactProblem) {
    let (mesh, mut problem, numbering) = hypar(n, 1e3);
    let chart = Chart::HyperbolicParaboloid { r: R, offset: 1.4 };
    problem.constraint = Some(rigid_plane_constraint(&mesh, &chart, &MATERIAL, &numbering));
    let sigma = balanced_tangency_scale(&problem);
    scale_tangency_multiplier(&mut problem, sigma);
    (mesh, problem)
}

const MATERIAL: Material = Material {
    young: 2.85e4,
    poisson: 0.4,
    thickness: 0.8,
};

/// The thesis hypar on the n×n diamond without contact, ψ unscaled.
fn hypar(n: usize, rho: f64) -> (Mesh, ContactProblem, DofNumbering) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("diamond.msh");
    run_gmsh(
        Path::new("meshes/diamond.geo"),
        &out,
        &[("n".into(), n as f64)],
    )
    .unwrap();
    let mesh = Mesh::read_msh(&out).unwrap();
    let chart = Chart::HyperbolicParaboloid { r: R, offset: 1.4 };
    let (problem, numbering) =
        assemble_shell(&mesh, &chart, &MATERIAL, rho, [0.0, 0.0, -0.25], None);
    (mesh, problem, numbering)
}

fn print(case: &str, r: &SolveReport) {
    let params: Vec<String> = r
        .parameters
        .iter()
        .map(|(n, v)| format!("{n} {v:.4e}"))
        .collect();
    eprintln!(
        "{case}: {:<16} iterations {:>6}  kkt {:.2e}  active {:>4}  factor {:.3} s  wall {:.3} s  [{}]",
        r.algorithm,
        r.iterations,
        r.measures.kkt,
        r.measures.active,
        r.factor_seconds,
        r.wall_seconds,
        params.join(", ")
    );
}

/// max_i |a_i − b_i| / max(‖a‖∞, ‖b‖∞).
fn rel_diff(a: &[f64], b: &[f64]) -> f64 {
    let d = a
        .iter()
        .zip(b)
        .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
    d / norm_inf(a).max(norm_inf(b)).max(f64::MIN_POSITIVE)
}

/// Runs the three solvers on `problem`, checks their KKT measures, the
/// agreement of x (primal part: U; ψ is compared through the tangency and
/// stationarity measures) and λ with the active-set solution, and returns
/// the active-set report.
fn all_solvers(
    case: &str,
    problem: &ContactProblem,
    max_newton: usize,
    agree_x: f64,
    agree_lambda: f64,
) -> SolveReport {
    let exact = active_set(problem, &ActiveSetOptions::default()).unwrap();
    print(case, &exact);
    assert!(exact.converged && exact.stop_reason == "kkt");
    assert!(exact.measures.kkt <= 1e-10, "{}", exact.measures.kkt);
    assert!(
        exact.iterations <= max_newton,
        "{case}: {} Newton steps",
        exact.iterations
    );
    // One symbolic analysis, one numeric factorisation per Newton step.
    assert_eq!(parameter(&exact, "symbolic_analyses"), 1.0);
    assert_eq!(
        parameter(&exact, "numeric_factorizations"),
        exact.iterations as f64
    );
    // The history records the active set and its changes at every step.
    let changes = exact.history.column("changes").unwrap();
    assert_eq!(changes.len(), exact.iterations);
    assert_eq!(
        exact.history.column("active").unwrap().last().copied(),
        Some(exact.measures.active as f64)
    );
    assert!(exact.measures.dual_min >= 0.0);

    // Tolerance 1e-10 (the brief asks 1e-8): at 1e-8 λ differs from the
    // Newton solution by up to 5e-6 (relative), the dual error being the gap
    // residual amplified by the conditioning of the dual operator.
    let fista = dual_accelerated(
        problem,
        &DualAcceleratedOptions {
            tol: 1e-10,
            ..Default::default()
        },
    )
    .unwrap();
    print(case, &fista);
    let split = uzawa_split(
        problem,
        &UzawaSplitOptions {
            tol: 1e-10,
            ..Default::default()
        },
    )
    .unwrap();
    print(case, &split);
    let np = problem.n_primal;
    for r in [&fista, &split] {
        assert!(r.converged && r.stop_reason == "kkt", "{}", r.algorithm);
        assert!(
            r.measures.kkt <= 1e-10,
            "{}: {}",
            r.algorithm,
            r.measures.kkt
        );
        assert_eq!(r.measures.active, exact.measures.active, "{}", r.algorithm);
        let (dx, dl) = (
            rel_diff(&r.x[..np], &exact.x[..np]),
            rel_diff(&r.lambda, &exact.lambda),
        );
        eprintln!(
            "{case}: {:<16} vs active-set: x {dx:.2e}, λ {dl:.2e}",
            r.algorithm
        );
        assert!(
            dx <= agree_x,
            "{case} {}: x differs by {dx:.3e}",
            r.algorithm
        );
        assert!(
            dl <= agree_lambda,
            "{case} {}: λ differs by {dl:.3e}",
            r.algorithm
        );
    }
    exact
}

/// P1⊕B3–P0 on the disk, n = 16 (784 triangles).
#[test]
fn disk_p1b_p0_solvers_agree() {
    let problem = membrane("p1b-p0", 16);
    eprintln!(
        "disk p1b-p0 n=16: {} unknowns, {} multipliers",
        problem.n(),
        problem.n_multipliers()
    );
    let exact = all_solvers("disk p1b-p0", &problem, 10, 1e-6, 1e-6);
    // Cold start: 𝒜₁ = {g > 0}, already close to the contact disk.
    assert!(exact.iterations <= 5, "{}", exact.iterations);
}

/// P2–P1 on the disk, n = 16.
#[test]
fn disk_p2_p1_solvers_agree() {
    let problem = membrane("p2-p1", 16);
    eprintln!(
        "disk p2-p1 n=16: {} unknowns, {} multipliers",
        problem.n(),
        problem.n_multipliers()
    );
    let exact = all_solvers("disk p2-p1", &problem, 10, 1e-6, 1e-6);
    assert!(exact.iterations <= 5, "{}", exact.iterations);
}

/// The 16×16 thesis hypar with the rigid plane.
#[test]
fn shell_hypar_16_solvers_agree() {
    let problem = shell(16);
    eprintln!(
        "shell 16×16: {} unknowns ({} primal), {} multipliers",
        problem.n(),
        problem.n_primal,
        problem.n_multipliers()
    );
    let exact = all_solvers("shell 16x16", &problem, 30, 1e-6, 1e-6);
    let changes = exact.history.column("changes").unwrap();
    eprintln!("shell 16x16: active-set changes per step {changes:?}");
    // Warm start from the solution: one Newton step.
    let warm = active_set(
        &problem,
        &ActiveSetOptions {
            initial_lambda: Some(exact.lambda.clone()),
            ..Default::default()
        },
    )
    .unwrap();
    print("shell 16x16 warm", &warm);
    assert_eq!(warm.iterations, 1);
    assert!(rel_diff(&warm.x, &exact.x) < 1e-10);
}

/// The interior-point start against the depth bisection on the disk
/// (p1b-p0 and p2-p1, n = 16) and the thesis shell (n = 16): the same
/// solution (x to 1e-10, the same contact set), KKT ≤ 1e-10, interior-point
/// steps taken and recorded, PDAS finishing from their predicted set in at
/// most 3 steps (measured: 1–2), and (λ, s) kept interior: every history row
/// finite, λ ≥ 0 at every interior-point iterate (dual_min of the row).
#[test]
fn interior_point_start_reaches_the_same_solution() {
    for (case, problem) in [
        ("disk p1b-p0", membrane("p1b-p0", 16)),
        ("disk p2-p1", membrane("p2-p1", 16)),
        ("shell 16x16", shell(16)),
    ] {
        let with = |cold_start| {
            active_set(
                &problem,
                &ActiveSetOptions {
                    cold_start,
                    ..Default::default()
                },
            )
            .unwrap()
        };
        let bisection = with(ColdStart::DEPTH_BISECTION);
        let interior = with(ColdStart::INTERIOR_POINT);
        print(&format!("{case} depth bisection"), &bisection);
        print(&format!("{case} interior point"), &interior);
        assert!(
            interior.converged && interior.measures.kkt <= 1e-10,
            "{case}"
        );
        assert!(rel_diff(&interior.x, &bisection.x) < 1e-10, "{case}");
        assert_eq!(interior.contact(), bisection.contact(), "{case}");
        let ip_steps = parameter(&interior, "interior_point_steps") as usize;
        assert!(ip_steps >= 1, "{case}: {ip_steps}");
        let finish = interior.iterations - 1 - ip_steps;
        assert!(finish <= 3, "{case}: PDAS finish of {finish} steps");
        let dual_min = interior.history.column("dual_min").unwrap();
        assert!(
            dual_min[1..=ip_steps].iter().all(|&d| d >= 0.0),
            "{case}: {dual_min:?}"
        );
        for name in ["kkt", "active", "linear_residual"] {
            let column = interior.history.column(name).unwrap();
            assert!(column.iter().all(|v| v.is_finite()), "{case}: {name}");
        }
    }
}

/// Lanczos' s_max against the largest eigenvalue of the dense dual operator
/// S = D⁻¹ C A⁻¹ Cᵀ (mean form D = W, integral form D = I) on a small disk.
#[test]
fn lanczos_s_max_matches_dense_eigenvalue() {
    let problem = membrane("p1b-p0", 6);
    let c = problem.constraint.as_ref().unwrap();
    let (n, m) = (problem.n(), problem.n_multipliers());
    let dense = |a: &SparseColMat<usize, f64>| {
        let mut d = nalgebra::DMatrix::<f64>::zeros(a.nrows(), a.ncols());
        for j in 0..a.ncols() {
            for (i, v) in a.symbolic().row_idx_of_col(j).zip(a.val_of_col(j)) {
                d[(i, j)] += v;
            }
        }
        d
    };
    let a = dense(&problem.matrix);
    let cm = dense(&c.matrix);
    let a_inv_ct = a.clone().cholesky().unwrap().solve(&cm.transpose());
    let s = &cm * a_inv_ct;
    let f = factorize_checked(&problem.matrix, problem.kind, Solves::Few, "A").unwrap();
    for (form, d) in [
        (StepForm::Mean, c.weights.clone()),
        (StepForm::Integral, vec![1.0; m]),
    ] {
        // D^{-1/2} S D^{-1/2}: symmetric, same eigenvalues as D⁻¹S.
        let sym = nalgebra::DMatrix::from_fn(m, m, |i, j| s[(i, j)] / (d[i] * d[j]).sqrt());
        let eig = nalgebra::SymmetricEigen::new(sym).eigenvalues;
        let dense_max = eig.max();
        let dense_min = eig.min();
        let lanczos = estimate_dual_spectrum(&problem, &f, form, 30).unwrap();
        let rel = (lanczos.s_max - dense_max).abs() / dense_max;
        eprintln!(
            "dense check ({form:?}, n {n}, m {m}): s_max dense {dense_max:.10e} Lanczos(30) {:.10e} rel {rel:.1e}; s_min dense {dense_min:.4e} Ritz {:.4e}",
            lanczos.s_max, lanczos.s_min
        );
        assert!(
            m > 30,
            "the check needs more multipliers than Lanczos steps"
        );
        assert!(rel <= 1e-6, "{form:?}: rel {rel:.3e}");
        // Ritz values lie inside the spectrum.
        assert!(lanczos.s_max <= dense_max * (1.0 + 1e-12));
        assert!(lanczos.s_min >= dense_min * (1.0 - 1e-9));
    }
}

/// max_iter too small: a report that says "not converged", no error.
#[test]
fn max_iter_gives_a_non_converged_report() {
    let problem = membrane("p1b-p0", 8);
    let r = active_set(
        &problem,
        &ActiveSetOptions {
            max_iter: 1,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(!r.converged && r.stop_reason == "max_iter" && r.iterations == 1);
    assert!(r.measures.kkt > 1e-10);
    let r = dual_accelerated(
        &problem,
        &DualAcceleratedOptions {
            max_iter: 5,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(!r.converged && r.stop_reason == "max_iter" && r.iterations == 5);
    let r = uzawa_split(
        &problem,
        &UzawaSplitOptions {
            max_iter: 5,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(!r.converged && r.stop_reason == "max_iter" && r.iterations == 5);
    assert_eq!(r.history.len(), 5);
}

/// The same matrix, entry for entry (pattern and values).
fn same_entries(a: &SparseColMat<usize, f64>, b: &SparseColMat<usize, f64>) -> bool {
    common::pattern(a) == common::pattern(b) && a.val() == b.val()
}

/// The active set owns the problem while it solves (its Newton matrix is
/// built in A's arrays) and gives A back entry for entry, whole or as its
/// lower triangle; a symmetric A whole or as its lower triangle gives the
/// same solve bit for bit, and so does a second solve; a general A with
/// unused room after each column (faer's col_nnz) solves as the
/// compressed one.
#[test]
fn the_active_set_gives_a_back() {
    use obstacle_fem::solvers::active_set::active_set;
    let problem = membrane("p1b-p0", 8);
    let whole = problem.matrix.clone();
    let general = ContactProblem {
        kind: MatrixKind::General,
        ..problem.clone()
    };
    let (mut problem, first) = active_set(problem, &ActiveSetOptions::default()).unwrap();
    assert!(first.converged && first.measures.kkt <= 1e-10);
    // A symmetric A comes back as its lower triangle.
    let lower = into_lower_triangle(whole.clone());
    assert!(same_entries(&problem.matrix, &lower));
    problem.store_lower_triangle();
    let (problem, second) = active_set(problem, &ActiveSetOptions::default()).unwrap();
    assert_eq!((&second.x, &second.lambda), (&first.x, &first.lambda));
    assert!(same_entries(&problem.matrix, &lower));
    let (general, compressed) = active_set(general, &ActiveSetOptions::default()).unwrap();
    assert!(same_entries(&general.matrix, &whole));
    let roomy = ContactProblem {
        matrix: with_room_per_column(&whole),
        ..general
    };
    let (roomy, roomy_report) = active_set(roomy, &ActiveSetOptions::default()).unwrap();
    assert!(same_entries(&roomy.matrix, &whole));
    assert!(compressed.converged && compressed.measures.kkt <= 1e-10);
    assert_eq!(
        (&roomy_report.x, &roomy_report.lambda),
        (&compressed.x, &compressed.lambda)
    );
}

/// `a` with one unused slot after each column (its entries counted by
/// col_nnz), the garbage slot a row index and value nobody may read.
fn with_room_per_column(a: &SparseColMat<usize, f64>) -> SparseColMat<usize, f64> {
    let (sa, n) = (a.symbolic(), a.ncols());
    let (mut col_ptr, mut col_nnz) = (vec![0], Vec::with_capacity(n));
    let (mut row_idx, mut values) = (Vec::new(), Vec::new());
    for j in 0..n {
        let rows = sa.row_idx_of_col_raw(j);
        row_idx.extend_from_slice(rows);
        values.extend_from_slice(a.val_of_col(j));
        row_idx.push(0);
        values.push(f64::NAN);
        col_nnz.push(rows.len());
        col_ptr.push(row_idx.len());
    }
    let symbolic = faer::sparse::SymbolicSparseColMat::new_checked(
        a.nrows(),
        n,
        col_ptr,
        Some(col_nnz),
        row_idx,
    );
    SparseColMat::new(symbolic, values)
}

/// A tolerance below round-off: the active set stops changing above `tol`
/// (stagnation, an error that says so); FISTA stops improving (stagnation
/// after `stall_window` iterations).
#[test]
fn stagnation_is_detected() {
    let problem = membrane("p1b-p0", 8);
    let err = active_set(
        &problem,
        &ActiveSetOptions {
            tol: 1e-30,
            ..Default::default()
        },
    )
    .unwrap_err();
    eprintln!("active set, tol 1e-30: {err}");
    assert!(err.to_string().contains("stagnation at iteration"), "{err}");
    let err = dual_accelerated(
        &problem,
        &DualAcceleratedOptions {
            tol: 1e-30,
            stall_window: 300,
            ..Default::default()
        },
    )
    .unwrap_err();
    eprintln!("FISTA, tol 1e-30: {err}");
    assert!(err.to_string().contains("stagnation at iteration"), "{err}");
}

/// Newton-min cycles on the 3×3 P-matrix of Ben Gharbia & Gilbert (Math.
/// Program. 2012): A = [[1,2,0],[0,1,2],[2,0,1]], x ≥ 0, λ = A x − 1 ≥ 0,
/// started from 𝒜 = {0}: {0} → {1} → {2} → {0}. The active set reports it.
#[test]
fn active_set_detects_cycling() {
    let entries = [
        (0, 0, 1.0),
        (0, 1, 2.0),
        (1, 1, 1.0),
        (1, 2, 2.0),
        (2, 0, 2.0),
        (2, 2, 1.0),
    ];
    let t: Vec<_> = entries
        .iter()
        .map(|&(i, j, v)| Triplet::new(i, j, v))
        .collect();
    let identity: Vec<_> = (0..3).map(|i| Triplet::new(i, i, 1.0)).collect();
    let problem = ContactProblem {
        matrix: SparseColMat::try_new_from_triplets(3, 3, &t).unwrap(),
        kind: MatrixKind::General,
        rhs: vec![1.0; 3],
        n_primal: 3,
        constraint: Some(Constraint {
            matrix: SparseColMat::try_new_from_triplets(3, 3, &identity).unwrap(),
            obstacle: vec![0.0; 3],
            weights: vec![1.0; 3],
        }),
        interior: None,
    };
    let err = active_set(
        &problem,
        &ActiveSetOptions {
            initial_lambda: Some(vec![1.0, 0.0, 0.0]),
            ..Default::default()
        },
    )
    .unwrap_err();
    eprintln!("cycling: {err}");
    match &err {
        Error::Numerical {
            measure, reason, ..
        } => {
            assert_eq!(measure, "active set 𝒜");
            assert!(reason.contains("cycling at iteration 3"), "{reason}");
            assert!(reason.contains("iteration 1"), "{reason}");
        }
        other => panic!("unexpected error {other}"),
    }
    // The cold start (𝒜₁ = {g > 0} = ∅) finds the solution x = (1/3)(1,1,1).
    let r = active_set(&problem, &ActiveSetOptions::default()).unwrap();
    assert!(r.converged && r.iterations == 1);
    assert!(r.x.iter().all(|v| (v - 1.0 / 3.0).abs() < 1e-15));
}

/// Steps above the stability bound: FISTA with L = s_max/10 and the first
/// splitting with α = 4/s_max(S_C) diverge, and say so.
#[test]
fn divergence_is_detected() {
    let problem = membrane("p1b-p0", 8);
    let f = factorize_checked(&problem.matrix, problem.kind, Solves::Few, "A").unwrap();
    let s = estimate_dual_spectrum(&problem, &f, StepForm::Mean, 50).unwrap();
    let err = dual_accelerated(
        &problem,
        &DualAcceleratedOptions {
            lipschitz: Some(0.1 * s.s_max),
            restart: Restart::Never,
            ..Default::default()
        },
    )
    .unwrap_err();
    eprintln!("FISTA, L = s_max/10: {err}");
    assert!(err.to_string().contains("diverged at iteration"), "{err}");
    let err = uzawa_split(
        &problem,
        &UzawaSplitOptions {
            steps: SplitSteps::Given {
                alpha: 4.0 / s.s_max,
                beta: 0.0,
            },
            ..Default::default()
        },
    )
    .unwrap_err();
    eprintln!("split, α = 4/s_max: {err}");
    assert!(err.to_string().contains("diverged at iteration"), "{err}");
    // (4.26) violated by the shares: refused before iterating.
    let err = uzawa_split(
        &problem,
        &UzawaSplitOptions {
            steps: SplitSteps::Shares {
                alpha_share: 1.5,
                beta_share: 0.6,
            },
            psi_riesz: PsiRiesz::Euclidean,
            ..Default::default()
        },
    )
    .unwrap_err();
    assert!(err.to_string().contains("(4.26)"), "{err}");
}

/// Nested iteration: the 16×16 solution's λ (P0), prolonged to the 32×32
/// triangles (each fine centroid lies in one coarse triangle: the meshes are
/// nested), warm-starts the active set on 32×32. (From 8×8 it cannot help:
/// the locked 8×8 shell does not touch the plane at all.) Measured: 27 Newton
/// steps cold, 18 warm, 72 active triangles.
#[test]
fn nested_iteration_warm_start() {
    let (coarse_mesh, coarse) = shell_with_mesh(16);
    let (fine_mesh, fine) = shell_with_mesh(32);
    let coarse_report = active_set(&coarse, &ActiveSetOptions::default()).unwrap();
    print("shell 16x16", &coarse_report);
    let inside = |mesh: &Mesh, t: usize, p: [f64; 2]| {
        let v = mesh.triangles[t].map(|i| mesh.vertices[i]);
        let cross = |a: [f64; 2], b: [f64; 2], c: [f64; 2]| {
            (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        };
        let s = [
            cross(v[0], v[1], p),
            cross(v[1], v[2], p),
            cross(v[2], v[0], p),
        ];
        s.iter().all(|&x| x >= -1e-9) || s.iter().all(|&x| x <= 1e-9)
    };
    let lambda0: Vec<f64> = fine_mesh
        .triangles
        .iter()
        .map(|tri| {
            let v = tri.map(|i| fine_mesh.vertices[i]);
            let centroid = [
                (v[0][0] + v[1][0] + v[2][0]) / 3.0,
                (v[0][1] + v[1][1] + v[2][1]) / 3.0,
            ];
            let t = (0..coarse_mesh.n_triangles())
                .find(|&t| inside(&coarse_mesh, t, centroid))
                .expect("each fine centroid lies in a coarse triangle");
            coarse_report.lambda[t]
        })
        .collect();
    // Against plain PDAS from the free solution (the default depth bisection
    // beats both: tests/naghdi_scenes.rs).
    let cold = active_set(
        &fine,
        &ActiveSetOptions {
            cold_start: ColdStart::Plain,
            ..Default::default()
        },
    )
    .unwrap();
    let warm = active_set(
        &fine,
        &ActiveSetOptions {
            initial_lambda: Some(lambda0),
            ..Default::default()
        },
    )
    .unwrap();
    print("shell 32x32 cold", &cold);
    print("shell 32x32 nested", &warm);
    assert!(warm.converged && warm.measures.kkt <= 1e-10);
    assert!(rel_diff(&warm.x, &cold.x) < 1e-10);
    assert!(cold.iterations <= 30, "cold: {}", cold.iterations);
    assert!(
        warm.iterations < cold.iterations,
        "nested {} vs cold {}",
        warm.iterations,
        cold.iterations
    );
}

// The signed-regularised LDLᵀ of the shell's saddle-point matrix
// [[K_ρ, Bᵀ], [B, 0]] against faer's LU on the same matrix: the same solution
// to round-off over the penalty range, and the fallbacks (the order that
// regularises no pivot, then LU) taken when the refined solve misses its
// accuracy.

/// Solves with the chain and with LU; returns (method, max|x − x_LU|/max|x_LU|,
/// relative residuals of the chain's and of LU's solve, symbolic analyses).
fn against_lu(problem: &ContactProblem, solves: Solves) -> (&'static str, f64, f64, f64, usize) {
    let kind = problem.kind;
    assert!(matches!(kind, MatrixKind::SymmetricSaddle { .. }));
    let mut chain = ReusableFactorization::analyze(&problem.matrix, kind, solves, "shell").unwrap();
    let (f, _) = chain.factorize(&problem.matrix, "shell").unwrap();
    let mut x = problem.rhs.clone();
    f.solve_in_place(&mut x);
    let lu = factorize_checked(&problem.matrix, MatrixKind::General, Solves::Few, "shell").unwrap();
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
        let mut problem = hypar(16, rho).1;
        if scaled {
            let sigma = balanced_tangency_scale(&problem);
            scale_tangency_multiplier(&mut problem, sigma);
        }
        for solves in [Solves::Few, Solves::Many] {
            let (method, diff, res, res_lu, analyses) = against_lu(&problem, solves);
            println!(
            "ρ = {rho:e}, scaled {scaled}, {solves:?}: {method}, |x − x_LU| {diff:.2e}, residual {res:.2e} (LU {res_lu:.2e})"
        );
            // At ρ = 1e12 (κ₂ ≈ 4e10) the AMD order's regularised pivots
            // leave a refined test residual above 1e-8 and the chain takes
            // the order with the multipliers after their neighbours (a
            // second analysis), where nothing is regularised and the LDLᵀ
            // holds; asked for that order, the first analysis holds.
            let expected = if rho > 1e10 && solves == Solves::Few {
                ("LDLᵀ", 2)
            } else {
                ("LDLᵀ", 1)
            };
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
}

#[test]
fn ldlt_falls_back_to_lu_when_the_signs_are_wrong() {
    // Declared with every unknown primal, the ψ pivots are forced positive:
    // the factors are of a different matrix, refinement cannot recover, and
    // the chain moves to LU, which then solves it as LU does.
    let mut problem = hypar(16, 1e3).1;
    problem.kind = MatrixKind::SymmetricSaddle {
        n_primal: problem.n(),
    };
    let (method, diff, res, _, analyses) = against_lu(&problem, Solves::Few);
    assert_eq!(method, "LU");
    assert_eq!(analyses, 2);
    assert_eq!(diff, 0.0);
    assert!(res < 1e-10, "{res:e}");
}

/// The lower triangle of `a` (row ≥ column).
fn lower_triangle(a: &SparseColMat<usize, f64>) -> SparseColMat<usize, f64> {
    into_lower_triangle(a.clone())
}

#[test]
fn a_problem_stored_by_its_lower_triangle_keeps_those_entries_and_products() {
    // The pipeline keeps a symmetric A as its lower triangle
    // (`ContactProblem::store_lower_triangle`): exactly the entries on and
    // below the diagonal, in order, and A x as the whole matrix gives it.
    let (_, mut problem, _) = hypar(8, 1e3);
    let whole = problem.matrix.clone();
    let x: Vec<f64> = (0..problem.n())
        .map(|i| ((i * 7919) % 101) as f64 / 101.0 - 0.5)
        .collect();
    let ax_whole = obstacle_fem::linalg::mat_vec(&whole, &x);
    problem.store_lower_triangle();
    let lower = &problem.matrix;
    for j in 0..whole.ncols() {
        let expected: Vec<(usize, f64)> = whole
            .symbolic()
            .row_idx_of_col(j)
            .zip(whole.val_of_col(j).iter().copied())
            .filter(|&(i, _)| i >= j)
            .collect();
        let kept: Vec<(usize, f64)> = lower
            .symbolic()
            .row_idx_of_col(j)
            .zip(lower.val_of_col(j).iter().copied())
            .collect();
        assert_eq!(kept, expected, "column {j}");
    }
    assert!(lower.val().len() * 10 < whole.val().len() * 6);
    let diff: Vec<f64> = problem
        .product(&x, 1)
        .iter()
        .zip(&ax_whole)
        .map(|(a, b)| a - b)
        .collect();
    let rel = norm_inf(&diff) / norm_inf(&ax_whole);
    println!("A x lower against whole: {rel:.1e}");
    assert!(rel < 1e-13, "{rel:e}");
    // A general matrix stays whole.
    problem.matrix = whole.clone();
    problem.kind = MatrixKind::General;
    problem.store_lower_triangle();
    assert_eq!(problem.matrix.val().len(), whole.val().len());
}

#[test]
fn a_symmetric_matrix_given_by_its_lower_triangle_solves_as_the_whole() {
    // linalg reads a symmetric matrix by its lower triangle, so it may be
    // given by it alone (the active set's Newton matrix is): the same
    // solution whole or lower, in both orders, condensed or not; checks and
    // refinement multiply by the implied whole matrix, so the residual
    // against the whole matrix is at round-off too.
    let mut problem = hypar(16, 1e3).1;
    let sigma = balanced_tangency_scale(&problem);
    scale_tangency_multiplier(&mut problem, sigma);
    let (whole, kind) = (&problem.matrix, problem.kind);
    let lower = lower_triangle(whole);
    assert!(lower.val().len() < whole.val().len() * 6 / 10);
    let rel = |x: &[f64]| norm_inf(&residual(whole, x, &problem.rhs)) / norm_inf(&problem.rhs);
    for solves in [Solves::Few, Solves::Many] {
        for interior in [None, problem.interior.as_ref()] {
            let solve = |a: &SparseColMat<usize, f64>| {
                let f = factorize_checked_with(a, kind, solves, interior, "shell").unwrap();
                let mut x = problem.rhs.clone();
                f.solve_in_place(&mut x);
                x
            };
            let (x_whole, x_lower) = (solve(whole), solve(&lower));
            let diff: Vec<f64> = x_whole.iter().zip(&x_lower).map(|(a, b)| a - b).collect();
            let diff = norm_inf(&diff) / norm_inf(&x_whole);
            let condensed = interior.is_some();
            println!(
                "{solves:?}, condensed {condensed}: |x_lower − x_whole| {diff:.1e}, residuals {:.1e} / {:.1e}",
                rel(&x_lower),
                rel(&x_whole)
            );
            assert!(diff < 1e-11, "{solves:?} condensed {condensed}: {diff:e}");
            assert!(rel(&x_lower) < 1e-10, "{solves:?} condensed {condensed}");
        }
    }
    // The LU fallback (signs declared wrong, as in the test above) reads
    // every entry: it is given the whole matrix the lower triangle implies.
    problem.kind = MatrixKind::SymmetricSaddle {
        n_primal: problem.n(),
    };
    let lower = lower_triangle(&problem.matrix);
    let mut chain =
        ReusableFactorization::analyze(&lower, problem.kind, Solves::Few, "shell").unwrap();
    let (f, _) = chain.factorize(&lower, "shell").unwrap();
    assert_eq!((chain.method(), chain.symbolic_analyses()), ("LU", 2));
    let mut x = problem.rhs.clone();
    f.solve_in_place(&mut x);
    let res = rel(&x);
    println!("LU fallback from the lower triangle: residual {res:.1e}");
    assert!(res < 1e-10, "{res:e}");
    // Refinement multiplies by the implied whole matrix too.
    let mut x_refined = x.clone();
    let refined = refine(&lower, problem.kind, &f, &problem.rhs, &mut x_refined, 1, 1);
    assert!(
        refined < 1e-10 && (refined - rel(&x_refined)).abs() < 1e-12,
        "{refined:e}"
    );
}

#[test]
fn a_singular_saddle_matrix_fails_naming_every_fallback() {
    // [[K, bᵀ], [b, 0]] with K = [[1, 1], [1, 1]] and b = [1, 1]: the first
    // two rows are equal. Both LDLᵀ orders miss their accuracy, LU fails,
    // and the error says what was tried before it.
    let entries: Vec<Triplet<usize, usize, f64>> = [
        (0, 0),
        (0, 1),
        (1, 0),
        (1, 1),
        (0, 2),
        (2, 0),
        (1, 2),
        (2, 1),
    ]
    .iter()
    .map(|&(i, j)| Triplet::new(i, j, 1.0))
    .collect();
    let a = SparseColMat::try_new_from_triplets(3, 3, &entries).unwrap();
    let kind = MatrixKind::SymmetricSaddle { n_primal: 2 };
    let message = match factorize_checked(&a, kind, Solves::Few, "singular saddle") {
        Ok(_) => panic!("a singular matrix was factorised"),
        Err(e) => e.to_string(),
    };
    for part in [
        "singular saddle",
        "a fallback after: LDLᵀ (AMD order)",
        "; LDLᵀ (multipliers after their neighbours)",
    ] {
        assert!(message.contains(part), "{part:?} not in {message}");
    }
}

/// Uzawa through the entry point with the step `step`.
fn uzawa_options(step: UzawaStep) -> SolverOptions {
    SolverOptions::Uzawa(UzawaOptions {
        step,
        step_form: StepForm::Mean,
        max_iter: 100_000,
        tol: 1e-8,
        stop: StopRule::Kkt,
        thesis_tol: 0.0,
        dual_norm: DualNorm::L2,
        show_progress: false,
        initial_lambda: None,
        linear: Default::default(),
    })
}

/// The one entry point `solvers::solve`: each method gives the report of
/// its own function bit for bit; Uzawa's report carries α, chosen by its
/// rule from the Lanczos estimate it also carries; without a constraint
/// every method is the one linear solve.
#[test]
fn the_entry_point_runs_every_method_and_the_linear_solve() {
    let problem = membrane("p1b-p0", 8);
    let direct = [
        active_set(&problem, &ActiveSetOptions::default()).unwrap(),
        dual_accelerated(&problem, &DualAcceleratedOptions::default()).unwrap(),
        uzawa_split(&problem, &UzawaSplitOptions::default()).unwrap(),
    ];
    let options = [
        SolverOptions::ActiveSet(ActiveSetOptions::default()),
        SolverOptions::DualAccelerated(DualAcceleratedOptions::default()),
        SolverOptions::UzawaSplit(UzawaSplitOptions::default()),
    ];
    for (d, o) in direct.iter().zip(&options) {
        let r = solve(&problem, o, &[]).unwrap();
        assert_eq!(r.algorithm, d.algorithm);
        assert_eq!(r.iterations, d.iterations, "{}", r.algorithm);
        assert!(r.x == d.x && r.lambda == d.lambda, "{}", r.algorithm);
        assert!(r.converged && r.alpha.is_none() && r.spectrum.is_none());
    }

    // The factorisation Uzawa makes: condensed by the problem's interior groups.
    let f = factorize_checked_with(
        &problem.matrix,
        problem.kind,
        Solves::Many,
        problem.interior.as_ref(),
        "A",
    )
    .unwrap();
    let s = estimate_dual_spectrum(&problem, &f, StepForm::Mean, 50).unwrap();
    for (step, alpha) in [
        (
            UzawaStep::Auto,
            (2.0 / (s.s_max + s.s_min)).min(1.9 / s.s_max),
        ),
        (UzawaStep::StabilityFactor(0.5), 1.0 / s.s_max),
        (UzawaStep::Given(5.0), 5.0),
    ] {
        let r = solve(&problem, &uzawa_options(step), &[]).unwrap();
        print(&format!("entry point, Uzawa {step:?}"), &r);
        assert_eq!(r.algorithm, "uzawa");
        assert_eq!(r.alpha, Some(alpha), "{step:?}");
        assert_eq!(parameter(&r, "alpha"), alpha);
        let estimate = r.spectrum.expect("Uzawa carries its estimate");
        assert_eq!((estimate.s_max, estimate.s_min), (s.s_max, s.s_min));
        assert!(
            r.converged && r.stop_reason == "kkt",
            "{step:?}: {}",
            r.stop_reason
        );
        assert!(rel_diff(&r.lambda, &direct[0].lambda) < 1e-5, "{step:?}");
    }

    let free = ContactProblem {
        constraint: None,
        ..membrane("p1b-p0", 8)
    };
    let mut reports: Vec<SolveReport> = options
        .iter()
        .map(|o| solve(&free, o, &[]).unwrap())
        .collect();
    reports.push(solve(&free, &uzawa_options(UzawaStep::Auto), &[]).unwrap());
    for r in &reports {
        assert_eq!(
            (r.algorithm.as_str(), r.stop_reason.as_str()),
            ("linear", "linear")
        );
        assert!(r.converged && r.iterations == 1 && r.history.is_empty());
        assert!(r.lambda.is_empty() && r.alpha.is_none());
        assert!(
            r.measures.stationarity < 1e-12,
            "{:.3e}",
            r.measures.stationarity
        );
        assert!(r.x == reports[0].x);
    }
}

/// `main` keeps freed memory for the next factorisation (glibc's mallopt);
/// glibc versions that cap the mmap threshold would refuse the setting and
/// every Newton step would fault in fresh pages again (issue 13: 12.5 s of
/// system time at the shell's n = 128).
#[test]
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn glibc_accepts_the_keep_freed_memory_settings() {
    assert!(obstacle_fem::linalg::keep_freed_memory());
}

/// A k×k grid's 5-point Laplacian with multipliers on every other cell,
/// each coupling the cell's three corners, as the lower triangle of a
/// Newton matrix of the active set: multiplier i's diagonal 0 when `on(i)`
/// holds, else the switched-off −1e12. Returns it, the number of primal
/// unknowns and the value positions of the multiplier diagonal.
fn grid_newton_matrix(
    k: usize,
    on: impl Fn(usize) -> bool,
) -> (SparseColMat<usize, f64>, usize, Vec<usize>) {
    let node = |i: usize, j: usize| i * k + j;
    let mut lower = Vec::new();
    for i in 0..k {
        for j in 0..k {
            lower.push(Triplet::new(node(i, j), node(i, j), 4.0 + 1e-3));
            if i + 1 < k {
                lower.push(Triplet::new(node(i + 1, j), node(i, j), -1.0));
            }
            if j + 1 < k {
                lower.push(Triplet::new(node(i, j + 1), node(i, j), -1.0));
            }
        }
    }
    let (n_primal, mut m) = (k * k, k * k);
    for i in 0..k - 1 {
        for j in (0..k - 1).step_by(2) {
            for c in [node(i, j), node(i + 1, j), node(i, j + 1)] {
                lower.push(Triplet::new(m, c, 1.0 / 3.0));
            }
            let d = if on(m - n_primal) { 0.0 } else { -1e12 };
            lower.push(Triplet::new(m, m, d));
            m += 1;
        }
    }
    let a = SparseColMat::try_new_from_triplets(m, m, &lower).unwrap();
    let s = a.symbolic();
    let diagonal = (n_primal..m)
        .map(|i| {
            (s.col_ptr()[i]..s.col_ptr()[i + 1])
                .find(|&p| s.row_idx()[p] == i)
                .unwrap()
        })
        .collect();
    (a, n_primal, diagonal)
}

/// An LDLᵀ of a Newton matrix that differs from the last one only in a
/// few declared multiplier diagonals (constraints switched on and off, so
/// their rows' equilibration changes too) factorises only the supernodes
/// those rows reach and keeps the others from the last factor: its solve
/// equals, bit for bit, the one of a factoriser that saw only that matrix,
/// for a fraction of the work; and the counts say so.
#[test]
fn a_declared_change_refactorises_only_the_supernodes_it_reaches() {
    {
        let k = 150;
        let zone = |i: usize| (i / 7).is_multiple_of(5);
        let (first, n_primal, declared) = grid_newton_matrix(k, zone);
        // Three constraints switched on, two off.
        let switched = [3, 400, 2001, 35, 3000];
        let next = grid_newton_matrix(k, |i| zone(i) != switched.contains(&i)).0;
        let kind = MatrixKind::SymmetricSaddle { n_primal };
        let b: Vec<f64> = (0..first.nrows())
            .map(|i| {
                if i < n_primal {
                    ((i * 37) % 11) as f64 - 5.0
                } else {
                    0.1
                }
            })
            .collect();
        // AMD eliminates most multipliers before their neighbours; the other
        // order after them, where a row's d_i reaches its neighbours' columns.
        for solves in [Solves::Few, Solves::Many] {
            let factoriser = || {
                // Two threads: the tree's split, which the partial
                // refactorisation needs.
                let mut f =
                    ReusableFactorization::analyze_with(&first, kind, solves, None, "grid", 2)
                        .unwrap();
                f.keep_eliminations(Some(&declared));
                f
            };
            let solve = |f: &mut ReusableFactorization, a: &SparseColMat<usize, f64>| {
                let a = std::sync::Arc::new(a.clone());
                f.factorize_and_solve_shared(&a, &b, Changed::Declared, "grid")
                    .unwrap()
                    .1
            };
            let mut reused = factoriser();
            solve(&mut reused, &first);
            let x = solve(&mut reused, &next);
            let mut fresh = factoriser();
            let y = solve(&mut fresh, &next);
            let differing = x
                .iter()
                .zip(&y)
                .filter(|(a, b)| a.to_bits() != b.to_bits())
                .count();
            assert_eq!(
                differing, 0,
                "{solves:?}: the solves differ in {differing} entries"
            );
            assert_eq!(reused.numeric_factorizations(), 2);
            assert_eq!(fresh.factorized_work(), 1.0);
            let work = reused.factorized_work() - 1.0;
            eprintln!(
                "{solves:?}: the second factorisation computed {:.1} % of the work",
                100.0 * work
            );
            assert!(work > 0.0 && work < 0.9, "{work}");
            // The solution is the system's (the symmetric matrix of that lower
            // triangle; the switched-off rows' own entries are ~1e12 x_i).
            let mut r = b.clone();
            for j in 0..next.ncols() {
                for (i, v) in next.symbolic().row_idx_of_col(j).zip(next.val_of_col(j)) {
                    r[i] -= v * x[j];
                    if i != j {
                        r[j] -= v * x[i];
                    }
                }
            }
            assert!(norm_inf(&r) <= 1e-9 * norm_inf(&b), "{:e}", norm_inf(&r));
        }
    }
}
