//! Nothing hangs, nothing aborts, errors name the input (issue 16, part 2):
//! one test per failure the adversarial user found, each failing on the code
//! before the guards (stack overflow, a NaN that compares equal, a zero load
//! reported as failure, unbounded meshing, a gmsh that never returns, a
//! huge declared dataset, errors blaming the wrong thing).

mod common;

use common::{run_obstacle, run_obstacle_env, text};
use obstacle_fem::output::read_result;
use std::path::{Path, PathBuf};
use std::process::Output;

const MEMBRANE: &str = "pipelines/scenes/obstacle-disk.toml";
const SHELL: &str = "pipelines/scenes/naghdi-hypar.toml";

/// One triangle, every vertex and edge on the boundary: P2–P1 has no free
/// unknown and every P1 multiplier acts on boundary dofs only.
const ONE_TRIANGLE: &str = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n3\n1 0 0 0\n2 1 0 0\n3 0 1 0\n$EndNodes\n$Elements\n4\n1 1 2 1 1 1 2\n2 1 2 1 1 2 3\n3 1 2 1 1 3 1\n4 2 2 2 2 1 2 3\n$EndElements\n";

/// The membrane scene on the mesh file `msh`, without errors or plots.
fn membrane_on(dir: &Path, msh: &Path, obstacle: bool) -> PathBuf {
    let mut s = format!(
        "name = \"tri\"\nmodel = \"membrane\"\nelement = \"p2-p1\"\n[mesh]\nfile = \"{}\"\n[load]\ng = -4.0\n",
        msh.display()
    );
    if obstacle {
        // Below the boundary values (u = 0): feasible, so the failure is the
        // multiplier without free unknowns, not the obstacle.
        s.push_str("[obstacle]\nshape = \"paraboloid\"\nheight = -0.5\ncurvature = 1.0\n");
    }
    s.push_str("[solver]\nmethod = \"uzawa\"\nalpha = \"auto\"\nstep_form = \"mean\"\n");
    let path = dir.join(if obstacle {
        "tri.toml"
    } else {
        "tri-free.toml"
    });
    std::fs::write(&path, s).unwrap();
    path
}

