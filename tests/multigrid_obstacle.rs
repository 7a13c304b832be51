//! The Newton multigrid method (`solver.method = "multigrid"`,
//! src/solvers/multigrid_newton.rs) on the hierarchy of `mesh.refine`: the
//! same discrete solution as the active set on the same mesh (the disk with
//! its circle snapped, the two-sided disk, the ball with nonzero boundary
//! values), its Newton steps per level bounded as the mesh is refined, the
//! scenes it refuses, and the refined mesh's MSH file read back as written.
//!
//! Measured figures are printed with eprintln (run with `--nocapture`).

mod common;

use common::manifest_path;
use obstacle_fem::mesh::Mesh;
use obstacle_fem::pipeline::{assembled, scene_hierarchy, solve_on, write_refined_msh, Start};
use obstacle_fem::scene::Scene;
use obstacle_fem::solvers::SolveReport;

/// The scene with `overrides`.
fn scene(path: &str, overrides: &[&str]) -> Scene {
    let overrides: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    Scene::load(&manifest_path(path), &overrides).unwrap()
}

/// The scene solved by multigrid on its hierarchy and by the active set on
/// the same finest mesh: both reports. The multigrid solve gives its
/// problem back with C entry for entry as assembled (it holds C in its
/// condensed rows meanwhile).
fn multigrid_and_active_set(path: &str, overrides: &[&str]) -> (SolveReport, SolveReport) {
    let mut with_mg = overrides.to_vec();
    with_mg.push("solver.method=multigrid");
    let mg_scene = scene(path, &with_mg);
    let dir = tempfile::tempdir().unwrap();
    let hierarchy = scene_hierarchy(&mg_scene, &dir.path().join("mesh.msh")).unwrap();
    let solved = solve_on(
        &mg_scene,
        hierarchy.finest(),
        Start::Scene(Some(&hierarchy)),
        false,
        &mut |_| {},
    )
    .unwrap();
    let (_, assembled) = assembled(&mg_scene, hierarchy.finest()).unwrap();
    let (given_back, as_assembled) = (
        &solved.problem.constraint.as_ref().unwrap().matrix,
        &assembled.constraint.as_ref().unwrap().matrix,
    );
    assert_eq!(
        common::pattern(given_back),
        common::pattern(as_assembled),
        "{path}: C's pattern"
    );
    assert_eq!(given_back.val(), as_assembled.val(), "{path}: C's values");
    let mg = solved.report;
    let mut with_as = overrides.to_vec();
    with_as.push("solver.method=active-set");
    let as_scene = scene(path, &with_as);
    let active_set = solve_on(
        &as_scene,
        hierarchy.finest(),
        Start::Scene(None),
        false,
        &mut |_| {},
    )
    .unwrap()
    .report;
    (mg, active_set)
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0, |m, x| m.max(x.abs()))
}

fn max_difference(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).fold(0.0, |m, (x, y)| m.max((x - y).abs()))
}

/// Newton steps on each level, coarsest first (the report's parameters).
fn newton_steps(report: &SolveReport) -> Vec<usize> {
    let levels = report.parameter("levels").unwrap() as usize;
    (0..levels)
        .map(|l| {
            report
                .parameter(&format!("newton_steps_level_{l}"))
                .unwrap() as usize
        })
        .collect()
}

/// Multigrid and the active set agree on (x, λ) and both meet the tolerance.
fn assert_same_solution(what: &str, mg: &SolveReport, active_set: &SolveReport, tol: f64) {
    assert!(
        mg.converged,
        "{what}: multigrid did not converge: {:?}",
        mg.measures
    );
    assert!(mg.measures.kkt <= tol, "{what}: KKT {:e}", mg.measures.kkt);
    let du = max_difference(&mg.x, &active_set.x) / max_abs(&active_set.x);
    let dl = max_difference(&mg.lambda, &active_set.lambda) / max_abs(&active_set.lambda);
    eprintln!(
        "{what}: steps per level {:?}, CG {}, |Δx|/|x| {du:.2e}, |Δλ|/|λ| {dl:.2e}, active {} / {}",
        newton_steps(mg),
        mg.parameter("cg_iterations").unwrap(),
        mg.measures.active,
        active_set.measures.active
    );
    assert!(du <= 1e-8, "{what}: x differs by {du:e} (relative)");
    assert!(dl <= 1e-6, "{what}: λ differs by {dl:e} (relative)");
    assert_eq!(mg.contact(), active_set.contact(), "{what}: contact sets");
}

#[test]
fn the_disk_on_its_refined_hierarchy_is_the_active_sets_solution() {
    // disk.geo with n = 4 refined 4 times: 16 boundary points per quarter,
    // each new one snapped onto the circle.
    let (mg, active_set) = multigrid_and_active_set(
        "pipelines/scenes/obstacle-disk.toml",
        &[
            "mesh.n=4",
            "mesh.refine=4",
            "solver.tol=1e-10",
            "output.errors=false",
        ],
    );
    assert_same_solution("disk", &mg, &active_set, 1e-10);
}

