//! Bad input (issue 6): each case gets one clear message naming the file,
//! the field and the reason, a non-zero exit, no panic, no partial result
//! file, and an existing result is never clobbered by a failed run. Same
//! input gives bit-identical result datasets.

mod common;

use common::{assert_one_error, run_obstacle, run_obstacle_env, solve_membrane, text};

use obstacle_fem::output::{read_result, AttrValue, ResultFile};
use std::path::{Path, PathBuf};
use std::process::Output;

const MEMBRANE: &str = "pipelines/scenes/obstacle-disk.toml";
const SHELL: &str = "pipelines/scenes/naghdi-hypar.toml";

/// The run fails with one `error:` line containing every expected word,
/// without a panic, and `out` (and its companions) do not exist.
fn assert_clear_failure(o: &Output, expected: &[&str], out: &Path, what: &str) {
    assert_one_error(o, expected, what);
    for ext in ["h5", "xdmf", "msh"] {
        assert!(
            !out.with_extension(ext).exists(),
            "{what} left a .{ext} file"
        );
    }
    assert_no_partial_files(out.parent().unwrap(), what);
}

fn assert_no_partial_files(dir: &Path, what: &str) {
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().to_string();
            assert!(
                !name.contains("partial") && !name.starts_with(".tmp"),
                "{what} left a temporary file {name}"
            );
        }
    }
}

/// A scene file without the mesh keys, meshed from `mesh_lines`.
fn write_scene(dir: &Path, name: &str, base: &str, mesh_lines: &str) -> PathBuf {
    let text = std::fs::read_to_string(base).unwrap();
    let mut out = String::new();
    let mut in_mesh = false;
    for line in text.lines() {
        if line.starts_with('[') {
            in_mesh = line.trim() == "[mesh]";
            out.push_str(line);
            out.push('\n');
            if in_mesh {
                out.push_str(mesh_lines);
                out.push('\n');
            }
            continue;
        }
        if !in_mesh {
            out.push_str(line);
            out.push('\n');
        }
    }
    let path = dir.join(name);
    std::fs::write(&path, out).unwrap();
    path
}

#[test]
fn malformed_toml_and_unknown_keys() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.h5");
    let o_str = out.to_str().unwrap();
    let broken = dir.path().join("broken.toml");
    std::fs::write(&broken, "name = \"x\"\nmodel = [\n").unwrap();
    let o = run_obstacle(&["solve", broken.to_str().unwrap(), "--out", o_str]);
    assert_clear_failure(
        &o,
        &["broken.toml", "not valid TOML"],
        &out,
        "malformed TOML",
    );
    // TOML's own lines follow: the position and the caret under `[`.
    let t = String::from_utf8_lossy(&o.stderr);
    assert!(
        t.contains("line 2, column 10") && t.contains("|          ^"),
        "{t}"
    );
    let missing = dir.path().join("missing.toml");
    let o = run_obstacle(&["solve", missing.to_str().unwrap(), "--out", o_str]);
    assert_clear_failure(&o, &["missing.toml", "cannot read"], &out, "missing scene");
    for (set, field) in [
        ("shell.youngs=1", "youngs"),
        ("solver.alpah=0.1", "alpah"),
        ("shell.chart.radius=3", "radius"),
        ("output.plot=[]", "plot"),
        ("shell.young=\"big\"", "shell.young"),
        ("mesh.n=1.5", "mesh.n"),
        ("solver.method=newton", "solver.method"),
        ("solver.linear=multigrid", "solver.linear"),
    ] {
        let o = run_obstacle(&["solve", SHELL, "--set", set, "--out", o_str]);
        assert_clear_failure(&o, &["naghdi-hypar.toml", field], &out, set);
    }
}

