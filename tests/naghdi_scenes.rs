//! The Naghdi shell through the whole pipeline (scene → gmsh → assembly →
//! solver → HDF5): the thesis' second test (`naghdi-hypar`, docs/formulation.md §2) and its
//! obstacle-free twin, the plate reduction, edge loads, and the checks a
//! scene gets before anything is solved.

mod common;

use common::{
    assert_one_error, field, mirror_map, root_attr, run_obstacle, scene_arg, solver_attr,
};

use obstacle_fem::output::{read_result, AttrValue};
use obstacle_fem::pipeline::RunSummary;
use obstacle_fem::run::run_scene;
use obstacle_fem::scene::Scene;
use obstacle_fem::Error;
use std::path::Path;

const HYPAR: &str = "pipelines/scenes/naghdi-hypar.toml";
const FREE: &str = "pipelines/scenes/naghdi-hypar-free.toml";

fn scene(path: &str, overrides: &[&str]) -> Result<Scene, Error> {
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    Scene::load(Path::new(path), &o)
}

fn run(path: &str, dir: &Path, name: &str, overrides: &[&str]) -> Result<RunSummary, Error> {
    run_scene(
        &scene(path, overrides)?,
        &dir.join(format!("{name}.h5")),
        false,
    )
}

fn history(summary: &RunSummary, column: &str, iteration: usize) -> f64 {
    summary.history.column(column).expect(column)[iteration - 1]
}

/// The thesis' shell as the thesis ran it: α = 0.01 (integral form), stop on
/// ‖λ^{k+1} − λ^k‖_{L²} < 0.01. Table 5.5 gives the gap at the origin after
/// 100 iterations as 0.0317884; ours is 0.03189 (0.3% apart). Its 6119 dofs
/// and the ranges of u are checked, and everything the result file records.
#[test]
fn thesis_run_reproduces_table_5_5_at_100_iterations() {
    let dir = tempfile::tempdir().unwrap();
    let s = run(HYPAR, dir.path(), "hypar", &[]).unwrap();
    assert_eq!(s.n_dofs, 6119, "thesis dof count");
    assert_eq!((s.n_vertices, s.n_triangles), (289, 512));
    assert_eq!(s.stop_reason, "thesis");
    let gap100 = history(&s, "gap_origin", 100);
    println!(
        "thesis run: {} iterations; gap at origin after 100/150/350: {gap100:.6} {:.6} {:.6}; ‖Δλ‖ {:.6} {:.6} {:.6}",
        s.iterations,
        history(&s, "gap_origin", 150),
        history(&s, "gap_origin", 350),
        history(&s, "dual_step", 100),
        history(&s, "dual_step", 150),
        history(&s, "dual_step", 350),
    );
    assert!(
        (gap100 / 0.0317884 - 1.0).abs() < 0.01,
        "gap(100) = {gap100}"
    );
    // The thesis stop: our count is 803 (the thesis' 686 is not reproducible, docs/formulation.md §3).
    assert!((700..=900).contains(&s.iterations), "{}", s.iterations);
    let file = read_result(&s.result_file).unwrap();
    let u = field(&file, "u");
    let u3: Vec<f64> = u.iter().skip(2).step_by(3).copied().collect();
    let u3_min = u3.iter().fold(f64::INFINITY, |m, v| m.min(*v));
    let u1_max = u.iter().step_by(3).fold(0.0f64, |m, v| m.max(v.abs()));
    // Thesis: u3 ∈ [−1.09, 0.029], |u_β| ≤ 0.005.
    assert!((-1.05..-0.95).contains(&u3_min), "u3 min {u3_min}");
    assert!((0.004..0.006).contains(&u1_max), "u1 max {u1_max}");
    assert_eq!(
        root_attr(&file, "simulated"),
        AttrValue::Str("clamping,body-force,tangency-multiplier,contact".into())
    );
    for plot in [
        "u1",
        "u2",
        "u3",
        "constraint",
        "contact",
        "lambda",
        "history",
    ] {
        assert!(
            dir.path().join(format!("hypar.{plot}.png")).exists(),
            "{plot}"
        );
    }
    assert!(dir.path().join("hypar.constraint-profiles.png").exists());
    assert!(
        !dir.path().join("hypar.gap.png").exists(),
        "only the plots asked for"
    );
}