/// A failed run with one `error:` line holding every expected word (no
/// panic, no abort: the exit status is 1, not 134).
fn assert_error(o: &Output, expected: &[&str], what: &str) {
    let t = text(o);
    assert_eq!(
        o.status.code(),
        Some(1),
        "{what}: exit status {:?}: {t}",
        o.status
    );
    assert!(!t.contains("panicked"), "{what} panicked: {t}");
    let errors: Vec<&str> = t.lines().filter(|l| l.starts_with("error: ")).collect();
    assert_eq!(errors.len(), 1, "{what}: one error line expected: {t}");
    for e in expected {
        assert!(errors[0].contains(e), "{what}: message lacks `{e}`: {t}");
    }
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn p2_p1_without_free_unknowns_is_refused_or_solved_never_aborts() {
    let dir = tempfile::tempdir().unwrap();
    let msh = dir.path().join("one-triangle.msh");
    std::fs::write(&msh, ONE_TRIANGLE).unwrap();
    let scene = membrane_on(dir.path(), &msh, true);
    let out = dir.path().join("r.h5");
    let expected = ["one-triangle.msh", "p2-p1", "no free unknown"];
    for method in ["uzawa", "active-set", "dual-accelerated", "uzawa-split"] {
        let o = run_obstacle(&[
            "solve",
            s(&scene),
            "--set",
            &format!("solver.method={method}"),
            "--out",
            s(&out),
        ]);
        assert_error(&o, &expected, method);
    }
    let o = run_obstacle(&["bench", "case", s(&scene), "--linear", "--out", s(&out)]);
    assert_error(&o, &expected, "bench case --linear");
    let o = run_obstacle_env(
        &["freefem", s(&scene), "--out", s(&out)],
        &[("FF_LOADPATH", "/usr/lib/freefem++")],
    );
    assert_error(&o, &expected, "freefem");
    assert!(!out.exists());
    // Without an obstacle the problem is legal: u = 0, one (empty) solve.
    let free = membrane_on(dir.path(), &msh, false);
    let o = run_obstacle(&["solve", s(&free), "--out", s(&out)]);
    assert!(o.status.success(), "{}", text(&o));
    let r = read_result(&out).unwrap();
    assert!(common::field(&r, "u").iter().all(|v| *v == 0.0));
}

/// `solve` of the membrane scene with the overrides `sets`, no errors
/// against the exact solution and no plots, into `out`.
fn solve_membrane(out: &Path, sets: &[&str]) -> Output {
    let mut args = vec!["solve", MEMBRANE, "--out", s(out)];
    for set in sets
        .iter()
        .chain(&["output.errors=false", "output.plots=[]"])
    {
        args.extend(["--set", set]);
    }
    run_obstacle(&args)
}

/// A small membrane result file (n = 4, active set).
fn small_result(dir: &Path, name: &str) -> PathBuf {
    let out = dir.join(name);
    let o = solve_membrane(&out, &["mesh.n=4", "solver.method=active-set"]);
    assert!(o.status.success(), "{}", text(&o));
    out
}

#[test]
fn compare_refuses_nan_tolerance_and_reports_nan_values() {
    let dir = tempfile::tempdir().unwrap();
    let a = small_result(dir.path(), "a.h5");
    let b = dir.path().join("b.h5");
    std::fs::copy(&a, &b).unwrap();
    let o = run_obstacle(&["compare", s(&a), s(&b), "--rtol", "nan"]);
    assert_error(&o, &["--rtol", "finite"], "--rtol nan");
    // The same file with one NaN in /fields/u: a difference, not 0.
    {
        let f = hdf5::File::open_rw(&b).unwrap();
        let ds = f.dataset("fields/u").unwrap();
        let mut u: Vec<f64> = ds.read_raw().unwrap();
        u[0] = f64::NAN;
        ds.write_raw(&u).unwrap();
    }
    let o = run_obstacle(&["compare", s(&a), s(&b), "--fields", "u"]);
    assert_error(&o, &["beyond rtol", "fields/u (inf)"], "NaN in B");
    assert!(text(&o).contains("| NO |"), "{}", text(&o));
}

#[test]
fn zero_load_with_the_obstacle_pushing_converges() {
    let dir = tempfile::tempdir().unwrap();
    for method in ["uzawa", "active-set"] {
        let out = dir.path().join(format!("{method}.h5"));
        let method_set = format!("solver.method={method}");
        let o = solve_membrane(&out, &["load.g=0", "mesh.n=8", &method_set]);
        let t = text(&o);
        assert!(o.status.success(), "{method}: {t}");
        assert!(t.contains("converged: true"), "{method}: {t}");
        assert!(!t.contains("warning"), "{method}: {t}");
        // The obstacle (φ(0) = 0.3) lifts the membrane to about its top (the
        // P0 constraint holds on triangle means: 0.3029 at the centre).
        let r = read_result(&out).unwrap();
        let u_max = common::field(&r, "u").iter().fold(0.0f64, |m, v| m.max(*v));
        assert!((u_max - 0.3).abs() < 0.01, "{method}: max u = {u_max}");
    }
}

#[test]
fn a_mesh_beyond_memory_is_refused_before_meshing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("big.h5");
    let o = run_obstacle(&[
        "solve",
        MEMBRANE,
        "--set",
        "mesh.n=100000",
        "--out",
        s(&out),
    ]);
    assert_error(
        &o,
        &[
            "mesh.n",
            "before meshing",
            "2.900e10 triangles",
            "GB",
            "mesh.memory_limit_gb",
        ],
        "mesh.n = 100000",
    );
    assert!(!out.with_extension("msh").exists());
    // The limit is the scene's when given: a tiny one refuses even n = 4
    // after meshing too (the estimate from the mesh itself).
    let o = run_obstacle(&[
        "solve",
        MEMBRANE,
        "--set",
        "mesh.h=0.5",
        "--set",
        "mesh.memory_limit_gb=1e-6",
        "--out",
        s(&out),
    ]);
    assert_error(
        &o,
        &[
            "mesh.h",
            "the mesh",
            "limit 0.000 GB = mesh.memory_limit_gb",
        ],
        "limit",
    );
}

#[test]
fn a_looping_geo_is_killed_after_the_time_limit() {
    let dir = tempfile::tempdir().unwrap();
    let geo = dir.path().join("loop.geo");
    std::fs::write(&geo, "x = 0;\nFor i In {1:1e15}\n  x = x + 1;\nEndFor\n").unwrap();
    let scene = dir.path().join("loop.toml");
    let text_of_scene = std::fs::read_to_string(MEMBRANE)
        .unwrap()
        .replace("../../meshes/disk.geo", s(&geo));
    std::fs::write(&scene, text_of_scene).unwrap();
    let o = run_obstacle_env(
        &["mesh", s(&scene), "--out", s(&dir.path().join("m.msh"))],
        &[("OBSTACLE_TOOL_TIMEOUT", "1")],
    );
    assert_error(
        &o,
        &["gmsh", "loop.geo", "within 1 s", "OBSTACLE_TOOL_TIMEOUT"],
        "loop",
    );
    let o = run_obstacle_env(&["mesh", s(&scene)], &[("OBSTACLE_TOOL_TIMEOUT", "soon")]);
    assert_error(&o, &["OBSTACLE_TOOL_TIMEOUT", "soon"], "bad limit");
}

#[test]
fn a_huge_declared_dataset_is_refused_without_allocating_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = small_result(dir.path(), "huge.h5");
    {
        let f = hdf5::File::open_rw(&path).unwrap();
        let dofs = f.group("dofs").unwrap();
        dofs.unlink("u").unwrap();
        // 1e9 entries declared, none written: the file stays small.
        dofs.new_dataset::<f64>()
            .shape([1_000_000_000usize])
            .create("u")
            .unwrap();
    }
    assert!(std::fs::metadata(&path).unwrap().len() < 1_000_000);
    let o = run_obstacle(&["info", s(&path)]);
    assert_error(
        &o,
        &["huge.h5", "/dofs/u", "declares 8000000000 bytes"],
        "info",
    );
}

