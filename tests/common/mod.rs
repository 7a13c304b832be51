//! Helpers shared by the integration tests (each test file says `mod
//! common;`): running the `obstacle` binary, looking things up in a result
//! file, test meshes (the structured square, the gmsh diamond), mirror maps.
//!
//! Running FreeFEM and reading its text output is library code
//! (`obstacle_fem::freefem`); the wrappers here are for tests: a missing
//! FreeFEM FAILS a test (CI installs it), it is never skipped.
#![allow(dead_code)]

use faer::sparse::SparseColMat;
use obstacle_fem::freefem;
use obstacle_fem::gmsh::run_gmsh;
use obstacle_fem::mesh::{BoundaryEdge, Mesh};
use obstacle_fem::output::{AttrValue, ResultFile};
use obstacle_fem::solvers::active_set::ActiveSetOptions;
use obstacle_fem::solvers::{ContactProblem, Probe, SolveReport, SolverOptions};
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A sparse matrix's pattern: its shape, column pointers and rows (two
/// matrices with equal patterns and equal `val()` are the same entry for
/// entry).
pub fn pattern(a: &SparseColMat<usize, f64>) -> (usize, usize, Vec<usize>, Vec<usize>) {
    let s = a.symbolic();
    (
        a.nrows(),
        a.ncols(),
        s.col_ptr().to_vec(),
        s.row_idx().to_vec(),
    )
}

pub fn manifest_path(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// Runs FreeFEM's `script` (a path below `freefem/`) with `args`: the
/// output and the wall time of the process. Panics when FreeFEM or its gmsh
/// plugin is missing.
pub fn run_freefem(script: &str, args: &[String]) -> (Output, f64) {
    freefem::run_script(&freefem::script_dir().join(script), args).unwrap_or_else(|e| panic!("{e}"))
}

pub fn check_success(what: &str, out: &Output) {
    assert!(
        out.status.success(),
        "{what} failed ({}):\n--- stdout\n{}\n--- stderr\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A script call that must fail with a message prefixed by the script's name.
pub fn check_rejected(what: &str, out: &Output, script: &str) {
    assert!(
        !out.status.success(),
        "{what}: the script should fail, but succeeded:\n{}",
        String::from_utf8_lossy(&out.stdout)
    );
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains(&format!("{script}:")), "{what}: {text}");
}

/// Runs the `obstacle` binary; its output, whatever the exit status.
pub fn obstacle_output(args: &[String]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_obstacle"))
        .args(args)
        .output()
        .expect("cannot run the obstacle binary")
}

/// Runs the `obstacle` binary and asserts it succeeds.
pub fn obstacle(args: &[String]) -> Output {
    let out = obstacle_output(args);
    check_success(&format!("obstacle {}", args.join(" ")), &out);
    out
}

/// Runs `obstacle solve ARGS` (with `--out FILE`) and checks its exit
/// status against the result it wrote: 0 when the run converged or met the
/// scene's stop rule, 2 when `solver.max_iter` stopped it first (the result
/// says `stop_reason = "max_iter"`, not converged: exactly K iterations with
/// a thesis tolerance never met).
pub fn obstacle_solve(args: &[String]) -> Output {
    let out = obstacle_output(args);
    let what = format!("obstacle {}", args.join(" "));
    let code = out.status.code();
    if code != Some(2) {
        check_success(&what, &out);
    }
    let file = args
        .iter()
        .position(|a| a == "--out")
        .map(|i| PathBuf::from(&args[i + 1]))
        .expect("obstacle_solve needs --out");
    let r = obstacle_fem::output::read_result(&file).unwrap_or_else(|e| panic!("{what}: {e}"));
    let stopped_by_max_iter = solver_attr(&r, "stop_reason") == &AttrValue::Str("max_iter".into())
        && solver_attr(&r, "converged") == &AttrValue::Bool(false);
    assert_eq!(
        code,
        Some(if stopped_by_max_iter { 2 } else { 0 }),
        "{what}: exit status against the result's stop"
    );
    out
}

pub fn read_numbers(path: &Path) -> Vec<f64> {
    freefem::read_numbers(path).unwrap_or_else(|e| panic!("{e}"))
}

pub fn read_info(path: &Path) -> HashMap<String, String> {
    freefem::Info::read(path)
        .unwrap_or_else(|e| panic!("{e}"))
        .values
}

/// FreeFEM's `PREFIX.mesh.txt`: vertices and triangles.
pub fn read_ff_mesh(path: &Path) -> (Vec<[f64; 2]>, Vec<[usize; 3]>) {
    freefem::read_mesh_text(path).unwrap_or_else(|e| panic!("{e}"))
}

pub fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0, |m, x| m.max(x.abs()))
}

