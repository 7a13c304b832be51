//! Static condensation of element-interior unknowns (src/linalg/condensed.rs)
//! is exact: every solver gives the iterates it gives without it, to
//! round-off, on the membrane P1⊕B3–P0 disk and both shell elements; a
//! wrong group declaration or a singular local block is an error naming the
//! group.

mod common;

use common::{fixed_uzawa_options, parameter, solve};
use faer::sparse::{SparseColMat, Triplet};
use obstacle_fem::linalg::{
    factorize_checked, factorize_checked_with, Changed, InteriorGroups, MatrixKind,
    ReusableFactorization, Solves,
};
use obstacle_fem::pipeline::{assemble, scene_mesh, setup_model};
use obstacle_fem::scene::{Scene, StepForm};
use obstacle_fem::solvers::active_set::{ActiveSetOptions, ColdStart};
use obstacle_fem::solvers::dual_accelerated::DualAcceleratedOptions;
use obstacle_fem::solvers::uzawa::UzawaStep;
use obstacle_fem::solvers::uzawa_split::UzawaSplitOptions;
use obstacle_fem::solvers::{ContactProblem, LinearOptions, SolveReport, SolverOptions};
use std::path::Path;

/// The three problems with interior groups: (label, scene, overrides).
const PROBLEMS: [(&str, &str, &[&str]); 3] = [
    (
        "membrane P1⊕B3–P0",
        "pipelines/scenes/obstacle-disk.toml",
        &["element=p1b-p0", "mesh.n=8"],
    ),
    (
        "shell p1b-p0",
        "pipelines/scenes/naghdi-hypar.toml",
        &["mesh.n=16"],
    ),
    (
        "shell p2b-psri",
        "pipelines/scenes/shell/hypar-psri.toml",
        &["mesh.n=6"],
    ),
];

/// The scene's assembled contact problem, as the pipeline builds it.
fn problem(scene: &str, overrides: &[&str]) -> ContactProblem {
    let overrides: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    let scene = Scene::load(Path::new(scene), &overrides).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mesh = scene_mesh(&scene, &dir.path().join("mesh.msh")).unwrap();
    let system = setup_model(&scene, &mesh).unwrap();
    assemble(&scene, &mesh, system.as_ref()).unwrap()
}

/// The same problem without its interior groups.
fn uncondensed(p: &ContactProblem) -> ContactProblem {
    ContactProblem {
        matrix: p.matrix.clone(),
        kind: p.kind,
        rhs: p.rhs.clone(),
        n_primal: p.n_primal,
        constraint: p
            .constraint
            .as_ref()
            .map(|c| obstacle_fem::solvers::Constraint {
                matrix: c.matrix.clone(),
                obstacle: c.obstacle.clone(),
                weights: c.weights.clone(),
            }),
        interior: None,
    }
}

/// max|a − b| / max|b|.
fn relative(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    let scale = b
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(f64::MIN_POSITIVE);
    a.iter()
        .zip(b)
        .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
        / scale
}

/// Both runs' x and λ agree to `tol` (relative max norm), after the same
/// number of iterations.
fn assert_same(label: &str, method: &str, with: &SolveReport, without: &SolveReport, tol: f64) {
    let (dx, dl) = (
        relative(&with.x, &without.x),
        relative(&with.lambda, &without.lambda),
    );
    eprintln!(
        "{label}, {method}: {} iterations, x differs by {dx:.1e}, λ by {dl:.1e}",
        with.iterations
    );
    assert_eq!(with.iterations, without.iterations, "{label}, {method}");
    assert!(
        dx <= tol && dl <= tol,
        "{label}, {method}: x {dx:.1e}, λ {dl:.1e} > {tol:.0e}"
    );
}