/// Run to the KKT tolerance 1e-8: no penetration, λ ≥ 0, complementarity,
/// the origin in (the closure of) the contact zone, mirror symmetry of the
/// converged solution, the tangency at round-off.
#[test]
fn converged_contact_solution() {
    let dir = tempfile::tempdir().unwrap();
    let s = run(
        HYPAR,
        dir.path(),
        "conv",
        &[
            "solver.stop=kkt",
            "solver.tol=1e-8",
            "solver.alpha=\"auto\"",
            "output.plots=[]",
        ],
    )
    .unwrap();
    let m = &s.measures;
    println!(
        "converged: {} iterations, {:.2} s, kkt {:.2e}, penetration {:.2e}, complementarity {:.2e}, stationarity {:.2e}, tangency {:.2e}, active {}",
        s.iterations, s.wall_seconds, m.kkt, m.penetration, m.complementarity, m.stationarity, m.tangency, m.active
    );
    assert!(s.converged && m.kkt <= 1e-8);
    let file = read_result(&s.result_file).unwrap();
    let (lambda, gap) = (field(&file, "lambda"), field(&file, "gap_mean"));
    // The scales of the relative KKT measures (docs/formulation.md §4): gaps against
    // ‖Φ_h‖∞ = 2.0002, complementarity against that times ‖λ‖∞.
    let gap_scale = field(&file, "phi")
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()));
    let lambda_scale = lambda.iter().fold(0.0f64, |m, v| m.max(*v));
    assert!((gap_scale - 2.0).abs() < 1e-3);
    for (t, (&l, &g)) in lambda.iter().zip(gap).enumerate() {
        assert!(l >= 0.0, "λ_{t} = {l}");
        assert!(g >= -1e-8 * gap_scale, "penetration {g} on triangle {t}");
        assert!(
            (l * g).abs() <= 1e-8 * gap_scale * lambda_scale,
            "λ ḡ = {} on {t}",
            l * g
        );
    }
    // The origin is a vertex of a contact triangle.
    let origin = file
        .vertices
        .iter()
        .position(|v| v[0].abs() + v[1].abs() < 1e-9)
        .unwrap();
    let touching = file
        .triangles
        .iter()
        .enumerate()
        .filter(|(t, tri)| tri.contains(&origin) && lambda[*t] > 0.0)
        .count();
    assert!(touching > 0, "the origin is not in the contact zone");
    // Mirror symmetry: u3 even in x and y, u1 odd in x and even in y.
    let u = field(&file, "u");
    let scale = u.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for (map, parity1) in [
        (mirror_map(&file.vertices, |v| [-v[0], v[1]], 1e-9), -1.0),
        (mirror_map(&file.vertices, |v| [v[0], -v[1]], 1e-9), 1.0),
    ] {
        for (v, &w) in map.iter().enumerate() {
            assert!((u[3 * v + 2] - u[3 * w + 2]).abs() < 1e-6 * scale);
            assert!((u[3 * v] - parity1 * u[3 * w]).abs() < 1e-6 * scale);
        }
    }
    assert!(m.tangency < 1e-9, "‖BU‖ = {}", m.tangency);
}

/// The shell without obstacle: one linear solve, no λ, stationarity and
/// ‖BU‖ at round-off, the contact effects absent from the file.
#[test]
fn free_shell_is_one_linear_solve() {
    let dir = tempfile::tempdir().unwrap();
    let s = run(FREE, dir.path(), "free", &[]).unwrap();
    assert_eq!(s.algorithm, "linear");
    assert_eq!(s.iterations, 1);
    assert_eq!(s.n_dofs, 7 * (289 + 512));
    assert!(
        s.measures.stationarity < 1e-10,
        "{}",
        s.measures.stationarity
    );
    assert!(s.measures.tangency < 1e-10, "{}", s.measures.tangency);
    let file = read_result(&s.result_file).unwrap();
    assert!(file.data.fields.iter().all(|f| f.name != "lambda"));
    assert!(file.data.history.is_empty());
    assert_eq!(
        root_attr(&file, "simulated"),
        AttrValue::Str("clamping,body-force,tangency-multiplier".into())
    );
    let u3_min = file
        .data
        .root_attrs
        .iter()
        .find(|(k, _)| k == "u3_min")
        .unwrap();
    // The free hypar on 16×16 (tests/naghdi.rs): u3 min −1.663.
    assert!(matches!(u3_min.1, AttrValue::F64(v) if (v + 1.663).abs() < 1e-3));
}

