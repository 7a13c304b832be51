//! `obstacle freefem` and `obstacle compare` end to end (docs/formulation.md §5 files on
//! both sides): the FreeFEM twin of a scene on the very mesh file of the Rust
//! run, exactly K = 100 Uzawa iterations on both sides, compared field by
//! field; `compare` failing beyond tolerance, on another mesh and on a file
//! that is not a result; and converged solutions (Rust's active set against
//! FreeFEM's Uzawa run to its thesis stop).
//!
//! Needs `gmsh`, `FreeFem++` and `libfreefem++` (`make deps`): a missing
//! FreeFEM fails, it is never skipped.

mod common;

use common::{obstacle, obstacle_output, scene_arg, set_args, solver_attr};
use obstacle_fem::output::compare::compare_results;
use obstacle_fem::output::{read_result, AttrValue};
use std::path::{Path, PathBuf};

const K: usize = 100;
/// Iterates after K steps: agreement to round-off, asserted to 1e-8.
const RTOL: f64 = 1e-8;

/// Exactly K iterations for `solve` (a thesis tolerance never met), no plots.
fn fixed_k() -> Vec<String> {
    set_args(&[
        "solver.stop=thesis",
        "solver.thesis_tol=1e-300",
        &format!("solver.max_iter={K}"),
        "output.plots=[]",
    ])
}

fn solve(dir: &Path, name: &str, scene_name: &str, extra: &[String]) -> PathBuf {
    let out = dir.join(format!("{name}.h5"));
    let mut args = vec!["solve".into(), scene_arg(scene_name)];
    args.extend_from_slice(extra);
    args.extend(["--quiet".into(), "--out".into(), out.display().to_string()]);
    common::obstacle_solve(&args);
    out
}

fn freefem(dir: &Path, name: &str, scene_name: &str, extra: &[String]) -> PathBuf {
    let out = dir.join(format!("{name}.h5"));
    let mut args = vec!["freefem".into(), scene_arg(scene_name)];
    args.extend_from_slice(extra);
    args.extend(["--out".into(), out.display().to_string()]);
    obstacle(&args);
    out
}

/// Both files: same vertices, triangles and in-triangle order; every common
/// field within `rtol`; the `compare` command agrees (exit 0).
fn assert_agree(a: &Path, b: &Path, rtol: f64, fields: &[&str], label: &str) {
    let (ra, rb) = (read_result(a).unwrap(), read_result(b).unwrap());
    assert_eq!(ra.vertices, rb.vertices, "{label}: vertex order");
    assert_eq!(ra.triangles, rb.triangles, "{label}: triangle order");
    let names: Vec<String> = fields.iter().map(|s| s.to_string()).collect();
    let rows = compare_results(&ra, a, &rb, b, Some(&names)).unwrap();
    for r in &rows {
        eprintln!(
            "{label}: {:<16} max rel {:.2e}, L² rel {:.2e}",
            r.name, r.max_rel, r.l2_rel
        );
        assert!(r.worst() <= rtol, "{label}: {} differs: {r:?}", r.name);
    }
    // Every requested name, at least as a field.
    for f in fields {
        assert!(
            rows.iter().any(|r| r.name == format!("fields/{f}")),
            "{label}: no fields/{f} compared"
        );
    }
    let out = obstacle(&[
        "compare".into(),
        a.display().to_string(),
        b.display().to_string(),
        "--rtol".into(),
        format!("{rtol:e}"),
        "--fields".into(),
        fields.join(","),
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("| fields/u |"), "{text}");
}

#[test]
fn freefem_command_matches_rust_after_k_iterations() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (element, alpha) in [("p1b-p0", "1.9"), ("p2-p1", "auto")] {
        let mut extra = set_args(&[
            "mesh.n=8",
            &format!("element={element}"),
            &format!("solver.alpha={alpha}"),
        ]);
        extra.extend(fixed_k());
        let rust = solve(d, &format!("rust-{element}"), "obstacle-disk", &extra);
        let ff = freefem(d, &format!("ff-{element}"), "obstacle-disk", &extra);
        // Both read the same mesh file.
        let r = read_result(&ff).unwrap();
        assert_eq!(
            solver_attr(&r, "algorithm"),
            &AttrValue::Str("uzawa (FreeFEM)".into())
        );
        assert_eq!(solver_attr(&r, "iterations"), &AttrValue::I64(K as i64));
        assert_eq!(
            solver_attr(&r, "alpha"),
            solver_attr(&read_result(&rust).unwrap(), "alpha"),
            "α = {alpha}: the same step on both sides"
        );
        let fields = ["u", "lambda", "gap_mean", "phi", "contact"];
        assert_agree(&rust, &ff, RTOL, &fields, &format!("disk n=8 {element}"));
    }
    // The thesis shell, 16×16, α = 0.01 integral form.
    let extra = fixed_k();
    let rust = solve(d, "rust-shell", "naghdi-hypar", &extra);
    let ff = freefem(d, "ff-shell", "naghdi-hypar", &extra);
    assert_agree(
        &rust,
        &ff,
        RTOL,
        &["u", "r", "psi", "lambda"],
        "naghdi-hypar 16×16",
    );
    // `info` reads the FreeFEM file.
    let out = obstacle(&["info".into(), ff.display().to_string()]);
    assert!(String::from_utf8_lossy(&out.stdout).contains("uzawa (FreeFEM)"));
}

