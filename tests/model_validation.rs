//! Problems a model refuses at setup, before assembling or solving, with an
//! error naming the scene key (issue 16): no Dirichlet part, an obstacle
//! above the boundary values, a floating shell, errors against an exact
//! solution that does not apply. Unchecked, each would reach the solver and
//! fail there with a message about a factorisation, or report nonsense.

mod common;
use common::{manifest_path, solve_scene, text};

/// Runs `solve` on a thesis scene with overrides; the output and whether a
/// result file was written.
fn solve(scene: &str, overrides: &[&str]) -> (std::process::Output, bool) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.h5");
    let o = solve_scene(scene, &out, overrides);
    (o, out.exists())
}

/// Checks that the run was refused with every phrase of `expect` and wrote nothing.
fn assert_refused(scene: &str, overrides: &[&str], expect: &[&str]) {
    let (o, written) = solve(scene, overrides);
    let t = text(&o);
    println!("{overrides:?}: {t}");
    assert!(!o.status.success(), "{overrides:?} ran: {t}");
    assert!(!written, "{overrides:?} wrote a result");
    for phrase in expect {
        assert!(
            t.contains(phrase),
            "{overrides:?}: `{phrase}` missing from: {t}"
        );
    }
    assert!(
        !t.contains("factoris") && !t.contains("Cholesky") && !t.contains("panicked"),
        "{t}"
    );
}

#[test]
fn a_dirichlet_part_must_be_a_boundary_part() {
    // "domain" is the disk's physical surface, not a boundary line: before,
    // no dof was fixed and the Cholesky factorisation failed.
    assert_refused(
        "obstacle-disk",
        &["mesh.dirichlet=[\"domain\"]", "mesh.h=0.4"],
        &["mesh.dirichlet", "not a part of the boundary", "boundary"],
    );
}

#[test]
fn an_obstacle_above_the_membranes_boundary_values_is_infeasible() {
    // φ = 1.5 − r² is 0.5 > 0 = u on the circle.
    assert_refused(
        "obstacle-disk",
        &["obstacle.height=1.5", "mesh.h=0.4"],
        &[
            "field `obstacle`",
            "infeasible",
            "Dirichlet boundary",
            "5.0",
        ],
    );
    // Touching the boundary (φ = 0 on the circle) is feasible and solves.
    let (o, written) = solve(
        "obstacle-disk",
        &["obstacle.height=1.0", "mesh.h=0.4", "output.plots=[]"],
    );
    assert!(o.status.success() && written, "{}", text(&o));
}

#[test]
fn exact_errors_apply_to_the_unit_disk_only() {
    let square = format!(
        "mesh.geo={}",
        manifest_path("meshes/rectangle.geo").display()
    );
    // The unit square is not the disk: errors against the disk's solution
    // were printed before.
    assert_refused(
        "obstacle-disk",
        &[&square, "mesh.h=0.25", "obstacle.height=-0.1"],
        &["output.errors", "not the unit disk", "radius"],
    );
    // No radial solution for these data (4k < g).
    assert_refused(
        "obstacle-disk",
        &["load.g=8", "mesh.h=0.4"],
        &["output.errors", "no radial solution"],
    );
    // Without errors the same square solves.
    let (o, written) = solve(
        "obstacle-disk",
        &[
            &square,
            "mesh.h=0.25",
            "obstacle.height=-0.1",
            "output.errors=false",
            "output.plots=[]",
        ],
    );
    assert!(o.status.success() && written, "{}", text(&o));
}

#[test]
fn a_floating_shell_is_refused_naming_the_free_directions() {
    assert_refused(
        "naghdi-hypar",
        &["shell.clamped=[]", "mesh.n=4"],
        &["shell.clamped", "u1 (e1), u2 (e2), u3 (e3)", "rigidly"],
    );
    // Held along e3 only (simple support of u3 alone): e1 and e2 are free.
    assert_refused(
        "naghdi-hypar",
        &[
            "shell.clamped=[]",
            "shell.boundary=[{part=\"se\", condition=\"fixed\", fix=[\"u3\"]}]",
            "mesh.n=4",
        ],
        &["u1 (e1), u2 (e2)", "rigidly"],
    );
}
