//! Cross-check of the locking-free shell element (PSRI, the element of
//! `pipelines/scenes/shell/*.toml`) against its FreeFEM twin
//! `freefem/naghdi-psri.edp`, end to end through the command line
//! (`obstacle solve`, `obstacle freefem`, `obstacle compare`): both sides
//! read the same mesh file and build the same discrete problem (u and θ in
//! the spaces of the Rust layout, P2 or P2⊕B3; PSRI with the weight rule of
//! forms.rs `psri_weight`, Radon's 7 points and the 3-point Strang–Fix rule;
//! P1 contact multipliers), and the whole coefficient vectors `/dofs/u`,
//! `/dofs/theta` and `/dofs/lambda` (P1), in the same spaces, must agree to
//! 1e-8 relative:
//!
//! * the clamped plate, 8×8, no contact (one linear solve);
//! * the thesis' hyperbolic paraboloid (`shell/hypar-psri.toml`), n = 8, in
//!   contact with the plane, after exactly K = 20 Uzawa iterations with a
//!   fixed α;
//! * the Scordelis–Lo roof quarter (symmetry planes and a diaphragm on the
//!   cylinder chart), n = 4: the scene's boundary conditions reach the
//!   script as `-fix`.
//!
//! The translation of the conditions (`freefem::psri_fix_spec`) is checked
//! on its own, with a symmetry plane `-fix` cannot state (refused).
//!
//! Needs `gmsh`, `FreeFem++` and `libfreefem++` (`make deps`): a missing
//! FreeFEM fails, it is never skipped.

mod common;

use common::{dofs, manifest_path, obstacle, rel_diff, scene_arg, set_args, solver_attr};
use obstacle_fem::freefem::psri_fix_spec;
use obstacle_fem::output::compare::compare_results;
use obstacle_fem::output::{read_result, AttrValue, ResultFile};
use obstacle_fem::pipeline::scene_mesh;
use obstacle_fem::scene::Scene;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Agreement required, relative to the Rust vector's max norm (and L²).
const RTOL: f64 = 1e-8;
const K: usize = 20;
/// The fixed Uzawa step of the contact case: safely below the stability
/// bound (α = auto is about 0.05 on this mesh, mean form); λ is active after
/// 20 steps.
const ALPHA: f64 = 0.02;

/// `obstacle solve` and `obstacle freefem` on the same scene file and
/// overrides; the two result files and the wall times of the two processes.
fn both(dir: &Path, name: &str, scene: &str, extra: &[String]) -> (PathBuf, PathBuf, f64, f64) {
    let rust = dir.join(format!("{name}.rust.h5"));
    let ff = dir.join(format!("{name}.ff.h5"));
    let mut args = vec!["solve".into(), scene.to_string()];
    args.extend_from_slice(extra);
    args.extend(["--quiet".into(), "--out".into(), rust.display().to_string()]);
    let t = Instant::now();
    common::obstacle_solve(&args);
    let rust_seconds = t.elapsed().as_secs_f64();
    let mut args = vec!["freefem".into(), scene.to_string()];
    args.extend_from_slice(extra);
    args.extend(["--out".into(), ff.display().to_string()]);
    let t = Instant::now();
    obstacle(&args);
    let ff_seconds = t.elapsed().as_secs_f64();
    (rust, ff, rust_seconds, ff_seconds)
}

fn space<'a>(r: &'a ResultFile, name: &str) -> &'a str {
    &r.data
        .dof_spaces
        .iter()
        .find(|(n, _)| n == name)
        .unwrap_or_else(|| panic!("/dofs/{name} has no space"))
        .1
}

/// `sets` and the overrides of a run of exactly K Uzawa steps with the fixed
/// α = ALPHA (the thesis stop with a tolerance never met).
fn exactly_k_uzawa_steps(sets: &[&str]) -> Vec<String> {
    let alpha = format!("solver.alpha={ALPHA}");
    let max_iter = format!("solver.max_iter={K}");
    let mut all = sets.to_vec();
    all.extend([
        "solver.method=uzawa",
        &alpha,
        "solver.step_form=mean",
        "solver.stop=thesis",
        "solver.thesis_tol=1e-300",
        &max_iter,
        "output.plots=[]",
    ]);
    set_args(&all)
}

