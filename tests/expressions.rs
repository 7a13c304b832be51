//! Issue 17: expressions in scenes (bad ones named by their key), boundary
//! values, the feasibility check against them, and the two-sided obstacle
//! solved alike by every solver.

mod common;

use common::{assert_one_error, dofs, field, solve_scene, solver_attr};
use obstacle_fem::output::{read_result, AttrValue};

const TWO_SIDED: &str = "peers/two-sided";

fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

/// A bad expression: one error naming the key, the position and the reason;
/// no result file.
#[test]
fn bad_expressions_name_their_key() {
    let dir = tmp();
    let out = dir.path().join("r.h5");
    let cases: [(&[&str], &[&str]); 6] = [
        (
            &["load.g=\"2*(x + \""],
            &["load.g", "character 6", "operand after"],
        ),
        (
            &["load.g=\"-4 + foo(x)\""],
            &["load.g", "character 6", "unknown function `foo`"],
        ),
        (
            &["load.g=\"1/(x - x)\""],
            &["load.g", "is inf at the point"],
        ),
        (
            &["obstacle.lower=\"ln(y + 0.5)\""],
            &[
                "obstacle.lower",
                "NaN",
                "at the point",
                "everywhere on the mesh",
            ],
        ),
        (
            &["mesh.dirichlet_value=\"1/(x*x + y*y - 1)\""],
            &["mesh.dirichlet_value", "inf"],
        ),
        (
            &["obstacle.upper=\"x^\""],
            &["obstacle.upper", "character 2", "operand after"],
        ),
    ];
    for (sets, expected) in cases {
        let o = solve_scene(TWO_SIDED, &out, &[sets[0], "mesh.n=4"]);
        assert_one_error(&o, expected, sets[0]);
        assert!(!out.exists(), "{}: no result after an error", sets[0]);
    }
}

/// The hard inputs of the expression reader, through the command line: deep
/// nesting is an error naming the key (never a stack overflow), blanks never
/// join numbers, a value beyond ±1e100 is refused where it is evaluated, and
/// the documented language (nested calls, clamps) is read.
#[test]
fn hard_expressions_are_read_or_refused_by_key() {
    let dir = tmp();
    let out = dir.path().join("r.h5");
    let nested = |n: usize| "if(x<0,".repeat(n) + "1" + &",2)".repeat(n);
    let deep = format!("load.g=\"{}\"", nested(1000));
    let cases: Vec<(String, Vec<&str>)> = vec![
        (deep, vec!["load.g", "nested more than 200"]),
        (
            "load.g=\"x y\"".into(),
            vec!["load.g", "character 3", "operator"],
        ),
        (
            "load.g=\"1 2\"".into(),
            vec!["load.g", "character 3", "operator"],
        ),
        ("load.g=\"2 .5\"".into(), vec!["load.g", "operator"]),
        (
            "load.g=\"1e200*(1+x)\"".into(),
            vec!["load.g", "1e100", "at the point"],
        ),
    ];
    for (set, expected) in &cases {
        let o = solve_scene(TWO_SIDED, &out, &[set, "mesh.n=4"]);
        assert_one_error(&o, expected, &set[..set.len().min(40)]);
        assert!(!out.exists());
    }
    let hundred = format!("load.g=\"{}\"", nested(100));
    for set in [
        hundred.as_str(),
        "obstacle.upper=\"max(0.1, min(0.15 + 0.1*r^2, 0.2))\"",
        "load.g=\"min(x, min(y, 1)) + atan2(y, atan2(x, 1)) - 2^3^2/64\"",
    ] {
        let o = solve_scene(TWO_SIDED, &out, &[set, "mesh.n=4"]);
        assert!(o.status.success(), "{set}: {}", common::text(&o));
    }
}