/// K iterations of Uzawa (both step forms), the first splitting and FISTA:
/// the same iterates with and without condensation to 1e-12, and the same
/// Lanczos estimate; each problem has interior groups (a bubble per field
/// and triangle).
#[test]
fn iterative_solvers_give_the_same_iterates_condensed() {
    const K: usize = 40;
    for (label, scene, overrides) in PROBLEMS {
        let condensed = problem(scene, overrides);
        let plain = uncondensed(&condensed);
        let groups = condensed.interior.as_ref().expect("declared by the model");
        let triangles = condensed.n_multipliers().max(1);
        assert!(
            !groups.is_empty() && groups.n_interior() >= groups.len(),
            "{label}"
        );
        eprintln!(
            "{label}: {} unknowns, {} interior in {} groups ({triangles} multipliers)",
            condensed.n(),
            groups.n_interior(),
            groups.len()
        );
        for step_form in [StepForm::Mean, StepForm::Integral] {
            let options = SolverOptions::Uzawa(fixed_uzawa_options(
                UzawaStep::StabilityFactor(0.5),
                step_form,
                K,
            ));
            let (with, without) = (
                solve(&condensed, &options, &[]).unwrap(),
                solve(&plain, &options, &[]).unwrap(),
            );
            let (a, b) = (with.alpha.unwrap(), without.alpha.unwrap());
            assert!((a - b).abs() <= 1e-10 * b, "{label}: α {a} vs {b}");
            assert_same(
                label,
                &format!("Uzawa ({step_form:?})"),
                &with,
                &without,
                1e-12,
            );
        }
        let others = [
            (
                "uzawa-split",
                SolverOptions::UzawaSplit(UzawaSplitOptions {
                    max_iter: K,
                    tol: 0.0,
                    ..Default::default()
                }),
            ),
            (
                "dual-accelerated",
                SolverOptions::DualAccelerated(DualAcceleratedOptions {
                    max_iter: K,
                    tol: 0.0,
                    ..Default::default()
                }),
            ),
        ];
        for (method, options) in others {
            match (
                solve(&condensed, &options, &[]),
                solve(&plain, &options, &[]),
            ) {
                (Ok(with), Ok(without)) => assert_same(label, method, &with, &without, 1e-12),
                // The first splitting needs a saddle matrix with ψ; both
                // runs refuse a problem alike.
                (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string(), "{label}"),
                (a, b) => panic!("{label}, {method}: {:?} vs {:?}", a.err(), b.err()),
            }
        }
    }
}

/// `solver.threads = 2` (two threads on the elimination tree of each
/// supernodal LDLᵀ) gives the sequential run's iterates: 40 Uzawa iterations on the
/// shell p1b-p0 at n = 16, condensed and whole, x and λ to 1e-12, the
/// Lanczos α to 1e-10, the same KKT history to 1e-8 relative.
#[test]
fn threaded_factorisations_give_the_sequential_iterates() {
    let (_, scene, overrides) = PROBLEMS[1];
    // The thread count travels in the method's linear options.
    let run = |threads: usize, condense: &str| {
        let mut sets = overrides.to_vec();
        sets.push(condense);
        let p = problem(scene, &sets);
        let mut uzawa = fixed_uzawa_options(UzawaStep::StabilityFactor(0.5), StepForm::Mean, 40);
        uzawa.linear.threads = threads;
        solve(&p, &SolverOptions::Uzawa(uzawa), &[]).unwrap()
    };
    for condense in ["solver.condense=true", "solver.condense=false"] {
        let sequential = run(1, condense);
        let threaded = run(2, condense);
        let (a, b) = (threaded.alpha.unwrap(), sequential.alpha.unwrap());
        assert!((a - b).abs() <= 1e-10 * b, "{condense}: α {a} vs {b}");
        assert_same(condense, "Uzawa, 2 threads", &threaded, &sequential, 1e-12);
        let (kt, ks) = (
            threaded.history.column("kkt").unwrap(),
            sequential.history.column("kkt").unwrap(),
        );
        assert_eq!(kt.len(), 40, "{condense}");
        assert!(
            relative(kt, ks) <= 1e-8,
            "{condense}: KKT history differs by {:.1e}",
            relative(kt, ks)
        );
    }
}