/// A flat chart eliminates r3 and ψ (r·a3 = r3): a symmetric positive definite
/// system, solved by Cholesky, with the same solution as the full (U, ψ)
/// saddle problem: r3 = 0 is what b(U, χ) = 0 enforces there.
#[test]
fn plate_reduction_matches_the_saddle_problem() {
    let dir = tempfile::tempdir().unwrap();
    let plate = [
        "shell.chart={kind=\"plate\", height=1.0}",
        "shell.thickness=4.0",
    ];
    let reduced = run(FREE, dir.path(), "plate", &plate).unwrap();
    let file = read_result(&reduced.result_file).unwrap();
    assert_eq!(
        root_attr(&file, "simulated"),
        AttrValue::Str("clamping,body-force,tangency-eliminated".into())
    );
    assert_eq!(reduced.measures.tangency, 0.0, "no ψ rows");
    // The same plate as a general chart (a hyperbolic paraboloid of huge r is
    // flat to 1e-16): the saddle problem keeps ψ.
    let saddle = run(
        FREE,
        dir.path(),
        "plate-saddle",
        &[
            "shell.chart={kind=\"hyperbolic-paraboloid\", r=1e12, offset=1.0}",
            "shell.thickness=4.0",
        ],
    )
    .unwrap();
    let other = read_result(&saddle.result_file).unwrap();
    let (a, b) = (field(&file, "u"), field(&other, "u"));
    let scale = a.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let diff = a
        .iter()
        .zip(b)
        .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
    println!("plate reduction vs saddle: max |Δu| = {diff:e} (scale {scale:e})");
    assert!(diff < 1e-8 * scale, "{diff:e}");
    let r = field(&file, "r");
    assert!(r.iter().skip(2).step_by(3).all(|v| *v == 0.0), "r3 = 0");
}

/// Edge loads: a traction N on a free edge of a plate adds ∫ N·v ℓ dσ; with a
/// flat chart ℓ = 1, and the sum over the u-component rows is N·|γ1|.
/// The clamped part must not carry one (rejected with the field named).
#[test]
fn edge_traction_on_a_free_part() {
    let dir = tempfile::tempdir().unwrap();
    let base = [
        "shell.chart={kind=\"plate\", height=1.0}",
        "shell.clamped=[\"sw\", \"se\"]",
        "load.f=[0.0, 0.0, 0.0]",
    ];
    let mut with_edge = base.to_vec();
    with_edge.push("load.edge=[{part=\"ne\", traction=[0.0, 0.0, -1.0]}]");
    let s = run(FREE, dir.path(), "edge", &with_edge).unwrap();
    let file = read_result(&s.result_file).unwrap();
    assert!(matches!(root_attr(&file, "simulated"), AttrValue::Str(t) if t.contains("edge-loads")));
    // Pushed down on the ne edge: the free corner region deflects downwards.
    let u = field(&file, "u");
    let u3_min = u.iter().skip(2).step_by(3).fold(0.0f64, |m, v| m.min(*v));
    assert!(u3_min < 0.0);
    let mut clamped_edge = base.to_vec();
    clamped_edge.push("load.edge=[{part=\"sw\", traction=[0.0, 0.0, -1.0]}]");
    let e = scene(FREE, &clamped_edge).unwrap_err().to_string();
    assert!(
        e.contains("load.edge[0].part") && e.contains("clamped"),
        "{e}"
    );
}