#[test]
fn out_of_range_values_name_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.h5");
    let o_str = out.to_str().unwrap();
    let cases: &[(&str, &str, &[&str])] = &[
        (SHELL, "shell.poisson=0.5", &["shell.poisson", "[0, 1/2)"]),
        (SHELL, "shell.poisson=0.7", &["shell.poisson"]),
        (SHELL, "shell.young=0", &["shell.young", "> 0"]),
        (SHELL, "shell.young=-2.85e4", &["shell.young", "> 0"]),
        (SHELL, "shell.thickness=0", &["shell.thickness", "> 0"]),
        (SHELL, "shell.thickness=-0.8", &["shell.thickness", "> 0"]),
        (SHELL, "shell.rho=-1", &["shell.rho", "≥ 0"]),
        (SHELL, "solver.alpha=0", &["solver.alpha", "> 0"]),
        (SHELL, "solver.alpha=-0.01", &["solver.alpha", "> 0"]),
        (SHELL, "solver.tol=0", &["solver.tol", "> 0"]),
        (SHELL, "solver.max_iter=0", &["solver.max_iter"]),
        (SHELL, "mesh.n=0", &["mesh.n"]),
        (SHELL, "mesh.h=-1", &["mesh.h", "> 0"]),
        (SHELL, "shell.chart.r=0", &["shell.chart", "r must be"]),
        (MEMBRANE, "solver.alpha=0", &["solver.alpha", "> 0"]),
    ];
    for (scene, set, expected) in cases {
        let o = run_obstacle(&["solve", scene, "--set", set, "--out", o_str]);
        assert_clear_failure(&o, expected, &out, set);
    }
    // α as a multiple of the stability bound: > 0, ≤ 100, Uzawa only, not with alpha.
    for (extra, expected) in [
        (&["solver.alpha_factor=0"][..], "> 0"),
        (&["solver.alpha_factor=1e3"][..], "≤ 100"),
        (&["solver.alpha_factor=0.5"][..], "not both"),
    ] {
        let mut args = vec!["solve", SHELL, "--out", o_str];
        for e in extra {
            args.extend(["--set", e]);
        }
        let o = run_obstacle(&args);
        assert_clear_failure(&o, &["solver.alpha_factor", expected], &out, extra[0]);
    }
}

