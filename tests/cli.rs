//! The `obstacle` command line: a user's mesh file, `info`, and clear errors
//! (file, field, reason; non-zero exit; nothing half-written).

mod common;

use common::{run_obstacle, text};

use std::path::Path;

const SCENE: &str = "pipelines/scenes/obstacle-disk.toml";

#[test]
fn solve_on_a_users_mesh_file_and_info() {
    let dir = tempfile::tempdir().unwrap();
    let msh = dir.path().join("user.msh");
    let o = run_obstacle(&[
        "mesh",
        SCENE,
        "--set",
        "mesh.n=6",
        "--out",
        msh.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("vertices"));
    // `--set mesh.file=…` replaces the scene's geo and h; on the command line a
    // relative path is relative to where the command runs.
    let out = dir.path().join("r.h5");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_obstacle"))
        .current_dir(dir.path())
        .env("CI", "1")
        .args([
            "solve",
            common::manifest_path(SCENE).to_str().unwrap(),
            "--set",
            "mesh.file=user.msh",
            "--set",
            "output.plots=[]",
            "--out",
            "r.h5",
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let run = obstacle_fem::output::read_result(&out).unwrap();
    let recorded = &run.data.scene_text;
    assert!(
        recorded.contains(&format!("file = \"{}\"", msh.display()))
            && !recorded.contains("geo =")
            && !recorded.contains("h = 0.1"),
        "the scene as run: {recorded}"
    );
    let user_mesh = obstacle_fem::mesh::Mesh::read_msh(&msh).unwrap();
    assert_eq!(run.vertices.len(), user_mesh.n_vertices());
    // And back: `--set mesh.geo=…` on a scene that names a file.
    let scene_text = std::fs::read_to_string(SCENE)
        .unwrap()
        .replace(
            "geo = \"../../meshes/disk.geo\"",
            &format!("file = \"{}\"", msh.display()),
        )
        .replace("h = 0.1 ", "# h = 0.1 ");
    let scene = dir.path().join("user.toml");
    std::fs::write(&scene, scene_text).unwrap();
    let o = run_obstacle(&[
        "solve",
        scene.to_str().unwrap(),
        "--set",
        "output.plots=[]",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(out.exists() && out.with_extension("xdmf").exists());
    let geo = common::manifest_path("meshes/disk.geo");
    let meshed = dir.path().join("meshed.h5");
    let o = run_obstacle(&[
        "solve",
        scene.to_str().unwrap(),
        "--set",
        &format!("mesh.geo={}", geo.display()),
        "--set",
        "mesh.n=4",
        "--set",
        "output.plots=[]",
        "--out",
        meshed.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let recorded = obstacle_fem::output::read_result(&meshed)
        .unwrap()
        .data
        .scene_text;
    assert!(
        recorded.contains("geo =") && !recorded.contains("file ="),
        "{recorded}"
    );
    let o = run_obstacle(&["info", out.to_str().unwrap()]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    for word in ["lambda", "gap_mean", "kkt", "iterations", "converged"] {
        assert!(t.contains(word), "info lacks {word}: {t}");
    }
}

#[test]
fn bad_input_is_one_clear_error_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bad.h5");
    let o_str = out.to_str().unwrap();
    let cases: &[(&[&str], &[&str])] = &[
        (
            &["--set", "solver.alpah=1"],
            &["obstacle-disk.toml", "alpah"],
        ),
        (&["--set", "solver.alpha=-1"], &["solver.alpha", "> 0"]),
        (
            &["--set", "mesh.dirichlet=[\"nowhere\"]", "--set", "mesh.n=4"],
            &["mesh.dirichlet", "nowhere", "boundary"],
        ),
        (&["--set", "mesh.geo=\"missing.geo\""], &["missing.geo"]),
        (
            &["--set", "mesh.n=4", "--set", "solver.alpha=30"],
            &["diverged", "2/s_max"],
        ),
    ];
    for (args, expected) in cases {
        let mut all = vec!["solve", SCENE, "--out", o_str];
        all.extend_from_slice(args);
        let o = run_obstacle(&all);
        let t = text(&o);
        assert!(!o.status.success(), "{args:?} should fail: {t}");
        assert!(t.starts_with("error: ") || t.contains("\nerror: "), "{t}");
        for e in *expected {
            assert!(t.contains(e), "{args:?}: message lacks `{e}`: {t}");
        }
        assert!(!t.contains("panicked"), "{t}");
        assert!(!out.exists(), "{args:?} left a result file");
    }
    // An unwritable output folder, and a foreign file given to `info`.
    let o = run_obstacle(&[
        "solve",
        SCENE,
        "--set",
        "mesh.n=4",
        "--out",
        "/proc/forbidden/r.h5",
    ]);
    assert!(
        !o.status.success() && text(&o).contains("/proc/forbidden"),
        "{}",
        text(&o)
    );
    let foreign = dir.path().join("foreign.h5");
    std::fs::write(&foreign, b"not hdf5 at all").unwrap();
    let o = run_obstacle(&["info", foreign.to_str().unwrap()]);
    assert!(
        !o.status.success() && text(&o).contains("foreign.h5"),
        "{}",
        text(&o)
    );
    assert!(!Path::new(&foreign).with_extension("xdmf").exists());
}

/// A reader that is gone before anything is printed (`obstacle info FILE |
/// head -0`): the command ends quietly with 141 (128 + SIGPIPE), no panic,
/// nothing on stderr. Also `compare` (a table) and `solve` (its line after
/// the result is in place, which stays).
#[test]
fn a_closed_output_pipe_ends_quietly() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.h5");
    let o = common::solve_membrane(&out, &["mesh.n=4", "output.plots=[]"]);
    assert!(o.status.success(), "{}", text(&o));
    let r = out.to_str().unwrap();
    let again = dir.path().join("again.h5");
    let commands: [&[&str]; 3] = [
        &["info", r],
        &["compare", r, r],
        &[
            "solve",
            SCENE,
            "--quiet",
            "--set",
            "mesh.n=4",
            "--set",
            "output.plots=[]",
            "--out",
            again.to_str().unwrap(),
        ],
    ];
    for args in commands {
        let (reader, writer) = std::io::pipe().unwrap();
        drop(reader);
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_obstacle"))
            .args(args)
            .env("CI", "1")
            .stdout(writer)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(141), "{args:?}: {stderr}");
        assert!(stderr.is_empty(), "{args:?}: {stderr}");
    }
    assert!(again.is_file(), "the solve's result is in place");
}

/// The exit status of `solve` says how the run ended: 0 converged or
/// stopped by the scene's rule (`stop = "thesis"` met, KKT above tol), 2
/// stopped by `solver.max_iter` (result written, `converged = false`), 0
/// again for that run with `--failure-marker` (a workflow's outcome), 1 for
/// an error, a usage error included (clap's own status would be 2).
#[test]
fn the_exit_status_says_how_the_run_ended() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.h5");
    let o_str = out.to_str().unwrap();
    let marker = dir.path().join("r.failed");
    let base = ["mesh.n=4", "output.plots=[]", "solver.method=uzawa"];
    let solve = |sets: &[&str], extra: &[&str]| {
        let mut args = vec!["solve", SCENE, "--quiet", "--out", o_str];
        for s in base.iter().chain(sets) {
            args.extend(["--set", s]);
        }
        args.extend(extra);
        run_obstacle(&args)
    };
    let attrs = || {
        let r = obstacle_fem::output::read_result(&out).unwrap();
        (
            common::solver_attr(&r, "converged").to_string(),
            common::solver_attr(&r, "stop_reason").to_string(),
        )
    };
    let o = solve(&["solver.stop=kkt"], &[]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    assert_eq!(attrs(), ("true".into(), "\"kkt\"".into()));

    let o = solve(&["solver.stop=kkt", "solver.max_iter=5"], &[]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("warning: not converged"), "{}", text(&o));
    assert_eq!(attrs(), ("false".into(), "\"max_iter\"".into()));

    let o = solve(
        &["solver.stop=kkt", "solver.max_iter=5"],
        &["--failure-marker", marker.to_str().unwrap()],
    );
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    assert!(!marker.exists());

    let o = solve(
        &[
            "solver.stop=thesis",
            "solver.thesis_tol=1e-2",
            "solver.tol=1e-12",
        ],
        &[],
    );
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    assert_eq!(attrs(), ("false".into(), "\"thesis\"".into()));

    let o = run_obstacle(&["freefem", SCENE, "--iterations", "0"]);
    common::assert_one_error(&o, &["--iterations", "0"], "--iterations 0");
    assert_eq!(o.status.code(), Some(1));
}