/// Same mesh and edges; the dof vectors `names` in the same spaces and within
/// RTOL (entry by entry, and through `compare` in max and L² norms); the
/// `compare` command agrees. Returns the worst relative difference.
fn assert_agree(rust: &Path, ff: &Path, names: &[&str], label: &str) -> f64 {
    let (a, b) = (read_result(rust).unwrap(), read_result(ff).unwrap());
    assert_eq!(a.vertices, b.vertices, "{label}: vertex order");
    assert_eq!(a.triangles, b.triangles, "{label}: triangle order");
    assert!(a.edges.is_some() && a.edges == b.edges, "{label}: edges");
    let mut worst = 0.0f64;
    for name in names {
        assert_eq!(space(&a, name), space(&b, name), "{label}: space of {name}");
        let (d, i) = rel_diff(dofs(&a, name), dofs(&b, name));
        eprintln!(
            "{label}: dofs/{name:<6} ({} values) max rel {d:.2e} (at {i})",
            dofs(&a, name).len()
        );
        assert!(d <= RTOL, "{label}: dofs/{name} differs by {d:e} at {i}");
        worst = worst.max(d);
    }
    let wanted: Vec<String> = names.iter().map(|s| s.to_string()).collect();
    let rows = compare_results(&a, rust, &b, ff, Some(&wanted)).unwrap();
    for r in &rows {
        assert!(r.worst() <= RTOL, "{label}: {} differs: {r:?}", r.name);
        worst = worst.max(r.worst());
    }
    // The command, on every quantity of both files (fields u, r, … too).
    obstacle(&[
        "compare".into(),
        rust.display().to_string(),
        ff.display().to_string(),
        "--rtol".into(),
        format!("{RTOL:e}"),
    ]);
    worst
}

#[test]
fn clamped_plate_free_matches_freefem() {
    let dir = tempfile::tempdir().unwrap();
    let extra = set_args(&["mesh.n=8", "output.plots=[]"]);
    let (rust, ff, rs, fs) = both(
        dir.path(),
        "plate",
        &scene_arg("shell/plate-clamped"),
        &extra,
    );
    let worst = assert_agree(&rust, &ff, &["u", "theta"], "plate 8×8");
    let r = read_result(&ff).unwrap();
    // Blocks of P2 or P2b: 81 vertices, 208 edges, 128 triangles.
    let (u_space, theta_space) = (space(&r, "u"), space(&r, "theta"));
    assert!(u_space == "P2^3" || u_space == "P2b^3", "{u_space}");
    assert!(
        theta_space == "P2^2" || theta_space == "P2b^2",
        "{theta_space}"
    );
    let n_u = if u_space.starts_with("P2b") {
        81 + 208 + 128
    } else {
        81 + 208
    };
    assert_eq!(dofs(&r, "u").len(), 3 * n_u);
    assert_eq!(
        solver_attr(&r, "stop_reason"),
        &AttrValue::Str("linear".into())
    );
    // The plate bends (u3 at the vertices): the test compares something.
    let u3_min = dofs(&r, "u")[2 * n_u..2 * n_u + 81]
        .iter()
        .fold(0.0f64, |m, v| m.min(*v));
    assert!(u3_min < -10.0, "u3 min {u3_min}");
    eprintln!("plate 8×8: worst {worst:.2e}; Rust {rs:.2} s, FreeFEM {fs:.2} s (processes)");
}

#[test]
fn hypar_contact_after_k_uzawa_iterations_matches_freefem() {
    let dir = tempfile::tempdir().unwrap();
    let extra = exactly_k_uzawa_steps(&["mesh.n=8"]);
    let (rust, ff, rs, fs) = both(dir.path(), "hypar", &scene_arg("shell/hypar-psri"), &extra);
    let worst = assert_agree(&rust, &ff, &["u", "theta", "lambda"], "hypar n=8, K=20");
    let (a, b) = (read_result(&rust).unwrap(), read_result(&ff).unwrap());
    assert_eq!(solver_attr(&b, "iterations"), &AttrValue::I64(K as i64));
    assert_eq!(solver_attr(&a, "iterations"), &AttrValue::I64(K as i64));
    assert_eq!(solver_attr(&b, "alpha"), &AttrValue::F64(ALPHA));
    assert_eq!(space(&b, "lambda"), "P1");
    // Contact is active: λ is compared where it matters.
    let active = dofs(&b, "lambda").iter().filter(|l| **l > 0.0).count();
    assert!(active > 0, "no active multiplier after {K} iterations");
    eprintln!(
        "hypar n=8, K={K}: worst {worst:.2e}, {active} active; Rust {rs:.2} s, FreeFEM {fs:.2} s (processes)"
    );
}