/// max |a − b| / max |a| (a: Rust), and where.
pub fn rel_diff(a: &[f64], b: &[f64]) -> (f64, usize) {
    assert_eq!(a.len(), b.len());
    let scale = max_abs(a);
    assert!(scale > 0.0, "the Rust vector is zero");
    let (i, d) = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .enumerate()
        .fold(
            (0, 0.0),
            |(bi, bd), (i, d)| if d > bd { (i, d) } else { (bi, bd) },
        );
    (d / scale, i)
}

// ---- the `obstacle` binary as a user runs it ----------------------------------

/// Runs the `obstacle` binary with `CI=1` (no progress bars) and the extra
/// environment `env`; its output, whatever the exit status.
pub fn run_obstacle_env(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_obstacle"));
    c.args(args).env("CI", "1");
    for (k, v) in env {
        c.env(k, v);
    }
    c.output().expect("the obstacle binary runs")
}

/// Runs the `obstacle` binary with `CI=1`; its output, whatever the exit status.
pub fn run_obstacle(args: &[&str]) -> Output {
    run_obstacle_env(args, &[])
}

/// `obstacle study STUDY --out-dir OUT_DIR --quiet` with `extra` arguments;
/// its output, whatever the exit status.
pub fn run_study(study: &Path, out_dir: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "study",
        study.to_str().unwrap(),
        "--out-dir",
        out_dir.to_str().unwrap(),
        "--quiet",
    ];
    args.extend(extra);
    run_obstacle(&args)
}

/// A study's Markdown table and CSV (`OUT_DIR/NAME.md`, `.csv`) with the
/// wall-time column (the only one that may differ between runs) blanked:
/// the table's last column dropped, the CSV's `time` cells emptied, its
/// header dropped and the out dir (as given and canonical) replaced by `OUT`.
pub fn study_tables(out_dir: &Path, name: &str) -> (String, String) {
    let md = std::fs::read_to_string(out_dir.join(format!("{name}.md"))).unwrap();
    // `time` is the last column of the default table.
    let md = md
        .lines()
        .map(|l| match l.strip_suffix(" |") {
            Some(row) if l.starts_with("| ") => row.rsplit_once(" | ").unwrap().0.to_string(),
            _ => l.to_string(),
        })
        .collect::<Vec<_>>()
        .join("\n");
    let csv = std::fs::read_to_string(out_dir.join(format!("{name}.csv"))).unwrap();
    let time = csv
        .lines()
        .next()
        .unwrap()
        .split(',')
        .position(|c| c == "time")
        .expect("a time column");
    let csv = csv
        .lines()
        .skip(1)
        .map(|l| {
            let mut cells: Vec<&str> = l.split(',').collect();
            cells[time] = "";
            cells.join(",")
        })
        .collect::<Vec<_>>()
        .join("\n");
    let canonical = out_dir.canonicalize().unwrap();
    let csv = csv
        .replace(canonical.to_str().unwrap(), "OUT")
        .replace(out_dir.to_str().unwrap(), "OUT");
    (md, csv)
}

/// `obstacle solve` of the membrane disk scene into `out`, quietly, with
/// `--set` for each of `sets`.
pub fn solve_membrane(out: &Path, sets: &[&str]) -> Output {
    solve_scene("obstacle-disk", out, sets)
}

/// `obstacle solve` of `pipelines/scenes/<scene>.toml` into `out` with `--set`
/// overrides, quiet; its output, whatever the exit status.
pub fn solve_scene(scene: &str, out: &Path, sets: &[&str]) -> Output {
    let scene = scene_arg(scene);
    let mut args = vec!["solve", &scene, "--quiet", "--out", out.to_str().unwrap()];
    for s in sets {
        args.extend(["--set", s]);
    }
    run_obstacle(&args)
}