/// A scene's exact solution (u, λ and the exact ∇u) is checked where the
/// errors evaluate it: at one point of the degree-10 rule per triangle
/// before anything is solved, and at every point of the rule as the errors
/// integrate it, after the solve; either way nothing is written.
#[test]
fn a_non_finite_exact_solution_is_refused_before_writing() {
    let dir = tmp();
    let out = dir.path().join("r.h5");
    for (set, key) in [
        ("output.exact.u=\"ln(x + 0.5)\"", "output.exact.u"),
        ("output.exact.lambda=\"sqrt(y)\"", "output.exact.lambda"),
        (
            "output.exact.u=\"acos(min(1, 1 + x))\"",
            "output.exact.u (∂u/∂x)",
        ),
    ] {
        let o = solve_scene("lshape", &out, &[set, "mesh.n=4", "output.errors=true"]);
        assert_one_error(&o, &[key, "at the point"], set);
        assert!(!out.exists());
    }
    // The ball's vertices at n = 4 lie on the integers of (−2, 2)², where
    // sin(πx) ≈ 0; the root is not real where |sin(πx)| > 1/2, between them,
    // far from each triangle's first rule point (near a corner).
    let between = "output.exact.lambda=\"sqrt(0.5 - abs(sin(pi*x)))\"";
    let o = solve_scene("peers/ball", &out, &[between, "mesh.n=4"]);
    assert_one_error(&o, &["output.exact.lambda", "NaN at the point"], between);
    assert!(
        !out.exists()
            && !out.with_extension("xdmf").exists()
            && !out.with_extension("msh").exists()
    );
}

/// ψ₁ > ψ₂ somewhere, and boundary values outside [ψ₁, ψ₂]: refused before
/// solving, naming the point.
#[test]
fn infeasible_obstacles_are_refused_before_solving() {
    let dir = tmp();
    let out = dir.path().join("r.h5");
    let o = solve_scene(TWO_SIDED, &out, &["mesh.n=4", "obstacle.upper=\"-0.2\""]);
    assert_one_error(
        &o,
        &["obstacle.upper", "infeasible", "lies above the upper"],
        "crossed",
    );
    // g_D = 0.3 on the circle lies above ψ₂ = 0.25 there.
    let o = solve_scene(TWO_SIDED, &out, &["mesh.n=4", "mesh.dirichlet_value=0.3"]);
    assert_one_error(
        &o,
        &[
            "field `obstacle`",
            "infeasible",
            "Dirichlet boundary",
            "above the upper obstacle",
        ],
        "g_D above ψ₂",
    );
    let o = solve_scene(
        TWO_SIDED,
        &out,
        &["mesh.n=4", "mesh.dirichlet_value=\"-0.3 + 0*x\""],
    );
    assert_one_error(&o, &["infeasible", "below the obstacle"], "g_D below ψ₁");
    // Ordered at every vertex (ψ₂ − ψ₁ = 1e-3 + 0.3 r² − 50 r e^{−400 r²}
    // is 1e-3 at the centre and positive beyond r = 0.15, where the other
    // vertices of n = 4 lie), crossed between them: the bump lifts ψ₁ above
    // ψ₂ around the centre, and P2–P1 tests the bounds by their moments
    // against the centre's hat (3.76e-2 against 1.79e-2).
    let crossed = [
        "mesh.n=4",
        "element=p2-p1",
        "obstacle.lower=\"0.149 - 0.2*r^2 + 50*r*exp(-400*r^2)\"",
        "obstacle.upper=\"0.15 + 0.1*r^2\"",
    ];
    let o = solve_scene(TWO_SIDED, &out, &crossed);
    assert_one_error(
        &o,
        &[
            "field `obstacle.upper`",
            "the bounds' integrated moments cross: infeasible",
            "at the vertex (0.000000, 0.000000)",
            "obstacle.lower's moment",
            "element p2-p1",
        ],
        "moments crossed",
    );
    assert!(!common::text(&o).contains("lies above the upper"));
    assert!(!out.exists());
    // P1⊕B3–P0 tests the interpolants, ordered with the vertex values: solved.
    let mut p1b = crossed;
    p1b[1] = "element=p1b-p0";
    let o = solve_scene(TWO_SIDED, &out, &p1b);
    assert!(o.status.success(), "{}", common::text(&o));
    let r = read_result(&out).unwrap();
    assert!(matches!(
        solver_attr(&r, "converged"),
        AttrValue::Bool(true)
    ));
}