/// Every float a scene can hold, set to NaN, +inf and −inf, is rejected by name.
#[test]
fn nan_and_inf_anywhere_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.h5");
    let o_str = out.to_str().unwrap();
    // (scene, extra overrides, field with the bad value as `{}`, field named in the message)
    let cases: &[(&str, &[&str], &str, &str)] = &[
        (SHELL, &[], "mesh.h={}", "mesh.h"),
        (SHELL, &[], "load.f=[0.0, {}, -0.25]", "load.f[1]"),
        (
            SHELL,
            &["shell.clamped=[\"ne\", \"nw\", \"sw\"]"],
            "load.edge=[{{part = \"se\", traction = [0.0, 0.0, {}]}}]",
            "load.edge[0].traction[2]",
        ),
        (
            SHELL,
            &["shell.clamped=[\"ne\", \"nw\", \"sw\"]"],
            "load.edge=[{{part = \"se\", moment = [{}, 0.0, 0.0]}}]",
            "load.edge[0].moment[0]",
        ),
        (SHELL, &[], "shell.young={}", "shell.young"),
        (SHELL, &[], "shell.poisson={}", "shell.poisson"),
        (SHELL, &[], "shell.thickness={}", "shell.thickness"),
        (SHELL, &[], "shell.rho={}", "shell.rho"),
        (SHELL, &[], "shell.chart.r={}", "shell.chart"),
        (SHELL, &[], "shell.chart.offset={}", "shell.chart"),
        (
            SHELL,
            &[],
            "shell.chart={{kind = \"plate\", height = {}}}",
            "shell.chart",
        ),
        (
            SHELL,
            &[],
            "shell.chart={{kind = \"cylinder\", radius = {}, height = 0.0}}",
            "shell.chart",
        ),
        (
            SHELL,
            &[],
            "shell.chart={{kind = \"cylinder\", radius = 100.0, height = {}}}",
            "shell.chart",
        ),
        (
            SHELL,
            &[],
            "shell.chart={{kind = \"curvature-kink\", r = {}, offset = 1.4}}",
            "shell.chart",
        ),
        (SHELL, &[], "obstacle.height={}", "obstacle.height"),
        (SHELL, &[], "solver.alpha={}", "solver.alpha"),
        (
            SHELL,
            &["solver.alpha=\"auto\""],
            "solver.tol={}",
            "solver.tol",
        ),
        (SHELL, &[], "solver.thesis_tol={}", "solver.thesis_tol"),
        (MEMBRANE, &[], "load.g={}", "load.g"),
        (MEMBRANE, &[], "obstacle.height={}", "obstacle.height"),
        (MEMBRANE, &[], "obstacle.curvature={}", "obstacle.curvature"),
        (MEMBRANE, &[], "solver.alpha={}", "solver.alpha"),
    ];
    for (scene, extra, template, field) in cases {
        for bad in ["nan", "inf", "-inf"] {
            let set = template
                .replace("{}", bad)
                .replace("{{", "{")
                .replace("}}", "}");
            let mut args = vec!["solve", scene, "--out", o_str];
            for e in *extra {
                args.extend(["--set", e]);
            }
            args.extend(["--set", &set]);
            let o = run_obstacle(&args);
            // "must be a finite number, got NaN" or "must lie in [0, 1/2), got NaN".
            let shown = if bad == "nan" { "NaN" } else { "inf" };
            assert_clear_failure(&o, &[field, shown], &out, &set);
        }
    }
    // alpha_factor needs `alpha` removed: a scene file without it.
    let text = std::fs::read_to_string(SHELL)
        .unwrap()
        .replace("alpha = 0.01", "alpha_factor = nan");
    let scene = dir.path().join("factor.toml");
    std::fs::write(&scene, text.replace("../../meshes", "/nonexistent")).unwrap();
    let o = run_obstacle(&["solve", scene.to_str().unwrap(), "--out", o_str]);
    assert_clear_failure(&o, &["solver.alpha_factor", "finite"], &out, "alpha_factor");
    let o = run_obstacle(&[
        "solve",
        scene.to_str().unwrap(),
        "--set",
        "solver.alpha_factor=0.5",
        "--set",
        "solver.method=active-set",
        "--out",
        o_str,
    ]);
    assert_clear_failure(
        &o,
        &["solver.alpha_factor", "only Uzawa"],
        &out,
        "alpha_factor method",
    );
}

#[test]
fn missing_or_failing_gmsh() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.h5");
    let o_str = out.to_str().unwrap();
    // No gmsh on PATH.
    let empty = dir.path().join("empty-bin");
    std::fs::create_dir(&empty).unwrap();
    let o = run_obstacle_env(
        &["solve", SHELL, "--out", o_str],
        &[("PATH", empty.to_str().unwrap())],
    );
    assert_clear_failure(&o, &["gmsh", "diamond.geo", "not found"], &out, "no gmsh");
    // gmsh fails on a broken .geo.
    let geo = dir.path().join("bad.geo");
    std::fs::write(&geo, "Point(1) = {0, 0, 0;\nthis is not gmsh\n").unwrap();
    let set = format!("mesh.geo=\"{}\"", geo.display());
    let o = run_obstacle(&["solve", SHELL, "--set", &set, "--out", o_str]);
    assert_clear_failure(&o, &["gmsh", "bad.geo"], &out, "bad .geo");
    // A .geo without triangles (a curve only).
    std::fs::write(
        &geo,
        "Point(1) = {0, 0, 0};\nPoint(2) = {1, 0, 0};\nLine(1) = {1, 2};\n",
    )
    .unwrap();
    let o = run_obstacle(&["solve", SHELL, "--set", &set, "--out", o_str]);
    assert_clear_failure(&o, &["bad.geo"], &out, "geo without a surface");
}