/// The active set: the same Newton steps, the same active set at the end
/// and the same solution to 1e-10, one symbolic analysis (of S) for all
/// steps.
/// Both cold starts: the interior-point steps after the first reuse the
/// bubbles' eliminations (only the multiplier diagonal changes,
/// `Changed::Declared`), which the whole matrix's run does not have.
#[test]
fn active_set_gives_the_same_active_set_and_solution_condensed() {
    for ((label, scene, overrides), cold_start) in PROBLEMS.into_iter().flat_map(|p| {
        [
            (p, ColdStart::DEPTH_BISECTION),
            (p, ColdStart::INTERIOR_POINT),
        ]
    }) {
        let condensed = problem(scene, overrides);
        let plain = uncondensed(&condensed);
        let options = SolverOptions::ActiveSet(ActiveSetOptions {
            cold_start,
            ..Default::default()
        });
        let (with, without) = (
            solve(&condensed, &options, &[]).unwrap(),
            solve(&plain, &options, &[]).unwrap(),
        );
        eprintln!(
            "{label}, {cold_start:?}: {} Newton solves condensed, {} whole",
            with.iterations, without.iterations
        );
        assert!(with.converged && without.converged, "{label}");
        assert_eq!(with.contact(), without.contact(), "{label}: active sets");
        assert_same(label, "active-set", &with, &without, 1e-10);
        assert_eq!(parameter(&with, "symbolic_analyses"), 1.0, "{label}");
        assert_eq!(
            parameter(&with, "numeric_factorizations"),
            with.iterations as f64,
            "{label}"
        );
    }
}

/// Without contact: the one linear solve agrees to 1e-12, and the
/// condensed factorisation solves a system of the Schur complement's size.
#[test]
fn linear_solve_agrees_condensed() {
    for (label, scene, overrides) in PROBLEMS {
        let mut condensed = problem(scene, overrides);
        condensed.constraint = None;
        let plain = uncondensed(&condensed);
        let options = SolverOptions::ActiveSet(ActiveSetOptions::default());
        let (with, without) = (
            solve(&condensed, &options, &[]).unwrap(),
            solve(&plain, &options, &[]).unwrap(),
        );
        assert_eq!(with.stop_reason, "linear");
        let dx = relative(&with.x, &without.x);
        eprintln!("{label}, linear solve: x differs by {dx:.1e}");
        assert!(dx <= 1e-12, "{label}: {dx:.1e}");
        let f = factorize_checked_with(
            &condensed.matrix,
            condensed.kind,
            Solves::Few,
            condensed.interior.as_ref(),
            "test",
        )
        .unwrap();
        // The one linear solve factorises the whole matrix (faster for one
        // solve); the condensed factorisation gives the same x.
        let mut x = condensed.rhs.clone();
        f.solve_in_place(&mut x);
        let dx = relative(&x, &without.x);
        eprintln!("{label}, condensed factorisation: x differs by {dx:.1e}");
        assert!(dx <= 1e-12, "{label}: condensed {dx:.1e}");
        let groups = condensed.interior.as_ref().unwrap();
        match f {
            obstacle_fem::linalg::Factorization::Condensed(c) => {
                assert_eq!(c.n_schur(), condensed.n() - groups.n_interior(), "{label}")
            }
            _ => panic!("{label}: not condensed"),
        }
    }
}

/// A group whose unknown couples with another group's is refused, naming
/// the group; so is an unknown declared twice, out of range, and a singular
/// local block.
#[test]
fn wrong_group_declarations_are_errors_naming_the_group() {
    // The p2b-psri shell's bubbles couple with its vertex unknowns (the
    // membrane's P1⊕B3 stiffness is block diagonal: its bubbles couple
    // with nothing).
    let p = problem(PROBLEMS[2].1, PROBLEMS[2].2);
    let groups = p.interior.as_ref().unwrap();
    let factorize = |g: &InteriorGroups| {
        factorize_checked_with(&p.matrix, p.kind, Solves::Few, Some(g), "stiffness")
            .err()
            .expect("refused")
            .to_string()
    };
    // Group 0 takes a vertex unknown coupled to triangle 0's bubble: its
    // row touches the bubbles of the neighbouring triangles too.
    let bubble = groups.group(0)[0];
    let vertex = (0..p.n())
        .find(|&i| {
            p.matrix.symbolic().row_idx_of_col(i).any(|r| r == bubble)
                && (0..groups.len()).all(|g| !groups.group(g).contains(&i))
        })
        .unwrap();
    let mut lists: Vec<Vec<usize>> = (0..groups.len())
        .map(|g| groups.group(g).to_vec())
        .collect();
    lists[0].push(vertex);
    let message = factorize(&InteriorGroups::from_groups(lists.clone()));
    eprintln!("{message}");
    assert!(
        message.contains("interior group") && message.contains("couples with"),
        "{message}"
    );
    assert!(
        message.contains(&format!("unknown {vertex}")) || message.contains("group 0"),
        "{message}"
    );

    lists[0].pop();
    lists[1].push(bubble);
    let message = factorize(&InteriorGroups::from_groups(lists.clone()));
    assert!(
        message.contains("interior group 1") && message.contains("already in interior group 0"),
        "{message}"
    );
    lists[1].pop();
    lists[1].push(p.n() + 3);
    let message = factorize(&InteriorGroups::from_groups(lists));
    assert!(
        message.contains("interior group 1") && message.contains("out of range"),
        "{message}"
    );

    // A zero interior block: [[0, 1], [1, 1]] with unknown 0 interior.
    let t = [(0, 1, 1.0), (1, 0, 1.0), (1, 1, 1.0)].map(|(i, j, v)| Triplet::new(i, j, v));
    let a = SparseColMat::try_new_from_triplets(2, 2, &t).unwrap();
    let g = InteriorGroups::from_groups([vec![0]]);
    let message = factorize_checked_with(&a, MatrixKind::General, Solves::Few, Some(&g), "toy")
        .err()
        .expect("refused")
        .to_string();
    assert!(
        message.contains("interior group 0") && message.contains("singular"),
        "{message}"
    );
}