/// Nonzero boundary values are lifted: without an obstacle u = g_D = x + 2y
/// (harmonic) is reproduced to round-off by P2, and the result stores it.
#[test]
fn boundary_values_are_lifted() {
    let dir = tmp();
    let out = dir.path().join("r.h5");
    let o = solve_scene(
        TWO_SIDED,
        &out,
        &[
            "mesh.n=6",
            "element=p2-p1",
            "load.g=0",
            "mesh.dirichlet_value=\"x + 2*y\"",
            "obstacle.lower=\"-5\"",
            "obstacle.upper=\"5\"",
        ],
    );
    assert!(o.status.success(), "{}", common::text(&o));
    let r = read_result(&out).unwrap();
    let u = field(&r, "u");
    let err = r
        .vertices
        .iter()
        .zip(u)
        .map(|(p, u)| (u - (p[0] + 2.0 * p[1])).abs())
        .fold(0.0f64, f64::max);
    assert!(err < 1e-10, "max |u − (x + 2y)| = {err:e}");
}

/// Every solver solves the two-sided problem to its tolerance, with both
/// bounds active, and all find the active-set method's solution.
#[test]
fn two_sided_in_every_solver() {
    let dir = tmp();
    let methods: [&[&str]; 4] = [
        &["solver.method=active-set"],
        &[
            "solver.method=uzawa",
            "solver.alpha=auto",
            "solver.step_form=mean",
        ],
        &["solver.method=uzawa-split"],
        &["solver.method=dual-accelerated"],
    ];
    let mut reference: Option<Vec<f64>> = None;
    for sets in methods {
        let out = dir.path().join(format!("{}.h5", &sets[0][14..]));
        let mut all = vec!["mesh.n=8", "solver.tol=1e-8"];
        all.extend_from_slice(sets);
        let o = solve_scene(TWO_SIDED, &out, &all);
        assert!(o.status.success(), "{sets:?}: {}", common::text(&o));
        let r = read_result(&out).unwrap();
        assert!(
            matches!(solver_attr(&r, "converged"), AttrValue::Bool(true)),
            "{sets:?}"
        );
        let AttrValue::F64(kkt) = solver_attr(&r, "kkt") else {
            panic!("kkt")
        };
        assert!(*kkt <= 1e-8, "{sets:?}: KKT {kkt:e}");
        let (lower, upper) = (field(&r, "lambda_lower"), field(&r, "lambda_upper"));
        let net = field(&r, "lambda");
        assert!(
            lower.iter().filter(|&&l| l > 0.0).count() > 10,
            "{sets:?}: lower bound active"
        );
        assert!(
            upper.iter().filter(|&&l| l > 0.0).count() > 10,
            "{sets:?}: upper bound active"
        );
        // A triangle cannot touch both bounds: net = lower − upper.
        for ((n, l), u) in net.iter().zip(lower).zip(upper) {
            assert!((n - (l - u)).abs() < 1e-12 && l * u == 0.0, "{sets:?}");
        }
        // Both mean gaps ≥ 0 (up to the tolerance, scaled by the obstacle's size).
        for name in ["gap_mean", "gap_upper_mean"] {
            let worst = field(&r, name)
                .iter()
                .copied()
                .fold(f64::INFINITY, f64::min);
            assert!(worst > -1e-6, "{sets:?}: {name} min {worst:e}");
        }
        let u = dofs(&r, "u").to_vec();
        match &reference {
            None => reference = Some(u),
            Some(reference) => {
                let diff = u
                    .iter()
                    .zip(reference)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max);
                assert!(diff < 1e-6, "{sets:?}: max |u − u_active_set| = {diff:e}");
            }
        }
    }
}