/// An obstacle the clamped boundary would have to penetrate (the plane
/// raised above the clamped corners) is infeasible: reported before any
/// solve, and no result file is written.
#[test]
fn infeasible_obstacle_is_detected_before_iterating() {
    let dir = tempfile::tempdir().unwrap();
    let e = run(HYPAR, dir.path(), "bad", &["obstacle.height=0.5"])
        .unwrap_err()
        .to_string();
    println!("{e}");
    assert!(
        e.contains("infeasible") && e.contains("field `obstacle`"),
        "{e}"
    );
    assert!(!dir.path().join("bad.h5").exists());
}

/// Bad shell input names the file and the field.
#[test]
fn bad_shell_input() {
    for (o, field) in [
        ("shell.poisson=0.5", "shell.poisson"),
        ("shell.young=-1", "shell.young"),
        ("shell.thickness=0", "shell.thickness"),
        ("shell.rho=-1", "shell.rho"),
        ("shell.rho=nan", "shell.rho"),
        (
            "shell.chart={kind=\"cylinder\", radius=0, height=1}",
            "shell.chart",
        ),
        ("shell.chart={kind=\"cone\"}", "shell.chart"),
        ("element=p2-p1", "element"),
        ("load.g=1.0", "load.g"),
        ("obstacle.shape=paraboloid", "obstacle.shape"),
        ("output.plots=[\"u\"]", "output.plots"),
        ("load.f=[0.0, inf, 0.0]", "load.f[1]"),
        ("obstacle.multiplier=\"p2\"", "obstacle.multiplier"),
        ("obstacle.multiplier=1", "obstacle.multiplier"),
    ] {
        let e = scene(HYPAR, &[o]).unwrap_err().to_string();
        assert!(
            e.contains("naghdi-hypar.toml") && e.contains(field),
            "{o}: {e}"
        );
    }
}

/// The active-set starts on 32×32, same solution, measured Newton solves:
/// plain PDAS from the free solution 27; nested iteration (the 16×16
/// solution as start) 18; depth bisection 10; the interior-point start (the
/// shell's default, "auto") 13 — it wins from n = 128 on (14 against 20;
/// 16 against 38 at n = 256: docs/work-precision.md, "The interior-point
/// start"), which no test size shows; here its count is bounded and
/// `/solver/cold_start` names it.
#[test]
fn active_set_starts_reach_the_same_solution_in_fewer_steps() {
    let dir = tempfile::tempdir().unwrap();
    let run_with = |label: &str, set: &[&str]| {
        let mut sets = vec![
            "mesh.n=32",
            "solver.method=active-set",
            "solver.tol=1e-10",
            "output.plots=[]",
        ];
        sets.extend_from_slice(set);
        let s = run(HYPAR, dir.path(), label, &sets).unwrap();
        assert!(s.converged);
        (s.iterations, read_result(&s.result_file).unwrap())
    };
    let (plain, a) = run_with("plain", &["solver.cold_start=\"plain\""]);
    let (nested, b) = run_with("nested", &["solver.nested=true"]);
    let (bisection, c) = run_with("bisection", &["solver.cold_start=\"depth-bisection\""]);
    let (interior, d) = run_with("auto", &[]);
    println!(
        "active set on 32×32: {plain} steps plain, {nested} nested, {bisection} depth bisection, {interior} interior point"
    );
    assert!(
        bisection < nested && nested < plain,
        "{bisection}, {nested}, {plain}"
    );
    assert!(bisection <= 12, "{bisection}");
    assert!(interior <= 15, "{interior}");
    assert!(
        matches!(solver_attr(&d, "cold_start"), AttrValue::Str(s) if s == "interior-point"),
        "{:?}",
        solver_attr(&d, "cold_start")
    );
    for other in [&b, &c, &d] {
        let (la, lb) = (field(&a, "lambda"), field(other, "lambda"));
        let scale = la.iter().fold(0.0f64, |m, v| m.max(*v));
        let diff = la
            .iter()
            .zip(lb)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
        assert!(diff < 1e-8 * scale, "{diff:e}");
    }
}

