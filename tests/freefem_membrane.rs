//! Cross-check of the membrane obstacle solver against FreeFEM
//! (`freefem/membrane-obstacle.edp`): the same disk mesh, the same discrete
//! problem (P1⊕B3–P0 and P2–P1), exactly 100 Uzawa iterations with a fixed α
//! from λ⁰ = 0, and the whole coefficient vectors of u (vertex values and
//! bubble amplitudes / edge-midpoint values) and λ compared entry by entry.
//!
//! Needs `gmsh`, `FreeFem++` and FreeFEM's plugins (`libfreefem++`) — `make deps`
//! installs them. A missing FreeFEM fails the test; it is never skipped.

mod common;

use common::{
    check_success, dofs, field, max_abs, obstacle, read_ff_mesh, read_info, read_numbers, rel_diff,
    solver_attr,
};
use obstacle_fem::mesh::Mesh;
use obstacle_fem::output::{read_result, AttrValue};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Output;

const ITERATIONS: usize = 100;
/// Agreement required, relative to the max norm of each Rust vector.
const RTOL: f64 = 1e-8;

fn scene() -> PathBuf {
    common::manifest_path("pipelines/scenes/obstacle-disk.toml")
}

fn script() -> PathBuf {
    obstacle_fem::freefem::script_dir().join("membrane-obstacle.edp")
}

/// Runs the membrane script; panics (never skips) when FreeFEM is missing.
fn run_freefem(args: &[String]) -> Output {
    common::run_freefem("membrane-obstacle.edp", args).0
}

fn info_usize(info: &HashMap<String, String>, key: &str) -> usize {
    info.get(key)
        .unwrap_or_else(|| panic!("FreeFEM info has no `{key}`"))
        .parse()
        .unwrap()
}

fn info_f64(info: &HashMap<String, String>, key: &str) -> f64 {
    info.get(key)
        .unwrap_or_else(|| panic!("FreeFEM info has no `{key}`"))
        .parse()
        .unwrap()
}

fn check_close(case: &str, what: &str, rust: &[f64], ff: &[f64]) -> f64 {
    let (rel, i) = rel_diff(rust, ff);
    eprintln!(
        "{case}: {what:<28} {:>5} values, max|Rust − FreeFEM| / max|Rust| = {rel:.2e} (max|Rust| = {:.6e})",
        rust.len(),
        max_abs(rust)
    );
    assert!(
        rel <= RTOL,
        "{case}: {what} differs: relative max difference {rel:.3e} > {RTOL:e} at index {i} \
         (Rust {}, FreeFEM {})",
        rust[i],
        ff[i]
    );
    rel
}

struct Case {
    element: &'static str,
    step_form: &'static str,
    alpha: f64,
}