/// The Scordelis–Lo quarter (docs/shell-benchmarks.md): the cylinder chart
/// on x ∈ [0, 40° R] (arc length), y ∈ [0, L/2]; symmetry planes x = 0 and
/// y = 0, a rigid diaphragm at y = L/2, a free edge.
const ROOF: &str = r#"name = "roof"
model = "naghdi"
element = "ELEMENT"

[mesh]
geo = "GEO"
n = 4
parameters = { x0 = 0.0, x1 = 17.453292519943297, y0 = 0.0, y1 = 25.0 }

[shell]
young = 4.32e8
poisson = 0.0
thickness = 0.25
boundary = [
    { part = "west", condition = "symmetry", normal = "x" },
    { part = "south", condition = "symmetry", normal = "y" },
    { part = "north", condition = "diaphragm", normal = "y" },
]

[shell.chart]
kind = "cylinder"
radius = 25.0
height = 0.0

[load]
f = [0.0, 0.0, -90.0]

[solver]
method = "active-set"
"#;

#[test]
fn roof_boundary_conditions_match_freefem() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("roof.toml");
    let geo = manifest_path("meshes/rectangle.geo");
    let text = ROOF
        .replace("GEO", &geo.display().to_string())
        .replace("ELEMENT", &psri_element());
    std::fs::write(&file, text).unwrap();
    let extra = set_args(&["output.plots=[]"]);
    let (rust, ff, rs, fs) = both(dir.path(), "roof", &file.display().to_string(), &extra);
    let worst = assert_agree(&rust, &ff, &["u", "theta"], "Scordelis-Lo n=4");
    let r = read_result(&ff).unwrap();
    let solver = solver_attr(&r, "program").to_string();
    assert!(solver.contains("naghdi-psri.edp"), "{solver}");
    eprintln!("Scordelis-Lo n=4: worst {worst:.2e}; Rust {rs:.2} s, FreeFEM {fs:.2} s (processes)");
}

/// Charts from the scene reach the twin as the expressions and their
/// symbolic derivatives (`-chart parametric`, the script's scene-functions
/// block): the Scordelis–Lo quarter on its parametric cylinder, the same roof
/// on the sphere preset (spelled for FreeFEM as a parametric chart), and the
/// thesis' hypar as a graph in contact after K Uzawa iterations.
#[test]
fn charts_from_the_scene_match_freefem() {
    let dir = tempfile::tempdir().unwrap();
    let extra = set_args(&["mesh.n=4", "output.plots=[]"]);
    let scene = scene_arg("shell/scordelis-lo-parametric");
    let (rust, ff, _, _) = both(dir.path(), "roof", &scene, &extra);
    let worst = assert_agree(&rust, &ff, &["u", "theta"], "parametric roof n=4");
    let sphere = set_args(&[
        "mesh.n=4",
        "output.plots=[]",
        "mesh.parameters={x0 = 0.0, x1 = 0.6, y0 = 0.0, y1 = 0.5}",
        r#"shell.chart={kind="sphere", radius=25.0, height=-20.0}"#,
        "output.probe=[0.6, 0.0]",
        r#"shell.boundary=[{part="west", condition="clamped"}, {part="south", condition="clamped"}]"#,
    ]);
    let (rust, ff, _, _) = both(dir.path(), "sphere", &scene, &sphere);
    let worst_sphere = assert_agree(&rust, &ff, &["u", "theta"], "sphere band n=4");
    let extra = exactly_k_uzawa_steps(&[
        "mesh.n=8",
        r#"shell.chart={kind="graph", height="(x^2 - y^2)/5000 + 1.4"}"#,
    ]);
    let (rust, ff, _, _) = both(dir.path(), "graph", &scene_arg("shell/hypar-psri"), &extra);
    let worst_graph = assert_agree(&rust, &ff, &["u", "theta", "lambda"], "graph hypar n=8");
    let b = read_result(&ff).unwrap();
    assert!(
        dofs(&b, "lambda").iter().any(|l| *l > 0.0),
        "graph hypar: in contact"
    );
    eprintln!(
        "parametric roof {worst:.2e}, sphere {worst_sphere:.2e}, graph hypar {worst_graph:.2e}"
    );
}