/// `obstacle.multiplier = "p1"` on the thesis' element: one multiplier per
/// vertex, the constraint tested with the P1 hats (docs/formulation.md §2).
/// On 32×32 by active-set to KKT 1e-10: λ ≥ 0 and complementary to the
/// mean gap at every vertex; against the default P0 multipliers on the same
/// mesh (measured: contact area 400.4 vs 351.6, force 607.87 vs 607.56,
/// u3 min −1.05220 vs −1.05230) the area is within 15% (the P1 area counts
/// the lumped weight |star|/3 of every contact vertex, half a ring more at
/// the rim), the force within 0.1%, u3 min within 1e-3.
#[test]
fn p1_multipliers_on_the_thesis_element() {
    let dir = tempfile::tempdir().unwrap();
    let solve = |multiplier: &str| {
        let set = format!("obstacle.multiplier=\"{multiplier}\"");
        let s = run(
            HYPAR,
            dir.path(),
            multiplier,
            &[
                "mesh.n=32",
                "solver.method=active-set",
                "solver.tol=1e-10",
                "output.plots=[]",
                &set,
            ],
        )
        .unwrap();
        assert!(
            s.converged && s.measures.kkt <= 1e-10,
            "{multiplier}: {:?}",
            s.measures
        );
        read_result(&s.result_file).unwrap()
    };
    let (p0, p1) = (solve("p0"), solve("p1"));
    let (lambda, gap) = (field(&p1, "lambda"), field(&p1, "gap_mean"));
    assert_eq!(lambda.len(), p1.vertices.len(), "one λ per vertex");
    let gap_scale = field(&p1, "phi").iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let lambda_scale = lambda.iter().fold(0.0f64, |m, v| m.max(*v));
    assert!(lambda_scale > 0.0);
    for (i, (&l, &g)) in lambda.iter().zip(gap).enumerate() {
        assert!(l >= 0.0, "λ_{i} = {l}");
        assert!(g >= -1e-10 * gap_scale, "penetration {g} at vertex {i}");
        assert!(
            (l * g).abs() <= 1e-10 * gap_scale * lambda_scale,
            "λ ḡ = {} at vertex {i}",
            l * g
        );
    }
    let attr = |file, name| match root_attr(file, name) {
        AttrValue::F64(v) => v,
        other => panic!("{name}: {other:?}"),
    };
    let rel = |name, tol: f64| {
        let (a, b) = (attr(&p0, name), attr(&p1, name));
        println!("{name}: p0 {a}, p1 {b}");
        assert!((a - b).abs() <= tol * a.abs(), "{name}: p0 {a}, p1 {b}");
    };
    rel("contact_area", 0.15);
    rel("contact_force", 1e-3);
    rel("u3_min", 1e-3);
}

/// `obstacle.multiplier` where it does not apply: the membrane (its pair
/// comes with `element`), P0 with `p2b-psri`, P1 in the FreeFEM twin of the
/// thesis' element (refused before FreeFem++ runs); each error names the key.
#[test]
fn multiplier_option_refused_where_it_does_not_apply() {
    for (scene_path, o, words) in [
        (
            "pipelines/scenes/obstacle-disk.toml",
            "obstacle.multiplier=\"p1\"",
            "membrane",
        ),
        (
            "pipelines/scenes/shell/hypar-psri.toml",
            "obstacle.multiplier=\"p0\"",
            "p2b-psri",
        ),
    ] {
        let e = scene(scene_path, &[o]).unwrap_err().to_string();
        assert!(
            e.contains(scene_path.rsplit('/').next().unwrap())
                && e.contains("obstacle.multiplier")
                && e.contains(words),
            "{o}: {e}"
        );
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ff.h5");
    let o = run_obstacle(&[
        "freefem",
        &scene_arg("naghdi-hypar"),
        "--set",
        "obstacle.multiplier=\"p1\"",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_one_error(
        &o,
        &["naghdi-hypar.toml", "obstacle.multiplier", "P0"],
        "freefem p1",
    );
    assert!(!out.exists());
}