/// An expression load and a two-sided obstacle reach the script as `func`s;
/// after K iterations both bounds' multipliers agree with Rust to round-off.
#[test]
fn freefem_twin_takes_expressions_and_two_sided_obstacles() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for element in ["p1b-p0", "p2-p1"] {
        let mut extra = set_args(&[
            "mesh.n=6",
            &format!("element={element}"),
            "solver.method=uzawa",
            "solver.alpha=auto",
            "solver.step_form=mean",
        ]);
        extra.extend(fixed_k());
        let rust = solve(d, &format!("rust-{element}"), "peers/two-sided", &extra);
        let ff = freefem(d, &format!("ff-{element}"), "peers/two-sided", &extra);
        let fields = [
            "u",
            "lambda",
            "lambda_lower",
            "lambda_upper",
            "gap_mean",
            "gap_upper_mean",
            "phi",
            "phi_upper",
        ];
        assert_agree(&rust, &ff, RTOL, &fields, &format!("two-sided {element}"));
        let upper = read_result(&ff).unwrap();
        let active = common::field(&upper, "lambda_upper")
            .iter()
            .filter(|&&l| l > 0.0)
            .count();
        assert!(
            active > 0,
            "{element}: the upper bound is active in FreeFEM's run"
        );
    }
}

#[test]
fn compare_fails_beyond_tolerance_and_on_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let run = |name: &str, set: &[&str]| {
        let mut extra = set_args(set);
        extra.extend(fixed_k());
        solve(d, name, "obstacle-disk", &extra)
    };
    let a = run("a", &["mesh.n=8", "solver.alpha=1.9"]);
    let b = run("b", &["mesh.n=8", "solver.alpha=1.5"]);
    let other_mesh = run("c", &["mesh.n=6", "solver.alpha=1.9"]);
    let compare = |x: &Path, y: &Path| {
        obstacle_output(&[
            "compare".into(),
            x.display().to_string(),
            y.display().to_string(),
        ])
    };
    // Different α: fields differ beyond 1e-8, exit status 1, named in the message.
    let out = compare(&a, &b);
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("beyond rtol") && err.contains("dofs/lambda"),
        "{err}"
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("| NO |"));
    // Same file: agreement.
    assert!(compare(&a, &a).status.success());
    // Another mesh.
    let out = compare(&a, &other_mesh);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("the mesh differs"), "{err}");
    // A truncated HDF5 file and a foreign file.
    let bytes = std::fs::read(&a).unwrap();
    let truncated = d.join("truncated.h5");
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
    let foreign = d.join("foreign.h5");
    std::fs::write(&foreign, "not an HDF5 file\n").unwrap();
    for bad in [&truncated, &foreign] {
        let out = compare(&a, bad);
        assert_eq!(out.status.code(), Some(1));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains(&bad.display().to_string()) && err.contains("not a readable HDF5 file"),
            "{err}"
        );
    }
    // A field neither file has.
    let out = obstacle_output(&[
        "compare".into(),
        a.display().to_string(),
        a.display().to_string(),
        "--fields".into(),
        "psi".into(),
    ]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("`psi`"));
}

/// Converged solutions: Rust's active set (the exact discrete KKT point, KKT
/// ≤ 1e-12) against FreeFEM's Uzawa run to the thesis stop
/// ‖λ^k − λ^{k−1}‖∞ < 1e-10 (α = auto). The Uzawa error is about the last
/// step / (1 − q), q the contraction factor (here ≈ 100× the step): the
/// stated tolerance is 1e-7 relative (measured ≈ 1.5e-9).
#[test]
fn converged_solutions_agree_to_the_stopping_tolerance() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for element in ["p1b-p0", "p2-p1"] {
        let base = [
            "mesh.n=8".to_string(),
            format!("element={element}"),
            "output.plots=[]".to_string(),
        ];
        let base: Vec<&str> = base.iter().map(String::as_str).collect();
        let mut rust_set = base.clone();
        rust_set.extend(["solver.method=active-set", "solver.tol=1e-12"]);
        let rust = solve(
            d,
            &format!("as-{element}"),
            "obstacle-disk",
            &set_args(&rust_set),
        );
        let mut ff_set = base;
        ff_set.extend([
            "solver.stop=thesis",
            "solver.thesis_tol=1e-10",
            "solver.dual_norm=\"inf\"",
            "solver.max_iter=20000",
        ]);
        let ff = freefem(
            d,
            &format!("ffc-{element}"),
            "obstacle-disk",
            &set_args(&ff_set),
        );
        let r = read_result(&ff).unwrap();
        assert_eq!(
            solver_attr(&r, "stop_reason"),
            &AttrValue::Str("thesis".into())
        );
        assert_agree(
            &rust,
            &ff,
            1e-7,
            &["u", "lambda"],
            &format!("converged disk n=8 {element}"),
        );
    }
}