/// A unit square: 4 corners, the centre, 4 triangles, 4 tagged boundary lines.
fn square_msh(nodes_extra: &str, elements: &[&str]) -> String {
    let mut s = String::from(
        "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$PhysicalNames\n2\n1 1 \"boundary\"\n2 2 \"domain\"\n$EndPhysicalNames\n",
    );
    s.push_str("$Nodes\n5\n1 0 0 0\n2 1 0 0\n3 1 1 0\n4 0 1 0\n");
    s.push_str(nodes_extra);
    s.push_str("$EndNodes\n$Elements\n");
    s.push_str(&format!("{}\n", elements.len()));
    for (i, e) in elements.iter().enumerate() {
        s.push_str(&format!("{} {e}\n", i + 1));
    }
    s.push_str("$EndElements\n");
    s
}

const LINES: [&str; 4] = ["1 2 1 1 1 2", "1 2 1 1 2 3", "1 2 1 1 3 4", "1 2 1 1 4 1"];
const TRIS: [&str; 4] = [
    "2 2 2 2 1 2 5",
    "2 2 2 2 2 3 5",
    "2 2 2 2 3 4 5",
    "2 2 2 2 4 1 5",
];

#[test]
fn invalid_meshes_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.h5");
    let o_str = out.to_str().unwrap();
    let centre = "5 0.5 0.5 0\n";
    let all = |tris: &[&str], lines: &[&str]| -> Vec<String> {
        lines.iter().chain(tris).map(|s| s.to_string()).collect()
    };
    let cases: Vec<(&str, String, Vec<String>, &[&str])> = vec![
        ("good", centre.into(), all(&TRIS, &LINES), &[]),
        (
            "duplicate",
            centre.into(),
            all(&[TRIS[0], TRIS[1], TRIS[2], TRIS[3], TRIS[1]], &LINES),
            &["duplicate triangle"],
        ),
        (
            "degenerate",
            "5 0.5 0 0\n".into(),
            all(&TRIS, &LINES),
            &["degenerate triangle"],
        ),
        (
            "inverted",
            centre.into(),
            all(&[TRIS[0], "2 2 2 2 3 2 5", TRIS[2], TRIS[3]], &LINES),
            &["inverted (clockwise) triangle"],
        ),
        (
            "untagged",
            centre.into(),
            all(&TRIS, &LINES[..3]),
            &["no tagged line element"],
        ),
    ];
    for (name, nodes, elements, expected) in cases {
        let msh = dir.path().join(format!("{name}.msh"));
        let refs: Vec<&str> = elements.iter().map(String::as_str).collect();
        std::fs::write(&msh, square_msh(&nodes, &refs)).unwrap();
        let scene = write_scene(
            dir.path(),
            &format!("{name}.toml"),
            MEMBRANE,
            &format!("file = \"{}\"", msh.display()),
        );
        let o = run_obstacle(&[
            "solve",
            scene.to_str().unwrap(),
            "--set",
            "output.plots=[]",
            "--set",
            "output.errors=false",
            // The unit square's corner (0, 0) is on the boundary (u = 0):
            // the disk's obstacle (0.3 there) would be infeasible.
            "--set",
            "obstacle.height=-0.5",
            "--out",
            o_str,
        ]);
        if expected.is_empty() {
            assert!(o.status.success(), "the good square solves: {}", text(&o));
            std::fs::remove_file(&out).unwrap();
            std::fs::remove_file(out.with_extension("xdmf")).unwrap();
            continue;
        }
        let mut words = vec![msh.file_name().unwrap().to_str().unwrap()];
        words.extend_from_slice(expected);
        assert_clear_failure(&o, &words, &out, name);
    }
}

/// A chart whose |a1×a2| is not a number on the mesh (r² underflows).
#[test]
fn singular_chart_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.h5");
    let o = run_obstacle(&[
        "solve",
        SHELL,
        "--set",
        "shell.chart.r=1e-200",
        "--set",
        "mesh.n=4",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_clear_failure(&o, &["shell.chart", "singular"], &out, "singular chart");
}

#[test]
fn unwritable_output_paths() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("a-file");
    std::fs::write(&file, "x").unwrap();
    for out in [
        file.join("r.h5"),
        PathBuf::from("/proc/forbidden/r.h5"),
        dir.path().join("r.txt"),
    ] {
        let o = run_obstacle(&[
            "solve",
            MEMBRANE,
            "--set",
            "mesh.n=4",
            "--out",
            out.to_str().unwrap(),
        ]);
        let t = text(&o);
        assert!(!o.status.success(), "{t}");
        assert!(!t.contains("panicked"), "{t}");
        let name = out.to_str().unwrap();
        assert!(
            t.contains(name) || t.contains(out.parent().unwrap().to_str().unwrap()),
            "{t}"
        );
    }
    assert_no_partial_files(dir.path(), "unwritable");
}

