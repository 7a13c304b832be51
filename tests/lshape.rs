//! The re-entrant corner case of issue 14 (pipelines/scenes/lshape*.toml,
//! docs/formulation.md §8): the scene's manufactured solution solves the
//! obstacle problem; the estimator is reliable and efficient on it at every
//! adaptive step (both pairs); the adaptive mesh is graded toward the corner;
//! Uzawa starts from the multiplier carried to the next mesh.

mod common;

use common::{assert_effectivity_per_step, solve, solve_scene, text};
use obstacle_fem::mesh::Mesh;
use obstacle_fem::output::{read_steps, ResultData};
use obstacle_fem::pipeline::{
    assemble, result_data, scene_mesh, setup_model, solver_options, warm_start,
};
use obstacle_fem::scene::Scene;
use obstacle_fem::solvers::{SolveReport, SolverOptions};
use obstacle_fem::transfer::prolong_dofs;
use std::path::{Path, PathBuf};

fn scene_file(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("pipelines/scenes/{name}.toml"))
}

/// On a grid of points of Ω (off the corner): u ≥ ψ, λ ≥ 0, λ (u − ψ) = 0,
/// u = ψ exactly on the contact disk, −Δu = g + λ (five-point differences,
/// h = 1e-3, error ≤ 2e-4 for r ≥ 0.1), the boundary value is u, and the
/// singular part r^(2/3) sin(2θ/3) vanishes on both edges at the corner and
/// equals r^(2/3) on the bisector θ = 3π/4.
#[test]
fn the_manufactured_solution_solves_the_obstacle_problem() {
    let scene = Scene::load(&scene_file("lshape"), &[]).unwrap();
    let exact = scene.output.exact.as_ref().expect("[output.exact]");
    let (u, lambda) = (|p| exact.u.eval(p), |p| exact.lambda.eval(p));
    let psi = |p| {
        scene
            .obstacle
            .as_ref()
            .unwrap()
            .lower
            .as_ref()
            .unwrap()
            .eval(p)
    };
    let g = |p| scene.load.as_ref().unwrap().g.as_ref().unwrap().eval(p);
    let g_d = scene.mesh.dirichlet_value.as_ref().unwrap();
    let smooth = |[x, y]: [f64; 2]| 0.25 * (1.0 - x * x) * (1.0 - y * y);
    let in_omega = |[x, y]: [f64; 2]| x.abs() < 1.0 && y.abs() < 1.0 && !(x >= 0.0 && y <= 0.0);
    let d2 = |[x, y]: [f64; 2]| (x + 0.5).powi(2) + (y - 0.5).powi(2);
    let (mut contact, mut checked) = (0, 0);
    let h = 1e-3;
    for i in 0..=80 {
        for j in 0..=80 {
            let p = [
                -0.99 + 1.98 * i as f64 / 80.0,
                -0.99 + 1.98 * j as f64 / 80.0,
            ];
            if !in_omega(p) || p[0].hypot(p[1]) < 0.1 {
                continue;
            }
            let (gap, l) = (u(p) - psi(p), lambda(p));
            assert!(
                gap >= 0.0 && l >= 0.0 && l * gap == 0.0,
                "{p:?}: gap {gap}, λ {l}"
            );
            if d2(p) < 0.09 {
                assert_eq!(gap, 0.0, "{p:?}: ψ ≠ u on the contact disk");
                assert_eq!(l, 4.0);
                contact += 1;
            } else {
                assert!(gap > 0.0, "{p:?}: ψ = u off the contact disk");
            }
            // −Δu = g + λ, off the contact circle (λ and g jump there).
            let near_circle = (d2(p).sqrt() - 0.3).abs() < 2.0 * h;
            let stencil = [[h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]];
            if !near_circle && stencil.iter().all(|s| in_omega([p[0] + s[0], p[1] + s[1]])) {
                let laplacian = stencil
                    .iter()
                    .map(|s| u([p[0] + s[0], p[1] + s[1]]) - u(p))
                    .sum::<f64>()
                    / (h * h);
                let residual = -laplacian - g(p) - l;
                assert!(residual.abs() < 1e-3, "{p:?}: −Δu − g − λ = {residual}");
                checked += 1;
            }
            assert_eq!(g_d.eval(p), u(p));
        }
    }
    assert!(
        contact > 50 && checked > 3000,
        "{contact} contact points, {checked} checked"
    );
    for t in [0.01, 0.3, 0.999] {
        // The edges at the corner: y = 0 (x > 0) and x = 0 (y < 0).
        for p in [[t, 0.0], [0.0, -t]] {
            let singular = u(p) - smooth(p);
            assert!(singular.abs() < 1e-15, "{p:?}: {singular}");
        }
        let p = [-t / 2f64.sqrt(), t / 2f64.sqrt()];
        let singular = u(p) - smooth(p);
        assert!(
            (singular - t.powf(2.0 / 3.0)).abs() < 1e-14,
            "{p:?}: {singular}"
        );
    }
}