#[test]
fn extreme_values_name_the_scene_key_or_the_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.h5");
    let cases: &[(&str, &str, &str)] = &[
        (MEMBRANE, "load.g=1e308", "field `load.g`"),
        (MEMBRANE, "solver.alpha=1e300", "field `solver.alpha`"),
        (
            MEMBRANE,
            "solver.alpha=\"AUTO\"",
            "field `solver.alpha`: must be a positive number or \"auto\", got \"AUTO\"",
        ),
        (SHELL, "shell.young=1e308", "field `shell.young`"),
        (SHELL, "shell.thickness=1e-300", "field `shell.thickness`"),
        (
            SHELL,
            "shell.young=1e-100",
            "shell.young × shell.thickness³",
        ),
    ];
    for (scene, set, expected) in cases {
        let o = run_obstacle(&["solve", scene, "--set", set, "--out", s(&out)]);
        assert_error(&o, &[expected], set);
        assert!(text(&o).len() < 400, "{set}: a long message: {}", text(&o));
    }
    for (scale, name) in [("e150", "big"), ("e-160", "small")] {
        let msh = dir.path().join(format!("{name}.msh"));
        let scaled = ONE_TRIANGLE
            .replace("2 1 0 0\n", &format!("2 1{scale} 0 0\n"))
            .replace("3 0 1 0\n", &format!("3 0 1{scale} 0\n"));
        std::fs::write(&msh, scaled).unwrap();
        let scene = membrane_on(dir.path(), &msh, false);
        let o = run_obstacle(&["solve", s(&scene), "--out", s(&out)]);
        assert_error(&o, &[&format!("{name}.msh"), "[1e-50, 1e50]"], name);
    }
    let o = run_obstacle(&["hard", s(&dir.path().join("no-such-folder"))]);
    assert_error(&o, &["no-such-folder", "no such folder"], "hard");
    assert!(text(&o).lines().count() <= 2, "{}", text(&o));
}

/// Writes `bytes`, which need not be UTF-8, as the string attribute `name`
/// of `loc`: fixed-length ASCII (what h5py makes of `np.bytes_`) or
/// variable-length UTF-8, replacing an attribute of that name.
fn write_raw_string_attr(loc: &hdf5::Location, name: &str, bytes: &[u8], fixed: bool) {
    use hdf5::types::{FixedAscii, VarLenUnicode};
    if loc.attr(name).is_ok() {
        loc.delete_attr(name).unwrap();
    }
    if fixed {
        // SAFETY: the value is only written out; nothing reads it as text.
        let v = unsafe { FixedAscii::<16>::from_ascii_unchecked(bytes) };
        let a = loc.new_attr::<FixedAscii<16>>().create(name).unwrap();
        a.write_scalar(&v).unwrap();
    } else {
        // SAFETY: as above.
        let v = unsafe { VarLenUnicode::from_str_unchecked(std::str::from_utf8_unchecked(bytes)) };
        let a = loc.new_attr::<VarLenUnicode>().create(name).unwrap();
        a.write_scalar(&v).unwrap();
    }
}

#[test]
fn string_attributes_that_are_not_utf8_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let good = small_result(dir.path(), "good.h5");
    let cases: &[(&str, &str, &str, &[u8], bool)] = &[
        ("scene-fixed.h5", "/", "scene", b"\xff", true),
        (
            "scene-varlen.h5",
            "/",
            "scene",
            b"name = \"\xc3\x28\"",
            false,
        ),
        ("algorithm.h5", "solver", "algorithm", b"uzawa\xff", true),
        ("location.h5", "fields/u", "location", b"vert\xe9x", false),
    ];
    for (name, object, attr, bytes, fixed) in cases {
        let path = dir.path().join(name);
        std::fs::copy(&good, &path).unwrap();
        {
            let f = hdf5::File::open_rw(&path).unwrap();
            if *object == "/" {
                write_raw_string_attr(&f, attr, bytes, *fixed);
            } else if let Ok(g) = f.group(object) {
                write_raw_string_attr(&g, attr, bytes, *fixed);
            } else {
                write_raw_string_attr(&f.dataset(object).unwrap(), attr, bytes, *fixed);
            }
        }
        let expected = [*name, &format!("attribute `{attr}`"), "not valid UTF-8"];
        let o = run_obstacle(&["info", s(&path)]);
        assert_error(&o, &expected, &format!("info {name}"));
        let page = dir.path().join(format!("{name}.html"));
        let o = run_obstacle(&["report", s(&path), "--out", s(&page)]);
        assert_error(&o, &expected, &format!("report {name}"));
        assert!(!page.exists(), "{name}: a page was written");
    }
}