fn solve_small(out: &Path, extra: &[&str]) -> Output {
    let mut sets = vec!["mesh.n=6", "output.plots=[]"];
    sets.extend(extra);
    solve_membrane(out, &sets)
}

#[test]
fn truncated_or_foreign_hdf5_given_to_info() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.h5");
    let o = solve_small(&good, &[]);
    assert!(o.status.success(), "{}", text(&o));
    let bytes = std::fs::read(&good).unwrap();
    let truncated = dir.path().join("truncated.h5");
    for cut in [bytes.len() / 2, 600, 8] {
        std::fs::write(&truncated, &bytes[..cut]).unwrap();
        let o = run_obstacle(&["info", truncated.to_str().unwrap()]);
        let t = text(&o);
        assert!(!o.status.success(), "cut {cut}: {t}");
        assert!(!t.contains("panicked"), "{t}");
        assert!(t.contains("error: ") && t.contains("truncated.h5"), "{t}");
    }
    // A valid HDF5 file that is not a result file.
    let foreign = dir.path().join("foreign.h5");
    {
        let f = hdf5::File::create(&foreign).unwrap();
        f.new_dataset::<f64>()
            .shape([3])
            .create("data")
            .unwrap()
            .write(&[1.0, 2.0, 3.0])
            .unwrap();
    }
    let o = run_obstacle(&["info", foreign.to_str().unwrap()]);
    let t = text(&o);
    assert!(!o.status.success(), "{t}");
    assert!(!t.contains("panicked"), "{t}");
    assert!(t.contains("error: ") && t.contains("foreign.h5"), "{t}");
    // `compare` names the bad file too, whichever side it is on.
    for bad in [&truncated, &foreign] {
        for args in [
            ["compare", good.to_str().unwrap(), bad.to_str().unwrap()],
            ["compare", bad.to_str().unwrap(), good.to_str().unwrap()],
        ] {
            let o = run_obstacle(&args);
            let t = text(&o);
            assert!(!o.status.success(), "{args:?}: {t}");
            assert!(!t.contains("panicked"), "{t}");
            let name = bad.file_name().unwrap().to_str().unwrap();
            assert!(t.contains("error: ") && t.contains(name), "{args:?}: {t}");
        }
    }
    // An empty file and a folder.
    let empty = dir.path().join("empty.h5");
    std::fs::write(&empty, b"").unwrap();
    for p in [&empty, &dir.path().to_path_buf()] {
        let o = run_obstacle(&["info", p.to_str().unwrap()]);
        let t = text(&o);
        assert!(!o.status.success() && !t.contains("panicked"), "{t}");
    }
}

/// A failed run with the same --out leaves the existing .h5, .xdmf and .msh
/// byte for byte as they were, and no temporary files.
#[test]
fn failed_runs_never_clobber_an_existing_result() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.h5");
    let o = solve_small(&out, &[]);
    assert!(o.status.success(), "{}", text(&o));
    let snapshot: Vec<(PathBuf, Vec<u8>)> = ["h5", "xdmf", "msh"]
        .iter()
        .map(|e| {
            let p = out.with_extension(e);
            let b = std::fs::read(&p).unwrap_or_else(|_| panic!("{} exists", p.display()));
            (p, b)
        })
        .collect();
    // Fails after meshing (divergence), in the model setup (bad Dirichlet
    // name), in scene validation, and in gmsh.
    for extra in [
        &["solver.alpha=30", "solver.max_iter=2000"][..],
        &["mesh.dirichlet=[\"nowhere\"]"][..],
        &["solver.tol=nan"][..],
        &["mesh.geo=\"missing.geo\""][..],
    ] {
        let o = solve_small(&out, extra);
        let t = text(&o);
        assert!(!o.status.success(), "{extra:?}: {t}");
        assert!(!t.contains("panicked"), "{t}");
        for (p, b) in &snapshot {
            assert!(
                std::fs::read(p).unwrap() == *b,
                "{extra:?} changed {}",
                p.display()
            );
        }
        assert_no_partial_files(dir.path(), extra[0]);
    }
}