fn compare(dir: &Path, msh: &Path, mesh: &Mesh, case: &Case) {
    let name = format!("{}-{}", case.element, case.step_form);
    let label = format!("{} {} α={}", case.element, case.step_form, case.alpha);

    // Rust: exactly ITERATIONS iterations (the thesis criterion never fires).
    let h5 = dir.join(format!("{name}.h5"));
    common::obstacle_solve(&[
        "solve".into(),
        scene().display().to_string(),
        "--set".into(),
        format!("element={}", case.element),
        "--set".into(),
        "mesh.n=8".into(),
        "--set".into(),
        "solver.stop=thesis".into(),
        "--set".into(),
        "solver.thesis_tol=1e-300".into(),
        "--set".into(),
        format!("solver.max_iter={ITERATIONS}"),
        "--set".into(),
        format!("solver.alpha={}", case.alpha),
        "--set".into(),
        format!("solver.step_form={}", case.step_form),
        "--quiet".into(),
        "--out".into(),
        h5.display().to_string(),
    ]);
    // The solve meshed the scene again: the very same file FreeFEM reads.
    assert_eq!(
        std::fs::read(h5.with_extension("msh")).unwrap(),
        std::fs::read(msh).unwrap(),
        "{label}: the solve's mesh differs from {}",
        msh.display()
    );
    let r = read_result(&h5).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(
        solver_attr(&r, "iterations"),
        &AttrValue::I64(ITERATIONS as i64),
        "{label}: Rust iterations"
    );
    assert_eq!(
        solver_attr(&r, "stop_reason"),
        &AttrValue::Str("max_iter".into()),
        "{label}: Rust stop reason"
    );
    assert_eq!(solver_attr(&r, "alpha"), &AttrValue::F64(case.alpha));
    assert_eq!(
        solver_attr(&r, "step_form"),
        &AttrValue::Str(case.step_form.into())
    );

    // FreeFEM, same K and α.
    let prefix = dir.join(format!("ff-{name}"));
    let out = run_freefem(&[
        "-mesh".into(),
        msh.display().to_string(),
        "-element".into(),
        case.element.into(),
        "-g".into(),
        "-4".into(),
        "-height".into(),
        "0.3".into(),
        "-curvature".into(),
        "1".into(),
        "-alpha".into(),
        format!("{}", case.alpha),
        "-stepform".into(),
        case.step_form.into(),
        "-iterations".into(),
        ITERATIONS.to_string(),
        "-out".into(),
        prefix.display().to_string(),
    ]);
    check_success(&format!("FreeFem++ {}", script().display()), &out);
    let file = |ext: &str| PathBuf::from(format!("{}.{ext}", prefix.display()));
    let info = read_info(&file("info.txt"));

    // Same mesh, same order: counts, then every vertex and triangle.
    let (nv, nt) = (r.vertices.len(), r.triangles.len());
    eprintln!(
        "{label}: FreeFEM nv {} nt {} ne {} | Rust nv {nv} nt {nt} ne {}",
        info_usize(&info, "nv"),
        info_usize(&info, "nt"),
        info_usize(&info, "ne"),
        mesh.n_edges()
    );
    assert_eq!(info_usize(&info, "nv"), nv, "{label}: vertex count");
    assert_eq!(info_usize(&info, "nt"), nt, "{label}: triangle count");
    assert_eq!(
        info_usize(&info, "ne"),
        mesh.n_edges(),
        "{label}: edge count"
    );
    assert_eq!(info_usize(&info, "iterations"), ITERATIONS);
    assert_eq!(info_f64(&info, "alpha"), case.alpha);
    let (ff_v, ff_t) = read_ff_mesh(&file("mesh.txt"));
    for (i, (a, b)) in ff_v.iter().zip(&r.vertices).enumerate() {
        assert!(
            (a[0] - b[0]).abs() <= 1e-15 && (a[1] - b[1]).abs() <= 1e-15,
            "{label}: vertex {i}: FreeFEM {a:?}, Rust {b:?}"
        );
    }
    assert_eq!(
        ff_t, r.triangles,
        "{label}: triangles (order or vertex order)"
    );

    // u: all dofs; λ: all multipliers.
    let (u_r, l_r) = (dofs(&r, "u"), dofs(&r, "lambda"));
    let (u_f, l_f) = (
        read_numbers(&file("u.txt")),
        read_numbers(&file("lambda.txt")),
    );
    assert_eq!(info_usize(&info, "ndof_u"), u_r.len(), "{label}: u dofs");
    assert_eq!(
        info_usize(&info, "ndof_lambda"),
        l_r.len(),
        "{label}: λ dofs"
    );
    assert_eq!(u_f.len(), u_r.len(), "{label}: FreeFEM u.txt length");
    assert_eq!(l_f.len(), l_r.len(), "{label}: FreeFEM lambda.txt length");
    let extra = if case.element == "p1b-p0" {
        assert_eq!(u_r.len(), nv + nt);
        assert_eq!(l_r.len(), nt);
        "u bubble amplitudes"
    } else {
        assert_eq!(u_r.len(), nv + mesh.n_edges());
        assert_eq!(l_r.len(), nv);
        assert_eq!(
            r.edges.as_deref(),
            Some(&mesh.edges[..]),
            "/mesh/edges order"
        );
        "u edge midpoints"
    };
    check_close(&label, "u (all dofs)", u_r, &u_f);
    check_close(&label, "u vertex values", &u_r[..nv], &u_f[..nv]);
    // Relative to the whole of u (bubbles are small corrections).
    let (rel, _) = rel_diff(u_r, &u_f);
    let bub = u_r[nv..]
        .iter()
        .zip(&u_f[nv..])
        .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()))
        / max_abs(u_r);
    eprintln!("{label}: {extra:<28} max diff / max|u| = {bub:.2e} (≤ {rel:.2e})");
    check_close(&label, "/fields/u vs FreeFEM", field(&r, "u"), &u_f[..nv]);
    check_close(&label, "lambda", l_r, &l_f);
    check_close(
        &label,
        "/fields/lambda vs FreeFEM",
        field(&r, "lambda"),
        &l_f,
    );

    // A non-trivial comparison: the projection max(0, ·) is active somewhere
    // and the contact set is a proper part of the domain.
    let active = l_r.iter().filter(|&&l| l > 0.0).count();
    assert!(
        active > 0 && active < l_r.len(),
        "{label}: {active} of {} multipliers positive",
        l_r.len()
    );
    let ff_active = l_f.iter().filter(|&&l| l > 0.0).count();
    assert_eq!(active, ff_active, "{label}: contact sets differ");
    eprintln!(
        "{label}: {active}/{} multipliers positive; FreeFEM {:.2e} s/iteration wall, {:.2e} CPU (UMFPACK), \
         last ‖Δλ‖∞ {:.3e}",
        l_r.len(),
        info_f64(&info, "seconds_per_iteration"),
        info_f64(&info, "loop_cpu_seconds") / ITERATIONS as f64,
        info_f64(&info, "last_dual_step_inf")
    );
}