/// A non-symmetric 5×5 matrix with the groups {1, 2} and {4} (unknowns 0
/// and 3 remain); `a33` and `a11` are the entries (3, 3) (between remaining
/// unknowns) and (1, 1) (interior), 5 and 3 unless a test changes them.
fn general_toy(a33: f64, a11: f64) -> (SparseColMat<usize, f64>, InteriorGroups) {
    let entries = [
        (0, 0, 4.0),
        (0, 1, 1.0),
        (1, 0, -2.0),
        (1, 1, a11),
        (1, 2, 0.5),
        (2, 1, 0.7),
        (2, 2, 2.0),
        (2, 3, -1.0),
        (3, 2, 0.3),
        (3, 3, a33),
        (3, 4, 2.0),
        (4, 3, -0.4),
        (4, 4, 1.5),
        (0, 3, 0.2),
        (3, 0, 0.9),
    ];
    let t: Vec<_> = entries
        .iter()
        .map(|&(i, j, v)| Triplet::new(i, j, v))
        .collect();
    let a = SparseColMat::try_new_from_triplets(5, 5, &t).unwrap();
    (a, InteriorGroups::from_groups([vec![1, 2], vec![4]]))
}

/// A non-symmetric matrix (LU on S, the local V = A_RI A_II⁻¹ kept apart):
/// A x = b and Aᵀ x = b agree with the uncondensed LU to round-off.
#[test]
fn general_matrices_condense_with_both_couplings() {
    let (a, g) = general_toy(5.0, 3.0);
    let condensed =
        factorize_checked_with(&a, MatrixKind::General, Solves::Few, Some(&g), "toy").unwrap();
    let direct = factorize_checked(&a, MatrixKind::General, Solves::Few, "toy").unwrap();
    let b = [1.0, -2.0, 0.5, 3.0, 0.25];
    let (mut x, mut y) = (b.to_vec(), b.to_vec());
    condensed.solve_in_place(&mut x);
    direct.solve_in_place(&mut y);
    assert!(relative(&x, &y) <= 1e-14, "{x:?} vs {y:?}");
    let (mut x, mut y) = (b.to_vec(), b.to_vec());
    condensed.solve_transpose_in_place(&mut x);
    direct.solve_transpose_in_place(&mut y);
    assert!(relative(&x, &y) <= 1e-14, "transposed: {x:?} vs {y:?}");
}