fn datasets(file: &ResultFile) -> Vec<(String, Vec<u64>)> {
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<u64>>();
    let d = &file.data;
    let mut out: Vec<(String, Vec<u64>)> = Vec::new();
    out.push((
        "mesh/vertices".into(),
        bits(&file.vertices.iter().flatten().copied().collect::<Vec<_>>()),
    ));
    out.push((
        "mesh/triangles".into(),
        file.triangles.iter().flatten().map(|&v| v as u64).collect(),
    ));
    for f in &d.fields {
        out.push((format!("fields/{}", f.name), bits(&f.values)));
    }
    for (n, v) in &d.dofs {
        out.push((format!("dofs/{n}"), bits(v)));
    }
    for (n, v) in &d.history {
        out.push((format!("solver/history/{n}"), bits(v)));
    }
    for (n, v) in d.solver_attrs.iter().chain(&d.root_attrs) {
        if n.contains("seconds") || n.starts_with("peak_rss_mb") {
            continue; // wall-time and memory attributes
        }
        let b = match v {
            AttrValue::F64(x) => vec![x.to_bits()],
            AttrValue::I64(x) => vec![*x as u64],
            AttrValue::Bool(x) => vec![*x as u64],
            AttrValue::Str(s) => s.bytes().map(u64::from).collect(),
        };
        out.push((format!("attr {n}"), b));
    }
    out
}

#[test]
fn same_input_gives_bit_identical_datasets() {
    let dir = tempfile::tempdir().unwrap();
    for (scene, extra) in [
        (MEMBRANE, &["mesh.n=6", "output.plots=[]"][..]),
        (
            "pipelines/scenes/hard/thin-0.08-contact.toml",
            &["mesh.n=8"][..],
        ),
    ] {
        let mut files = Vec::new();
        for run in 0..2 {
            let out = dir.path().join(format!("run{run}.h5"));
            let mut args = vec!["solve", scene, "--out", out.to_str().unwrap()];
            for e in extra {
                args.extend(["--set", e]);
            }
            let o = run_obstacle(&args);
            assert!(o.status.success(), "{}", text(&o));
            files.push(datasets(&read_result(&out).unwrap()));
        }
        assert!(files[0].len() > 10, "{scene}: datasets compared");
        assert_eq!(files[0], files[1], "{scene}: two runs differ");
    }
}

/// A FreeFEM comparison without FreeFem++ on PATH (gmsh still there): one
/// clear error naming the tool, no result file.
#[test]
fn freefem_missing_when_a_comparison_is_asked() {
    let dir = tempfile::tempdir().unwrap();
    let bin = dir.path().join("bin");
    std::fs::create_dir(&bin).unwrap();
    let gmsh = std::env::split_paths(&std::env::var_os("PATH").unwrap())
        .map(|p| p.join("gmsh"))
        .find(|p| p.is_file())
        .expect("gmsh on PATH");
    std::os::unix::fs::symlink(gmsh, bin.join("gmsh")).unwrap();
    let out = dir.path().join("ff.h5");
    let o = run_obstacle_env(
        &[
            "freefem",
            MEMBRANE,
            "--set",
            "mesh.n=4",
            "--iterations",
            "5",
            "--out",
            out.to_str().unwrap(),
        ],
        &[("PATH", bin.to_str().unwrap())],
    );
    let t = text(&o);
    assert!(!o.status.success(), "{t}");
    assert!(!t.contains("panicked"), "{t}");
    assert!(t.contains("error: ") && t.contains("FreeFem++"), "{t}");
    assert!(!out.exists() && !out.with_extension("xdmf").exists());
}