/// The name of the PSRI element (`element` in a scene), as the shell
/// scenes give it.
fn psri_element() -> String {
    let file = manifest_path("pipelines/scenes/shell/plate-clamped.toml");
    let scene = Scene::load(&file, &[]).unwrap_or_else(|e| panic!("{e}"));
    scene.element.name().to_string()
}

/// A scene file in `dir` from the rectangle mesh (n = 2, unit square) with
/// the given chart and `[shell]` extra lines.
fn rectangle_scene(dir: &Path, name: &str, chart: &str, shell_extra: &str) -> Scene {
    let geo = manifest_path("meshes/rectangle.geo");
    let element = psri_element();
    let text = format!(
        r#"name = "{name}"
model = "naghdi"
element = "{element}"

[mesh]
geo = "{}"
n = 2

[shell]
young = 1e3
poisson = 0.3
thickness = 0.01
{shell_extra}

[shell.chart]
{chart}

[load]
f = [0.0, 0.0, -1.0]

[solver]
method = "active-set"
"#,
        geo.display()
    );
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, &text).unwrap();
    Scene::load(&path, &[]).unwrap_or_else(|e| panic!("{e}"))
}

fn fix_spec(dir: &Path, scene: &Scene) -> obstacle_fem::error::Result<String> {
    let mesh = scene_mesh(scene, &dir.join(format!("{}.msh", scene.name))).unwrap();
    psri_fix_spec(scene, &mesh)
}

#[test]
fn scene_conditions_become_the_fix_option() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Physical tags of rectangle.geo: 1 south, 2 east, 3 north, 4 west.
    let all = "u1,u2,u3,theta1,theta2";
    let plate = r#"kind = "plate"
height = 0.0"#;
    let cylinder = r#"kind = "cylinder"
radius = 2.0
height = 0.0"#;
    // Default: all of the boundary clamped.
    let s = rectangle_scene(d, "default", plate, "");
    assert_eq!(
        fix_spec(d, &s).unwrap(),
        format!("1:{all};2:{all};3:{all};4:{all}")
    );
    // Named clamped parts, and every other condition.
    let s = rectangle_scene(
        d,
        "mixed",
        plate,
        r#"clamped = ["west"]
boundary = [
    { part = "south", condition = "symmetry", normal = "y" },
    { part = "east", condition = "simply-supported" },
    { part = "north", condition = "fixed", fix = ["u3", "theta2"] },
]"#,
    );
    assert_eq!(
        fix_spec(d, &s).unwrap(),
        format!("1:u2,theta2;2:u1,u2,u3;3:u3,theta2;4:{all}")
    );
    // A diaphragm and a free part; the cylinder's crown line x = 0 is a
    // symmetry plane with normal e1 (a_2 = e2 lies in it: θ1 = 0).
    let s = rectangle_scene(
        d,
        "roof",
        cylinder,
        r#"boundary = [
    { part = "west", condition = "symmetry", normal = "x" },
    { part = "north", condition = "diaphragm", normal = "y" },
    { part = "east", condition = "free" },
]"#,
    );
    assert_eq!(fix_spec(d, &s).unwrap(), "3:u1,u3;4:u1,theta1");
    // On the cylinder's line y = 0 a plane with normal e3 contains a_1 only
    // at the crown x = 0: θ1 = 0 on part of the line only, which -fix (whole
    // labels) cannot state.
    let s = rectangle_scene(
        d,
        "refused",
        cylinder,
        r#"boundary = [
    { part = "south", condition = "symmetry", normal = "z" },
]"#,
    );
    let err = fix_spec(d, &s).unwrap_err().to_string();
    assert!(
        err.contains("south") && err.contains("naghdi-psri.edp") && err.contains("cannot state"),
        "{err}"
    );
}