/// A failed run: non-zero exit, no panic, exactly one `error:` line, which
/// contains every word of `expected`.
pub fn assert_one_error(o: &Output, expected: &[&str], what: &str) {
    let t = text(o);
    assert!(!o.status.success(), "{what} should fail: {t}");
    assert!(!t.contains("panicked"), "{what} panicked: {t}");
    let errors: Vec<&str> = t.lines().filter(|l| l.starts_with("error: ")).collect();
    assert_eq!(errors.len(), 1, "{what}: one error line expected: {t}");
    for e in expected {
        assert!(errors[0].contains(e), "{what}: the error lacks `{e}`: {t}");
    }
}

/// Standard output followed by standard error, as text.
pub fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

// ---- looking things up in a result file ---------------------------------------

/// The values of `/fields/{name}`.
pub fn field<'a>(r: &'a ResultFile, name: &str) -> &'a [f64] {
    &r.data
        .fields
        .iter()
        .find(|f| f.name == name)
        .unwrap_or_else(|| panic!("no /fields/{name}"))
        .values
}

/// The coefficient vector `/dofs/{name}`.
pub fn dofs<'a>(r: &'a ResultFile, name: &str) -> &'a [f64] {
    &r.data
        .dofs
        .iter()
        .find(|(n, _)| n == name)
        .unwrap_or_else(|| panic!("no /dofs/{name}"))
        .1
}

/// An attribute of `/solver`.
pub fn solver_attr<'a>(r: &'a ResultFile, name: &str) -> &'a AttrValue {
    &r.data
        .solver_attrs
        .iter()
        .find(|(n, _)| n == name)
        .unwrap_or_else(|| panic!("no /solver attribute {name}"))
        .1
}

/// An attribute of the file's root group.
pub fn root_attr(file: &ResultFile, name: &str) -> AttrValue {
    file.data
        .root_attrs
        .iter()
        .find(|(k, _)| k == name)
        .unwrap_or_else(|| panic!("no attribute {name}"))
        .1
        .clone()
}

// ---- meshes --------------------------------------------------------------------

/// A structured triangulation of [-1, 1]² with n × n squares, each cut
/// along a diagonal (alternating), boundary edges tagged 1.
pub fn square_mesh(n: usize) -> Mesh {
    let idx = |i: usize, j: usize| j * (n + 1) + i;
    let mut vertices = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            vertices.push([
                -1.0 + 2.0 * i as f64 / n as f64,
                -1.0 + 2.0 * j as f64 / n as f64,
            ]);
        }
    }
    let mut triangles = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let (a, b, c, d) = (idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1));
            if (i + j) % 2 == 0 {
                triangles.push([a, b, c]);
                triangles.push([a, c, d]);
            } else {
                triangles.push([a, b, d]);
                triangles.push([b, c, d]);
            }
        }
    }
    let mut boundary_edges = Vec::new();
    for k in 0..n {
        for e in [
            [idx(k, 0), idx(k + 1, 0)],
            [idx(n, k), idx(n, k + 1)],
            [idx(k + 1, n), idx(k, n)],
            [idx(0, k + 1), idx(0, k)],
        ] {
            boundary_edges.push(BoundaryEdge {
                vertices: e,
                tag: 1,
            });
        }
    }
    Mesh::from_parts(
        vertices,
        triangles,
        boundary_edges,
        BTreeMap::new(),
        PathBuf::new(),
    )
    .expect("valid square mesh")
}

/// The structured diamond {|x| + |y| < 50√2} with n subdivisions per side
/// (`meshes/diamond.geo` through gmsh), written to `dir`: the file and the mesh.
pub fn diamond(dir: &Path, n: usize) -> (PathBuf, Mesh) {
    let msh = dir.join(format!("diamond-{n}.msh"));
    run_gmsh(
        &manifest_path("meshes/diamond.geo"),
        &msh,
        &[("n".into(), n as f64)],
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let mesh = Mesh::read_msh(&msh).unwrap_or_else(|e| panic!("{e}"));
    (msh, mesh)
}

/// For each point, the index of the point at its image under `f` (within
/// `tol` in each coordinate; `tol` must be below 1e-6): mirror symmetries.
/// Panics when a point has no mirror.
pub fn mirror_map(points: &[[f64; 2]], f: impl Fn([f64; 2]) -> [f64; 2], tol: f64) -> Vec<usize> {
    assert!(tol < 1e-6, "tol {tol} exceeds the bucket size");
    // Bucket by rounded coordinates (tol << bucket size).
    let bucket = |p: [f64; 2]| [(p[0] * 1e6).round() as i64, (p[1] * 1e6).round() as i64];
    let mut grid: HashMap<[i64; 2], Vec<usize>> = HashMap::new();
    for (i, &p) in points.iter().enumerate() {
        grid.entry(bucket(p)).or_default().push(i);
    }
    points
        .iter()
        .map(|&p| {
            let q = f(p);
            let b = bucket(q);
            let mut found = None;
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for &j in grid.get(&[b[0] + dx, b[1] + dy]).into_iter().flatten() {
                        let w = points[j];
                        if (w[0] - q[0]).abs() <= tol && (w[1] - q[1]).abs() <= tol {
                            found = Some(j);
                        }
                    }
                }
            }
            found.unwrap_or_else(|| panic!("no point at the mirror {q:?} of {p:?}"))
        })
        .collect()
}