#[test]
fn the_two_sided_disk_touches_both_bounds_and_is_the_active_sets_solution() {
    // To 1e-12: steps that keep the active set are taken whole, where J's
    // change along them lies below its round-off (an Armijo test on it
    // stalls at 2.8e-10 here).
    let (mg, active_set) = multigrid_and_active_set(
        "pipelines/scenes/peers/two-sided.toml",
        &[
            "mesh.n=4",
            "mesh.refine=4",
            "solver.tol=1e-12",
            "output.errors=false",
        ],
    );
    assert_same_solution("two-sided", &mg, &active_set, 1e-12);
    // Rows [0, m) are the lower bound's, [m, 2m) the upper's.
    let m = mg.lambda.len() / 2;
    let lower = mg.lambda[..m].iter().filter(|&&l| l > 0.0).count();
    let upper = mg.lambda[m..].iter().filter(|&&l| l > 0.0).count();
    eprintln!("two-sided: {lower} triangles on the lower bound, {upper} on the upper");
    assert!(lower > 0 && upper > 0, "lower {lower}, upper {upper}");
}

#[test]
fn newton_steps_per_level_stay_bounded_as_the_ball_is_refined() {
    // Bueler's ball: nonzero boundary values, lifted into each level's start.
    let mut finest_steps = Vec::new();
    for refine in [3, 4, 5] {
        let r = format!("mesh.refine={refine}");
        let (mg, active_set) = multigrid_and_active_set(
            "pipelines/scenes/peers/ball.toml",
            &["mesh.n=4", &r, "solver.tol=1e-10"],
        );
        assert_same_solution(&format!("ball, refine {refine}"), &mg, &active_set, 1e-10);
        let steps = newton_steps(&mg);
        assert!(
            steps.iter().all(|&s| s <= 10),
            "refine {refine}: Newton steps per level {steps:?}"
        );
        finest_steps.push(*steps.last().unwrap());
    }
    // Measured on the finest level at 33², 65², 129²: see the output.
    eprintln!("ball: finest-level Newton steps {finest_steps:?}");
}

#[test]
fn each_level_starts_on_the_finer_obstacle_where_the_coarser_one_touches() {
    // The ball's obstacle is curved: the interpolant of a coarse solution
    // lying on it misses the finer obstacle by O(H²) at the new vertices.
    // Started from that interpolant alone, the first Newton step of the
    // finest level (129²) takes 784 of its 3096 contact rows out of contact
    // and the second puts 718 back; started on the finer obstacle, the
    // first step moves the rim only: 68 rows.
    let (mg, _) = multigrid_and_active_set(
        "pipelines/scenes/peers/ball.toml",
        &["mesh.n=4", "mesh.refine=5", "solver.tol=1e-10"],
    );
    let history = &mg.history;
    let (levels, changes) = (
        history.column("level").unwrap(),
        history.column("active_changes").unwrap(),
    );
    let finest = *levels.last().unwrap();
    let first = levels.iter().position(|&l| l == finest).unwrap();
    // The level's start is its first row; its first step's changes are the next.
    let first_step_changes = changes[first + 1];
    let contact_rows = mg.contact().iter().filter(|&&c| c).count();
    assert_eq!(contact_rows, 3096);
    assert!(
        first_step_changes <= 0.05 * contact_rows as f64,
        "the finest level's first step changed {first_step_changes} of {contact_rows} contact rows"
    );
}

#[test]
fn the_multigrid_method_refuses_what_it_cannot_solve() {
    let refusal = |path: &str, overrides: &[&str]| {
        let overrides: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
        Scene::load(&manifest_path(path), &overrides)
            .unwrap_err()
            .to_string()
    };
    let disk = "pipelines/scenes/obstacle-disk.toml";
    let e = refusal(
        disk,
        &["solver.method=multigrid", "mesh.refine=2", "element=p2-p1"],
    );
    assert!(
        e.contains("solver.method") && e.contains("p1b-p0") && e.contains("p2-p1"),
        "{e}"
    );
    let e = refusal(disk, &["solver.method=multigrid"]);
    assert!(
        e.contains("solver.method") && e.contains("mesh.refine"),
        "{e}"
    );
    let e = refusal(disk, &["mesh.refine=13"]);
    assert!(e.contains("mesh.refine") && e.contains("13"), "{e}");
    let e = refusal(
        "pipelines/scenes/naghdi-hypar.toml",
        &["solver.method=multigrid", "mesh.refine=1"],
    );
    assert!(e.contains("solver.method") && e.contains("naghdi"), "{e}");
}

#[test]
fn a_refined_mesh_is_written_and_read_back_as_it_is() {
    let s = scene(
        "pipelines/scenes/obstacle-disk.toml",
        &["mesh.n=4", "mesh.refine=2"],
    );
    let dir = tempfile::tempdir().unwrap();
    let msh = dir.path().join("mesh.msh");
    let hierarchy = scene_hierarchy(&s, &msh).unwrap();
    write_refined_msh(&s, &hierarchy, &msh).unwrap();
    let written = hierarchy.finest();
    let read = Mesh::read_msh(&msh).unwrap();
    assert_eq!(read.vertices, written.vertices);
    assert_eq!(read.triangles, written.triangles);
    let edges = |m: &Mesh| -> Vec<([usize; 2], i32)> {
        m.boundary_edges
            .iter()
            .map(|e| (e.vertices, e.tag))
            .collect()
    };
    assert_eq!(edges(&read), edges(written));
    assert_eq!(read.physical_names, written.physical_names);
    // 16 points per quarter circle of radius 1, all on the circle.
    let boundary = written.boundary_vertex_mask(None);
    let off = (0..written.n_vertices())
        .filter(|&v| boundary[v])
        .map(|v| (written.vertices[v][0].hypot(written.vertices[v][1]) - 1.0).abs())
        .fold(0.0, f64::max);
    assert!(
        off <= 1e-12,
        "a boundary vertex lies {off:e} off the circle"
    );
}