/// `Changed::Declared`: after a matrix whose groups were eliminated and
/// kept, one that differs only in the declared entry between remaining
/// unknowns (here the diagonal of unknown 3, as an interior-point step
/// changes its multiplier diagonal) is factorised from the kept
/// eliminations; its solution agrees with a fresh condensed factorisation
/// to round-off. `Changed::Any` after an interior entry changed eliminates
/// anew. Declaring an entry of a group is an error naming it.
#[test]
fn kept_eliminations_serve_a_matrix_changed_between_remaining_unknowns() {
    let entries = |a33: f64, a11: f64| std::sync::Arc::new(general_toy(a33, a11).0);
    let (_, g) = general_toy(5.0, 3.0);
    let b = [1.0, -2.0, 0.5, 3.0, 0.25];
    let fresh = |a: &SparseColMat<usize, f64>| {
        let f =
            factorize_checked_with(a, MatrixKind::General, Solves::Few, Some(&g), "toy").unwrap();
        let mut x = b.to_vec();
        f.solve_in_place(&mut x);
        x
    };
    let first = entries(5.0, 3.0);
    let mut reused = ReusableFactorization::analyze_with(
        &first,
        MatrixKind::General,
        Solves::Few,
        Some(&g),
        "toy",
        1,
    )
    .unwrap();
    // The value position of the diagonal entry (i, i).
    let diagonal = |i: usize| {
        let s = first.symbolic();
        (s.col_ptr()[i]..s.col_ptr()[i + 1])
            .find(|&k| s.row_idx()[k] == i)
            .unwrap()
    };
    let a33 = diagonal(3);
    reused.keep_eliminations(Some(&[a33]));
    let (_, x, _) = reused
        .factorize_and_solve_shared(&first, &b, Changed::Any, "toy")
        .unwrap();
    assert!(relative(&x, &fresh(&first)) <= 1e-14);
    for (changed, a) in [
        (Changed::Declared, entries(-7.5, 3.0)),
        (Changed::Declared, entries(1e6, 3.0)),
        (Changed::Any, entries(1e6, -4.0)),
    ] {
        let (_, x, residual) = reused
            .factorize_and_solve_shared(&a, &b, changed, "toy")
            .unwrap();
        let y = fresh(&a);
        assert!(relative(&x, &y) <= 1e-13, "{changed:?}: {x:?} vs {y:?}");
        assert!(residual <= 1e-14, "{changed:?}: {residual:e}");
    }
    assert_eq!(reused.symbolic_analyses(), 1);
    assert_eq!(reused.numeric_factorizations(), 4);
    // (1, 1) lies in the group {1, 2}.
    let a11 = diagonal(1);
    reused.keep_eliminations(Some(&[a11]));
    let err = reused
        .factorize_and_solve_shared(&first, &b, Changed::Any, "toy")
        .err()
        .expect("an entry of a group declared")
        .to_string();
    assert!(
        err.contains("declared entry") && err.contains(&format!("value {a11}")),
        "{err}"
    );
}

/// PDAS steps solved with the last factorisation (`switched_steps`, the
/// bordered system of the constraints switched since it): the shell p1b-p0
/// at n = 64 from the interior-point start, two threads (the sweeps need
/// the tree's split), reaches the factorised run's active set and solution
/// (x to 1e-10, KKT ≤ 1e-10), with as many Newton steps and one
/// factorisation fewer per switched step.
#[test]
fn switched_pdas_steps_reach_the_factorised_solution() {
    let problem = problem("pipelines/scenes/naghdi-hypar.toml", &["mesh.n=64"]);
    let run = |switched_steps| {
        let options = SolverOptions::ActiveSet(ActiveSetOptions {
            cold_start: ColdStart::INTERIOR_POINT,
            switched_steps,
            // The sweeps need the tree's split.
            linear: LinearOptions {
                threads: 2,
                ..Default::default()
            },
            ..Default::default()
        });
        solve(&problem, &options, &[]).unwrap()
    };
    let (switched, factorised) = (run(true), run(false));
    let count = |r: &SolveReport| {
        (
            parameter(r, "numeric_factorizations"),
            parameter(r, "switched_steps"),
        )
    };
    eprintln!(
        "shell n = 64: (factorisations, switched steps) {:?} against {:?}, KKT {:.1e} / {:.1e}",
        count(&switched),
        count(&factorised),
        switched.measures.kkt,
        factorised.measures.kkt
    );
    for r in [&switched, &factorised] {
        assert!(r.converged && r.measures.kkt <= 1e-10);
    }
    assert_eq!(switched.iterations, factorised.iterations);
    let (f, s) = count(&switched);
    assert!(s >= 1.0, "no step was switched");
    assert_eq!(f + s, switched.iterations as f64);
    assert_eq!(count(&factorised), (factorised.iterations as f64, 0.0));
    assert_eq!(switched.contact(), factorised.contact());
    assert_same("shell p1b-p0", "switched", &switched, &factorised, 1e-10);
}