/// The path of `pipelines/scenes/<rel>.toml`, as a command-line argument.
pub fn scene_arg(rel: &str) -> String {
    manifest_path(&format!("pipelines/scenes/{rel}.toml"))
        .display()
        .to_string()
}

/// `--set` arguments for each override.
pub fn set_args(pairs: &[&str]) -> Vec<String> {
    pairs
        .iter()
        .flat_map(|p| ["--set".to_string(), p.to_string()])
        .collect()
}

/// An adaptive run's steps against its exact solution (issue 14): prints
/// dofs, η, H¹ error and η / error per step and asserts the effectivity
/// index within [1, 10] and every indicator η_T positive and finite.
pub fn assert_effectivity_per_step(label: &str, steps: &[ResultFile]) {
    let attr = |step: &ResultFile, name: &str| {
        obstacle_fem::output::numeric_attr(&step.data.root_attrs, name)
            .unwrap_or_else(|| panic!("no attribute {name}"))
    };
    println!("{label}: step, dofs, η, H¹ error, η / error");
    for (k, step) in steps.iter().enumerate() {
        let (eta, error) = (attr(step, "estimator"), attr(step, "error_h1_u"));
        let effectivity = eta / error;
        println!(
            "  {k}  {}  {eta:.4e}  {error:.4e}  {effectivity:.2}",
            attr(step, "n_dofs")
        );
        assert!(
            (1.0..=10.0).contains(&effectivity),
            "{label} step {k}: effectivity {effectivity}"
        );
        assert!(
            field(step, "estimator")
                .iter()
                .all(|&e| e > 0.0 && e.is_finite()),
            "{label} step {k}: an indicator ≤ 0"
        );
    }
}

/// Uzawa run for exactly `max_iter` iterations (tolerance 0, KKT stop rule,
/// no progress, cold start): the tests that compare iterates after K steps.
pub fn fixed_uzawa_options(
    step: obstacle_fem::solvers::uzawa::UzawaStep,
    step_form: obstacle_fem::scene::StepForm,
    max_iter: usize,
) -> obstacle_fem::solvers::uzawa::UzawaOptions {
    obstacle_fem::solvers::uzawa::UzawaOptions {
        step,
        step_form,
        max_iter,
        tol: 0.0,
        stop: obstacle_fem::solvers::StopRule::Kkt,
        thesis_tol: 0.0,
        dual_norm: obstacle_fem::solvers::DualNorm::L2,
        show_progress: false,
        initial_lambda: None,
        linear: Default::default(),
    }
}

/// A parameter the solve reported (`SolveReport::parameter`), which the
/// method must report: a missing one fails the test, naming it.
pub fn parameter(report: &obstacle_fem::solvers::SolveReport, name: &str) -> f64 {
    report
        .parameter(name)
        .unwrap_or_else(|| panic!("{}: no parameter {name}", report.algorithm))
}

/// `solvers::solve` of a copy of `problem` (a solve owns the problem it
/// solves and gives it back): its report.
pub fn solve(
    problem: &ContactProblem,
    options: &SolverOptions,
    probes: &[Probe],
) -> obstacle_fem::error::Result<SolveReport> {
    obstacle_fem::solvers::solve(problem.clone(), options, probes).map(|(_, report)| report)
}

/// The active set on a copy of `problem`: its report.
pub fn active_set(
    problem: &ContactProblem,
    options: &ActiveSetOptions,
) -> obstacle_fem::error::Result<SolveReport> {
    obstacle_fem::solvers::active_set::active_set(problem.clone(), options)
        .map(|(_, report)| report)
}