/// Both pairs to ~12000 unknowns: effectivity η / ‖∇(u − u_h)‖ in [1, 10] at
/// every step; the last mesh is graded toward the corner: the triangles at
/// (0, 0) are more than 4× smaller than those of a uniform mesh of as many
/// triangles (longest edges compared) and 10× smaller than the last mesh's
/// largest (a marked triangle is only halved once per step: 6–8 steps here).
#[test]
fn estimator_is_reliable_and_grades_the_mesh_toward_the_corner() {
    let dir = tempfile::tempdir().unwrap();
    for element in ["p1b-p0", "p2-p1"] {
        let out = dir.path().join(format!("{element}.h5"));
        let set = format!("element=\"{element}\"");
        let o = solve_scene(
            "lshape-adapt",
            &out,
            &[&set, "adapt.max_dofs=12000", "output.plots=[]"],
        );
        assert!(o.status.success(), "{}", text(&o));
        let steps = read_steps(&out).unwrap();
        assert!(steps.len() >= 4, "{element}: {} steps", steps.len());
        assert_effectivity_per_step(element, &steps);
        let last = steps.last().unwrap();
        let longest = |t: &[usize; 3]| {
            (0..3)
                .map(|i| {
                    let (a, b) = (last.vertices[t[i]], last.vertices[t[(i + 1) % 3]]);
                    (a[0] - b[0]).hypot(a[1] - b[1])
                })
                .fold(0.0, f64::max)
        };
        let corner = last
            .vertices
            .iter()
            .position(|v| v[0] == 0.0 && v[1] == 0.0)
            .expect("the corner is a vertex");
        let at_corner = last
            .triangles
            .iter()
            .filter(|t| t.contains(&corner))
            .map(longest)
            .fold(0.0, f64::max);
        let largest = last.triangles.iter().map(longest).fold(0.0, f64::max);
        // meshes/lshape.geo with n: 6 n² triangles, longest edge √2 / n.
        let uniform_h = (12.0 / last.triangles.len() as f64).sqrt();
        println!(
            "{element}: corner h {at_corner:.3e}, uniform h {uniform_h:.3e}, largest {largest:.3e}"
        );
        assert!(
            at_corner < 0.25 * uniform_h,
            "{element}: corner h {at_corner} vs uniform {uniform_h}"
        );
        assert!(
            at_corner < 0.1 * largest,
            "{element}: corner h {at_corner} vs largest {largest}"
        );
    }
}

/// One Uzawa solve of the L-shape on `mesh.n = n`, cold or started from a
/// run's `/dofs` carried to this mesh (what the adaptive loop carries):
/// its report, result data and mesh.
fn uzawa_on(
    n: i64,
    coarse: Option<(&ResultData, &Mesh)>,
    dir: &Path,
) -> (SolveReport, ResultData, Mesh) {
    let overrides: Vec<String> = [
        "solver.method=\"uzawa\"",
        "solver.alpha=\"auto\"",
        "solver.step_form=\"mean\"",
        "solver.tol=1e-8",
        "solver.max_iter=100000",
        "output.plots=[]",
    ]
    .iter()
    .map(|s| s.to_string())
    .chain([format!("mesh.n={n}")])
    .collect();
    let scene = Scene::load(&scene_file("lshape"), &overrides).unwrap();
    let mesh = scene_mesh(&scene, &dir.join(format!("n{n}.msh"))).unwrap();
    let system = setup_model(&scene, &mesh).unwrap();
    let problem = assemble(&scene, &mesh, system.as_ref()).unwrap();
    let carried = coarse.map_or(Vec::new(), |(data, coarse_mesh)| {
        prolong_dofs(data, coarse_mesh, &mesh)
    });
    let start = warm_start(system.as_ref(), &problem, &carried).unwrap();
    assert_eq!(start.is_some(), coarse.is_some(), "the warm start is built");
    // The loop's options start Uzawa cold: give it the carried λ here.
    let lambda = start.as_ref().map(|s| s.lambda.clone());
    let mut options = solver_options(&scene.solver, scene.model, start, false);
    let SolverOptions::Uzawa(uzawa) = &mut options else {
        panic!("the scene asks for Uzawa")
    };
    uzawa.initial_lambda = lambda;
    let report = solve(&problem, &options, &[]).unwrap();
    assert!(
        report.converged,
        "n = {n}: {} iterations",
        report.iterations
    );
    let (data, _) = result_data(&scene, system.as_ref(), &problem, &report).unwrap();
    drop(system);
    (report, data, mesh)
}

/// Uzawa takes an initial multiplier: from the n = 16 solution's own λ it
/// stops at once, at the same u. From the n = 8 solution carried to n = 16
/// (what the adaptive loop would pass) it needs more iterations than from
/// zero, measured here and in docs/formulation.md §8: the loop starts Uzawa cold.
#[test]
fn uzawa_warm_start_is_taken_and_measured() {
    let dir = tempfile::tempdir().unwrap();
    let coarse = uzawa_on(8, None, dir.path());
    let cold = uzawa_on(16, None, dir.path());
    let (carried, _, _) = uzawa_on(16, Some((&coarse.1, &coarse.2)), dir.path());
    let (again, _, _) = uzawa_on(16, Some((&cold.1, &cold.2)), dir.path());
    let cold = cold.0;
    println!(
        "Uzawa on n = 16 to KKT 1e-8: {} iterations cold, {} from the carried n = 8 λ, {} from its own λ",
        cold.iterations, carried.iterations, again.iterations
    );
    assert!(
        again.iterations <= 2,
        "from its own λ: {} iterations",
        again.iterations
    );
    assert!(
        carried.iterations > cold.iterations,
        "the carried λ now pays: update §8 and the loop"
    );
    for warm in [&carried, &again] {
        let difference = cold
            .x
            .iter()
            .zip(&warm.x)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(difference < 1e-6, "cold and warm u differ by {difference}");
    }
}