fn disk_mesh(dir: &Path) -> (PathBuf, Mesh) {
    let msh = dir.join("disk.msh");
    obstacle(&[
        "mesh".into(),
        scene().display().to_string(),
        "--set".into(),
        "mesh.n=8".into(),
        "--out".into(),
        msh.display().to_string(),
    ]);
    let mesh = Mesh::read_msh(&msh).unwrap_or_else(|e| panic!("{e}"));
    (msh, mesh)
}

#[test]
fn freefem_and_rust_uzawa_agree_on_the_disk() {
    let dir = tempfile::tempdir().unwrap();
    let (msh, mesh) = disk_mesh(dir.path());
    for case in [
        Case {
            element: "p1b-p0",
            step_form: "mean",
            alpha: 1.9,
        },
        Case {
            element: "p2-p1",
            step_form: "mean",
            alpha: 1.9,
        },
        // The integral form (D = w): α scales with 1/|T|.
        Case {
            element: "p1b-p0",
            step_form: "integral",
            alpha: 100.0,
        },
        Case {
            element: "p2-p1",
            step_form: "integral",
            alpha: 100.0,
        },
    ] {
        compare(dir.path(), &msh, &mesh, &case);
    }
}

#[test]
fn freefem_script_refuses_bad_options() {
    let dir = tempfile::tempdir().unwrap();
    let (msh, _) = disk_mesh(dir.path());
    let prefix = dir.path().join("bad").display().to_string();
    let base = |extra: &[&str]| -> Vec<String> {
        let mut a: Vec<String> = vec![
            "-mesh".into(),
            msh.display().to_string(),
            "-iterations".into(),
            "3".into(),
            "-out".into(),
            prefix.clone(),
        ];
        a.extend(extra.iter().map(|s| s.to_string()));
        a
    };
    for (what, args) in [
        ("missing -alpha", base(&[])),
        ("iterative solver", base(&["-alpha", "1", "-solver", "CG"])),
        (
            "unknown element",
            base(&["-alpha", "1", "-element", "p3-p2"]),
        ),
        (
            "unknown step form",
            base(&["-alpha", "1", "-stepform", "median"]),
        ),
    ] {
        let out = run_freefem(&args);
        common::check_rejected(what, &out, "membrane-obstacle.edp");
    }
    // And the good call works (3 iterations).
    let out = run_freefem(&base(&["-alpha", "1"]));
    check_success("FreeFem++ with valid options", &out);
}
